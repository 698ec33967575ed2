from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from pcainterp_stream.estimate.basis import Basis, bilinear_weights, image_to_grid, sample_rows
from pcainterp_stream.estimate.estimator import (
    SolveForm,
    Uncertainty,
    densify,
    densify_batch,
    depth_from_disparity,
    posterior_covariance,
)


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
