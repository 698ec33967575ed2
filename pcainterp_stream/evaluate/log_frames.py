"""Read a densified log back as frames for ``pcainterp evaluate``.

densify writes a frame's outputs (estimate, std, features, camera info) at its left image's
log time, up to a few tens of frames after the input images in the file. Here the channels
are grouped by header stamp into a :class:`Frame`, which also carries the right image of the
pair (for SGBM) and, with a reference topic, the reference message of its stamp. Both may be
logged after the outputs: a stereo driver's right image is received (logged) apart from the
left one by jitter, mostly after it, and a LiDAR message comes when its sweep ends. So a
complete frame waits for them, a bounded number of frames, so memory stays bounded.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.reference import ReferenceTopic
from pcainterp_stream.frontend.images import PairImages
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import decode_image, open_log
from pcainterp_stream.io.outputs import (
    FOCAL_BASELINE_KEY,
    MEASUREMENTS_KEY,
    EstimateTopics,
    OutputTopics,
    decode_estimate,
    estimate_topics,
    missing_outputs,
    recorded_tolerance_ns,
)
from pcainterp_stream.records import StereoCamera

__all__ = [
    "GROUND_TRUTH_DEPTH",
    "GROUND_TRUTH_POSE",
    "PENDING_FRAMES",
    "REFERENCE_BUFFER",
    "REFERENCE_WAIT_FRAMES",
    "RIGHT_STAMP_TOLERANCE_NS",
    "RIGHT_WAIT_FRAMES",
    "Frame",
    "ReadState",
    "read_frames",
]

GROUND_TRUTH_DEPTH = "/ground_truth/depth"
GROUND_TRUTH_POSE = "/ground_truth/pose"
RIGHT_STAMP_TOLERANCE_NS = 1_000_000
"""The right image belongs to the frame whose stamp is this close (pairing's default), unless
the log records the tolerance densify paired with or ``stamp_tolerance_ns`` is given."""
REFERENCE_WAIT_FRAMES = 4
"""A complete frame waits for its reference message until this many frames are waiting."""
RIGHT_WAIT_FRAMES = 8
"""A complete frame waits for its right image until this many frames are waiting. A frame
is complete once densify's outputs of it are read, and densify writes them only after it
paired the right image, so in a densified log the right image is seldom far behind."""
PENDING_FRAMES = 32
"""Stamps whose channels are gathered at once (and right images and reference messages
kept): densify writes a frame's outputs up to its look-ahead, the densify thread's queue and
the output encoders' frames (~20 at the fit check's warm-up) after the frame's input images."""
REFERENCE_BUFFER = PENDING_FRAMES
"""Reference messages kept (by stamp) for frames not yet complete."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One densified frame as read from the log."""

    index: int
    stamp_ns: int
    camera: StereoCamera
    estimate: npt.NDArray[np.float32]
    std: npt.NDArray[np.float32]
    pixels: npt.NDArray[np.float64]
    disparities: npt.NDArray[np.float64]
    left: npt.NDArray[Any]
    right: npt.NDArray[Any] | None
    depth: npt.NDArray[np.float32] | None
    pose: npt.NDArray[np.float64] | None
    min_disparity: float = 0.0
    reference: Any = None
    """The reference topic's message of this stamp (None: none, or no reference topic)."""
    right_gap_ns: int | None = None
    """Without a right image: how far (ns) the nearest one read was from the frame's stamp."""


@dataclass
class ReadState:
    """What reading the log found besides the frames."""

    measurements: str | None = None
    seen_disparity: bool = False
    metadata: dict[str, str] = field(default_factory=dict)
    """The estimate channel's metadata (a compact log's f*b and min disparity)."""
    tolerance_ns: int = RIGHT_STAMP_TOLERANCE_NS
    """The stamp tolerance of a frame's right image (given, recorded or the default)."""
    tolerance_from: str = "the default: the log records none"
    """Where :attr:`tolerance_ns` came from, for messages."""
    damage: list[str] = field(default_factory=list)
    """The reader's damage lines (the reader's own list: it grows as the log is read)."""
    converted: bool = False
    """The estimate channel carries no ``pcainterp.*`` metadata at all: the log went through
    a tool that keeps none (rosbag2 keeps only QoS: rosbags-convert, ``ros2 bag convert``)."""
    recovered_focal_baseline: float | None = None
    """f*b (px*m) read from the features (z * disparity) when the metadata lacked it."""

    @property
    def notes(self) -> list[str]:
        """Return what the report should say about the log's lost metadata ([]: none lost)."""
        if not self.converted:
            return []
        lost = "the stamp tolerance densify paired with (1 ms assumed unless given), its basis"
        note = (
            "the densified log's channels carry no pcainterp metadata, as after a ROS 2 bag "
            "tool (rosbags-convert, `ros2 bag convert`: rosbag2 keeps none)"
        )
        if self.recovered_focal_baseline is not None:
            note += (
                f"; f*b {self.recovered_focal_baseline:.6g} px*m was read from the features "
                "(z * disparity)"
            )
            lost += " and its smallest resolvable disparity"
        return [f"{note}; unknown: {lost}; evaluate the log densify wrote to have them"]


@dataclass(frozen=True)
class _Complete:
    """A frame whose densified channels are all read, waiting for its right image.

    It also waits for its reference message; it is kept as messages, decoded and rectified
    only when it is yielded.
    """

    index: int
    stamp_ns: int
    parts: dict[str, Any]


def read_frames(
    path: Path,
    topics: OutputTopics,
    max_frames: int | None,
    reference: ReferenceTopic | None = None,
    state: ReadState | None = None,
    images: PairImages | None = None,
    tolerance_ns: int | None = None,
) -> Iterator[Frame]:
    """Yield the densified frames of a log in order, grouping channels by header stamp.

    Each frame takes the right image nearest its stamp within ``tolerance_ns`` (None: the
    tolerance the log records densify paired with). A complete frame waits for a right
    image stamped at or after its own (right images come in stamp order, so the nearest one
    is then known), at most :data:`RIGHT_WAIT_FRAMES` frames; a frame whose right image
    never comes (dropped) goes on without one. With a reference topic, each frame carries
    the reference message of its stamp, waited for at most :data:`REFERENCE_WAIT_FRAMES`
    frames. The waits bound the frames held in memory.

    Args:
        path: a log written by ``pcainterp densify``.
        topics: its output topics.
        max_frames: yield at most this many frames (None: all).
        reference: the reference topic, if any.
        state: filled with what reading finds besides the frames.
        images: the input pair's topics and rectification.
        tolerance_ns: the stamp tolerance of a frame's right image (ns).

    Raises:
        LogReadError: the log lacks densified channels or the left images; a frame's
            channels do not decode.
    """
    state = state or ReadState()
    images = images or PairImages()
    left_image, right_image = images.left_topic, images.right_topic
    with open_log(path) as reader:
        state.damage = reader.damage
        present = reader.topics()
        where = estimate_topics(present, topics)
        needed = [where.estimate, where.std, topics.features, topics.camera_info]
        missing, hint = missing_outputs(present, topics, [*needed, left_image])
        if missing:
            raise LogReadError(
                f"{path} has no {', '.join(missing)}"
                f"{hint or _missing_advice(present, topics, missing, left_image)}"
            )
        truth = [] if reference is not None else [GROUND_TRUTH_DEPTH]
        optional = [t for t in (*truth, GROUND_TRUTH_POSE) if t in present]
        grouped = [*needed, left_image, *optional]
        complete = len(grouped)
        # the right image may be stamped up to the pairing tolerance apart from the left and
        # logged before or after the outputs (written at the left image's log time)
        has_right = right_image in present
        wanted = [*grouped, *([right_image] if has_right else [])]
        infos = [t for t in images.info_topics if t in present and t not in wanted]
        wanted += infos
        if reference is not None and reference.topic not in wanted:
            wanted.append(reference.topic)
        rights: dict[int, Any] = {}
        references: dict[int, Any] = {}
        pending: dict[int, dict[str, Any]] = {}
        waiting: deque[_Complete] = deque()
        index = yielded = 0

        def ready(frame: _Complete) -> bool:
            """Return True when the oldest waiting frame has all it can still get."""
            right_known = not has_right or any(other >= frame.stamp_ns for other in rights)
            return (right_known or len(waiting) > RIGHT_WAIT_FRAMES) and (
                reference is None
                or frame.stamp_ns in references
                or len(waiting) > REFERENCE_WAIT_FRAMES
            )

        def release() -> Frame:
            frame = waiting.popleft()
            if where.compact and FOCAL_BASELINE_KEY not in state.metadata:
                _recover_focal_baseline(frame, topics.features, state)
            return _frame(
                frame,
                rights=rights,
                reference=references.pop(frame.stamp_ns, None),
                topics=topics,
                images=images,
                where=where,
                metadata=state.metadata,
                tolerance_ns=state.tolerance_ns,
            )

        for raw in reader.messages(wanted):
            if raw.topic == where.estimate and not state.seen_disparity:
                state.seen_disparity = True
                state.metadata = dict(raw.channel_metadata)
                state.measurements = state.metadata.get(MEASUREMENTS_KEY)
                state.converted = not any(key.startswith("pcainterp.") for key in state.metadata)
                recorded = recorded_tolerance_ns(state.metadata)
                if tolerance_ns is not None:
                    state.tolerance_ns, state.tolerance_from = tolerance_ns, "--stamp-tolerance-ms"
                elif recorded is not None:
                    state.tolerance_ns = recorded
                    state.tolerance_from = "the tolerance the log was densified with"
            message = reader.decode(raw)
            if raw.topic in infos:
                images.see_info(raw.topic, message)
                continue
            if reference is not None and raw.topic == reference.topic:
                references[rosmsg.stamp_ns(message)] = message
                while len(references) > REFERENCE_BUFFER:
                    references.pop(min(references))
            full_estimate = raw.topic == where.estimate and not where.compact
            stamp = rosmsg.stamp_ns(message.image if full_estimate else message)
            if raw.topic == right_image:
                rights[stamp] = message
                while len(rights) > PENDING_FRAMES:
                    rights.pop(min(rights))
            elif raw.topic in grouped:
                parts = pending.setdefault(stamp, {})
                parts[raw.topic] = message
                if len(parts) == complete:
                    del pending[stamp]
                    waiting.append(_Complete(index, stamp, parts))
                    index += 1
                while len(pending) > PENDING_FRAMES:  # frames are written close together
                    pending.pop(min(pending))
            while waiting and ready(waiting[0]):
                yield release()
                yielded += 1
                if max_frames is not None and yielded >= max_frames:
                    return
        while waiting:  # the end of the log: no right image or reference can come any more
            yield release()
            yielded += 1
            if max_frames is not None and yielded >= max_frames:
                return


def _missing_advice(
    present: Iterable[str], topics: OutputTopics, missing: list[str], left_image: str
) -> str:
    """Say how to get a log evaluate can read: densify it, or densify it with more outputs."""
    outputs = [topics.depth, topics.disparity, topics.depth_std, topics.disparity_std]
    outputs.append(topics.features)
    written = [topic for topic in (*outputs, topics.camera_info) if topic in present]
    if not written or missing == [left_image]:
        return (
            "; evaluate needs a log written by `pcainterp densify` (with the input's stereo images)"
        )
    names = [topic.rsplit("/", 1)[1] for topic in written]
    return (
        f"; densify wrote only {', '.join(names)} into it (`pcainterp densify --outputs`): "
        "evaluate needs depth or disparity, disparity_std, features and camera_info; densify "
        "again with --outputs depth,disparity_std,features,camera_info (or without --outputs)"
    )


def _recover_focal_baseline(frame: _Complete, features_topic: str, state: ReadState) -> None:
    """Put f*b into a compact log's metadata from its features when the metadata lacks it.

    A compact log's depth needs f*b to become disparity; densify records it in the channel
    metadata, which a ROS 2 bag tool drops. Every feature point holds z = f*b / disparity
    (``io/outputs``), so f*b = z * disparity of any point with a disparity.

    Raises:
        LogReadError: the frame's features hold no point with a disparity.
    """
    features = rosmsg.pointcloud2_arrays(frame.parts[features_topic])
    if "z" in features and "disparity" in features:
        z = np.asarray(features["z"], dtype=np.float64)
        disparity = np.asarray(features["disparity"], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(z) & np.isfinite(disparity) & (z > 0) & (disparity > 0)
        if usable.any():
            focal_baseline = float(np.median(z[usable] * disparity[usable]))
            state.metadata[FOCAL_BASELINE_KEY] = repr(focal_baseline)
            state.recovered_focal_baseline = focal_baseline
            return
    converted = (
        "its channels carry no pcainterp metadata (a ROS 2 bag tool such as rosbags-convert "
        "or `ros2 bag convert` keeps none)"
        if state.converted
        else f"its depth channel has no {FOCAL_BASELINE_KEY} metadata"
    )
    raise LogReadError(
        f"frame {frame.index} of the densified log: {converted}, and its {features_topic} "
        "holds no point with a disparity to read f*b from, so the depth cannot be turned "
        "into disparity; evaluate the log as densify wrote it, or densify again with "
        "--precision full (its DisparityImage carries f and b)"
    )


def _camera(info: Any, baseline: float, size: tuple[int, int]) -> StereoCamera:
    p = rosmsg.projection_matrix(info)
    return StereoCamera(
        width=size[1],
        height=size[0],
        fx=float(p[0, 0]),
        fy=float(p[1, 1]),
        cx=float(p[0, 2]),
        cy=float(p[1, 2]),
        baseline=baseline,
    )


def _frame(
    complete: _Complete,
    *,
    rights: dict[int, Any],
    reference: Any,
    topics: OutputTopics,
    images: PairImages,
    where: EstimateTopics,
    metadata: dict[str, str],
    tolerance_ns: int = RIGHT_STAMP_TOLERANCE_NS,
) -> Frame:
    """Build a frame from its complete messages and the right image nearest its stamp."""
    index, stamp, parts = complete.index, complete.stamp_ns, complete.parts
    try:
        decoded = decode_estimate(
            parts[where.estimate], parts[where.std], parts[topics.camera_info], metadata
        )
    except ValueError as err:
        raise LogReadError(f"frame {index} of the densified log: {err}") from None
    estimate = decoded.disparity
    features = rosmsg.pointcloud2_arrays(parts[topics.features])
    depth = parts.get(GROUND_TRUTH_DEPTH)
    pose = parts.get(GROUND_TRUTH_POSE)
    nearest_right = min(rights, key=lambda other: abs(other - stamp), default=None)
    right, gap = None, None
    if nearest_right is not None:
        gap = abs(nearest_right - stamp)
        right = rights[nearest_right] if gap <= tolerance_ns else None
    return Frame(
        index=index,
        stamp_ns=stamp,
        camera=_camera(
            parts[topics.camera_info],
            decoded.baseline,
            (int(estimate.shape[0]), int(estimate.shape[1])),
        ),
        estimate=estimate,
        std=decoded.disparity_std,
        pixels=np.stack([features["u"], features["v"]], axis=1),
        disparities=features["disparity"],
        left=images.rectified(decode_image(parts[images.left_topic]), "left"),
        right=None if right is None else images.rectified(decode_image(right), "right"),
        depth=None if depth is None else rosmsg.image_array(depth).astype(np.float32),
        pose=None if pose is None else rosmsg.pose_matrix(pose),
        min_disparity=decoded.min_disparity,
        reference=reference,
        right_gap_ns=gap if right is None else None,
    )
