"""One measured frame of the frame processor: what its stereo worker made of the pair.

:class:`Measured` is what a stereo worker hands the densify thread: the frame's points
and whatever the densification and the adaptation take of its SGBM map.
:func:`cells_on_grid` makes the edge-aware prior's cells again for a basis the densify
thread switched to after the worker measured the frame; :func:`check_cells` says whether the
fit check scores a basis with such cells, and :func:`sgbm_maps` makes the check's maps.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.cells import Seeding, cell_grid_size
from pcainterp_stream.estimate.dense import MapHoles
from pcainterp_stream.frontend.motion import Motion
from pcainterp_stream.records import StereoCamera, StereoFrame


class Measured(NamedTuple):
    """A frame measured by a stereo worker (the maps only where they are needed)."""

    frame: StereoFrame
    pixels: npt.NDArray[np.float32]
    disparities: npt.NDArray[np.float32]
    counts: dict[str, int]
    motion: Motion | None = None  # from the previous frame (carried points only)
    disparity_map: npt.NDArray[np.float32] | None = None  # SGBM's (dense mode only)
    sgbm_map: npt.NDArray[np.float32] | None = None  # SGBM's, NaN = invalid (fit check)
    grid_map: npt.NDArray[np.float32] | None = None  # preprocessed for the log's own basis
    # SGBM's map as matched, for the two above if the log's own basis needs them later
    raw_map: npt.NDArray[np.float32] | None = None
    # the fit check's held-out pixels and interpolation, made beside SGBM (check frames)
    held_out: adapt.HeldOut | None = None
    holes: MapHoles | None = None  # the map's holes and their neighbours (dense mode only)
    partition: Seeding | None = None  # along SGBM's map, for an edge-aware prior
    noise: npt.NDArray[np.float32] | None = None  # extra noise std of each point (near)


def cells_on_grid(item: Measured, basis_grid: tuple[int, int]) -> Seeding | None:
    """Return a frame's cells (its seeding) on the cell grid of a basis.

    The stereo worker made them for the basis in use when it measured the frame; when the
    densify thread has switched to a basis of another grid since, they are made again from
    the frame's SGBM map, which the worker keeps while a switch may come. So the cells a
    frame is estimated with depend on the basis it is estimated with, never on when its
    worker ran.

    Args:
        item: the measured frame.
        basis_grid: (rows, cols) of the grid of the basis the frame is estimated with.

    Returns:
        The seeding, or None (no seeds, or edge-aware cells not made).
    """
    partition = item.partition
    if partition is None or partition.field.shape == cell_grid_size(basis_grid):
        return partition
    disparity_map = item.raw_map if item.raw_map is not None else item.sgbm_map
    assert disparity_map is not None, "a frame measured before a switch keeps its map"
    # NaN (sgbm_map) and SGBM's <= 0 (raw_map) are both unknown on the cell grid
    return Seeding.along(disparity_map, item.pixels, item.frame.camera.image_size, basis_grid)


def check_cells(options: dict[str, object]) -> bool:
    """Return True when the estimate's options draw edge-aware cells (the local prior has them).

    The fit check scores each basis as the frames will be densified: one whose local prior
    is edge-aware with its cells along SGBM's map, which densify draws in sparse stereo mode
    (scored without them, the street basis lost near-ties it wins with them: a raw KITTI
    drive took the indoor basis and erred 7 % more).
    """
    local = options.get("local_prior")
    return bool(getattr(local, "edge_aware", False))


def sgbm_maps(
    disparity_map: npt.NDArray[np.float32], camera: StereoCamera
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None]:
    """Return a frame's SGBM map (NaN where invalid) and its grid map for the log's basis.

    The grid map is None for a blank pair (no valid pixel: no map to learn from).
    """
    sgbm_map = np.where(disparity_map > 0, disparity_map, np.nan).astype(np.float32)
    if not np.isfinite(sgbm_map).any():
        return sgbm_map, None
    return sgbm_map, adapt.grid_map(sgbm_map, camera.image_size)
