"""The frames the fit check and the log's own basis see, and which of them are one view.

:class:`AdaptFrame` is what :class:`~.adaptation.Adaptation` needs of one measured frame (its
SGBM maps from the stereo workers); :func:`still_links` tells, by ego-motion, which of
consecutive frames repeat an earlier frame's view (:data:`STILL_SHIFT`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.cells import Seeding
from pcainterp_stream.frontend.motion import Motion, view_shift
from pcainterp_stream.records import StereoCamera

STILL_SHIFT = 0.25
"""A frame whose ego-motion since a frame (chained frame to frame) moves its measurements
less than this median (px, :func:`~.motion.view_shift`) is that frame's view again. A camera
standing still measured 0.00-0.02 px from its first frame over 8 frames (the synthetic
street with fresh sensor noise in every frame, whose SGBM grid maps are 0.07-0.10 px apart,
where the maps' own test, :data:`~.adapt.SAME_VIEW` = 0.1 px, splits them into views; a
KITTI frame repeated with noise), 0.03 px creeping 1 cm/s; a camera swaying 1-2 cm and
0.2-1 degree per frame 1-7 px per frame."""


@dataclass(frozen=True)
class AdaptFrame:
    """What the adaptation needs of one measured frame (SGBM maps from the stereo workers)."""

    pixels: npt.NDArray[np.float32]
    disparities: npt.NDArray[np.float32]
    sgbm_map: npt.NDArray[np.float32] | None
    grid_map: npt.NDArray[np.float32] | None
    image_size: tuple[int, int]
    focal_baseline: float
    # the check's held-out pixels and plain interpolation of this frame, when the stereo
    # worker made them beside SGBM (else the check makes them)
    held_out: adapt.HeldOut | None = None
    # the ego-motion from the previous frame (None: unknown) and the camera it is in
    motion: Motion | None = None
    camera: StereoCamera | None = None
    index: int = 0  # the frame's index (the lines name it)
    # an over-exposed pair's clipped pixels, left out of a check made here (held_out None)
    clipped: npt.NDArray[np.bool_] | None = None

    def measured(self) -> adapt.Measured:
        """Return the frame as :func:`adapt.refit_prior` and the check take it."""
        assert self.sgbm_map is not None
        return adapt.Measured(self.pixels, self.disparities, self.sgbm_map)

    def cells(self, basis_grid: tuple[int, int]) -> Seeding | None:
        """Return the frame's edge-aware cells on a basis's grid, as densify draws them."""
        assert self.sgbm_map is not None
        return Seeding.along(self.sgbm_map, self.pixels, self.image_size, basis_grid)


def still_links(frames: list[AdaptFrame]) -> list[int]:
    """Return, for each of consecutive frames, the earliest frame of its view by ego-motion.

    A frame is the view of an earlier one when the motions chained from that frame move its
    measurements by less than :data:`STILL_SHIFT` (:func:`~.motion.view_shift`); a frame
    without a motion (the first, a lost one, another camera) starts a view of its own.
    """
    links: list[int] = []
    since = np.eye(4)
    for index, frame in enumerate(frames):
        still = False
        if index and frame.motion is not None and frame.camera is not None:
            since = frame.motion.transform @ since
            shift = view_shift(since, frame.pixels, frame.disparities, frame.camera)
            still = shift < STILL_SHIFT
        if not still:
            since = np.eye(4)
        links.append(links[-1] if still else index)
    return links
