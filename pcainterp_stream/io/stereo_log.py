"""The input topics and messages of a stereo log as this project writes it.

The topics are the README's input topics.

Shared by the synthetic log writer (:mod:`pcainterp_stream.synth.log`) and the KITTI
importer (:mod:`pcainterp_stream.io.kitti`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.io import rosmsg
from pcainterp_stream.records import StereoCamera

LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
LEFT_INFO = "/stereo/left/camera_info"
RIGHT_INFO = "/stereo/right/camera_info"
DEPTH = "/ground_truth/depth"
POSE = "/ground_truth/pose"
LIDAR_DEPTH = "/ground_truth/lidar_depth"
"""Sparse depth truth (sensor_msgs/msg/Image 32FC1, m, NaN = no return)."""

LEFT_FRAME = "stereo_left_optical"
RIGHT_FRAME = "stereo_right_optical"
WORLD_FRAME = "world"


def stereo_messages(
    stamp_ns: int,
    left: npt.NDArray[np.uint8],
    right: npt.NDArray[np.uint8],
    camera: StereoCamera,
) -> Iterator[tuple[str, Any]]:
    """Yield (topic, message) for one rectified pair and its two camera infos.

    Args:
        stamp_ns: header stamp (ns).
        left: (H, W) uint8 left grey image.
        right: (H, W) uint8 right grey image.
        camera: the pair's calibration; (H, W) must equal ``camera.image_size``.

    Raises:
        ValueError: if an image's shape or dtype does not match the camera.
    """
    for name, image in (("left", left), ("right", right)):
        if image.shape != camera.image_size or image.dtype != np.uint8:
            raise ValueError(
                f"Expected `{name}` to be uint8 of shape {camera.image_size}, "
                f"got {image.dtype} {image.shape}"
            )
    yield LEFT_IMAGE, rosmsg.image_message(left, stamp_ns, LEFT_FRAME, encoding="mono8")
    yield RIGHT_IMAGE, rosmsg.image_message(right, stamp_ns, RIGHT_FRAME, encoding="mono8")
    yield LEFT_INFO, rosmsg.camera_info_message(camera, stamp_ns, LEFT_FRAME)
    yield RIGHT_INFO, rosmsg.camera_info_message(camera, stamp_ns, RIGHT_FRAME, right=True)


def pose_message(camera_to_world: npt.NDArray[np.float64], stamp_ns: int) -> Any:
    """Return the ``/ground_truth/pose`` message: (4, 4) left camera-to-world, frame "world"."""
    return rosmsg.pose_stamped_message(camera_to_world, stamp_ns, WORLD_FRAME)
