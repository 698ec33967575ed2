"""The additions beyond the paper (prior.py) against brute-force Gaussian algebra."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pcainterp_stream import Basis, DensifyResult, densify, densify_batch
from pcainterp_stream.estimate.prior import (
    Kernel,
    LocalPrior,
    Robust,
    RobustStart,
    TemporalPrior,
    covariance_scale,
    evidence_sigma,
    robust_weights,
)
from pcainterp_stream.estimate.variance import innovation_variance_scale


def _basis(height: int = 12, width: int = 16, n_components: int = 6, seed: int = 0) -> Basis:
    """A full-resolution (grid = image) random orthonormal basis of smooth fields."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width] / max(height, width)
    fields = [
        np.cos(np.pi * (a * xs + b * ys) + c)
        for a, b, c in rng.uniform(0.0, 3.0, size=(n_components, 3))
    ]
    matrix = np.stack([f.ravel() for f in fields], axis=1)
    q, _ = np.linalg.qr(matrix)
    components = q.T.reshape(n_components, height, width).astype(np.float32)
    eigenvalues = np.sort(rng.uniform(5.0, 200.0, n_components))[::-1]
    mean = (20.0 + 10.0 * ys).astype(np.float32)
    return Basis(
        mean=mean,
        components=components,
        eigenvalues=eigenvalues,
        total_variance=float(eigenvalues.sum()) * 1.5,
        image_size=(height, width),
        focal_baseline=100.0,
        n_train=50,
    )


def _points(basis: Basis, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    height, width = basis.image_size
    pixels = np.stack(
        [rng.integers(0, width, k), rng.integers(0, height, k)], axis=1
    ).astype(np.float64)
    disparities = rng.uniform(10.0, 40.0, k)
    return pixels, disparities


def _brute_force(
    basis: Basis,
    pixels: np.ndarray,
    disparities: np.ndarray,
    sigma: float,
    local: LocalPrior | None,
    noise_weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Dense GP posterior over every pixel: d ~ N(m, B Lambda B^T + C), z = d(p) + n."""
    height, width = basis.image_size
    b = basis.pixel_major.astype(np.float64)
    prior = b @ np.diag(basis.eigenvalues) @ b.T
    ys, xs = np.mgrid[0:height, 0:width]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    if local is not None:
        prior += local.variance * local.axis(grid[:, 0], grid[:, 0]) * local.axis(
            grid[:, 1], grid[:, 1]
        )
    index = (pixels[:, 1].astype(int) * width + pixels[:, 0].astype(int))
    weights = np.ones(len(index)) if noise_weights is None else noise_weights
    system = prior[np.ix_(index, index)] + np.diag(sigma**2 / weights)
    gain = np.linalg.solve(system, prior[index]).T  # (s, k)
    mean = basis.mean_flat.astype(np.float64)
    estimate = mean + gain @ (disparities - mean[index])
    variance = np.diag(prior) - np.einsum("sk,ks->s", gain, prior[index])
    return estimate.reshape(height, width), np.sqrt(np.maximum(variance, 0)).reshape(
        height, width
    )


def _assert_matches(result: DensifyResult, expected: tuple[np.ndarray, np.ndarray]) -> None:
    """The result's map and std equal ``expected`` (:func:`_brute_force`)."""
    np.testing.assert_allclose(result.disparity, expected[0], atol=2e-3)
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.disparity_std, expected[1], atol=2e-3)


@pytest.mark.parametrize("kernel", [Kernel.LAPLACE, Kernel.GAUSSIAN])
@pytest.mark.parametrize("length_scale", [3.0, 20.0])  # full-size and grid local part
def test_hybrid_prior_equals_dense_gaussian_posterior(kernel: Kernel, length_scale: float) -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=1)
    local = LocalPrior(variance=4.0, length_scale=length_scale, kernel=kernel)
    assert local.smooth_at(1.0) == (length_scale == 20.0)
    result = densify(
        basis, pixels, disparities, sigma=1.5, local_prior=local, variance_stride=1
    )
    _assert_matches(result, _brute_force(basis, pixels, disparities, 1.5, local))


def test_hybrid_map_passes_closer_to_the_measurements() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=2)
    cols, rows = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
    plain = densify(basis, pixels, disparities, sigma=0.5)
    hybrid = densify(
        basis, pixels, disparities, sigma=0.5,
        local_prior=LocalPrior(variance=50.0, length_scale=2.0),
    )
    plain_gap = np.abs(plain.disparity[rows, cols] - disparities).mean()
    hybrid_gap = np.abs(hybrid.disparity[rows, cols] - disparities).mean()
    assert hybrid_gap < 0.5 * plain_gap


def test_zero_local_variance_is_the_paper_estimate() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 5, seed=3)
    plain = densify(basis, pixels, disparities, sigma=2.0, variance_stride=1)
    hybrid = densify(
        basis, pixels, disparities, sigma=2.0, variance_stride=1,
        local_prior=LocalPrior(variance=0.0, length_scale=4.0),
    )
    np.testing.assert_allclose(hybrid.disparity, plain.disparity, atol=1e-4)
    np.testing.assert_allclose(hybrid.coefficients, plain.coefficients, rtol=1e-6, atol=1e-8)
    assert hybrid.disparity_std is not None
    assert plain.disparity_std is not None
    np.testing.assert_allclose(hybrid.disparity_std, plain.disparity_std, atol=1e-3)


def test_robust_weights_match_a_weighted_gaussian_posterior() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 10, seed=4)
    disparities[3] += 60.0  # a wrong SGBM lookup
    local = LocalPrior(variance=4.0, length_scale=3.0)
    result = densify(
        basis, pixels, disparities, sigma=1.0, local_prior=local, robust="cauchy",
        variance_stride=1,
    )
    assert result.weights is not None
    assert result.weights[3] < 0.5
    assert result.n_downweighted >= 1
    # at convergence the estimate is the Gaussian posterior with noise sigma^2 / w
    _assert_matches(result, _brute_force(basis, pixels, disparities, 1.0, local, result.weights))


def _drawn(basis: Basis, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A field drawn from the basis's prior, and 30 points of it with 0.3 px noise."""
    rng = np.random.default_rng(seed)
    truth = basis.mean + np.tensordot(
        rng.normal(size=6) * np.sqrt(basis.eigenvalues), basis.components, axes=1
    )
    pixels, _ = _points(basis, 30, seed=seed)
    rows, cols = pixels[:, 1].astype(int), pixels[:, 0].astype(int)
    return truth, pixels, truth[rows, cols] + rng.normal(0, 0.3, 30)


def test_robust_estimate_resists_an_outlier() -> None:
    basis = _basis()
    truth, pixels, disparities = _drawn(basis, seed=5)
    disparities[:3] += 40.0
    plain = densify(basis, pixels, disparities, sigma=0.5)
    robust = densify(basis, pixels, disparities, sigma=0.5, robust=Robust.HUBER)
    assert np.abs(robust.disparity - truth).mean() < 0.5 * np.abs(plain.disparity - truth).mean()
    assert robust.n_downweighted >= 3


def test_robust_reweights_only_a_frame_with_an_outlier() -> None:
    basis = _basis()
    _, pixels, disparities = _drawn(basis, seed=7)
    options = {"sigma": 0.5, "robust": "cauchy"}

    def solve(values: np.ndarray, **more: float) -> DensifyResult:
        return densify_batch(basis, [pixels], [values], **options, **more)[0]  # type: ignore[arg-type]

    # every leave-one-out residual within 4 predictive std: the unweighted solve stands
    clean = solve(disparities)
    plain = densify_batch(basis, [pixels], [disparities], sigma=0.5)[0]
    assert clean.weights is not None
    np.testing.assert_array_equal(clean.weights, 1.0)
    np.testing.assert_array_equal(clean.disparity, plain.disparity)
    np.testing.assert_allclose(clean.disparity_std, plain.disparity_std, rtol=1e-5)
    # robust_from=0: reweighted all the same, every Cauchy weight below 1
    always = solve(disparities, robust_from=0.0)
    assert always.weights is not None
    assert always.weights.max() < 1.0
    assert not np.array_equal(always.disparity, plain.disparity)
    # one wrong lookup: the frame is reweighted from it
    wrong = disparities.copy()
    wrong[4] += 40.0
    outlier = solve(wrong)
    assert outlier.weights is not None
    assert outlier.weights[4] < 0.5
    np.testing.assert_array_equal(outlier.disparity, solve(wrong, robust_from=0.0).disparity)
    with pytest.raises(ValueError, match="robust_from"):
        solve(disparities, robust_from=-1.0)


def test_robust_weights_shapes() -> None:
    t = np.array([0.0, 1.0, 3.0, -10.0])
    np.testing.assert_allclose(robust_weights(t, Robust.NONE), 1.0)
    huber = robust_weights(t, Robust.HUBER)
    assert huber[0] == 1.0
    assert huber[1] == 1.0
    assert huber[3] == pytest.approx(0.1345)
    cauchy = robust_weights(t, Robust.CAUCHY)
    assert np.all(np.diff(cauchy[:3]) < 0)
    assert cauchy[3] < 0.1


def test_evidence_recovers_the_noise_level() -> None:
    rng = np.random.default_rng(6)
    k = 400
    signal_factor = rng.normal(size=(k, 20)) * 3.0
    signal = signal_factor @ signal_factor.T
    draws = [
        signal_factor @ rng.normal(size=20) + rng.normal(0.0, 1.7, k) for _ in range(5)
    ]
    fitted = [evidence_sigma(signal, d) for d in draws]
    assert np.median(fitted) == pytest.approx(1.7, rel=0.08)


def test_sigma_evidence_is_reported_per_frame() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 40, seed=7)
    result = densify(basis, pixels, disparities, sigma="evidence")
    assert 0.1 <= result.sigma <= 20.0
    with pytest.raises(ValueError, match="evidence"):
        densify(basis, pixels, disparities, sigma="auto")


def test_temporal_prior_carries_information_and_resets() -> None:
    basis = _basis()
    rng = np.random.default_rng(8)
    coefficients = rng.normal(size=6) * np.sqrt(basis.eigenvalues)
    truth = basis.mean + np.tensordot(coefficients, basis.components, axes=1)
    state = TemporalPrior(process_noise=0.01)
    errors_static, errors_temporal = [], []
    for frame in range(6):
        pixels, _ = _points(basis, 3, seed=100 + frame)
        rows, cols = pixels[:, 1].astype(int), pixels[:, 0].astype(int)
        disparities = truth[rows, cols] + rng.normal(0, 0.2, 3)
        static = densify(basis, pixels, disparities, sigma=0.2)
        temporal = densify(basis, pixels, disparities, sigma=0.2, temporal=state)
        errors_static.append(np.abs(static.disparity - truth).mean())
        errors_temporal.append(np.abs(temporal.disparity - truth).mean())
        assert temporal.temporal == ("static" if frame == 0 else "temporal")
    assert np.mean(errors_temporal[2:]) < 0.5 * np.mean(errors_static[2:])
    # a different scene fails the innovation test: the static prior comes back
    pixels, _ = _points(basis, 8, seed=200)
    jump = densify(basis, pixels, np.full(8, 300.0), sigma=0.2, temporal=state)
    assert jump.temporal == "reset"
    assert state.resets == 1


def test_a_repeated_frame_is_not_new_evidence_for_the_temporal_prior() -> None:
    """A driver sending its last pair again: bit-identical measurements were folded in as
    independent evidence each time, and the std halved over 30 frames while the error stayed
    (+-2 sigma coverage 93 -> 83 %). A repeat gets the previous frame's prior again."""
    basis = _basis()
    pixels, disparities = _points(basis, 6, seed=400)
    state = TemporalPrior(process_noise=0.01)
    first = densify(basis, pixels, disparities, sigma=1.0, temporal=state)
    second = densify(basis, pixels + 1.0, disparities, sigma=1.0, temporal=state)
    repeats = [densify(basis, pixels + 1.0, disparities, sigma=1.0, temporal=state)
               for _ in range(3)]
    assert first.disparity_std is not None
    assert second.disparity_std is not None
    assert np.median(second.disparity_std) < np.median(first.disparity_std)  # new evidence
    for repeat in repeats:
        assert repeat.temporal == "temporal"
        np.testing.assert_array_equal(repeat.disparity, second.disparity)
        assert repeat.disparity_std is not None
        np.testing.assert_array_equal(repeat.disparity_std, second.disparity_std)
    # new measurements after the repeats: the state is the repeated frame's posterior
    third = densify(basis, pixels + 2.0, disparities, sigma=1.0, temporal=state)
    assert third.temporal == "temporal"
    assert state.frames == 6



def test_frames_without_measurements_are_not_repeats_and_widen_the_std() -> None:
    """A gap in the measurements: each empty frame predicts one step further (the std
    widens), although two empty frames have the same (empty) measurements."""
    basis = _basis()
    pixels, disparities = _points(basis, 6, seed=500)
    state = TemporalPrior(process_noise=0.05)
    densify(basis, pixels, disparities, sigma=1.0, temporal=state)
    empty = np.zeros((0, 2)), np.zeros(0)
    stds = []
    for _ in range(4):
        gap = densify(basis, *empty, sigma=1.0, temporal=state)
        assert gap.disparity_std is not None
        stds.append(float(np.median(gap.disparity_std)))
    assert all(b > a for a, b in itertools.pairwise(stds)), stds

def test_temporal_batch_equals_one_by_one() -> None:
    basis = _basis()
    frames = [_points(basis, 6, seed=300 + i) for i in range(4)]
    one_state, batch_state = TemporalPrior(), TemporalPrior()
    one = [
        densify(basis, p, d, sigma=1.0, temporal=one_state,
                local_prior=LocalPrior(2.0, 3.0))
        for p, d in frames
    ]
    batch = densify_batch(
        basis, [p for p, _ in frames], [d for _, d in frames], sigma=1.0,
        temporal=batch_state, local_prior=LocalPrior(2.0, 3.0),
    )
    for a, b in zip(one, batch, strict=True):
        np.testing.assert_allclose(a.disparity, b.disparity, atol=1e-4)
        assert a.disparity_std is not None
        assert b.disparity_std is not None
        np.testing.assert_allclose(a.disparity_std, b.disparity_std, atol=1e-4)


def test_adding_a_measurement_never_raises_the_hybrid_variance() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 8, seed=9)
    local = LocalPrior(variance=3.0, length_scale=2.5)
    fewer = densify(basis, pixels[:-1], disparities[:-1], local_prior=local, variance_stride=1)
    more = densify(basis, pixels, disparities, local_prior=local, variance_stride=1)
    assert fewer.disparity_std is not None
    assert more.disparity_std is not None
    assert np.all(more.disparity_std <= fewer.disparity_std + 1e-3)


def test_paper_uncertainty_with_a_local_prior_is_refused() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 4, seed=10)
    with pytest.raises(ValueError, match="exact"):
        densify(basis, pixels, disparities, uncertainty="paper",
                local_prior=LocalPrior(1.0, 2.0))


def test_local_prior_validates() -> None:
    with pytest.raises(ValueError, match="length_scale"):
        LocalPrior(variance=1.0, length_scale=0.0)
    with pytest.raises(ValueError, match="variance"):
        LocalPrior(variance=-1.0, length_scale=1.0)
    assert LocalPrior.from_meta(LocalPrior(2.0, 5.0, Kernel.GAUSSIAN).to_meta()) == LocalPrior(
        2.0, 5.0, Kernel.GAUSSIAN
    )


def test_empty_frame_with_every_addition_is_the_prior() -> None:
    basis = _basis()
    result = densify(
        basis, np.zeros((0, 2)), np.zeros(0), sigma="evidence", robust="huber",
        local_prior=LocalPrior(2.0, 3.0), temporal=TemporalPrior(), variance_stride=1,
    )
    np.testing.assert_allclose(result.disparity, basis.mean, atol=1e-4)
    assert result.disparity_std is not None
    np.testing.assert_allclose(
        result.disparity_std**2, basis.prior_variance + 2.0, rtol=1e-3
    )


def _innovation_by_hand(
    basis: Basis, pixels: np.ndarray, disparities: np.ndarray, sigma: float,
    local: LocalPrior | None,
) -> float:
    """z^T K^-1 z / k from the dense prior covariance at the measured pixels."""
    _height, width = basis.image_size
    b = basis.pixel_major.astype(np.float64)
    index = pixels[:, 1].astype(int) * width + pixels[:, 0].astype(int)
    system = b[index] @ np.diag(basis.eigenvalues) @ b[index].T
    if local is not None:
        system += local.matrix(pixels)
    system += sigma**2 * np.eye(len(index))
    innovation = disparities - basis.mean_flat.astype(np.float64)[index]
    return float(innovation @ np.linalg.solve(system, innovation)) / len(index)


@pytest.mark.parametrize("form", ["measurement", "coefficient"])
def test_normalised_innovation_of_the_paper_model(form: str) -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9 if form == "measurement" else 20, seed=11)
    result = densify(basis, pixels, disparities, sigma=1.5, solve_form=form)
    expected = _innovation_by_hand(basis, pixels, disparities, 1.5, None)
    assert result.normalised_innovation == pytest.approx(expected, rel=1e-8)


def test_normalised_innovation_of_the_hybrid_model() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=12)
    local = LocalPrior(variance=4.0, length_scale=3.0)
    result = densify(basis, pixels, disparities, sigma=1.5, local_prior=local)
    expected = _innovation_by_hand(basis, pixels, disparities, 1.5, local)
    assert result.normalised_innovation == pytest.approx(expected, rel=1e-8)


def test_covariance_scale() -> None:
    assert covariance_scale(0.0, 0) == 1.0  # no measurement: the model's own scale
    assert covariance_scale(1.0, 300) == pytest.approx(1.0)
    assert covariance_scale(9.0, 1000) == pytest.approx(9.0, rel=0.01)
    # few points stay near 1
    assert 1.0 < covariance_scale(9.0, 2) < 4.0
    assert covariance_scale(float("nan"), 10) == 1.0


def test_scale_by_innovation_widens_the_std_only() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=13)
    local = LocalPrior(variance=4.0, length_scale=3.0)
    plain = densify(basis, pixels, disparities, sigma=1.5, local_prior=local, std_scale=1.3)
    scaled = densify(
        basis, pixels, disparities, sigma=1.5, local_prior=local, std_scale=1.3,
        scale_by_innovation=True,
    )
    np.testing.assert_array_equal(scaled.disparity, plain.disparity)
    factor = np.sqrt(covariance_scale(plain.normalised_innovation, 9))
    # measurements disagreeing with the prior (a > 1): widened everywhere by sqrt(a)
    assert factor > 1.05  # the test must see a change
    assert scaled.disparity_std is not None
    assert plain.disparity_std is not None
    np.testing.assert_allclose(scaled.disparity_std, plain.disparity_std * factor, rtol=1e-5)


def test_agreeing_measurements_narrow_the_std_only_where_they_reach() -> None:
    """a < 1 narrows the std by the share of the variance the measurements explain.

    Bug hunt 9B F5: a frame whose measurements agreed with the prior (a ~ 0.1) had its whole
    std narrowed by sqrt(a), also where nothing was measured (a sky 6-7 px off held its
    truth within +-2 sigma at 0.1 % of its pixels).
    """
    basis = _basis(height=12, width=48)
    rng = np.random.default_rng(5)
    pixels = np.stack([rng.uniform(0, 12, 30), rng.uniform(0, 12, 30)], axis=1)
    rows = np.clip(pixels.round().astype(int), 0, [47, 11])
    disparities = basis.mean[rows[:, 1], rows[:, 0]] + rng.normal(0.0, 0.05, 30)
    local = LocalPrior(variance=4.0, length_scale=3.0)
    options = dict(sigma=1.0, local_prior=local, std_scale=1.3, uncertainty="exact")
    plain = densify(basis, pixels, disparities, **options)
    scaled = densify(basis, pixels, disparities, scale_by_innovation=True, **options)
    assert plain.disparity_std is not None
    assert scaled.disparity_std is not None
    np.testing.assert_array_equal(scaled.disparity, plain.disparity)
    a = covariance_scale(plain.normalised_innovation, 30)
    assert a < 0.3  # agreeing measurements
    ratio = scaled.disparity_std / plain.disparity_std
    # never narrower than sqrt(a), never wider than the model's own std
    assert ratio.min() >= np.sqrt(a) - 1e-4
    assert ratio.max() <= 1.0 + 1e-4
    # where the measurements are (x < 12): narrowed; far right (x >= 36): about the prior's
    assert np.median(ratio[:, :12]) < 0.8
    assert ratio[:, 36:].min() > 0.9  # (sqrt(a) ~ 0.34 before)


def test_innovation_variance_scale() -> None:
    variance = np.array([0.0, 1.0, 2.0, 4.0, 5.0], np.float32)
    prior = np.full(5, 4.0, np.float32)
    assert innovation_variance_scale(2.5, variance, prior) == 2.5  # a >= 1: as before
    np.testing.assert_allclose(
        innovation_variance_scale(0.2, variance, prior), [0.2, 0.4, 0.6, 1.0, 1.0], rtol=1e-6
    )
    # a prior variance of 0 (nothing to explain): the model's own scale
    zero = np.zeros(1, np.float32)
    assert innovation_variance_scale(0.2, zero, zero)[0] == 1.0


@pytest.mark.parametrize(
    ("kernel", "length_scale", "spacing"),
    [(Kernel.LAPLACE, 64.0, 4.0), (Kernel.LAPLACE, 40.0, 2.0), (Kernel.GAUSSIAN, 10.0, 2.0)],
)
def test_long_local_kernel_on_a_coarser_grid_matches_full_size(
    kernel: Kernel, length_scale: float, spacing: float
) -> None:
    """The local part of a long kernel, computed on a 4x or 2x coarser grid, stays close."""
    small = _basis(height=12, width=16, n_components=6, seed=4)
    # a 12 x 16 grid over a 48 x 64 image; a constant mean and (almost) no basis
    # variance leave the local part alone in the estimate
    basis = Basis(
        mean=np.full((12, 16), 20.0, dtype=np.float32), components=small.components,
        eigenvalues=np.full(6, 1e-9), total_variance=1.0, image_size=(48, 64),
        focal_baseline=100.0, n_train=50,
    )
    rng = np.random.default_rng(5)
    pixels = np.stack([rng.uniform(0, 63, 12), rng.uniform(0, 47, 12)], axis=1)
    disparities = rng.uniform(10.0, 40.0, 12)
    local = LocalPrior(variance=25.0, length_scale=length_scale, kernel=kernel)
    assert local.sample_spacing(4.0) == spacing  # 4 image px per grid px
    result = densify(basis, pixels, disparities, sigma=0.5, local_prior=local)
    alpha = np.linalg.solve(local.matrix(pixels) + 0.25 * np.eye(12), disparities - 20.0)
    ys, xs = np.arange(48.0), np.arange(64.0)
    full = (local.axis(pixels[:, 1], ys).T * (local.variance * alpha)) @ local.axis(
        pixels[:, 0], xs
    )
    error = np.abs(result.disparity - 20.0 - full)
    # the interpolation rounds off each measurement's peak v alpha_j by <= spacing / ell
    cusp = np.abs(local.variance * alpha).max()
    assert error.max() <= spacing / length_scale * cusp
    assert error.mean() < 0.05 * np.abs(full).max()


@pytest.mark.parametrize("local", [None, LocalPrior(variance=4.0, length_scale=3.0)])
def test_per_measurement_noise_equals_dense_gaussian_posterior(local: LocalPrior | None) -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=5)
    noise_std = np.linspace(0.0, 3.0, 9)
    result = densify(
        basis, pixels, disparities, sigma=1.5, local_prior=local, variance_stride=1,
        noise_std=noise_std,
    )
    # R_j = sigma^2 + s_j^2 = sigma^2 / w_j
    weights = 1.5**2 / (1.5**2 + noise_std**2)
    _assert_matches(result, _brute_force(basis, pixels, disparities, 1.5, local, weights))


def test_zero_per_measurement_noise_is_the_plain_estimate() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=6)
    plain = densify(basis, pixels, disparities, sigma=1.5)
    noisy = densify(basis, pixels, disparities, sigma=1.5, noise_std=np.zeros(9))
    np.testing.assert_allclose(noisy.disparity, plain.disparity, atol=1e-4)
    assert noisy.disparity_std is not None
    assert plain.disparity_std is not None
    np.testing.assert_allclose(noisy.disparity_std, plain.disparity_std, atol=1e-4)


def test_per_measurement_noise_follows_dropped_measurements() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=7)
    disparities[2] = np.nan
    noise_std = np.full(9, 1.0)
    noise_std[2] = 0.0
    result = densify(basis, pixels, disparities, sigma=1.0, noise_std=noise_std)
    kept = np.delete(np.arange(9), 2)
    expected = densify(
        basis, pixels[kept], disparities[kept], sigma=1.0, noise_std=noise_std[kept]
    )
    assert result.n_dropped == 1
    np.testing.assert_allclose(result.disparity, expected.disparity, atol=1e-5)


@pytest.mark.parametrize(
    ("noise_std", "match"),
    [(np.ones(3), "`noise_std` of shape"), (np.full(9, -1.0), "finite and >= 0")],
)
def test_per_measurement_noise_validates(noise_std: np.ndarray, match: str) -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=8)
    with pytest.raises(ValueError, match=match):
        densify(basis, pixels, disparities, noise_std=noise_std)


def test_short_kernel_local_map_in_blocks_equals_the_full_product(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pcainterp_stream.estimate import solve

    rng = np.random.default_rng(9)
    local = solve._Local(
        prior=LocalPrior(variance=2.0, length_scale=4.0, kernel=Kernel.GAUSSIAN),
        positions=rng.uniform([0.0, 0.0], [600.0, 200.0], (150, 2)),
        alpha=rng.normal(size=150),
        lower_inverse=None,
        prior_rows=None,
    )
    blocked = solve._local_mean(local, (100, 300), (200, 600), 1.0)
    monkeypatch.setattr(solve, "_LOCAL_BLOCKS", 1)
    full = solve._local_mean(local, (100, 300), (200, 600), 1.0)
    assert np.abs(full).max() > 0.5
    np.testing.assert_allclose(blocked, full, atol=1e-6)


@pytest.mark.parametrize("offset", [300.0, 19_000.0])
def test_a_trimmed_start_leaves_a_far_point_out_where_the_plain_one_follows_it(
    offset: float,
) -> None:
    # a feature stream's triangulation failure: one of 200 points hundreds of px off; with
    # the fitted noise (0.1 px) the plain start's Cauchy weight still trusted it to a few
    # px (71 px off the map without it), and at 19,000 px it down-weighted the good points
    basis = _basis(height=48, width=64)
    rng = np.random.default_rng(3)
    truth = basis.mean + np.tensordot(
        rng.normal(size=6) * np.sqrt(basis.eigenvalues), basis.components, axes=1
    )
    pixels = np.stack([rng.integers(0, 64, 200), rng.integers(0, 48, 200)], axis=1).astype(float)
    measured = truth[pixels[:, 1].astype(int), pixels[:, 0].astype(int)] + rng.normal(0, 0.1, 200)
    options = {"sigma": 0.1, "local_prior": LocalPrior(variance=40.0, length_scale=8.0)}
    without = densify(basis, pixels[1:], measured[1:], robust="cauchy", **options)  # type: ignore[arg-type]
    bad = measured.copy()
    bad[0] += offset

    def solve(start: str) -> DensifyResult:
        return densify(basis, pixels, bad, robust="cauchy", robust_start=start, **options)  # type: ignore[arg-type]

    plain, trimmed = solve("plain"), solve("trimmed")
    # the plain start follows the point (300 px) or down-weights the good ones (19,000 px)
    assert np.abs(plain.disparity - without.disparity).max() > 20.0 or plain.n_downweighted > 50
    np.testing.assert_allclose(trimmed.disparity, without.disparity, atol=1e-3)
    assert trimmed.weights is not None
    assert trimmed.weights[0] < 1e-9
    assert trimmed.n_downweighted <= 2
    # a frame without an outlier is not reweighted by either start
    clean = densify(
        basis, pixels, measured, robust="cauchy", robust_start=RobustStart.TRIMMED, **options  # type: ignore[arg-type]
    )
    assert clean.weights is not None
    np.testing.assert_array_equal(clean.weights, 1.0)
