"""Cells of the edge-aware local prior: the measurements' nearest regions along a disparity map.

The stationary local kernel lets a measurement inform every pixel within its length scale,
across depth edges too. The edge-aware prior (``prior.LocalPrior.cell_weight`` w < 1)
multiplies it by a partition term,

    C(x, x') = v k(x - x') [w + (1 - w) 1{cell(x) = cell(x')}],

where cell(x) is the measurement nearest to x along the front end's own disparity map (a
geodesic Voronoi partition): on a grid spanning the image, a step between 4-neighbours
costs 1 + min(|disparity difference|, cap), 1 where either value is unknown, so a path
across a depth edge is long. Each grid node takes the cell of its nearest measurement node
(multi-source Dijkstra); measurements on one node share its cell. The term is positive
semi-definite for any partition (a constant plus a block indicator, times a kernel), so C
is a valid covariance; w = 1 is the stationary kernel itself.

Pure maths over arrays (docs/estimator.md, "An edge-aware local prior").
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

STEP_CAP = 20.0
"""Largest disparity difference (px) a grid step is charged for: one depth edge costs at
most 21 steps, so a far measurement on the pixel's own surface can still win."""

CELL_GRID_SCALE = 0.5
"""Cell grid of the estimate, as a fraction of the basis grid per axis (docs/sharper_sparse.md,
"The edge-aware local prior": on the basis grid itself the search cost ~4x as much for
about the same maps)."""


@dataclass(frozen=True, eq=False)
class Cells:
    """A geodesic partition of the image among a frame's measurements.

    Attributes:
        labels: (rows, cols) int64, the cell of each node of the cell grid (the index of
            the measurement that names it), spanning the image pixel-centre aligned.
        point_cells: (k,) int64, the cell of each measurement.
        members: (m, n_cells) int64, row r holds each cell's r-th measurement, -1 past the
            last; column c is cell c's (cell ids are measurement indices, so n_cells = k).
    """

    labels: npt.NDArray[np.int64]
    point_cells: npt.NDArray[np.int64]
    members: npt.NDArray[np.int64]

    def at(
        self, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], image_size: tuple[int, int]
    ) -> npt.NDArray[np.int64]:
        """Return the cells (len(ys), len(xs)) of the points at columns xs x rows ys.

        Args:
            xs: (n,) float64, x in px of an image of ``image_size`` (height, width).
            ys: (m,) float64, y in px of that image.
            image_size: the image the cell grid spans.
        """
        rows, cols = self.labels.shape
        column = _node(xs, image_size[1], cols)
        row = _node(ys, image_size[0], rows)
        cells: npt.NDArray[np.int64] = self.labels.take(row, axis=0).take(column, axis=1)
        return cells


def _node(coordinates: npt.NDArray[np.float64], size: int, count: int) -> npt.NDArray[np.intp]:
    """The node (0 .. count - 1) of a grid of ``count`` cells over ``size`` px holding px."""
    node = np.floor((coordinates + 0.5) * (count / size)).astype(np.intp)
    return np.clip(node, 0, count - 1)


def cell_grid_size(basis_grid: tuple[int, int], scale: float = CELL_GRID_SCALE) -> tuple[int, int]:
    """Return (rows, cols) of the cell grid for a basis grid (``scale`` of it per axis)."""
    return max(1, round(basis_grid[0] * scale)), max(1, round(basis_grid[1] * scale))


def to_cell_grid(
    disparity_map: npt.NDArray[np.floating], size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Return a disparity map (H, W) on the cell grid (rows, cols), float32, NaN = unknown.

    Nearest-neighbour resampling (an average would blur the depth edges the cells follow);
    values <= 0 (SGBM's invalid) become NaN.
    """
    values = np.asarray(disparity_map, dtype=np.float32)
    if values.shape != size:
        values = np.asarray(
            cv2.resize(values, (size[1], size[0]), interpolation=cv2.INTER_NEAREST), np.float32
        )
    with np.errstate(invalid="ignore"):
        return np.where(values > 0, values, np.float32(np.nan)).astype(np.float32)


def cell_map(
    disparity_map: npt.NDArray[np.floating], basis_grid: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Return a frame's disparity map on the cell grid of a basis grid (:func:`to_cell_grid`)."""
    return to_cell_grid(disparity_map, cell_grid_size(basis_grid))


@functools.lru_cache(maxsize=8)
def _grid_graph(
    rows: int, cols: int
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """The 4-neighbour grid's edges in CSR order: (order, indices, indptr).

    Both directions of each edge are stored (a directed search on a symmetric graph needs
    no transpose); ``order`` puts [horizontal costs, vertical costs] twice into CSR order.
    """
    index = np.arange(rows * cols).reshape(rows, cols)
    start = np.concatenate([index[:, :-1].ravel(), index[:-1].ravel()])
    end = np.concatenate([index[:, 1:].ravel(), index[1:].ravel()])
    both_start = np.concatenate([start, end])
    both_end = np.concatenate([end, start])
    order = np.lexsort((both_end, both_start))
    indices = both_end[order].astype(np.int32)
    indptr = np.searchsorted(both_start[order], np.arange(rows * cols + 1)).astype(np.int32)
    return order, indices, indptr


def measurement_cells(
    disparity_map: npt.ArrayLike | None,
    pixels: npt.NDArray[np.float64],
    image_size: tuple[int, int],
    basis_grid: tuple[int, int],
) -> Cells | None:
    """Return the cells of a frame's measurements along its disparity map, on the cell grid.

    Args:
        disparity_map: (h, w) float disparity (px) spanning the image at any resolution,
            <= 0 or NaN unknown (the front end's SGBM map, or :func:`cell_map` of it).
        pixels: (k, 2) float64, (x, y) of the measurements in px of ``image_size``.
        image_size: (height, width) of the image.
        basis_grid: the basis grid (rows, cols); the cells are on :func:`cell_grid_size`.

    Returns:
        The :class:`Cells`, or None without a map or measurements.

    Raises:
        ValueError: the map is not 2-D.
    """
    if disparity_map is None or pixels.shape[0] == 0:
        return None
    values = np.asarray(disparity_map, dtype=np.float32)
    if values.ndim != 2 or values.size == 0:
        raise ValueError(f"Expected a disparity map of shape (h, w), got {values.shape}")
    rows, cols = size = cell_grid_size(basis_grid)
    # pixel-centre aligned, as basis.image_to_grid: node centres at integers
    grid_x = (pixels[:, 0] + 0.5) * (cols / image_size[1]) - 0.5
    grid_y = (pixels[:, 1] + 0.5) * (rows / image_size[0]) - 0.5
    return geodesic_cells(to_cell_grid(values, size), np.column_stack([grid_x, grid_y]))


def geodesic_cells(
    field: npt.NDArray[np.float32],
    grid_positions: npt.NDArray[np.float64],
    *,
    step_cap: float = STEP_CAP,
) -> Cells:
    """Partition a grid among measurements by their distance along a disparity map.

    Args:
        field: (rows, cols) float32 disparity (px) on the cell grid, NaN = unknown.
        grid_positions: (k, 2) float64, (x, y) of the measurements in cell-grid nodes
            (node centres at integers); clamped to the grid.
        step_cap: largest disparity difference charged per step (px).

    Returns:
        The :class:`Cells`; with no measurement, one empty partition (every label -1).
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    rows, cols = field.shape
    k = grid_positions.shape[0]
    if k == 0:
        return Cells(
            np.full((rows, cols), -1, np.int64), np.zeros(0, np.int64), np.zeros((0, 0), np.int64)
        )
    node_x = np.clip(np.floor(grid_positions[:, 0] + 0.5), 0, cols - 1).astype(np.int64)
    node_y = np.clip(np.floor(grid_positions[:, 1] + 0.5), 0, rows - 1).astype(np.int64)
    node = node_y * cols + node_x
    seeds, first = np.unique(node, return_index=True)
    owner = np.full(rows * cols, -1, np.int64)
    owner[seeds] = first
    if rows * cols == 1:
        labels = owner.reshape(rows, cols)
    else:
        order, indices, indptr = _grid_graph(rows, cols)
        step = np.concatenate(
            [np.abs(field[:, 1:] - field[:, :-1]).ravel(), np.abs(field[1:] - field[:-1]).ravel()]
        )
        step = np.where(np.isfinite(step), np.minimum(step, step_cap), 0.0) + 1.0
        costs = np.concatenate([step, step])[order]
        graph = csr_matrix((costs, indices, indptr), shape=(rows * cols, rows * cols))
        _, _, sources = dijkstra(
            graph, directed=True, indices=seeds, min_only=True, return_predecessors=True
        )
        reached = sources >= 0
        labels = np.full(rows * cols, -1, np.int64)
        labels[reached] = owner[sources[reached]]
        labels = labels.reshape(rows, cols)
    point_cells = owner[node]
    # each cell's measurements, row r = its r-th one (cells hold one point but for shared nodes)
    by_cell = np.argsort(point_cells, kind="stable")
    sorted_cells = point_cells[by_cell]
    starts = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.arange(k) - starts
    members = np.full((int(rank.max()) + 1, k), -1, np.int64)
    members[rank, sorted_cells] = by_cell
    return Cells(labels, point_cells, members)
