"""Cells of the edge-aware local prior: the measurements' nearest regions along a disparity map.

The stationary local kernel lets a measurement inform every pixel within its length scale,
across depth edges too. The edge-aware prior (``prior.LocalPrior.cell_weight`` w < 1)
multiplies it by a partition term,

    C(x, x') = v k(x - x') [w + (1 - w) 1{cell(x) = cell(x')}],

where cell(x) is the seed measurement nearest to x along the front end's own disparity map
(a geodesic Voronoi partition, :class:`Partition`): on a grid spanning the image, a step
between 4-neighbours costs 1 + min(|disparity difference|, cap), 1 where either value is
unknown, so a path across a depth edge is long. Each grid node takes the cell of its
nearest seed node (:func:`geodesic_labels`: two rounds of raster passes, a close
approximation of multi-source Dijkstra). The seeds are the frame's own measurements;
any other measurement (e.g. one carried over from earlier frames) and any pixel belongs to
the cell of the node it falls on (:meth:`Partition.cells`). The term is positive
semi-definite for any partition (a constant plus a block indicator, times a kernel), so C
is a valid covariance; w = 1 is the stationary kernel itself.

Pure maths over arrays (docs/estimator.md, "Beyond the paper"; docs/sharper_sparse.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

STEP_CAP = 20.0
"""Largest disparity difference (px) a grid step is charged for: one depth edge costs at
most 21 steps, so a far measurement on the pixel's own surface can still win."""

CELL_GRID_SCALE = 0.5
"""Cell grid of the estimate, as a fraction of the basis grid per axis: 8 image px per node at
the default grid scale. On a grid half as fine again (16 px per node) the gain in error was
40-60 % smaller on the LiDAR frames and the odometry clip (docs/sharper_sparse.md)."""


@dataclass(frozen=True, eq=False)
class Cells:
    """A frame's measurements in the cells of a :class:`Partition`.

    A cell's id is the flat index of its seed node; its measurements are listed by cell,
    in their own order within a cell (the first is its rank-0 measurement).

    Attributes:
        labels: (rows, cols) int64, the cell of each node of the cell grid (the flat index
            of its seed node), spanning the image pixel-centre aligned.
        point_cells: (k,) int64, the cell of each measurement.
        order: (k,) intp, the measurements sorted by cell.
        starts: (rows * cols,) intp, where each cell's measurements begin in ``order``.
        counts: (rows * cols,) intp, the measurements of each cell. A cell holds one
            measurement but where several share a node (or carried ones join it).
        first: (rows * cols,) intp, each cell's first measurement, -1 where it has none.
    """

    labels: npt.NDArray[np.int64]
    point_cells: npt.NDArray[np.int64]
    order: npt.NDArray[np.intp]
    starts: npt.NDArray[np.intp]
    counts: npt.NDArray[np.intp]
    first: npt.NDArray[np.intp]

    def members(
        self, cells: npt.NDArray[np.int64], *, after: int = 0
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Return (entry, j): the measurements j of each of ``cells`` past its first ``after``.

        Entry-major (the index into ``cells``), each cell's measurements in rank order.
        """
        count = self.counts.take(cells)
        holding = np.flatnonzero(count > after)  # the entries with any to list
        count = count.take(holding) - after
        entry = np.repeat(holding, count)
        # each entry's measurements: order[starts + after ...], one after the other
        skip = self.starts.take(cells.take(holding)) + after - (np.cumsum(count) - count)
        at = np.repeat(skip, count)
        at += np.arange(entry.size)
        j: npt.NDArray[np.intp] = self.order.take(at)
        return entry, j

    def at(
        self, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], image_size: tuple[int, int]
    ) -> npt.NDArray[np.int64]:
        """Return the cells (len(ys), len(xs)) of the points at columns xs x rows ys.

        Args:
            xs: (n,) float64, x in px of an image of ``image_size`` (height, width).
            ys: (m,) float64, y in px of that image.
            image_size: the image the cell grid spans (at any resolution).
        """
        row, column = self.nodes(xs, ys, image_size)
        cells: npt.NDArray[np.int64] = self.labels.take(row, axis=0).take(column, axis=1)
        return cells

    def nodes(
        self, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], image_size: tuple[int, int]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Return the cell-grid row of each of ``ys`` and the column of each of ``xs``."""
        rows, cols = self.labels.shape
        return node_along(ys, image_size[0], rows), node_along(xs, image_size[1], cols)


@dataclass(frozen=True, eq=False)
class Partition:
    """A geodesic partition of the image among seed measurements, on the cell grid.

    Attributes:
        labels: (rows, cols) int64, each node's cell: the flat index (row * cols + col) of
            its nearest seed node along the disparity map.
        image_size: (height, width) of the image the grid spans, pixel-centre aligned.
    """

    labels: npt.NDArray[np.int64]
    image_size: tuple[int, int]

    @classmethod
    def along(
        cls,
        disparity_map: npt.ArrayLike,
        pixels: npt.ArrayLike,
        image_size: tuple[int, int],
        basis_grid: tuple[int, int],
        *,
        step_cap: float = STEP_CAP,
    ) -> Partition | None:
        """Partition the image among measurements by their distance along a disparity map.

        Args:
            disparity_map: (h, w) float disparity (px) spanning the image at any
                resolution, <= 0 or NaN unknown (the front end's SGBM map, or
                :func:`cell_map` of it).
            pixels: (k, 2) float, (x, y) of the seed measurements in px of ``image_size``.
            image_size: (height, width) of the image.
            basis_grid: the basis grid (rows, cols); the partition is on
                :func:`cell_grid_size` of it.
            step_cap: largest disparity difference charged per step (px).

        Returns:
            The :class:`Partition`, or None without seeds.

        Raises:
            ValueError: the map is not 2-D or the pixels not (k, 2).
        """
        seeding = Seeding.along(disparity_map, pixels, image_size, basis_grid)
        return partition_all([seeding], step_cap=step_cap)[0]

    def cells(self, pixels: npt.NDArray[np.float64]) -> Cells:
        """Return the cells of measurements (k, 2) (x, y) in px of the partition's image."""
        rows, cols = self.labels.shape
        point_cells = self.labels.reshape(-1)[_flat_nodes(pixels, self.image_size, (rows, cols))]
        order = np.argsort(point_cells, kind="stable")
        counts = np.bincount(point_cells, minlength=rows * cols)
        starts = np.cumsum(counts) - counts
        first = np.full(rows * cols, -1, np.intp)
        holding = counts > 0
        first[holding] = order.take(starts[holding])
        return Cells(self.labels, point_cells, order, starts, counts, first)


@dataclass(frozen=True, eq=False)
class Seeding:
    """A frame's partition before its label search: the map on the cell grid and the seeds.

    Made beside the matcher (one resize); :func:`partition_all` then searches the labels of
    several frames at once, so the search's whole-grid numpy calls are shared by a batch
    instead of made per frame.

    Attributes:
        field: (rows, cols) float32 disparity (px) on the cell grid, NaN = unknown.
        nodes: (k,) intp, k >= 1, the flat node of each seed measurement.
        image_size: (height, width) of the image the grid spans, pixel-centre aligned.
    """

    field: npt.NDArray[np.float32]
    nodes: npt.NDArray[np.intp]
    image_size: tuple[int, int]

    @classmethod
    def along(
        cls,
        disparity_map: npt.ArrayLike,
        pixels: npt.ArrayLike,
        image_size: tuple[int, int],
        basis_grid: tuple[int, int],
    ) -> Seeding | None:
        """Return the seeding of :meth:`Partition.along` (same arguments), or None without seeds.

        Raises:
            ValueError: the map is not 2-D or the pixels not (k, 2).
        """
        values = np.asarray(disparity_map, dtype=np.float32)
        if values.ndim != 2 or values.size == 0:
            raise ValueError(f"Expected a disparity map of shape (h, w), got {values.shape}")
        seeds = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if seeds.shape[0] == 0:
            return None
        size = cell_grid_size(basis_grid)
        return cls(to_cell_grid(values, size), _flat_nodes(seeds, image_size, size), image_size)


def partition_all(
    frames: Sequence[Seeding | Partition | None], *, step_cap: float = STEP_CAP
) -> list[Partition | None]:
    """Return the partitions of several frames, searching the seedings' labels together.

    Seedings on grids of one shape are searched as one stack (:func:`geodesic_labels`);
    partitions and None pass through. Each frame's labels are those it gets alone.
    """
    found: list[Partition | None] = [
        None if f is None or isinstance(f, Seeding) else f for f in frames
    ]
    shapes = {f.field.shape for f in frames if isinstance(f, Seeding)}
    for shape in sorted(shapes):
        which = [
            i for i, f in enumerate(frames) if isinstance(f, Seeding) and f.field.shape == shape
        ]
        seedings = [frames[i] for i in which]
        assert all(isinstance(f, Seeding) for f in seedings)
        fields = np.stack([f.field for f in seedings if isinstance(f, Seeding)])
        size = shape[0] * shape[1]
        seeds = np.concatenate(
            [f.nodes + n * size for n, f in enumerate(seedings) if isinstance(f, Seeding)]
        )
        labels = geodesic_labels(fields, seeds, step_cap=step_cap)
        for n, i in enumerate(which):
            seeding = frames[i]
            assert isinstance(seeding, Seeding)
            found[i] = Partition(labels[n], seeding.image_size)
    return found


def node_along(coordinates: npt.NDArray[np.float64], size: int, count: int) -> npt.NDArray[np.intp]:
    """Return the node (0 .. count - 1) of each coordinate (px) on ``count`` nodes over ``size`` px.

    Non-decreasing in the coordinates.
    """
    node = np.floor((coordinates + 0.5) * (count / size)).astype(np.intp)
    np.maximum(node, 0, out=node)
    np.minimum(node, count - 1, out=node)
    return node


def _flat_nodes(
    pixels: npt.NDArray[np.float64], image_size: tuple[int, int], grid: tuple[int, int]
) -> npt.NDArray[np.intp]:
    """The flat node index (row * cols + col) of the grid node holding each pixel (x, y)."""
    column = node_along(pixels[:, 0], image_size[1], grid[1])
    row = node_along(pixels[:, 1], image_size[0], grid[0])
    flat: npt.NDArray[np.intp] = row * grid[1] + column
    return flat


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


SWEEPS = 2
"""Rounds of the label search (:func:`geodesic_labels`), each a pass along every row and
column both ways. On the KITTI frames, the three LiDAR frames and synthetic drives two rounds
label 99.1-99.5 % of the nodes as exact multi-source Dijkstra does, and the nearest-seed
interpolation along them is within 0.004 px of Dijkstra's (docs/sharper_sparse.md)."""


def geodesic_labels(
    field: npt.NDArray[np.float32],
    seeds: npt.NDArray[np.intp],
    *,
    step_cap: float = STEP_CAP,
    sweeps: int = SWEEPS,
) -> npt.NDArray[np.int64]:
    """Label each node of a grid with its nearest seed node along a disparity map.

    The distance between 4-neighbours is 1 + min(|field difference|, step_cap) (1 where
    either is NaN). Raster passes relax it: along a row from the left, with P the running
    sum of the steps, d(j) <- min over i <= j of d(i) + P(j) - P(i) = P(j) + cummin(d - P)(j)
    (one ``minimum.accumulate``), from the right likewise, then along the columns. A
    shortest path with r turns between rows and columns is exact after about r / 4 rounds;
    ``sweeps`` rounds are an approximation of multi-source Dijkstra, exact where the paths
    turn few times (always on a field without edges). After one round every node has a
    label.

    Each node's state is one int64 (:func:`_packed`): its distance in units of 2^-q px
    (q <= 16: exact for SGBM's 1/16 px disparities), a tie order and its label, so a
    minimum carries the label along and a pass is four whole-array calls. Ties go as in
    sequential passes: a node keeps its own label, then takes the nearest source from the
    left, then from the right. The passes from the left and from the right start from the
    same distances and are merged by one minimum: the same labels as running them one
    after the other, as a path from the right never gains by first going left.

    Several grids of one shape, stacked (frames, rows, cols), are searched at once (each on
    its own, with the same calls for all): ``seeds`` then index the stack (frame * rows *
    cols + row * cols + col) and each label is the flat index within its own grid.

    Args:
        field: (rows, cols) or (frames, rows, cols) float32 disparity (px) on the grid,
            NaN = unknown.
        seeds: (k,) flat indices (row * cols + col) of the seed nodes (repeats allowed),
            k >= 1, at least one in every grid.
        step_cap: largest disparity difference charged per step (px).
        sweeps: rounds of passes.

    Returns:
        int64 of the field's shape, the flat index of each node's nearest seed node.
    """
    rows, cols = field.shape[-2:]
    layout = _packed((rows, cols), step_cap)
    values = field.astype(np.float64)
    state = np.full(field.shape, layout.infinite, np.int64)
    state.flat[seeds] = seeds % (rows * cols)  # distance 0, order 0, the seed's own label
    passes = _Pass.both(values, step_cap, layout)  # along the rows, then the columns
    start = np.empty_like(state)
    forward = np.empty_like(state)
    backward = np.empty_like(state)
    for _ in range(sweeps):
        for step in passes:
            np.bitwise_and(state, layout.clear_order, out=start)
            np.add(start, step.forward_key, out=forward)
            np.minimum.accumulate(forward, axis=step.axis, out=forward)
            forward += step.position
            np.add(start, step.backward_key, out=backward)
            reverse = backward[..., ::-1] if step.axis == -1 else backward[..., ::-1, :]
            np.minimum.accumulate(reverse, axis=step.axis, out=reverse)
            backward -= step.position
            np.minimum(forward, backward, out=state)
    labels: npt.NDArray[np.int64] = state & np.int64(layout.label_mask)
    return labels


@dataclass(frozen=True)
class _Layout:
    """The bits of a node's state in :func:`geodesic_labels`.

    state = (distance * 2^quantum) * 2^low + order * 2^label_bits + label, low =
    label_bits + order bits; the distance may be negative inside a pass (d - P), which
    two's complement keeps clear of the low bits.
    """

    quantum: int
    label_bits: int
    low: int
    infinite: int
    clear_order: np.int64
    label_mask: int


def _packed(shape: tuple[int, int], step_cap: float) -> _Layout:
    """The :class:`_Layout` for a grid ``shape`` (raises ValueError past int64's range)."""
    rows, cols = shape
    label_bits = max(rows * cols - 1, 1).bit_length()
    order_bits = (2 * max(rows, cols)).bit_length()
    low = label_bits + order_bits
    longest = (rows + cols) * (1.0 + step_cap)  # no shortest path is longer
    # values range over -longest .. infinite + longest, infinite = 4 longest
    quantum = min(16, 62 - low - math.ceil(math.log2(6.0 * longest)))
    if quantum < 0:
        raise ValueError(f"Expected a cell grid of at most ~10^5 nodes a side, got {shape}")
    order_mask = ((1 << order_bits) - 1) << label_bits
    return _Layout(
        quantum=quantum,
        label_bits=label_bits,
        low=low,
        infinite=(math.ceil(4.0 * longest) << quantum) << low,
        clear_order=np.int64(~order_mask),
        label_mask=(1 << label_bits) - 1,
    )


@dataclass(frozen=True, eq=False)
class _Pass:
    """The constants of :func:`geodesic_labels`' passes along one axis (both ways).

    Attributes:
        axis: -1 along the rows, -2 along the columns.
        position: P, the running sum of the step costs along the axis, packed (int64).
        forward_key: order(i) - P(i): from the start, the nearest source (largest i) wins
            a tie, order = count - 1 - i.
        backward_key: order(i) + P(i): from the end the smallest i wins, order = count + i,
            after any source from the start.
    """

    axis: int
    position: npt.NDArray[np.int64]
    forward_key: npt.NDArray[np.int64]
    backward_key: npt.NDArray[np.int64]

    @classmethod
    def both(
        cls, values: npt.NDArray[np.float64], step_cap: float, layout: _Layout
    ) -> tuple[_Pass, _Pass]:
        """The passes along the rows and along the columns of a field (float64, NaN unknown).

        The field may be a stack of grids (..., rows, cols). The step costs of both axes are
        computed in one buffer (the same calls for both).
        """
        *stack, rows, cols = values.shape
        across, down = (*stack, rows, cols - 1), (*stack, rows - 1, cols)
        buffer = np.empty(math.prod(across) + math.prod(down))
        along_rows = buffer[: math.prod(across)].reshape(across)
        along_columns = buffer[math.prod(across) :].reshape(down)
        np.subtract(values[..., 1:], values[..., :-1], out=along_rows)
        np.subtract(values[..., 1:, :], values[..., :-1, :], out=along_columns)
        np.abs(buffer, out=buffer)
        np.minimum(buffer, step_cap, out=buffer)  # NaN stays NaN ...
        np.fmax(buffer, 0.0, out=buffer)  # ... and costs nothing here: 1 where either is unknown
        buffer += 1.0
        buffer *= float(1 << layout.quantum)
        np.rint(buffer, out=buffer)
        return cls._along(along_rows, -1, values.shape, layout), cls._along(
            along_columns, -2, values.shape, layout
        )

    @classmethod
    def _along(
        cls, step: npt.NDArray[np.float64], axis: int, shape: tuple[int, ...], layout: _Layout
    ) -> _Pass:
        """The pass along ``axis`` (-1 or -2) with these quantised step costs."""
        count = shape[axis]
        running = np.zeros(shape)
        np.cumsum(step, axis=axis, out=running[..., 1:] if axis == -1 else running[..., 1:, :])
        position = np.empty(shape, np.int64)  # exact: whole numbers times 2^low
        np.multiply(running, float(1 << layout.low), out=position, casting="unsafe")
        index = np.arange(count, dtype=np.int64) << layout.label_bits
        order_shape = (1, count) if axis == -1 else (count, 1)
        forward_order = ((np.int64(count - 1) << layout.label_bits) - index).reshape(order_shape)
        backward_order = ((np.int64(count) << layout.label_bits) + index).reshape(order_shape)
        return cls(axis, position, forward_order - position, backward_order + position)
