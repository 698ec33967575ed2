"""A group of measurements beyond the prior's reach is kept, and the std widened around it.

Bug hunt 13A F5: a near object measured by the near-reach match (~30 points at 160 px on a
620 px camera) was down-weighted point by point by the Cauchy IRLS as outliers against the
prior, the estimate there fell to ~60 px and the std covered ~20 % of the object.

The fix (a consistent group kept at weight 1, the std widened around it) was reverted after
review 59c F4, F5 (it made a clean fisheye log worse and was slow at 1280x720): the first test
is the bug as it stands, an expected failure until a fix that leaves clean logs alone.
"""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream import Basis, DensifyResult, densify_batch
from pcainterp_stream.estimate.prior import LocalPrior, Robust


def _basis() -> Basis:
    """A smooth street-like basis on a coarse grid of a 1242x375 image."""
    rng = np.random.default_rng(3)
    grid = (24, 78)
    ys, xs = np.mgrid[0 : grid[0], 0 : grid[1]] / grid[1]
    fields = [
        np.cos(np.pi * (a * xs + b * ys) + c) for a, b, c in rng.uniform(0.0, 2.0, size=(8, 3))
    ]
    q, _ = np.linalg.qr(np.stack([f.ravel() for f in fields], axis=1))
    eigenvalues = np.sort(rng.uniform(5.0, 100.0, 8))[::-1]
    rows = np.mgrid[0 : grid[0], 0 : grid[1]][0] / grid[0]
    return Basis(
        mean=(5.0 + 60.0 * rows).astype(np.float32),
        components=q.T.reshape(8, *grid).astype(np.float32),
        eigenvalues=eigenvalues,
        total_variance=float(eigenvalues.sum()) * 1.5,
        image_size=(375, 1242),
        focal_baseline=200.0,
        n_train=50,
    )


def _frame(basis: Basis, near: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """150 points of the mean field, then ``near`` points of a lattice at 300 px (a near plane)."""
    rng = np.random.default_rng(11)
    far = np.stack([rng.uniform(0, 1241, 150), rng.uniform(0, 374, 150)], axis=1)
    lattice = np.stack(
        np.meshgrid(np.arange(553.0, 800.0, 40.0), np.arange(136.0, 260.0, 40.0)), axis=-1
    ).reshape(-1, 2)[:near]
    pixels = np.concatenate([far, lattice])
    mean = basis.mean.astype(np.float64)
    rows = np.clip(pixels[:, 1] * mean.shape[0] / 375, 0, mean.shape[0] - 1).astype(int)
    cols = np.clip(pixels[:, 0] * mean.shape[1] / 1242, 0, mean.shape[1] - 1).astype(int)
    disparities = mean[rows, cols] + rng.normal(0.0, 0.3, pixels.shape[0])
    disparities[150:] += 300.0 - mean[rows[150:], cols[150:]]
    return pixels, disparities, np.arange(pixels.shape[0]) >= 150


def _solve(basis: Basis, pixels: np.ndarray, disparities: np.ndarray) -> DensifyResult:
    return densify_batch(
        basis,
        [pixels],
        [disparities],
        sigma=0.1,
        robust=Robust.CAUCHY,
        local_prior=LocalPrior(40.0, 64.0),
        image_size=basis.image_size,
        focal_baseline=basis.focal_baseline,
    )[0]


@pytest.mark.xfail(
    strict=True, reason="bug hunt 13A F5: the group fix was reverted (review 59c F4, F5)"
)
def test_a_group_beyond_the_prior_is_kept_and_covered() -> None:
    basis = _basis()
    pixels, disparities, near = _frame(basis, 28)
    result = _solve(basis, pixels, disparities)
    assert result.weights is not None
    assert result.disparity_std is not None
    # the lattice agrees with itself: kept, not 28 outliers
    assert np.all(result.weights[near] > 0.5)
    # the estimate follows it, and +-2 std around it reaches its points' value
    cols, rows = pixels[near, 0].astype(int), pixels[near, 1].astype(int)
    assert np.median(result.disparity[rows, cols] - disparities[near]) > -30.0
    box = (slice(120, 276), slice(530, 820))
    level = np.median(disparities[near])
    covered = np.abs(result.disparity[box] - level) <= 2.0 * result.disparity_std[box]
    assert covered.mean() > 0.9


def test_a_few_agreeing_outliers_are_still_outliers() -> None:
    basis = _basis()
    pixels, disparities, near = _frame(basis, 4)
    result = _solve(basis, pixels, disparities)
    assert result.weights is not None
    assert np.all(result.weights[near] < 0.5)
    clean = _solve(basis, pixels[~near], disparities[~near])
    assert clean.weights is not None
    np.testing.assert_array_equal(clean.weights, 1.0)  # no group without an outlier
