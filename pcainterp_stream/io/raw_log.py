"""Write raw stereo logs the way a camera driver records them, from rectified views.

A rectified pair (rendered, or published rectified like KITTI's) is turned back into the raw,
distorted images a camera with a given calibration would have taken: for every raw pixel its
rectified position is ``cv2.undistortPoints(p, K, D, R=R, P=P)`` (``cv2.fisheye`` for
``equidistant``), and the rectified image is sampled there. The images go out under driver
topic names (``/camera/left/image_raw``...) with the calibration's ``CameraInfo`` (raw K and
D, R and P), as kitti2bag writes them. Used by ``pcainterp synth --raw`` and the KITTI raw
round-trip tool, to test that ``densify`` rectifies such logs as ``image_proc`` would.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.io.camera_model import StereoCalibration, unrectify_maps

LEFT_IMAGE = "/camera/left/image_raw"
RIGHT_IMAGE = "/camera/right/image_raw"
LEFT_INFO = "/camera/left/camera_info"
RIGHT_INFO = "/camera/right/camera_info"
LEFT_FRAME = "camera_left_optical"
RIGHT_FRAME = "camera_right_optical"


class Unrectifier:
    """Render raw images of a calibrated pair from its rectified images (maps built once)."""

    def __init__(self, calibration: StereoCalibration) -> None:
        self.calibration = calibration
        self._maps = [unrectify_maps(calibration.left), unrectify_maps(calibration.right)]

    def __call__(
        self, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]
    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
        """Return the raw (left, right) images: zero where the rectified view has no pixel."""
        out = [
            np.asarray(
                cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
                dtype=np.uint8,
            )
            for image, (mx, my) in zip((left, right), self._maps, strict=True)
        ]
        return out[0], out[1]


def raw_stereo_messages(
    stamp_ns: int,
    left: npt.NDArray[np.uint8],
    right: npt.NDArray[np.uint8],
    calibration: StereoCalibration,
) -> Iterator[tuple[str, Any]]:
    """Yield (topic, message) of one raw pair and its two camera infos, driver topic names."""
    yield LEFT_IMAGE, rosmsg.image_message(left, stamp_ns, LEFT_FRAME, encoding="mono8")
    yield RIGHT_IMAGE, rosmsg.image_message(right, stamp_ns, RIGHT_FRAME, encoding="mono8")
    yield LEFT_INFO, camera_info_message(calibration.left, stamp_ns, LEFT_FRAME)
    yield RIGHT_INFO, camera_info_message(calibration.right, stamp_ns, RIGHT_FRAME)
