"""A group of measurements beyond the prior's reach is kept, and the std widened around it.

Bug hunt 13A F5: a near object measured by the near-reach match (~30 points at 160 px on a
620 px camera) was down-weighted point by point by the Cauchy IRLS as outliers against the
prior, the estimate there fell to ~60 px and the std covered ~20 % of the object.

Review 59c F4, F5: the first form of the fix kept modest chained offsets on a clean fisheye
log as groups (worse map), widened the background's std beside a near object, and took
0.3-0.7 s a call at 1280x720.
"""

from __future__ import annotations

import numpy as np

from pcainterp_stream import Basis, DensifyResult, densify_batch
from pcainterp_stream.estimate.prior import LocalPrior, Robust
from pcainterp_stream.estimate.solve import _consistent_group
from pcainterp_stream.estimate.variance import widen_near_group


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


def test_a_modest_offset_the_links_chain_is_not_a_group() -> None:
    # a clean fisheye log's "groups": 20 down-weighted points ~10 px off a prior that misses
    # the frame's points by ~10 px anyway: not a surface beyond the prior's reach
    rng = np.random.default_rng(5)
    positions = np.concatenate([rng.uniform(0, 600, (200, 2)), rng.uniform(300, 360, (20, 2))])
    innovation = np.concatenate([rng.normal(0.0, 15.0, 200), rng.normal(-10.0, 0.5, 20)])
    weights = np.where(np.arange(220) >= 200, 0.3, 1.0)
    assert not _consistent_group(positions, innovation, weights).any()
    # the same points 300 px off are one
    innovation[200:] = rng.normal(300.0, 5.0, 20)
    assert _consistent_group(positions, innovation, weights)[200:].all()


def _panel() -> tuple[np.ndarray, ...]:
    """A 720x1280 frame: background at 8 px measured on a 40 px grid, a panel at 200 px."""
    disparity = np.full((720, 1280), 8.0, dtype=np.float32)
    disparity[300:420, 500:700] = 190.0  # the estimate falls short of the panel
    ys, xs = np.mgrid[20:720:40, 20:1280:40]
    points = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    on = (points[:, 0] >= 500) & (points[:, 0] < 700) & (points[:, 1] >= 300) & (points[:, 1] < 420)
    values = np.where(on, 200.0, 8.0)
    return disparity, points[on], values[on], points[~on], values[~on]


def test_the_background_beside_a_group_keeps_its_std() -> None:
    disparity, members, level, others, background = _panel()
    std = widen_near_group(
        disparity, np.ones_like(disparity), members, level, 96.0, (others, background)
    )
    assert np.all(std[300:420, 500:700] >= 5.0)  # the panel: +-2 std reaches 200
    beside = np.ones(std.shape, dtype=bool)
    beside[280:440, 480:720] = False
    np.testing.assert_array_equal(std[beside], 1.0)  # the background is left alone

