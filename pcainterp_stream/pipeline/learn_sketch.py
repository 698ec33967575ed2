"""The summaries a cluster's learning tasks return, and their merges (pairwise or in one step).

A :class:`ChunkSummary` holds what the incremental SVD keeps of a chunk's centred grid maps
(:class:`~pcainterp_stream.estimate.learning.Sketch`: n, the mean, the scatter trace and
U S truncated to r columns) with the grid and camera. :func:`merge` merges two, truncating
to r columns (the tree of :mod:`pcainterp_stream.pipeline.distributed`); :func:`combine`
merges any number of exact ones (``keep=None``) in one step, exactly: the pooled scatter of
all their maps, as one process learns maps that fit its memory.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.estimate.learning import Sketch, merge_sketches, truncated_product

__all__ = ["ChunkSummary", "combine", "empty", "merge", "sketch_of", "summarize"]


@dataclass(frozen=True)
class ChunkSummary:
    """Sketch of the centred grid maps of some frames.

    Attributes:
        n_maps: number of maps n.
        mean: (s,) float64 mean grid map (px).
        factor: (s, r) float32 U S of the centred maps, truncated to r columns (px).
        squares: sum of squared centred norms (px^2), exact.
        grid_size: (gh, gw) of the grid, gh * gw = s.
        image_size: (H, W) of the images (px).
        focal_baseline: f*b (px*m) the maps are in (the target's, else the first map's camera's).
        flat_maps: SGBM maps among them with almost no disparity (:func:`learn.is_flat`).
        blank_maps: maps of the frames skipped, with no disparity above 0
            (:func:`learn.shows_surface`). A summary of blank maps only has n_maps 0
            (:func:`empty`): merges carry its count and ignore the rest.
        far_pixels: valid map pixels below the far cut of a basis with no fitted prior
            (``learn --no-fit-prior``; :func:`map_checks.warn_far_cut`), 0 otherwise.
        valid_pixels: the valid map pixels those are counted among.
    """

    n_maps: int
    mean: npt.NDArray[np.float64]
    factor: npt.NDArray[np.float32]
    squares: float
    grid_size: tuple[int, int]
    image_size: tuple[int, int]
    focal_baseline: float
    flat_maps: int = 0
    blank_maps: int = 0
    far_pixels: int = 0
    valid_pixels: int = 0


COUNTS = ("flat_maps", "blank_maps", "far_pixels", "valid_pixels")
"""The counts a summary carries beside its statistics: merges add them."""


def empty(
    grid_size: tuple[int, int], image_size: tuple[int, int], focal_baseline: float, blank: int
) -> ChunkSummary:
    """Return the summary of no map, carrying the count of ``blank`` maps skipped."""
    cells = grid_size[0] * grid_size[1]
    return ChunkSummary(
        n_maps=0,
        mean=np.zeros(cells, dtype=np.float64),
        factor=np.zeros((cells, 0), dtype=np.float32),
        squares=0.0,
        grid_size=grid_size,
        image_size=image_size,
        focal_baseline=focal_baseline,
        blank_maps=blank,
    )


def _counted(summary: ChunkSummary, others: list[ChunkSummary]) -> ChunkSummary:
    """Return ``summary`` with the counts (:data:`COUNTS`) of ``others`` added."""
    return _summed(summary, [summary, *others])


def _summed(summary: ChunkSummary, summaries: list[ChunkSummary]) -> ChunkSummary:
    """Return ``summary`` with its counts (:data:`COUNTS`) the sums of ``summaries``'."""
    total = {name: sum(getattr(each, name) for each in summaries) for name in COUNTS}
    return dataclasses.replace(
        summary,
        flat_maps=total["flat_maps"],
        blank_maps=total["blank_maps"],
        far_pixels=total["far_pixels"],
        valid_pixels=total["valid_pixels"],
    )


def summarize(
    grid_maps: npt.NDArray[np.float32],
    keep: int | None,
    *,
    grid_size: tuple[int, int],
    image_size: tuple[int, int],
    focal_baseline: float,
) -> ChunkSummary:
    """Summarise a block of grid maps.

    Args:
        grid_maps: (n, s) float32 grid maps (px), n >= 1.
        keep: r, the columns kept of the factor; None: all (the summary is exact).
        grid_size: (gh, gw) of the grid.
        image_size: (H, W) of the images (px).
        focal_baseline: f*b (px*m) of the camera.

    Returns:
        The :class:`ChunkSummary`.
    """
    mean = grid_maps.mean(axis=0, dtype=np.float64)
    centred = (grid_maps - mean).astype(np.float32).T  # (s, n)
    squares = float(np.einsum("sn,sn->", centred, centred, dtype=np.float64))
    factor = (
        truncated_product(centred, centred.shape[1] if keep is None else keep)
        if np.any(centred)
        else np.zeros((centred.shape[0], 0), dtype=np.float32)
    )
    return ChunkSummary(
        n_maps=int(grid_maps.shape[0]),
        mean=mean,
        factor=factor,
        squares=squares,
        grid_size=grid_size,
        image_size=image_size,
        focal_baseline=focal_baseline,
    )


def merge(
    first: ChunkSummary | None, second: ChunkSummary | None, keep: int
) -> ChunkSummary | None:
    """Merge two summaries (None is empty); exact up to the truncation to ``keep`` columns.

    Args:
        first: a summary or None.
        second: a summary or None.
        keep: r, the columns kept of the merged factor.

    Returns:
        The summary of both sets of maps (the camera of ``first`` is kept).

    Raises:
        PcaInterpError: the two summaries have different image sizes.
    """
    if first is None or second is None:
        return first if second is None else second
    if not first.n_maps or not second.n_maps:  # blank maps only: their count is kept
        return _counted(second, [first]) if first.n_maps == 0 else _counted(first, [second])
    _check_camera(first, second)
    merged = merge_sketches(sketch_of(first), sketch_of(second), keep)
    summary = ChunkSummary(
        n_maps=merged.n_maps,
        mean=merged.mean,
        factor=merged.factor,
        squares=merged.squares,
        grid_size=first.grid_size,
        image_size=first.image_size,
        focal_baseline=first.focal_baseline,
    )
    return _summed(summary, [first, second])


def sketch_of(summary: ChunkSummary) -> Sketch:
    """Return the :class:`~pcainterp_stream.estimate.learning.Sketch` of a summary."""
    return Sketch(summary.mean, summary.factor, summary.squares, summary.n_maps)


def _check_camera(first: ChunkSummary, second: ChunkSummary) -> None:
    if first.image_size != second.image_size or first.grid_size != second.grid_size:
        raise PcaInterpError(
            f"logs have {first.image_size[1]}x{first.image_size[0]} and "
            f"{second.image_size[1]}x{second.image_size[0]} images; learn one basis per camera"
        )


def combine(summaries: list[ChunkSummary | None]) -> ChunkSummary | None:
    """Merge summaries in one step, exactly: none of the columns is truncated.

    The scatter of all the maps is the sum of the summaries' scatters and of
    n_i (m_i - m)(m_i - m)^T: its factor is [U_1 S_1 | ... | sqrt(n_i) (m_i - m) ...],
    orthogonalised by one thin SVD (:func:`~pcainterp_stream.estimate.learning.
    truncated_product`) keeping every direction. Exact when the summaries are
    (``summarize(..., keep=None)``); the same summaries in the same order give the same
    bytes.

    Args:
        summaries: the summaries in a fixed order (chunk order); None entries are empty.

    Returns:
        The summary of all their maps (the first one's camera), None when all are None;
        an :func:`empty` one with their blank maps' count when none has a map.

    Raises:
        PcaInterpError: two summaries have different image sizes.
    """
    given = [summary for summary in summaries if summary is not None]
    present = [summary for summary in given if summary.n_maps]
    if not present:  # none, or blank maps only: their count is kept
        return _counted(given[0], given[1:]) if given else None
    first = present[0]
    for other in present[1:]:
        _check_camera(first, other)
    total = sum(summary.n_maps for summary in present)
    mean = sum(summary.n_maps * summary.mean for summary in present) / total
    shifts = [summary.mean - mean for summary in present]
    columns = [summary.factor for summary in present]
    columns += [
        (np.sqrt(summary.n_maps) * shift).astype(np.float32)[:, None]
        for summary, shift in zip(present, shifts, strict=True)
    ]
    stacked = np.concatenate(columns, axis=1)
    factor = (
        truncated_product(stacked, stacked.shape[1])
        if np.any(stacked)
        else np.zeros((stacked.shape[0], 0), dtype=np.float32)
    )
    squares = sum(
        summary.squares + summary.n_maps * float(shift @ shift)
        for summary, shift in zip(present, shifts, strict=True)
    )
    summary = ChunkSummary(
        n_maps=total,
        mean=np.asarray(mean, dtype=np.float64),
        factor=factor,
        squares=float(squares),
        grid_size=first.grid_size,
        image_size=first.image_size,
        focal_baseline=first.focal_baseline,
    )
    return _summed(summary, given)
