"""Tests of the quarter-resolution measurements beyond the matcher's range (frontend/near.py)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.frontend.near import NearConfig, near_points, wants_near
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity

HEIGHT, WIDTH = 192, 768
NEAR = 160  # px: beyond the half-resolution matcher's 128 px, inside the quarter's 256


def _pair(disparity: int) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """A textured fronto-parallel plane at ``disparity`` px (coarse texture: 4x scale)."""
    rng = np.random.default_rng(3)
    noise = rng.random((HEIGHT, WIDTH + disparity)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 2.5)
    texture = (texture - texture.min()) / (texture.max() - texture.min()) * 255
    scene = texture.astype(np.uint8)
    return np.ascontiguousarray(scene[:, :WIDTH]), np.ascontiguousarray(scene[:, disparity:])


def test_near_points_measure_beyond_the_range() -> None:
    left, right = _pair(NEAR)
    half = compute_disparity(left, right, SgbmConfig(downscale=2))
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    found = near_points(left, right, half, *empty, NearConfig(trigger_share=0.0))
    assert found.matched
    assert found.pixels.shape[0] > 20
    assert np.median(np.abs(found.disparities - NEAR)) < 2.0


def test_near_points_flag_contradicted_lookups_and_skip_far_planes() -> None:
    left, right = _pair(NEAR)
    half = compute_disparity(left, right, SgbmConfig(downscale=2))
    pixels = np.array([[400.0, 96.0], [500.0, 100.0]], np.float32)
    values = np.array([60.0, NEAR], np.float32)
    found = near_points(left, right, half, pixels, values, NearConfig(trigger_share=0.0))
    assert found.contradicted.tolist() == [True, False]
    far_left, far_right = _pair(40)
    far = compute_disparity(far_left, far_right, SgbmConfig(downscale=2))
    always = NearConfig(trigger_share=0.0)
    assert near_points(far_left, far_right, far, pixels, values, always).pixels.shape[0] == 0


def test_trigger() -> None:
    config = NearConfig(trigger_share=0.01)
    far = np.full((64, 64), 40.0, np.float32)
    assert not wants_near(far, config)
    far[:16] = 120.0
    assert wants_near(far, config)
    assert wants_near(np.full((8, 8), np.nan, np.float32), NearConfig(trigger_share=0.0))
    assert not wants_near(np.full((8, 8), np.nan, np.float32), NearConfig())  # nothing valid


def test_a_pair_too_narrow_for_the_quarter_match_is_left_alone() -> None:
    from pcainterp_stream.frontend.near import extend_near

    left, right = _pair(NEAR)
    narrow_left, narrow_right = left[:, :200].copy(), right[:, :200].copy()
    half = np.full(narrow_left.shape, 127.0, np.float32)  # the trigger would fire
    pixels = np.array([[100.0, 50.0]], np.float32)
    values = np.array([120.0], np.float32)
    out = extend_near(narrow_left, narrow_right, half, pixels, values, NearConfig())
    assert out[0] is pixels
    assert out[2] is None
    assert out[3]["near_matched"] == 0
    # too short for the quarter lookup's patch: left alone too, however the map reads
    short_left, short_right = left[:8].copy(), right[:8].copy()
    lookup = np.array([[300.0, 0.0]], np.float32), np.array([60.0], np.float32)
    high = np.full(short_left.shape, 127.0, np.float32)
    short = extend_near(short_left, short_right, high, *lookup, NearConfig())
    assert short[0] is lookup[0]
    assert short[2] is None


FAINT = 12.0  # grey levels of the plane's texture: too faint for the matcher to hold on to


def _occluding_pair(
    near: int, far: int, start: int, stop: int
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """A faint plane at ``far`` px behind a box at ``near`` px over left columns [start, stop)."""
    rng = np.random.default_rng(5)

    def texture(width: int, contrast: float) -> npt.NDArray[np.uint8]:
        noise = cv2.GaussianBlur(rng.random((HEIGHT, width)).astype(np.float32), (0, 0), 2.5)
        scaled = (noise - noise.min()) / (noise.max() - noise.min()) * contrast
        return (scaled + 128 - contrast / 2).astype(np.uint8)

    back, box = texture(WIDTH + far, FAINT), texture(WIDTH + near, 255.0)
    columns = np.arange(WIDTH)
    left = np.where((columns >= start) & (columns < stop), box[:, :WIDTH], back[:, :WIDTH])
    # a right column x sees the box's column x + near where that lies on the box
    on_box = (columns + near >= start) & (columns + near < stop)
    right = np.where(on_box, box[:, near : near + WIDTH], back[:, far : far + WIDTH])
    return np.ascontiguousarray(left, np.uint8), np.ascontiguousarray(right, np.uint8)


@pytest.mark.parametrize(
    ("start", "stop"),
    [
        (480, 720),
        # a box running off the right edge (a car half out of view): its strip's match
        # lands in the right view's own band, which is matched too
        (720, 1000),
    ],
)
def test_the_right_views_check_keeps_points_off_the_occluded_background(
    start: int, stop: int
) -> None:
    # left of the box, columns [start - (NEAR - far), start) of the plane are hidden from
    # the right camera; a matcher lends them the box's value, the right view does not
    far = 40
    left, right = _occluding_pair(NEAR, far, start, stop)
    half = compute_disparity(left, right, SgbmConfig(downscale=2))
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    checked = near_points(left, right, half, *empty, NearConfig(trigger_share=0.0))  # default
    assert checked.pixels.shape[0] > 3
    assert np.all(checked.pixels[:, 0] >= start - 4)
    assert np.median(np.abs(checked.disparities - NEAR)) < 2.0
    unchecked = near_points(
        left, right, half, *empty, NearConfig(trigger_share=0.0, lr_max_diff=0.0)
    )
    assert np.any(unchecked.pixels[:, 0] < start - 4)  # what the check is for


def test_the_right_view_is_matched_only_when_a_value_needs_its_check() -> None:
    from unittest import mock

    import pcainterp_stream.frontend.near as near

    calls: list[bool] = []
    match = near.quarter_disparity

    def counted(*args: object, right_view: bool = False) -> npt.NDArray[np.float32]:
        calls.append(right_view)
        return match(*args, right_view=right_view)  # type: ignore[arg-type]

    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    always = NearConfig(trigger_share=0.0)
    with mock.patch.object(near, "quarter_disparity", counted):
        far_left, far_right = _pair(40)  # nothing near the range's end: no candidate
        far = compute_disparity(far_left, far_right, SgbmConfig(downscale=2))
        near_points(far_left, far_right, far, *empty, always)
        assert calls == [False]
        calls.clear()
        left, right = _pair(NEAR)
        half = compute_disparity(left, right, SgbmConfig(downscale=2))
        assert near_points(left, right, half, *empty, always).pixels.shape[0] > 0
        assert calls == [False, True]


def test_the_added_points_need_extra_noise() -> None:
    # lookups_only tells them from the front end's own lookups by it
    with pytest.raises(ValueError, match="noise"):
        NearConfig(noise=0.0)


def test_a_16_bit_pair_is_matched_on_one_grey_scale() -> None:
    from pcainterp_stream.frontend.near import extend_near
    from pcainterp_stream.frontend.stereo import to_grey8_pair

    left, right = _pair(NEAR)
    # 12-bit images; a small highlight in the right view only would stretch a scale of
    # its own to ~2.3x the left one's
    left16, right16 = left.astype(np.uint16) * 4, right.astype(np.uint16) * 4
    right16[:4, :32] = 4095
    half = compute_disparity(left, right, SgbmConfig(downscale=2))
    lookups = np.array([[400.0, 96.0]], np.float32), np.array([60.0], np.float32)
    config = NearConfig(trigger_share=0.0)
    got = extend_near(left16, right16, half, *lookups, config)
    want = extend_near(*to_grey8_pair(left16, right16), half, *lookups, config)
    assert got[0].shape[0] > 20
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def _wall(height: int, width: int, disparity: int) -> tuple[npt.NDArray[np.uint8], ...]:
    """A textured wall over the whole pair at ``disparity`` px (finer texture than _pair's)."""
    rng = np.random.default_rng(11)
    noise = cv2.GaussianBlur(rng.random((height, width + disparity)).astype(np.float32), (0, 0), 3)
    scene = ((noise - noise.min()) / (noise.max() - noise.min()) * 255).astype(np.uint8)
    return np.ascontiguousarray(scene[:, :width]), np.ascontiguousarray(scene[:, disparity:])


def test_a_near_wall_over_a_1080p_pair_adds_at_most_the_lattices_count() -> None:
    # a 20 px grid over a near wall of a 1920 x 1080 pair was ~4,400 points, a 3840 x 2160
    # one ~19,000: the estimate's solve is cubic in them (200 s and 12 GB for a 4K frame);
    # now at most the fill lattice's count on a 1920 x 1080 pair (near.MAX_NEAR_POINTS)
    most = 1250
    left, right = _wall(1080, 1920, 180)
    half = np.full(left.shape, np.nan, np.float32)  # SGBM measured nothing: all candidates
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    found = near_points(left, right, half, *empty, NearConfig(trigger_share=0.0))
    assert most // 2 < found.pixels.shape[0] <= most
    assert np.median(np.abs(found.disparities - 180)) < 2.0
    # an even, coarser grid over the whole wall, not one side of it cut off
    assert found.pixels[:, 0].min() < 300
    assert found.pixels[:, 0].max() > 1850
    assert found.pixels[:, 1].min() < 30
    assert found.pixels[:, 1].max() > 1030
    xs, ys = np.unique(found.pixels[:, 0]), np.unique(found.pixels[:, 1])
    assert np.ptp(np.diff(xs)) < 1e-3
    assert np.ptp(np.diff(ys)) < 1e-3
    assert 30.0 < np.diff(xs)[0] < 45.0  # a wider side than the 20 px grid's


def test_the_cap_thins_the_grid_evenly_and_leaves_fewer_points_alone() -> None:
    left, right = _pair(NEAR)
    half = compute_disparity(left, right, SgbmConfig(downscale=2))
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    always = NearConfig(trigger_share=0.0)
    full = near_points(left, right, half, *empty, always, max_points=0)
    same = near_points(left, right, half, *empty, always, max_points=full.pixels.shape[0])
    np.testing.assert_array_equal(same.pixels, full.pixels)
    third = full.pixels.shape[0] // 3
    thin = near_points(left, right, half, *empty, always, max_points=third)
    assert third // 2 < thin.pixels.shape[0] <= third
    # the grid laid again with a wider, even side over the same extent
    xs = np.unique(thin.pixels[:, 0])
    assert np.ptp(np.diff(xs)) < 1e-3
    assert np.diff(xs)[0] > 1.5 * always.spacing
    assert np.ptp(thin.pixels[:, 0]) > 0.8 * np.ptp(full.pixels[:, 0])
    assert np.median(np.abs(thin.disparities - NEAR)) < 2.0


def test_the_grid_side_grows_with_a_large_image_as_the_lattices_does() -> None:
    from pcainterp_stream.frontend.fill import scaled_spacing

    left, right = _wall(2160, 3840, 180)
    half = np.full(left.shape, np.nan, np.float32)
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    found = near_points(left, right, half, *empty, NearConfig(trigger_share=0.0), max_points=0)
    side = scaled_spacing(20.0, (256, 8, 3840 - 8, 2160 - 8))
    assert side > 38.0
    xs = np.unique(found.pixels[:, 0])
    assert np.median(np.diff(xs)) == pytest.approx(side, abs=1.0)
    assert found.pixels.shape[0] < 5200  # against ~19,000 at 20 px
