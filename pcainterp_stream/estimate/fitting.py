"""Fit the hyperparameters of the estimate by the evidence (type-II maximum likelihood).

The marginal likelihood of a frame's sparse measurements under the hybrid prior is

    log p(z) = log N(z~; 0, K),   K = B~ Lambda B~^T + v C_ell(P, P) + sigma^2 I

(``prior.py``); summed over training frames it is maximised over the local variance v, the
length scale ell, the kernel shape and the noise sigma. The process noise q of the temporal
prior maximises the summed one-step predictive likelihoods of frame sequences. The frames
must not be among the basis's training maps: a basis reproduces its own training maps, so
on them the basis misses nothing and the fit would find no local part.

Maths only: the measurements come in as arrays (the log side is in ``jobs``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis, bilinear_weights, image_to_grid, sample_rows
from pcainterp_stream.estimate.estimator import clean_measurements
from pcainterp_stream.estimate.prior import Kernel, LocalPrior, TemporalPrior, covariance_scale
from pcainterp_stream.estimate.solve import triangular_lapack

FloatArray = npt.NDArray[np.float64]

LENGTH_SCALES = (4.0, 8.0, 16.0, 32.0, 64.0, 128.0)
"""Length scales (basis image px) tried by :func:`fit_local_prior`."""

PROCESS_NOISES = (0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
"""Process noise fractions tried by :func:`fit_process_noise`."""


@dataclass(frozen=True, eq=False)
class FitFrame:
    """One frame's measurements on the basis.

    Attributes:
        rows: (k, l) float64, B~, the basis sampled at the measurements.
        residual: (k,) float64, z~ = z - m~ in basis disparity units (px).
        positions: (k, 2) float64, (x, y) in basis image px.
    """

    rows: FloatArray
    residual: FloatArray
    positions: FloatArray


def fit_frame(
    basis: Basis,
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    image_size: tuple[int, int] | None = None,
    focal_baseline: float | None = None,
    max_points: int | None = None,
) -> FitFrame:
    """Map one frame's measurements onto the basis for fitting.

    Args:
        basis: the PCA basis.
        pixels: (k, 2) float, (x, y) in px of ``image_size``.
        disparities: (k,) float (px) of a camera with ``focal_baseline``.
        image_size: (height, width) of the measurements' camera (default: the basis's).
        focal_baseline: f*b of that camera (default: the basis's).
        max_points: keep at most this many (the first ones), to bound the cost.

    Returns:
        The :class:`FitFrame`.
    """
    size = basis.image_size if image_size is None else image_size
    fb = basis.focal_baseline if focal_baseline is None else focal_baseline
    to_basis = basis.focal_baseline / fb if basis.focal_baseline > 0 and fb > 0 else 1.0
    # the front end's measurements: SGBM's 0 is a match (estimator.densify, zero_is_match)
    kept_pixels, kept_disparities, _ = clean_measurements(
        pixels, disparities, size, zero_is_match=True
    )
    if max_points is not None:
        kept_pixels, kept_disparities = kept_pixels[:max_points], kept_disparities[:max_points]
    indices, weights = bilinear_weights(
        image_to_grid(kept_pixels, size, basis.grid_size), basis.grid_size
    )
    rows = sample_rows(basis.pixel_major, indices, weights).astype(np.float64)
    mean_at = (basis.mean_flat[indices] * weights).sum(axis=1)
    return FitFrame(
        rows=rows,
        residual=kept_disparities * to_basis - mean_at,
        positions=image_to_grid(kept_pixels, size, basis.image_size),
    )


def _log_evidence(system: FloatArray, innovation: FloatArray) -> float:
    """Return log N(innovation; 0, system) via Cholesky; -inf if not positive definite."""
    lapack = triangular_lapack()
    lower, info = lapack.dpotrf(system, lower=1, clean=1)
    if info != 0:
        return -math.inf
    solved, info = lapack.dtrtrs(lower, innovation, lower=1)
    return float(
        -0.5 * solved @ solved
        - np.log(np.diag(lower)).sum()
        - 0.5 * innovation.size * math.log(2.0 * math.pi)
    )


@dataclass(frozen=True)
class LocalFit:
    """The result of :func:`fit_local_prior`.

    Attributes:
        local: the fitted local prior (None when the plain prior had the best evidence).
        sigma: the fitted noise std (px).
        log_evidence: summed log evidence of the best fit (nats).
        plain_sigma: the noise std fitted with the paper's prior alone (px).
        plain_log_evidence: its summed log evidence (nats).
        table: every candidate tried: kernel, length scale, v, sigma, log evidence.
    """

    local: LocalPrior | None
    sigma: float
    log_evidence: float
    plain_sigma: float
    plain_log_evidence: float
    table: list[dict[str, Any]]

    def to_meta(self) -> dict[str, Any]:
        """Return the JSON form stored in a basis's ``meta["prior"]``."""
        return {
            "local": None if self.local is None else self.local.to_meta(),
            "sigma": self.sigma,
            "log_evidence": self.log_evidence,
            "plain_sigma": self.plain_sigma,
            "plain_log_evidence": self.plain_log_evidence,
        }


MIN_SIGMA = 0.1
"""Smallest noise std (px) the fit may choose: SGBM disparities are 1/16 px steps, and
without a floor the local kernel absorbs the noise and sigma runs to 0 (K singular)."""


def _maximise(
    objective: Any, start: Sequence[float], *, tolerance: float = 0.05
) -> tuple[FloatArray, float]:
    """Maximise over log-parameters with Nelder-Mead (scipy.optimize)."""
    from scipy.optimize import minimize

    x0 = np.asarray(start, dtype=np.float64)
    # steps of 1 in log space (a factor e): scipy's default simplex (5 % of each value) can be
    # smaller than the tolerance and end the search where it started
    simplex = np.vstack([x0, x0 + np.eye(x0.size)])
    result = minimize(
        lambda x: -objective(x),
        x0,
        method="Nelder-Mead",
        options={
            "xatol": tolerance,
            "fatol": 0.5,
            "maxiter": 200,
            "initial_simplex": simplex,
        },
    )
    return np.asarray(result.x, dtype=np.float64), float(-result.fun)


def fit_local_prior(
    basis: Basis,
    frames: Sequence[FitFrame],
    *,
    kernels: Sequence[Kernel | str] = (Kernel.LAPLACE, Kernel.GAUSSIAN),
    length_scales: Sequence[float] = LENGTH_SCALES,
    fixed: LocalPrior | None = None,
) -> LocalFit:
    """Fit the hybrid prior's local kernel and the noise level by maximising the evidence.

    For every kernel and length scale, log v and log sigma are found by Nelder-Mead on the
    summed log evidence; the best (kernel, ell, v, sigma) wins. The paper's prior with only
    sigma fitted is the reference (``plain_*``).

    Args:
        basis: the PCA basis.
        frames: training frames that are **not** among the basis's training maps.
        kernels: kernel shapes to try.
        length_scales: length scales to try (basis image px).
        fixed: use this kernel (shape, length scale and v) as it is and fit only sigma
            under it: for a basis whose fit frames are not like the data it will meet
            (the built-in basis: synthetic frames, used on real streets).

    Returns:
        The :class:`LocalFit`.

    Raises:
        ValueError: no frame has a measurement.
    """
    usable = [frame for frame in frames if frame.residual.size]
    if not usable:
        raise ValueError("Expected at least one frame with measurements to fit the prior")
    signals = [(f.rows * basis.eigenvalues) @ f.rows.T for f in usable]
    scale = float(np.median([np.median(np.diag(s)) for s in signals]))

    floor = math.log(MIN_SIGMA)

    def plain(log_sigma: FloatArray) -> float:
        variance = math.exp(2.0 * max(log_sigma[0], floor))
        total = 0.0
        for signal, frame in zip(signals, usable, strict=True):
            system = signal.copy()
            system.flat[:: signal.shape[0] + 1] += variance
            total += _log_evidence(system, frame.residual)
        return total

    plain_x, plain_evidence = _maximise(plain, [math.log(2.0)])
    plain_x[0] = max(plain_x[0], floor)
    table: list[dict[str, Any]] = [
        {
            "kernel": "none",
            "length_scale": None,
            "variance": 0.0,
            "sigma": math.exp(plain_x[0]),
            "log_evidence": plain_evidence,
        }
    ]
    best: tuple[float, LocalPrior | None, float] = (plain_evidence, None, math.exp(plain_x[0]))
    if fixed is not None:
        matrices = [fixed.matrix(f.positions) for f in usable]

        def with_fixed(x: FloatArray) -> float:
            noise = math.exp(2.0 * max(x[0], floor))
            total = 0.0
            for signal, matrix, frame in zip(signals, matrices, usable, strict=True):
                system = signal + matrix  # C_pp with v included
                system.flat[:: signal.shape[0] + 1] += noise
                total += _log_evidence(system, frame.residual)
            return total

        x, evidence = _maximise(with_fixed, [plain_x[0]])
        sigma = math.exp(max(x[0], floor))
        table.append({**fixed.to_meta(), "sigma": sigma, "log_evidence": evidence})
        best = (evidence, fixed, sigma)
        kernels = ()  # nothing else to try
    for kernel in kernels:
        # every other length scale first, then the neighbours of the best of those
        coarse = list(length_scales[::2])
        tried: dict[float, float] = {}
        queue = list(coarse)
        while queue:
            length_scale = queue.pop(0)
            shape = LocalPrior(1.0, length_scale, Kernel(kernel))
            kernel_matrices = [shape.matrix(f.positions) for f in usable]

            def hybrid(x: FloatArray, kernel_matrices: list[FloatArray] = kernel_matrices) -> float:
                local_variance, noise = math.exp(x[0]), math.exp(2.0 * max(x[1], floor))
                total = 0.0
                for signal, matrix, frame in zip(signals, kernel_matrices, usable, strict=True):
                    system = signal + local_variance * matrix
                    system.flat[:: signal.shape[0] + 1] += noise
                    total += _log_evidence(system, frame.residual)
                return total

            x, evidence = _maximise(hybrid, [math.log(0.1 * scale + 1.0), plain_x[0]])
            x[1] = max(x[1], floor)
            local = LocalPrior(math.exp(x[0]), length_scale, Kernel(kernel))
            table.append(
                {
                    "kernel": Kernel(kernel).value,
                    "length_scale": length_scale,
                    "variance": local.variance,
                    "sigma": math.exp(x[1]),
                    "log_evidence": evidence,
                }
            )
            if evidence > best[0]:
                best = (evidence, local, math.exp(x[1]))
            tried[length_scale] = evidence
            if not queue and len(tried) == len(coarse):
                peak = length_scales.index(max(tried, key=lambda ell: tried[ell]))
                queue = [
                    length_scales[i]
                    for i in (peak - 1, peak + 1)
                    if 0 <= i < len(length_scales) and length_scales[i] not in tried
                ]
    return LocalFit(
        local=best[1],
        sigma=best[2],
        log_evidence=best[0],
        plain_sigma=math.exp(plain_x[0]),
        plain_log_evidence=plain_evidence,
        table=table,
    )


CELL_WEIGHTS = (0.0, 0.1, 0.25, 0.4, 0.5, 0.6, 0.75, 0.9, 1.0)
"""Cell weights w tried by :func:`fit_cell_weight` (1: the stationary kernel)."""


def fit_cell_weight(
    basis: Basis,
    frames: Sequence[FitFrame],
    point_cells: Sequence[npt.NDArray[np.int64]],
    *,
    local: LocalPrior,
    sigma: float,
    candidates: Sequence[float] = CELL_WEIGHTS,
) -> tuple[float, dict[float, float]]:
    """Fit the edge-aware kernel's cell weight w by the evidence, the kernel and sigma kept.

    Each candidate's summed log evidence log N(z~; 0, B~ Lambda B~^T + C_pp(w) + sigma^2 I)
    over the frames, C_pp(w) = v k(p_i - p_j) [w + (1 - w) 1{same cell}] (:mod:`cells`).

    Args:
        basis: the PCA basis.
        frames: frames that are not among the basis's training maps (:func:`fit_frame`).
        point_cells: (k_f,) the cells of each frame's measurements, in the same order.
        local: the local kernel (its shape, length scale and v are kept).
        sigma: the noise std (px).
        candidates: cell weights in [0, 1] to try.

    Returns:
        The best w and the summed log evidence (nats) of every candidate.

    Raises:
        ValueError: no frame has a measurement, or the cells do not match the frames.
    """
    if len(point_cells) != len(frames):
        raise ValueError(
            f"Expected one `point_cells` array per frame ({len(frames)}), got {len(point_cells)}"
        )
    usable = [
        (frame, cells)
        for frame, cells in zip(frames, point_cells, strict=True)
        if frame.residual.size
    ]
    if not usable:
        raise ValueError("Expected at least one frame with measurements to fit the cell weight")
    signals = [(frame.rows * basis.eigenvalues) @ frame.rows.T for frame, _ in usable]
    scores: dict[float, float] = {}
    for weight in candidates:
        prior = LocalPrior(local.variance, local.length_scale, local.kernel, cell_weight=weight)
        total = 0.0
        for signal, (frame, cells) in zip(signals, usable, strict=True):
            if cells.shape != frame.residual.shape:
                raise ValueError(
                    f"Expected `point_cells` of shape {frame.residual.shape}, got {cells.shape}"
                )
            system = signal + prior.matrix(frame.positions, cells)
            system.flat[:: system.shape[0] + 1] += sigma**2
            total += _log_evidence(system, frame.residual)
        scores[float(weight)] = total
    best = max(scores, key=lambda weight: scores[weight])
    return best, scores


def fit_process_noise(
    basis: Basis,
    sequences: Sequence[Sequence[FitFrame]],
    *,
    local: LocalPrior | None,
    sigma: float,
    candidates: Sequence[float] = PROCESS_NOISES,
    reset_threshold: float = 3.0,
) -> tuple[float, dict[float, float]]:
    """Fit the temporal prior's process noise q by the one-step predictive likelihood.

    Each sequence is filtered with the temporal prior (its first frame with the static
    prior); the log evidence of every later frame under its predicted prior is summed.

    Args:
        basis: the PCA basis.
        sequences: consecutive frames (not in the basis's training maps), one list per log.
        local: the local prior used with it (or None).
        sigma: the noise std (px).
        candidates: process noise fractions to try.
        reset_threshold: the temporal prior's innovation test.

    Returns:
        The best q and the summed log evidence of every candidate.
    """
    from pcainterp_stream.estimate.prior import Model
    from pcainterp_stream.estimate.solve import _solve_beyond

    model = Model(sigma=sigma, local=local)
    eigenvalues = basis.eigenvalues
    scores: dict[float, float] = {}
    for q in candidates:
        total = 0.0
        for sequence in sequences:
            state = TemporalPrior(process_noise=q, reset_threshold=reset_threshold)
            for frame in sequence:
                predicted = state.predict(eigenvalues)
                if predicted is not None and frame.residual.size:
                    mean, variance = predicted
                    innovation = frame.residual - frame.rows @ mean
                    system = (frame.rows * variance) @ frame.rows.T
                    if local is not None:
                        system += local.matrix(frame.positions)
                    system.flat[:: system.shape[0] + 1] += sigma**2
                    total += _log_evidence(system, innovation)
                _solve_beyond(
                    frame.rows,
                    frame.residual,
                    frame.positions,
                    eigenvalues,
                    model,
                    state,
                    need_factor=False,
                )
        scores[q] = total
    best = max(scores, key=lambda q: scores[q])
    return best, scores


COVERAGE_TARGET = 0.954
"""Share of reference pixels the calibrated +-2 std band should hold (a Gaussian's)."""


def fit_std_scale(
    estimates: Sequence[FloatArray | npt.NDArray[np.float32]],
    stds: Sequence[FloatArray | npt.NDArray[np.float32]],
    references: Sequence[FloatArray | npt.NDArray[np.float32]],
) -> float:
    """Return the factor on the posterior std that puts 95.4 % of errors inside +-2 std.

    The posterior only knows the model (basis, kernel, Gaussian noise); what the model gets
    wrong on real data shows up as errors outside the band. One factor, fitted on held-out
    frames with a dense reference, calibrates the band there: s = q_0.954(|e| / std) / 2.

    Args:
        estimates: per frame (H, W) estimated disparity (px).
        stds: per frame (H, W) posterior std (px).
        references: per frame (H, W) reference disparity (px), NaN where unknown.

    Returns:
        The factor s (1 when no pixel is usable).
    """
    ratios = []
    for estimate, std, reference in zip(estimates, stds, references, strict=True):
        valid = np.isfinite(reference) & np.isfinite(estimate) & (std > 0)
        ratios.append(np.abs(estimate[valid] - reference[valid]) / std[valid])
    joined = np.concatenate(ratios) if ratios else np.zeros(0)
    if joined.size == 0:
        return 1.0
    return float(np.quantile(joined, COVERAGE_TARGET) / 2.0)


ABSURD_STD_SCALE = 1e3
"""A fitted std scale above this says the basis's own posterior std is degenerate.

Fitted scales of usable bases: 0.67-1.8 (the built-in ones), 4-37 (a log's own basis, whose
one or few components leave the posterior std narrow; 37.4 brought a flat wall's std from 4
to 99 % coverage). A basis learned from two EuRoC maps on dense mode's lattice fitted 2.94e7
(its local kernel 3.9e-15 px^2): its std is then that one factor times a number ~0."""


def fitted_std_scale(fitted: dict[str, Any], hybrid: bool) -> tuple[float, bool]:
    """Return the std scale a basis's fitted prior gives, and whether it is per frame.

    The scale was fitted with the basis's own fitted prior (its local kernel, or the paper's
    prior when the evidence preferred it): it applies when the estimate uses that prior
    (``hybrid``: with a local kernel), else 1 (``--prior paper`` on a hybrid fit). The
    second value: the scale multiplies each frame's covariance scale too
    (``innovation_std_scale``; bases fitted before it existed have only the plain factor).

    Examples:
        >>> fitted_std_scale({"local": None, "std_scale": 37.4}, hybrid=False)
        (37.4, False)
        >>> fitted_std_scale({"local": {"variance": 1.0}, "std_scale": 0.7}, hybrid=False)
        (1.0, False)
    """
    if hybrid != bool(fitted.get("local")):
        return 1.0, False
    per_frame = "innovation_std_scale" in fitted
    key = "innovation_std_scale" if per_frame else "std_scale"
    return float(fitted.get(key, 1.0)), per_frame


class CalibrationFrame(NamedTuple):
    """A held-out frame with a dense reference, for :func:`fit_std_scale`.

    Attributes:
        pixels: (k, 2) float, (x, y) px of the frame's camera.
        disparities: (k,) float, measured disparities (px).
        image_size: (height, width) of the frame's camera.
        focal_baseline: f*b of the frame's camera (px*m).
        reference: (H, W) float reference disparity (px), NaN where unknown.
    """

    pixels: npt.ArrayLike
    disparities: npt.ArrayLike
    image_size: tuple[int, int]
    focal_baseline: float
    reference: npt.ArrayLike


def fit_prior(
    basis: Basis,
    sequences: Sequence[Sequence[FitFrame]],
    calibration: Sequence[CalibrationFrame],
    *,
    max_frames: int,
    sequence_frames: int,
    robust: str,
    local: LocalPrior | None = None,
) -> dict[str, Any]:
    """Fit everything ``densify`` takes from a basis, on frames the basis did not see.

    The local kernel and sigma by the evidence of up to ``max_frames`` frames spread over
    the sequences (:func:`fit_local_prior`), the process noise on the first
    ``sequence_frames`` of each sequence (:func:`fit_process_noise`), and the std scale on
    the calibration frames densified as ``densify`` would (hybrid prior, fitted sigma,
    ``robust`` loss; :func:`fit_std_scale`), once for the posterior std and once for the
    std scaled per frame by sqrt(a) of :func:`prior.covariance_scale`
    (``innovation_std_scale``, what ``densify`` uses by default).

    Args:
        basis: the PCA basis.
        sequences: per log, consecutive held-out frames (:func:`fit_frame`).
        calibration: held-out frames with a dense reference.
        max_frames: frames of the kernel fit.
        sequence_frames: frames per sequence of the process-noise fit.
        robust: the robust loss ``densify`` will use.
        local: a fixed local kernel (``fit_local_prior``'s ``fixed``): only sigma, the
            process noise and the std scale are fitted.

    Returns:
        The JSON-ready ``meta["prior"]`` of a basis.

    Raises:
        ValueError: no frame has a measurement.
    """
    from pcainterp_stream.estimate.estimator import densify

    frames = [frame for sequence in sequences for frame in sequence if frame.residual.size]
    if not frames:
        raise ValueError("Expected at least one held-out frame with measurements")
    step = max(1, len(frames) // max_frames)
    local_fit = fit_local_prior(basis, frames[::step], fixed=local)
    process_noise, scores = fit_process_noise(
        basis,
        [sequence[:sequence_frames] for sequence in sequences],
        local=local_fit.local,
        sigma=local_fit.sigma,
    )
    estimates, stds, scaled_stds, references = [], [], [], []
    for frame in calibration:
        result = densify(
            basis,
            frame.pixels,
            frame.disparities,
            sigma=local_fit.sigma,
            local_prior=local_fit.local,
            robust=robust,
            image_size=frame.image_size,
            focal_baseline=frame.focal_baseline,
            zero_is_match=True,
        )
        assert result.disparity_std is not None
        estimates.append(result.disparity)
        stds.append(result.disparity_std)
        scale = covariance_scale(result.normalised_innovation, result.n_measurements)
        scaled_stds.append(result.disparity_std * np.float32(np.sqrt(scale)))
        references.append(np.asarray(frame.reference, dtype=np.float32))
    fitted = local_fit.to_meta()
    fitted.update(
        {
            "std_scale": fit_std_scale(estimates, stds, references),
            "innovation_std_scale": fit_std_scale(estimates, scaled_stds, references),
            "process_noise": process_noise,
            "process_noise_log_evidence": {str(q): v for q, v in scores.items()},
            "candidates": local_fit.table,
            "fit_frames": len(frames[::step]),
            "held_out_frames": len(frames),
            "local_fixed": local is not None,
        }
    )
    return fitted
