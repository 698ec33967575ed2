"""Tests of the stereo front end on synthetic pairs with known disparity (and one KITTI pair)."""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pcainterp_stream.frontend.fill import weighted_fill
from pcainterp_stream.frontend.matchers import DENSE_SGBM, REFINED_DENSE_SGBM
from pcainterp_stream.frontend.refine import TEXTURELESS, fill_rows, textureless
from pcainterp_stream.frontend.sgbm_limits import ImageTooNarrowError, narrowest_width
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    LookupMethod,
    SgbmConfig,
    SgbmMode,
    StereoFrontEnd,
    compute_disparity,
    compute_right_disparity,
    compute_weak_disparity,
    detect_corners,
    lattice_points,
    lookup_disparities,
    sparse_lookups,
    to_grey8_pair,
)

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
KITTI_DRIVE = REALDATA / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"

HEIGHT, WIDTH = 160, 320
D_BACK, D_FRONT = 10.3, 20.6  # fractional on purpose: sub-pixel recovery is tested
RECT = (150, 50, 250, 110)  # x0, y0, x1, y1 of the nearer rectangle in the left image
SGBM = SgbmConfig(num_disparities=32)
GFTT = GfttConfig(max_corners=300, min_distance=5.0)
LATTICE_24 = GfttConfig(
    max_corners=20, min_distance=5.0, fill_spacing=24.0, fill_placement="lattice"
)
"""20 corners and the plain lattice of side 24 px in their gaps (no point moved)."""


def _texture(rng: np.random.Generator, height: int, width: int) -> npt.NDArray[np.float32]:
    noise = rng.random((height, width)).astype(np.float32)
    image = cv2.GaussianBlur(noise, (0, 0), 1.2)
    return np.asarray((image - image.min()) / (image.max() - image.min()), np.float32)


def _synthetic_pair(
    seed: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8], npt.NDArray[np.float32]]:
    """Textured plane at D_BACK with a nearer textured rectangle at D_FRONT.

    Right pixel (x_r, y) sees the surface point of left pixel (x_r + d, y); the rectangle
    occludes the background in both views. Returns (left, right, true left disparity).
    """
    rng = np.random.default_rng(seed)
    back = _texture(rng, HEIGHT, WIDTH + 64)
    front = _texture(rng, HEIGHT, WIDTH + 64)
    x0, y0, x1, y1 = RECT
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    in_left = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
    left = np.where(in_left, front[:, :WIDTH], back[:, :WIDTH])
    x_front = xs + np.float32(D_FRONT)
    right_back = cv2.remap(back, xs + np.float32(D_BACK), ys, cv2.INTER_CUBIC)
    right_front = cv2.remap(front, x_front, ys, cv2.INTER_CUBIC)
    in_right = (x_front >= x0) & (x_front < x1) & (ys >= y0) & (ys < y1)
    right = np.where(in_right, right_front, right_back)
    truth = np.where(in_left, D_FRONT, D_BACK).astype(np.float32)

    def to_uint8(image: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8]:
        return np.asarray(np.clip(image * 255 + 0.5, 0, 255), np.uint8)

    return to_uint8(left), to_uint8(right), truth


@pytest.fixture(scope="module")
def pair() -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8], npt.NDArray[np.float32]]:
    return _synthetic_pair()


@pytest.fixture(scope="module")
def disparity(
    pair: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8], npt.NDArray[np.float32]],
) -> npt.NDArray[np.float32]:
    return compute_disparity(pair[0], pair[1], SGBM)


def _truth_at(truth: npt.NDArray[np.float32], pixels: npt.NDArray[np.float32]) -> npt.NDArray[Any]:
    cols = np.clip(np.round(pixels[:, 0]).astype(int), 0, truth.shape[1] - 1)
    rows = np.clip(np.round(pixels[:, 1]).astype(int), 0, truth.shape[0] - 1)
    return np.asarray(truth[rows, cols])


def _ramp(height: int = 100, width: int = 200) -> npt.NDArray[np.float32]:
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    return np.asarray(10.0 + 0.3 * xs + 0.2 * ys, np.float32)


# --- corners -----------------------------------------------------------------------------


def test_corners_found_inside_usable_area(pair: tuple[npt.NDArray[Any], ...]) -> None:
    corners = detect_corners(pair[0], GFTT, min_x=SGBM.valid_min_x)
    assert corners.dtype == np.float32
    assert corners.shape[1] == 2
    assert corners.shape[0] >= 200
    slack = GFTT.subpixel_window  # cornerSubPix moves a corner at most this far
    assert corners[:, 0].min() >= SGBM.valid_min_x - slack
    assert corners[:, 0].max() <= WIDTH - 1 - GFTT.border + slack
    assert corners[:, 1].min() >= GFTT.border - slack
    assert corners[:, 1].max() <= HEIGHT - 1 - GFTT.border + slack
    # sub-pixel refinement moves positions off the integer grid
    assert np.mean(corners != np.round(corners)) > 0.5


def test_corners_are_those_of_the_whole_image_with_the_mask(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    # detect_corners searches a crop around the usable area: the corners must be the same
    grey = to_grey8_pair(pair[0], pair[1])[0]
    height, width = grey.shape
    config = GfttConfig(subpixel=False)
    for min_x in (0, 3, 40):
        mask = np.zeros((height, width), np.uint8)
        x_start = max(config.border, min_x)
        mask[config.border : height - config.border, x_start : width - config.border] = 255
        whole = cv2.goodFeaturesToTrack(
            grey,
            config.max_corners,
            config.quality_level,
            config.min_distance,
            mask=mask,
            blockSize=config.block_size,
        )
        found = detect_corners(grey, config, min_x=min_x)
        np.testing.assert_array_equal(found, whole.reshape(-1, 2))


def test_blank_image_gives_empty_corners_and_measurements() -> None:
    blank = np.full((HEIGHT, WIDTH), 128, np.uint8)
    corners = detect_corners(blank, GFTT)
    assert corners.shape == (0, 2)
    assert corners.dtype == np.float32
    result = StereoFrontEnd(gftt=GFTT, sgbm=SGBM).measure(blank, blank)
    assert result.pixels.shape == (0, 2)
    assert result.disparities.shape == (0,)
    assert result.counts.corners == 0
    assert result.disparity_map.shape == (HEIGHT, WIDTH)


def test_left_band_is_not_searched(pair: tuple[npt.NDArray[Any], ...]) -> None:
    corners = detect_corners(pair[0], GFTT, min_x=WIDTH)
    assert corners.shape == (0, 2)


def test_buckets_spread_the_corners_over_the_cells() -> None:
    # strong texture on the left tenth, faint texture elsewhere: strongest-first takes the
    # strong tenth, in turns every cell gets its share
    rng = np.random.default_rng(3)
    image = rng.normal(128, 15, (HEIGHT, WIDTH))
    image[:, :32] = rng.normal(128, 60, (HEIGHT, 32))
    grey = np.asarray(np.clip(image, 0, 255), np.uint8)
    plain = GfttConfig(max_corners=80, min_distance=3.0)
    bucketed = GfttConfig(max_corners=80, min_distance=3.0, buckets=(4, 2))
    strongest = detect_corners(grey, plain)
    in_turns = detect_corners(grey, bucketed)
    assert len(in_turns) == 80
    assert np.mean(strongest[:, 0] < 40) > 0.9
    columns = (in_turns[:, 0] * 4 // WIDTH).astype(int)
    cells = columns * 2 + (in_turns[:, 1] * 2 // HEIGHT).astype(int)
    assert np.bincount(cells, minlength=8).min() >= 5


def test_lattice_points_fill_only_the_gaps() -> None:
    area = (10, 10, 210, 110)
    assert lattice_points(np.zeros((0, 2), np.float32), 0.0, area).shape == (0, 2)
    full = lattice_points(np.zeros((0, 2), np.float32), 20.0, area)
    assert full.shape == (10 * 5, 2)
    # centred in the area, 20 px apart
    assert np.allclose(np.diff(np.unique(full[:, 0])), 20.0)
    assert full[:, 0].min() - 10 == pytest.approx(209 - full[:, 0].max())
    kept = full[:7] + np.float32(3.0)
    gaps = lattice_points(kept, 20.0, area)
    distance = np.sqrt(((gaps[:, None, :] - kept[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
    assert distance.min() > 10.0
    assert len(gaps) == 50 - 7


def test_lattice_lookups_measure_the_gaps(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, truth = pair
    corners_only = GfttConfig(max_corners=20, min_distance=5.0, fill_spacing=0.0)
    filled = LATTICE_24
    sparse = StereoFrontEnd(gftt=corners_only, sgbm=SGBM).measure(left, right)
    dense = StereoFrontEnd(gftt=filled, sgbm=SGBM).measure(left, right)
    assert dense.counts.kept >= sparse.counts.kept + 40
    np.testing.assert_array_equal(dense.pixels[: sparse.counts.kept], sparse.pixels)
    error = np.abs(dense.disparities - _truth_at(truth, dense.pixels))
    assert np.median(error) < 0.15
    counts = dense.counts
    assert counts.corners == (
        counts.kept + counts.outside + counts.invalid + counts.discontinuity + counts.inconsistent
    )


def test_no_corners_looks_up_the_lattice_alone(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, truth = pair
    lattice = GfttConfig(
        max_corners=0, fill_spacing=24.0, fill_placement="lattice", fill_min_support=0.0
    )
    assert detect_corners(left, lattice).shape == (0, 2)
    found = StereoFrontEnd(gftt=lattice, sgbm=SGBM).measure(left, right)
    area = (max(lattice.border, SGBM.valid_min_x), lattice.border)
    area += (WIDTH - lattice.border, HEIGHT - lattice.border)
    expected = lattice_points(np.zeros((0, 2), np.float32), 24.0, area)
    assert 0 < found.counts.kept <= len(expected) == found.counts.corners
    # every kept point is a lattice point, and measured as well as the corners are
    on_lattice = np.abs(found.pixels[:, None, :] - expected[None, :, :]).sum(axis=2).min(axis=1)
    assert on_lattice.max() == 0.0
    assert np.median(np.abs(found.disparities - _truth_at(truth, found.pixels))) < 0.15


@pytest.mark.parametrize(
    "config",
    [
        SgbmConfig(),
        SgbmConfig(downscale=2),
        SgbmConfig(mode=SgbmMode.SGBM, block_size=7),
        SgbmConfig(min_disparity=16, num_disparities=32),
        REFINED_DENSE_SGBM,
    ],
    ids=["full", "half", "sgbm-mode", "min-disparity", "refined"],
)
def test_too_narrow_a_pair_is_refused_not_crashed(config: SgbmConfig) -> None:
    # OpenCV's 3-way SGBM crashes the process on images narrower than its range
    rng = np.random.default_rng(4)
    width = narrowest_width(config)
    image = (rng.random((24, width)) * 255).astype(np.uint8)
    assert compute_disparity(image, image, config).shape == image.shape
    narrower = np.ascontiguousarray(image[:, :-1])
    with pytest.raises(ImageTooNarrowError, match="narrower than the"):
        compute_disparity(narrower, narrower, config)


def test_a_padded_matcher_matches_a_narrow_pair() -> None:
    # the left band's padding gives SGBM the columns the range needs
    image = (np.random.default_rng(5).random((24, 6)) * 255).astype(np.uint8)
    assert narrowest_width(DENSE_SGBM) <= 6
    assert compute_disparity(image, image, DENSE_SGBM).shape == image.shape


def test_neither_corners_nor_lattice_is_refused() -> None:
    with pytest.raises(ValueError, match="needs a lattice"):
        GfttConfig(max_corners=0, fill_spacing=0.0)
    with pytest.raises(ValueError, match="max_corners must be >= 0"):
        GfttConfig(max_corners=-1)


def test_sparse_lookups_are_the_front_ends(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, _ = pair
    filled = GfttConfig(max_corners=20, min_distance=5.0, fill_spacing=24.0)
    measured = StereoFrontEnd(gftt=filled, sgbm=SGBM).measure(left, right)
    found = sparse_lookups(left, measured.disparity_map, filled, min_x=SGBM.valid_min_x)
    np.testing.assert_array_equal(found.pixels, measured.pixels)
    np.testing.assert_array_equal(found.disparities, measured.disparities)
    assert found.counts == measured.counts


def test_no_lattice_lookups_on_a_blank_surface() -> None:
    # SGBM's costs tie on a blank image and it returns disparity 0 everywhere
    blank = np.full((HEIGHT, WIDTH), 128, np.uint8)
    assert np.nanmax(compute_disparity(blank, blank, SGBM)) == 0.0
    filled = GfttConfig(fill_spacing=20.0)
    assert StereoFrontEnd(gftt=filled, sgbm=SGBM).measure(blank, blank).counts.corners == 0


# --- lookup on analytic maps ---------------------------------------------------------------


def test_bilinear_lookup_is_exact_on_a_ramp() -> None:
    disparity = _ramp()
    rng = np.random.default_rng(1)
    corners = np.column_stack([rng.uniform(5, 190, 200), rng.uniform(5, 90, 200)]).astype(
        np.float32
    )
    found = lookup_disparities(disparity, corners)
    assert found.counts.kept == 200
    expected = 10.0 + 0.3 * corners[:, 0] + 0.2 * corners[:, 1]
    np.testing.assert_allclose(found.disparities, expected, atol=1e-3)
    np.testing.assert_array_equal(found.pixels, corners)


def test_median_lookup_takes_the_nearest_pixel_value_on_a_ramp() -> None:
    disparity = _ramp()
    corners = np.array([[20.4, 30.6], [100.0, 50.0], [150.7, 70.2]], np.float32)
    found = lookup_disparities(disparity, corners, method=LookupMethod.MEDIAN, median_window=5)
    nearest = np.round(corners)
    np.testing.assert_allclose(
        found.disparities, 10.0 + 0.3 * nearest[:, 0] + 0.2 * nearest[:, 1], atol=1e-4
    )


def test_invalid_region_yields_no_lookups() -> None:
    disparity = _ramp()
    disparity[40:60, 80:120] = np.nan
    inside_hole = np.array([[90.3, 45.5], [100.0, 50.0], [110.6, 55.2]], np.float32)
    next_to_hole = np.array([[78.0, 50.0], [100.0, 60.2]], np.float32)
    far = np.array([[30.0, 30.0]], np.float32)
    found = lookup_disparities(disparity, np.concatenate([inside_hole, next_to_hole, far]))
    assert found.counts.invalid == 3
    assert found.counts.discontinuity == 2  # valid sample, but a hole in the support patch
    assert found.counts.kept == 1
    np.testing.assert_array_equal(found.indices, [5])


def test_out_of_image_and_nan_corners_are_counted() -> None:
    corners = np.array([[-1.0, 10.0], [199.5, 10.0], [50.0, 0.2], [np.nan, 5.0]], np.float32)
    found = lookup_disparities(_ramp(), corners)
    assert found.counts.outside == 4
    assert found.pixels.shape == (0, 2)


def test_empty_corners_are_data() -> None:
    found = lookup_disparities(_ramp(), np.zeros((0, 2), np.float32))
    assert found.pixels.shape == (0, 2)
    assert found.disparities.shape == (0,)
    assert found.counts.corners == 0


def test_lr_check_rejects_an_injected_inconsistency() -> None:
    left = np.full((100, 200), 12.0, np.float32)
    right = np.full((100, 200), 12.0, np.float32)
    right[:, 100:140] += 3.0  # right pixels 100..139 disagree; they match left x 112..151
    right[:, :20] = np.nan  # no right value: no evidence against the left one
    corners = np.array(
        [[60.0, 50.0], [120.5, 50.0], [140.2, 30.0], [170.0, 20.0], [25.0, 40.0]], np.float32
    )
    without = lookup_disparities(left, corners)
    assert without.counts.kept == 5
    checked = lookup_disparities(left, corners, right_disparity=right)
    assert checked.counts.inconsistent == 2
    np.testing.assert_array_equal(checked.indices, [0, 3, 4])


def test_bad_lookup_arguments_raise() -> None:
    with pytest.raises(ValueError, match=r"corners must have shape \(k, 2\)"):
        lookup_disparities(_ramp(), np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match=r"right_disparity has shape \(5, 5\)"):
        lookup_disparities(
            _ramp(), np.zeros((0, 2), np.float32), right_disparity=np.zeros((5, 5), np.float32)
        )


# --- SGBM on the synthetic pair ------------------------------------------------------------


def test_sgbm_lookups_recover_the_true_disparity(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    left, right, truth = pair
    result = StereoFrontEnd(gftt=GFTT, sgbm=SGBM).measure(left, right)
    assert result.counts.kept >= 200
    error = np.abs(result.disparities - _truth_at(truth, result.pixels))
    # SGBM's parabolic sub-pixel fit is biased towards integers ("pixel locking", up to
    # ~0.3 px at fractional parts near 0.5), so bound the bulk, not every value.
    assert np.median(error) < 0.15
    assert np.mean(error < 0.25) >= 0.9
    # no lookup takes a value blended across the rectangle's outline
    nearest_layer = np.minimum(
        np.abs(result.disparities - D_BACK), np.abs(result.disparities - D_FRONT)
    )
    assert nearest_layer.max() < 1.0
    counts = result.counts
    assert dict(counts) == {
        "corners": counts.corners,
        "kept": counts.kept,
        "outside": counts.outside,
        "invalid": counts.invalid,
        "discontinuity": counts.discontinuity,
        "inconsistent": counts.inconsistent,
        "far_zeros": counts.far_zeros,
        "far_rematched": counts.far_rematched,
    }
    assert counts.corners == (
        counts.kept + counts.outside + counts.invalid + counts.discontinuity + counts.inconsistent
    )


def test_corners_on_the_rectangle_outline_are_rejected(
    disparity: npt.NDArray[np.float32],
) -> None:
    x0, y0, x1, y1 = RECT
    ys = np.arange(y0 + 2, y1 - 2, 0.7, dtype=np.float32)
    xs = np.arange(x0 + 2, x1 - 2, 0.7, dtype=np.float32)
    outline = np.concatenate(
        [
            np.column_stack([np.full_like(ys, x0 - 0.5), ys]),
            np.column_stack([np.full_like(ys, x1 - 0.5), ys]),
            np.column_stack([xs, np.full_like(xs, y0 - 0.5)]),
            np.column_stack([xs, np.full_like(xs, y1 - 0.5)]),
        ]
    )
    found = lookup_disparities(disparity, outline)
    assert found.counts.kept <= 0.05 * len(outline)
    assert found.counts.discontinuity + found.counts.invalid >= 0.9 * len(outline)


def test_sgbm_left_band_yields_no_lookups(disparity: npt.NDArray[np.float32]) -> None:
    ys = np.arange(20.0, 140.0, 7.0, dtype=np.float32)
    band = np.column_stack([np.full_like(ys, 5.0), ys])  # x < min_disp + num_disp - ~10
    assert np.isnan(disparity[:, :10]).all()
    assert lookup_disparities(disparity, band).counts.kept == 0


def test_lr_check_on_sgbm_keeps_good_lookups(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, _ = pair
    right_map = compute_right_disparity(left, right, SGBM)
    # the right view's map: right pixel x_r matches left x_r + d
    rows, cols = 80, np.arange(60, 120)
    np.testing.assert_allclose(np.nanmedian(right_map[rows, cols]), D_BACK, atol=0.25)
    plain = StereoFrontEnd(gftt=GFTT, sgbm=SGBM).measure(left, right)
    checked = StereoFrontEnd(gftt=GFTT, sgbm=SGBM, lr_check=True).measure(left, right)
    assert checked.counts.kept >= 0.9 * plain.counts.kept
    assert checked.counts.kept + checked.counts.inconsistent == plain.counts.kept


def test_half_resolution_matching(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, truth = pair
    half = SgbmConfig(num_disparities=32, downscale=2)
    result = StereoFrontEnd(gftt=GFTT, sgbm=half).measure(left, right)
    assert result.disparity_map.shape == (HEIGHT, WIDTH)
    assert result.counts.kept >= 150
    error = np.abs(result.disparities - _truth_at(truth, result.pixels))
    assert np.median(error) < 0.3


def test_full_width_matching_fills_the_left_band(pair: tuple[npt.NDArray[Any], ...]) -> None:
    left, right, _ = pair
    wide = SgbmConfig(num_disparities=32, full_width=True)
    assert (wide.valid_min_x, wide.band, SGBM.valid_min_x) == (0, 32, 32)
    plain = compute_disparity(left, right, SGBM)
    padded = compute_disparity(left, right, wide)
    assert padded.shape == (HEIGHT, WIDTH)
    # the band: the plain matcher leaves it empty; padded, the pixels whose match is in
    # the right image (x >= d, with a margin for the block) get the true disparity
    assert np.isnan(plain[:, : SGBM.band - 1]).mean() > 0.9
    seen = padded[8:-8, int(D_BACK) + 4 : SGBM.band]
    assert np.isfinite(seen).mean() > 0.9
    assert np.nanmedian(np.abs(seen - D_BACK)) < 0.3
    # right of the band the two matchers agree
    both = np.isfinite(plain) & np.isfinite(padded)
    both[:, : SGBM.band] = False
    assert np.mean(np.abs(plain - padded)[both] < 0.5) > 0.99
    # and it runs at half resolution too
    half = compute_disparity(
        left, right, SgbmConfig(num_disparities=32, downscale=2, full_width=True)
    )
    assert np.isfinite(half[8:-8, int(D_BACK) + 8 : SGBM.band]).mean() > 0.8


def test_near_half_of_the_range_comes_from_half_resolution(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    left, right, truth = pair
    split = SgbmConfig(num_disparities=32, full_width=True, near_at_half=True)
    assert split.split() == (
        SgbmConfig(num_disparities=16, full_width=True),
        SgbmConfig(num_disparities=32, full_width=True, downscale=2),
    )
    for whole in (SgbmConfig(num_disparities=16, near_at_half=True), SGBM):
        assert whole.split() is None
    assert SgbmConfig(num_disparities=32, downscale=2, near_at_half=True).split() is None
    # the far matcher searches [0, 16): the front rectangle (20.6 px) lies beyond it, and
    # both surfaces lie at or beyond 16 - NEAR_MARGIN = 8, so they come from the half
    # resolution match of the whole range
    far = compute_disparity(left, right, SgbmConfig(num_disparities=16, full_width=True))
    mixed = compute_disparity(left, right, split)
    half = compute_disparity(left, right, split.split()[1])  # type: ignore[index]
    inner = np.zeros(truth.shape, bool)
    inner[8:-8, 40:-8] = True
    front = inner & (truth == np.float32(D_FRONT)) & np.isfinite(mixed)
    assert front.sum() > 1000
    assert np.median(np.abs(mixed[front] - D_FRONT)) < 0.5
    assert np.nanmedian(np.abs(far[front] - D_FRONT)) > 3  # the far matcher alone cannot
    near = np.isfinite(half) & (half >= 8)
    np.testing.assert_array_equal(mixed[near], half[near])
    # where the half-resolution value is farther, the full-resolution one is kept
    wide = SgbmConfig(num_disparities=64, full_width=True, near_at_half=True)
    far_wide = compute_disparity(left, right, SgbmConfig(num_disparities=32, full_width=True))
    half_wide = compute_disparity(left, right, wide.split()[1])  # type: ignore[index]
    kept = ~(half_wide >= 24)
    np.testing.assert_array_equal(compute_disparity(left, right, wide)[kept], far_wide[kept])


def test_half_resolution_refined_at_full_resolution(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    left, right, truth = pair
    full = SgbmConfig(num_disparities=32, full_width=True)
    refined_config = SgbmConfig(num_disparities=32, full_width=True, refine_range=8)
    refined = compute_disparity(left, right, refined_config)
    whole = compute_disparity(left, right, full)
    half = compute_disparity(
        left, right, SgbmConfig(num_disparities=32, full_width=True, downscale=2)
    )
    inner = np.zeros(truth.shape, bool)
    inner[8:-8, 8:-8] = True
    both = inner & np.isfinite(refined) & np.isfinite(whole)
    assert both.sum() > 0.8 * inner.sum()
    # as accurate as the whole range at full resolution, and finer than half resolution
    refined_error = np.abs(refined[both] - truth[both])
    assert np.mean(refined_error) < np.mean(np.abs(whole[both] - truth[both])) + 0.05
    assert np.mean(refined_error) < 0.8 * np.nanmean(np.abs(half[both] - truth[both]))
    # both surfaces, the nearer one too
    for value in (D_BACK, D_FRONT):
        surface = both & (truth == np.float32(value))
        assert np.median(np.abs(refined[surface] - value)) < 0.25
    # the half-resolution map's holes stay holes (each hole pixel its 2x2 pixels); no match
    # left of the right image
    size = (truth.shape[1] // 2, truth.shape[0] // 2)
    coarse = compute_disparity(
        *(cv2.resize(image, size, interpolation=cv2.INTER_AREA) for image in (left, right)),
        SgbmConfig(num_disparities=32, full_width=True, downscale=2).matched(),
    )
    coarse_holes = np.isnan(coarse).repeat(2, axis=0).repeat(2, axis=1)
    assert coarse_holes.any()
    assert not np.isfinite(refined[coarse_holes]).any()
    columns = np.arange(truth.shape[1], dtype=np.float32)[None, :]
    assert not (refined > columns).any()
    # at half resolution the refinement is off
    np.testing.assert_array_equal(
        compute_disparity(left, right, replace(refined_config, downscale=2)), half
    )


def test_refined_map_removes_textureless_pixels_and_marks_weak_ones(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    left, right, _truth = pair
    config = SgbmConfig(num_disparities=32, full_width=True, refine_range=8)
    # a blank square (the sky, a white wall) in both images, on the farther surface
    blank_left, blank_right = left.copy(), right.copy()
    blank_left[20:60, 40:100] = 128
    blank_right[20:60, 40 - 10 : 100 - 10] = 128
    disparity, weak = compute_weak_disparity(blank_left, blank_right, config)
    assert weak is not None
    assert weak.shape == disparity.shape
    half = cv2.resize(blank_left, (WIDTH // 2, HEIGHT // 2), interpolation=cv2.INTER_AREA)
    flat = textureless(half).repeat(2, axis=0).repeat(2, axis=1)
    assert flat[30:50, 50:90].all()  # the blank square's inside, at least
    assert not np.isfinite(disparity[flat]).any()
    # the textured rest keeps its values; the map is compute_disparity's
    np.testing.assert_array_equal(disparity, compute_disparity(blank_left, blank_right, config))
    assert np.isfinite(disparity[~flat]).mean() > 0.8
    # weak pixels are valid ones, found next to the half-resolution map's holes (the
    # nearer rectangle's occlusion edge and the blank square), a small share of the map
    assert not weak[~np.isfinite(disparity)].any()
    assert 0 < weak.sum() < 0.25 * np.isfinite(disparity).sum()
    # other matchers mark none
    assert compute_weak_disparity(left, right, replace(config, refine_range=0))[1] is None
    measured = StereoFrontEnd(gftt=GFTT, sgbm=config).measure(blank_left, blank_right)
    assert measured.weak is not None
    np.testing.assert_array_equal(measured.weak, weak)
    assert StereoFrontEnd(gftt=GFTT, sgbm=SGBM).measure(left, right).weak is None


def test_textureless_is_the_mean_gradient_below_the_threshold() -> None:
    rng = np.random.default_rng(3)
    image = np.full((40, 60), 100, np.uint8)
    image[:, 30:] = rng.integers(0, 255, (40, 30), dtype=np.uint8)
    found = textureless(image)
    assert found[:, :20].all()
    assert not found[:, 40:].any()
    # a ramp of one grey level per px (8 through the 3x3 Sobel's weights) is texture
    ramp = np.tile(np.arange(60, dtype=np.uint8), (40, 1))
    assert TEXTURELESS < 8
    assert not textureless(ramp)[:, 4:-4].any()


@pytest.mark.parametrize(
    "changes",
    [{"refine_range": -8}, {"refine_range": 12}, {"refine_range": 8, "near_at_half": True}],
)
def test_refine_range_is_checked(changes: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="refine_range"):
        SgbmConfig(**changes)


@settings(max_examples=60, deadline=None)
@given(
    values=arrays(
        np.float32,
        st.tuples(st.integers(1, 4), st.integers(1, 12)),
        elements=st.one_of(st.just(np.float32(np.nan)), st.floats(0, 100, width=32)),
    )
)
def test_row_fill_takes_the_nearest_value_on_the_left(values: npt.NDArray[np.float32]) -> None:
    filled = fill_rows(values)
    for row, out in zip(values, filled, strict=True):
        valid = np.flatnonzero(np.isfinite(row))
        for x, value in enumerate(out):
            if np.isfinite(row[x]):
                assert value == row[x]
                continue
            left = valid[valid < x]
            right = valid[valid > x]
            if left.size:
                assert value == row[left[-1]]
            elif right.size:
                assert value == row[right[0]]
            else:
                assert value == 0.0


# --- inputs --------------------------------------------------------------------------------


def test_mismatched_sizes_raise_naming_both_shapes(pair: tuple[npt.NDArray[Any], ...]) -> None:
    with pytest.raises(ValueError, match=r"\(160, 320\).*\(160, 300\)"):
        compute_disparity(pair[0], pair[1][:, :300], SGBM)
    with pytest.raises(ValueError, match=r"\(160, 320\).*\(160, 300\)"):
        StereoFrontEnd().measure(pair[0], pair[1][:, :300])


def test_unsupported_image_type_raises() -> None:
    image = np.zeros((10, 40), np.float32)
    with pytest.raises(ValueError, match="left image has shape"):
        compute_disparity(image, image, SGBM)


def test_rgb_input_matches_grey(
    pair: tuple[npt.NDArray[Any], ...], disparity: npt.NDArray[np.float32]
) -> None:
    left, right, _ = pair
    rgb_left = np.repeat(left[:, :, None], 3, axis=2)
    rgb_right = np.repeat(right[:, :, None], 3, axis=2)
    np.testing.assert_array_equal(compute_disparity(rgb_left, rgb_right, SGBM), disparity)


def test_uint16_input_is_scaled_to_8_bit(
    pair: tuple[npt.NDArray[Any], ...], disparity: npt.NDArray[np.float32]
) -> None:
    left, right, _ = pair
    # a 12-bit camera: >> 8 would leave 16 grey levels
    left16 = (left.astype(np.uint16) * 16).astype(np.uint16)
    right16 = (right.astype(np.uint16) * 16).astype(np.uint16)
    grey_left, _ = to_grey8_pair(left16, right16)
    assert grey_left.dtype == np.uint8
    assert grey_left.max() == 255
    assert len(np.unique(grey_left)) > 150
    from16 = compute_disparity(left16, right16, SGBM)
    both = ~np.isnan(from16) & ~np.isnan(disparity)
    assert both.mean() > 0.8
    assert np.mean(np.abs(from16[both] - disparity[both]) <= 0.25) > 0.95


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="multiple of 16, got 100"):
        SgbmConfig(num_disparities=100)
    with pytest.raises(ValueError, match="block_size must be odd"):
        SgbmConfig(block_size=4)
    assert SgbmConfig(block_size=5).penalty_small == 200
    assert SgbmConfig(block_size=5).penalty_large == 800


def test_concurrent_threads_give_the_sequential_result(
    pair: tuple[npt.NDArray[Any], ...],
) -> None:
    left, right, _ = pair
    front_end = StereoFrontEnd(gftt=GFTT, sgbm=SGBM)
    expected = front_end.measure(left, right)
    results: list[Any] = [None] * 4

    def work(slot: int) -> None:
        results[slot] = front_end.measure(left, right)

    threads = [threading.Thread(target=work, args=(slot,)) for slot in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for result in results:
        np.testing.assert_array_equal(result.pixels, expected.pixels)
        np.testing.assert_array_equal(result.disparities, expected.disparities)


# --- real data -----------------------------------------------------------------------------


@pytest.mark.realdata
def test_kitti_pair_gives_many_well_spread_lookups() -> None:
    if not KITTI_DRIVE.is_dir():
        pytest.skip(f"KITTI raw drive not found at {KITTI_DRIVE} (../shared/realdata absent)")
    left = np.asarray(cv2.imread(str(KITTI_DRIVE / "image_00" / "data" / "0000000000.png"), 0))
    right = np.asarray(cv2.imread(str(KITTI_DRIVE / "image_01" / "data" / "0000000000.png"), 0))
    front_end = StereoFrontEnd()
    result = front_end.measure(left, right)
    assert result.counts.kept >= 250
    assert np.isfinite(result.disparities).all()
    assert result.disparities.min() >= 0.0
    assert result.disparities.max() <= front_end.sgbm.valid_min_x
    # spread: a 4 x 3 grid over the searched area, at least 10 of its 12 cells used
    x_start = front_end.sgbm.valid_min_x
    cols = ((result.pixels[:, 0] - x_start) / (left.shape[1] - x_start) * 4).astype(int)
    rows = (result.pixels[:, 1] / left.shape[0] * 3).astype(int)
    assert len(set(zip(cols.tolist(), rows.tolist(), strict=True))) >= 10


# --- weighted fill placements ------------------------------------------------------------


def test_weighted_fill_with_unit_weight_is_farthest_point_sampling() -> None:
    line = np.column_stack([np.arange(0, 101, 1.0), np.zeros(101)]).astype(np.float32)
    ones = np.ones(101, np.float32)
    chosen = weighted_fill(np.zeros((0, 2), np.float32), line, ones, 3)
    assert sorted(line[chosen, 0].tolist()) == [0.0, 50.0, 100.0]
    # from a kept point at x = 0: the far end first, then the middle
    kept = np.array([[0.0, 0.0]], np.float32)
    chosen = weighted_fill(kept, line, ones, 2)
    assert line[chosen, 0].tolist() == [100.0, 50.0]


def test_weighted_fill_counts_the_areas_edge_as_covered() -> None:
    line = np.column_stack([np.arange(0, 101, 1.0), np.zeros(101)]).astype(np.float32)
    ones = np.ones(101, np.float32)
    area = (0, -50, 101, 51)
    chosen = weighted_fill(np.zeros((0, 2), np.float32), line, ones, 2, area)
    # the middle first (gap 2 x 50 to the mirrored edges), then halfway to an edge
    assert line[chosen[0], 0] == 50.0
    assert line[chosen[1], 0] in (17.0, 83.0)
    square = np.mgrid[0:40, 0:40].reshape(2, -1).T.astype(np.float32)
    picked = square[
        weighted_fill(square[:0], square, np.ones(1600, np.float32), 16, (0, 0, 40, 40))
    ]
    assert picked.min() >= 4.0
    assert picked.max() <= 35.0


def test_weighted_fill_puts_more_points_where_the_weight_is_larger() -> None:
    ys, xs = np.mgrid[0:60, 0:120].astype(np.float32)
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    weights = np.where(grid[:, 0] >= 60, 3.0, 1.0).astype(np.float32)
    chosen = weighted_fill(np.zeros((0, 2), np.float32), grid, weights, 60)
    right = int((grid[chosen, 0] >= 60).sum())
    assert right >= 3 * (60 - right)
    even = weighted_fill(np.zeros((0, 2), np.float32), grid, np.ones_like(weights), 60)
    assert 20 <= int((grid[even, 0] >= 60).sum()) <= 40


def test_weighted_fill_stops_where_nothing_is_left_to_cover() -> None:
    points = np.array([[1.0, 1.0], [5.0, 5.0]], np.float32)
    ones = np.ones(2, np.float32)
    assert weighted_fill(points, points, ones, 5).size == 0
    assert weighted_fill(points[:1], points, ones, 5).tolist() == [1]
    assert weighted_fill(points[:1], points, np.zeros(2, np.float32), 5).size == 0


def _placed(
    pair: tuple[npt.NDArray[Any], ...], placement: str
) -> tuple[Any, Any, npt.NDArray[np.float32]]:
    """The lattice's measurements, a placement's, and its fill points."""
    left, right, _ = pair
    lattice = LATTICE_24
    placed = replace(lattice, fill_placement=placement)
    # a prior std growing downwards, 1 px at the top to 9 px at the bottom
    prior_std = np.repeat(np.linspace(1.0, 9.0, 8, dtype=np.float32)[:, None], 16, axis=1)
    corners = StereoFrontEnd(gftt=replace(lattice, fill_spacing=0.0), sgbm=SGBM)
    base = StereoFrontEnd(gftt=lattice, sgbm=SGBM).measure(left, right)
    found = StereoFrontEnd(gftt=placed, sgbm=SGBM, prior_std=prior_std).measure(left, right)
    own = corners.measure(left, right)
    np.testing.assert_array_equal(found.pixels[: own.counts.kept], own.pixels)
    return base, found, found.pixels[own.counts.kept :]


@pytest.mark.parametrize("placement", ["even", "prior_std", "disparity"])
def test_weighted_placements_look_up_as_many_points_as_the_lattice(
    pair: tuple[npt.NDArray[Any], ...], placement: str
) -> None:
    truth = pair[2]
    base, found, fill = _placed(pair, placement)
    assert found.counts.kept == base.counts.kept == len(found.pixels)
    assert len(fill) >= 40
    # on the lattice 4 times finer, and measured as well as the lattice's points
    area = (max(8, SGBM.valid_min_x), 8, WIDTH - 8, HEIGHT - 8)
    finer = lattice_points(np.zeros((0, 2), np.float32), 6.0, area)
    on_lattice = np.abs(fill[:, None, :] - finer[None, :, :]).sum(axis=2).min(axis=1)
    assert on_lattice.max() == 0.0
    assert np.median(np.abs(found.disparities - _truth_at(truth, found.pixels))) < 0.15


def test_weighted_placements_follow_their_weights(pair: tuple[npt.NDArray[Any], ...]) -> None:
    truth = pair[2]
    even = _placed(pair, "even")[2]
    by_prior = _placed(pair, "prior_std")[2]
    by_disparity = _placed(pair, "disparity")[2]
    # the prior's std grows downwards; the rectangle is twice as near as the plane
    assert by_prior[:, 1].mean() > even[:, 1].mean() + 5.0
    assert _truth_at(truth, by_disparity).mean() > _truth_at(truth, even).mean() + 0.5


def test_prior_std_placement_needs_the_map_and_options_are_checked(
    pair: tuple[npt.NDArray[Any], ...], disparity: npt.NDArray[np.float32]
) -> None:
    placed = GfttConfig(fill_placement="prior_std", fill_spacing=24.0)
    with pytest.raises(ValueError, match="prior's std map"):
        sparse_lookups(pair[0], disparity, placed, min_x=SGBM.valid_min_x)
    with pytest.raises(ValueError, match="fill_placement must be one of"):
        GfttConfig(fill_placement="random")
    with pytest.raises(ValueError, match="fill_exponent must be >= 0"):
        GfttConfig(fill_exponent=-1.0)
    with pytest.raises(ValueError, match="fill_min_support must be in"):
        GfttConfig(fill_min_support=1.5)


def test_a_greedy_fill_seeks_the_gaps_and_the_support_check_skips_sgbms_holes(
    pair: tuple[npt.NDArray[Any], ...], disparity: npt.NDArray[np.float32]
) -> None:
    # a hole in SGBM's map with one small valid island in it: the largest gap of all
    holed = disparity.copy()
    holed[20:140, 200:300] = np.nan
    holed[76:86, 246:256] = D_BACK
    even = GfttConfig(
        max_corners=20,
        min_distance=5.0,
        fill_spacing=24.0,
        fill_placement="even",
        fill_min_support=0.0,
    )
    supported = replace(even, fill_min_support=0.8)
    lattice = replace(even, fill_placement="lattice", fill_min_support=0.8)

    def in_hole(config: GfttConfig) -> int:
        found = sparse_lookups(pair[0], holed, config, min_x=SGBM.valid_min_x)
        x, y = found.pixels[:, 0], found.pixels[:, 1]
        return int(((x >= 200) & (x < 300) & (y >= 20) & (y < 140)).sum())

    assert in_hole(even) >= 1
    assert in_hole(supported) == 0
    assert in_hole(lattice) == 0
    counts = [
        sparse_lookups(pair[0], holed, config, min_x=SGBM.valid_min_x).counts.kept
        for config in (replace(even, fill_placement="lattice"), even, supported)
    ]
    assert counts[0] == counts[1] == counts[2]


def test_lookup_on_a_map_smaller_than_its_patch_rejects_every_point() -> None:
    tiny = np.full((2, 3), 50.0, np.float32)  # the 4 x 4 px support patch fits nowhere
    found = lookup_disparities(tiny, np.array([[1.0, 0.5], [0.0, 0.0]], np.float32))
    assert found.indices.size == 0
    assert found.counts.outside == 2
