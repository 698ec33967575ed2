"""Dense fusion: the whole SGBM map as the measurement (issue 18, ``--measurements dense``).

The sparse mode (:mod:`estimator`) keeps a few hundred SGBM lookups. Here every valid SGBM
pixel is a measurement, in two layers.

**The field** (coarse, the PCA prior). The valid pixels are averaged onto measurement
cells, ``cell`` x ``cell`` basis-grid cells each (cv2 INTER_AREA, pixel-centre aligned like
:func:`basis.image_to_grid`); a cell whose valid share is below ``min_fraction`` is left out
(holes, borders, the left band, speckles). Cell c with n_c valid pixels, mean zbar_c and
spread s_c^2 of its pixels is one measurement of the basis's field averaged over the cell,

    zbar_c = a_c^T y + mbar_c + e_c,   e_c ~ N(0, R_c / w_c),
    R_c = (s_c^2 + sigma_px^2) / n_c + rho^2,

a_c the basis rows averaged over the cell the same way (INTER_AREA of each component), y ~
N(0, Lambda) the coefficients, sigma_px the noise of one SGBM pixel, rho the cell-level
representation error (what l components cannot hold), w_c robust (Cauchy) IRLS weights of
the standardised cell residuals. With S = A Lambda^(1/2) and W = diag(w / R), the posterior
is exact in coefficient space (an l x l system whatever the number of cells):

    G = I + S^T W S = L L^T,   y_hat = Lambda^(1/2) G^-1 S^T W (zbar - mbar),
    Sigma_y = Lambda^(1/2) G^-1 Lambda^(1/2),   var f(x) = ||L^-1 Lambda^(1/2) b(x)||^2,

with f(x) = b(x)^T y_hat + m(x) on the basis grid, resampled bilinearly to the image, and
its variance exact on the variance grid (:meth:`Basis.variance_grid`), resampled.

**The pixels.** The true disparity of pixel x is d(x) = f(x) + g(x), g the detail the field
does not hold, g ~ N(0, tau^2) independently per pixel. Where SGBM is valid it measures
d(x) with noise sigma_px and a Cauchy weight w_x on its disagreement with the field, so the
posterior is the product of two Gaussians:

    d_hat = (f / v_f + w_x z / sigma_px^2) / P,   var = 1 / P,   P = 1 / v_f + w_x / sigma_px^2,

v_f = var f(x) + tau^2. Where SGBM has no value (a hole) the estimate fuses the field with
the nearest valid SGBM pixel z_nn at distance r px, modelled as a measurement of d(x) whose
variance grows with the distance (a random walk from the nearest measured pixel):

    d_hat = (f / v_f + z_nn / v_nn) / P,   var = 1 / P,   P = 1 / v_f + 1 / v_nn,
    v_nn = a^2 + b^2 r.

What is approximated: the pixel layer takes the field as independent of the pixel's own
measurement (which entered the field through its cell mean, 1/n_c of it) and, in holes,
of the nearest pixel (a one-neighbour Vecchia approximation of the local model); every
other variance is exact for the model stated. sigma_px, rho, tau, a and b are
:class:`DenseModel` values chosen by measurement (docs/results.md, "Dense fusion").
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis, resample_grid
from pcainterp_stream.estimate.estimator import DensifyResult, depth_from_disparity
from pcainterp_stream.estimate.prior import Robust, robust_weights
from pcainterp_stream.estimate.solve import SolveForm, _cholesky_inverse
from pcainterp_stream.estimate.variance import Uncertainty, _variance_stride

__all__ = ["DenseModel", "aggregate_cells", "densify_dense"]


@dataclass(frozen=True)
class DenseModel:
    """The noise model and options of dense fusion (module docstring for the maths).

    Attributes:
        cell: measurement cell side in basis-grid cells (2: 8 x 8 px at KITTI size with
            the built-in basis's 1/4 grid).
        min_fraction: a cell is a measurement when at least this share of it is valid.
        pixel_std: sigma_px, noise std (px) of one valid SGBM pixel.
        cell_std: rho, representation error std (px) of a cell mean.
        detail_std: tau, std (px) of the per-pixel detail the field does not hold.
        nearest_std: a, std (px) of the nearest valid pixel as a measurement of a hole
            pixel right next to it.
        nearest_rate: b^2, variance (px^2) the nearest pixel loses per px of distance.
        robust: IRLS loss on the cells and the pixels (``"none"`` or ``"cauchy"``...).
        robust_iterations: IRLS reweightings of the cells.
    """

    cell: int = 2
    min_fraction: float = 0.5
    pixel_std: float = 1.0
    cell_std: float = 2.0
    detail_std: float = 8.0
    nearest_std: float = 2.0
    nearest_rate: float = 1.0
    robust: Robust = Robust.CAUCHY
    robust_iterations: int = 1

    def __post_init__(self) -> None:
        if self.cell < 1:
            raise ValueError(f"Expected `cell` >= 1 basis-grid cells, got {self.cell}")
        if not 0.0 < self.min_fraction <= 1.0:
            raise ValueError(f"Expected `min_fraction` in (0, 1], got {self.min_fraction}")
        for name in ("pixel_std", "cell_std", "detail_std", "nearest_std"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"Expected `{name}` > 0 (px), got {value}")
        if not (np.isfinite(self.nearest_rate) and self.nearest_rate >= 0):
            raise ValueError(f"Expected `nearest_rate` >= 0 (px^2 per px), got {self.nearest_rate}")
        if self.robust_iterations < 0:
            raise ValueError(f"Expected `robust_iterations` >= 0, got {self.robust_iterations}")
        object.__setattr__(self, "robust", Robust(self.robust))


@dataclass(frozen=True, eq=False)
class Cells:
    """A disparity map averaged onto measurement cells.

    Attributes:
        size: (height, width) of the cell grid.
        fraction: (height, width) float64, valid share of each cell.
        mean: (height, width) float64, mean of the valid pixels (NaN where none).
        spread: (height, width) float64, variance of the valid pixels about it (px^2).
        pixels_per_cell: image pixels per cell.
    """

    size: tuple[int, int]
    fraction: npt.NDArray[np.float64]
    mean: npt.NDArray[np.float64]
    spread: npt.NDArray[np.float64]
    pixels_per_cell: float


def aggregate_cells(disparity: npt.ArrayLike, size: tuple[int, int]) -> Cells:
    """Average the valid (finite, >= 0) pixels of a disparity map onto a cell grid.

    Args:
        disparity: (H, W) float, NaN (or negative) where invalid.
        size: (height, width) of the cell grid, at most the map's.

    Returns:
        The :class:`Cells`: INTER_AREA means of the valid pixels, their spread and share.
    """
    values = np.asarray(disparity, dtype=np.float32)
    if values.ndim != 2:
        raise ValueError(f"Expected a (H, W) disparity map, got shape {values.shape}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values >= 0)
    mask = valid.astype(np.float32)
    filled = np.where(valid, values, np.float32(0.0))
    dsize = (int(size[1]), int(size[0]))

    def area(image: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
        return np.asarray(cv2.resize(image, dsize, interpolation=cv2.INTER_AREA), np.float64)

    fraction = area(mask)
    total = area(filled)
    squares = area(filled * filled)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(fraction > 0, total / fraction, np.nan)
        spread = np.maximum(squares / fraction - mean * mean, 0.0)
    pixels = values.shape[0] * values.shape[1] / (size[0] * size[1])
    return Cells(
        size=(int(size[0]), int(size[1])),
        fraction=fraction,
        mean=mean,
        spread=np.where(fraction > 0, spread, np.nan),
        pixels_per_cell=pixels,
    )


def densify_dense(
    basis: Basis | None,
    disparity: npt.ArrayLike,
    *,
    focal_baseline: float | None = None,
    uncertainty: Uncertainty | str = Uncertainty.EXACT_COARSE,
    model: DenseModel | None = None,
    variance_stride: int | None = None,
) -> DensifyResult:
    """Fuse a whole (SGBM) disparity map with the PCA prior: complete, with its std.

    Args:
        basis: the PCA basis; None: the built-in one (:meth:`Basis.default`).
        disparity: (H, W) float disparity map (px) of the output camera, NaN where the
            matcher found none; H x W is the output size (any, mapped onto the basis).
        focal_baseline: f*b (px*m) of the map's camera (default: the basis's).
        uncertainty: ``"exact-coarse"`` (field std exact on the variance grid), ``"exact"``
            (on the basis grid itself) or ``"none"``; ``"paper"`` is a sparse-mode option.
        model: the noise model (:class:`DenseModel`; default values measured).
        variance_stride: the variance grid's coarsening (``"exact-coarse"``); None: auto.

    Returns:
        The :class:`DensifyResult`; its ``pixels`` and ``disparities`` are the centres and
        means of the cells used (the ``/pcainterp/features`` of dense mode), ``weights``
        their robust weights.

    Raises:
        ValueError: a bad shape or option.
    """
    basis = Basis.default() if basis is None else basis
    model = model or DenseModel()
    mode = Uncertainty(uncertainty)
    if mode is Uncertainty.PAPER:
        raise ValueError(
            'uncertainty "paper" is the sparse mode\'s diagonal approximation; dense mode '
            'reports the exact std ("exact-coarse", "exact") or none'
        )
    values = np.asarray(disparity, dtype=np.float32)
    if values.ndim != 2 or values.shape[0] < 1 or values.shape[1] < 1:
        raise ValueError(f"Expected a (H, W) disparity map, got shape {values.shape}")
    out_size = (int(values.shape[0]), int(values.shape[1]))
    fb_out = basis.focal_baseline if focal_baseline is None else float(focal_baseline)
    if not (np.isfinite(fb_out) and fb_out >= 0):
        raise ValueError(f"Expected `focal_baseline` > 0 (px*m), got {focal_baseline}")
    to_basis = basis.focal_baseline / fb_out if basis.focal_baseline > 0 and fb_out > 0 else 1.0

    # the field: cells -> coefficient-space posterior
    size = _cell_size(basis, model.cell)
    cells = aggregate_cells(values, size)
    used = (cells.fraction >= model.min_fraction).reshape(-1)
    rows, mean_rows = _cell_rows(basis, size)
    scaled_rows = rows[used] * np.sqrt(basis.eigenvalues).astype(np.float32)
    residual = cells.mean.reshape(-1)[used] * to_basis - mean_rows[used]
    count = cells.fraction.reshape(-1)[used] * cells.pixels_per_cell
    noise = (
        cells.spread.reshape(-1)[used] + model.pixel_std**2
    ) * to_basis**2 / count + model.cell_std**2
    weights = np.ones(residual.shape[0])
    iterations = model.robust_iterations if model.robust is not Robust.NONE else 0
    for iteration in range(iterations + 1):
        inverse_lower, scaled = _solve_cells(scaled_rows, residual, weights / noise)
        if iteration == iterations:
            break
        fitted = scaled_rows @ scaled.astype(np.float32)
        standardised = (residual - fitted) / np.sqrt(noise + model.cell_std**2)
        weights = robust_weights(standardised, model.robust)
    root = np.sqrt(basis.eigenvalues)
    coefficients = root * scaled
    coefficient_variance = basis.eigenvalues * np.einsum("ij,ij->j", inverse_lower, inverse_lower)
    grid = basis.pixel_major @ coefficients.astype(np.float32) + basis.mean_flat
    field = resample_grid(grid.reshape(basis.grid_size) * np.float32(1.0 / to_basis), out_size)

    field_variance = None
    if mode is not Uncertainty.NONE:
        stride = 1 if mode is Uncertainty.EXACT else _variance_stride(basis, variance_stride)
        vgrid = basis.variance_grid(stride)
        projected = (inverse_lower.astype(np.float32) * root.astype(np.float32)) @ (
            vgrid.component_rows
        )
        projected *= projected
        per_point = projected.sum(axis=0) * np.float32(1.0 / to_basis**2)
        field_variance = resample_grid(per_point.reshape(vgrid.size), out_size)

    disparity_map, std = _pixels(values, field, field_variance, model)
    min_disparity = model.pixel_std
    depth, depth_std = (None, None)
    if fb_out > 0:
        depth, depth_std = depth_from_disparity(disparity_map, std, fb_out, min_disparity)
    centres = _cell_centres(size, out_size)[used]
    return DensifyResult(
        disparity=disparity_map,
        disparity_std=std,
        depth=depth,
        depth_std=depth_std,
        coefficients=coefficients,
        coefficient_variance=coefficient_variance,
        pixels=centres,
        disparities=cells.mean.reshape(-1)[used],
        n_dropped=int(np.count_nonzero(~used)),
        solve_form=SolveForm.COEFFICIENT,
        uncertainty=mode,
        focal_baseline=fb_out,
        min_disparity=min_disparity,
        sigma=model.pixel_std,
        weights=weights,
        n_downweighted=int(np.count_nonzero(weights < 0.5)),
    )


def _solve_cells(
    scaled_rows: npt.NDArray[np.float32],
    residual: npt.NDArray[np.float64],
    precision: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Solve G a = S^T W r, G = I + S^T W S = L L^T; return (L^-1, a)."""
    n_components = scaled_rows.shape[1]
    weighted = scaled_rows * precision.astype(np.float32)[:, None]
    system = np.eye(n_components) + (weighted.T @ scaled_rows).astype(np.float64)
    inverse_lower = _cholesky_inverse(system)
    right = (weighted.T @ residual.astype(np.float32)).astype(np.float64)
    return inverse_lower, inverse_lower.T @ (inverse_lower @ right)


def _pixels(
    values: npt.NDArray[np.float32],
    field: npt.NDArray[np.float32],
    field_variance: npt.NDArray[np.float32] | None,
    model: DenseModel,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None]:
    """The per-pixel layer: SGBM pixels fused with the field; holes with the nearest pixel."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values >= 0)
    detail = np.float32(model.detail_std**2)
    prior_variance = detail if field_variance is None else field_variance + detail
    pixel_variance = np.float32(model.pixel_std**2)
    if not valid.any():
        std = None if field_variance is None else np.sqrt(prior_variance).astype(np.float32)
        return field.copy(), std
    measured = np.where(valid, values, field)
    disagreement = (measured - field) / np.sqrt(prior_variance + pixel_variance)
    weight = np.where(valid, robust_weights(disagreement, model.robust), 0.0).astype(np.float32)
    nearest, distance = _nearest_valid(values, valid)
    nearest_variance = np.float32(model.nearest_std**2) + np.float32(model.nearest_rate) * distance
    # precision P: from the field, plus the pixel's own SGBM value or else its nearest one
    own = weight / pixel_variance
    other = np.where(valid, np.float32(0.0), np.float32(1.0) / nearest_variance)
    precision = np.float32(1.0) / prior_variance + own + other
    estimate = field / prior_variance + own * measured + other * nearest
    estimate /= precision
    if field_variance is None:
        return estimate.astype(np.float32), None
    return estimate.astype(np.float32), np.sqrt(np.float32(1.0) / precision).astype(np.float32)


def _nearest_valid(
    values: npt.NDArray[np.float32], valid: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Each pixel's nearest valid value and its distance (px; 0 on valid pixels)."""
    distance, labels = cv2.distanceTransformWithLabels(
        (~valid).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    # labels number the valid (zero) pixels 1.. in row-major order
    lookup = np.concatenate([[np.float32(0.0)], values[valid]]).astype(np.float32)
    return lookup[labels], np.asarray(distance, np.float32)


_ROWS: dict[tuple[str, tuple[int, int]], tuple[npt.NDArray[np.float32], npt.NDArray[np.float64]]]
_ROWS = {}


def _cell_size(basis: Basis, cell: int) -> tuple[int, int]:
    gh, gw = basis.grid_size
    return (max(1, -(-gh // cell)), max(1, -(-gw // cell)))


def _cell_rows(
    basis: Basis, size: tuple[int, int]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float64]]:
    """The basis rows and mean averaged over each cell (INTER_AREA), (s_c, l) and (s_c,)."""
    key = (basis.fingerprint, size)
    cached = _ROWS.get(key)
    if cached is not None:
        return cached
    dsize = (size[1], size[0])
    components = [
        np.asarray(cv2.resize(c, dsize, interpolation=cv2.INTER_AREA), np.float32).reshape(-1)
        for c in basis.components
    ]
    rows = np.ascontiguousarray(np.stack(components, axis=1))
    mean = np.asarray(cv2.resize(basis.mean, dsize, interpolation=cv2.INTER_AREA), np.float64)
    if len(_ROWS) >= 4:
        _ROWS.pop(next(iter(_ROWS)))
    _ROWS[key] = (rows, mean.reshape(-1))
    return _ROWS[key]


def _cell_centres(size: tuple[int, int], out_size: tuple[int, int]) -> npt.NDArray[np.float64]:
    """(s_c, 2) (x, y) output-image px of the cell centres, pixel-centre aligned."""
    ys, xs = np.mgrid[0 : size[0], 0 : size[1]]
    x = (xs.ravel() + 0.5) * (out_size[1] / size[1]) - 0.5
    y = (ys.ravel() + 0.5) * (out_size[0] / size[0]) - 0.5
    return np.stack([x, y], axis=1).astype(np.float64)
