"""Dense fusion: the whole SGBM map fused with the sparse estimate.

``--measurements dense``. The sparse mode (:mod:`estimator`) keeps a few hundred SGBM
lookups and gives the MAP field f(x) with its posterior std s_f(x). Dense mode then uses
every pixel of the SGBM map, per pixel, with that field as the prior.

The true disparity of pixel x is d(x) = f(x) + g(x): g is the detail the field does not
hold, independent per pixel, g ~ N(0, tau^2). So the prior of pixel x is
N(f(x), v_f(x)), v_f = s_f^2 + tau^2.

**Where SGBM is valid** its value z measures d(x) with noise sigma_px and a Cauchy weight w
on its disagreement with the field, (z - f) / sqrt(v_f + sigma_px^2). The posterior is the
product of the two Gaussians:

    P = 1 / v_f + w / sigma_px^2,   d_hat = (f / v_f + w z / sigma_px^2) / P,   var = 1 / P.

A matcher may mark some of its values as weak (:class:`MapHoles`): matched, but less surely
than the others. Their value is fused as any matched pixel's, and their std is
sqrt(var + weak_std^2): the matcher's doubt added to the fusion's. (Giving them the noise
sigma_px^2 + weak_std^2 instead pulls them towards the field, which measured worse on real
truth: docs/dense.md.)

**In a hole** (no SGBM value: the left band, occlusions, sky, textureless road, speckles)
the pixel may continue the surface of one of its four directional nearest valid SGBM pixels
(left, right, up, down in its row and column; c_j at distance r_j px), or none of them. A
continued neighbour measures d(x) with a variance growing with the distance, q_j = a^2 +
b^2 r_j (a random walk from the measured pixel). The estimate is a mixture over the five
hypotheses. Hypothesis j has the Gaussian posterior

    m_j = (f / v_f + c_j / q_j) / (1 / v_f + 1 / q_j),   var_j = 1 / (1 / v_f + 1 / q_j)

and the weight pi_j exp(-(c_j - f)^2 / (2 (v_f + q_j))) sqrt(v_f / (v_f + q_j)), with
pi_j = 1 / (1 + r_j / L): the density of c_j under the field N(f, v_f + q_j) relative to
the field's own peak density, times a prior that favours near neighbours. "None" has
m_0 = f, var_0 = v_f and weight pi_0. So the field decides which side a hole belongs to:
an occlusion takes the background, the sky none of the buildings around it. The estimate is
the mixture mean d_hat = sum_j p_j m_j (p_j the normalised weights) and its variance the
mixture variance sum_j p_j (var_j + m_j^2) - d_hat^2.

What is approximated: the field is the sparse estimate's posterior, treated as independent
of the SGBM pixel it is fused with (the pixel entered the field only if it was one of the
few hundred lookups); g is independent between pixels; in holes the hypotheses' weights
are the relative densities above, not the full evidence of a joint model of the
neighbours (which would couple every hole pixel). The values of
:class:`DenseModel` were chosen by measurement (docs/results.md, "Dense mode", and
docs/dense.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import (
    DensifyResult,
    depth_from_disparity,
    disparity_array,
)
from pcainterp_stream.estimate.prior import ROBUST_SCALES, Robust, robust_weights
from pcainterp_stream.estimate.variance import _variance_stride

__all__ = [
    "DenseModel",
    "MapHoles",
    "directional_neighbours",
    "field_options",
    "find_holes",
    "fuse_dense",
]

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class DenseModel:
    """The noise model of dense fusion (module docstring for the maths).

    Attributes:
        pixel_std: sigma_px, noise std (px) of one valid SGBM pixel.
        detail_std: tau, std (px) of the per-pixel detail the field does not hold.
        neighbour_std: a, std (px) of a neighbour continued into the pixel next to it.
        neighbour_rate: b^2, variance (px^2) a continued neighbour adds per px of distance.
        neighbour_reach: L (px): a neighbour r px away is continued with prior weight
            1 / (1 + r / L).
        no_neighbour: pi_0, prior weight of "no neighbour continues" (the field alone).
        hole_std_scale: factor on the std in holes (a calibration on held-out frames).
        robust: loss on the SGBM pixels' disagreement with the field.
        weak_std: std (px) added (in quadrature) to the std of a map's weak pixels
            (:class:`MapHoles`: matched, but less surely, e.g. next to the holes of a
            half-resolution guide).
        field_std_coarsening: the field's std s_f is computed on a variance grid this many
            times coarser than sparse mode's (``estimator.densify``'s ``variance_stride``)
            and resampled: it weighs the field against SGBM's value, which dominates where
            it matched, and sets the holes' spread, which the neighbours dominate near
            the holes' edges; 2 costs ~4 ms less per KITTI frame for 0.001-0.002 px
            (docs/dense.md). 1: as sparse mode.
    """

    pixel_std: float = 0.75
    detail_std: float = 8.0
    neighbour_std: float = 1.0
    neighbour_rate: float = 0.1
    neighbour_reach: float = 1.0
    no_neighbour: float = 0.02
    hole_std_scale: float = 3.0
    robust: Robust = Robust.CAUCHY
    weak_std: float = 8.0
    field_std_coarsening: int = 2

    def __post_init__(self) -> None:
        for name in ("pixel_std", "detail_std", "neighbour_std", "neighbour_reach"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"Expected `{name}` > 0, got {value}")
        for name in ("neighbour_rate", "no_neighbour", "hole_std_scale", "weak_std"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"Expected `{name}` >= 0, got {value}")
        if self.hole_std_scale == 0:
            raise ValueError("Expected `hole_std_scale` > 0, got 0")
        if self.field_std_coarsening < 1:
            raise ValueError(
                f"Expected `field_std_coarsening` >= 1, got {self.field_std_coarsening}"
            )
        object.__setattr__(self, "robust", Robust(self.robust))


def field_options(basis: Basis, model: DenseModel | None = None) -> dict[str, Any]:
    """Return the keyword arguments of ``estimator.densify`` for dense mode's field.

    Its std's variance grid: ``model.field_std_coarsening`` times sparse mode's stride
    for ``basis``.
    """
    model = model or DenseModel()
    return {"variance_stride": model.field_std_coarsening * _variance_stride(basis, None)}


@dataclass(frozen=True)
class MapHoles:
    """A disparity map's holes and their four directional nearest valid pixels.

    What of the fusion depends on the map alone, not on the estimate: ``densify`` finds it
    in the stereo workers beside SGBM (:func:`find_holes`), so the sequential densify
    thread is left with the per-pixel arithmetic against the field.

    Attributes:
        shape: (H, W) of the map.
        index: (n,) flat (row-major) indices of the hole pixels (NaN, infinite, negative
            or, unless found with ``zero_is_match``, 0 values), ascending.
        neighbours: four (value, distance) pairs of (n,) float32 arrays, left, right, up,
            down: the nearest valid pixel in that direction along the hole's row or
            column; distance ``inf`` (value 0) where there is none.
        weak: flat indices of valid pixels whose value the matcher is less sure of
            (``DenseModel.weak_std``), ascending; empty for most matchers.
    """

    shape: tuple[int, int]
    index: npt.NDArray[np.intp]
    neighbours: tuple[tuple[F32, F32], ...]
    weak: npt.NDArray[np.intp] = dataclasses.field(default_factory=lambda: np.zeros(0, np.intp))


def find_holes(
    disparity_map: npt.ArrayLike,
    weak: npt.NDArray[np.bool_] | None = None,
    *,
    zero_is_match: bool = False,
) -> MapHoles:
    """Find a disparity map's holes and their directional neighbours (:class:`MapHoles`).

    Args:
        disparity_map: (H, W) float disparity (px), NaN, 0 or negative where there is none
            (16-bit integers raise, see :func:`fuse_dense`).
        weak: (H, W) bool, the matcher's weak pixels (``Measurements.weak``), or None.
        zero_is_match: a value of exactly 0 is a match at zero disparity (SGBM with
            ``minDisparity`` 0, as ``pcainterp densify``'s front end), not a hole.

    Returns:
        The holes, for :func:`fuse_dense`'s ``holes``.

    Raises:
        ValueError: the map is not 2-D, or ``weak`` is not of its shape.
        TypeError: the map is of 16-bit integers, boolean or complex.
    """
    values = np.ascontiguousarray(disparity_array(disparity_map, "disparity_map", np.float32))
    if values.ndim != 2:
        raise ValueError(f"Expected an (H, W) disparity map, got shape {values.shape}")
    if weak is not None and weak.shape != values.shape:
        raise ValueError(
            f"Expected weak pixels of the map's shape {values.shape}, got {weak.shape}"
        )
    with np.errstate(invalid="ignore"):
        matched = values >= 0 if zero_is_match else values > 0
        hole = ~(np.isfinite(values) & matched)
    index, neighbours = _hole_neighbours(values, hole)
    height, width = values.shape
    holes = MapHoles((height, width), index, tuple(neighbours))
    if weak is not None:
        holes = dataclasses.replace(holes, weak=np.flatnonzero(weak & ~hole))
    return holes


def fuse_dense(
    estimate: DensifyResult,
    disparity_map: npt.ArrayLike,
    model: DenseModel | None = None,
    holes: MapHoles | None = None,
    *,
    zero_is_match: bool = False,
) -> DensifyResult:
    """Fuse a frame's sparse estimate with its whole SGBM disparity map, pixel by pixel.

    Args:
        estimate: the frame's sparse MAP estimate (:func:`estimator.densify`), the field.
        disparity_map: (H, W) float SGBM disparity (px) of the same camera and size, NaN,
            0 or negative where the matcher found none (a hole: KITTI's PNGs code it 0,
            ``StereoSGBM.compute() / 16`` -1). 16-bit integers (the matchers' fixed point,
            16 or 256 x px) raise: divide them first.
        model: the noise model; None: the measured defaults.
        holes: :func:`find_holes` of ``disparity_map``, when already found (``densify``
            finds them in its stereo workers); None: found here. The result is the same.
        zero_is_match: with ``holes`` None, a value of exactly 0 is a match at zero
            disparity, not a hole (:func:`find_holes`).

    Returns:
        A :class:`DensifyResult` like ``estimate`` (same coefficients, points and weights)
        with the fused disparity, its std and the depth from them.

    Raises:
        ValueError: the map's (or the holes') shape differs from the estimate's.
        TypeError: the map is of 16-bit integers, boolean or complex.
    """
    model = model or DenseModel()
    values = disparity_array(disparity_map, "disparity_map", np.float32)
    field = np.asarray(estimate.disparity, dtype=np.float32)
    if values.shape != field.shape:
        raise ValueError(
            f"Expected a disparity map of the estimate's shape {field.shape}, got {values.shape}"
        )
    holes = find_holes(values, zero_is_match=zero_is_match) if holes is None else holes
    if holes.shape != field.shape:
        raise ValueError(f"Expected the holes of a {field.shape} map, got {holes.shape}")
    detail = np.float32(model.detail_std**2)
    index = holes.index
    hole_field = field.ravel().take(index)
    if estimate.disparity_std is None:
        hole_prior = np.full(index.shape, detail, np.float32)
    else:
        hole_prior = np.square(estimate.disparity_std.ravel().take(index), dtype=np.float32)
        hole_prior += detail
    hole_mean, hole_variance = _holes(holes, hole_field, hole_prior, model)
    # the matched pixels band by band (the temporaries stay in the cache); the holes' values
    # computed there are replaced below
    disparity = np.empty(field.shape, np.float32)  # C order: written through ravel() below
    std = None if estimate.disparity_std is None else np.empty(field.shape, np.float32)
    for top in range(0, field.shape[0], BAND_ROWS):
        rows = slice(top, top + BAND_ROWS)
        _fuse_matched(
            values[rows],
            field[rows],
            None if estimate.disparity_std is None else estimate.disparity_std[rows],
            model,
            disparity[rows],
            None if std is None else std[rows],
        )
    disparity.ravel()[index] = hole_mean
    if std is not None:
        std.ravel()[index] = np.sqrt(hole_variance) * np.float32(model.hole_std_scale)
        if holes.weak.size:  # the matcher's doubt, beside the fusion's
            weak = np.square(std.ravel().take(holes.weak)) + np.float32(model.weak_std**2)
            std.ravel()[holes.weak] = np.sqrt(weak)
    depth, depth_std = None, None
    if estimate.focal_baseline > 0:
        depth, depth_std = depth_from_disparity(
            disparity, std, estimate.focal_baseline, estimate.min_disparity
        )
    return dataclasses.replace(
        estimate, disparity=disparity, disparity_std=std, depth=depth, depth_std=depth_std
    )


BAND_ROWS = 24
"""Rows fused at a time: a KITTI-sized band's temporaries (~120 KB each) stay in the cache."""


def _fuse_matched(
    values: F32,
    field: F32,
    field_std: F32 | None,
    model: DenseModel,
    disparity: F32,
    std: F32 | None,
) -> None:
    """The posterior of matched pixels (module docstring) into ``disparity`` and ``std``.

    Elementwise over a band of rows; holes get meaningless values (or NaN).
    """
    detail = np.float32(model.detail_std**2)
    prior_variance: F32 = (
        np.full(field.shape, detail, np.float32)
        if field_std is None
        else np.square(field_std, dtype=np.float32) + detail
    )
    with np.errstate(invalid="ignore", over="ignore"):
        # the disagreement (z - f) / sqrt(v_f + sigma_px^2), then its robust weight, in place
        weight = values - field
        spread = prior_variance + np.float32(model.pixel_std**2)
        weight /= np.sqrt(spread, out=spread)
        weight = _robust_weights(weight, model.robust)
        weight *= np.float32(1.0 / model.pixel_std**2)  # w / sigma_px^2
        field_precision = np.reciprocal(prior_variance, out=prior_variance)  # 1 / v_f
        precision = field_precision + weight
        np.multiply(field, field_precision, out=disparity)
        weight *= values
        disparity += weight
        disparity /= precision
        if std is not None:
            np.sqrt(np.reciprocal(precision, out=precision), out=std)


def _robust_weights(standardised: F32, robust: Robust) -> F32:
    """:func:`prior.robust_weights` in float32, in place on ``standardised``."""
    if robust is Robust.NONE:
        return np.ones_like(standardised)
    if robust is Robust.HUBER:
        return robust_weights(standardised.astype(np.float64), robust).astype(np.float32)
    standardised *= np.float32(1.0 / ROBUST_SCALES[Robust.CAUCHY])
    standardised *= standardised
    standardised += np.float32(1.0)
    return np.reciprocal(standardised, out=standardised)


def _holes(holes: MapHoles, f: F32, v_f: F32, model: DenseModel) -> tuple[F32, F32]:
    """The mixture posterior (mean, variance) at the hole pixels, in ``holes.index`` order.

    ``f`` and ``v_f`` are the field and its variance at the holes.
    """
    one = np.float32(1.0)
    field_precision = one / v_f
    field_term = f / v_f
    total = np.full(f.shape, np.float32(model.no_neighbour))
    mean_sum = total * f
    second_sum = total * (v_f + f * f)
    base = np.float32(model.neighbour_std**2)
    rate = np.float32(model.neighbour_rate)
    length = np.float32(model.neighbour_reach)
    # in place, each with the same operations in the same order as written in the maths
    for value, distance in holes.neighbours:
        found = np.isfinite(distance)
        reach = np.where(found, distance, np.float32(0.0))
        spread = rate * reach
        spread += base
        both = v_f + spread
        weight = value - f  # the gap, then the weight
        weight *= np.float32(-0.5) * weight
        weight /= both
        np.exp(weight, out=weight)
        both = np.divide(v_f, both, out=both)
        weight *= np.sqrt(both, out=both)
        reach /= length
        reach += one
        weight /= reach
        weight[~found] = 0.0
        variance = np.divide(one, spread)
        variance += field_precision
        np.divide(one, variance, out=variance)
        mean = np.divide(value, spread, out=spread)
        mean += field_term
        mean *= variance
        total += weight
        variance += mean * mean
        mean *= weight
        mean_sum += mean
        variance *= weight
        second_sum += variance
    estimate = (mean_sum / total).astype(np.float32)
    spread_out = np.maximum(second_sum / total - estimate * estimate, np.float32(1e-6))
    return estimate, spread_out.astype(np.float32)


def _hole_neighbours(
    values: F32, hole: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.intp], list[tuple[F32, F32]]]:
    """The hole pixels (flat, row-major) and their four directional nearest valid pixels.

    Returns (value, distance) at the holes for left, right, up and down; distance ``inf``
    (value 0) where the row or column has no valid pixel on that side. The holes of a row
    form runs; every pixel of a run shares the valid pixel just before it and just after
    it, so the work is one pass over the mask per axis and then per run or per hole pixel,
    not per image pixel. Up and down are the runs of the transposed mask: their rows are
    written into a transposed image, transposed back and read at the holes.
    """
    height, width = hole.shape
    flat = np.flatnonzero(hole)
    if flat.size == 0:  # no holes (or no pixels): nothing to look for
        return flat, [(np.zeros(0, np.float32), np.zeros(0, np.float32)) for _ in range(4)]
    found = _along_rows(flat, values.ravel(), hole)
    hole_t = np.asarray(cv2.transpose(hole.view(np.uint8)), np.uint8).view(bool)
    _, first, past = _runs(hole_t)  # a column's runs: first row, one past the last
    length = past - first
    flat_t = np.flatnonzero(hole_t)  # the holes in column-major order
    # the rows above and below each hole, put back in row-major order by a transpose
    if height < np.iinfo(np.int16).max:
        rows = np.empty((flat_t.size, 2), np.int16)
        rows[:, 0] = np.repeat(first - 1, length)
        rows[:, 1] = np.repeat(past, length)
        packed = np.empty((width, height), np.int32)  # both rows of a pixel in one int32
        packed.ravel()[flat_t] = rows.view(np.int32).ravel()
        back = np.asarray(cv2.transpose(packed), np.int32).ravel().take(flat)
        pair = back.view(np.int16).reshape(-1, 2)
        sides = [pair[:, 0].astype(np.intp), pair[:, 1].astype(np.intp)]
    else:  # rows beyond int16: one transpose each
        sides = []
        for side in (first - 1, past):
            image = np.empty((width, height), np.int32)
            image.ravel()[flat_t] = np.repeat(side, length)
            back = np.asarray(cv2.transpose(image), np.int32).ravel().take(flat)
            sides.append(back.astype(np.intp))
    row = flat // width
    column_of = flat - row * width
    flat_values = values.ravel()
    for neighbour in sides:
        missing = (neighbour < 0) | (neighbour >= height)
        distance = np.abs(row - neighbour).astype(np.float32)
        distance[missing] = np.inf
        neighbour[missing] = 0
        neighbour *= width
        neighbour += column_of
        value = flat_values.take(neighbour)
        value[missing] = 0.0
        found.append((value, distance))
    return flat, found


def _runs(
    hole: npt.NDArray[np.bool_],
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """The runs of True along the rows of ``hole``, in row-major order.

    Returns each run's row, its first column and the column one past its last.
    """
    height, width = hole.shape
    padded = np.zeros((height, width + 2), np.int8)
    padded[:, 1:-1] = hole
    change = np.diff(padded, axis=1).ravel()  # +1 where a run starts, -1 one past its end
    starts = np.flatnonzero(change == 1)  # flat in the (H, W + 1) change image
    row = starts // (width + 1)
    first = starts - row * (width + 1)
    past = np.flatnonzero(change == -1) - row * (width + 1)
    return row, first, past


def _along_rows(
    flat: npt.NDArray[np.intp], values: F32, hole: npt.NDArray[np.bool_]
) -> list[tuple[F32, F32]]:
    """(value, distance) of the nearest valid pixel left and right of each hole pixel.

    ``flat``: the hole pixels' flat indices (row-major), ``values`` the map, flat. Value 0
    and distance ``inf`` where the row has no valid pixel on that side.
    """
    width = hole.shape[1]
    row, first, past = _runs(hole)
    length = past - first
    row *= width
    found = []
    sides = ((row + first - 1, first > 0, True), (row + past, past < width, False))
    for source, exists, left in sides:
        missing = ~exists
        source[missing] = 0
        value = values.take(source)  # one per run, then one per pixel
        value[missing] = 0.0
        at = np.repeat(source, length)
        gap = np.subtract(flat, at, out=at) if left else np.subtract(at, flat, out=at)
        distance = gap.astype(np.float32)
        distance[np.repeat(missing, length)] = np.inf
        found.append((np.repeat(value, length), distance))
    return found


def directional_neighbours(
    values: npt.ArrayLike, valid: npt.NDArray[np.bool_]
) -> list[tuple[F32, F32]]:
    """The nearest valid value and its distance to the left, right, above and below.

    Args:
        values: (H, W) float values.
        valid: (H, W) bool, where ``values`` count.

    Returns:
        Four (value, distance) pairs of (H, W) float32 arrays in the order left, right,
        up, down: the nearest valid pixel in that direction along the pixel's row or column
        (the pixel itself when it is valid: distance 0); distance ``inf`` (value 0) where
        there is none.
    """
    array = np.ascontiguousarray(values, dtype=np.float32)
    valid = np.ascontiguousarray(valid, dtype=bool)
    if array.shape != valid.shape or array.ndim != 2:
        raise ValueError(f"Expected values and valid of one (H, W) shape, got {array.shape}")
    flat, at_holes = _hole_neighbours(array, ~valid)
    found: list[tuple[F32, F32]] = []
    for hole_value, hole_distance in at_holes:
        value = np.where(valid, array, np.float32(0.0)).astype(np.float32)
        distance = np.zeros(array.shape, np.float32)
        value.ravel()[flat] = hole_value
        distance.ravel()[flat] = hole_distance
        found.append((value, distance))
    return found
