"""Learning a PCA basis of disparity maps (paper section III-A), streamed.

Each map is preprocessed in a fixed order (:func:`preprocess_disparity`):
invalid pixels take the nearest valid pixel's value, a 5x5 box filter, area resampling to
the basis grid. Then the mean m and the leading eigenpairs of C = D D^T / (n - 1) (D the
centred grid maps) are found without ever forming the s x s matrix C:

- ``exact``: the n x n Gram matrix D^T D (maps kept on the grid, so only for small n*s);
  u_i = D v_i / sqrt(e_i), lambda_i = e_i / (n - 1).
- ``streaming``: an incremental SVD over batches (as scikit-learn's IncrementalPCA, in
  column form). The state is U S of the centred data seen so far, truncated to
  r = l + oversampling columns, plus the running mean; a batch X_b (mean m_b) is merged by
  the SVD of [U S | X_b - m_b | sqrt(n_a n_b / n) (m_a - m_b)] (the last column corrects for
  the moved mean). Memory is O(s * (r + batch)) whatever n is.

``auto`` keeps the grid maps while they fit a memory budget and switches to streaming,
seeded with what it kept, once they do not.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.estimator import disparity_array

DEFAULT_BOX_SIZE = 5
"""Side (px) of the box filter applied after filling invalid pixels (paper: 5x5)."""

_COLUMN_BLOCK = 65536
"""Grid pixels processed at once in the float64 Gram products (bounds temporary memory)."""


class LearnMethod(StrEnum):
    """How the eigenpairs are computed."""

    AUTO = "auto"
    """Exact while the grid maps fit ``exact_max_bytes``, otherwise streaming."""
    EXACT = "exact"
    """n x n Gram matrix of all maps (keeps them all on the grid)."""
    STREAMING = "streaming"
    """Incremental SVD over batches; memory independent of n."""


def preprocess_disparity(
    disparity: npt.ArrayLike,
    grid_size: tuple[int, int],
    *,
    min_disparity: float = 0.0,
    box_size: int = DEFAULT_BOX_SIZE,
) -> npt.NDArray[np.float32]:
    """Prepare one disparity map for learning (in this order; docs/estimator.md, "Learning").

    1. invalid pixels (NaN or < ``min_disparity``) take the value of the nearest valid
       pixel (``cv2.distanceTransformWithLabels``, ``DIST_LABEL_PIXEL``);
    2. a ``box_size`` x ``box_size`` box filter;
    3. area resampling to the basis grid (``cv2.INTER_AREA``).

    Args:
        disparity: (H, W) float, disparity (px); NaN or < min_disparity is invalid. 16-bit
            integers (the matchers' fixed point, 16 or 256 x px) raise: divide them first.
        grid_size: (gh, gw) of the basis grid.
        min_disparity: smallest valid disparity (px). The default 0 takes a 0 for a match
            at zero disparity (SGBM with ``minDisparity`` 0: ``learn``'s maps); a map whose
            holes are coded 0 (KITTI's disparity PNGs) needs them set to NaN first, or a
            ``min_disparity`` > 0 (e.g. 1/256 px, KITTI's resolution).
        box_size: side of the box filter (px); 1 disables it.

    Returns:
        (gh, gw) float32 disparity on the grid (px).

    Raises:
        ValueError: the map is not 2-D or has no valid pixel.
        TypeError: the map is of 16-bit integers, boolean or complex.
    """
    values = disparity_array(disparity, "disparity", np.float32)
    if values.ndim != 2:
        raise ValueError(f"Expected `disparity` of shape (H, W), got {values.shape}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values >= min_disparity)
    n_valid = int(np.count_nonzero(valid))
    if n_valid == 0:
        raise ValueError(
            "disparity map has no valid pixel (all NaN or < min_disparity); skip this frame"
        )
    if n_valid < valid.size:
        # zero pixels of the source are the valid ones; every pixel gets the label of its
        # nearest valid pixel
        source = np.where(valid, 0, 1).astype(np.uint8)
        _, labels = cv2.distanceTransformWithLabels(
            source, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
        )
        by_label = np.zeros(int(labels.max()) + 1, dtype=np.float32)
        by_label[labels[valid]] = values[valid]
        values = by_label[labels]
    if box_size > 1:
        values = np.asarray(cv2.blur(values, (box_size, box_size)), dtype=np.float32)
    if values.shape != tuple(grid_size):
        values = np.asarray(
            cv2.resize(values, (grid_size[1], grid_size[0]), interpolation=cv2.INTER_AREA),
            dtype=np.float32,
        )
    return np.ascontiguousarray(values, dtype=np.float32)


def learn_basis(
    maps: Iterable[npt.ArrayLike],
    *,
    n_components: int = 500,
    variance: float | None = None,
    grid_scale: float = 0.25,
    method: LearnMethod | str = LearnMethod.AUTO,
    focal_baseline: float = 0.0,
    min_disparity: float = 0.0,
    box_size: int = DEFAULT_BOX_SIZE,
    preprocessed: bool = False,
    image_size: tuple[int, int] | None = None,
    batch_size: int = 64,
    oversampling: int = 20,
    exact_max_bytes: int = 1 << 30,
    exact_max_maps: int = 3000,
    progress: Callable[[int], None] | None = None,
    meta: dict[str, Any] | None = None,
) -> Basis:
    """Learn a PCA basis from a stream of disparity maps.

    Args:
        maps: iterable of (H, W) float disparity maps (px; NaN or < min_disparity
            invalid: 0 is valid by default, see :func:`preprocess_disparity`), consumed
            once and never all held in memory by the streaming path. With
            ``preprocessed=True``, (gh, gw) float32 grid maps from
            :func:`preprocess_disparity` instead.
        n_components: l, the number of components to keep (the maximum when ``variance``
            is given).
        variance: if given, keep the smallest l whose cumulative variance ratio reaches it,
            in (0, 1].
        grid_scale: basis grid pixels per image pixel, in (0, 1].
        method: ``"auto"``, ``"exact"`` or ``"streaming"`` (see :class:`LearnMethod`).
        focal_baseline: f*b (px*m) of the training camera, stored in the basis; 0 unknown.
        min_disparity: smallest valid disparity (px).
        box_size: box filter side (px).
        preprocessed: maps are already on the grid; ``image_size`` must then be given.
        image_size: (H, W) of the images; default: the shape of the first map.
        batch_size: maps merged per incremental-SVD step.
        oversampling: extra columns kept by the streaming path beyond l.
        exact_max_bytes: ``auto`` keeps float32 grid maps up to this many bytes.
        exact_max_maps: ``auto`` uses the Gram path for at most this many maps.
        progress: called with the number of maps consumed so far, after each map.
        meta: extra entries for the basis's ``meta`` (e.g. SGBM parameters).

    Returns:
        The learned :class:`Basis` (components orthonormal over grid pixels).

    Raises:
        ValueError: fewer than two maps, inconsistent shapes or bad options.
        TypeError: a map of 16-bit integers (fixed point), boolean or complex.
    """
    learn_method = LearnMethod(method)
    if n_components < 1:
        raise ValueError(f"Expected `n_components` >= 1, got {n_components}")
    if variance is not None and not 0.0 < variance <= 1.0:
        raise ValueError(f"Expected `variance` in (0, 1], got {variance}")
    if not (math.isfinite(focal_baseline) and focal_baseline >= 0.0):
        raise ValueError(
            f"Expected `focal_baseline` finite and >= 0 (px*m; 0 when unknown), "
            f"got {focal_baseline}"
        )
    iterator = iter(maps)
    try:
        first = disparity_array(next(iterator), "maps[0]", np.float32)
    except StopIteration:
        raise ValueError("`maps` is empty; learning needs at least two disparity maps") from None
    if first.ndim != 2:
        raise ValueError(f"Expected each map of shape (H, W), got {first.shape}")
    if preprocessed:
        if image_size is None:
            raise ValueError("`image_size` is required with preprocessed=True")
        grid_size = (int(first.shape[0]), int(first.shape[1]))
        size = (int(image_size[0]), int(image_size[1]))
    else:
        size = (
            (int(first.shape[0]), int(first.shape[1]))
            if image_size is None
            else (int(image_size[0]), int(image_size[1]))
        )
        grid_size = grid_size_for(size, grid_scale)

    def grid_maps() -> Iterator[npt.NDArray[np.float32]]:
        for index, raw in enumerate(itertools.chain([first], iterator)):
            array = disparity_array(raw, f"maps[{index}]", np.float32)
            expected = grid_size if preprocessed else size
            if array.shape != expected:
                raise ValueError(f"map {index} has shape {array.shape}, expected {expected}")
            if preprocessed:
                grid = np.ascontiguousarray(array)
            else:
                grid = preprocess_disparity(
                    array, grid_size, min_disparity=min_disparity, box_size=box_size
                )
            yield grid.reshape(-1)
            if progress is not None:
                progress(index + 1)

    n_pixels = grid_size[0] * grid_size[1]
    keep = n_components + oversampling
    stream = grid_maps()
    if learn_method is LearnMethod.EXACT:
        fit = _gram_fit(np.stack(list(stream)), n_components)
        used = LearnMethod.EXACT
    elif learn_method is LearnMethod.STREAMING:
        fit = streaming_fit(stream, keep, batch_size)
        used = LearnMethod.STREAMING
    else:
        budget = min(exact_max_maps, max(2, exact_max_bytes // (4 * n_pixels)))
        kept = list(itertools.islice(stream, budget + 1))
        if len(kept) <= budget:
            fit = _gram_fit(np.stack(kept), n_components)
            used = LearnMethod.EXACT
        else:
            fit = streaming_fit(itertools.chain(kept, stream), keep, batch_size)
            used = LearnMethod.STREAMING

    return basis_from_fit(
        fit,
        grid_size=grid_size,
        image_size=size,
        n_components=n_components,
        variance=variance,
        grid_scale=grid_scale,
        used=used,
        requested=learn_method,
        focal_baseline=focal_baseline,
        min_disparity=min_disparity,
        box_size=box_size,
        preprocessed=preprocessed,
        batch_size=batch_size,
        oversampling=oversampling,
        meta=meta,
    )


def basis_from_fit(
    fit: PcaFit,
    *,
    grid_size: tuple[int, int],
    image_size: tuple[int, int],
    n_components: int,
    variance: float | None,
    grid_scale: float,
    used: LearnMethod | str,
    requested: LearnMethod | str,
    focal_baseline: float = 0.0,
    min_disparity: float = 0.0,
    box_size: int = DEFAULT_BOX_SIZE,
    preprocessed: bool = False,
    batch_size: int | None = None,
    oversampling: int | None = None,
    meta: dict[str, Any] | None = None,
) -> Basis:
    """Build a :class:`Basis` from fitted eigenpairs, as :func:`learn_basis` does.

    Keeps l components (``n_components``, fewer with ``variance``), fixes their signs
    (largest-magnitude entry positive) and records the preprocessing and learning options.

    Args:
        fit: mean (s,), components (s, r) and eigenvalues (r,) of the grid maps.
        grid_size: (gh, gw) of the basis grid, gh * gw = s.
        image_size: (H, W) of the images (px).
        n_components: l, the most components to keep.
        variance: keep the fewest components reaching this variance ratio, or None.
        grid_scale: basis grid pixels per image pixel (recorded).
        used: the method that produced ``fit`` (recorded).
        requested: the method asked for (recorded).
        focal_baseline: f*b (px*m) of the training camera; 0 unknown.
        min_disparity: smallest valid disparity (px) (recorded).
        box_size: box filter side (px) (recorded).
        preprocessed: maps were preprocessed by the caller (recorded).
        batch_size: maps per incremental step, for streaming methods (recorded).
        oversampling: extra columns kept, for streaming methods (recorded).
        meta: extra entries for the basis's ``meta``.

    Returns:
        The :class:`Basis`.
    """
    used = str(used)
    streaming = used != str(LearnMethod.EXACT)
    size = image_size
    eigenvalues = fit.eigenvalues
    n_keep = min(n_components, eigenvalues.shape[0])
    if n_keep == 0:
        raise ValueError(
            "the maps do not vary (every map is the same after preprocessing: a static scene, "
            "repeated frames or blank images); learn from frames that show different scenes"
        )
    if variance is not None and fit.total_variance > 0:
        ratio = np.cumsum(eigenvalues) / fit.total_variance
        reached = np.flatnonzero(ratio >= variance - 1e-12)
        if reached.size:
            n_keep = min(n_keep, int(reached[0]) + 1)
    components = fit.components[:, :n_keep]
    # deterministic signs: the largest-magnitude entry of each component is positive
    peak = components[np.abs(components).argmax(axis=0), np.arange(n_keep)]
    components = components * np.where(peak < 0, -1.0, 1.0)
    from pcainterp_stream.version import __version__

    info: dict[str, Any] = {
        "software": f"pcainterp_stream {__version__}",
        "preprocessing": {
            "invalid_fill": "nearest valid pixel",
            "min_disparity": min_disparity,
            "box_size": box_size,
            "resampling": "area",
            "grid_scale": grid_scale,
            "preprocessed_by_caller": preprocessed,
        },
        "learning": {
            "method": str(used),
            "requested_method": str(requested),
            "n_components_requested": n_components,
            "variance_requested": variance,
            "oversampling": oversampling if streaming else None,
            "batch_size": batch_size if streaming else None,
            "explained_variance_ratio": float(eigenvalues[:n_keep].sum() / fit.total_variance)
            if fit.total_variance > 0
            else 1.0,
        },
    }
    if meta:
        info.update(meta)
    return Basis(
        mean=fit.mean.reshape(grid_size).astype(np.float32),
        components=np.ascontiguousarray(components.T, dtype=np.float32).reshape(n_keep, *grid_size),
        eigenvalues=np.ascontiguousarray(eigenvalues[:n_keep], dtype=np.float64),
        total_variance=float(fit.total_variance),
        image_size=size,
        focal_baseline=float(focal_baseline),
        n_train=fit.n_maps,
        meta=info,
    )


@dataclass(frozen=True)
class PcaFit:
    """Eigenpairs of the centred grid maps (float64).

    Attributes:
        mean: (s,) mean grid map (px).
        components: (s, r) orthonormal eigenvectors, eigenvalues descending.
        eigenvalues: (r,) eigenvalues of the covariance (px^2), descending.
        total_variance: trace of the covariance (px^2).
        n_maps: number of maps n.
    """

    mean: npt.NDArray[np.float64]  # (s,)
    components: npt.NDArray[np.float64]  # (s, r), orthonormal columns
    eigenvalues: npt.NDArray[np.float64]  # (r,), descending
    total_variance: float
    n_maps: int


def _gram_fit(maps: npt.NDArray[np.float32], keep: int | None = None) -> PcaFit:
    """Exact eigenpairs via the n x n Gram matrix of the centred maps (n, s).

    Only the leading ``keep`` eigenpairs are returned (None: all): forming every
    component costs s * n * rank products, 2.9e12 for 10,000 maps on a 310 x 94 grid.
    """
    n_maps, n_pixels = maps.shape
    if n_maps < 2:
        raise ValueError(f"learning needs at least two disparity maps, got {n_maps}")
    mean = maps.mean(axis=0, dtype=np.float64)
    gram = np.zeros((n_maps, n_maps))
    for start in range(0, n_pixels, _COLUMN_BLOCK):
        block = maps[:, start : start + _COLUMN_BLOCK] - mean[start : start + _COLUMN_BLOCK]
        gram += block @ block.T
    energies, vectors = np.linalg.eigh(gram)
    order = np.argsort(energies)[::-1]
    energies, vectors = energies[order], vectors[:, order]
    rank = int(np.count_nonzero(energies > max(energies[0], 0.0) * 1e-10))
    if keep is not None:
        rank = min(rank, keep)
    energies, vectors = energies[:rank], vectors[:, :rank]
    components = np.empty((n_pixels, rank))
    scale = vectors / np.sqrt(energies)
    for start in range(0, n_pixels, _COLUMN_BLOCK):
        block = maps[:, start : start + _COLUMN_BLOCK] - mean[start : start + _COLUMN_BLOCK]
        components[start : start + _COLUMN_BLOCK] = block.T @ scale  # u_i = D v_i / sqrt(e_i)
    return PcaFit(
        mean=mean,
        components=components,
        eigenvalues=energies / (n_maps - 1),
        total_variance=float(np.trace(gram) / (n_maps - 1)),
        n_maps=n_maps,
    )


@dataclass(frozen=True)
class Sketch:
    """The state of the incremental SVD: what it keeps of n centred maps.

    Attributes:
        mean: (s,) float64 mean of the maps (px).
        factor: (s, r) float32 U S of the centred maps, columns orthogonal (px).
        squares: sum of squared centred norms of the maps (px^2), the scatter's trace.
        n_maps: number of maps n.
    """

    mean: npt.NDArray[np.float64]
    factor: npt.NDArray[np.float32]
    squares: float
    n_maps: int


def streaming_fit(
    maps: Iterator[npt.NDArray[np.float32]],
    keep: int,
    batch_size: int,
    start: Sketch | None = None,
) -> PcaFit:
    """Incremental SVD of the centred maps, truncated to ``keep`` columns after each batch.

    Args:
        maps: (s,) float32 grid maps, flattened.
        keep: columns kept after each batch (l + oversampling).
        batch_size: maps merged per step.
        start: the state of maps seen before (a basis's, :func:`finetune.basis_sketch`);
            None starts empty.

    Returns:
        The :class:`PcaFit` of all maps (those of ``start`` included).
    """
    if batch_size < 1:
        raise ValueError(f"Expected `batch_size` >= 1, got {batch_size}")
    basis: npt.NDArray[np.float32] | None = None  # (s, r) U * S of the centred data so far
    mean: npt.NDArray[np.float64] | None = None
    n_seen = 0
    squares = 0.0  # sum of squared centred norms, merged with Chan's formula
    if start is not None:
        basis, mean, squares, n_seen = start.factor, start.mean, start.squares, start.n_maps
    while True:
        batch_list = list(itertools.islice(maps, batch_size))
        if not batch_list:
            break
        batch = np.stack(batch_list, axis=1)  # (s, b) float32
        n_batch = batch.shape[1]
        batch_mean = batch.mean(axis=1, dtype=np.float64)
        centred = (batch - batch_mean[:, None]).astype(np.float32)
        batch_squares = float(np.einsum("sb,sb->", centred, centred, dtype=np.float64))
        columns = [centred]
        if basis is not None and mean is not None:
            total = n_seen + n_batch
            shift = mean - batch_mean
            correction = np.sqrt(n_seen * n_batch / total) * shift
            columns = [basis, centred, correction[:, None].astype(np.float32)]
            squares += batch_squares + float(shift @ shift) * n_seen * n_batch / total
            mean = (n_seen * mean + n_batch * batch_mean) / total
        else:
            squares = batch_squares
            mean = batch_mean
        n_seen += n_batch
        basis = truncated_product(np.concatenate(columns, axis=1), keep)
    if basis is None or mean is None or n_seen < 2:
        raise ValueError(f"learning needs at least two disparity maps, got {n_seen}")
    return fit_from_factor(mean, basis, squares, n_seen)


def merge_sketches(first: Sketch, second: Sketch, keep: int) -> Sketch:
    """Merge the sketches of two sets of maps; exact up to the truncation to ``keep`` columns.

    The factor is the thin SVD of [U1 S1 | U2 S2 | sqrt(n1 n2 / n) (m1 - m2)] (the last
    column corrects for the moved mean), the step of :func:`streaming_fit` between two
    groups of maps of any size.

    Args:
        first: the sketch of n1 maps.
        second: the sketch of n2 maps on the same grid.
        keep: r, the columns kept of the merged factor.

    Returns:
        The sketch of the n1 + n2 maps.
    """
    total = first.n_maps + second.n_maps
    shift = first.mean - second.mean
    correction = (np.sqrt(first.n_maps * second.n_maps / total) * shift).astype(np.float32)
    stacked = np.concatenate([first.factor, second.factor, correction[:, None]], axis=1)
    factor = (
        truncated_product(stacked, keep)
        if np.any(stacked)
        else np.zeros((stacked.shape[0], 0), dtype=np.float32)
    )
    return Sketch(
        mean=(first.n_maps * first.mean + second.n_maps * second.mean) / total,
        factor=factor,
        squares=first.squares
        + second.squares
        + float(shift @ shift) * first.n_maps * second.n_maps / total,
        n_maps=total,
    )


def fit_from_factor(
    mean: npt.NDArray[np.float64],
    basis: npt.NDArray[np.float32],
    squares: float,
    n_seen: int,
) -> PcaFit:
    """Turn a truncated factor U S of centred maps into eigenpairs.

    Args:
        mean: (s,) float64 mean of the maps (px).
        basis: (s, r) float32 U S of the centred maps (columns orthogonal), px.
        squares: sum of squared centred norms of all maps (px^2).
        n_seen: number of maps n >= 2.

    Returns:
        The :class:`PcaFit` (eigenvalues S^2 / (n - 1)).
    """
    singular = np.sqrt(np.einsum("sr,sr->r", basis, basis, dtype=np.float64))
    nonzero = singular > 0
    components = basis[:, nonzero].astype(np.float64) / singular[nonzero]
    return PcaFit(
        mean=mean,
        components=components,
        eigenvalues=singular[nonzero] ** 2 / (n_seen - 1),
        total_variance=squares / (n_seen - 1),
        n_maps=n_seen,
    )


def truncated_product(matrix: npt.NDArray[np.float32], keep: int) -> npt.NDArray[np.float32]:
    """Return U_r S_r (s, <= keep) float32 of the thin SVD of ``matrix`` (s, c).

    The SVD comes from the c x c Gram matrix in float64 (c is small): matrix = U S V^T,
    U S = matrix V. Singular values below 1e-7 of the largest carry only rounding.
    """
    n_pixels, n_columns = matrix.shape
    gram = np.zeros((n_columns, n_columns))
    for start in range(0, n_pixels, _COLUMN_BLOCK):
        block = matrix[start : start + _COLUMN_BLOCK].astype(np.float64)
        gram += block.T @ block
    energies, vectors = np.linalg.eigh(gram)
    order = np.argsort(energies)[::-1][:keep]
    energies, vectors = energies[order], vectors[:, order]
    rank = int(np.count_nonzero(energies > max(energies[0], 0.0) * 1e-14))
    vectors = vectors[:, :rank]
    out = np.empty((n_pixels, rank), dtype=np.float32)
    for start in range(0, n_pixels, _COLUMN_BLOCK):
        block = matrix[start : start + _COLUMN_BLOCK].astype(np.float64)
        out[start : start + _COLUMN_BLOCK] = block @ vectors
    return out
