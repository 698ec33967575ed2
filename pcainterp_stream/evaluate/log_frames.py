"""Read a densified log back as frames for ``pcainterp evaluate``.

densify writes a frame's outputs (estimate, std, features, camera info) at its left image's
log time, up to a few tens of frames after the input images in the file. Here the channels
are grouped by header stamp into a :class:`Frame`, which also carries the right image of the
pair (for SGBM), the ground-truth depth and pose nearest its stamp (their streams may run
on other clocks and rates) and, with a reference topic, the reference message nearest its
stamp (a projected LiDAR scan is stamped with the scan's time, not the camera's).
Any may be logged after the outputs: a stereo driver's right image is received (logged)
apart from the left one by jitter, mostly after it, and a LiDAR message comes when its
sweep ends. So a complete frame waits for them, a bounded number of frames, so memory
stays bounded.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError
from pcainterp_stream.evaluate.reference import ReferenceTopic
from pcainterp_stream.evaluate.stamped import SeenStamps, Stamped, UnplacedStamps, crowded_stamp
from pcainterp_stream.frontend.images import PairImages
from pcainterp_stream.frontend.pair_forms import grey_alike
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.depth_image import depth_metres
from pcainterp_stream.io.logreader import decode_image, open_log
from pcainterp_stream.io.output_cameras import FrameCameras, features_focal_baseline
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
from pcainterp_stream.io.reader_base import closest_topic
from pcainterp_stream.records import StereoCamera

__all__ = [
    "GROUND_TRUTH_DEPTH",
    "GROUND_TRUTH_POSE",
    "PENDING_FRAMES",
    "POSE_BUFFER",
    "REFERENCE_BUFFER",
    "REFERENCE_WAIT_FRAMES",
    "RIGHT_STAMP_TOLERANCE_NS",
    "RIGHT_WAIT_FRAMES",
    "TRUTH_WAIT_FRAMES",
    "Frame",
    "ReadState",
    "frame_count",
    "read_frames",
]

GROUND_TRUTH_DEPTH = "/ground_truth/depth"
GROUND_TRUTH_POSE = "/ground_truth/pose"
TRUTH_TOPICS = (GROUND_TRUTH_DEPTH, GROUND_TRUTH_POSE)
RIGHT_STAMP_TOLERANCE_NS = 1_000_000
"""The right image belongs to the frame whose stamp is this close (pairing's default), unless
the log records the tolerance densify paired with or ``stamp_tolerance_ns`` is given."""
REFERENCE_WAIT_FRAMES = 4
"""A complete frame waits for its reference message until this many frames are waiting."""
RIGHT_WAIT_FRAMES = 8
"""A complete frame waits for its right image until this many frames are waiting. A frame
is complete once densify's outputs of it are read, and densify writes them only after it
paired the right image, so in a densified log the right image is seldom far behind."""
TRUTH_WAIT_FRAMES = 31
"""A complete frame waits for its ground truth and pose until this many frames are waiting:
they may be logged later than the images (another recorder, a post-processing step), as
far as the :data:`PENDING_FRAMES` their buffers keep."""
PENDING_FRAMES = 32
"""Stamps whose channels are gathered at once (and right images and reference messages
kept): densify writes a frame's outputs up to its look-ahead, the densify thread's queue and
the output encoders' frames (~20 at the fit check's warm-up) after the frame's input images."""
REFERENCE_BUFFER = PENDING_FRAMES
"""Reference messages kept (by stamp) for frames not yet complete."""
POSE_BUFFER = 4096
"""Ground-truth poses kept (by stamp): a pose stream may run at hundreds of Hz, and a
frame's outputs come up to :data:`PENDING_FRAMES` frames after its images."""


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
    """The reference topic's message nearest this stamp within the reference tolerance
    (None: none, or no reference topic)."""
    reference_gap_ns: int | None = None
    """With a reference topic: how far (ns) the matched message, or without one the nearest
    read, is from the frame's stamp (None: no reference message read near it)."""
    right_gap_ns: int | None = None
    """Without a right image: how far (ns) the nearest one read was from the frame's stamp."""
    depth_gap_ns: int | None = None
    """Without ``/ground_truth/depth`` in a log that has it: the nearest one's distance (ns)."""
    pose_gap_ns: int | None = None
    """Without a pose in a log that has them (poses read): the nearest one's distance (ns)."""
    cx_offset: float | None = None
    """cx_left - cx_right (px) of the input pair's camera infos when the frame was read
    (:meth:`~pcainterp_stream.frontend.images.PairImages.cx_offset`; None: unknown)."""
    shared: tuple[str, ...] = ()
    """The truth topics (depth, pose) whose messages within the tolerance are all another
    frame's (stamped nearer it, or taken): left without it (one message, one frame)."""
    restamped: bool = False
    """densify stamped the outputs off the left image's header stamp (0 or a repeat)."""


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
    reference_tolerance_ns: int | None = None
    """The stamp tolerance of a frame's reference message (None: :attr:`tolerance_ns`)."""
    reference_tolerance_from: str = ""
    """Where :attr:`reference_tolerance_ns` came from, for messages."""
    reference_offsets: list[int] = field(default_factory=list)
    """The stamp offsets (ns) of the reference messages matched to frames."""
    damage: list[str] = field(default_factory=list)
    """The reader's damage lines (the reader's own list: it grows as the log is read)."""
    converted: bool = False
    """The estimate channel carries no ``pcainterp.*`` metadata at all: the log went through
    a tool that keeps none (rosbag2 keeps only QoS: rosbags-convert, ``ros2 bag convert``)."""
    recovered: list[float] = field(default_factory=list)
    """Each frame's f*b (px*m) read from its features (z * disparity) when the metadata
    lacked it (:attr:`recovered_focal_baseline`)."""
    unrecorded_note: str = ""
    """The sentence on frames decoded with their features' f*b, the camera change's record
    lost (``FrameCameras.unrecorded_note``; "": none)."""
    merged: int = 0
    """Densified messages that replaced one of the same topic and stamp: frames are told
    apart by header stamp, so frames sharing a stamp became one."""
    incomplete: dict[str, int] = field(default_factory=dict)
    """Per densified topic, the stamps of left images or outputs left out because that topic
    never came with their stamp (a frame densify dropped, a message lost)."""
    repeated: dict[str, int] = field(default_factory=dict)
    """Per topic matched by stamp (right image, truth, poses, reference), the messages with
    the stamp of an earlier one of the topic (stamps that restart, a message logged twice):
    a frame takes the message of its stamp nearest its own log time."""
    copies: dict[str, int] = field(default_factory=dict)
    """Per image topic of the input pair, the images logged again right after themselves (the
    same stamp, size, encoding and bytes): skipped, as densify dropped them."""
    undecodable_left: int = 0
    """Left images with no densified output at all whose image does not decode (a damaged
    JPEG): densify skipped them, no pairing dropped them."""
    undecodable: dict[str, int] = field(default_factory=dict)
    """Per topic of the input pair (images, camera infos), the messages that do not decode (a
    damaged message, bytes of another type): skipped, as densify skipped them."""

    shared: dict[str, list[int]] = field(default_factory=dict)
    """Per truth topic (depth, pose), the frames left without its message because each one
    within the tolerance is another frame's, stamped nearer it."""
    shared_squeezed: int = 0
    """Of the frames of :attr:`shared`, those placed by densify with their time unknown
    (before the clock's rate was known, or crowded after a missed stamp): they take only a
    truth message of their exact stamp."""
    shared_restamped: int = 0
    """Of the frames of :attr:`shared`, those densify restamped (their camera's header stamp
    repeated or 0: placed within one frame interval of the last stamp of its own)."""
    steps: deque[int] = field(default_factory=lambda: deque(maxlen=64))
    """The last steps (ns) between the stamps of successive frames read (forward only)."""

    @property
    def shared_note(self) -> str:
        """Return the sentence on frames left without truth of their own ("": none).

        Per cause (review 16e R3): frames densify placed with their time unknown take only a
        message of their exact stamp, so theirs is untold (no frame may have taken it); the
        others lost theirs to a frame stamped nearer it, for their stamps (restamped: a
        camera clock that repeats its stamp) or a tolerance of half their interval or more
        (review 16b R3).
        """
        if not self.shared:
            return ""
        count = max(len(frames) for frames in self.shared.values())
        which = ", ".join(
            f"{topic} on {len(frames)} (frame {frames[0]} first)"
            for topic, frames in sorted(self.shared.items())
        )
        head = f"{count} frame{'' if count == 1 else 's'} left out ({which})"
        squeezed = min(self.shared_squeezed, count)
        clauses = (
            []
            if not squeezed
            else [
                f"{squeezed} of them {'has' if squeezed == 1 else 'have'} no time of their "
                "own: their camera's header stamp repeated or "
                "was 0 (before the clock's rate was known, or on several frames in a row) and "
                "densify placed them within one frame interval of the last stamp of its own, so "
                "only a truth message of their exact stamp is theirs, and none is; give the "
                "camera images their own stamps (or stamp the truth on the images' clock)"
            ]
        )
        if count > squeezed:
            clauses.append(f"{count - squeezed}: {self._nearer_note}")
        return f"{head}: {'; '.join(clauses)}"

    @property
    def _nearer_note(self) -> str:
        """The clause on frames whose truth within the tolerance went to other frames."""
        shared = "each truth message within the stamp tolerance of them is another frame's"
        step = int(np.median(list(self.steps))) if self.steps else 0
        restamped = self.shared_restamped - self.shared_squeezed
        if restamped > 0:
            return (
                f"{shared}, stamped nearer it: {restamped} of them repeat their camera's "
                "header stamp (a paused or stuck camera clock), and densify placed them "
                "within one frame interval of the last stamp of its own; give the camera "
                "images their own stamps (or stamp the truth on the images' clock)"
            )
        if step and 2 * self.tolerance_ns >= step:
            return (
                f"{shared}, stamped nearer it: the stamp tolerance, "
                f"{self.tolerance_ns / 1e6:g} ms ({self.tolerance_from}), is half the frames' "
                f"interval ({step / 1e6:g} ms) or more, so a message between two frames is "
                "within it of both; pass a smaller --stamp-tolerance-ms (under "
                f"{step / 2e6:g} ms)"
            )
        return f"{shared}, stamped nearer it: the frames are stamped closer together than the truth"

    @property
    def reference_tolerance(self) -> tuple[int, str]:
        """Return the reference's stamp tolerance (ns) and where it came from."""
        if self.reference_tolerance_ns is None:
            return self.tolerance_ns, self.tolerance_from
        return self.reference_tolerance_ns, self.reference_tolerance_from

    def reference_note(self, topic: str) -> str:
        """Return the sentence on reference messages matched off the frames' stamps ("": none)."""
        offsets = [offset for offset in self.reference_offsets if offset]
        if not offsets:
            return ""
        tolerance, where = self.reference_tolerance
        return (
            f"{topic} matched to frames by the nearest header stamp within {tolerance / 1e6:g} "
            f"ms ({where}): {len(offsets)} of {len(self.reference_offsets)} messages stamped "
            f"{min(offsets) / 1e6:.2f}-{max(offsets) / 1e6:.2f} ms from their frame's "
            f"(median {float(np.median(offsets)) / 1e6:.2f} ms)"
        )

    @property
    def copies_note(self) -> str:
        """Return the sentence on input images logged twice and skipped ("": none)."""
        if not self.copies:
            return ""
        counts = ", ".join(f"{n} on {topic}" for topic, n in sorted(self.copies.items()))
        return f"images logged again right after themselves were skipped ({counts}), as densify did"

    @property
    def undecodable_note(self) -> str:
        """Return the sentence on input messages that do not decode, skipped ("": none)."""
        if not self.undecodable:
            return ""
        counts = ", ".join(f"{n} on {topic}" for topic, n in sorted(self.undecodable.items()))
        return (
            f"messages that do not decode were skipped ({counts}: damaged, or bytes of "
            "another type), as densify skipped them"
        )

    @property
    def repeated_note(self) -> str:
        """Return the sentence on messages with the stamp of an earlier one ("": none)."""
        if not self.repeated:
            return ""
        counts = ", ".join(f"{n} on {topic}" for topic, n in sorted(self.repeated.items()))
        return (
            f"messages with the stamp of an earlier one of their topic ({counts}; stamps that "
            "restart, or a message logged twice): a frame takes the message of its stamp "
            "nearest its own log time"
        )

    @property
    def recovered_focal_baseline(self) -> str | None:
        """f*b (px*m) read from the features, as the note says it (a range when it changed)."""
        if not self.recovered:
            return None
        low, high = f"{min(self.recovered):.6g}", f"{max(self.recovered):.6g}"
        return low if low == high else f"{low}-{high}"

    @property
    def notes(self) -> list[str]:
        """Return what the report should say about the log's lost metadata ([]: none lost)."""
        if not self.converted:
            return [self.unrecorded_note] if self.unrecorded_note else []
        lost = "the stamp tolerance densify paired with (1 ms assumed unless given), its basis"
        note = (
            "the densified log's channels carry no pcainterp metadata, as after a ROS 2 bag "
            "tool (rosbags-convert, `ros2 bag convert`: rosbag2 keeps none)"
        )
        if self.recovered_focal_baseline is not None:
            note += (
                f"; f*b {self.recovered_focal_baseline} px*m was read from the features "
                "(z * disparity)"
            )
            lost += " and its smallest resolvable disparity"
        return [f"{note}; unknown: {lost}; evaluate the log densify wrote to have them"]

    @property
    def incomplete_note(self) -> str:
        """Return the sentence on frames merged or left out for missing outputs ("": none)."""
        merged = (
            f"{self.merged} densified messages had the stamp of another of their topic and "
            "replaced it: frames are told apart by header stamp, so frames sharing one were "
            "merged; give each frame its own stamp"
            if self.merged
            else ""
        )
        if not self.incomplete:
            return merged
        counts = ", ".join(f"{topic} on {n}" for topic, n in sorted(self.incomplete.items()))
        count = max(self.incomplete.values())
        why = (
            "the log is damaged (see damage): the frames at the damage are lost"
            if self.damage
            else "densify drops unpaired frames"
        )
        left_out = (
            f"at least {count} frame{'' if count == 1 else 's'} left out: their densified "
            f"channels are incomplete (missing {counts}; {why})"
        )
        return f"{merged}; {left_out}" if merged else left_out

    @property
    def undecodable_left_note(self) -> str:
        """Return the sentence on left images without outputs that do not decode ("": none)."""
        count = self.undecodable_left
        if not count:
            return ""
        return (
            f"{count} frame{'' if count == 1 else 's'} left out: {'its' if count == 1 else 'their'}"
            " left image does not decode (a damaged JPEG or PNG), so densify skipped it and "
            "wrote no outputs (densify's pairing: line counts it undecodable)"
        )


@dataclass(frozen=True)
class _Complete:
    """A frame whose densified channels are all read, waiting for its right image.

    It also waits for its reference message; it is kept as messages, decoded and rectified
    only when it is yielded.
    """

    index: int
    stamp_ns: int
    parts: dict[str, Any]
    log_time_ns: int = 0
    """The log time of its left image: of messages sharing a stamp, the nearest is its own."""


def read_frames(
    path: Path,
    topics: OutputTopics,
    max_frames: int | None,
    reference: ReferenceTopic | None = None,
    state: ReadState | None = None,
    images: PairImages | None = None,
    tolerance_ns: int | None = None,
    *,
    poses: bool = True,
) -> Iterator[Frame]:
    """Yield the densified frames of a log in order, grouping channels by header stamp.

    A frame is its densified channels and left image of one stamp. It takes the right
    image, ``/ground_truth/depth`` (without a reference topic) and ``/ground_truth/pose``
    (with ``poses``) nearest its stamp within ``tolerance_ns`` (None: the tolerance the log
    records densify paired with), each when the log has the topic; a frame without one
    within it has None there and the distance to the nearest (``*_gap_ns``). A complete
    frame waits for each to have a message stamped at or after its own (they come in stamp
    order, so the nearest one is then known) and, once the left stamps went back (a restart),
    read as far past the frame's log time as the message it would take is before it
    (:meth:`Stamped.settled`: the message of a stamp nearest the frame in log time may then
    be logged after the frame's left image, whatever the recorder's order), at most
    :data:`RIGHT_WAIT_FRAMES` frames for the right image and :data:`TRUTH_WAIT_FRAMES` for
    truth and pose; a frame whose message never comes (dropped) goes on without it. With a
    reference topic, each frame carries the reference message nearest its stamp within
    ``state.reference_tolerance_ns`` (None: the frames' tolerance), each message matched to
    one frame, the one stamped nearest it (:meth:`Stamped.claim`); a frame waits for a
    reference stamped at or after its own and for the next frame, at most
    :data:`REFERENCE_WAIT_FRAMES` frames. The waits bound the frames held in memory. Of
    messages of one topic with the same stamp (stamps that restart mid-log, as a simulator
    restarted during the recording stamps them; a message logged twice), the one nearest
    the frame's left image in log time is matched (the first of a tie); the repeats are
    counted (``state.repeated``) and the report names them.

    Args:
        path: a log written by ``pcainterp densify``.
        topics: its output topics.
        max_frames: yield at most this many frames (None: all).
        reference: the reference topic, if any.
        state: filled with what reading finds besides the frames.
        images: the input pair's topics and rectification.
        tolerance_ns: the stamp tolerance of a frame's right image, truth and pose (ns).
        poses: read ``/ground_truth/pose`` (temporal mode needs it, stereo mode does not).

    Raises:
        LogReadError: the log lacks densified channels or the left images; a frame's
            channels do not decode.
    """
    state = state or ReadState()
    images = images or PairImages()
    left_image, right_image = images.left_topic, images.right_topic
    try:  # each camera's f*b when the camera changed (a compact log's depth needs it)
        cameras = FrameCameras.of_log(path, topics.prefix)
    except ValueError as err:
        raise LogReadError(str(err)) from None
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
        grouped = [*needed, left_image]
        complete = len(grouped)
        # the right image may be stamped up to the pairing tolerance apart from the left and
        # logged before or after the outputs (written at the left image's log time); the
        # truth and the poses may come from other clocks and rates: each is matched by stamp
        truth = [] if reference is not None else [GROUND_TRUTH_DEPTH]
        nearby_topics = [right_image, *truth, *([GROUND_TRUTH_POSE] if poses else [])]
        nearby = {
            t: Stamped(POSE_BUFFER if t == GROUND_TRUTH_POSE else PENDING_FRAMES)
            for t in nearby_topics
            if t in present
        }
        latest: dict[str, int] = {}
        logged: dict[str, int] = {}  # the last log time read of each: a topic's come in order
        wanted = [*grouped, *nearby]
        infos = [t for t in images.info_topics if t in present and t not in wanted]
        wanted += infos
        if reference is not None and reference.topic not in wanted:
            wanted.append(reference.topic)
        references = Stamped(REFERENCE_BUFFER)
        reference_latest = -1  # the last reference stamp read
        released: list[int] = []  # the stamp of the frame released last
        released_at: list[tuple[int, int]] = []  # and its log time
        taken: dict[str, dict[tuple[int, int], int]] = {}  # truth messages frames took
        stamps = SeenStamps()  # of the topics matched by stamp: repeated stamps counted
        unplaced = UnplacedStamps(left_image, *nearby)  # the right image, truth, poses
        # the reference on its own clock, by the same rule (a sim clock stamps every topic)
        reference_clock = UnplacedStamps(*([reference.topic] if reference is not None else []))
        pending: dict[int, dict[str, Any]] = {}
        pending_log_times: dict[int, int] = {}  # of the left image of a pending stamp
        waiting: deque[_Complete] = deque()
        index = yielded = 0
        left_high, restarted = -1, False  # the left stamps went back: the longer wait applies

        def ready(frame: _Complete) -> bool:
            """Return True when the oldest waiting frame has all it can still get."""
            stamp, log_time = frame.stamp_ns, frame.log_time_ns
            for topic in nearby:  # the right image waits less than truth from another source
                wait = RIGHT_WAIT_FRAMES if topic == right_image else TRUTH_WAIT_FRAMES
                # the nearest stamp is known once one at or after it is read; after stamps
                # restarted, the message nearest the frame's log time once the topic is read
                # as far past the frame as the one kept is before it (whatever the order)
                # and the truth's frame once the next frame not crowded after it is known
                # (one message, one frame; crowded: placed within a tick, its time unknown)
                if len(waiting) <= wait and (
                    latest.get(topic, -1) < stamp
                    or (topic != right_image and not next_known(stamp))
                    or (restarted and not nearby[topic].settled(stamp, log_time, logged[topic]))
                ):
                    return False
            # the nearest reference is known once one stamped at or after the frame's is
            # read, and whose it is once the next frame's stamp is known
            return (
                reference is None
                or (
                    reference_latest >= stamp
                    and len(waiting) > 1
                    and references.settled(stamp, log_time, logged[reference.topic])
                )
                or len(waiting) > REFERENCE_WAIT_FRAMES
            )

        def next_known(stamp: int) -> bool:
            """Whether a frame after the oldest waiting one is not crowded after it."""
            return any(not placed_crowded(f, [stamp]) for f in list(waiting)[1:])

        def placed_crowded(frame: _Complete, before: list[int]) -> bool:
            """Whether densify placed the frame crowded after ``before`` (:func:`crowded_stamp`)."""
            own = rosmsg.stamp_ns(frame.parts[images.left_topic])
            return own != frame.stamp_ns and crowded_stamp(frame.stamp_ns, before, state.steps)

        def release() -> Frame:
            frame = waiting.popleft()
            # its camera's f*b (a compact frame's features tell a change whose record was lost)
            features = frame.parts[topics.features] if where.compact else None
            metadata = cameras.metadata(state.metadata, frame.log_time_ns, features)
            state.unrecorded_note = cameras.unrecorded_note
            if where.compact and FOCAL_BASELINE_KEY not in metadata:
                recovered = _recover_focal_baseline(frame, topics.features, state)
                metadata = {**metadata, FOCAL_BASELINE_KEY: repr(recovered)}
            crowded = placed_crowded(frame, released)
            after = [f for f in waiting if not placed_crowded(f, [frame.stamp_ns])][:1]
            after = after or list(waiting)[:1]  # after a run of crowded frames (else the next)
            neighbours = [*released[-1:], *(f.stamp_ns for f in after)]
            matched, reference_gap = references.claim(
                frame.stamp_ns, frame.log_time_ns, state.reference_tolerance[0], neighbours
            )
            around = [*released_at, *((f.stamp_ns, f.log_time_ns) for f in after)]
            if not crowded:  # a crowded frame's placed stamp is no neighbour of another's
                if released and frame.stamp_ns > released[-1]:
                    state.steps.append(frame.stamp_ns - released[-1])
                released[:] = [frame.stamp_ns]
                released_at[:] = [(frame.stamp_ns, frame.log_time_ns)]
            if matched is not None and reference_gap is not None:
                state.reference_offsets.append(reference_gap)
            built = _frame(
                frame,
                nearby=nearby,
                reference=matched,
                reference_gap_ns=reference_gap if reference is not None else None,
                topics=topics,
                images=images,
                where=where,
                metadata=metadata,
                tolerance_ns=state.tolerance_ns,
                taken=taken,
                neighbours=around,
                squeezed=crowded or unplaced.squeezed(frame.stamp_ns),
            )
            for topic in built.shared:
                state.shared.setdefault(topic, []).append(built.index)
            state.shared_restamped += bool(built.shared) and built.restamped
            state.shared_squeezed += bool(built.shared) and (
                crowded or unplaced.squeezed(frame.stamp_ns)
            )
            return built

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
            try:
                message = reader.decode(raw)
            except LogReadError:  # densify skipped such an input message: no frame has it
                if raw.topic not in (left_image, right_image, *infos):
                    raise
                state.undecodable[raw.topic] = state.undecodable.get(raw.topic, 0) + 1
                continue
            if raw.topic in infos:
                images.see_info(raw.topic, message)
                continue
            if reference is not None and raw.topic == reference.topic:
                # stamped 0 or its previous message's: placed as truth and the frames are
                stamp = reference_clock.stamp(raw.topic, rosmsg.stamp_ns(message), raw.log_time_ns)
                stamps.first(raw.topic, stamp, state.repeated)  # a repeat is counted, and kept
                references.add(stamp, raw.log_time_ns, message)
                reference_latest, logged[raw.topic] = stamp, raw.log_time_ns
            full_estimate = raw.topic == where.estimate and not where.compact
            stamp = rosmsg.stamp_ns(message.image if full_estimate else message)
            if raw.topic in (left_image, right_image) and unplaced.copy(
                raw.topic, stamp, message, raw.log_time_ns
            ):
                state.copies[raw.topic] = state.copies.get(raw.topic, 0) + 1
                continue  # the same image again (densify dropped it): no frame, no repeat
            if raw.topic in (left_image, right_image, *nearby):
                stamp = unplaced.stamp(raw.topic, stamp, raw.log_time_ns)
                for topic, placed, moved in unplaced.moved():  # beside the first left image
                    nearby[topic].restamp(placed, moved)
                    if latest.get(topic) == placed:
                        latest[topic] = moved
            elif stamp == 0 and raw.log_time_ns != 0 and raw.topic in grouped:
                # (stamp 0 at log time 0 is a clock that starts at 0: KITTI's times.txt)
                raise LogReadError(_zero_output_message(path, raw.topic, left_image))
            if raw.topic in nearby:
                stamps.first(raw.topic, stamp, state.repeated)  # a repeat is counted, and kept
                nearby[raw.topic].add(stamp, raw.log_time_ns, message)
                # the last stamp, not the largest: after stamps restart, a frame of the new
                # run waits for the new run's messages
                latest[raw.topic], logged[raw.topic] = stamp, raw.log_time_ns
            elif raw.topic in grouped:
                parts = pending.setdefault(stamp, {})
                state.merged += raw.topic in parts
                parts[raw.topic] = message
                if raw.topic == left_image or stamp not in pending_log_times:
                    pending_log_times[stamp] = raw.log_time_ns
                if raw.topic == left_image:
                    restarted, left_high = restarted or stamp < left_high, max(left_high, stamp)
                if len(parts) == complete:
                    del pending[stamp]
                    log_time = pending_log_times.pop(stamp)
                    waiting.append(_Complete(index, stamp, parts, log_time))
                    index += 1
                while len(pending) > PENDING_FRAMES:  # frames are written close together
                    oldest = min(pending)
                    pending_log_times.pop(oldest, None)
                    _count_incomplete(pending.pop(oldest), grouped, state)
            while waiting and ready(waiting[0]):
                yield release()
                yielded += 1
                if max_frames is not None and yielded >= max_frames:
                    return
        for parts in pending.values():
            _count_incomplete(parts, grouped, state)
        while waiting:  # the end of the log: no right image or reference can come any more
            yield release()
            yielded += 1
            if max_frames is not None and yielded >= max_frames:
                return


def frame_count(path: Path, topics: OutputTopics, max_frames: int | None) -> int | None:
    """Return how many densified frames a log holds (at most ``max_frames``), for progress.

    The estimate channel's message count in the log's summary; None when the log has no
    summary of counts or cannot be read (its error is raised when it is evaluated).
    """
    try:
        with open_log(path) as reader:
            present = reader.topics()
    except PcaInterpError:
        return None
    estimate = estimate_topics(present, topics).estimate
    count = present[estimate].message_count if estimate in present else None
    if not count:
        return None
    return count if max_frames is None else min(count, max_frames)


def _missing_advice(
    present: Iterable[str], topics: OutputTopics, missing: list[str], left_image: str
) -> str:
    """Say how to get a log evaluate can read: densify it, or densify it with more outputs."""
    outputs = [topics.depth, topics.disparity, topics.depth_std, topics.disparity_std]
    outputs.append(topics.features)
    written = [topic for topic in (*outputs, topics.camera_info) if topic in present]
    close = closest_topic(left_image, present) if missing == [left_image] else None
    if close is not None:  # a typo in --left-topic, as densify's message says
        return f"; the closest is {close}: set --left-topic to it"
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


def _count_incomplete(parts: dict[str, Any], grouped: list[str], state: ReadState) -> None:
    """Count a stamp whose densified channels and left image never all came.

    A left image alone (no output of its stamp) whose image does not decode is counted
    apart (:attr:`ReadState.undecodable_left`): densify skipped it (the last of ``grouped``
    is the left image topic).
    """
    left = grouped[-1]
    if list(parts) == [left]:
        try:
            decode_image(parts[left])
        except (ValueError, PcaInterpError):
            state.undecodable_left += 1
            return
    for topic in grouped:
        if topic not in parts:
            state.incomplete[topic] = state.incomplete.get(topic, 0) + 1


def _zero_output_message(path: Path, topic: str, left_image: str) -> str:
    """Say that a densified output is stamped 0: written by a densify that copied stamp 0."""
    return (
        f"{path}: {topic} has header stamp 0: the input images ({left_image}) have no header "
        "stamps and the densify that wrote this log copied them, so its frames cannot be told "
        "apart or matched to truth; densify the input again (densify now stamps such frames "
        "with their left image's log time)"
    )


def _recover_focal_baseline(frame: _Complete, features_topic: str, state: ReadState) -> float:
    """Return a compact frame's f*b from its features when the log's metadata lacks it.

    A compact log's depth needs f*b to become disparity; densify records it in the channel
    metadata, which a ROS 2 bag tool drops. Every feature point holds z = f*b / disparity
    (``io/outputs``), so f*b = z * disparity of any point with a disparity: each frame's
    own (the camera may change), else the last frame's that had one.

    Raises:
        LogReadError: no frame so far had a feature point with a disparity.
    """
    focal_baseline = features_focal_baseline(frame.parts[features_topic])
    if focal_baseline is not None:
        state.recovered.append(focal_baseline)
        return focal_baseline
    if state.recovered:
        return state.recovered[-1]
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


def truth_depth(message: Any, topic: str = GROUND_TRUTH_DEPTH) -> npt.NDArray[np.float32]:
    """Read a ground-truth depth image as metres by its encoding (REP 118), as a reference's.

    32FC1 is metres, 16UC1 and mono16 millimetres (0: no value, NaN), as ``--reference-topic``
    reads them (:func:`~pcainterp_stream.io.depth_image.depth_metres`).

    Raises:
        LogReadError: the image is no depth image (a camera image's encoding).
    """
    try:
        return depth_metres(message).astype(np.float32)
    except ValueError as err:
        raise LogReadError(
            f"{topic}: {err}; ground-truth depth must be 32FC1 (m) or 16UC1 (mm)"
        ) from None


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
    nearby: dict[str, Stamped],
    reference: Any,
    reference_gap_ns: int | None = None,
    topics: OutputTopics,
    images: PairImages,
    where: EstimateTopics,
    metadata: dict[str, str],
    tolerance_ns: int = RIGHT_STAMP_TOLERANCE_NS,
    taken: dict[str, dict[tuple[int, int], int]] | None = None,
    neighbours: list[tuple[int, int]] | None = None,
    squeezed: bool = False,
) -> Frame:
    """Build a frame from its complete messages and the messages nearest its stamp.

    ``taken``: the truth messages earlier frames took (:func:`_shared_truth`); None: none.
    ``neighbours``: the frames before and after it, (stamp, log time) each: a truth message
    nearer one of them is that frame's. ``squeezed``: its stamp was placed with its time
    unknown (:meth:`UnplacedStamps.squeezed`) or crowded after the frame before
    (:func:`~pcainterp_stream.evaluate.stamped.crowded_stamp`: the second and later of
    stamps missed in a row): only a message of that very stamp is its own.
    """
    index, stamp, parts = complete.index, complete.stamp_ns, complete.parts
    taken = {} if taken is None else taken
    try:
        decoded = decode_estimate(
            parts[where.estimate], parts[where.std], parts[topics.camera_info], metadata
        )
    except ValueError as err:
        raise LogReadError(f"frame {index} of the densified log: {err}") from None
    estimate = decoded.disparity
    features = rosmsg.pointcloud2_arrays(parts[topics.features])
    log_time = complete.log_time_ns
    found = {
        topic: messages.nearest(stamp, tolerance_ns, log_time)
        for topic, messages in nearby.items()
        if topic not in TRUTH_TOPICS
    }
    shared = _truth_of_its_own(
        nearby, found, taken, complete, tolerance_ns, neighbours or [], squeezed=squeezed
    )
    right, gap, _ = found.get(images.right_topic, (None, None, None))
    depth, depth_gap, _ = found.get(GROUND_TRUTH_DEPTH, (None, None, None))
    pose, pose_gap, _ = found.get(GROUND_TRUTH_POSE, (None, None, None))
    left_image = images.rectified(decode_image(parts[images.left_topic]), "left")
    right_image = None if right is None else images.rectified(decode_image(right), "right")
    if right_image is not None:  # a colour + mono or 8 + 16-bit rig: grey, as densify made it
        left_image, right_image, _ = grey_alike(left_image, right_image)
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
        left=left_image,
        right=right_image,
        depth=None if depth is None else truth_depth(depth),
        pose=None if pose is None else rosmsg.pose_matrix(pose),
        min_disparity=decoded.min_disparity,
        reference=reference,
        reference_gap_ns=reference_gap_ns,
        right_gap_ns=gap if right is None else None,
        depth_gap_ns=depth_gap if depth is None else None,
        pose_gap_ns=pose_gap if pose is None else None,
        cx_offset=images.cx_offset(),
        shared=shared,
        restamped=rosmsg.stamp_ns(parts[images.left_topic]) != stamp,
    )


def _truth_of_its_own(
    nearby: dict[str, Stamped],
    found: dict[str, tuple[Any, int | None, tuple[int, int] | None]],
    taken: dict[str, dict[tuple[int, int], int]],
    complete: _Complete,
    tolerance_ns: int,
    neighbours: list[tuple[int, int]],
    *,
    squeezed: bool = False,
) -> tuple[str, ...]:
    """Put in ``found`` the frame's truth and pose messages; return the topics it lost.

    ``taken``: per truth topic, the messages frames took (their key: placed stamp, log time)
    and which frame took each (the latest :data:`POSE_BUFFER` kept). One message is the
    truth of one instant, so it goes to one frame, the one stamped nearest it, then logged
    nearest it (as a reference message, :meth:`Stamped.claim`): of a camera paused amid a
    run, the frame after the pause keeps its truth and the paused copies placed before it
    are left out (review 16b R1); frames stamped closer together than the truth (a clock
    stuck for the whole log) are left out, never scored against another frame's truth.
    A frame placed with no rate measured or crowded after the frame before (``squeezed``:
    within one frame interval of the last stamp of its own, its time unknown) takes only a
    message of its very stamp (truth repeated on the same paused clock, placed alike); a
    message merely near it is the truth of another instant: it is left out, as lost (the
    25-frame stuck log of fix EV16 scored its last frame against the second frame's truth,
    4.1 px).
    """
    lost = []
    for topic in TRUTH_TOPICS:
        if topic not in nearby:
            continue
        seen = taken.setdefault(topic, {})
        stamp, log_time = complete.stamp_ns, complete.log_time_ns
        message, gap, key, shared = nearby[topic].nearest_own(
            stamp, log_time, 0 if squeezed else tolerance_ns, neighbours, seen
        )
        if squeezed and message is None:  # one near it, of another instant: lost
            near = nearby[topic].nearest_own(stamp, log_time, tolerance_ns, neighbours, seen)
            gap, shared = near[1], shared or near[0] is not None or near[3]
        found[topic] = (message, gap, key)
        if shared:
            lost.append(topic)
        if key is not None:
            seen[key] = complete.index
            if len(seen) > POSE_BUFFER:
                del seen[next(iter(seen))]
    return tuple(lost)
