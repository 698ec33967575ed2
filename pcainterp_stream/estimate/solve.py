"""The MAP solve of one frame (paper section III-B).

Coefficient or measurement form, the hybrid prior's local part, robust IRLS, and the
triangular-BLAS helpers they share.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from pcainterp_stream.compiled import hold_scipy_blas_at_one_thread, one_blas_thread_when_loaded
from pcainterp_stream.estimate.cells import Cells, node_along
from pcainterp_stream.estimate.lapack import routines
from pcainterp_stream.estimate.prior import (
    DOWNWEIGHTED_BELOW,
    GROUP_AGREE,
    GROUP_BEYOND,
    GROUP_RADIUS,
    GROUP_SIZE,
    GROUP_SPREAD,
    MAD_TO_STD,
    REJECT_FROM,
    REJECTED_WEIGHT,
    LocalPrior,
    Model,
    Robust,
    RobustStart,
    TemporalPrior,
    evidence_noise,
    robust_weights,
)

_Float = TypeVar("_Float", np.float32, np.float64)


DEFAULT_SIGMA = 2.0


"""Measurement noise std (px), the paper's value."""


_LOCAL_BLOCKS = 8


"""Column blocks of the local map when the kernel's support is short (``_local_mean``)."""


class SolveForm(StrEnum):
    """Which linear system computes the MAP estimate."""

    AUTO = "auto"
    """Measurement form when k < l, otherwise coefficient form."""
    COEFFICIENT = "coefficient"
    """l x l system (paper's form)."""
    MEASUREMENT = "measurement"
    """k x k system (Woodbury)."""


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
    # the edge-aware kernel's partition (prior.LocalPrior.cell_weight < 1), or None
    cells: Cells | None = None


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
    # the measurements kept as a group the prior cannot reach (_consistent_group), or None
    group: npt.NDArray[np.bool_] | None = None


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
            coefficients,
            coefficient_variance,
            factor,
            True,
            form,
            sigma=sigma,
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
        coefficients,
        coefficient_variance,
        factor,
        False,
        form,
        sigma=sigma,
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
    cells: Cells | None = None,
) -> _Posterior:
    """The estimate with the additions of ``prior.py``, in measurement space.

    Temporal prior first; when its normalised innovation fails the test the frame is solved
    again with the static prior (and the state restarts from that posterior). ``cells``:
    the measurements' partition for an edge-aware local prior (:mod:`cells`), or None.
    """
    if temporal is not None:  # a repeated frame: predicted from the previous frame's prior
        measured = (positions, residual)
        temporal.repeats(*measured, *(() if extra_variance is None else (extra_variance,)))
    predicted = temporal.predict(eigenvalues) if temporal is not None else None
    if cells is not None and (model.local is None or not model.local.edge_aware):
        cells = None
    local_matrix = None
    if model.local is not None and rows.shape[0]:
        if cells is None:
            local_matrix = model.local.matrix(positions)
        else:  # each measurement with every one of its cell (itself too)
            pairs = cells.members(cells.point_cells)
            local_matrix = model.local.matrix(positions, cells.point_cells, pairs=pairs)
    posterior = _solve_measurement(
        rows,
        residual,
        positions,
        eigenvalues,
        model,
        predicted,
        local_matrix,
        need_factor=need_factor,
        extra_variance=extra_variance,
        cells=cells,
    )
    if predicted is not None and temporal is not None:
        if not temporal.accepts(posterior.normalised_innovation):
            temporal.resets += 1
            posterior = _solve_measurement(
                rows,
                residual,
                positions,
                eigenvalues,
                model,
                None,
                local_matrix,
                need_factor=need_factor,
                label="reset",
                extra_variance=extra_variance,
                cells=cells,
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
    cells: Cells | None = None,
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
    scale = 1.0
    if model.sigma is not None:
        sigma = model.sigma
    else:  # sigma and the prior's scale by the evidence (on top of known extra noise)
        sigma, scale = evidence_noise(signal, innovation, extra_variance)
    if not np.isfinite(sigma):  # no measurements: nothing to fit
        sigma, scale = DEFAULT_SIGMA, 1.0
    weights = np.ones(k)
    noise = sigma**2 if extra_variance is None else sigma**2 + extra_variance
    noise = noise / scale  # the unit prior with the fit's noise-to-signal ratio; sigma is s
    iterations = model.robust_iterations if model.robust is not Robust.NONE else 0
    rejected = np.zeros(k, dtype=bool)  # left out by the trimmed start, for good
    group = None
    for iteration in range(iterations + 1):
        # K = signal + R, R on the diagonal of the factorisation's own copy
        lower_inverse = _cholesky_inverse(signal, noise / weights) if k else np.zeros((0, 0))
        alpha = lower_inverse.T @ (lower_inverse @ innovation)  # K^-1 (z~ - B~ mu)
        if iteration == iterations:
            break
        # leave-one-out standardised residuals: alpha_j / sqrt([K^-1]_jj)
        inverse_diagonal = np.einsum("ij,ij->j", lower_inverse, lower_inverse)
        standardised = alpha / np.sqrt(inverse_diagonal)
        if iteration == 0 and not np.max(np.abs(standardised), initial=0.0) >= model.robust_from:
            break  # no outlier: the unweighted solve stands (weights 1)
        if iteration == 0 and model.robust_start is RobustStart.TRIMMED:
            # the suspects: beyond robust_from, in the residuals' own spread when one point
            # pulled the fit so far that most of the others are beyond it too
            spread = max(1.0, MAD_TO_STD * float(np.median(np.abs(standardised))))
            trimmed = _trimmed_residuals(
                signal, noise, innovation, np.abs(standardised) >= model.robust_from * spread
            )
            if trimmed is not None:
                standardised, rejected = trimmed, np.abs(trimmed) >= REJECT_FROM
        updated = robust_weights(standardised, model.robust)
        updated[rejected] = REJECTED_WEIGHT
        converged = bool(np.max(np.abs(updated - weights), initial=0.0) < 1e-3)
        weights = updated
        if converged:
            # one more solve with the final weights
            iterations = iteration + 1
        if iteration + 1 == iterations:  # the weights of the last solve: a group kept
            # the trimmed start's rejections stand (tuned on other systems' clouds)
            group = _consistent_group(positions, innovation, weights) & ~rejected
            weights[group] = 1.0
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
            cells=cells,
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
        group=group if group is not None and group.any() else None,
    )


def _consistent_group(
    positions: npt.NDArray[np.float64],
    innovation: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64],
) -> npt.NDArray[np.bool_]:
    """Return the down-weighted measurements (k,) that a group of their neighbours agrees with.

    A down-weighted measurement whose innovation has the same sign as a down-weighted
    neighbour's (within :data:`prior.GROUP_RADIUS` basis px) and is within
    :data:`prior.GROUP_AGREE` of it is linked to it; the linked sets of at least
    :data:`prior.GROUP_SIZE` measurements are returned: a surface the prior cannot reach
    (a near object measured by the near-reach match), not outliers.
    """
    down = np.flatnonzero(weights < DOWNWEIGHTED_BELOW)
    group = np.zeros(weights.size, dtype=bool)
    if down.size < GROUP_SIZE:
        return group
    where = positions[down]
    value = innovation[down]
    distance = np.hypot(*(where[:, None, :] - where[None, :, :]).transpose(2, 0, 1))
    larger = np.maximum(np.abs(value[:, None]), np.abs(value[None, :]))
    linked = (
        (distance <= GROUP_RADIUS)
        & (np.sign(value[:, None]) == np.sign(value[None, :]))
        & (np.abs(value[:, None] - value[None, :]) <= GROUP_AGREE * larger)
    )
    labels = np.arange(down.size)
    while True:  # each one takes the smallest label it is linked to, until none changes
        lowest = np.where(linked, labels[None, :], down.size).min(axis=1)
        if np.array_equal(lowest, labels):
            break
        labels = lowest
    typical = float(np.median(np.abs(innovation)))  # the frame's typical misfit
    for label in np.flatnonzero(np.bincount(labels, minlength=down.size) >= GROUP_SIZE):
        members = np.flatnonzero(labels == label)
        centre = float(np.median(value[members]))
        # beyond the prior's reach: far off it next to the frame's typical misfit (a
        # near object beyond the matcher's range), not a modest offset the links chained
        if abs(centre) < GROUP_BEYOND * typical:
            continue
        # the group's own surface: members off its median are left out (an occlusion band's
        # matches beside a near object are linked through neighbours, not like the object)
        spread = MAD_TO_STD * float(np.median(np.abs(value[members] - centre)))
        limit = min(GROUP_AGREE, max(3.0 * spread / abs(centre), GROUP_SPREAD)) * abs(centre)
        members = members[np.abs(value[members] - centre) <= limit]
        if members.size >= GROUP_SIZE:
            group[down[members]] = True
    return group


def _trimmed_residuals(
    signal: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64] | float,
    innovation: npt.NDArray[np.float64],
    suspect: npt.NDArray[np.bool_],
) -> npt.NDArray[np.float64] | None:
    """Standardised residuals t_j (k,) against the solve without the ``suspect`` points.

    A kept point's is its leave-one-out residual in that solve; a suspect's is its
    residual against that solve's prediction over the predictive std with its own noise,
    (z~_j - K_jS K_SS^-1 z~_S) / sqrt(K_jj - K_jS K_SS^-1 K_Sj) (:attr:`prior.RobustStart.
    TRIMMED`). None when half of the points or more are suspects (nothing to trim against).
    """
    k = innovation.size
    kept = ~suspect
    if 2 * np.count_nonzero(kept) <= k:  # most are suspects: nothing to trim them against
        return None
    noise_of = np.broadcast_to(np.asarray(noise, dtype=np.float64), (k,))
    lower_inverse = _cholesky_inverse(signal[np.ix_(kept, kept)], noise_of[kept])
    alpha = lower_inverse.T @ (lower_inverse @ innovation[kept])
    standardised = np.empty(k)
    standardised[kept] = alpha / np.sqrt(np.einsum("ij,ij->j", lower_inverse, lower_inverse))
    cross = signal[np.ix_(kept, suspect)]  # K_Sj: the suspects' covariance with the kept
    projected = lower_inverse @ cross
    variance = signal[suspect, suspect] + noise_of[suspect]
    variance -= np.einsum("ij,ij->j", projected, projected)
    standardised[suspect] = (innovation[suspect] - cross.T @ alpha) / np.sqrt(variance)
    return standardised


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
    whole_x = None  # (k, W): every measurement's x factor at every column, when computed
    step = -(-width // blocks)
    for start in range(0, width, step):
        columns = xs[start : start + step]
        first = int(np.searchsorted(position_x, columns[0] - support, side="left"))
        last = int(np.searchsorted(position_x, columns[-1] + support, side="right"))
        if first < last:
            along_x = local.prior.axis(position_x[first:last], columns, np.float32)
            dense[:, start : start + step] = along_y[first:last].T @ along_x
            if blocks == 1 and first == 0 and last == order.size:
                whole_x = along_x
    if local.cells is None:
        return dense
    # the edge-aware kernel: w times the stationary part plus (1 - w) times each point's
    # own cell's, sum over j in cell(x) of v alpha_j k(x - p_j), from the same factors
    if whole_x is None:
        whole_x = local.prior.axis(position_x, xs, np.float32)
    weight = local.prior.cell_weight
    dense *= np.float32(weight)
    rank = np.empty(order.size, np.intp)
    rank[order] = np.arange(order.size)  # each measurement's row of the factor tables
    dense += _own_cell_mean(
        local.cells, rank, along_y, whole_x, basis_image, np.float32(1.0 - weight)
    )
    return dense


@dataclass(frozen=True, eq=False)
class _Nodes:
    """Where the points of a grid (rows ys x columns xs) fall on a cell grid (R, C).

    Attributes:
        row, column: (len(ys),), (len(xs),) the cell-grid row of each y, column of each x.
        node_rows: (R * C, bh) the rows (index of ys) of each node's points, padded by
            repetition, nodes row-major.
        node_columns: (R * C, bw) the columns (index of xs) of each node's points, likewise.
        blocks: (R * C, bh * bw) intp, the flat index (row-major) of each node's points,
            len(ys) * len(xs) (one past the last) at the padding.
    """

    row: npt.NDArray[np.intp]
    column: npt.NDArray[np.intp]
    node_rows: npt.NDArray[np.intp]
    node_columns: npt.NDArray[np.intp]
    blocks: npt.NDArray[np.intp]


@functools.lru_cache(maxsize=4)
def _nodes(
    out_size: tuple[int, int], basis_image: tuple[int, int], cell_grid: tuple[int, int]
) -> _Nodes:
    """The :class:`_Nodes` of the grid ``out_size`` spanning the basis image (cached)."""
    ys = _image_coordinates(out_size[0], basis_image[0])
    xs = _image_coordinates(out_size[1], basis_image[1])
    row = node_along(ys, basis_image[0], cell_grid[0])
    column = node_along(xs, basis_image[1], cell_grid[1])
    rows_of, row_valid = _spans(row, cell_grid[0])
    columns_of, column_valid = _spans(column, cell_grid[1])
    # (R, C, bh, bw): the flat index of each node's points
    blocks = (rows_of * out_size[1])[:, None, :, None] + columns_of[None, :, None, :]
    valid = row_valid[:, None, :, None] & column_valid[None, :, None, :]
    blocks = np.where(valid, blocks, out_size[0] * out_size[1])
    nodes = _Nodes(
        row=row,
        column=column,
        node_rows=np.repeat(rows_of, cell_grid[1], axis=0),
        node_columns=np.tile(columns_of, (cell_grid[0], 1)),
        blocks=blocks.reshape(cell_grid[0] * cell_grid[1], -1),
    )
    for array in dataclasses.astuple(nodes):
        array.flags.writeable = False
    return nodes


def _own_cell_mean(
    cells: Cells,
    rank: npt.NDArray[np.intp],
    along_y: npt.NDArray[np.float32],
    along_x: npt.NDArray[np.float32],
    basis_image: tuple[int, int],
    factor: np.float32,
) -> npt.NDArray[np.float32]:
    """Return ``factor`` times sum over j in cell(x) of a_j(y) b_j(x) at the points of a grid.

    ``along_y`` (k, H) and ``along_x`` (k, W) hold each measurement's kernel factors at the
    grid's rows and columns (a_j with its coefficient, as the local mean's product uses
    them), measurement j in row ``rank[j]``; the grid spans the basis image pixel-centre
    aligned. Returns (H, W) float32. The cells are constant on each node of the cell grid,
    so with j(R, C) the first measurement of node (R, C)'s cell the term is
    a_j(y) b_j(x): a (H, C) table of a and a (R, W) table of b gathered from the factors,
    then to the points (a few passes over them, no loop). Few cells hold further
    measurements (carried ones in a seed's cell, several measurements on one node): their
    nodes are added block by block, one (node, measurement) pair at a time, in rank order.
    """
    height, width = along_y.shape[1], along_x.shape[1]
    grid = cells.labels.shape
    nodes = _nodes((height, width), basis_image, (grid[0], grid[1]))
    labels = cells.labels.reshape(-1)
    first = cells.first.take(labels).reshape(grid)
    present = first >= 0  # a cell whose seed was dropped has no measurement
    at = rank.take(np.where(present, first, 0))  # (R, C): the node's row of the factors
    weight = np.where(present, factor, np.float32(0.0))
    # (H, C): a_j(R(y), C)(y) times factor, and (R, W): b_j(R, C(x))(x)
    by_row = at.take(nodes.row, axis=0)
    by_row *= height
    by_row += np.arange(height)[:, None]
    table_y = along_y.take(by_row)
    table_y *= weight.take(nodes.row, axis=0)
    by_column = at.take(nodes.column, axis=1)
    by_column *= width
    by_column += np.arange(width)
    table_x = along_x.take(by_column)
    # one spare element past the points: the later ranks' padding adds there
    spill = np.empty(height * width + 1, np.float32)
    own: npt.NDArray[np.float32] = spill[:-1].reshape(height, width)
    np.multiply(table_y.take(nodes.column, axis=1), table_x.take(nodes.row, axis=0), out=own)
    # the later measurements of each node's cell, node by node: (node, j) pairs
    node, later = cells.members(labels, after=1)
    if node.size:
        row = rank.take(later)[:, None]
        block_y = along_y.take(row * height + nodes.node_rows.take(node, axis=0))
        block_y *= factor
        block_x = along_x.take(row * width + nodes.node_columns.take(node, axis=0))
        # each node's block of points, row by row (padding: a spare point past the last)
        values = np.repeat(block_y, block_x.shape[1], axis=1)
        values *= np.tile(block_x, (1, block_y.shape[1]))
        np.add.at(spill, nodes.blocks.take(node, axis=0).reshape(-1), values.reshape(-1))
    return own


def _spans(
    node: npt.NDArray[np.intp], count: int
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
    """The points of each of ``count`` nodes along an axis, padded: (count, n) indices and mask.

    ``node`` (non-decreasing) is the node of each point; a node's points are consecutive.
    Padding repeats the node's first point (or point 0) and is masked False.
    """
    sizes = np.bincount(node, minlength=count)
    starts = np.cumsum(sizes) - sizes
    offsets = np.arange(max(int(sizes.max(initial=0)), 1))
    valid = offsets < sizes[:, None]
    indices = np.where(valid, starts[:, None] + offsets, np.minimum(starts, node.size - 1)[:, None])
    return indices.astype(np.intp), valid


def _cross_covariance(
    local: _Local,
    ys: npt.NDArray[np.float64],
    xs: npt.NDArray[np.float64],
    basis_image: tuple[int, int],
) -> npt.NDArray[np.float32]:
    """c(P, x) (k, len(ys) * len(xs)) float32 at the points x of rows ys x columns xs.

    ``ys`` and ``xs`` are basis-image px; the separable kernel is one outer product per
    measurement. The edge-aware kernel, C(p_j, x) = v k(p_j - x) [w + (1 - w) 1{same
    cell}], is that product scaled by w, with v k itself at the pairs of x and the
    measurements of its own cell (about one per point).
    """
    along_y = local.prior.axis(local.positions[:, 1], ys, np.float32)
    along_x = local.prior.axis(local.positions[:, 0], xs, np.float32)
    variance = np.float32(local.prior.variance)
    k = local.alpha.size
    if local.cells is None:
        product = along_y[:, :, None] * along_x[:, None, :] * variance
        covariance: npt.NDArray[np.float32] = product.reshape(k, ys.size * xs.size)
        return covariance
    scaled = along_y * np.float32(local.prior.variance * local.prior.cell_weight)
    covariance = (scaled[:, :, None] * along_x[:, None, :]).reshape(k, ys.size * xs.size)
    at, j = local.cells.members(local.cells.at(xs, ys, basis_image).reshape(-1))
    row, column = np.divmod(at, xs.size)
    covariance[j, at] = along_y[j, row] * along_x[j, column] * variance
    return covariance


def _local_covariance(
    local: _Local, vgrid_size: tuple[int, int], basis_image: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """c(P, x) for x on the variance grid, (k, s_v) float32."""
    ys = _image_coordinates(vgrid_size[0], basis_image[0])
    xs = _image_coordinates(vgrid_size[1], basis_image[1])
    return _cross_covariance(local, ys, xs, basis_image)


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
        with one_blas_thread_when_loaded():
            from scipy.linalg import lapack
    except ImportError:  # pragma: no cover - scipy is a dependency
        return None
    hold_scipy_blas_at_one_thread()
    return lapack


def _cholesky_inverse(
    system: npt.NDArray[np.float64],
    diagonal: npt.NDArray[np.float64] | float | None = None,
) -> npt.NDArray[np.float64]:
    """Return L^-1 (lower triangular) of the Cholesky factor L L^T = system (+ diagonal).

    LAPACK ``dpotrf`` and a blocked triangular inverse through scipy's library (its
    OpenBLAS held at one thread, see :func:`triangular_lapack` and :mod:`.lapack`);
    numpy's general ``inv`` of the factor only when scipy is missing. ``diagonal`` is added
    to the diagonal of a copy; ``system`` is not modified.

    Raises:
        numpy.linalg.LinAlgError: the system is not positive definite.
    """
    unlocked = routines()
    if unlocked is not None:  # scipy's routines, the GIL released
        inverse, info = unlocked.cholesky_inverse(system, diagonal)
        if info != 0:
            raise np.linalg.LinAlgError(f"matrix is not positive definite (dpotrf info {info})")
        return inverse
    if diagonal is not None:  # pragma: no cover - scipy's wheels have the routines
        system = system.copy()
        system.flat[:: system.shape[0] + 1] += diagonal
    lapack = triangular_lapack()  # pragma: no cover - scipy's wheels have the routines
    if lapack is None:  # pragma: no cover - scipy is a dependency
        return np.tril(np.linalg.inv(np.linalg.cholesky(system)))
    lower, info = lapack.dpotrf(system, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix is not positive definite (dpotrf info {info})")
    inverse, info = lapack.dtrtri(lower, lower=1)
    if info != 0:  # pragma: no cover - a Cholesky factor has a positive diagonal
        raise np.linalg.LinAlgError(f"singular Cholesky factor (dtrtri info {info})")
    return np.asarray(inverse, dtype=np.float64)


def _lower_times(
    lower: npt.NDArray[_Float], matrix: npt.NDArray[_Float], *, overwrite: bool = False
) -> npt.NDArray[_Float]:
    """Return lower @ matrix for a lower-triangular ``lower`` (BLAS ``?trmm``, half a GEMM).

    BLAS is column-major: the C-ordered ``matrix`` is its transpose there, so the call
    computes matrix^T lower^T (right side, transposed triangle). ``overwrite``: the caller
    gives ``matrix`` up, and the product may be computed in it.
    """
    if lower.shape[0] == 0:
        return lower @ matrix
    unlocked = routines()
    if unlocked is not None:  # scipy's routine, the GIL released
        return unlocked.lower_times(lower, matrix, overwrite=overwrite)
    if triangular_lapack() is None:  # pragma: no cover - scipy is a dependency
        return lower @ matrix
    from scipy.linalg import blas

    trmm = blas.strmm if matrix.dtype == np.float32 else blas.dtrmm
    product = trmm(1.0, lower, np.ascontiguousarray(matrix).T, lower=1, side=1, trans_a=1)
    return np.ascontiguousarray(product.T)


def _add_product(
    total: npt.NDArray[_Float], left: npt.NDArray[_Float], right: npt.NDArray[_Float]
) -> None:
    """``total += left @ right`` in place, C-ordered arrays of one float type (BLAS ``?gemm``)."""
    unlocked = routines()
    if unlocked is not None:  # scipy's routine, the GIL released, no temporary product
        unlocked.add_product(total, left, right)
        return
    total += left @ right  # pragma: no cover - scipy's wheels have the routines
