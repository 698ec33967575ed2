"""MAP densification of sparse disparities with a PCA basis (paper section III-B, III-C).

Per frame, with k measurements z at image positions p and the basis sampled there
bilinearly (B~ (k, l), m~ (k,)), z~ = z - m~, prior y ~ N(0, Lambda), noise N(0, sigma^2 I):

coefficient (l-space) form, the paper's system pre- and post-multiplied by Lambda^(1/2),

    A = sigma^2 I + Lambda^(1/2) B~^T B~ Lambda^(1/2) = R^T R        (l x l, Cholesky)
    y_hat = Lambda^(1/2) A^-1 Lambda^(1/2) B~^T z~                    (= paper eq. (11))
    Sigma_y = sigma^2 Lambda^(1/2) A^-1 Lambda^(1/2)                  (paper misses sigma^2)

measurement (k-space, Woodbury) form,

    K = B~ Lambda B~^T + sigma^2 I = L L^T                            (k x k, Cholesky)
    y_hat = Lambda B~^T K^-1 z~,   Sigma_y = Lambda - W^T W,  W = L^-1 B~ Lambda

and the dense map d_hat(x) = b(x)^T y_hat + m(x), b(x) the (l,) row of B at pixel x. The
posterior variance of d_hat(x) is b(x)^T Sigma_y b(x):

    exact, measurement form: sum_i lambda_i u_i(x)^2 - ||W b(x)||^2   (k*l per pixel)
    exact, coefficient form: ||V b(x)||^2, V = sigma R^-T Lambda^(1/2)  (l*l per pixel)
    paper (eq. 15/16):       sum_i kappa_i^2 u_i(x)^2,  kappa_i^2 = [Sigma_y]_ii

The small solves run in float64; the products with the basis (s rows) run in float32 BLAS,
batched over frames. The variance may be evaluated on a grid coarser than the basis grid
(``variance_stride``): it is exact at that grid's points and resampled bilinearly.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from pcainterp_stream.basis import (
    Basis,
    VarianceGrid,
    bilinear_weights,
    image_to_grid,
    resample_grid,
    sample_rows,
)
from pcainterp_stream.prior import (
    DOWNWEIGHTED_BELOW,
    LocalPrior,
    Model,
    Robust,
    TemporalPrior,
    covariance_scale,
    evidence_sigma,
    robust_weights,
)

_Float = TypeVar("_Float", np.float32, np.float64)

DEFAULT_SIGMA = 2.0
"""Measurement noise std (px), the paper's value."""

DEFAULT_VARIANCE_GRID_SCALE = 0.0625
"""Automatic variance grid: the coarsest stride whose grid is still >= this scale of the image."""

_VARIANCE_ROWS_PER_CHUNK = 512
"""Rows of the stacked exact-variance factor multiplied at once (bounds memory to ~rows*s)."""

_LOCAL_BLOCKS = 8
"""Column blocks of the local map when the kernel's support is short (``_local_mean``)."""


class Uncertainty(StrEnum):
    """How the per-pixel posterior std is computed."""

    NONE = "none"
    """No uncertainty: ``disparity_std`` and ``depth_std`` are None."""
    PAPER = "paper"
    """The paper's diagonal approximation sum_i kappa_i^2 u_i(x)^2."""
    EXACT = "exact"
    """The true posterior variance diag(B Sigma_y B^T)."""


class SolveForm(StrEnum):
    """Which linear system computes the MAP estimate."""

    AUTO = "auto"
    """Measurement form when k < l, otherwise coefficient form."""
    COEFFICIENT = "coefficient"
    """l x l system (paper's form)."""
    MEASUREMENT = "measurement"
    """k x k system (Woodbury)."""


@dataclass(frozen=True, eq=False)
class DensifyResult:
    """The dense estimate of one frame.

    Attributes:
        disparity: (H, W) float32, MAP disparity (px) at the output image size.
        disparity_std: (H, W) float32, posterior std of disparity (px); None when the
            uncertainty mode is ``none``.
        depth: (H, W) float32, f*b / disparity (m) with REP 118 ranges: ``+inf`` (farther
            than measurable) where disparity < ``min_disparity``, NaN only where there is
            no estimate; None when no focal_baseline is known.
        depth_std: (H, W) float32, f*b / d^2 * disparity_std (m) (delta method), ``+inf``
            where depth is; None when depth or disparity_std is None.
        coefficients: (l,) float64, the MAP estimate y_hat (basis units).
        coefficient_variance: (l,) float64, kappa_i^2 = [Sigma_y]_ii.
        pixels: (k, 2) float64, the measurements used, (x, y) in output image px.
        disparities: (k,) float64, the measured disparities used (px, output camera).
        n_dropped: number of measurements dropped (non-finite or outside the image).
        solve_form: the system that was solved.
        uncertainty: the uncertainty mode.
        focal_baseline: f*b (px*m) used for depth; 0 when unknown.
        min_disparity: the smallest disparity the estimate resolves (px, output camera):
            the noise std ``sigma`` mapped to the output camera. A disparity below it
            cannot be told from 0 by one measurement, so its depth is ``+inf``; no
            finite depth exceeds f*b / min_disparity (:func:`depth_from_disparity`).
        sigma: the measurement noise std used (px, basis units; fitted with ``"evidence"``).
        weights: (k,) float64 final IRLS weight of each measurement (1 without ``robust``).
        n_downweighted: measurements whose robust weight ended below 0.5.
        temporal: "static" (the basis prior), "temporal" (the previous frame's posterior)
            or "reset" (temporal prior rejected by the innovation test, static used).
        normalised_innovation: (z~ - B~ mu)^T K^-1 (z~ - B~ mu) / k, the measurements'
            misfit to the prior; 1 on average when the model holds (0 on the paper's path).
    """

    disparity: npt.NDArray[np.float32]
    disparity_std: npt.NDArray[np.float32] | None
    depth: npt.NDArray[np.float32] | None
    depth_std: npt.NDArray[np.float32] | None
    coefficients: npt.NDArray[np.float64]
    coefficient_variance: npt.NDArray[np.float64]
    pixels: npt.NDArray[np.float64]
    disparities: npt.NDArray[np.float64]
    n_dropped: int
    solve_form: SolveForm
    uncertainty: Uncertainty
    focal_baseline: float
    min_disparity: float = DEFAULT_SIGMA
    sigma: float = DEFAULT_SIGMA
    weights: npt.NDArray[np.float64] | None = None
    n_downweighted: int = 0
    temporal: str = "static"
    normalised_innovation: float = 0.0

    @property
    def n_measurements(self) -> int:
        """Return k, the number of measurements used."""
        return int(self.disparities.shape[0])


@dataclass(frozen=True)
class _Local:
    """The local part of a hybrid-prior posterior: d_local(x) = c(x, P) alpha."""

    prior: LocalPrior
    positions: npt.NDArray[np.float64]  # (k, 2) (x, y) basis image px
    alpha: npt.NDArray[np.float64]  # (k,) K^-1 innovation
    lower_inverse: npt.NDArray[np.float32] | None  # (k, k) L^-1, for the exact variance
    prior_rows: npt.NDArray[np.float32] | None  # (k, l) B~ P, for the exact variance
    # bilinear grid indices and weights (k, 4) of the measurements: B~ = their mix of rows
    indices: npt.NDArray[np.intp] | None = None
    weights: npt.NDArray[np.float64] | None = None


@dataclass(frozen=True)
class _Posterior:
    coefficients: npt.NDArray[np.float64]
    coefficient_variance: npt.NDArray[np.float64]
    # rows r with variance(x) = base(x) + sign * ||factor b(x)||^2; None unless exact
    factor: npt.NDArray[np.float32] | None
    subtract_from_prior: bool
    solve_form: SolveForm
    # beyond the paper (prior.py): base(x) = sum_i p_i u_i(x)^2 when the prior variances
    # p are not Lambda (temporal), the local part, the noise used and the robust weights
    prior_diagonal: npt.NDArray[np.float64] | None = None
    local: _Local | None = None
    sigma: float = DEFAULT_SIGMA
    weights: npt.NDArray[np.float64] | None = None
    normalised_innovation: float = 0.0
    temporal: str = "static"


def densify(
    basis: Basis,
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    sigma: float | str = DEFAULT_SIGMA,
    uncertainty: Uncertainty | str = Uncertainty.EXACT,
    solve_form: SolveForm | str = SolveForm.AUTO,
    focal_baseline: float | None = None,
    image_size: tuple[int, int] | None = None,
    variance_stride: int | None = None,
    local_prior: LocalPrior | None = None,
    robust: Robust | str = Robust.NONE,
    temporal: TemporalPrior | None = None,
    std_scale: float = 1.0,
    robust_iterations: int = 1,
    scale_by_innovation: bool = False,
    noise_std: npt.ArrayLike | None = None,
) -> DensifyResult:
    """Densify one frame's sparse disparities with the MAP estimate.

    Args:
        basis: the PCA basis.
        pixels: (k, 2) float, (x, y) positions in px of the output image (``image_size``).
        disparities: (k,) float, measured disparities (px) of the output camera.
        sigma: measurement noise std (px), > 0, or ``"evidence"``: fitted per frame by
            maximising the marginal likelihood (:func:`prior.evidence_sigma`).
        uncertainty: ``"exact"``, ``"paper"`` or ``"none"`` (see :class:`Uncertainty`).
        solve_form: ``"auto"``, ``"coefficient"`` or ``"measurement"``.
        focal_baseline: f*b (px*m) of the camera the measurements come from; defaults to
            the basis's. Disparities are scaled by basis.focal_baseline / focal_baseline
            onto the basis and back, and depth = focal_baseline / disparity.
        image_size: (height, width) of the camera the measurements come from and of the
            result; defaults to the basis's. Pixels are mapped pixel-centre aligned.
        variance_stride: evaluate the std on a grid this many times coarser than the basis
            grid (exact there, resampled bilinearly); None picks it automatically
            (:data:`DEFAULT_VARIANCE_GRID_SCALE`).
        local_prior: the hybrid prior's local covariance (:class:`prior.LocalPrior`); None
            is the paper's prior.
        robust: ``"none"``, ``"huber"`` or ``"cauchy"``: IRLS on the leave-one-out
            standardised residuals (:class:`prior.Robust`).
        temporal: the stream's temporal prior state, updated in place; None: static prior.
        std_scale: factor on the reported std (a calibration fitted on held-out frames,
            ``fitting.fit_std_scale``); 1 reports the posterior std itself.
        robust_iterations: IRLS reweightings with ``robust`` (:class:`prior.Model`).
        scale_by_innovation: also multiply the std by sqrt(a), the frame's covariance
            scale fitted from its normalised innovation (:func:`prior.covariance_scale`).
        noise_std: (k,) float, extra noise std (px of the output camera) of each
            measurement, added in quadrature to ``sigma``: R_j = (sigma^2 + s_j^2) / w_j
            (e.g. points carried over from earlier frames, :mod:`motion`). None: all 0.

    Returns:
        The :class:`DensifyResult`. Zero usable measurements give the prior (mean map,
        prior std); non-finite or out-of-image measurements are dropped and counted.

    Raises:
        ValueError: an argument has the wrong shape or value.
    """
    return densify_batch(
        basis,
        [pixels],
        [disparities],
        sigma=sigma,
        uncertainty=uncertainty,
        solve_form=solve_form,
        focal_baseline=focal_baseline,
        image_size=image_size,
        variance_stride=variance_stride,
        local_prior=local_prior,
        robust=robust,
        temporal=temporal,
        std_scale=std_scale,
        robust_iterations=robust_iterations,
        scale_by_innovation=scale_by_innovation,
        noise_stds=None if noise_std is None else [noise_std],
    )[0]


def densify_batch(
    basis: Basis,
    pixels_list: Sequence[npt.ArrayLike],
    disparities_list: Sequence[npt.ArrayLike],
    *,
    sigma: float | str = DEFAULT_SIGMA,
    uncertainty: Uncertainty | str = Uncertainty.EXACT,
    solve_form: SolveForm | str = SolveForm.AUTO,
    focal_baseline: float | None = None,
    image_size: tuple[int, int] | None = None,
    variance_stride: int | None = None,
    local_prior: LocalPrior | None = None,
    robust: Robust | str = Robust.NONE,
    temporal: TemporalPrior | None = None,
    std_scale: float = 1.0,
    robust_iterations: int = 1,
    scale_by_innovation: bool = False,
    noise_stds: Sequence[npt.ArrayLike | None] | None = None,
) -> list[DensifyResult]:
    """Densify several frames at once with matrix-matrix products across frames.

    Numerically the same as calling :func:`densify` per frame (to float32 rounding), but
    the products with the basis are batched: B @ Y for all frames' maps and one stacked
    product for all frames' exact-variance factors.

    Args:
        basis: the PCA basis.
        pixels_list: F arrays (k_f, 2) float, (x, y) in output image px.
        disparities_list: F arrays (k_f,) float, disparities (px).
        sigma: measurement noise std (px), > 0.
        uncertainty: ``"exact"``, ``"paper"`` or ``"none"``.
        solve_form: ``"auto"``, ``"coefficient"`` or ``"measurement"``.
        focal_baseline: f*b (px*m) of the measurements' camera (default: the basis's).
        image_size: (height, width) of the measurements' camera (default: the basis's).
        variance_stride: std grid coarsening over the basis grid; None: automatic.
        local_prior: local covariance of the hybrid prior, or None.
        robust: IRLS loss, ``"none"``, ``"huber"`` or ``"cauchy"``.
        temporal: temporal prior state carried across calls (frames in stream order).
        std_scale: factor on the reported std (1: the posterior std itself).
        robust_iterations: IRLS reweightings with ``robust``.
        scale_by_innovation: multiply each frame's std by sqrt(a) of
            :func:`prior.covariance_scale` too.
        noise_stds: F arrays (k_f,) (or None) of extra per-measurement noise std (px),
            see :func:`densify`; None: none.

    Returns:
        One :class:`DensifyResult` per frame, in order.

    Raises:
        ValueError: an argument has the wrong shape or value.
    """
    if len(pixels_list) != len(disparities_list):
        raise ValueError(
            f"Expected `disparities_list` to have one array per frame of `pixels_list` "
            f"({len(pixels_list)}), got {len(disparities_list)}"
        )
    model = Model(
        sigma=_sigma(sigma),
        local=local_prior,
        robust=Robust(robust),
        robust_iterations=robust_iterations,
    )
    if not (np.isfinite(std_scale) and std_scale > 0):
        raise ValueError(f"Expected `std_scale` > 0, got {std_scale}")
    mode = Uncertainty(uncertainty)
    form = SolveForm(solve_form)
    out_size = _image_size(basis, image_size)
    fb_out = _focal_baseline(basis, focal_baseline)
    # disparity in basis units = disparity of the output camera * to_basis
    to_basis = basis.focal_baseline / fb_out if basis.focal_baseline > 0 and fb_out > 0 else 1.0
    stride = _variance_stride(basis, variance_stride)

    if noise_stds is not None and len(noise_stds) != len(pixels_list):
        raise ValueError(
            f"Expected `noise_stds` to have one entry per frame ({len(pixels_list)}), "
            f"got {len(noise_stds)}"
        )
    frames = []
    extra_variances: list[npt.NDArray[np.float64] | None] = []
    for index, (pixels, disparities) in enumerate(
        zip(pixels_list, disparities_list, strict=True)
    ):
        kept_pixels, kept_disparities, keep = _clean(pixels, disparities, out_size)
        frames.append((kept_pixels, kept_disparities, int(keep.size - np.count_nonzero(keep))))
        noise = None if noise_stds is None else noise_stds[index]
        extra_variances.append(
            None if noise is None else (_noise_std(noise, keep) * to_basis) ** 2
        )
    eigenvalues = basis.eigenvalues
    need_factor = mode is Uncertainty.EXACT
    if temporal is not None:
        key = (out_size, fb_out, basis.n_components)
        if temporal.key != key:
            temporal.reset()
            temporal.key = key
    posteriors = []
    for (frame_pixels, frame_disparities, _), extra_variance in zip(
        frames, extra_variances, strict=True
    ):
        grid_positions = image_to_grid(frame_pixels, out_size, basis.grid_size)
        indices, weights = bilinear_weights(grid_positions, basis.grid_size)
        rows = sample_rows(basis.pixel_major, indices, weights).astype(np.float64)
        mean_at = (basis.mean_flat[indices] * weights).sum(axis=1)
        residual = frame_disparities * to_basis - mean_at
        if model.is_paper and temporal is None and extra_variance is None:
            assert model.sigma is not None
            posteriors.append(
                _solve(rows, residual, eigenvalues, model.sigma, form, need_factor=need_factor)
            )
            continue
        positions = image_to_grid(frame_pixels, out_size, basis.image_size)
        posterior = _solve_beyond(
            rows, residual, positions, eigenvalues, model, temporal,
            need_factor=need_factor, extra_variance=extra_variance,
        )
        if posterior.local is not None:
            local = dataclasses.replace(posterior.local, indices=indices, weights=weights)
            posterior = dataclasses.replace(posterior, local=local)
        posteriors.append(posterior)

    # d_hat = B Y + m for all frames at once (s, F)
    coefficients = np.stack([p.coefficients for p in posteriors], axis=1).astype(np.float32)
    grid_maps = basis.pixel_major @ coefficients
    grid_maps += basis.mean_flat[:, None]
    # the local part at the coarsest spacing its kernel is smooth at (prior.LocalPrior.
    # smooth_at): on the basis grid with the basis part, else finer and resampled below
    spacing = basis.image_size[1] / basis.grid_size[1]  # basis image px per grid px
    local_spacings = [
        None if p.local is None else p.local.prior.sample_spacing(spacing) for p in posteriors
    ]
    for index, posterior in enumerate(posteriors):
        if posterior.local is not None and local_spacings[index] == spacing:
            grid_maps[:, index] += _local_mean(
                posterior.local, basis.grid_size, basis.image_size, 1.0
            ).reshape(-1)
    grid_maps *= np.float32(1.0 / to_basis)

    variances: npt.NDArray[np.float32] | None = None
    vgrid = basis.variance_grid(stride) if mode is not Uncertainty.NONE else None
    if vgrid is not None:
        covariance = None
        if mode is Uncertainty.EXACT and any(
            p.local is not None and p.prior_diagonal is None for p in posteriors
        ):
            covariance = basis.prior_covariance(stride)
        variances = _variances(vgrid, posteriors, mode, basis.image_size, covariance)

    results = []
    for index, (posterior, (frame_pixels, frame_disparities, n_dropped)) in enumerate(
        zip(posteriors, frames, strict=True)
    ):
        disparity = resample_grid(grid_maps[:, index].reshape(basis.grid_size), out_size)
        local_spacing = local_spacings[index]
        if posterior.local is not None and local_spacing is not None and local_spacing < spacing:
            coarse = (
                max(1, round(out_size[0] / local_spacing)),
                max(1, round(out_size[1] / local_spacing)),
            )
            local_map = _local_mean(posterior.local, coarse, basis.image_size, 1.0 / to_basis)
            disparity += resample_grid(local_map, out_size)
        disparity_std = None
        if vgrid is not None and variances is not None:
            frame_scale = std_scale
            if scale_by_innovation:
                frame_scale *= np.sqrt(
                    covariance_scale(posterior.normalised_innovation, frame_pixels.shape[0])
                )
            grid_std = np.sqrt(np.maximum(variances[index], 0.0)) * np.float32(
                frame_scale / to_basis
            )
            disparity_std = resample_grid(grid_std.reshape(vgrid.size), out_size)
        # REP 118: a disparity below one noise std cannot be told from 0 (infinity)
        min_disparity = posterior.sigma / to_basis
        depth, depth_std = _depth(disparity, disparity_std, fb_out, min_disparity)
        results.append(
            DensifyResult(
                disparity=disparity,
                disparity_std=disparity_std,
                depth=depth,
                depth_std=depth_std,
                coefficients=posterior.coefficients,
                coefficient_variance=posterior.coefficient_variance,
                pixels=frame_pixels,
                disparities=frame_disparities,
                n_dropped=n_dropped,
                solve_form=posterior.solve_form,
                uncertainty=mode,
                focal_baseline=fb_out,
                min_disparity=min_disparity,
                sigma=posterior.sigma,
                weights=posterior.weights,
                n_downweighted=_downweighted(posterior.weights),
                temporal=posterior.temporal,
                normalised_innovation=posterior.normalised_innovation,
            )
        )
    return results


def posterior_covariance(
    basis: Basis,
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    sigma: float = DEFAULT_SIGMA,
    image_size: tuple[int, int] | None = None,
) -> npt.NDArray[np.float64]:
    """Return the full coefficient posterior covariance Sigma_y (for tests and analysis).

    Args:
        basis: the PCA basis.
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px); only their count and validity matter.
        sigma: measurement noise std (px).
        image_size: (height, width) of the measurements' camera (default: the basis's).

    Returns:
        (l, l) float64, Sigma_y = sigma^2 (sigma^2 Lambda^-1 + B~^T B~)^-1, computed in the
        coefficient form (valid for zero eigenvalues too).
    """
    out_size = _image_size(basis, image_size)
    frame_pixels, _, _ = clean_measurements(pixels, disparities, out_size)
    indices, weights = bilinear_weights(
        image_to_grid(frame_pixels, out_size, basis.grid_size), basis.grid_size
    )
    rows = sample_rows(basis.pixel_major, indices, weights).astype(np.float64)
    root = np.sqrt(basis.eigenvalues)
    scaled = rows * root
    system = sigma**2 * np.eye(basis.n_components) + scaled.T @ scaled
    covariance: npt.NDArray[np.float64] = sigma**2 * (
        root[:, None] * np.linalg.inv(system) * root[None, :]
    )
    return covariance


def _solve(
    rows: npt.NDArray[np.float64],
    residual: npt.NDArray[np.float64],
    eigenvalues: npt.NDArray[np.float64],
    sigma: float,
    form: SolveForm,
    *,
    need_factor: bool,
) -> _Posterior:
    """MAP estimate and posterior of one frame; rows = B~ (k, l), residual = z~ (k,)."""
    k, n_components = rows.shape
    if k == 0:
        return _Posterior(
            coefficients=np.zeros(n_components),
            coefficient_variance=eigenvalues.copy(),
            factor=np.zeros((0, n_components), dtype=np.float32) if need_factor else None,
            subtract_from_prior=True,
            solve_form=SolveForm.MEASUREMENT,
            sigma=sigma,
        )
    if form is SolveForm.AUTO:
        form = SolveForm.MEASUREMENT if k < n_components else SolveForm.COEFFICIENT
    variance = sigma**2
    if form is SolveForm.MEASUREMENT:
        # Woodbury: K = B~ Lambda B~^T + sigma^2 I = L L^T, formed as C C^T (syrk), C = B~ Λ^½
        scaled = rows * np.sqrt(eigenvalues)
        system = scaled @ scaled.T
        system.flat[:: k + 1] += variance
        lower_inverse = _cholesky_inverse(system)  # L^-1
        # M = L^-1 B~ (one triangular product); K^-1 = L^-T L^-1 is never formed
        whitened_rows = _lower_times(lower_inverse, rows)
        coefficients = eigenvalues * (whitened_rows.T @ (lower_inverse @ residual))
        # kappa_i^2 = lambda_i - lambda_i^2 ||M_i||^2, in float64 (large lambda cancel)
        coefficient_variance = eigenvalues - eigenvalues**2 * np.einsum(
            "kl,kl->l", whitened_rows, whitened_rows
        )
        factor = None
        if need_factor:
            factor = (whitened_rows * eigenvalues).astype(np.float32)  # W = L^-1 B~ Λ
        return _Posterior(
            coefficients, coefficient_variance, factor, True, form, sigma=sigma,
            normalised_innovation=_normalised_innovation(rows, residual, coefficients, sigma),
        )
    # coefficient form: A = sigma^2 I + Λ^½ B~^T B~ Λ^½ = L_A L_A^T (paper's system, symmetrised)
    root = np.sqrt(eigenvalues)
    scaled = rows * root
    system = scaled.T @ scaled
    system.flat[:: n_components + 1] += variance
    lower_inverse = _cholesky_inverse(system)
    inverse = lower_inverse.T @ lower_inverse  # A^-1
    coefficients = root * (inverse @ (scaled.T @ residual))
    # Sigma_y = V^T V with V = sigma L_A^-1 Λ^½
    factor64 = sigma * lower_inverse * root
    coefficient_variance = np.einsum("rl,rl->l", factor64, factor64)
    factor = factor64.astype(np.float32) if need_factor else None
    return _Posterior(
        coefficients, coefficient_variance, factor, False, form, sigma=sigma,
        normalised_innovation=_normalised_innovation(rows, residual, coefficients, sigma),
    )


def _normalised_innovation(
    rows: npt.NDArray[np.float64],
    residual: npt.NDArray[np.float64],
    coefficients: npt.NDArray[np.float64],
    sigma: float,
) -> float:
    """z~^T K^-1 z~ / k of the paper's model, from K^-1 z~ = (z~ - B~ y_hat) / sigma^2."""
    k = residual.shape[0]
    return float(residual @ (residual - rows @ coefficients)) / (sigma**2 * k) if k else 0.0


def _sigma(sigma: float | str) -> float | None:
    """Validate the ``sigma`` argument: a positive number, or "evidence" (None)."""
    if isinstance(sigma, str):
        if sigma == "evidence":
            return None
        raise ValueError(f'Expected `sigma` > 0 (px) or "evidence", got {sigma!r}')
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"Expected `sigma` > 0 (px), got {sigma}")
    return float(sigma)


def _downweighted(weights: npt.NDArray[np.float64] | None) -> int:
    return 0 if weights is None else int(np.count_nonzero(weights < DOWNWEIGHTED_BELOW))


def _solve_beyond(
    rows: npt.NDArray[np.float64],
    residual: npt.NDArray[np.float64],
    positions: npt.NDArray[np.float64],
    eigenvalues: npt.NDArray[np.float64],
    model: Model,
    temporal: TemporalPrior | None,
    *,
    need_factor: bool,
    extra_variance: npt.NDArray[np.float64] | None = None,
) -> _Posterior:
    """The estimate with the additions of ``prior.py``, in measurement space.

    Temporal prior first; when its normalised innovation fails the test the frame is solved
    again with the static prior (and the state restarts from that posterior).
    """
    predicted = temporal.predict(eigenvalues) if temporal is not None else None
    local_matrix = (
        model.local.matrix(positions) if model.local is not None and rows.shape[0] else None
    )
    posterior = _solve_measurement(
        rows, residual, positions, eigenvalues, model, predicted, local_matrix,
        need_factor=need_factor, extra_variance=extra_variance,
    )
    if predicted is not None and temporal is not None:
        if not temporal.accepts(posterior.normalised_innovation):
            temporal.resets += 1
            posterior = _solve_measurement(
                rows, residual, positions, eigenvalues, model, None, local_matrix,
                need_factor=need_factor, label="reset", extra_variance=extra_variance,
            )
    if temporal is not None and posterior.temporal != "temporal":
        temporal.static_innovation = posterior.normalised_innovation
    if temporal is not None:
        temporal.update(posterior.coefficients, posterior.coefficient_variance)
    return posterior


def _solve_measurement(
    rows: npt.NDArray[np.float64],
    residual: npt.NDArray[np.float64],
    positions: npt.NDArray[np.float64],
    eigenvalues: npt.NDArray[np.float64],
    model: Model,
    predicted: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None,
    local_matrix: npt.NDArray[np.float64] | None,
    *,
    need_factor: bool,
    label: str = "static",
    extra_variance: npt.NDArray[np.float64] | None = None,
) -> _Posterior:
    """MAP estimate and posterior under prior y ~ N(mu, diag(p)), local prior, weighted noise.

    See the module docstring of ``prior.py`` for the equations; rows = B~ (k, l),
    residual = z~ (k,), positions (k, 2) basis image px. ``predicted`` is (mu, p) of the
    temporal prior, None for the static prior (mu = 0, p = lambda); ``local_matrix`` is
    C_pp of the local prior (None without one); ``extra_variance`` (k,) is added to
    sigma^2 per measurement (basis units^2).
    """
    k, n_components = rows.shape
    if predicted is None:
        mean = np.zeros(n_components)
        prior_diagonal = eigenvalues
    else:
        mean, prior_diagonal = predicted
        label = "temporal"
    prior_rows = rows * prior_diagonal  # B~ P
    innovation = residual - rows @ mean
    scaled = rows * np.sqrt(prior_diagonal)
    signal = scaled @ scaled.T  # B~ P B~^T as C C^T (numpy uses syrk: half the flops)
    if local_matrix is not None:
        signal += local_matrix  # + C_pp
    if model.sigma is not None:
        sigma = model.sigma
    elif extra_variance is not None:  # fit sigma^2 on top of the known extra noise
        sigma = evidence_sigma(signal + np.diag(extra_variance), innovation)
    else:
        sigma = evidence_sigma(signal, innovation)
    if not np.isfinite(sigma):  # no measurements: nothing to fit
        sigma = DEFAULT_SIGMA
    weights = np.ones(k)
    noise = sigma**2 if extra_variance is None else sigma**2 + extra_variance
    iterations = model.robust_iterations if model.robust is not Robust.NONE else 0
    for iteration in range(iterations + 1):
        system = signal.copy()
        system.flat[:: k + 1] += noise / weights  # + R
        lower_inverse = _cholesky_inverse(system) if k else np.zeros((0, 0))
        alpha = lower_inverse.T @ (lower_inverse @ innovation)  # K^-1 (z~ - B~ mu)
        if iteration == iterations:
            break
        # leave-one-out standardised residuals: alpha_j / sqrt([K^-1]_jj)
        inverse_diagonal = np.einsum("ij,ij->j", lower_inverse, lower_inverse)
        updated = robust_weights(alpha / np.sqrt(inverse_diagonal), model.robust)
        converged = bool(np.max(np.abs(updated - weights), initial=0.0) < 1e-3)
        weights = updated
        if converged:
            # one more solve with the final weights
            iterations = iteration + 1
    coefficients = mean + prior_rows.T @ alpha  # y = mu + P B~^T alpha
    gain = _lower_times(lower_inverse, prior_rows)  # W = L^-1 B~ P (k, l)
    coefficient_variance = prior_diagonal - np.einsum("kl,kl->l", gain, gain)
    local = None
    if model.local is not None:
        local = _Local(
            prior=model.local,
            positions=positions,
            alpha=alpha,
            lower_inverse=lower_inverse.astype(np.float32) if need_factor else None,
            prior_rows=prior_rows.astype(np.float32) if need_factor else None,
        )
    return _Posterior(
        coefficients=coefficients,
        coefficient_variance=coefficient_variance,
        # with a local part the variance takes L^-1 (B~ P b(x) + c(P, x)) instead
        factor=gain.astype(np.float32) if need_factor and local is None else None,
        subtract_from_prior=True,
        solve_form=SolveForm.MEASUREMENT,
        prior_diagonal=None if predicted is None else prior_diagonal,
        local=local,
        sigma=float(sigma),
        weights=weights,
        normalised_innovation=float(innovation @ alpha / k) if k else 0.0,
        temporal=label,
    )


def _image_coordinates(count: int, basis_size: int) -> npt.NDArray[np.float64]:
    """Centres of ``count`` cells spanning a basis image axis, in its px (pixel-centre)."""
    cells = np.arange(count, dtype=np.float64)
    return (cells + 0.5) * (basis_size / count) - 0.5


def _local_mean(
    local: _Local, out_size: tuple[int, int], basis_image: tuple[int, int], scale: float
) -> npt.NDArray[np.float32]:
    """The local part c(x, P) alpha at every output pixel times ``scale``, (H, W) float32.

    Separable kernel: sum_j alpha_j v k_y(y - y_j) k_x(x - x_j) = (K_y^T diag(v alpha)) K_x.
    """
    height, width = out_size
    if local.alpha.size == 0:
        return np.zeros(out_size, dtype=np.float32)
    ys = _image_coordinates(height, basis_image[0])
    xs = _image_coordinates(width, basis_image[1])
    support = local.prior.support()
    blocks = _LOCAL_BLOCKS if _LOCAL_BLOCKS * 2.0 * support < basis_image[1] else 1
    # short kernels: columns in blocks, each with only the measurements within the
    # kernel's support of it (sorted by x); the terms left out are < 4e-18 of the peak
    order = np.argsort(local.positions[:, 0], kind="stable")
    position_x = local.positions[order, 0]
    along_y = local.prior.axis(local.positions[order, 1], ys, np.float32)  # (k, H)
    along_y *= (scale * local.prior.variance * local.alpha[order]).astype(np.float32)[:, None]
    dense = np.zeros(out_size, dtype=np.float32)
    step = -(-width // blocks)
    for start in range(0, width, step):
        columns = xs[start : start + step]
        first = int(np.searchsorted(position_x, columns[0] - support, side="left"))
        last = int(np.searchsorted(position_x, columns[-1] + support, side="right"))
        if first < last:
            along_x = local.prior.axis(position_x[first:last], columns, np.float32)
            dense[:, start : start + step] = along_y[first:last].T @ along_x
    return dense


def _local_covariance(
    local: _Local, vgrid_size: tuple[int, int], basis_image: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """c(P, x) for x on the variance grid, (k, s_v) float32."""
    ys = _image_coordinates(vgrid_size[0], basis_image[0])
    xs = _image_coordinates(vgrid_size[1], basis_image[1])
    along_y = local.prior.axis(local.positions[:, 1], ys, np.float32)
    along_x = local.prior.axis(local.positions[:, 0], xs, np.float32)
    product = along_y[:, :, None] * along_x[:, None, :] * np.float32(local.prior.variance)
    covariance: npt.NDArray[np.float32] = product.reshape(
        local.alpha.size, vgrid_size[0] * vgrid_size[1]
    )
    return covariance


def _variance_beyond(
    vgrid: VarianceGrid,
    posterior: _Posterior,
    basis_image: tuple[int, int],
    covariance: npt.NDArray[np.float32] | None = None,
) -> npt.NDArray[np.float32]:
    """Exact variance of one frame with temporal and/or local prior, (s_v,) float32.

    var(x) = b^T P b + v - ||L^-1 (B~ P b(x) + c(P, x))||^2, with W = L^-1 B~ P (the
    factor) when there is no local part.
    """
    local = posterior.local
    if local is not None:
        if local.lower_inverse is None or local.prior_rows is None:
            raise AssertionError("exact variance needs the posterior factor")
        # L^-1 (B~ P U + C): one triangular product (half a GEMM) instead of two GEMMs
        if covariance is not None and posterior.prior_diagonal is None and (
            local.indices is not None and local.weights is not None
        ):
            # static prior P = Lambda: B~ Lambda U = the bilinear mix of U Lambda U_v^T rows
            joint = sample_rows(covariance, local.indices, local.weights)
        else:
            joint = local.prior_rows @ vgrid.component_rows
        joint += _local_covariance(local, vgrid.size, basis_image)
        projected = _lower_times(local.lower_inverse, joint)
    else:
        projected = _factor(posterior) @ vgrid.component_rows
    reduction = np.einsum("ks,ks->s", projected, projected)
    if posterior.prior_diagonal is not None:
        # b(x)^T P b(x) = sum_i p_i u_i(x)^2, one GEMV
        base = posterior.prior_diagonal.astype(np.float32) @ vgrid.squared_rows
    else:
        base = vgrid.prior_variance
    if posterior.local is not None:
        base = base + np.float32(posterior.local.prior.variance)
    result: npt.NDArray[np.float32] = (base - reduction).astype(np.float32)
    return result


@functools.cache
def triangular_lapack() -> Any:
    """Return scipy's LAPACK with its OpenBLAS held at one thread, or None.

    numpy has no triangular inverse: ``np.linalg.inv`` of the Cholesky factor costs ~4x
    LAPACK's ``dtrtri`` (4.4 vs 1.2 ms at k = 300, measured). scipy ships a second OpenBLAS
    whose idle threads spin after a call and halved the speed of the next numpy product
    (docs/estimator.md); a 300 x 300 factorisation gains nothing from threads, so that
    library (only scipy's, found by its path) is limited to one thread, once per process.
    """
    try:
        from scipy.linalg import lapack
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - both are dependencies
        return None
    controller = ThreadpoolController()
    scipy_blas = [
        module for module in controller.lib_controllers if "scipy.libs" in module.filepath
    ]
    for module in scipy_blas:
        module.set_num_threads(1)
    return lapack


def _cholesky_inverse(system: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Return L^-1 (lower triangular) of the Cholesky factor L L^T = system.

    LAPACK ``dpotrf`` + ``dtrtri`` through scipy (its OpenBLAS held at one thread, see
    :func:`triangular_lapack`); numpy's general ``inv`` of the factor only when scipy is
    missing.

    Raises:
        numpy.linalg.LinAlgError: the system is not positive definite.
    """
    lapack = triangular_lapack()
    if lapack is None:  # pragma: no cover - scipy is a dependency
        return np.tril(np.linalg.inv(np.linalg.cholesky(system)))
    lower, info = lapack.dpotrf(system, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix is not positive definite (dpotrf info {info})")
    inverse, info = lapack.dtrtri(lower, lower=1)
    if info != 0:  # pragma: no cover - a Cholesky factor has a positive diagonal
        raise np.linalg.LinAlgError(f"singular Cholesky factor (dtrtri info {info})")
    return np.asarray(inverse, dtype=np.float64)


def _lower_times(lower: npt.NDArray[_Float], matrix: npt.NDArray[_Float]) -> npt.NDArray[_Float]:
    """Return lower @ matrix for a lower-triangular ``lower`` (BLAS ``?trmm``, half a GEMM).

    BLAS is column-major: the C-ordered ``matrix`` is its transpose there, so the call
    computes matrix^T lower^T (right side, transposed triangle) with no copy of ``matrix``.
    """
    if lower.shape[0] == 0:
        return lower @ matrix
    if triangular_lapack() is None:  # pragma: no cover - scipy is a dependency
        return lower @ matrix
    from scipy.linalg import blas

    trmm = blas.strmm if matrix.dtype == np.float32 else blas.dtrmm
    product = trmm(1.0, lower, np.ascontiguousarray(matrix).T, lower=1, side=1, trans_a=1)
    return np.ascontiguousarray(product.T)


def _variances(
    vgrid: VarianceGrid,
    posteriors: list[_Posterior],
    mode: Uncertainty,
    basis_image: tuple[int, int],
    covariance: npt.NDArray[np.float32] | None = None,
) -> npt.NDArray[np.float32]:
    """Posterior variance (F, s_v) float32 on the variance grid (basis disparity units).

    ``covariance`` is the basis's :meth:`~Basis.prior_covariance` (or None).
    """
    n_frames = len(posteriors)
    if any(p.local is not None or p.prior_diagonal is not None for p in posteriors):
        if mode is Uncertainty.PAPER:
            raise ValueError(
                'uncertainty="paper" is the diagonal approximation of the paper\'s prior; '
                'use "exact" with a local or temporal prior'
            )
        return np.stack(
            [_variance_beyond(vgrid, p, basis_image, covariance) for p in posteriors]
        )
    if mode is Uncertainty.PAPER:
        kappa2 = np.stack([p.coefficient_variance for p in posteriors], axis=1)
        # eq. (15/16): sum_i kappa_i^2 u_i(x)^2, one GEMM for all frames
        paper: npt.NDArray[np.float32] = (vgrid.squared_rows.T @ kappa2.astype(np.float32)).T
        return np.ascontiguousarray(paper)
    out = np.empty((n_frames, vgrid.prior_variance.shape[0]), dtype=np.float32)
    # stack frames' factors and multiply in chunks of rows: (sum r_f, l) @ (l, s_v)
    start = 0
    while start < n_frames:
        stop = start
        n_rows = 0
        while stop < n_frames and (stop == start or n_rows < _VARIANCE_ROWS_PER_CHUNK):
            factor = posteriors[stop].factor
            n_rows += 0 if factor is None else factor.shape[0]
            stop += 1
        factors = [_factor(p) for p in posteriors[start:stop]]
        counts = [f.shape[0] for f in factors]
        stacked = factors[0] if len(factors) == 1 else np.concatenate(factors, axis=0)
        projected = stacked @ vgrid.component_rows
        projected *= projected
        offset = 0
        for index, count in enumerate(counts):
            reduction = projected[offset : offset + count].sum(axis=0)
            offset += count
            posterior = posteriors[start + index]
            if posterior.subtract_from_prior:
                out[start + index] = vgrid.prior_variance - reduction
            else:
                out[start + index] = reduction
        start = stop
    return out


def _factor(posterior: _Posterior) -> npt.NDArray[np.float32]:
    if posterior.factor is None:
        raise AssertionError("exact variance needs the posterior factor")
    return posterior.factor


def depth_from_disparity(
    disparity: npt.NDArray[np.float32],
    disparity_std: npt.NDArray[np.float32] | None,
    focal_baseline: float,
    min_disparity: float,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None]:
    """Depth w = f*b / d and its delta-method std f*b / d^2 * std_d, with REP 118 ranges.

    A disparity below ``min_disparity`` (the smallest one the estimate resolves, zero and
    negative ones included) is "farther than measurable": depth and depth std ``+inf``.
    A NaN disparity (no estimate) gives NaN. No finite depth ever comes from a disparity
    below ``min_disparity``, so no depth exceeds f*b / ``min_disparity``.

    Args:
        disparity: (H, W) float32 disparity (px).
        disparity_std: (H, W) float32 std of the disparity (px), or None.
        focal_baseline: f*b (px*m), > 0.
        min_disparity: smallest resolvable disparity (px), > 0.

    Returns:
        depth: (H, W) float32 (m); depth_std: (H, W) float32 (m), None when
        ``disparity_std`` is None.

    Raises:
        ValueError: ``focal_baseline`` or ``min_disparity`` is not positive.
    """
    if not focal_baseline > 0:
        raise ValueError(f"Expected `focal_baseline` > 0, got {focal_baseline}")
    if not min_disparity > 0:
        raise ValueError(f"Expected `min_disparity` > 0, got {min_disparity}")
    with np.errstate(invalid="ignore"):
        resolved = disparity >= np.float32(min_disparity)
    too_far = ~resolved & ~np.isnan(disparity)
    inverse = np.where(too_far, np.float32(0.0), np.float32(np.nan))
    np.divide(np.float32(1.0), disparity, out=inverse, where=resolved)
    with np.errstate(over="ignore"):  # a tiny min_disparity may overflow float32: inf
        depth = inverse * np.float32(focal_baseline)
        depth[too_far] = np.inf
        if disparity_std is None:
            return depth, None
        depth_std = inverse * inverse
        depth_std *= np.float32(focal_baseline)
        depth_std *= disparity_std
    depth_std[too_far] = np.inf
    return depth, depth_std


def _depth(
    disparity: npt.NDArray[np.float32],
    disparity_std: npt.NDArray[np.float32] | None,
    focal_baseline: float,
    min_disparity: float,
) -> tuple[npt.NDArray[np.float32] | None, npt.NDArray[np.float32] | None]:
    """:func:`depth_from_disparity`, or no depth at all when f*b is unknown (<= 0)."""
    if focal_baseline <= 0:
        return None, None
    return depth_from_disparity(disparity, disparity_std, focal_baseline, min_disparity)


def clean_measurements(
    pixels: npt.ArrayLike, disparities: npt.ArrayLike, image_size: tuple[int, int]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int]:
    """Validate shapes, drop non-finite and out-of-image measurements, count the drops.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px).
        image_size: (height, width); pixel centres span [-0.5, size - 0.5].

    Returns:
        The kept pixels (m, 2) float64, their disparities (m,) float64, and k - m.

    Raises:
        ValueError: ``pixels`` is not (k, 2) or ``disparities`` not (k,).
    """
    kept_pixels, kept_disparities, keep = _clean(pixels, disparities, image_size)
    return kept_pixels, kept_disparities, int(keep.size - np.count_nonzero(keep))


def _clean(
    pixels: npt.ArrayLike, disparities: npt.ArrayLike, image_size: tuple[int, int]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`clean_measurements`, returning the (k,) mask of what it kept instead of a count."""
    pixel_array = np.asarray(pixels, dtype=np.float64)
    disparity_array = np.asarray(disparities, dtype=np.float64)
    if pixel_array.size == 0 and pixel_array.ndim < 2:
        pixel_array = pixel_array.reshape(0, 2)
    if pixel_array.ndim != 2 or pixel_array.shape[1] != 2:
        raise ValueError(f"Expected `pixels` of shape (k, 2) as (x, y), got {pixel_array.shape}")
    if disparity_array.shape != (pixel_array.shape[0],):
        raise ValueError(
            f"Expected `disparities` of shape ({pixel_array.shape[0]},) to match `pixels`, "
            f"got {disparity_array.shape}"
        )
    height, width = image_size
    x, y = pixel_array[:, 0], pixel_array[:, 1]
    with np.errstate(invalid="ignore"):
        keep: npt.NDArray[np.bool_] = (
            np.isfinite(disparity_array)
            & (x >= -0.5)
            & (x <= width - 0.5)
            & (y >= -0.5)
            & (y <= height - 0.5)
        )
    return pixel_array[keep], disparity_array[keep], keep


def _noise_std(noise_std: npt.ArrayLike, keep: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """Validate a frame's per-measurement ``noise_std`` and keep the entries ``keep`` keeps."""
    noise_array = np.asarray(noise_std, dtype=np.float64)
    if noise_array.shape != keep.shape:
        raise ValueError(
            f"Expected `noise_std` of shape {keep.shape} to match `disparities`, "
            f"got {noise_array.shape}"
        )
    if not bool(np.all(np.isfinite(noise_array) & (noise_array >= 0))):
        raise ValueError("Expected every `noise_std` finite and >= 0 (px)")
    return noise_array[keep]


def _image_size(basis: Basis, image_size: tuple[int, int] | None) -> tuple[int, int]:
    if image_size is None:
        return basis.image_size
    size = tuple(int(v) for v in image_size)
    if len(size) != 2 or size[0] < 1 or size[1] < 1:
        raise ValueError(f"Expected `image_size` as (height, width) > 0, got {image_size}")
    return (size[0], size[1])


def _focal_baseline(basis: Basis, focal_baseline: float | None) -> float:
    if focal_baseline is None:
        return basis.focal_baseline
    if not (np.isfinite(focal_baseline) and focal_baseline > 0):
        raise ValueError(f"Expected `focal_baseline` > 0 (px*m), got {focal_baseline}")
    return float(focal_baseline)


def _variance_stride(basis: Basis, variance_stride: int | None) -> int:
    if variance_stride is not None:
        if variance_stride < 1:
            raise ValueError(f"Expected `variance_stride` >= 1, got {variance_stride}")
        return int(variance_stride)
    grid_scale = basis.grid_size[0] / basis.image_size[0]
    return max(1, int(np.floor(grid_scale / DEFAULT_VARIANCE_GRID_SCALE + 1e-9)))
