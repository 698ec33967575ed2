"""Dense fusion (issue 18): the cells, the exact field posterior, the pixel layer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from pcainterp_stream.estimate.basis import Basis, resample_grid
from pcainterp_stream.estimate.dense import (
    DenseModel,
    _cell_rows,
    _nearest_valid,
    aggregate_cells,
    densify_dense,
)
from pcainterp_stream.estimate.prior import Robust


def random_basis(seed: int = 0, grid: tuple[int, int] = (6, 8), n_components: int = 5) -> Basis:
    rng = np.random.default_rng(seed)
    s = grid[0] * grid[1]
    q = np.linalg.qr(rng.normal(size=(s, n_components)))[0]
    return Basis(
        mean=rng.uniform(5, 30, grid).astype(np.float32),
        components=q.T.reshape(n_components, *grid).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(1.0, 300, n_components))[::-1].copy(),
        total_variance=2000.0,
        image_size=(grid[0] * 4, grid[1] * 4),
        focal_baseline=380.0,
        n_train=40,
    )


def test_cells_average_the_valid_pixels_only() -> None:
    disparity = np.full((8, 12), 7.0, dtype=np.float32)
    disparity[:4, :4] = np.nan  # one whole cell of the 2 x 3 grid missing
    disparity[4:, 8:10] = np.nan  # half of another
    disparity[4:, 10:] = 9.0
    cells = aggregate_cells(disparity, (2, 3))
    np.testing.assert_allclose(cells.fraction, [[0, 1, 1], [1, 1, 0.5]])
    assert np.isnan(cells.mean[0, 0])
    np.testing.assert_allclose(cells.mean[1, 2], 9.0)
    np.testing.assert_allclose(cells.mean[0, 1], 7.0)
    np.testing.assert_allclose(cells.spread[1, 1], 0.0, atol=1e-9)
    assert cells.pixels_per_cell == 16


def test_field_posterior_is_exact_gaussian_conditioning() -> None:
    basis = random_basis(3)
    rng = np.random.default_rng(1)
    size = basis.grid_size
    disparity = (basis.mean + rng.normal(0, 2.0, size)).astype(np.float32)
    disparity[rng.random(size) < 0.3] = np.nan
    model = DenseModel(cell=1, min_fraction=0.5, robust=Robust.NONE, cell_std=0.8)
    result = densify_dense(basis, disparity, uncertainty="exact", model=model)
    # brute force: zbar = A y + m + e, e ~ N(0, R), y ~ N(0, Lambda)
    cells = aggregate_cells(disparity, size)
    used = (cells.fraction >= 0.5).reshape(-1)
    rows, mean = _cell_rows(basis, size)
    a = rows[used].astype(np.float64)
    r = cells.mean.reshape(-1)[used] - mean[used]
    noise = (cells.spread.reshape(-1)[used] + 1.0**2) / (
        cells.fraction.reshape(-1)[used] * cells.pixels_per_cell
    ) + 0.8**2
    information = np.diag(1 / basis.eigenvalues) + a.T @ (a / noise[:, None])
    covariance = np.linalg.inv(information)
    expected = covariance @ (a.T @ (r / noise))
    np.testing.assert_allclose(result.coefficients, expected, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(result.coefficient_variance, np.diag(covariance), rtol=1e-4)
    assert result.n_measurements == int(used.sum())
    # the std at a hole pixel: 1 / (1 / (b^T Sigma b + tau^2) + 1 / (a^2 + b^2 r))
    b = basis.pixel_major.astype(np.float64)
    field_variance = np.einsum("sl,lm,sm->s", b, covariance, b).reshape(size)
    distance = ndimage.distance_transform_edt(np.isnan(disparity))
    hole = np.isnan(disparity)
    nearest = model.nearest_std**2 + model.nearest_rate * distance
    expected_std = np.sqrt(1 / (1 / (field_variance + model.detail_std**2) + 1 / nearest))
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.disparity_std[hole], expected_std[hole], rtol=2e-2)


def test_valid_pixels_keep_sgbm_and_holes_are_filled() -> None:
    basis = random_basis(5)
    rng = np.random.default_rng(2)
    truth = np.repeat(np.repeat(basis.mean, 4, axis=0), 4, axis=1)
    disparity = (truth + rng.normal(0, 0.3, truth.shape)).astype(np.float32)
    disparity[5:12, 3:20] = np.nan
    disparity[20, 25] = truth[20, 25] + 60.0  # a wrong match
    result = densify_dense(basis, disparity)
    valid = np.isfinite(disparity)
    valid[20, 25] = False
    assert np.isfinite(result.disparity).all()
    assert result.disparity_std is not None
    assert np.isfinite(result.disparity_std).all()
    # where SGBM is valid the estimate is SGBM's, moved by at most ~1.4 % of its distance
    # to the field (sigma_px^2 / tau^2)
    moved = np.abs(result.disparity - disparity)[valid]
    assert moved.mean() < 0.05
    assert moved.max() < 0.5
    # the wrong match is down-weighted (Cauchy) and pulled towards the field, more than
    # without the robust weight
    plain = densify_dense(basis, disparity, model=DenseModel(robust=Robust.NONE))
    error = abs(result.disparity[20, 25] - truth[20, 25])
    assert error < abs(plain.disparity[20, 25] - truth[20, 25]) - 5.0
    hole = np.isnan(disparity)
    assert result.disparity_std[hole].min() > result.disparity_std[valid].max()
    # deeper in the hole, less certain
    assert result.disparity_std[8, 11] > result.disparity_std[5, 11]


def test_empty_map_gives_the_prior_and_paper_is_refused() -> None:
    basis = random_basis(7)
    empty = np.full(basis.image_size, np.nan, dtype=np.float32)
    result = densify_dense(basis, empty)
    assert result.n_measurements == 0
    np.testing.assert_allclose(result.disparity, resample_grid(basis.mean, basis.image_size))
    with pytest.raises(ValueError, match="paper"):
        densify_dense(basis, empty, uncertainty="paper")
    with pytest.raises(ValueError, match="shape"):
        densify_dense(basis, np.zeros(5))


def test_depth_follows_the_camera() -> None:
    basis = random_basis(9)
    disparity = np.repeat(np.repeat(basis.mean, 4, axis=0), 4, axis=1).astype(np.float32)
    result = densify_dense(basis, disparity, focal_baseline=190.0)
    assert result.depth is not None
    np.testing.assert_allclose(result.depth, 190.0 / result.disparity, rtol=1e-5)


def test_nearest_valid_matches_exact_distance_transform() -> None:
    rng = np.random.default_rng(4)
    values = rng.uniform(1, 50, (40, 60)).astype(np.float32)
    valid = rng.random((40, 60)) < 0.1
    nearest, distance = _nearest_valid(values, valid)
    exact, (_rows, _cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    np.testing.assert_allclose(distance, exact, atol=0.1 * exact.max() + 0.05)
    assert (distance[valid] == 0).all()
    np.testing.assert_array_equal(nearest[valid], values[valid])
    # each hole pixel takes the value of a valid pixel about as near as the nearest one
    ys, xs = np.nonzero(~valid)
    for y, x in zip(ys[::37], xs[::37], strict=True):
        candidates = np.argwhere(valid & np.isclose(values, nearest[y, x]))
        gap = np.hypot(candidates[:, 0] - y, candidates[:, 1] - x).min()
        assert gap <= exact[y, x] * 1.1 + 0.5
