"""The guard against an unrectified or swapped stereo pair (``PairingConfig.check_rows``).

The pairer shows it the first frames of a pair: matched corners of a rectified pair lie on
the same rows, with non-negative disparities. A pair that fails is refused with the fix.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend import rectify as rect

__all__ = ["RowCheck"]

ROW_CHECK_FRAMES = 5
"""How many first frames the row check looks at (it decides earlier with enough matches)."""

ROW_CHECK_MATCHES = 150
"""Matches after which the row check decides."""

ROW_CHECK_MIN_MATCHES = 30
"""Fewer matches than this over the first frames: no verdict (textureless, unrelated images)."""

MAX_ROW_OFFSET_PX = 1.0
"""Largest median vertical offset (px) of matched corners a rectified pair may have."""

MIN_MEDIAN_DISPARITY_PX = -1.0
"""A median disparity of matched corners below this says left and right are swapped."""


class RowCheck:
    """The guard against an unrectified or swapped pair (``PairingConfig.check_rows``).

    A frame's matching (ORB corners, a RANSAC fundamental matrix: ~30-60 ms a KITTI frame,
    in OpenCV without the interpreter lock) runs in a thread of its own while the frame goes
    on to stereo matching; the next frame waits for it, so the check looks at the same
    frames and decides at the same one as a check in line would. A bad pair is refused
    when the next frame arrives, or by :meth:`finish` at the end of the stream.

    Args:
        left_topic: the left image topic (named in the error).
        right_topic: the right image topic.
        calibration_files: the calibration comes from files, not camera infos.
    """

    def __init__(self, left_topic: str, right_topic: str, *, calibration_files: bool) -> None:
        self.pair = f"{left_topic} / {right_topic}"
        self.calibration_files = calibration_files
        self.frames = 0
        self.points: list[Any] = []
        self.done = False
        self._pending: tuple[Future[Any], bool] | None = None
        self._executor: ThreadPoolExecutor | None = None

    def see(self, left: Any, right: Any, *, rectified: bool) -> None:
        """Start matching one frame's corners, once the frame before has been decided on.

        Raises:
            CalibrationError: the pair does not look rectified, or looks swapped.
        """
        self._decide()  # the frame before says whether this one is needed
        if self.done:
            return
        if self._executor is None:
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="row-check")
        self._pending = (self._executor.submit(rect.correspondences, left, right), rectified)

    def finish(self) -> None:
        """Decide with the last frame being matched (end of the stream).

        Raises:
            CalibrationError: the pair does not look rectified, or looks swapped.
        """
        try:
            self._decide()
        finally:
            self._close()

    def _decide(self) -> None:
        try:
            if self._pending is not None:
                (future, rectified), self._pending = self._pending, None
                self._add(future.result(), rectified=rectified)
        finally:
            if self.done:
                self._close()

    def _close(self) -> None:
        self._pending = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def _add(self, matches: Any, *, rectified: bool) -> None:
        """Add one frame's correspondences; decide once there are enough."""
        self.frames += 1
        self.points.append(matches)
        points = np.concatenate(self.points)
        if points.shape[0] < ROW_CHECK_MATCHES and self.frames < ROW_CHECK_FRAMES:
            return
        self.done = True
        self.points = []
        if points.shape[0] < ROW_CHECK_MIN_MATCHES:
            return
        offset = rect.row_offset(points)
        pair = self.pair
        where = f"median over {offset.matches} matched corners of the first {self.frames} frame(s)"
        if offset.median_abs_dy > MAX_ROW_OFFSET_PX:
            if rectified:
                fix = "the calibration does not fit these images: check the camera infos" + (
                    " (or the --calibration files)" if self.calibration_files else ""
                )
            else:
                fix = (
                    "pass --rectify always to remap them with their CameraInfo (or "
                    "--calibration files), or check the CameraInfo"
                )
            raise CalibrationError(
                f"the stereo pair {pair} does not look rectified: matched corners are "
                f"{offset.median_abs_dy:.2f} px apart vertically ({where}; rectified < "
                f"{MAX_ROW_OFFSET_PX:g} px); {fix}; --rectify never densifies them anyway"
            )
        if offset.median_dx < MIN_MEDIAN_DISPARITY_PX:
            raise CalibrationError(
                f"the stereo pair {pair} has negative disparities: x_left - x_right = "
                f"{offset.median_dx:.1f} px ({where}): left and right look swapped; swap "
                "--left-topic and --right-topic (or fix the baseline sign of the right camera's "
                "P); --rectify never densifies them anyway"
            )
