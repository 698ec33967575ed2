"""The per-pixel posterior variance (paper section III-C).

Exact diag(B Sigma_y B^T), the paper's diagonal approximation, and where they are
evaluated (:class:`Uncertainty`): ``"exact"`` at every output pixel, ``"exact-coarse"`` and
``"paper"`` on a variance grid coarser than the basis grid, resampled bilinearly.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import (
    Basis,
    VarianceGrid,
    bilinear_weights,
    sample_rows,
)
from pcainterp_stream.estimate.solve import (
    _add_product,
    _cross_covariance,
    _image_coordinates,
    _local_covariance,
    _lower_times,
    _Posterior,
)

DEFAULT_VARIANCE_GRID_SCALE = 0.0625
"""Automatic variance grid of ``"exact-coarse"`` and ``"paper"``: the coarsest stride whose
grid is still >= this scale of the image. Finer grids cost 2-8x as much and were still not
within 2 % of the exact std (docs/stages.md, "Exact posterior std: variance grid")."""

_EXACT_PIXELS_PER_CHUNK = 1 << 14
"""Output pixels whose ``"exact"`` variance is evaluated at once (memory ~(l + k) x this)."""


_VARIANCE_ROWS_PER_CHUNK = 512


"""Rows of the stacked exact-variance factor multiplied at once (bounds memory to ~rows*s)."""


class Uncertainty(StrEnum):
    """How the per-pixel posterior std is computed."""

    NONE = "none"
    """No uncertainty: ``disparity_std`` and ``depth_std`` are None."""
    PAPER = "paper"
    """The paper's diagonal approximation sum_i kappa_i^2 u_i(x)^2, on the variance grid."""
    EXACT = "exact"
    """The exact posterior variance at every output pixel x: b(x)^T Sigma_y b(x), b(x) the
    bilinear row of the basis at x (as for a measurement), plus the local part of a hybrid
    prior with its kernel evaluated at x itself. Without a local part about the cost of
    the variance on the basis grid itself (0.06-0.11 s per KITTI-size frame, l = 60-200,
    one BLAS thread); with one, k*l + k^2 products per output pixel (1.6-2.4 s)
    (docs/stages.md, "Exact posterior std: variance grid")."""
    EXACT_COARSE = "exact-coarse"
    """The exact posterior variance at the points of the variance grid (``variance_stride``;
    by default 1/16 of the image resolution), resampled bilinearly: exact at those points
    only. It misses the posterior's fine structure between them: the components'
    roughness at the basis grid's scale, and the dips of the std towards sigma at and near
    the measurements (deep with a hybrid prior). The default: on learned bases its +-2
    sigma coverage was within 0.6 points of ``EXACT``'s and its NLL within 0.7 %, at 1/6
    (the paper's prior) to 1/100 (hybrid prior) of the cost (docs/stages.md, "Exact
    posterior std: variance grid")."""


def _variance_beyond(
    vgrid: VarianceGrid,
    posterior: _Posterior,
    basis_image: tuple[int, int],
    covariance: npt.NDArray[np.float32] | None = None,
    coordinates: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None,
) -> npt.NDArray[np.float32]:
    """Exact variance of one frame with temporal and/or local prior, (s_v,) float32.

    var(x) = b^T P b + v - ||L^-1 (B~ P b(x) + c(P, x))||^2, with W = L^-1 B~ P (the
    factor) when there is no local part. ``coordinates`` (ys, xs) are the basis-image px
    of the points' rows and columns when ``vgrid`` does not span the whole image.
    """
    local = posterior.local
    if local is not None:
        if local.lower_inverse is None or local.prior_rows is None:
            raise AssertionError("exact variance needs the posterior factor")
        # L^-1 (B~ P U + C): one triangular product (half a GEMM) instead of two GEMMs,
        # in place; C first, B~ P U added to it by the GEMM itself (no temporary)
        if coordinates is None:
            joint = _local_covariance(local, vgrid.size, basis_image)
        else:
            joint = _cross_covariance(local, *coordinates, basis_image)
        if (
            covariance is not None
            and posterior.prior_diagonal is None
            and (local.indices is not None and local.weights is not None)
        ):
            # static prior P = Lambda: B~ Lambda U = the bilinear mix of U Lambda U_v^T rows
            joint += sample_rows(covariance, local.indices, local.weights)
        else:
            _add_product(joint, local.prior_rows, vgrid.component_rows)
        projected = _lower_times(local.lower_inverse, joint, overwrite=True)
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


def _variances(
    vgrid: VarianceGrid,
    posteriors: list[_Posterior],
    mode: Uncertainty,
    basis_image: tuple[int, int],
    covariance: npt.NDArray[np.float32] | None = None,
    coordinates: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None,
) -> npt.NDArray[np.float32]:
    """Posterior variance (F, s_v) float32 at the points of ``vgrid`` (basis disparity units).

    ``covariance`` is the basis's :meth:`~Basis.prior_covariance` (or None); ``coordinates``
    as in :func:`_variance_beyond`. Any mode but ``"paper"`` is the exact variance there.
    """
    n_frames = len(posteriors)
    if any(p.local is not None or p.prior_diagonal is not None for p in posteriors):
        if mode is Uncertainty.PAPER:
            raise ValueError(
                'uncertainty="paper" is the diagonal approximation of the paper\'s prior; '
                'use "exact-coarse" or "exact" with a local or temporal prior'
            )
        return np.stack(
            [_variance_beyond(vgrid, p, basis_image, covariance, coordinates) for p in posteriors]
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


def _variance_stride(basis: Basis, variance_stride: int | None) -> int:
    if variance_stride is not None:
        if variance_stride < 1:
            raise ValueError(f"Expected `variance_stride` >= 1, got {variance_stride}")
        return int(variance_stride)
    grid_scale = basis.grid_size[0] / basis.image_size[0]
    return max(1, int(np.floor(grid_scale / DEFAULT_VARIANCE_GRID_SCALE + 1e-9)))


def _pixel_variances(
    basis: Basis, posteriors: list[_Posterior], out_size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Exact posterior variance (F, H * W) float32 at every output pixel (basis units).

    The ``"exact"`` mode. The basis row at output pixel x is its bilinear sample
    b(x) = sum_c w_c(x) u(g_c) over the 4 grid points g_c around it (the row a measurement
    at x has, and the dense map's own resampling), so the variance is the model's
    b(x)^T Sigma_y b(x) there, not a resampling of grid values: where the components are
    rough at the grid's scale, the variance of the bilinear mix is below the mix of the
    variances. Without a local part that quadratic form is exact from grid quantities
    (:func:`_bilinear_variance`, about the cost of the variance on the basis grid itself).
    A hybrid prior's kernel is evaluated at x itself, so the std dips to about sigma at
    each measurement as the posterior does; those frames are evaluated pixel by pixel, in
    chunks of rows (:data:`_EXACT_PIXELS_PER_CHUNK` pixels) taken as a
    :class:`VarianceGrid`, with the products of the variance grid.
    """
    out = np.empty((len(posteriors), out_size[0] * out_size[1]), dtype=np.float32)
    pixelwise = [i for i, p in enumerate(posteriors) if p.local is not None]
    static_base: npt.NDArray[np.float64] | None = None
    for index, posterior in enumerate(posteriors):
        if posterior.local is not None:
            continue
        base = None
        if posterior.subtract_from_prior:
            if posterior.prior_diagonal is not None:
                base = _neighbour_prior(basis, posterior.prior_diagonal)
            else:
                if static_base is None:
                    static_base = _neighbour_prior(basis, basis.eigenvalues)
                base = static_base
        out[index] = _bilinear_variance(basis, posterior, base, out_size).reshape(-1)
    if not pixelwise:
        return out
    chosen = [posteriors[i] for i in pixelwise]
    height, width = out_size
    # output pixel centres on the basis grid (image_to_grid) and in basis-image px
    grid_x = _image_coordinates(width, basis.grid_size[1])
    grid_y = _image_coordinates(height, basis.grid_size[0])
    basis_x = _image_coordinates(width, basis.image_size[1])
    basis_y = _image_coordinates(height, basis.image_size[0])
    rows_per_chunk = max(1, _EXACT_PIXELS_PER_CHUNK // width)
    for top in range(0, height, rows_per_chunk):
        bottom = min(top + rows_per_chunk, height)
        ys, xs = np.meshgrid(grid_y[top:bottom], grid_x, indexing="ij")
        indices, weights = bilinear_weights(
            np.stack([xs.ravel(), ys.ravel()], axis=1), basis.grid_size
        )
        rows = sample_rows(basis.pixel_major, indices, weights)  # (n, l): b(x) of each pixel
        squared = rows.astype(np.float64)
        squared *= squared
        chunk = VarianceGrid(
            size=(bottom - top, width),
            component_rows=np.ascontiguousarray(rows.T),
            prior_variance=(squared @ basis.eigenvalues).astype(np.float32),
        )
        out[pixelwise, top * width : bottom * width] = _variances(
            chunk,
            chosen,
            Uncertainty.EXACT,
            basis.image_size,
            coordinates=(basis_y[top:bottom], basis_x),
        )
    return out


def _neighbour_products(fields: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """Inner products over axis 0 of neighbouring grid points of (r, gh, gw) ``fields``.

    Returns (5, gh, gw) float64 G, at grid point (y, x): G[0] = <f(y, x), f(y, x)>,
    G[1] = <f(y, x), f(y, x+1)>, G[2] = <f(y, x), f(y+1, x)>, G[3] = <f(y, x), f(y+1, x+1)>,
    G[4] = <f(y, x+1), f(y+1, x)>; 0 where the neighbour is outside the grid.
    """
    _, gh, gw = fields.shape
    products = np.zeros((5, gh, gw), dtype=np.float64)
    products[0] = np.einsum("rij,rij->ij", fields, fields)
    products[1, :, :-1] = np.einsum("rij,rij->ij", fields[:, :, :-1], fields[:, :, 1:])
    products[2, :-1] = np.einsum("rij,rij->ij", fields[:, :-1], fields[:, 1:])
    products[3, :-1, :-1] = np.einsum("rij,rij->ij", fields[:, :-1, :-1], fields[:, 1:, 1:])
    products[4, :-1, :-1] = np.einsum("rij,rij->ij", fields[:, :-1, 1:], fields[:, 1:, :-1])
    return products


def _neighbour_prior(
    basis: Basis, prior_variances: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """:func:`_neighbour_products` of the prior, u(g)^T diag(p) u(g') (float64 sums)."""
    scaled = (
        basis.components.astype(np.float64)
        * np.sqrt(np.maximum(prior_variances, 0.0))[:, None, None]
    )
    return _neighbour_products(scaled)


def _bilinear_variance(
    basis: Basis,
    posterior: _Posterior,
    base: npt.NDArray[np.float64] | None,
    out_size: tuple[int, int],
) -> npt.NDArray[np.float64]:
    """Exact variance (H, W) at every output pixel of a frame without a local part.

    With b(x) = sum_c w_c u(g_c), ||F b(x)||^2 = sum_c,c' w_c w_c' <F u(g_c), F u(g_c')>
    for the frame's factor F, and likewise b(x)^T P b(x): the inner products of each grid
    point with its right, lower and two diagonal neighbours (``base`` for the prior, None
    in the coefficient form) make the bilinear quadratic form exact at every pixel. The
    bilinear weights are separable: first along x for each grid row, then along y.
    """
    gh, gw = basis.grid_size
    factor = _factor(posterior)
    projected = (factor @ basis.component_rows).reshape(factor.shape[0], gh, gw)
    products = _neighbour_products(projected)
    if base is not None:
        products = base - products
    x0, x1, fx = _axis_weights(out_size[1], gw)
    y0, y1, fy = _axis_weights(out_size[0], gh)
    # along x: the same-row form and the form with the next grid row, (gh, W) each
    same = (
        (1 - fx) ** 2 * products[0][:, x0]
        + fx**2 * products[0][:, x1]
        + 2 * fx * (1 - fx) * products[1][:, x0]
    )
    below = (
        (1 - fx) ** 2 * products[2][:, x0]
        + fx**2 * products[2][:, x1]
        + fx * (1 - fx) * (products[3][:, x0] + products[4][:, x0])
    )
    fy = fy[:, None]
    variance: npt.NDArray[np.float64] = (
        (1 - fy) ** 2 * same[y0] + fy**2 * same[y1] + 2 * fy * (1 - fy) * below[y0]
    )
    return variance


def _axis_weights(
    count: int, grid_count: int
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.float64]]:
    """Grid cells (i0, i1) and weights of i1 of ``count`` pixel centres along one axis.

    The one-axis factor of :func:`basis.bilinear_weights` (pixel-centre aligned, clamped
    to the border).
    """
    position = np.clip(_image_coordinates(count, grid_count), 0.0, grid_count - 1)
    first = np.minimum(np.floor(position).astype(np.intp), max(grid_count - 2, 0))
    second = np.minimum(first + 1, grid_count - 1)
    return first, second, position - first


def prior_std_map(basis: Basis) -> npt.NDArray[np.float32]:
    """The prior's disparity std on the basis grid (px): sqrt(diag(B Lambda B^T) + v).

    v is the variance of the basis's fitted local prior (0 without one). What the
    ``"prior_std"`` fill placement weighs its points by (:mod:`.frontend.fill`).
    """
    local = basis.meta.get("prior", {}).get("local")
    variance = float(local["variance"]) if isinstance(local, dict) else 0.0
    return np.asarray(np.sqrt(basis.prior_variance + np.float32(variance)), np.float32)


def innovation_variance_scale(
    scale: float, variance: npt.NDArray[np.float32], prior_variance: npt.NDArray[np.float32]
) -> npt.NDArray[np.float32] | float:
    """The factor on a frame's posterior variance from its covariance scale a.

    a (:func:`prior.covariance_scale`) is fitted from the frame's measurements: how far
    they stray from the prior, at the measurements. Where the posterior is still the prior
    (nothing measured near enough to reduce the variance) the frame has not said how far
    the prior errs, so a < 1 (measurements agreeing with the prior) narrows the variance
    only by the share its measurements explain:

        factor = a + (1 - a) r,  r = clip(var / var_prior, 0, 1)

    1 where the posterior keeps the prior's variance, a where the measurements pin it
    down. a >= 1 (measurements disagreeing) widens everywhere as before.

    Args:
        scale: the frame's covariance scale a (> 0).
        variance: the frame's posterior variance (any shape).
        prior_variance: the static prior's variance at the same points (same shape).

    Returns:
        a (a float) or the factor (the shape of ``variance``) float32.
    """
    if scale >= 1.0:
        return scale
    with np.errstate(divide="ignore", invalid="ignore"):
        share: npt.NDArray[np.float32] = np.divide(variance, prior_variance, dtype=np.float32)
    share[~(share <= 1.0)] = 1.0  # NaN (0 / 0): nothing to explain
    np.maximum(share, 0.0, out=share)
    share *= np.float32(1.0 - scale)
    share += np.float32(scale)
    return share


NEAR_RANGE_START = 0.75
"""Where :func:`widen_near_range` starts widening the std: this share of the matcher's range."""

NEAR_RANGE_SLOPE = 1.0
"""How fast :func:`widen_near_range` widens the std: px of std per px of disparity beyond
:data:`NEAR_RANGE_START`."""


def widen_near_range(
    disparity: npt.NDArray[np.float32], std: npt.NDArray[np.float32], match_range: float
) -> npt.NDArray[np.float32]:
    """Widen the std where the estimate nears the largest disparity the matcher measures.

    A surface nearer than the matcher's range has no measurements of its own: the estimate
    there is pulled towards the farther points around it and falls short of the truth, by
    more the nearer the surface, while the posterior std knows nothing of the range. The std
    is widened as std'^2 = std^2 + (s max(0, d - r0))^2, r0 = ``NEAR_RANGE_START`` x the range
    and s = ``NEAR_RANGE_SLOPE``: chosen by the Gaussian log-likelihood of the synthetic
    drives' dense truth (their near objects lie beyond SGBM's 128 px) among the settings
    that leave a real indoor log alone, whose near surfaces SGBM measures at 64-96 px (a
    start at half the range widened a fifth of its std and lowered its log-likelihood).

    Args:
        disparity: (H, W) the estimate (px).
        std: (H, W) its std (px); changed in place where widened and returned.
        match_range: the largest disparity the measurements can have (px, > 0).

    Returns:
        ``std``.
    """
    start = np.float32(NEAR_RANGE_START * match_range)
    # flat indices: ~4x faster than a boolean mask where the near pixels are scattered
    near = np.flatnonzero(disparity > start)
    if near.size:
        excess = (disparity.take(near) - start) * np.float32(NEAR_RANGE_SLOPE)
        np.put(std, near, np.sqrt(np.square(std.take(near)) + np.square(excess)))
    return std


BORDER_GAIN = 0.5
"""How much :func:`widen_at_border` widens the outermost pixel's std (share of its std)."""


def widen_at_border(
    std: npt.NDArray[np.float32], margins: tuple[float, float]
) -> npt.NDArray[np.float32]:
    """Widen the std between the outermost variance-grid cell centres and the image border.

    The variance grid's outermost cell centres sit half a variance cell inside the image
    (0.5 x the output size / the grid's size: 8 px at the basis's own image size with the
    default 1/16 grid, 3.9 px on a 620x188 log with the street basis); the bilinear
    resampling holds the std constant beyond them while the estimate, extrapolated past
    the last measurements, keeps drifting (bug hunt 17D F4: 44-62 % inside +-2 sigma in
    the outermost rows / columns of the synthetic logs). The std is widened there by a
    ramp, std' = std (1 + g t), t = 1 - i / margin for the i-th pixel from the border
    (1 at the outermost pixel; the last ramped pixel, i = ceil(margin) - 1, gets a little
    over 1, e.g. x1.06 at margin 8), per side (a corner pixel gets both factors: x2.25),
    g = ``BORDER_GAIN``: the outermost 8 px then hold 93.8-100 % on the synthetic and real
    sources (docs/options.md, "The std at depth edges and at the border"). In dense mode
    the fusion weighs SGBM against this std, so the fused estimate moves there too.

    Args:
        std: (H, W) the std (px); changed in place and returned.
        margins: (rows, columns) px between the border and the outermost cell centres;
            an axis whose margin is below 2 px is left alone.

    Returns:
        ``std``.
    """
    height, width = std.shape
    for axis, (size, margin) in enumerate(((height, margins[0]), (width, margins[1]))):
        if margin < 2.0:  # a fine grid (cells under 4 px): the clamp spans a px or so
            continue
        steps = np.arange(int(np.ceil(margin)), dtype=np.float32)  # 0 = outermost px
        ramp = 1.0 + np.float32(BORDER_GAIN) * np.clip(1.0 - steps / np.float32(margin), 0, 1)
        count = min(steps.size, size // 2)
        for index in range(count):
            factor = ramp[index]
            if axis == 0:
                lines = (std[index], std[size - 1 - index])
            else:
                lines = (std[:, index], std[:, size - 1 - index])
            for line in lines:
                line *= factor
    return std


def off_plane(
    disparity: npt.NDArray[np.float32], sigma: float, window: int
) -> npt.NDArray[np.float32]:
    """Return how far the estimate bends away from a plane near each pixel (px).

    |d - G_sigma * d| (a Gaussian blur preserves a plane, and a plane in the scene is a
    plane in disparity), its maximum over a ``window`` x ``window`` neighbourhood: zero on
    planar surfaces (the ground, walls), large along the smoothed depth steps where the
    estimate errs most (bug hunt 17D F1).

    Args:
        disparity: (H, W) the estimate (px; NaN read as 0).
        sigma: the blur's std (px).
        window: the neighbourhood's side (px, odd).

    Returns:
        (H, W) float32.
    """
    values = np.nan_to_num(disparity, nan=0.0).astype(np.float32, copy=False)
    blurred = cv2.GaussianBlur(values, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    bend = np.abs(values - np.asarray(blurred, dtype=np.float32))
    if window > 1:
        bend = np.asarray(cv2.dilate(bend, np.ones((window, window), np.uint8)), np.float32)
    return bend


EDGE_WIDENING = (0.85, 6.0, 9, 2.0)
"""(a, sigma, window, b) of :func:`widen_off_plane`: the setting measured in docs/options.md."""


def widen_off_plane(
    disparity: npt.NDArray[np.float32],
    std: npt.NDArray[np.float32],
    setting: tuple[float, float, int, float] = EDGE_WIDENING,
) -> npt.NDArray[np.float32]:
    """Return the std widened where the estimate bends (depth edges), the rest narrowed.

    std' = sqrt((a std)^2 + (b off_plane(d))^2). Not applied by ``densify``: it lifts the
    +-2 sigma coverage at depth edges (synthetic street 80.7 -> 86.4 %, 1280x720 65.9 ->
    83.2 %, indoor 35 -> 58 %) and the Gaussian NLL, but narrows them on the real indoor
    pair (EuRoC against SGBM 82.3 -> 80.4 %) and the fisheye log (docs/options.md, "The
    std at depth edges and at the border"; ``tools/std_regions.py`` measures it on a
    densified log).

    Args:
        disparity: (H, W) the estimate (px).
        std: (H, W) its std (px); not changed.
        setting: (a, sigma, window, b).

    Returns:
        (H, W) float32, the widened std.
    """
    scale, sigma, window, gain = setting
    bend = off_plane(disparity, sigma, window)
    return np.asarray(np.hypot(np.float32(scale) * std, np.float32(gain) * bend), np.float32)


def widen_near_group(
    disparity: npt.NDArray[np.float32],
    std: npt.NDArray[np.float32],
    pixels: npt.NDArray[np.float64],
    disparities: npt.NDArray[np.float64],
    radius: float,
    others: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None,
) -> npt.NDArray[np.float32]:
    """Widen the std on the surface of a group of measurements the prior could not reach.

    A group of measurements that agree with each other but not with the prior (a near
    object measured by the near-reach match, :func:`solve._consistent_group`) is kept in
    the fit, but the prior's smooth kernel cannot follow it far: between and around its
    points the estimate falls back towards the prior while the surface may go on. Within
    ``radius`` of a member the std is widened as std' = std + |g| / 2, g the gap between
    the nearest member's disparity and the estimate (the +-2 std band reaches the member's
    value with the model's own +-2 std beyond it), on the group's own surface only: inside
    the group (the members' closing by ``radius``), where a member is the nearest
    measurement, where the estimate is nearer the member's value than the nearest other
    measurement's, or more than 2 std off that one. The background beside a near object,
    whose estimate keeps its own measurements' value, is left alone (review 59c F4). The
    nearest member / other measurement comes from distance transforms of the members'
    bounding box plus ``radius`` on a grid of ``radius`` / 16 (the widening is drawn on it,
    nearest-neighbour upsampled), not member by member: a few ms at 1280x720.

    Args:
        disparity: (H, W) the estimate (px).
        std: (H, W) its std (px); changed in place where widened and returned.
        pixels: (m, 2) the members' (x, y) (px of the output image).
        disparities: (m,) the members' disparities (px).
        radius: how far from a member the std is widened (px).
        others: the other measurements' (n, 2) (x, y) and (n,) disparities; None: the
            std is widened all round each member.

    Returns:
        ``std``.
    """
    if pixels.shape[0] == 0:
        return std
    height, width = disparity.shape
    x0, y0 = (np.floor(pixels.min(axis=0) - radius).astype(int)).clip(0)
    x1 = min(width, int(np.ceil(pixels[:, 0].max() + radius)) + 1)
    y1 = min(height, int(np.ceil(pixels[:, 1].max() + radius)) + 1)
    window = (slice(y0, y1), slice(x0, x1))
    # which pixels are the group's and the nearest member's value: on a grid of radius / 16
    step = max(1, int(radius // 16))
    box = (0, 0, -(-(x1 - x0) // step), -(-(y1 - y0) // step))
    origin = np.array([x0, y0], dtype=np.float64)
    nearest, value = _nearest_value((pixels - origin) / step, disparities, box)
    estimate = disparity[window][::step, ::step]
    gap = np.abs(value - estimate)
    own = nearest <= radius / step
    if others is not None and others[0].shape[0]:
        apart, other = _nearest_value((others[0] - origin) / step, others[1], box)
        off = np.abs(other - estimate)
        inside = cv2.distanceTransform(own.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        spread = std[window][::step, ::step]
        own &= (inside >= 0.95 * radius / step) | (nearest <= apart)
        own |= (nearest <= radius / step) & ((gap < off) | (off > 2.0 * spread))

    # each sample over its step x step block; the gap itself at every pixel
    def blocks(grid: npt.NDArray[Any]) -> npt.NDArray[Any]:
        up = cv2.resize(grid, None, fx=step, fy=step, interpolation=cv2.INTER_NEAREST)
        return np.asarray(up)[: y1 - y0, : x1 - x0]

    half = np.abs(blocks(value) - disparity[window]) * np.float32(0.5)  # any float dtype
    view = std[window]
    np.add(view, half, out=view, where=blocks(own.astype(np.uint8)) > 0)
    return std


def _nearest_value(
    pixels: npt.NDArray[np.float64],
    values: npt.NDArray[np.float64],
    box: tuple[int, int, int, int],
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Return the distance (px) to and the value of the nearest point over ``box``'s pixels.

    ``box`` is (x0, y0, x1, y1), end exclusive; points outside it are moved to its edge: the
    distance is then a lower bound and the value theirs, so near the box's edge a point
    outside it may count as nearer than it is (it decides only which pixels there widen).
    """
    x0, y0, x1, y1 = box
    cols = np.clip(np.rint(pixels[:, 0]).astype(int) - x0, 0, x1 - x0 - 1)
    rows = np.clip(np.rint(pixels[:, 1]).astype(int) - y0, 0, y1 - y0 - 1)
    seeds = np.ones((y1 - y0, x1 - x0), dtype=np.uint8)
    seeds[rows, cols] = 0
    distance, labels = cv2.distanceTransformWithLabels(
        seeds, cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
    )
    lookup = np.zeros(int(labels.max()) + 1, dtype=np.float32)
    lookup[labels[rows, cols]] = values  # points sharing a pixel: one of their values
    return np.asarray(distance, dtype=np.float32), lookup[labels]
