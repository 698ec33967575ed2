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
batched over frames. Where the variance is evaluated (:class:`Uncertainty`): ``"exact"`` at
every output pixel (the model's posterior variance there); ``"exact-coarse"`` (the default)
and ``"paper"`` on a grid coarser than the basis grid (``variance_stride``), exact only at
that grid's points, resampled bilinearly.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import (
    Basis,
    bilinear_weights,
    image_to_grid,
    resample_grid,
    sample_rows,
)
from pcainterp_stream.estimate.cells import Partition, Seeding, partition_all
from pcainterp_stream.estimate.prior import (
    GROUP_RADIUS,
    ROBUST_FROM,
    LocalPrior,
    Model,
    Robust,
    RobustStart,
    TemporalPrior,
    covariance_scale,
)
from pcainterp_stream.estimate.solve import (
    DEFAULT_SIGMA,
    SolveForm,
    _downweighted,
    _local_mean,
    _sigma,
    _solve,
    _solve_beyond,
)
from pcainterp_stream.estimate.variance import (
    Uncertainty,
    _pixel_variances,
    _variance_stride,
    _variances,
    innovation_variance_scale,
    widen_at_border,
    widen_near_group,
    widen_near_range,
)

__all__ = [
    "DEFAULT_SIGMA",
    "DensifyResult",
    "SolveForm",
    "Uncertainty",
    "clean_measurements",
    "densify",
    "densify_batch",
    "depth_from_disparity",
    "disparity_array",
    "posterior_covariance",
]


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
        n_dropped: number of measurements dropped (non-finite, <= 0 or outside the image).
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

    def unknown(self) -> DensifyResult:
        """Return this result with no estimate: disparity NaN and no std nor depth.

        For a frame that had no information at all (not one measurement, nor a temporal
        prior): its MAP estimate is the prior's mean, a scene that was never seen, which a
        caller that reads the depth without its std would take for a measurement.
        """
        unknown = np.full(self.disparity.shape, np.nan, dtype=np.float32)
        return dataclasses.replace(
            self, disparity=unknown, disparity_std=None, depth=None, depth_std=None
        )


def densify(
    basis: Basis | None,
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    sigma: float | str = DEFAULT_SIGMA,
    uncertainty: Uncertainty | str = Uncertainty.EXACT_COARSE,
    solve_form: SolveForm | str = SolveForm.AUTO,
    focal_baseline: float | None = None,
    image_size: tuple[int, int] | None = None,
    variance_stride: int | None = None,
    local_prior: LocalPrior | None = None,
    robust: Robust | str = Robust.NONE,
    temporal: TemporalPrior | None = None,
    std_scale: float = 1.0,
    robust_iterations: int = 1,
    robust_start: RobustStart | str = RobustStart.PLAIN,
    scale_by_innovation: bool = False,
    noise_std: npt.ArrayLike | None = None,
    edge_map: npt.ArrayLike | None = None,
    match_range: float | None = None,
    zero_is_match: bool = False,
) -> DensifyResult:
    """Densify one frame's sparse disparities with the MAP estimate.

    Args:
        basis: the PCA basis; None: the built-in one (:meth:`Basis.default`).
        pixels: (k, 2) float, (x, y) positions in px of the output image (``image_size``).
        disparities: (k,) float, measured disparities (px) of the output camera; a value
            <= 0 is no measurement (the invalid code of disparity images: 0 in KITTI's
            PNGs, -1 in OpenCV's ``StereoSGBM.compute() / 16``) and is dropped. 16-bit
            integers (the matchers' fixed point, 16 or 256 x px) raise: divide them first.
        sigma: measurement noise std in px of the basis's camera, > 0 (the
            measurements are mapped to it, so on the camera of ``focal_baseline`` the
            noise std is sigma * focal_baseline / basis.focal_baseline: docs/estimator.md,
            "Camera mapping"), or ``"evidence"``: fitted per frame by maximising the
            marginal likelihood (:func:`prior.evidence_sigma`).
        uncertainty: ``"exact-coarse"`` (exact on the variance grid, resampled; the
            default), ``"exact"`` (exact at every output pixel: 0.06-2.4 s per KITTI-size
            frame), ``"paper"`` or ``"none"`` (see :class:`Uncertainty`).
        solve_form: ``"auto"``, ``"coefficient"`` or ``"measurement"``.
        focal_baseline: f*b (px*m) of the camera the measurements come from; defaults to
            the basis's. Disparities are scaled by basis.focal_baseline / focal_baseline
            onto the basis and back, and depth = focal_baseline / disparity.
        image_size: (height, width) of the camera the measurements come from and of the
            result; defaults to the basis's. Pixels are mapped pixel-centre aligned.
        variance_stride: ``"exact-coarse"`` and ``"paper"`` evaluate the std on a grid
            this many times coarser than the basis grid (resampled bilinearly); None picks
            it automatically (:data:`variance.DEFAULT_VARIANCE_GRID_SCALE`). ``"exact"``
            evaluates every output pixel and ignores it.
        local_prior: the hybrid prior's local covariance (:class:`prior.LocalPrior`); None
            is the paper's prior.
        robust: ``"none"``, ``"huber"`` or ``"cauchy"``: IRLS on the leave-one-out
            standardised residuals (:class:`prior.Robust`).
        temporal: the stream's temporal prior state, updated in place; None: static prior.
        std_scale: factor on the reported std (a calibration fitted on held-out frames,
            ``fitting.fit_std_scale``); 1 reports the posterior std itself.
        robust_iterations: IRLS reweightings with ``robust`` (:class:`prior.Model`).
        robust_start: ``"plain"`` or ``"trimmed"``: where a frame's first weights come
            from (:class:`prior.RobustStart`; ``"trimmed"`` for points of another system,
            which may be off by hundreds of px).
        scale_by_innovation: also scale the variance by the frame's covariance scale a,
            fitted from its normalised innovation (:func:`prior.covariance_scale`), where the
            measurements reached: a + (1 - a) r (:func:`variance.innovation_variance_scale`).
        noise_std: (k,) float, extra noise std (px of the output camera) of each
            measurement, added in quadrature to ``sigma``: R_j = (sigma^2 + s_j^2) / w_j
            (e.g. points carried over from earlier frames, :mod:`motion`). None: all 0.
        edge_map: (h, w) float, a disparity map of the frame spanning the image at any
            resolution (px, <= 0 or NaN unknown; e.g. the front end's SGBM map), along which
            an edge-aware ``local_prior`` (``cell_weight`` < 1) partitions the image among
            the kept measurements (:class:`cells.Partition`); None: the stationary kernel.
        match_range: the largest disparity (px of the output camera) the measurements'
            matcher returns (SGBM's range): the std is widened where the estimate nears it
            (:func:`variance.widen_near_range`); None: the std as the model gives it.
        zero_is_match: keep a disparity of exactly 0 as a measurement (a match at zero
            disparity, infinitely far: what SGBM with ``minDisparity`` 0 returns, as
            ``pcainterp densify``'s own front end does); False drops it with the negative
            ones. Negative disparities are always dropped.

    Returns:
        The :class:`DensifyResult`. Zero usable measurements give the prior (mean map,
        prior std); non-finite, <= 0 (see ``zero_is_match``) or out-of-image measurements
        are dropped and counted in ``n_dropped``.

    Raises:
        ValueError: an argument has the wrong shape or value.
        TypeError: ``disparities`` or ``edge_map`` are 16-bit integers, boolean or complex.
    """
    partition = None
    edge_values = None if edge_map is None else disparity_array(edge_map, "edge_map", np.float32)
    if edge_values is not None and local_prior is not None and local_prior.edge_aware:
        resolved = basis if basis is not None else Basis.default()
        size = _image_size(resolved, image_size)
        seeds, _, _ = clean_measurements(pixels, disparities, size, zero_is_match=zero_is_match)
        partition = Partition.along(edge_values, seeds, size, resolved.grid_size)
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
        robust_start=robust_start,
        scale_by_innovation=scale_by_innovation,
        noise_stds=None if noise_std is None else [noise_std],
        partitions=None if partition is None else [partition],
        match_range=match_range,
        zero_is_match=zero_is_match,
    )[0]


def densify_batch(
    basis: Basis | None,
    pixels_list: Sequence[npt.ArrayLike],
    disparities_list: Sequence[npt.ArrayLike],
    *,
    sigma: float | str = DEFAULT_SIGMA,
    uncertainty: Uncertainty | str = Uncertainty.EXACT_COARSE,
    solve_form: SolveForm | str = SolveForm.AUTO,
    focal_baseline: float | None = None,
    image_size: tuple[int, int] | None = None,
    variance_stride: int | None = None,
    local_prior: LocalPrior | None = None,
    robust: Robust | str = Robust.NONE,
    temporal: TemporalPrior | None = None,
    std_scale: float = 1.0,
    robust_iterations: int = 1,
    robust_from: float = ROBUST_FROM,
    robust_start: RobustStart | str = RobustStart.PLAIN,
    scale_by_innovation: bool = False,
    noise_stds: Sequence[npt.ArrayLike | None] | None = None,
    with_depth: bool = True,
    with_depth_std: bool = True,
    partitions: Sequence[Partition | Seeding | None] | None = None,
    match_range: float | None = None,
    zero_is_match: bool = False,
) -> list[DensifyResult]:
    """Densify several frames at once with matrix-matrix products across frames.

    Numerically the same as calling :func:`densify` per frame (to float32 rounding), but
    the products with the basis are batched: B @ Y for all frames' maps and one stacked
    product for all frames' exact-variance factors.

    Args:
        basis: the PCA basis; None: the built-in one (:meth:`Basis.default`).
        pixels_list: F arrays (k_f, 2) float, (x, y) in output image px.
        disparities_list: F arrays (k_f,) float, disparities (px); <= 0 is no measurement
            and is dropped (see :func:`densify`).
        sigma: measurement noise std (px of the basis's camera, as in :func:`densify`), > 0.
        uncertainty: ``"exact-coarse"`` (default), ``"exact"``, ``"paper"`` or ``"none"``.
        solve_form: ``"auto"``, ``"coefficient"`` or ``"measurement"``.
        focal_baseline: f*b (px*m) of the measurements' camera (default: the basis's).
        image_size: (height, width) of the measurements' camera (default: the basis's).
        variance_stride: std grid coarsening over the basis grid (``"exact-coarse"``,
            ``"paper"``); None: automatic.
        local_prior: local covariance of the hybrid prior, or None.
        robust: IRLS loss, ``"none"``, ``"huber"`` or ``"cauchy"``.
        temporal: temporal prior state carried across calls (frames in stream order).
        std_scale: factor on the reported std (1: the posterior std itself).
        robust_iterations: IRLS reweightings with ``robust``.
        robust_from: reweight a frame only when a measurement's leave-one-out standardised
            residual reaches this (:class:`prior.Model`); 0: always.
        robust_start: ``"plain"`` or ``"trimmed"`` (:class:`prior.RobustStart`).
        scale_by_innovation: scale each frame's variance by its covariance scale too, as
            :func:`densify` does.
        noise_stds: F arrays (k_f,) (or None) of extra per-measurement noise std (px),
            see :func:`densify`; None: none.
        with_depth: also convert to depth and its std; False leaves ``depth`` and
            ``depth_std`` None (for a caller that changes the disparity first, as dense
            fusion does, and converts then).
        with_depth_std: with ``with_depth``, also the depth's std; False leaves
            ``depth_std`` None (the depth itself is made), for a caller that does not use
            it (half of the conversion's time).
        partitions: F partitions of the images (or None) along their disparity maps, for
            an edge-aware ``local_prior`` (:meth:`cells.Partition.along`, e.g. seeded by
            each frame's own measurements; a measurement is in the cell of the grid node it
            falls on), or their :class:`cells.Seeding` (searched here, the batch's at once);
            None: the stationary kernel.
        match_range: the matcher's largest disparity (px), see :func:`densify`; None: off.
        zero_is_match: keep disparities of exactly 0 as measurements, see :func:`densify`.

    Returns:
        One :class:`DensifyResult` per frame, in order (none for no frames).

    Raises:
        ValueError: an argument has the wrong shape or value.
        TypeError: disparities of 16-bit integers, boolean or complex (see :func:`densify`).
        BasisError: ``basis`` is None and the built-in basis is missing.
    """
    if basis is None:
        basis = Basis.default()
    if len(pixels_list) != len(disparities_list):
        raise ValueError(
            f"Expected `disparities_list` to have one array per frame of `pixels_list` "
            f"({len(pixels_list)}), got {len(disparities_list)}"
        )
    if not pixels_list:
        return []
    model = Model(
        sigma=_sigma(sigma),
        local=local_prior,
        robust=Robust(robust),
        robust_iterations=robust_iterations,
        robust_from=robust_from,
        robust_start=RobustStart(robust_start),
    )
    if not (np.isfinite(std_scale) and std_scale > 0):
        raise ValueError(f"Expected `std_scale` > 0, got {std_scale}")
    if match_range is not None and not (np.isfinite(match_range) and match_range > 0):
        raise ValueError(f"Expected `match_range` > 0 or None, got {match_range}")
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
    if partitions is not None and len(partitions) != len(pixels_list):
        raise ValueError(
            f"Expected `partitions` to have one entry per frame ({len(pixels_list)}), "
            f"got {len(partitions)}"
        )
    searched = None if partitions is None else partition_all(partitions)
    frames = []
    extra_variances: list[npt.NDArray[np.float64] | None] = []
    for index, (pixels, disparities) in enumerate(zip(pixels_list, disparities_list, strict=True)):
        kept_pixels, kept_disparities, keep = _clean(pixels, disparities, out_size, zero_is_match)
        frames.append((kept_pixels, kept_disparities, int(keep.size - np.count_nonzero(keep))))
        noise = None if noise_stds is None else noise_stds[index]
        extra_variances.append(None if noise is None else (_noise_std(noise, keep) * to_basis) ** 2)
    eigenvalues = basis.eigenvalues
    need_factor = mode in (Uncertainty.EXACT, Uncertainty.EXACT_COARSE)
    if temporal is not None:
        key = (out_size, fb_out, basis.n_components)
        if temporal.key != key:
            temporal.reset()
            temporal.key = key
    posteriors = []
    edge_aware = model.local is not None and model.local.edge_aware
    for index, ((frame_pixels, frame_disparities, _), extra_variance) in enumerate(
        zip(frames, extra_variances, strict=True)
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
        cells = None
        partition = None if searched is None else searched[index]
        if edge_aware and partition is not None and frame_pixels.shape[0]:
            cells = partition.cells(frame_pixels)
        posterior = _solve_beyond(
            rows,
            residual,
            positions,
            eigenvalues,
            model,
            temporal,
            need_factor=need_factor,
            extra_variance=extra_variance,
            cells=cells,
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
    variance_size = out_size  # where the variances are: every output pixel ("exact")
    static_prior: npt.NDArray[np.float32] | None = None  # the basis part's, there
    if mode is Uncertainty.EXACT:
        variances = _pixel_variances(basis, posteriors, out_size)
        if scale_by_innovation:
            static_prior = resample_grid(basis.prior_variance, out_size).reshape(-1)
    elif mode is not Uncertainty.NONE:
        vgrid = basis.variance_grid(stride)
        variance_size = vgrid.size
        static_prior = vgrid.prior_variance
        # B~ Lambda U_v^T as a GEMM (k l s_v products, ~4.5 ms per KITTI-size frame on one
        # core), not gathered from the cached U Lambda U_v^T (Basis.prior_covariance): that
        # matrix takes 218 MB and 1-3 s to build, and gathering 4k of its rows from memory
        # was no faster than the GEMM (docs/benchmarks.md, "Throughput")
        variances = _variances(vgrid, posteriors, mode, basis.image_size)

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
        if variances is not None:
            frame_variance = np.maximum(variances[index], 0.0)
            if scale_by_innovation:
                assert static_prior is not None
                local_variance = 0.0 if posterior.local is None else posterior.local.prior.variance
                frame_variance *= innovation_variance_scale(
                    covariance_scale(posterior.normalised_innovation, frame_pixels.shape[0]),
                    frame_variance,
                    static_prior + np.float32(local_variance),
                )
            grid_std = np.sqrt(frame_variance) * np.float32(std_scale / to_basis)
            disparity_std = resample_grid(grid_std.reshape(variance_size), out_size)
            if variance_size != out_size:  # held constant past the outermost cell centres
                widen_at_border(
                    disparity_std,
                    (0.5 * out_size[0] / variance_size[0], 0.5 * out_size[1] / variance_size[1]),
                )
            if match_range is not None:
                widen_near_range(disparity, disparity_std, match_range)
            if posterior.group is not None:
                widen_near_group(
                    disparity,
                    disparity_std,
                    frame_pixels[posterior.group],
                    frame_disparities[posterior.group],
                    GROUP_RADIUS * out_size[1] / basis.image_size[1],
                    (frame_pixels[~posterior.group], frame_disparities[~posterior.group]),
                )
        # REP 118: a disparity below one noise std cannot be told from 0 (infinity)
        min_disparity = posterior.sigma / to_basis
        depth, depth_std = (
            _depth(disparity, disparity_std if with_depth_std else None, fb_out, min_disparity)
            if with_depth
            else (None, None)
        )
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
    infinity = np.float32(np.inf)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        too_far = disparity < np.float32(min_disparity)  # NaN (no estimate) is not
        # whatever 1 / d is where d is too small, both outputs are +inf there
        inverse = np.divide(np.float32(1.0), disparity, dtype=np.float32)
        # a tiny min_disparity may overflow float32: inf
        depth = np.multiply(inverse, np.float32(focal_baseline))
        np.copyto(depth, infinity, where=too_far)
        if disparity_std is None:
            return depth, None
        np.multiply(inverse, inverse, out=inverse)
        np.multiply(inverse, np.float32(focal_baseline), out=inverse)
        np.multiply(inverse, disparity_std, out=inverse)
    np.copyto(inverse, infinity, where=too_far)
    return depth, inverse


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
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    image_size: tuple[int, int],
    *,
    zero_is_match: bool = False,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int]:
    """Validate shapes, drop unusable measurements, count the drops.

    A measurement is dropped when its disparity is non-finite or <= 0 (0 kept with
    ``zero_is_match``) or its pixel is outside the image.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px); see :func:`disparity_array` for the dtypes.
        image_size: (height, width); pixel centres span [-0.5, size - 0.5].
        zero_is_match: keep a disparity of exactly 0 (a match at zero disparity, as SGBM
            with ``minDisparity`` 0 returns: the front end's measurements) instead of
            taking it for the invalid code of a disparity image.

    Returns:
        The kept pixels (m, 2) float64, their disparities (m,) float64, and k - m.

    Raises:
        ValueError: ``pixels`` is not (k, 2) or ``disparities`` not (k,).
        TypeError: ``disparities`` of a dtype :func:`disparity_array` refuses.
    """
    kept_pixels, kept_disparities, keep = _clean(pixels, disparities, image_size, zero_is_match)
    return kept_pixels, kept_disparities, int(keep.size - np.count_nonzero(keep))


def disparity_array(
    values: npt.ArrayLike, name: str, dtype: type[np.floating[Any]] = np.float64
) -> npt.NDArray[Any]:
    """Return disparities (px) as a float array, refusing the matchers' fixed point.

    A 16-bit integer array is a disparity image in fixed point (OpenCV's ``StereoSGBM`` and
    ``StereoBM`` ``compute()`` give int16 16 x px, invalid < 0; a KITTI disparity PNG is
    uint16 256 x px, invalid 0), which taken as px would be 16 or 256 times too large.
    Other integers (e.g. a list of whole px) are px.

    Args:
        values: the disparities, any shape.
        name: the argument's name, for the error.
        dtype: the float dtype returned.

    Returns:
        ``values`` as ``dtype`` (no copy when they are already).

    Raises:
        TypeError: 16-bit integer, boolean or complex values.
    """
    array = np.asarray(values)
    if array.dtype in (np.int16, np.uint16):
        raise TypeError(
            f"Expected `{name}` as float disparities in px, got {array.dtype}: a 16-bit "
            f"disparity image is fixed point (OpenCV's StereoSGBM/StereoBM compute(): int16 "
            f"16 x px, invalid < 0; a KITTI disparity PNG: uint16 256 x px, invalid 0); "
            f"pass e.g. `disparity.astype(np.float32) / 16` (or / 256)"
        )
    if array.dtype.kind in "bc":
        raise TypeError(f"Expected `{name}` as float disparities in px, got {array.dtype}")
    return np.asarray(array, dtype=dtype)


def _clean(
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    image_size: tuple[int, int],
    zero_is_match: bool,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`clean_measurements`, returning the (k,) mask of what it kept instead of a count."""
    pixel_array = np.asarray(pixels, dtype=np.float64)
    disparity_values = disparity_array(disparities, "disparities")
    if pixel_array.size == 0 and pixel_array.ndim < 2:
        pixel_array = pixel_array.reshape(0, 2)
    if pixel_array.ndim != 2 or pixel_array.shape[1] != 2:
        raise ValueError(f"Expected `pixels` of shape (k, 2) as (x, y), got {pixel_array.shape}")
    if disparity_values.shape != (pixel_array.shape[0],):
        raise ValueError(
            f"Expected `disparities` of shape ({pixel_array.shape[0]},) to match `pixels`, "
            f"got {disparity_values.shape}"
        )
    height, width = image_size
    x, y = pixel_array[:, 0], pixel_array[:, 1]
    with np.errstate(invalid="ignore"):
        # a disparity <= 0 is no stereo match (0: infinitely far; < 0: behind the camera),
        # the invalid code of disparity images; SGBM's own 0 is a match at its range's end
        usable = disparity_values >= 0 if zero_is_match else disparity_values > 0
        keep: npt.NDArray[np.bool_] = (
            np.isfinite(disparity_values)
            & usable
            & (x >= -0.5)
            & (x <= width - 0.5)
            & (y >= -0.5)
            & (y <= height - 0.5)
        )
    return pixel_array[keep], disparity_values[keep], keep


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
    whole = all(float(v) == int(v) for v in image_size)
    if len(size) != 2 or not whole or size[0] < 1 or size[1] < 1:
        raise ValueError(f"Expected `image_size` as (height, width) > 0, got {image_size}")
    return (size[0], size[1])


def _focal_baseline(basis: Basis, focal_baseline: float | None) -> float:
    if focal_baseline is None:
        return basis.focal_baseline
    if not (np.isfinite(focal_baseline) and focal_baseline > 0):
        raise ValueError(f"Expected `focal_baseline` > 0 (px*m), got {focal_baseline}")
    return float(focal_baseline)
