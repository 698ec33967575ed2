"""Dense fusion (issue 18): the sparse estimate fused with the whole SGBM map."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from pcainterp_stream.estimate.dense import (
    DenseModel,
    directional_neighbours,
    find_holes,
    fuse_dense,
)
from pcainterp_stream.estimate.estimator import DensifyResult, Uncertainty
from pcainterp_stream.estimate.prior import Robust
from pcainterp_stream.estimate.solve import SolveForm


def field_estimate(
    disparity: np.ndarray, std: float | None = 2.0, focal_baseline: float = 380.0
) -> DensifyResult:
    """A DensifyResult holding a given field (the sparse estimate) and a constant std."""
    field = np.asarray(disparity, np.float32)
    return DensifyResult(
        disparity=field,
        disparity_std=None if std is None else np.full(field.shape, std, np.float32),
        depth=None,
        depth_std=None,
        coefficients=np.zeros(3),
        coefficient_variance=np.ones(3),
        pixels=np.zeros((0, 2)),
        disparities=np.zeros(0),
        n_dropped=0,
        solve_form=SolveForm.MEASUREMENT,
        uncertainty=Uncertainty.EXACT_COARSE,
        focal_baseline=focal_baseline,
        min_disparity=0.5,
    )


@settings(max_examples=examples(40), deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    height=st.integers(1, 12),
    width=st.integers(1, 12),
    share=st.floats(0.0, 1.0),
)
def test_directional_neighbours_match_a_scan(
    seed: int, height: int, width: int, share: float
) -> None:
    rng = np.random.default_rng(seed)
    values = rng.uniform(0, 50, (height, width)).astype(np.float32)
    valid = rng.random((height, width)) < share
    found = directional_neighbours(values, valid)
    steps = [(0, -1), (0, 1), (-1, 0), (1, 0)]  # left, right, up, down
    for (value, distance), (dy, dx) in zip(found, steps, strict=True):
        for y in range(height):
            for x in range(width):
                r, yy, xx = 0, y, x
                while 0 <= yy < height and 0 <= xx < width and not valid[yy, xx]:
                    r, yy, xx = r + 1, yy + dy, xx + dx
                if 0 <= yy < height and 0 <= xx < width:
                    assert distance[y, x] == r
                    assert value[y, x] == values[yy, xx]
                else:
                    assert np.isinf(distance[y, x])


def test_directional_neighbours_of_a_map_taller_than_int16() -> None:
    # up and down of a map too tall for int16 rows are left and right of its transpose
    rng = np.random.default_rng(5)
    values = rng.uniform(0, 50, (np.iinfo(np.int16).max + 9, 3)).astype(np.float32)
    valid = rng.random(values.shape) < 0.3
    valid[:, 2] = False  # a column without any valid pixel
    up, down = directional_neighbours(values, valid)[2:]
    left, right = directional_neighbours(values.T, valid.T)[:2]
    for (value, distance), (value_t, distance_t) in zip((up, down), (left, right), strict=True):
        np.testing.assert_array_equal(value, value_t.T)
        np.testing.assert_array_equal(distance, distance_t.T)
    assert np.isinf(up[1][:, 2]).all()


@pytest.mark.parametrize("shape", [(0, 5), (5, 0), (3, 4)])
def test_a_map_without_holes_has_no_neighbours_to_find(shape: tuple[int, int]) -> None:
    holes = find_holes(np.ones(shape, np.float32))
    assert holes.index.size == 0
    assert [(value.size, distance.size) for value, distance in holes.neighbours] == [(0, 0)] * 4


def test_valid_pixels_keep_sgbm_and_a_wrong_match_is_pulled_back() -> None:
    rng = np.random.default_rng(2)
    field = rng.uniform(10, 40, (20, 30)).astype(np.float32)
    sgbm = field + rng.normal(0, 3.0, field.shape).astype(np.float32)
    sgbm[5, 7] = field[5, 7] + 80.0  # a wrong match
    model = DenseModel()
    fused = fuse_dense(field_estimate(field), sgbm, model)
    ok = np.ones(field.shape, bool)
    ok[5, 7] = False
    # moved towards the field by sigma_px^2 / (sigma_px^2 + w v_f) of the gap: under 3 %
    # for these gaps (< 12 px, Cauchy weight > 0.6, v_f = 68 px^2)
    gap = np.abs(field - sgbm)[ok]
    assert gap.max() < 12
    moved = np.abs(fused.disparity - sgbm)[ok]
    assert (moved <= 0.03 * gap + 1e-4).all()
    plain = fuse_dense(field_estimate(field), sgbm, dataclasses.replace(model, robust=Robust.NONE))
    # the Cauchy weight pulls the wrong match back by over a tenth of its 80 px more
    assert abs(fused.disparity[5, 7] - field[5, 7]) < abs(plain.disparity[5, 7] - field[5, 7]) - 8
    assert fused.disparity_std is not None
    # about sigma_px / sqrt(w): w < 1 where they differ, > 0.8 for these gaps
    assert (fused.disparity_std[ok] < 1.12 * model.pixel_std).all()


def test_a_hole_takes_the_side_the_field_supports() -> None:
    # an occlusion: background (10 px) left of the hole, foreground (40 px) right of it;
    # the field says background; a second row has a "sky" hole the field puts at 1 px
    field = np.full((2, 21), 10.0, np.float32)
    sgbm = np.full((2, 21), np.nan, np.float32)
    sgbm[0, :6] = 10.0
    sgbm[0, 15:] = 40.0
    field[0, 15:] = 40.0
    field[1] = 1.0
    sgbm[1, :3] = 30.0
    sgbm[1, 18:] = 30.0
    fused = fuse_dense(field_estimate(field, std=1.0), sgbm)
    assert np.abs(fused.disparity[0, 6:15] - 10.0).max() < 1.0
    assert np.abs(fused.disparity[1, 6:15] - 1.0).max() < 2.0
    assert fused.disparity_std is not None
    hole_std = fused.disparity_std[np.isnan(sgbm)]
    assert hole_std.min() > fused.disparity_std[np.isfinite(sgbm)].max()
    assert np.isfinite(fused.disparity).all()


def test_depth_std_and_shapes() -> None:
    field = np.full((4, 5), 19.0, np.float32)
    sgbm = field.copy()
    sgbm[1, 1] = np.nan
    fused = fuse_dense(field_estimate(field, focal_baseline=190.0), sgbm)
    assert fused.depth is not None
    np.testing.assert_allclose(fused.depth, 190.0 / fused.disparity, rtol=1e-5)
    no_std = fuse_dense(field_estimate(field, std=None), sgbm)
    assert no_std.disparity_std is None
    assert no_std.depth_std is None
    with pytest.raises(ValueError, match="shape"):
        fuse_dense(field_estimate(field), sgbm[:, :3])
    with pytest.raises(ValueError, match="pixel_std"):
        DenseModel(pixel_std=0.0)


def test_inputs_are_left_alone_and_outputs_are_float32() -> None:
    rng = np.random.default_rng(3)
    field = rng.uniform(5, 40, (12, 16))
    estimate = dataclasses.replace(
        field_estimate(field),
        disparity=field,  # float64, as a caller may pass
        disparity_std=np.full(field.shape, 2.0),
    )
    sgbm = field + rng.normal(0, 1, field.shape)
    sgbm[:, :3] = np.nan
    sgbm[5, 6:9] = -1.0
    before = (estimate.disparity.copy(), estimate.disparity_std.copy(), sgbm.copy())
    fused = fuse_dense(estimate, sgbm)
    after = (estimate.disparity, estimate.disparity_std, sgbm)
    for old, new in zip(before, after, strict=True):
        np.testing.assert_array_equal(old, new)
    for array in (fused.disparity, fused.disparity_std, fused.depth, fused.depth_std):
        assert array is not None
        assert array.dtype == np.float32
    # arrays in column-major order (a transpose's view) fuse as their row-major copies
    transposed = dataclasses.replace(
        estimate,
        disparity=np.asfortranarray(field),
        disparity_std=np.asfortranarray(estimate.disparity_std),
    )
    same = fuse_dense(transposed, np.asfortranarray(sgbm))
    for name in ("disparity", "disparity_std", "depth", "depth_std"):
        np.testing.assert_array_equal(getattr(same, name), getattr(fused, name))
        assert not any(np.shares_memory(array, given) for given in after)


@settings(max_examples=examples(40), deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    height=st.integers(1, 12),
    width=st.integers(1, 12),
    share=st.floats(0.0, 1.0),
)
def test_holes_found_ahead_fuse_to_the_same_values(
    seed: int, height: int, width: int, share: float
) -> None:
    # densify finds the holes in its stereo workers and fuses on the densify thread: the
    # result must be the one fuse_dense finds on its own, to the bit
    rng = np.random.default_rng(seed)
    field = rng.uniform(3, 60, (height, width)).astype(np.float32)
    sgbm = (field + rng.uniform(-2, 2, field.shape)).astype(np.float32)
    missing = rng.random(field.shape) >= share
    kinds = rng.integers(0, 3, field.shape)
    sgbm[missing & (kinds == 0)] = np.nan
    sgbm[missing & (kinds == 1)] = -1.0
    sgbm[missing & (kinds == 2)] = np.inf
    holes = find_holes(sgbm)
    np.testing.assert_array_equal(holes.index, np.flatnonzero(missing))
    alone = fuse_dense(field_estimate(field), sgbm)
    ahead = fuse_dense(field_estimate(field), sgbm, holes=holes)
    for name in ("disparity", "disparity_std", "depth", "depth_std"):
        np.testing.assert_array_equal(getattr(ahead, name), getattr(alone, name))
    left = directional_neighbours(sgbm, ~missing)[0]
    np.testing.assert_array_equal(holes.neighbours[0][0], left[0].ravel()[holes.index])
    np.testing.assert_array_equal(holes.neighbours[0][1], left[1].ravel()[holes.index])


def test_holes_of_another_map_are_refused() -> None:
    field = np.full((4, 5), 19.0, np.float32)
    sgbm = field.copy()
    sgbm[1, 1] = np.nan
    with pytest.raises(ValueError, match="holes"):
        fuse_dense(field_estimate(field), sgbm, holes=find_holes(sgbm[:, :4]))
    with pytest.raises(ValueError, match="map"):
        find_holes(sgbm[0])


@settings(max_examples=examples(40), deadline=None)
@given(seed=st.integers(0, 2**31 - 1), weak_std=st.floats(0.0, 10.0))
def test_weak_pixels_keep_their_value_and_widen_their_std(seed: int, weak_std: float) -> None:
    # a matcher's weak pixels are fused as any matched pixel; only their std grows, by
    # weak_std in quadrature; holes and the other pixels do not move
    rng = np.random.default_rng(seed)
    field = rng.uniform(3, 60, (6, 9)).astype(np.float32)
    sgbm = (field + rng.uniform(-3, 3, field.shape)).astype(np.float32)
    sgbm[rng.random(field.shape) < 0.3] = np.nan
    weak = rng.random(field.shape) < 0.4
    model = DenseModel(weak_std=weak_std)
    plain = fuse_dense(field_estimate(field), sgbm, model)
    marked = fuse_dense(field_estimate(field), sgbm, model, holes=find_holes(sgbm, weak))
    np.testing.assert_array_equal(marked.disparity, plain.disparity)
    assert plain.disparity_std is not None
    assert marked.disparity_std is not None
    widened = weak & np.isfinite(sgbm)
    np.testing.assert_array_equal(marked.disparity_std[~widened], plain.disparity_std[~widened])
    expected = np.sqrt(np.square(plain.disparity_std[widened]) + np.float32(weak_std**2))
    np.testing.assert_allclose(marked.disparity_std[widened], expected, rtol=1e-6)
    np.testing.assert_array_equal(find_holes(sgbm, weak).weak, np.flatnonzero(widened))
    assert find_holes(sgbm).weak.size == 0


def test_weak_pixels_of_another_shape_and_a_negative_weak_std_are_refused() -> None:
    sgbm = np.full((4, 5), 19.0, np.float32)
    with pytest.raises(ValueError, match="weak"):
        find_holes(sgbm, np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="weak_std"):
        DenseModel(weak_std=-1.0)


def test_holes_coded_zero_fuse_as_nan_holes() -> None:
    """A 0 is no match (KITTI's disparity PNGs code their holes 0), as NaN and -1 are."""
    rng = np.random.default_rng(31)
    field = rng.uniform(5, 40, (12, 16)).astype(np.float32)
    noisy = (field + rng.normal(0, 0.5, field.shape)).astype(np.float32)
    hole = rng.random(field.shape) < 0.2
    hole[3:7, 4:12] = True
    fused = {
        code: fuse_dense(field_estimate(field), np.where(hole, np.float32(code), noisy))
        for code in (np.nan, -1.0, 0.0)
    }
    for name in ("disparity", "disparity_std", "depth", "depth_std"):
        np.testing.assert_array_equal(getattr(fused[0.0], name), getattr(fused[np.nan], name))
        np.testing.assert_array_equal(getattr(fused[-1.0], name), getattr(fused[np.nan], name))
    zeros = np.where(hole, np.float32(0.0), noisy)
    np.testing.assert_array_equal(find_holes(zeros).index, np.flatnonzero(hole))
    # SGBM's own 0 (minDisparity 0, densify's front end) is a match at zero disparity
    assert find_holes(zeros, zero_is_match=True).index.size == 0
    matched = fuse_dense(field_estimate(field), zeros, zero_is_match=True)
    assert float(matched.disparity[hole].mean()) < float(fused[0.0].disparity[hole].mean()) - 5


@pytest.mark.parametrize("dtype", [np.int16, np.uint16])
def test_fixed_point_maps_are_refused(dtype: type) -> None:
    """OpenCV's StereoSGBM.compute() gives int16 16 x px, KITTI's PNGs uint16 256 x px."""
    field = np.full((4, 5), 19.0, np.float32)
    fixed = np.full(field.shape, 19 * 16, dtype)
    with pytest.raises(TypeError, match=r"`disparity_map` as float disparities in px.*16 x px"):
        fuse_dense(field_estimate(field), fixed)
    with pytest.raises(TypeError, match="astype"):
        find_holes(fixed)


def test_a_strided_float64_map_fuses_as_its_float32_copy() -> None:
    rng = np.random.default_rng(32)
    field = rng.uniform(5, 40, (12, 16)).astype(np.float32)
    wide = np.repeat(field + rng.normal(0, 1, field.shape), 2, axis=1)  # float64
    wide[2:5, 6:10] = np.nan
    view = wide[:, ::2]  # a non-contiguous view
    fused = fuse_dense(field_estimate(field), view)
    copy = fuse_dense(field_estimate(field), np.ascontiguousarray(view, np.float32))
    for name in ("disparity", "disparity_std", "depth", "depth_std"):
        np.testing.assert_array_equal(getattr(fused, name), getattr(copy, name))
