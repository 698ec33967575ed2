"""Evidence fits of the hybrid prior and the temporal process noise; learn --fit-prior."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.cli import main
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.fitting import (
    FitFrame,
    fit_local_prior,
    fit_process_noise,
    fit_std_scale,
)
from pcainterp_stream.estimate.prior import Kernel, LocalPrior
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.pipeline import jobs


def _tiny_basis(n_components: int = 3) -> Basis:
    height, width = 20, 30
    ys, xs = np.mgrid[0:height, 0:width] / 30.0
    fields = [np.ones_like(xs), xs - xs.mean(), ys - ys.mean()][:n_components]
    q, _ = np.linalg.qr(np.stack([f.ravel() for f in fields], axis=1))
    return Basis(
        mean=np.full((height, width), 20.0, dtype=np.float32),
        components=q.T.reshape(n_components, height, width).astype(np.float32),
        eigenvalues=np.array([400.0, 100.0, 50.0][:n_components]),
        total_variance=600.0,
        image_size=(height, width),
        focal_baseline=100.0,
        n_train=10,
    )


def _draw_frames(
    basis: Basis, local: LocalPrior, sigma: float, n_frames: int, k: int, seed: int
) -> list[FitFrame]:
    """Frames whose residuals are exact draws of the hybrid model."""
    rng = np.random.default_rng(seed)
    height, width = basis.image_size
    frames = []
    for _ in range(n_frames):
        positions = np.stack(
            [rng.uniform(0, width - 1, k), rng.uniform(0, height - 1, k)], axis=1
        )
        flat = (np.round(positions[:, 1]) * width + np.round(positions[:, 0])).astype(int)
        positions = np.stack([flat % width, flat // width], axis=1).astype(np.float64)
        rows = basis.pixel_major[flat].astype(np.float64)
        covariance = (rows * basis.eigenvalues) @ rows.T + local.matrix(positions)
        covariance += sigma**2 * np.eye(k)
        residual = np.linalg.cholesky(covariance) @ rng.normal(size=k)
        frames.append(FitFrame(rows=rows, residual=residual, positions=positions))
    return frames


def test_fit_recovers_the_generating_kernel() -> None:
    basis = _tiny_basis()
    truth = LocalPrior(variance=9.0, length_scale=4.0, kernel=Kernel.LAPLACE)
    frames = _draw_frames(basis, truth, sigma=0.8, n_frames=12, k=80, seed=1)
    fit = fit_local_prior(basis, frames, length_scales=(1.0, 4.0, 16.0))
    assert fit.local is not None
    assert fit.local.length_scale == 4.0
    assert fit.local.kernel is Kernel.LAPLACE
    assert fit.local.variance == pytest.approx(9.0, rel=0.35)
    assert fit.sigma == pytest.approx(0.8, rel=0.3)
    assert fit.log_evidence > fit.plain_log_evidence
    assert len(fit.table) == 1 + 2 * 3


def test_fixed_kernel_fits_sigma_only() -> None:
    """A fixed kernel is kept as given; sigma is still fitted by the evidence under it."""
    basis = _tiny_basis()
    truth = LocalPrior(variance=9.0, length_scale=4.0, kernel=Kernel.LAPLACE)
    frames = _draw_frames(basis, truth, sigma=0.8, n_frames=12, k=80, seed=1)
    fixed = LocalPrior(variance=9.0, length_scale=4.0, kernel=Kernel.LAPLACE)
    fit = fit_local_prior(basis, frames, fixed=fixed)
    assert fit.local == fixed
    assert fit.sigma == pytest.approx(0.8, rel=0.3)
    assert len(fit.table) == 2  # the paper's prior and the fixed kernel
    # a kernel far too wide and strong: the evidence is lower, sigma still found
    wrong = fit_local_prior(basis, frames, fixed=LocalPrior(900.0, 64.0, Kernel.GAUSSIAN))
    assert wrong.log_evidence < fit.log_evidence


def test_fit_keeps_the_paper_prior_when_there_is_no_local_part() -> None:
    basis = _tiny_basis()
    frames = _draw_frames(basis, LocalPrior(0.0, 4.0), sigma=1.0, n_frames=8, k=60, seed=2)
    fit = fit_local_prior(basis, frames, length_scales=(2.0, 8.0))
    # the best local variance is (close to) zero: no meaningful gain in evidence
    assert fit.local is None or fit.local.variance < 0.3
    assert fit.plain_sigma == pytest.approx(1.0, rel=0.15)


def test_fit_needs_measurements() -> None:
    basis = _tiny_basis()
    empty = FitFrame(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2)))
    with pytest.raises(ValueError, match="at least one frame"):
        fit_local_prior(basis, [empty])


def test_process_noise_prefers_small_noise_for_a_static_scene() -> None:
    basis = _tiny_basis()
    rng = np.random.default_rng(3)
    coefficients = rng.normal(size=3) * np.sqrt(basis.eigenvalues)
    sequence = []
    for _ in range(8):
        index = rng.choice(20 * 30, 6, replace=False)
        rows = basis.pixel_major[index].astype(np.float64)
        positions = np.stack([index % 30, index // 30], axis=1).astype(np.float64)
        residual = rows @ coefficients + rng.normal(0, 0.3, 6)
        sequence.append(FitFrame(rows, residual, positions))
    best, scores = fit_process_noise(
        basis, [sequence], local=None, sigma=0.3, candidates=(0.001, 0.1, 1.0)
    )
    assert best == 0.001
    assert scores[0.001] > scores[1.0]


@pytest.mark.slow
def test_learn_fit_prior_then_densify_uses_it(tmp_path: Path) -> None:
    train, test = tmp_path / "train.mcap", tmp_path / "test.mcap"
    jobs.synth(train, frames=20, seed=21, scale=0.25, fmt="mcap")
    jobs.synth(test, frames=4, seed=22, scale=0.25, fmt="mcap")
    basis_path = tmp_path / "basis.npz"
    assert main(["learn", str(train), "-o", str(basis_path), "--components", "10",
                 "--fit-prior", "--holdout", "0.25", "--with-synthetic", "0"]) == 0
    basis = Basis.load(basis_path)
    assert basis.n_train == 15  # 5 of 20 frames held out for the fit
    prior = basis.meta["prior"]
    assert prior["held_out_frames"] == 5
    assert prior["sigma"] > 0
    assert prior["process_noise"] > 0
    assert prior["std_scale"] > 0
    assert prior["innovation_std_scale"] > 0
    assert {row["kernel"] for row in prior["candidates"]} == {"none", "laplace", "gaussian"}
    out = tmp_path / "dense.mcap"
    assert main(["densify", str(test), "-o", str(out), "--basis", str(basis_path),
                 "--robust", "cauchy", "--temporal"]) == 0
    summary = jobs.densify(
        test, tmp_path / "dense2.mcap", basis_path,
        processor=jobs.ProcessorConfig(robust="huber", temporal=True, prior="auto"),
    )
    assert summary.frames == 4
    assert summary.temporal_resets >= 0
    assert summary.downweighted >= 0


def test_fit_prior_with_fit_logs_uses_every_frame_of_them(tmp_path: Path) -> None:
    train, fit_log = tmp_path / "train.mcap", tmp_path / "fit.mcap"
    jobs.synth(train, frames=8, seed=31, scale=0.25, fmt="mcap")
    jobs.synth(fit_log, frames=3, seed=32, scale=0.25, fmt="mcap")
    options = jobs.LearnOptions(
        n_components=5, depth_topic="/ground_truth/depth", fit_prior=True, fit_logs=(fit_log,)
    )
    basis = jobs.learn([train], tmp_path / "b.npz", options, PairingConfig())
    assert basis.n_train == 8
    assert basis.meta["prior"]["held_out_frames"] == 3


def test_prior_hybrid_without_a_fitted_basis_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "log.mcap"
    jobs.synth(log, frames=3, seed=41, scale=0.25, fmt="mcap")
    basis_path = tmp_path / "basis.npz"
    options = jobs.LearnOptions(n_components=2, fit_prior=False)
    jobs.learn([log], basis_path, options, PairingConfig())
    code = main(["densify", str(log), "-o", str(tmp_path / "o.mcap"), "--basis",
                 str(basis_path), "--prior", "hybrid"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "--no-fit-prior" in err[0]
    assert "pcainterp learn" in err[0]
    assert not (tmp_path / "o.mcap").exists()


def test_std_scale_puts_95_percent_inside_two_std() -> None:
    rng = np.random.default_rng(5)
    reference = rng.normal(size=(50, 60))
    estimate = np.zeros_like(reference)
    std = np.full_like(reference, 0.5)  # the true spread is 1: twice too confident
    reference[0, :5] = np.nan
    scale = fit_std_scale([estimate], [std], [reference])
    assert scale == pytest.approx(2.0, rel=0.05)
    inside = np.abs(reference - estimate) <= 2 * scale * std
    assert np.nanmean(inside[np.isfinite(reference)]) == pytest.approx(0.954, abs=0.005)
    assert fit_std_scale([], [], []) == 1.0


def test_std_scale_multiplies_the_reported_std() -> None:
    from pcainterp_stream import densify

    basis = _tiny_basis()
    pixels = np.array([[3.0, 4.0], [20.0, 10.0]])
    plain = densify(basis, pixels, [25.0, 30.0])
    scaled = densify(basis, pixels, [25.0, 30.0], std_scale=1.5)
    assert plain.disparity_std is not None
    assert scaled.disparity_std is not None
    np.testing.assert_allclose(scaled.disparity_std, 1.5 * plain.disparity_std, rtol=1e-5)
    np.testing.assert_array_equal(scaled.disparity, plain.disparity)
    with pytest.raises(ValueError, match="std_scale"):
        densify(basis, pixels, [25.0, 30.0], std_scale=0.0)


def test_resolve_settings_calibrates_as_the_fit_did() -> None:
    from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings

    basis = _tiny_basis()
    fitted = {
        "local": {"variance": 2.0, "length_scale": 8.0, "kernel": "laplace"},
        "sigma": 0.5, "std_scale": 1.2, "innovation_std_scale": 0.9,
    }
    with_both = dataclasses.replace(basis, meta={"prior": fitted})
    settings = resolve_settings(with_both, ProcessorConfig())
    assert settings.scale_by_innovation
    assert settings.std_scale == 0.9
    # a basis fitted before the per-frame scale existed keeps its plain factor
    older = {k: v for k, v in fitted.items() if k != "innovation_std_scale"}
    older_basis = dataclasses.replace(basis, meta={"prior": older})
    settings = resolve_settings(older_basis, ProcessorConfig())
    assert not settings.scale_by_innovation
    assert settings.std_scale == 1.2
    settings = resolve_settings(with_both, ProcessorConfig(calibrate=False))
    assert not settings.scale_by_innovation
    assert settings.std_scale == 1.0
    settings = resolve_settings(with_both, ProcessorConfig(prior="paper"))
    assert not settings.scale_by_innovation
    assert settings.std_scale == 1.0


def test_resolve_settings_widens_the_std_near_sgbms_range_in_sparse_stereo_mode() -> None:
    from pcainterp_stream.frontend.stereo import SgbmConfig
    from pcainterp_stream.pipeline.processor import (
        MeasurementSource,
        ProcessorConfig,
        resolve_settings,
    )

    basis = _tiny_basis()
    assert resolve_settings(basis, ProcessorConfig()).match_range == 128
    assert resolve_settings(basis, ProcessorConfig()).densify_options()["match_range"] == 128
    narrow = ProcessorConfig(sgbm=SgbmConfig(num_disparities=64, downscale=2))
    assert resolve_settings(basis, narrow).match_range == 64
    # a range that is no multiple of 32 is matched at half resolution as the next one up
    odd = ProcessorConfig(sgbm=SgbmConfig(num_disparities=80, downscale=2))
    assert resolve_settings(basis, odd).match_range == 96
    full = ProcessorConfig(sgbm=SgbmConfig(num_disparities=96, min_disparity=8))
    assert resolve_settings(basis, full).match_range == 104
    # dense mode fuses SGBM's map itself; a feature stream's points have no known range
    assert resolve_settings(basis, ProcessorConfig(measurements="dense")).match_range is None
    features = ProcessorConfig(source=MeasurementSource.FEATURES)
    assert resolve_settings(basis, features).match_range is None


def test_densify_keeps_its_own_sgbm_zero_matches_where_the_library_drops_them() -> None:
    """SGBM with minDisparity 0 returns 0 for a match at zero disparity: densify's front end
    passes such lookups, and its estimate, fit check and prior fit keep them (its output is
    what it was); the library's default takes a 0 for the invalid code of a disparity image.
    """
    from pcainterp_stream.estimate.estimator import densify
    from pcainterp_stream.estimate.fitting import fit_frame
    from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings

    basis = _tiny_basis()
    options = resolve_settings(basis, ProcessorConfig()).densify_options()
    assert options["zero_is_match"] is True
    pixels = np.array([[3.0, 4.0], [10.0, 12.0], [20.0, 5.0], [25.0, 15.0]])
    values = np.array([20.0, 0.0, 18.0, 22.0])
    assert densify(basis, pixels, values, **options).n_dropped == 0
    assert densify(basis, pixels, values).n_dropped == 1
    assert fit_frame(basis, pixels, values).residual.size == 4

