"""Plain typed records passed between the stages of the pipeline.

Data flows one way: reader -> :class:`StereoFrame` -> processor -> result -> writer. The
records here are shared by readers, writers, the synthetic generator and the processor, so
that none of those modules has to import another (as rosbags keeps its shared record
types in ``interfaces``). Time is integer nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair's intrinsics, as ROS ``CameraInfo`` P matrices give them.

    Attributes:
        width: image width (px).
        height: image height (px).
        fx: focal length along x (px).
        fy: focal length along y (px).
        cx: principal point x (px).
        cy: principal point y (px).
        baseline: distance between the optical centres (m), positive.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

    @property
    def focal_baseline(self) -> float:
        """Return f*b (px*m): depth = focal_baseline / disparity."""
        return self.fx * self.baseline

    @property
    def image_size(self) -> tuple[int, int]:
        """Return (height, width) in px."""
        return (self.height, self.width)

    def projection_left(self) -> npt.NDArray[np.float64]:
        """Return the left camera's 3x4 rectified projection matrix P."""
        return np.array(
            [[self.fx, 0.0, self.cx, 0.0], [0.0, self.fy, self.cy, 0.0], [0.0, 0.0, 1.0, 0.0]]
        )

    def projection_right(self) -> npt.NDArray[np.float64]:
        """Return the right camera's 3x4 P, with P[0, 3] = -fx * baseline (ROS convention)."""
        p = self.projection_left()
        p[0, 3] = -self.fx * self.baseline
        return p


class StereoFrame(NamedTuple):
    """One rectified stereo pair read from a log.

    Attributes:
        index: 0-based position of the pair in the stream.
        stamp_ns: header stamp of the left image (ns).
        log_time_ns: log time of the left image message (ns).
        frame_id: header frame_id of the left image.
        left: (H, W) uint8/uint16 grey or (H, W, 3) uint8 RGB left image.
        right: right image, same size and layout as ``left``.
        camera: the pair's calibration.
    """

    index: int  # type: ignore[assignment]  # shadows tuple.index on purpose: the frame number
    stamp_ns: int
    log_time_ns: int
    frame_id: str
    left: npt.NDArray[np.generic]
    right: npt.NDArray[np.generic]
    camera: StereoCamera


class SparseFeatures(NamedTuple):
    """Sparse 3-D points another system wrote into the log (``/features``).

    Attributes:
        stamp_ns: header stamp (ns).
        log_time_ns: log time of the message (ns).
        frame_id: header frame_id (the left optical frame).
        points: (n, 3) float32 x, y, z in the left optical frame (m).
    """

    stamp_ns: int
    log_time_ns: int
    frame_id: str
    points: npt.NDArray[np.float32]


class SynthFrame(NamedTuple):
    """One frame of the synthetic driving world, with its ground truth.

    Attributes:
        index: 0-based frame number.
        stamp_ns: capture time (ns), 10 Hz from the start of the drive.
        left: (H, W) uint8 rectified left grey image.
        right: (H, W) uint8 rectified right grey image.
        depth: (H, W) float32 ground-truth depth of the left camera (m, z along the optical
            axis), NaN where there is no surface (sky), as REP 118 asks.
        camera_to_world: (4, 4) float64 pose of the left camera (optical frame: x right,
            y down, z forward) in the world frame.
        camera: the stereo calibration.
    """

    index: int  # type: ignore[assignment]  # shadows tuple.index on purpose: the frame number
    stamp_ns: int
    left: npt.NDArray[np.uint8]
    right: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32]
    camera_to_world: npt.NDArray[np.float64]
    camera: StereoCamera


class RawMessage(NamedTuple):
    """One message of a log exactly as stored, for copying it into an output log.

    ROS 1 messages are converted to CDR with a ``ros2msg`` schema by the reader, so every
    ROS message reaches a writer in the ROS 2 MCAP profile; other encodings pass unchanged.

    Attributes:
        topic: channel topic.
        msgtype: ROS type name in ROS 2 spelling (``sensor_msgs/msg/Image``), or the schema
            name for non-ROS channels.
        schema_name: schema name as the output should record it.
        schema_encoding: ``ros2msg`` for ROS messages, else the input's (``jsonschema``...).
        schema_data: schema text/bytes.
        message_encoding: ``cdr`` for ROS messages, else the input's.
        channel_metadata: channel metadata (e.g. ``offered_qos_profiles``).
        data: serialized message.
        log_time_ns: log time (ns).
        publish_time_ns: publish time (ns).
        sequence: channel sequence number (0 when the format has none).
    """

    topic: str
    msgtype: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    channel_metadata: dict[str, str]
    data: bytes
    log_time_ns: int
    publish_time_ns: int
    sequence: int


class DensifiedFrame(NamedTuple):
    """The processor's output for one stereo pair, ready for the writers.

    Attributes:
        frame: the input pair (stamp, frame id, images, camera).
        pixels: (k, 2) float32 (x, y) image px of the measurements used.
        disparities: (k,) float32 measured disparities (px).
        disparity: (H, W) float32 dense MAP disparity (px); NaN all over for a frame
            without any measurement, own or carried (no estimate, not the prior's mean).
        disparity_std: (H, W) float32 posterior std of the disparity (px).
        depth: (H, W) float32 depth (m) with REP 118 ranges: ``+inf`` (farther than
            measurable) where the disparity is below ``min_disparity``, NaN where there is
            no estimate.
        depth_std: (H, W) float32 posterior std of the depth (m), ``+inf`` where depth is.
        measurement_source: "stereo" (GFTT + SGBM), "features" (a sparse stream) or "dense"
            (the whole SGBM map, ``--measurements dense``).
        counts: named counts of the frame (corners, lookups rejected by reason, dropped).
        min_disparity: the smallest disparity the estimate resolves (px); below it the
            disparity is kept as estimated but is not valid (``DisparityImage``'s window).
    """

    frame: StereoFrame
    pixels: npt.NDArray[np.float32]
    disparities: npt.NDArray[np.float32]
    disparity: npt.NDArray[np.float32]
    disparity_std: npt.NDArray[np.float32]
    depth: npt.NDArray[np.float32]
    depth_std: npt.NDArray[np.float32]
    measurement_source: str
    counts: dict[str, int]
    min_disparity: float = 0.0

    @property
    def estimated(self) -> bool:
        """Whether the frame has an estimate (a black frame has none: its maps are NaN)."""
        return self.pixels.shape[0] > 0 or bool(np.isfinite(self.disparity).any())
