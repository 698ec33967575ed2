"""Fine-tuning a basis with more maps (``learn --with-synthetic``): the pooled covariance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import subspace_angles

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.finetune import (
    basis_sketch,
    builtin_fits,
    camera_distance,
    camera_mismatch,
    finetune_basis,
)
from pcainterp_stream.estimate.learning import learn_basis

GRID = (12, 20)


def grid_maps(count: int, offset: float, seed: int) -> list[np.ndarray]:
    """Smooth random disparity maps on GRID: a few modes and a little noise."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0 : GRID[0], 0 : GRID[1]]
    maps = []
    for _ in range(count):
        a = rng.normal(size=4)
        value = (
            offset
            + a[0] * rows
            + a[1] * cols / 3
            + a[2] * np.sin(cols / 3)
            + a[3] * np.cos(rows / 2)
            + 0.3 * rng.normal(size=GRID)
        )
        maps.append(value.astype(np.float32))
    return maps


def learn(maps: list[np.ndarray]) -> Basis:
    return learn_basis(
        maps, n_components=100, grid_scale=1.0, preprocessed=True, image_size=GRID, method="exact"
    )


def test_merging_a_complete_basis_equals_learning_from_all_maps() -> None:
    first, second = grid_maps(15, 10.0, seed=1), grid_maps(8, 14.0, seed=2)
    start = learn(first)
    assert start.n_components == 14  # every component of 15 maps: nothing truncated
    merged = finetune_basis(start, second, n_prior=15, n_components=100, preprocessed=True)
    together = learn(first + second)
    assert merged.n_train == together.n_train == 23
    assert merged.n_components == together.n_components == 22
    np.testing.assert_allclose(merged.mean, together.mean, atol=1e-4)
    np.testing.assert_allclose(
        merged.eigenvalues, together.eigenvalues, rtol=1e-4, atol=1e-6 * together.eigenvalues[0]
    )
    assert merged.total_variance == pytest.approx(together.total_variance, rel=1e-6)
    leading = slice(0, 10)
    a = merged.components[leading].reshape(10, -1).T.astype(np.float64)
    b = together.components[leading].reshape(10, -1).T.astype(np.float64)
    assert np.degrees(subspace_angles(a, b)).max() < 0.1
    assert merged.meta["finetune"]["n_prior"] == 15
    assert merged.meta["finetune"]["n_maps"] == 8
    assert merged.meta["finetune"]["prior_basis"]["fingerprint"] == start.fingerprint
    assert merged.meta["learning"]["method"] == "finetune"


def test_sketch_reproduces_the_basis_scatter() -> None:
    start = learn(grid_maps(10, 5.0, seed=3))
    sketch = basis_sketch(start, 40)
    factor = sketch.factor.astype(np.float64)
    # U sqrt((n - 1) Lambda): its Gram is diag((n - 1) lambda)
    np.testing.assert_allclose(np.diag(factor.T @ factor), 39 * start.eigenvalues, rtol=1e-4)
    assert sketch.squares == pytest.approx(39 * start.total_variance)
    assert sketch.n_maps == 40


def test_weight_of_the_basis_sets_how_far_the_mean_moves() -> None:
    start = learn(grid_maps(10, 5.0, seed=4))
    constant = np.full(GRID, 50.0, dtype=np.float32)
    for n_prior in (2, 10, 1000):
        merged = finetune_basis(start, [constant], n_prior=n_prior, preprocessed=True)
        expected = (n_prior * start.mean + constant) / (n_prior + 1)
        np.testing.assert_allclose(merged.mean, expected, rtol=1e-5)


def test_maps_of_another_camera_are_mapped_onto_the_basis() -> None:
    start = learn_basis(
        grid_maps(10, 5.0, seed=5),
        n_components=5,
        grid_scale=0.5,
        preprocessed=True,
        image_size=(24, 40),
        focal_baseline=300.0,
    )
    # a twice larger camera with twice the f*b: a constant disparity of 60 px there is 30 px
    # in the basis's camera, whatever the resampling
    other_camera = np.full((48, 80), 60.0, dtype=np.float32)
    other_camera[0, 0] = np.nan  # invalid pixels are filled, not averaged in
    merged = finetune_basis(start, [other_camera], n_prior=4, focal_baseline=600.0)
    expected = (4 * start.mean + 30.0) / 5
    np.testing.assert_allclose(merged.mean, expected, rtol=1e-5)
    assert merged.image_size == (24, 40)
    assert merged.grid_size == start.grid_size
    assert merged.focal_baseline == 300.0
    assert merged.meta["finetune"]["disparity_scale"] == pytest.approx(0.5)
    assert merged.meta["finetune"]["maps_image_size"] == [48, 80]


def test_bad_arguments_are_named() -> None:
    start = learn(grid_maps(5, 5.0, seed=6))
    with pytest.raises(ValueError, match="n_prior"):
        finetune_basis(start, grid_maps(2, 5.0, seed=7), n_prior=1, preprocessed=True)
    with pytest.raises(ValueError, match="empty"):
        finetune_basis(start, [], n_prior=5, preprocessed=True)
    with pytest.raises(ValueError, match=r"map 0 has shape \(3, 3\)"):
        finetune_basis(start, [np.zeros((3, 3))], n_prior=5, preprocessed=True)


def kitti_like() -> Basis:
    """A basis for the built-in basis's camera: 1241 x 376 px, f*b 386 px*m."""
    basis = learn(grid_maps(4, 20.0, seed=8))
    return dataclasses.replace(basis, image_size=(376, 1241), focal_baseline=386.17)


@pytest.mark.parametrize(
    ("image_size", "focal_baseline"),
    [
        ((370, 1226), 379.8),  # the KITTI odometry clip
        ((375, 1242), 387.2),  # the KITTI raw drive
        ((94, 310), 96.5),  # a quarter-size synthetic log: same look, smaller pixels
        ((376, 1241), 386.17 * 1.4),  # a 1.4x wider baseline: within 1.5x
    ],
)
def test_a_kitti_like_camera_matches(image_size: tuple[int, int], focal_baseline: float) -> None:
    assert camera_mismatch(kitti_like(), image_size, focal_baseline) is None


@pytest.mark.parametrize(
    ("image_size", "focal_baseline", "reason"),
    [
        ((480, 640), 300.0, "aspect ratio 1.33 against 3.30"),
        ((720, 1280), 300.0, "aspect ratio 1.78 against 3.30"),
        ((376, 1100), 386.17, "aspect ratio 2.93 against 3.30"),  # 11 % narrower
        ((376, 1241), 386.17 / 1.6, "disparity range (f*b / image width) 0.194 m against 0.311 m"),
        ((188, 620), 386.17, "disparity range (f*b / image width) 0.623 m against 0.311 m"),
        ((376, 1241), 0.0, "f*b unknown"),
    ],
)
def test_another_camera_is_named(
    image_size: tuple[int, int], focal_baseline: float, reason: str
) -> None:
    assert camera_mismatch(kitti_like(), image_size, focal_baseline) == reason


@pytest.mark.parametrize(
    ("image_size", "focal_baseline", "kinds", "fits"),
    [
        ((376, 1241), 386.17, ["street", "indoor"], True),  # KITTI's grey camera
        ((94, 310), 96.5, ["street", "indoor"], True),  # quarter-size synthetic drive
        ((480, 752), 48.02, ["indoor", "street"], True),  # EuRoC's VI-sensor
        ((120, 188), 12.0, ["indoor", "street"], True),  # quarter-size synthetic walk
        ((480, 640), 30.0, ["indoor", "street"], False),  # a depth camera: like neither
    ],
)
def test_builtin_fits_puts_the_built_in_basis_of_the_camera_first(
    image_size: tuple[int, int], focal_baseline: float, kinds: list[str], fits: bool
) -> None:
    found = builtin_fits(image_size, focal_baseline)
    assert [fit.kind for fit in found] == kinds
    assert (found[0].mismatch is None) is fits
    assert found[1].mismatch is not None
    for fit in found:  # within the tolerances exactly when camera_mismatch finds nothing
        distance = camera_distance(fit.basis, image_size, focal_baseline)
        assert fit.distance == distance
        assert (distance <= 1.0) is (fit.mismatch is None)


@pytest.mark.parametrize("dtype", [np.int16, np.uint16])
def test_fixed_point_maps_are_refused(dtype: type) -> None:
    """OpenCV's StereoSGBM.compute() gives int16 16 x px, KITTI's PNGs uint16 256 x px."""
    start = learn(grid_maps(5, 5.0, seed=8))
    fixed = np.full(GRID, 20 * 16, dtype)
    with pytest.raises(TypeError, match=r"`maps\[0\]` as float disparities in px"):
        finetune_basis(start, [fixed], n_prior=5)
