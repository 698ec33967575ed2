from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from pcainterp_stream.estimate import variance
from pcainterp_stream.estimate.basis import Basis, bilinear_weights, image_to_grid, sample_rows
from pcainterp_stream.estimate.estimator import (
    SolveForm,
    Uncertainty,
    densify,
    densify_batch,
    depth_from_disparity,
    posterior_covariance,
)
from pcainterp_stream.estimate.learning import learn_basis
from pcainterp_stream.estimate.prior import Kernel, LocalPrior, Model, TemporalPrior


def random_basis(
    seed: int,
    n_components: int = 6,
    grid_size: tuple[int, int] = (7, 9),
    image_size: tuple[int, int] | None = None,
) -> Basis:
    rng = np.random.default_rng(seed)
    s = grid_size[0] * grid_size[1]
    q = np.linalg.qr(rng.normal(size=(s, n_components)))[0]
    return Basis(
        mean=rng.uniform(5, 30, grid_size).astype(np.float32),
        components=q.T.reshape(n_components, *grid_size).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(0.5, 400, n_components))[::-1].copy(),
        total_variance=3000.0,
        image_size=grid_size if image_size is None else image_size,
        focal_baseline=380.0,
        n_train=50,
    )


def random_pixels(rng: np.random.Generator, k: int, image_size: tuple[int, int]) -> np.ndarray:
    return rng.uniform([0, 0], [image_size[1] - 1, image_size[0] - 1], (k, 2))


def rows_at(basis: Basis, pixels: np.ndarray) -> np.ndarray:
    indices, weights = bilinear_weights(
        image_to_grid(pixels, basis.image_size, basis.grid_size), basis.grid_size
    )
    return sample_rows(basis.pixel_major, indices, weights).astype(np.float64)


seeds = st.integers(min_value=0, max_value=2**31 - 1)


SIGMA_IN_SPAN = 1e-4


@settings(max_examples=examples(25), deadline=None)
@given(seed=seeds, extra=st.integers(min_value=0, max_value=10))
@example(seed=120938, extra=0)  # a near-singular sampling a new user's run drew
@example(seed=6390037, extra=0)  # a measurement of negative disparity (dropped by densify)
def test_map_in_span_is_reproduced(seed: int, extra: int) -> None:
    basis = random_basis(seed)
    rng = np.random.default_rng(seed)
    coefficients = rng.normal(size=basis.n_components) * np.sqrt(basis.eigenvalues)
    truth = basis.mean + np.tensordot(coefficients, basis.components, axes=1)
    k = basis.n_components + extra
    pixels = random_pixels(rng, k, basis.image_size)
    # The property needs a well-posed sampling: the MAP estimate shrinks the coefficients
    # along the sampled rows' singular direction v_i by sigma^2 / (sigma^2 + lambda s_i^2)
    # (eq. 11), so sigma -> 0 pins every coefficient only where lambda_min s_min^2 >>
    # sigma^2. k = l random positions can sample the basis almost singularly (seed 120938:
    # s_min = 1.2e-4, a 40 % shrinkage). Require a shrinkage below 1e-4.
    indices, weights = bilinear_weights(
        image_to_grid(pixels, basis.image_size, basis.grid_size), basis.grid_size
    )
    measured = (truth.reshape(-1)[indices] * weights).sum(axis=1)
    # a disparity <= 0 is no measurement (densify drops it: seed 6390037 drew one at -3.3 px)
    assume(measured.min() > 0)
    result = densify(basis, pixels, measured, sigma=SIGMA_IN_SPAN, uncertainty="none")
    # every draw: the measurements themselves are reproduced (a shrunk direction moves them
    # by at most s_i sigma^2 / (sigma^2 + lambda s_i^2) |y_i| <= sigma |y_i| / (2 sqrt(lambda)))
    fitted = (result.disparity.astype(np.float64).reshape(-1)[indices] * weights).sum(axis=1)
    np.testing.assert_allclose(fitted, measured, atol=1e-3)
    singular = np.linalg.svd(rows_at(basis, pixels), compute_uv=False)
    assume(basis.eigenvalues.min() * singular.min() ** 2 >= 1e4 * SIGMA_IN_SPAN**2)
    np.testing.assert_allclose(result.disparity, truth, atol=2e-3)


@settings(max_examples=examples(25), deadline=None)
@given(seed=seeds, k=st.integers(min_value=0, max_value=12))
def test_adding_a_measurement_never_raises_variance(seed: int, k: int) -> None:
    basis = random_basis(seed)
    rng = np.random.default_rng(seed)
    pixels = random_pixels(rng, k + 1, basis.image_size)
    values = rng.uniform(5, 30, k + 1)
    before = densify(basis, pixels[:k], values[:k], variance_stride=1).disparity_std
    after = densify(basis, pixels, values, variance_stride=1).disparity_std
    assert before is not None
    assert after is not None
    assert np.all(after <= before + 1e-3 * (1 + before))


@settings(max_examples=examples(25), deadline=None)
@given(
    seed=seeds, k=st.integers(min_value=1, max_value=14), mode=st.sampled_from(["exact", "paper"])
)
def test_solve_forms_agree(seed: int, k: int, mode: str) -> None:
    basis = random_basis(seed)
    rng = np.random.default_rng(seed)
    pixels = random_pixels(rng, k, basis.image_size)
    values = rng.uniform(5, 30, k)
    coefficient = densify(basis, pixels, values, solve_form="coefficient", uncertainty=mode)
    measurement = densify(basis, pixels, values, solve_form="measurement", uncertainty=mode)
    assert coefficient.solve_form is SolveForm.COEFFICIENT
    assert measurement.solve_form is SolveForm.MEASUREMENT
    np.testing.assert_allclose(
        coefficient.coefficients, measurement.coefficients, rtol=1e-6, atol=1e-6
    )
    np.testing.assert_allclose(coefficient.disparity, measurement.disparity, rtol=1e-5, atol=1e-4)
    assert coefficient.disparity_std is not None
    assert measurement.disparity_std is not None
    np.testing.assert_allclose(
        coefficient.disparity_std, measurement.disparity_std, rtol=1e-3, atol=1e-3
    )


@settings(max_examples=examples(25), deadline=None)
@given(seed=seeds, k=st.integers(min_value=0, max_value=14), sigma=st.floats(0.3, 5.0))
def test_exact_variance_equals_brute_force(seed: int, k: int, sigma: float) -> None:
    basis = random_basis(seed)
    rng = np.random.default_rng(seed)
    pixels = random_pixels(rng, k, basis.image_size)
    values = rng.uniform(5, 30, k)
    rows = rows_at(basis, pixels)
    # Sigma_y = sigma^2 (sigma^2 Lambda^-1 + B~^T B~)^-1 (the paper's, times sigma^2)
    covariance = sigma**2 * np.linalg.inv(sigma**2 * np.diag(1 / basis.eigenvalues) + rows.T @ rows)
    np.testing.assert_allclose(
        posterior_covariance(basis, pixels, values, sigma=sigma), covariance, rtol=1e-6, atol=1e-8
    )
    full = basis.components.reshape(basis.n_components, -1).T.astype(np.float64)
    expected = np.sqrt(np.diag(full @ covariance @ full.T)).reshape(basis.grid_size)
    result = densify(basis, pixels, values, sigma=sigma, variance_stride=1)
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.disparity_std, expected, rtol=2e-3, atol=2e-3)
    # MAP mean from the paper's system (eq. 11)
    indices, weights = bilinear_weights(
        image_to_grid(pixels, basis.image_size, basis.grid_size), basis.grid_size
    )
    residual = values - (basis.mean.reshape(-1)[indices] * weights).sum(axis=1)
    coefficients = np.linalg.solve(
        sigma**2 * np.diag(1 / basis.eigenvalues) + rows.T @ rows, rows.T @ residual
    )
    np.testing.assert_allclose(result.coefficients, coefficients, rtol=1e-5, atol=1e-6)


@settings(max_examples=examples(20), deadline=None)
@given(seed=seeds, k=st.integers(min_value=0, max_value=14))
def test_paper_mode_is_the_diagonal_formula(seed: int, k: int) -> None:
    basis = random_basis(seed)
    rng = np.random.default_rng(seed)
    pixels = random_pixels(rng, k, basis.image_size)
    values = rng.uniform(5, 30, k)
    kappa2 = np.diag(posterior_covariance(basis, pixels, values))
    u = basis.components.astype(np.float64)
    expected = np.sqrt(np.tensordot(kappa2, u**2, axes=1))
    result = densify(basis, pixels, values, uncertainty="paper", variance_stride=1)
    assert result.uncertainty is Uncertainty.PAPER
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.coefficient_variance, kappa2, rtol=1e-6)
    np.testing.assert_allclose(result.disparity_std, expected, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("mode", ["exact", "paper", "none"])
def test_batch_equals_one_by_one(mode: str) -> None:
    basis = random_basis(3, n_components=8, grid_size=(8, 12), image_size=(20, 30))
    rng = np.random.default_rng(3)
    ks = [0, 3, 7, 12, 20]
    pixels = [random_pixels(rng, k, basis.image_size) for k in ks]
    values = [rng.uniform(5, 30, k) for k in ks]
    batch = densify_batch(basis, pixels, values, uncertainty=mode)
    for frame_pixels, frame_values, batched in zip(pixels, values, batch, strict=True):
        single = densify(basis, frame_pixels, frame_values, uncertainty=mode)
        np.testing.assert_allclose(batched.disparity, single.disparity, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(batched.coefficients, single.coefficients, rtol=1e-9)
        if mode == "none":
            assert batched.disparity_std is None
            assert batched.depth_std is None
        else:
            assert batched.disparity_std is not None
            assert single.disparity_std is not None
            np.testing.assert_allclose(
                batched.disparity_std, single.disparity_std, rtol=1e-4, atol=1e-4
            )


def test_zero_measurements_give_the_prior() -> None:
    basis = random_basis(4, image_size=(14, 18))
    result = densify(basis, np.zeros((0, 2)), np.zeros(0), variance_stride=1)
    np.testing.assert_allclose(
        result.disparity,
        cv2.resize(basis.mean, (18, 14), interpolation=cv2.INTER_LINEAR),
        atol=1e-5,
    )
    assert result.disparity_std is not None
    prior_std = cv2.resize(np.sqrt(basis.prior_variance), (18, 14), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(result.disparity_std, prior_std, rtol=1e-4)
    np.testing.assert_array_equal(result.coefficients, 0)
    assert result.n_measurements == 0


def test_non_finite_and_out_of_image_dropped() -> None:
    basis = random_basis(5, image_size=(14, 18))
    pixels = np.array([[3.0, 4.0], [np.nan, 2.0], [30.0, 2.0], [5.0, -3.0], [6.0, 7.0], [2.0, 2.0]])
    values = np.array([10.0, 11.0, 12.0, 13.0, np.inf, 14.0])
    result = densify(basis, pixels, values)
    assert result.n_dropped == 4
    np.testing.assert_array_equal(result.pixels, [[3.0, 4.0], [2.0, 2.0]])
    np.testing.assert_array_equal(result.disparities, [10.0, 14.0])
    clean = densify(basis, pixels[[0, 5]], values[[0, 5]])
    np.testing.assert_array_equal(result.disparity, clean.disparity)


def test_depth_from_disparity() -> None:
    basis = random_basis(6, image_size=(14, 18))
    rng = np.random.default_rng(6)
    pixels = random_pixels(rng, 5, basis.image_size)
    result = densify(basis, pixels, rng.uniform(5, 30, 5), focal_baseline=100.0)
    assert result.depth is not None
    assert result.depth_std is not None
    assert result.disparity_std is not None
    positive = result.disparity >= result.min_disparity
    np.testing.assert_allclose(
        result.depth[positive], 100.0 / result.disparity[positive], rtol=1e-6
    )
    np.testing.assert_allclose(
        result.depth_std[positive],
        100.0 / result.disparity[positive] ** 2 * result.disparity_std[positive],
        rtol=1e-5,
    )
    assert not np.isnan(result.depth).any()
    too_far = result.disparity < result.min_disparity
    assert np.all(np.isposinf(result.depth[too_far]))
    assert np.all(np.isposinf(result.depth_std[too_far]))


def test_sky_is_farther_than_measurable() -> None:
    """REP 118: where the map's disparity is below the resolvable one the depth is +inf."""
    basis = random_basis(8, image_size=(14, 18))
    rows = np.arange(basis.grid_size[0])[:, None] * np.ones((1, basis.grid_size[1]))
    sky = rows < 3  # the top rows: disparity 0
    mean = np.where(sky, 0.0, 5.0 + 3.0 * rows).astype(np.float32)
    basis = dataclasses.replace(basis, mean=mean, eigenvalues=basis.eigenvalues * 1e-4)
    rng = np.random.default_rng(8)
    pixels = random_pixels(rng, 6, basis.image_size)
    result = densify(basis, pixels, np.full(6, 20.0), sigma=1.5)
    assert result.depth is not None
    assert result.depth_std is not None
    assert result.min_disparity == pytest.approx(1.5)
    too_far = result.disparity < result.min_disparity
    assert too_far[0].all(), "the top image row is sky"
    assert not too_far[-1].any(), "the bottom image row is road"
    assert np.all(np.isposinf(result.depth[too_far]))
    assert np.all(np.isposinf(result.depth_std[too_far]))
    assert np.all(np.isfinite(result.depth[~too_far]))
    assert result.depth[~too_far].max() <= basis.focal_baseline / 1.5
    # the disparity itself is kept as estimated
    assert np.all(result.disparity[0] < 1.5)


def test_depth_from_disparity_ranges() -> None:
    disparity = np.array([[np.nan, -1.0, 0.0, 0.4, 0.5, 2.0]], dtype=np.float32)
    std = np.full_like(disparity, 0.1)
    depth, depth_std = depth_from_disparity(disparity, std, 10.0, 0.5)
    assert depth_std is not None
    np.testing.assert_array_equal(depth, [[np.nan, np.inf, np.inf, np.inf, 20.0, 5.0]])
    np.testing.assert_allclose(depth_std, [[np.nan, np.inf, np.inf, np.inf, 4.0, 0.25]])
    with pytest.raises(ValueError, match="min_disparity"):
        depth_from_disparity(disparity, std, 10.0, 0.0)


def test_camera_mapping_round_trip() -> None:
    # the log camera has twice the resolution, so twice f (px) and twice the disparities
    basis = random_basis(7, n_components=6, grid_size=(8, 10), image_size=(16, 20))
    rng = np.random.default_rng(7)
    pixels = random_pixels(rng, 9, basis.image_size)
    values = rng.uniform(5, 30, 9)
    direct = densify(basis, pixels, values)
    log_pixels = (pixels + 0.5) * 2 - 0.5
    mapped = densify(
        basis, log_pixels, values * 2, image_size=(32, 40), focal_baseline=2 * basis.focal_baseline
    )
    np.testing.assert_allclose(mapped.coefficients, direct.coefficients, rtol=1e-6, atol=1e-9)
    expected = (
        cv2.resize(
            basis.mean
            + np.tensordot(direct.coefficients.astype(np.float32), basis.components, axes=1),
            (40, 32),
            interpolation=cv2.INTER_LINEAR,
        )
        * 2
    )
    np.testing.assert_allclose(mapped.disparity, expected, rtol=1e-4, atol=1e-3)
    assert mapped.disparity.shape == (32, 40)
    assert mapped.disparity_std is not None
    assert direct.disparity_std is not None
    down = cv2.resize(mapped.disparity_std, (20, 16), interpolation=cv2.INTER_AREA) / 2
    np.testing.assert_allclose(down.mean(), direct.disparity_std.mean(), rtol=0.05)
    # depth is invariant: same scene, same metres
    assert mapped.depth is not None
    assert direct.depth is not None
    np.testing.assert_allclose(np.nanmedian(mapped.depth), np.nanmedian(direct.depth), rtol=0.05)


def test_sigma_is_in_px_of_the_basis_camera_and_says_so() -> None:
    # a camera of 1/8 the basis's f*b: sigma 2 (basis px) is 0.25 px of the log's camera,
    # the smallest disparity it resolves (bug hunt 6A F2: documented, not converted)
    basis = random_basis(7, n_components=6, grid_size=(8, 10), image_size=(16, 20))
    rng = np.random.default_rng(7)
    pixels = random_pixels(rng, 9, basis.image_size)
    values = rng.uniform(1, 4, 9)
    fb = basis.focal_baseline / 8
    result = densify(basis, pixels, values, sigma=2.0, focal_baseline=fb)
    assert result.sigma == 2.0
    assert result.min_disparity == pytest.approx(0.25)
    for function in (densify, densify_batch):
        assert "px of the basis's camera" in " ".join((function.__doc__ or "").split())
    assert "px of the basis's camera" in " ".join((Model.__doc__ or "").split())


@pytest.mark.parametrize(
    ("pixels", "values", "match"),
    [
        (np.zeros((3, 3)), np.zeros(3), r"`pixels` of shape \(k, 2\)"),
        (np.zeros((3, 2)), np.zeros(4), r"`disparities` of shape \(3,\)"),
    ],
)
def test_bad_arrays_named(pixels: np.ndarray, values: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        densify(random_basis(8), pixels, values)


def test_bad_options_named() -> None:
    basis = random_basis(9)
    with pytest.raises(ValueError, match="`sigma` > 0"):
        densify(basis, np.zeros((0, 2)), np.zeros(0), sigma=0.0)
    with pytest.raises(ValueError, match="'bogus' is not a valid Uncertainty"):
        densify(basis, np.zeros((0, 2)), np.zeros(0), uncertainty="bogus")
    with pytest.raises(ValueError, match="`disparities_list`"):
        densify_batch(basis, [np.zeros((0, 2))], [])


# ----------------------------------------------------------------------------- exact std
# "exact" is the posterior std at every output pixel; "exact-coarse" (the default) is exact
# only at the points of the variance grid (docs/stages.md, "Exact posterior std").


def _learned_like_basis(image_size: tuple[int, int] = (48, 64)) -> Basis:
    """A basis learned from piecewise-planar maps (road, boxes with sharp edges).

    Like a basis learned from real SGBM maps, its components are not smooth at the scale of
    the basis grid (1/4 of the image), so the std is not bilinear between grid points.
    """
    rng = np.random.default_rng(17)
    height, width = image_size
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    maps = []
    for _ in range(60):
        horizon = rng.uniform(0.3, 0.6) * height
        disparity = np.where(ys > horizon, (ys - horizon) * rng.uniform(0.3, 0.8), 0.0)
        for _ in range(int(rng.integers(1, 4))):
            left, size = rng.uniform(0, width - 8), rng.uniform(6, width / 2)
            top, bottom = rng.uniform(0, horizon), rng.uniform(horizon, height)
            box = (xs >= left) & (xs < left + size) & (ys >= top) & (ys < bottom)
            disparity = np.where(box, np.maximum(disparity, rng.uniform(5, 30)), disparity)
        maps.append(disparity.astype(np.float32))
    return learn_basis(maps, n_components=20, grid_scale=0.25, focal_baseline=100.0)


def _dense_posterior_std(
    basis: Basis,
    pixels: np.ndarray,
    sigma: float,
    local: LocalPrior | None,
    prior_variances: np.ndarray | None = None,
) -> np.ndarray:
    """Posterior std of the Gaussian model at every image pixel, from its dense covariance.

    d = m + B y (+ local part), B the bilinear rows of the basis at every pixel,
    y ~ N(., diag(prior_variances or eigenvalues)); measurements at integer ``pixels``.
    """
    height, width = basis.image_size
    ys, xs = np.mgrid[0:height, 0:width]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    rows = rows_at(basis, grid)
    variances = basis.eigenvalues if prior_variances is None else prior_variances
    prior = (rows * variances) @ rows.T
    if local is not None:
        prior += (
            local.variance * local.axis(grid[:, 0], grid[:, 0]) * local.axis(grid[:, 1], grid[:, 1])
        )
    index = pixels[:, 1].astype(int) * width + pixels[:, 0].astype(int)
    system = prior[np.ix_(index, index)] + sigma**2 * np.eye(index.size)
    gain = np.linalg.solve(system, prior[index])
    variance = np.diag(prior) - np.einsum("ks,ks->s", prior[index], gain)
    return np.sqrt(np.maximum(variance, 0.0)).reshape(height, width)


def _measured(basis: Basis, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """k distinct integer pixels and disparities near the basis mean there (> 0: its sky is 0
    and a disparity <= 0 is no measurement)."""
    rng = np.random.default_rng(seed)
    height, width = basis.image_size
    flat = rng.choice(height * width, size=k, replace=False)
    pixels = np.stack([flat % width, flat // width], axis=1).astype(np.float64)
    mean = cv2.resize(basis.mean, (width, height), interpolation=cv2.INTER_LINEAR)
    values = np.abs(mean[flat // width, flat % width] + rng.normal(0.0, 2.0, k))
    return pixels, values


LOCAL_PRIORS = [
    None,
    LocalPrior(variance=4.0, length_scale=12.0, kernel=Kernel.LAPLACE),
    LocalPrior(variance=4.0, length_scale=8.0, kernel=Kernel.GAUSSIAN),
]


@pytest.mark.parametrize("local", LOCAL_PRIORS, ids=["paper", "laplace", "gaussian"])
def test_exact_is_the_posterior_std_at_every_pixel(local: LocalPrior | None) -> None:
    basis = _learned_like_basis()
    assert basis.grid_size == (12, 16)
    pixels, values = _measured(basis, 30, seed=1)
    expected = _dense_posterior_std(basis, pixels, 0.3, local)
    exact = densify(basis, pixels, values, sigma=0.3, local_prior=local, uncertainty="exact")
    assert exact.uncertainty is Uncertainty.EXACT
    assert exact.disparity_std is not None
    relative = np.abs(exact.disparity_std - expected) / expected
    assert relative.max() < 2e-3
    # at the measurements too, where the hybrid prior's std dips towards sigma
    rows, cols = pixels[:, 1].astype(int), pixels[:, 0].astype(int)
    np.testing.assert_allclose(exact.disparity_std[rows, cols], expected[rows, cols], rtol=2e-3)


def test_exact_coarse_is_the_default_and_only_exact_on_its_grid() -> None:
    basis = _learned_like_basis()
    local = LOCAL_PRIORS[1]
    pixels, values = _measured(basis, 30, seed=2)
    expected = _dense_posterior_std(basis, pixels, 0.3, local)
    coarse = densify(basis, pixels, values, sigma=0.3, local_prior=local)
    assert coarse.uncertainty is Uncertainty.EXACT_COARSE
    assert Uncertainty("exact-coarse") is Uncertainty.EXACT_COARSE
    assert coarse.disparity_std is not None
    # resampled from a grid of 3 x 4 points, it cannot hold the dips at the measurements
    rows, cols = pixels[:, 1].astype(int), pixels[:, 0].astype(int)
    assert np.median(coarse.disparity_std[rows, cols] / expected[rows, cols]) > 1.5
    # with a full-resolution basis grid and stride 1, every pixel is a grid point
    full = random_basis(3, n_components=8, grid_size=(10, 14))
    pixels, values = _measured(full, 12, seed=3)
    on_grid = densify(full, pixels, values, local_prior=local, variance_stride=1)
    everywhere = densify(full, pixels, values, local_prior=local, uncertainty="exact")
    assert on_grid.disparity_std is not None
    assert everywhere.disparity_std is not None
    np.testing.assert_allclose(on_grid.disparity_std, everywhere.disparity_std, rtol=1e-4)


def test_exact_in_chunks_batched_and_temporal(monkeypatch: pytest.MonkeyPatch) -> None:
    basis = _learned_like_basis()
    local = LOCAL_PRIORS[1]
    frames = [_measured(basis, 20 + 5 * i, seed=10 + i) for i in range(3)]
    whole = densify_batch(
        basis,
        [p for p, _ in frames],
        [v for _, v in frames],
        sigma=0.5,
        local_prior=local,
        temporal=TemporalPrior(),
        uncertainty="exact",
    )
    # 3 output rows per chunk: 16 chunks per frame, each a partial VarianceGrid
    monkeypatch.setattr(variance, "_EXACT_PIXELS_PER_CHUNK", 3 * basis.image_size[1])
    state = TemporalPrior()
    predicted = None
    for index, ((pixels, values), batched) in enumerate(zip(frames, whole, strict=True)):
        if index == 2:
            predicted = state.predict(basis.eigenvalues)
        single = densify(
            basis,
            pixels,
            values,
            sigma=0.5,
            local_prior=local,
            temporal=state,
            uncertainty="exact",
            variance_stride=3,  # ignored by "exact"
        )
        assert single.disparity_std is not None
        assert batched.disparity_std is not None
        np.testing.assert_allclose(single.disparity_std, batched.disparity_std, rtol=1e-4)
    # the third frame's prior is the temporal one: N(mu, diag(p)) + the local part
    assert whole[2].temporal == "temporal"
    assert predicted is not None
    expected = _dense_posterior_std(basis, frames[2][0], 0.5, local, predicted[1])
    assert whole[2].disparity_std is not None
    np.testing.assert_allclose(whole[2].disparity_std, expected, rtol=2e-3)


@pytest.mark.parametrize(
    ("grid_size", "out_size", "k"),
    [
        ((7, 9), (20, 31), 0),
        ((7, 9), (20, 31), 4),  # measurement form
        ((7, 9), (23, 29), 14),  # coefficient form (k >= l), another camera's size
        ((1, 9), (3, 40), 5),  # one grid row
        ((6, 1), (25, 2), 3),  # one grid column
    ],
)
def test_exact_without_a_local_part_is_its_bilinear_form(
    grid_size: tuple[int, int], out_size: tuple[int, int], k: int
) -> None:
    # the bilinear quadratic form from grid neighbours (no local part) against the pixel by
    # pixel evaluation (a local part of variance 0), for the static and the temporal prior
    basis = random_basis(5, grid_size=grid_size, image_size=(20, 31))
    rng = np.random.default_rng(5)
    frames = [(random_pixels(rng, k, out_size), rng.uniform(5, 30, k)) for _ in range(2)]
    states = [TemporalPrior(), TemporalPrior()]
    for pixels, values in frames:
        results = [
            densify(
                basis,
                pixels,
                values,
                uncertainty="exact",
                image_size=out_size,
                focal_baseline=300.0,
                local_prior=local,
                temporal=state,
            )
            for local, state in zip([None, LocalPrior(0.0, 5.0)], states, strict=True)
        ]
        static = densify(basis, pixels, values, uncertainty="exact", image_size=out_size)
        pixelwise = densify(
            basis,
            pixels,
            values,
            uncertainty="exact",
            image_size=out_size,
            local_prior=LocalPrior(0.0, 5.0),
        )
        for a, b in (results, (static, pixelwise)):
            assert a.disparity_std is not None
            assert b.disparity_std is not None
            assert a.disparity_std.shape == out_size
            np.testing.assert_allclose(a.disparity_std, b.disparity_std, rtol=1e-4, atol=1e-5)


@settings(max_examples=examples(50), deadline=None)
@given(
    seed=seeds,
    match_range=st.sampled_from([16.0, 64.0, 128.0, 256.0]),
    top=st.floats(min_value=1.0, max_value=400.0),
)
def test_near_range_widening_raises_the_std_only_near_the_range(
    seed: int, match_range: float, top: float
) -> None:
    rng = np.random.default_rng(seed)
    disparity = rng.uniform(0.0, top, (9, 11)).astype(np.float32)
    std = rng.uniform(0.1, 20.0, (9, 11)).astype(np.float32)
    widened = variance.widen_near_range(disparity, std.copy(), match_range)
    start = variance.NEAR_RANGE_START * match_range
    far = disparity <= np.float32(start)
    np.testing.assert_array_equal(widened[far], std[far])
    excess = variance.NEAR_RANGE_SLOPE * (disparity[~far].astype(np.float64) - start)
    np.testing.assert_allclose(widened[~far], np.hypot(std[~far], excess), rtol=1e-5)
    assert np.all(widened >= std)


def test_match_range_widens_the_std_of_near_estimates_only() -> None:
    basis = random_basis(3, image_size=(35, 45))
    pixels = random_pixels(np.random.default_rng(4), 12, basis.image_size)
    disparities = np.linspace(5.0, 60.0, 12)
    plain = densify(basis, pixels, disparities, sigma=1.0)
    near = densify(basis, pixels, disparities, sigma=1.0, match_range=64.0)
    assert plain.disparity_std is not None
    assert near.disparity_std is not None
    assert plain.depth_std is not None
    assert near.depth_std is not None
    np.testing.assert_array_equal(near.disparity, plain.disparity)
    beyond = plain.disparity > variance.NEAR_RANGE_START * 64.0
    assert beyond.any()
    assert (~beyond).any()
    np.testing.assert_array_equal(near.disparity_std[~beyond], plain.disparity_std[~beyond])
    assert np.all(near.disparity_std[beyond] > plain.disparity_std[beyond])
    assert np.all(near.depth_std[beyond] > plain.depth_std[beyond])  # the depth's std follows
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ValueError, match="match_range"):
            densify(basis, pixels, disparities, match_range=bad)


def test_disparities_at_or_below_zero_are_dropped_and_counted() -> None:
    """A disparity <= 0 is no match (the invalid code of disparity images: 0, SGBM's -1)."""
    basis = random_basis(21, image_size=(14, 18))
    rng = np.random.default_rng(21)
    pixels = random_pixels(rng, 8, basis.image_size)
    values = rng.uniform(5, 30, 8)
    invalid = values.copy()
    invalid[[1, 4, 6]] = [0.0, -1.0, -16.0]
    clean = densify(basis, pixels[[0, 2, 3, 5, 7]], values[[0, 2, 3, 5, 7]])
    result = densify(basis, pixels, invalid)
    assert result.n_dropped == 3
    assert result.n_measurements == 5
    np.testing.assert_array_equal(result.disparities, values[[0, 2, 3, 5, 7]])
    np.testing.assert_array_equal(result.disparity, clean.disparity)
    (batched,) = densify_batch(basis, [pixels], [invalid])
    assert batched.n_dropped == 3
    np.testing.assert_array_equal(batched.disparity, clean.disparity)
    # the front end's SGBM matches at zero disparity (minDisparity 0) are kept on request
    kept = densify(basis, pixels, invalid, zero_is_match=True)
    assert kept.n_dropped == 2
    assert 0.0 in kept.disparities


def test_noise_std_follows_the_dropped_disparities() -> None:
    basis = random_basis(22, image_size=(14, 18))
    rng = np.random.default_rng(22)
    pixels = random_pixels(rng, 6, basis.image_size)
    values = np.array([10.0, 0.0, 12.0, -1.0, 15.0, 11.0])
    noise = np.array([0.5, 9.0, 0.5, 9.0, 0.5, 0.5])
    result = densify(basis, pixels, values, noise_std=noise)
    used = [0, 2, 4, 5]
    clean = densify(basis, pixels[used], values[used], noise_std=noise[used])
    np.testing.assert_array_equal(result.disparity, clean.disparity)


@pytest.mark.parametrize("dtype", [np.int16, np.uint16])
def test_fixed_point_disparities_are_refused(dtype: type) -> None:
    """OpenCV's StereoSGBM gives int16 16 x px, KITTI's PNGs uint16 256 x px."""
    basis = random_basis(23, image_size=(14, 18))
    pixels = random_pixels(np.random.default_rng(23), 4, basis.image_size)
    with pytest.raises(TypeError, match=r"`disparities` as float disparities in px, got u?int16"):
        densify(basis, pixels, np.array([160, 320, 0, 200], dtype=dtype))
    with pytest.raises(TypeError, match="astype"):
        densify_batch(basis, [pixels], [np.array([160, 320, 16, 200], dtype=dtype)])
    with pytest.raises(TypeError, match="got bool"):
        densify(basis, pixels, np.ones(4, bool))
    with pytest.raises(TypeError, match="`edge_map`"):
        densify(basis, pixels, np.full(4, 10.0), edge_map=np.full((14, 18), 160, dtype))


def test_dtypes_and_views_give_the_same_estimate() -> None:
    basis = random_basis(24, image_size=(14, 18))
    rng = np.random.default_rng(24)
    pixels = random_pixels(rng, 6, basis.image_size).round()
    values = rng.integers(5, 30, 6).astype(np.float64)
    reference = densify(basis, pixels, values)
    wide = np.zeros((6, 4))
    wide[:, ::2] = pixels
    strided = np.repeat(values, 2)[::2]  # a non-contiguous view
    for other_pixels, other_values in [
        (pixels.astype(np.float32), values.astype(np.float32)),
        (pixels.astype(np.int64), values.astype(np.int64)),
        (pixels.tolist(), values.tolist()),
        (wide[:, ::2], strided),
        (np.asfortranarray(pixels), values),
    ]:
        result = densify(basis, other_pixels, other_values)
        np.testing.assert_allclose(result.disparity, reference.disparity, rtol=1e-5, atol=1e-5)


def test_a_batch_of_no_frames_is_no_results() -> None:
    assert densify_batch(None, [], []) == []


@pytest.mark.parametrize("size", [(94.9, 310.9), (94.0, 310.5)])
def test_a_fractional_image_size_is_refused(size: tuple[float, float]) -> None:
    pixels = np.array([[5.0, 5.0]])
    with pytest.raises(ValueError, match="image_size"):
        densify(None, pixels, np.array([10.0]), image_size=size)  # type: ignore[arg-type]
    assert densify(None, pixels, np.array([10.0]), image_size=(94.0, 310.0)).disparity.shape == (
        94,
        310,
    )  # type: ignore[arg-type]
