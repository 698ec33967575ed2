"""What the densify thread builds once at the start, before the first frames reach it."""

from __future__ import annotations

from pcainterp_stream import compiled
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.lapack import routines
from pcainterp_stream.estimate.variance import _variance_stride

__all__ = ["prepare"]


def prepare(basis: Basis, uncertainty: str) -> None:
    """Build what the first densification needs once (run in the densify thread at start).

    The basis's pixel-major copy and variance grid, the LAPACK set-up and scipy's spatial
    module: done while the first pairs are read and matched, not in the job's start-up
    nor while the stereo workers wait for the first batch.
    """
    basis.pixel_major  # noqa: B018 - a cached property: built here
    basis.mean_flat  # noqa: B018
    if uncertainty not in ("none", "exact"):
        basis.variance_grid(_variance_stride(basis, None))
    # scipy's LAPACK (its OpenBLAS with one thread), Qhull and k-d tree load here, while the
    # stereo workers match the first pairs, not in the job's start-up: the solve's
    # routines, the check's triangulation and nearest neighbours, the carried points' gaps
    routines()
    compiled.module("spatial._qhull")
    compiled.module("spatial._ckdtree")
