"""Write synthetic (or imported) stereo frames as a log with the project's input topics.

Per frame, all stamped with the frame's capture time (header stamp = log time), in this
order (the README's input topics):

==============================  ===============================  =======================
topic                           type                             content
==============================  ===============================  =======================
``/stereo/left/image_rect``     sensor_msgs/msg/Image mono8      rectified left grey
``/stereo/right/image_rect``    sensor_msgs/msg/Image mono8      rectified right grey
``/stereo/left/camera_info``    sensor_msgs/msg/CameraInfo       P = [fx 0 cx 0; ...]
``/stereo/right/camera_info``   sensor_msgs/msg/CameraInfo       P[0, 3] = -fx * b
``/ground_truth/depth``         sensor_msgs/msg/Image 32FC1      metres, +inf for sky
``/ground_truth/lidar_depth``   sensor_msgs/msg/Image 32FC1      optional, see below
``/ground_truth/pose``          geometry_msgs/msg/PoseStamped    left camera in "world"
==============================  ===============================  =======================

The sky, NaN in the frames' depth maps, is written as +inf: REP 118 (after REP 117) keeps
NaN for "no value" and +inf for "too far", and ``evaluate`` reads them so.

The ground-truth topics are optional per frame (:func:`frame_messages` with
``ground_truth=False``), which the KITTI importer uses. ``/ground_truth/lidar_depth`` is
written only when asked for (``lidar=LidarConfig(...)``, ``pcainterp synth --lidar``): the
same depth at the few percent of the pixels a 64-beam scanner would hit, NaN elsewhere
(:mod:`pcainterp_stream.synth.lidar`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logwriter import (
    LogFormat,
    LogWriter,
    ProgressCallback,
    WriteSummary,
    open_writer,
)
from pcainterp_stream.io.stereo_log import (
    DEPTH,
    LEFT_FRAME,
    LEFT_IMAGE,
    LEFT_INFO,
    POSE,
    RIGHT_FRAME,
    RIGHT_IMAGE,
    RIGHT_INFO,
    WORLD_FRAME,
    pose_message,
    stereo_messages,
)
from pcainterp_stream.records import SynthFrame
from pcainterp_stream.synth.lidar import LIDAR_DEPTH, LidarConfig, lidar_depth

__all__ = [
    "DEPTH",
    "LEFT_FRAME",
    "LEFT_IMAGE",
    "LEFT_INFO",
    "LIDAR_DEPTH",
    "POSE",
    "RIGHT_FRAME",
    "RIGHT_IMAGE",
    "RIGHT_INFO",
    "WORLD_FRAME",
    "frame_messages",
    "pose_message",
    "stereo_messages",
    "truth_depth_message",
    "write_frame",
    "write_synthetic_log",
]


def frame_messages(
    frame: SynthFrame, *, ground_truth: bool = True, lidar: LidarConfig | None = None
) -> Iterator[tuple[str, Any]]:
    """Yield (topic, message) of one synthetic frame in the order of the module table.

    Args:
        frame: the frame; ``depth`` (H, W) float32 metres, NaN for sky.
        ground_truth: also yield ``/ground_truth/depth`` and ``/ground_truth/pose``.
        lidar: with ``ground_truth``, also yield ``/ground_truth/lidar_depth`` from this
            scanner (None: not).

    Raises:
        ValueError: if an array's shape does not match the frame's camera.
    """
    yield from stereo_messages(frame.stamp_ns, frame.left, frame.right, frame.camera)
    if not ground_truth:
        return
    if frame.depth.shape != frame.camera.image_size:
        raise ValueError(
            f"Expected `depth` of frame {frame.index} to have shape {frame.camera.image_size}, "
            f"got {frame.depth.shape}"
        )
    depth = np.asarray(frame.depth, dtype=np.float32)
    yield DEPTH, truth_depth_message(depth, frame.stamp_ns)
    if lidar is not None:
        sparse = lidar_depth(depth, frame.camera, frame_index=frame.index, config=lidar)
        yield (
            LIDAR_DEPTH,
            rosmsg.image_message(sparse, frame.stamp_ns, LEFT_FRAME, encoding="32FC1"),
        )
    yield POSE, pose_message(frame.camera_to_world, frame.stamp_ns)


def truth_depth_message(
    depth: npt.NDArray[np.float32], stamp_ns: int, frame_id: str = LEFT_FRAME
) -> Any:
    """Return the ``/ground_truth/depth`` Image of a rendered depth map, sky as +inf.

    Args:
        depth: (H, W) float32 depth (m), NaN for sky (``SynthFrame.depth``).
        stamp_ns: header stamp (ns).
        frame_id: header frame id.

    Returns:
        A 32FC1 ``sensor_msgs/msg/Image``, +inf (REP 118: too far) where ``depth`` is NaN.
    """
    far = np.where(np.isnan(depth), np.float32(np.inf), depth).astype(np.float32, copy=False)
    return rosmsg.image_message(far, stamp_ns, frame_id, encoding="32FC1")


def write_frame(
    writer: LogWriter,
    frame: SynthFrame,
    *,
    ground_truth: bool = True,
    lidar: LidarConfig | None = None,
) -> None:
    """Add one frame's messages to an open writer (log time = header stamp)."""
    for topic, message in frame_messages(frame, ground_truth=ground_truth, lidar=lidar):
        writer.add_message(topic, message, frame.stamp_ns)


def write_synthetic_log(
    frames: Iterable[SynthFrame],
    path: str | os.PathLike[str],
    *,
    format: LogFormat | str | None = None,
    progress: ProgressCallback | None = None,
    total: int | None = None,
    lidar: LidarConfig | None = None,
) -> WriteSummary:
    """Write frames with their ground truth as a log, one frame in memory at a time.

    Args:
        frames: the frames, e.g. ``pcainterp_stream.synth.generate(config)``.
        path: output ``.mcap``, ``.bag`` or rosbag2 folder; written atomically.
        format: output format; chosen from the path's name when None.
        progress: called as ``progress(frames_done, total)`` after every frame.
        total: number of frames, passed on to ``progress`` (None if unknown).
        lidar: also write ``/ground_truth/lidar_depth`` from this scanner (None: not).

    Returns:
        What was written (path, counts per topic, first and last log time).

    Raises:
        LogWriteError: the output cannot be written.
        ValueError: a frame's arrays do not match its camera.
    """
    with open_writer(path, format) as writer:
        for done, frame in enumerate(frames, start=1):
            write_frame(writer, frame, lidar=lidar)
            if progress is not None:
                progress(done, total)
    return writer.summary()
