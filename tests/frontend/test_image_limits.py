"""The sizes below which the stereo front end measures nothing (bug hunt 14C F5)."""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream.frontend.image_limits import (
    empty_cause,
    points_floor,
    small_images_cause,
    too_narrow,
    too_small_for_points,
)
from pcainterp_stream.frontend.matchers import DENSE_SGBM, REFINED_DENSE_SGBM
from pcainterp_stream.frontend.sgbm_limits import ImageTooNarrowError
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    SgbmConfig,
    compute_disparity,
    sparse_lookups,
)


@pytest.mark.parametrize("border", [8, 3])
def test_the_points_floor_is_where_a_point_first_has_a_place(border: int) -> None:
    # on a textured image the size of the floor a 1 px lattice has a point to look up; one px
    # less in either direction and neither it nor a corner has a place: the floor tracks
    # detect_corners and the fill's area
    gftt = GfttConfig(border=border, fill_spacing=1.0, fill_placement="lattice")
    width, height = points_floor(gftt, 0)
    assert (width, height) == (2 * border + 1, 2 * border + 1)
    rng = np.random.default_rng(1)
    for w, h, some in (
        (width, height, True),
        (width - 1, height, False),
        (width, height - 1, False),
    ):
        image = (rng.random((h, w)) * 255).astype(np.uint8)
        flat = np.full((h, w), 3.0, np.float32)
        found = sparse_lookups(image, flat, gftt)
        assert (found.counts.corners > 0) == some, (w, h)


def test_the_points_floor_is_right_of_an_unmatched_band() -> None:
    half = SgbmConfig(downscale=2)  # the band left unmatched: 128 px
    assert points_floor(GfttConfig(), half.valid_min_x) == (128 + 8 + 1, 17)
    text = too_small_for_points(136, 100, GfttConfig(), half)
    assert text is not None
    assert "right of SGBM's 128 px unmatched band" in text
    assert too_small_for_points(137, 17, GfttConfig(), half) is None


def test_too_narrow_names_a_range_that_fits_or_the_smallest_width() -> None:
    assert too_narrow(17, REFINED_DENSE_SGBM) is None
    assert too_narrow(16, REFINED_DENSE_SGBM) == (
        "16 px wide, narrower than the 17 px SGBM needs for 160 disparities; no disparity "
        "range fits images this narrow: the smallest, 16 disparities, needs 17 px"
    )
    text = too_narrow(62, SgbmConfig(downscale=2))
    assert text is not None
    assert text.endswith("pass --num-disparities 32 (or less, a multiple of 16)")
    assert too_narrow(6, DENSE_SGBM) is None  # padded: no width of its own


def test_the_matcher_s_own_refusal_advises_no_range_below_16() -> None:
    # the refined matcher's +-8 px pass has 16 disparities whatever --num-disparities
    image = np.zeros((20, 16), np.uint8)
    with pytest.raises(ImageTooNarrowError) as caught:
        compute_disparity(image, image, SgbmConfig(num_disparities=16))
    assert "smaller --num-disparities" not in str(caught.value)
    assert str(caught.value).endswith(
        "no disparity range fits images this narrow (16 is the smallest)"
    )
    assert "pass a smaller --num-disparities" in str(ImageTooNarrowError(40, 129, 128))


def test_the_empty_cause_names_small_images_only() -> None:
    assert empty_cause(None) == "blank, dark or textureless images"
    assert empty_cause((24, 18)).startswith("24x18 px images: under 32 px a side")


def test_the_cause_of_a_small_frame_names_the_floor_it_is_under() -> None:
    # review 14b R4: 132x96 at half-resolution SGBM is under the points' floor (137 px wide),
    # though no side is under 32 px: its frames were blamed on "blank, dark or textureless"
    half = SgbmConfig(downscale=2)
    cause = small_images_cause(132, 96, GfttConfig(), half)
    assert cause is not None
    assert cause.startswith("images of 132x96 px, under the 137x17 px")
    assert small_images_cause(132, 96, None, half) is None  # dense mode: no points floor
    assert small_images_cause(640, 480, GfttConfig(), half) is None
    assert small_images_cause(24, 18, None, SgbmConfig()) == empty_cause((24, 18))
