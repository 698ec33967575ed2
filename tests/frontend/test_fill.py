"""The nudged lattice: a rejected lattice point is moved to where a lookup passes; the
lattice's side on a large image."""

from __future__ import annotations

import math
from dataclasses import replace
from functools import partial

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from pcainterp_stream.frontend.corners import GfttConfig, lattice_points
from pcainterp_stream.frontend.fill import (
    FILL_REFERENCE_AREA,
    NUDGES,
    fill_points,
    nudged_lattice,
    scaled_spacing,
    valid_share,
)
from pcainterp_stream.frontend.stereo import lookup_disparities, sparse_lookups

HEIGHT, WIDTH = 120, 200
AREA = (8, 8, WIDTH - 8, HEIGHT - 8)
SPACING = 40.0
NUDGED = GfttConfig(max_corners=0, fill_spacing=SPACING, fill_placement="nudged")
NONE_KEPT = np.zeros((0, 2), np.float32)


def _textured() -> npt.NDArray[np.uint8]:
    rng = np.random.default_rng(0)
    return np.asarray(rng.integers(0, 256, (HEIGHT, WIDTH)), np.uint8)


def _ramp() -> npt.NDArray[np.float32]:
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    return np.asarray(20.0 + 0.05 * xs + 0.02 * ys, np.float32)


def _look_up(disparity: npt.NDArray[np.float32]) -> partial[object]:
    return partial(lookup_disparities, disparity)


def _nodes() -> npt.NDArray[np.float32]:
    return lattice_points(NONE_KEPT, SPACING, AREA)


def _place(
    disparity: npt.NDArray[np.float32], config: GfttConfig = NUDGED
) -> npt.NDArray[np.float32]:
    return nudged_lattice(_textured(), disparity, config, AREA, _nodes(), _look_up(disparity))


def test_where_every_lookup_passes_the_nudged_lattice_is_the_lattice() -> None:
    np.testing.assert_array_equal(_place(_ramp()), _nodes())


def test_a_rejected_point_moves_a_quarter_side_along_the_first_axis_that_passes() -> None:
    node = _nodes()[7]
    x, y = int(node[0]), int(node[1])
    holed = _ramp()
    holed[y - 3 : y + 4, x - 3 : x + 4] = np.nan  # the node's lookup fails; +x does not
    placed = _place(holed)
    assert len(placed) == len(_nodes())
    moved = placed[-1]
    np.testing.assert_array_equal(moved, node + np.float32(SPACING / 4) * NUDGES[0])
    assert not np.any(np.all(placed == node, axis=1))
    # each point, moved or not, passes the lookup's checks
    assert lookup_disparities(holed, placed).counts.kept == len(placed)


def test_a_point_that_passes_nowhere_is_dropped() -> None:
    node = _nodes()[7]
    x, y = int(node[0]), int(node[1])
    holed = _ramp()
    holed[y - 16 : y + 17, x - 16 : x + 17] = np.nan  # wider than every move
    placed = _place(holed)
    assert len(placed) == len(_nodes()) - 1
    np.testing.assert_array_equal(placed, np.delete(_nodes(), 7, axis=0))


def test_a_move_next_to_a_hole_needs_the_support_share() -> None:
    node = _nodes()[7]
    x, y = int(node[0]), int(node[1])
    holed = _ramp()
    # the node's lookup fails, and the SGBM holes around every move leave it < 90 % valid
    holed[y - 3 : y + 4, x - 3 : x + 4] = np.nan
    holed[y - 20 : y + 21 : 4, x - 20 : x + 21] = np.nan
    holed[y - 2 : y + 3, :] = _ramp()[y - 2 : y + 3, :]  # the row of the x moves stays looked up
    holed[y - 3 : y + 4, x - 3 : x + 4] = np.nan
    moves = node + np.float32(SPACING / 4) * NUDGES
    shares = valid_share(holed, moves)
    assert shares.max() < 0.9
    lenient = replace(NUDGED, nudge_min_support=0.0)
    assert len(_place(holed, lenient)) == len(_nodes())
    assert len(_place(holed)) == len(_nodes()) - 1


@settings(max_examples=examples(30), deadline=None)
@given(
    holes=st.lists(
        st.tuples(
            st.integers(0, WIDTH - 1),
            st.integers(0, HEIGHT - 1),
            st.integers(1, 30),
        ),
        max_size=6,
    ),
    corners=st.lists(
        st.tuples(st.floats(8.0, WIDTH - 9.0), st.floats(8.0, HEIGHT - 9.0)), max_size=8
    ),
)
def test_nudged_points_pass_their_lookups_and_keep_clear_of_the_corners(
    holes: list[tuple[int, int, int]], corners: list[tuple[float, float]]
) -> None:
    holed = _ramp()
    for x, y, half in holes:
        holed[max(y - half, 0) : y + half + 1, max(x - half, 0) : x + half + 1] = np.nan
    kept = np.array(corners, np.float32).reshape(-1, 2)
    grey = _textured()
    look_up = _look_up(holed)
    placed = fill_points(grey, holed, NUDGED, AREA, kept, look_up)
    nodes = lattice_points(kept, SPACING, AREA)
    assert len(placed) <= len(nodes)
    assert lookup_disparities(holed, placed).counts.kept == len(placed)
    if len(kept) and len(placed):
        gaps = np.sqrt(((placed[:, None, :] - kept[None, :, :]) ** 2).sum(axis=2))
        assert gaps.min() > SPACING * (0.5 - np.sqrt(2.0) / 4)
    # every point is a lattice point or one move from one, at most one per lattice point
    offsets = placed[:, None, :] - nodes[None, :, :]
    steps = np.concatenate([np.zeros((1, 2), np.float32), NUDGES]) * np.float32(SPACING / 4)
    owner = np.full(len(placed), -1)
    for step in steps:
        match = np.all(np.abs(offsets - step) < 1e-4, axis=2)
        owner = np.where(match.any(axis=1) & (owner < 0), match.argmax(axis=1), owner)
    assert np.all(owner >= 0)
    assert len(np.unique(owner)) == len(owner)
    # the plain lattice keeps a subset of them
    lattice = fill_points(
        grey, holed, replace(NUDGED, fill_placement="lattice"), AREA, kept, look_up
    )
    assert lookup_disparities(holed, lattice).counts.kept <= len(placed)


def test_the_front_ends_counts_add_up_with_the_nudged_lattice() -> None:
    holed = _ramp()
    for x, y in _nodes().astype(int):  # every lattice point's lookup fails
        holed[y - 3 : y + 4, x - 3 : x + 4] = np.nan
    config = replace(NUDGED, max_corners=5, min_distance=5.0)
    found = sparse_lookups(_textured(), holed, config)
    plain = sparse_lookups(_textured(), holed, replace(config, fill_placement="lattice"))
    assert found.counts.kept > plain.counts.kept
    counts = found.counts
    assert counts.corners == (
        counts.kept + counts.outside + counts.invalid + counts.discontinuity + counts.inconsistent
    )


def test_the_support_share_is_checked() -> None:
    with pytest.raises(ValueError, match="nudge_min_support must be in"):
        GfttConfig(nudge_min_support=-0.1)


def _searched(
    width: int, height: int, band: int = 128, border: int = 8
) -> tuple[int, int, int, int]:
    return (band, border, width - border, height - border)


def test_a_4k_pairs_fill_keeps_about_the_reference_areas_points() -> None:
    """Bug hunt 8C F5: a 4096x2160 pair's 40 px lattice had 5346 points (43 s per frame)."""
    height, width = 2160, 4096
    area = _searched(width, height)
    grey = np.asarray(np.random.default_rng(1).integers(0, 256, (height, width)), np.uint8)
    disparity = np.full((height, width), 20.0, np.float32)
    look_up = _look_up(disparity)
    reference = FILL_REFERENCE_AREA / 40.0**2  # the points on the reference area
    for placement in ("nudged", "lattice"):
        gftt = GfttConfig(fill_placement=placement)
        placed = fill_points(grey, disparity, gftt, area, NONE_KEPT, look_up)
        assert 0.9 * reference <= len(placed) <= 1.1 * reference, (placement, len(placed))
    # spread evenly: the lattice of the grown side, every point of it
    side = scaled_spacing(40.0, area)
    assert side > 80.0
    np.testing.assert_array_equal(placed, lattice_points(NONE_KEPT, side, area))


@pytest.mark.parametrize(
    ("width", "height", "spacing"),
    [(1242, 375, 40.0), (1241, 376, 34.0), (752, 480, 40.0), (1280, 720, 10.0), (1920, 1080, 40.0)],
)
def test_the_fill_is_unchanged_up_to_1080p(width: int, height: int, spacing: float) -> None:
    """KITTI, EuRoC, 1280x720 and 1920x1080 keep the given side and the very same points."""
    area = _searched(width, height)
    assert scaled_spacing(spacing, area) == spacing
    grey = np.asarray(np.random.default_rng(2).integers(0, 256, (height, width)), np.uint8)
    disparity = np.full((height, width), 20.0, np.float32)
    gftt = GfttConfig(fill_spacing=spacing, fill_placement="lattice")
    placed = fill_points(grey, disparity, gftt, area, NONE_KEPT, _look_up(disparity))
    np.testing.assert_array_equal(placed, lattice_points(NONE_KEPT, spacing, area))


def test_the_side_grows_with_the_square_root_of_the_area_past_the_reference() -> None:
    side = math.sqrt(FILL_REFERENCE_AREA)
    assert scaled_spacing(40.0, (0, 0, int(side), int(side))) == 40.0
    assert scaled_spacing(40.0, (0, 0, int(2 * side), int(2 * side))) == pytest.approx(
        80.0, rel=1e-3
    )
    assert scaled_spacing(0.0, (0, 0, 10_000, 10_000)) == 0.0  # no lattice stays none
