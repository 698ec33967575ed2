"""The std at the image border (bug hunt 17D F4) and the depth-edge widening (F1)."""

from __future__ import annotations

import numpy as np

from pcainterp_stream.estimate import variance
from pcainterp_stream.estimate.basis import Basis, resample_grid
from pcainterp_stream.estimate.estimator import densify


def _basis() -> Basis:
    rng = np.random.default_rng(3)
    grid = (7, 9)
    q = np.linalg.qr(rng.normal(size=(63, 5)))[0]
    return Basis(
        mean=rng.uniform(5, 30, grid).astype(np.float32),
        components=q.T.reshape(5, *grid).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(0.5, 400, 5))[::-1].copy(),
        total_variance=3000.0,
        image_size=(70, 90),
        focal_baseline=380.0,
        n_train=50,
    )


def test_the_std_grows_past_the_outermost_variance_cells() -> None:
    basis = _basis()
    rng = np.random.default_rng(5)
    pixels = rng.uniform([10, 10], [80, 60], (15, 2))
    values = rng.uniform(5.0, 30.0, 15)
    out = (70, 90)
    coarse = densify(basis, pixels, values, image_size=out, variance_stride=3)
    exact = densify(basis, pixels, values, image_size=out, uncertainty="exact")
    std = coarse.disparity_std
    assert std is not None
    assert exact.disparity_std is not None
    np.testing.assert_array_equal(coarse.disparity, exact.disparity)  # the estimate is kept
    # the variance grid is 3 x 3: cell centres 70 / 6 rows and 15 columns inside the border
    inner = std[12:-12, 15:-15]
    flat = resample_grid(np.ones((3, 3), np.float32), out)  # (constant: the ramp alone)
    ramp = variance.widen_at_border(flat.copy(), (70 / 6, 15.0))
    np.testing.assert_allclose(ramp[35, 0], 1.0 + variance.BORDER_GAIN, rtol=1e-6)
    np.testing.assert_allclose(ramp[0, 45], 1.0 + variance.BORDER_GAIN, rtol=1e-6)
    np.testing.assert_array_equal(ramp[12:-12, 15:-15], 1.0)
    assert np.all(np.diff(ramp[35, :16]) <= 0)
    # before the fix the outermost column's std equalled the cell centre's (clamped)
    assert np.all(std[20:50, 0] > 1.3 * std[20:50, 15])
    assert np.all(std[0, 20:70] > 1.3 * std[12, 20:70])
    assert np.all(np.isfinite(inner))


def test_exact_std_is_not_ramped() -> None:
    basis = _basis()
    rng = np.random.default_rng(6)
    pixels = rng.uniform([10, 10], [80, 60], (15, 2))
    values = rng.uniform(5.0, 30.0, 15)
    exact = densify(basis, pixels, values, image_size=(70, 90), uncertainty="exact")
    std = exact.disparity_std
    assert std is not None
    # the exact std is held flat over the outermost half basis cell (5 px) by the resampling;
    # a ramp there would make the outermost row / column 2-5 % wider than the next one
    np.testing.assert_allclose(std[:, 0], std[:, 1], rtol=1e-5)
    np.testing.assert_allclose(std[0, :], std[1, :], rtol=1e-5)
    np.testing.assert_allclose(std[-1, :], std[-2, :], rtol=1e-5)


def test_off_plane_is_zero_on_a_plane_and_large_at_a_step() -> None:
    ys, xs = np.mgrid[0:120, 0:160].astype(np.float32)
    plane = 3.0 + 0.2 * xs + 0.1 * ys
    assert float(np.max(variance.off_plane(plane, 8.0, 9)[36:-36, 36:-36])) < 1e-3
    step = plane + np.where(xs >= 80, 10.0, 0.0).astype(np.float32)
    bend = variance.off_plane(step, 8.0, 9)
    assert bend[60, 80] > 3.0
    std = np.full(plane.shape, 1.0, np.float32)
    widened = variance.widen_off_plane(step, std)
    scale = variance.EDGE_WIDENING[0]
    np.testing.assert_allclose(widened[60, 36:44], scale, rtol=1e-3)  # the plane: a std
    assert widened[60, 80] > 5.0  # the step: b off_plane
