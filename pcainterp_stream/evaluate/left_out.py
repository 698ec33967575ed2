"""The frames ``pcainterp evaluate`` leaves out for want of a truth or pose near their stamp.

A frame takes the ground-truth depth and pose nearest its stamp within the stamp tolerance.
When some have none, the report says how far the nearest was and, when a wider tolerance
would take the frame's own message, which tolerance to pass: never one of a second or more
(that is another clock, not a late message) nor half a frame period (another frame's).

Temporal mode pairs a frame with the next one only when that is one frame interval later
(:meth:`LeftOut.pairs`: at most :data:`PAIR_STEP_FACTOR` x the median stamp step, forward in
time); across a pause, dropped frames or stamps that go back the frame is left unpaired,
and counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from pcainterp_stream.evaluate.frame_step import frame_step_ns
from pcainterp_stream.evaluate.log_frames import (
    GROUND_TRUTH_DEPTH,
    GROUND_TRUTH_POSE,
    Frame,
    ReadState,
)
from pcainterp_stream.evaluate.reference import ReferenceTopic, disparity_image_dropped
from pcainterp_stream.evaluate.results import Evaluation, grouped_causes
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.outputs import OutputTopics

__all__ = [
    "MAX_ADVISED_TOLERANCE_NS",
    "PAIR_STEP_FACTOR",
    "LeftOut",
    "no_reference_message",
    "no_truth_cause",
    "no_truth_message",
    "reference_tolerance",
]

MAX_ADVISED_TOLERANCE_NS = 1_000_000_000
"""The widest stamp tolerance the report advises: a gap of a second or more is another
clock (or stamps that are not set), which no tolerance matches frame by frame."""

PAIR_STEP_FACTOR = 1.5
"""Temporal mode pairs frames at most this many median stamp steps apart (one frame
interval, with jitter; a frame dropped in between makes two)."""


@dataclass
class LeftOut:
    """Frames left out for want of a truth or pose message near their stamp."""

    truths: int = 0
    poses: int = 0
    gaps: dict[str, list[int]] = field(default_factory=lambda: {"truth": [], "pose": []})
    stamps: list[int] = field(default_factory=list)
    """The stamps (ns) of the frames read, for their period."""
    step_ns: int | None = None
    """The median step of the log's frame stamps (ns; None: unknown), for :meth:`pairs`."""
    unpaired: int = 0
    """Frames temporal mode left unpaired: the next frame was not one interval later."""

    def pairs(self, before_ns: int, after_ns: int) -> bool:
        """Return whether two frames read one after the other make a temporal pair; count not.

        The second must be later by at most :data:`PAIR_STEP_FACTOR` x :attr:`step_ns`
        (any step forward when that is unknown).
        """
        step = after_ns - before_ns
        limit = math.inf if self.step_ns is None else PAIR_STEP_FACTOR * self.step_ns
        if 0 < step <= limit:
            return True
        self.unpaired += 1
        return False

    def see(self, gap_ns: int | None, what: str, *, shared: bool = False) -> None:
        """Count a frame without ``what`` ("truth" or "pose"); ``gap_ns``: the nearest's.

        ``shared``: the nearest message was an earlier frame's (``ReadState.shared_note``
        says so): not counted here.
        """
        if shared:
            return
        if what == "truth":
            self.truths += 1
        else:
            self.poses += 1
        if gap_ns is not None:
            self.gaps[what].append(gap_ns)

    def notes(self, state: ReadState, truth_topic: str) -> list[str]:
        """Say how many frames lacked a pose or truth, and the tolerance that would pair them."""
        notes = []
        for what, count, topic in (
            ("truth", self.truths, truth_topic),
            ("pose", self.poses, GROUND_TRUTH_POSE),
        ):
            if not count or not topic:
                continue
            tolerance, where = (
                state.reference_tolerance
                if what == "truth"
                else (state.tolerance_ns, state.tolerance_from)
            )
            note = (
                f"{count} frame{'' if count == 1 else 's'} left out: no {topic} within "
                f"{tolerance / 1e6:g} ms of their stamp ({where})"
            )
            gaps = self.gaps[what]
            if gaps:
                note += f"; {len(gaps)} had one {min(gaps) / 1e6:.2f}-{max(gaps) / 1e6:.2f} ms away"
                note += self._advice(max(gaps), topic)
            notes.append(note)
        if self.unpaired:
            step = "" if self.step_ns is None else f" of {self.step_ns / 1e6:.3g} ms"
            notes.append(
                f"{self.unpaired} frame{'' if self.unpaired == 1 else 's'} left unpaired in "
                "temporal mode: the next frame is not one frame interval after it (more than "
                f"{PAIR_STEP_FACTOR:g} x the median step{step} later, or earlier: a pause, "
                "dropped frames or stamps that go back)"
            )
        return notes

    def _advice(self, widest_ns: int, topic: str) -> str:
        """Return the tolerance to pass, or why none would take the frames' own messages."""
        unique = np.unique(self.stamps)
        steps = np.diff(unique)
        period = float(np.median(steps)) if steps.size else math.inf
        if len(self.stamps) > 1 and unique.size == 1:
            return (
                f", and all {len(self.stamps)} frames have header stamp {int(unique[0])} ns: "
                "their stamps do not tell them apart (the input images have no header stamps), "
                "so no tolerance matches them; densify the input again, which stamps such "
                "frames with their left image's log time"
            )
        if widest_ns >= MAX_ADVISED_TOLERANCE_NS:
            return (
                f": a second or more, so {topic} and the images are stamped on different "
                "clocks (or not at all); no tolerance matches them frame by frame: stamp them "
                "on one clock"
            )
        if widest_ns < period / 2:
            return f": pass --stamp-tolerance-ms {math.ceil(widest_ns / 1e6)} to take it"
        # a stamp half a frame away or more is another frame's: no tolerance fixes it
        return f", another frame's ({period / 1e6:.0f} ms apart): the stream lacks them"


def reference_tolerance(
    state: ReadState,
    given_ns: int | None,
    path: Path,
    topics: OutputTopics,
    max_frames: int | None,
) -> None:
    """Set the stamp tolerance of a reference topic's messages in ``state``.

    ``--stamp-tolerance-ms`` when given; else just under half the frame interval, so that a
    frame takes the reference nearest it and never its neighbour's: a user's reference (a
    LiDAR scan projected into the camera) is stamped with its own sensor's time, not the
    camera's. A log of one frame keeps the frames' tolerance.
    """
    if given_ns is not None:
        state.reference_tolerance_ns = given_ns
        state.reference_tolerance_from = "--stamp-tolerance-ms"
        return
    step = frame_step_ns(path, topics, max_frames)
    if step is None or step < 2:
        return
    state.reference_tolerance_ns = (step - 1) // 2
    state.reference_tolerance_from = (
        f"the default for a reference topic: under half the frame interval of "
        f"{step / 1e6:.3g} ms; set it with --stamp-tolerance-ms"
    )


def no_truth_message(
    path: Path, result: Evaluation, reference: ReferenceTopic | None, max_frames: int | None
) -> str:
    """Say that no evaluated frame's reference had a pixel with truth, and what to do."""
    count = result.frames + len(result.no_truth)
    frames = f"{count} frame{'' if count == 1 else 's'} evaluated"
    if max_frames is not None:
        frames += f" (at most {max_frames}: --max-frames)"
    if result.reference == "SGBM":
        return (
            f"SGBM of the pair found no pixel in any of the {frames} of {path}, so there is "
            "no reference to score against; evaluate a log with ground truth or pass "
            "--reference-topic"
        )
    topic = reference.topic if reference is not None else GROUND_TRUTH_DEPTH
    causes = grouped_causes(result.no_truth, result.no_truth_causes) or [NO_VALUE]
    return (
        f"{topic} holds no truth in any of the {frames} of {path}: {'; '.join(causes)}, so "
        "there is nothing to score against; pass a --reference-topic that holds truth"
    )


NO_VALUE = "every pixel is NaN, 0 or < 0 (no value, REP 118; +inf, too far, would count)"
"""Why a depth or disparity image holds no truth when nothing else explains it."""


def no_truth_cause(
    frame: Frame,
    reference: npt.NDArray[np.float64],
    counted: npt.NDArray[np.bool_],
    topic: ReferenceTopic | None,
    *,
    mode: str,
    sgbm: bool,
) -> str:
    """Say why a frame's reference holds no truth on any pixel to score.

    Args:
        frame: the frame (its reference message, for a DisparityImage's own bounds).
        reference: its reference disparity (px; NaN: no truth).
        counted: the reference pixels that land in the other view (``ReferenceView.counted``).
        topic: the reference topic (None: the ground truth or SGBM).
        mode: ``stereo`` or ``temporal``.
        sgbm: the reference is SGBM of the pair.
    """
    with np.errstate(invalid="ignore"):
        truth = np.isfinite(reference) & (reference >= 0)
    if not truth.any():
        if sgbm:
            return "SGBM found no pixel in the pair"
        if topic is not None and topic.msgtype == rosmsg.DISPARITY_IMAGE:
            dropped = disparity_image_dropped(frame.reference, frame.cx_offset or 0.0)
            return dropped or "every pixel is NaN, 0 or < 0 (no value)"
        return NO_VALUE
    if not counted.any():
        other = "the next frame (temporal mode)" if mode == "temporal" else "the right camera"
        return f"its {int(truth.sum())} px of truth all leave the view of {other}"
    return (
        "its truth lies only where the estimate is NaN (outside the rectified box of a raw or "
        "black-bordered pair)"
    )


def no_reference_message(frame: Frame, right_topic: str, state: ReadState) -> str:
    """Say why a frame has no reference: no right image within the tolerance, or none."""
    gap = frame.right_gap_ns
    if gap is None:
        return (
            f"frame {frame.index} has neither {GROUND_TRUTH_DEPTH} nor {right_topic}; "
            "evaluate needs ground truth or the right image for an SGBM reference"
        )
    start = (
        f"frame {frame.index} has no {GROUND_TRUTH_DEPTH} and the right images of "
        f"{right_topic} did not pair with it within {state.tolerance_ns / 1e6:g} ms "
        f"({state.tolerance_from}; the nearest is {gap / 1e6:.2f} ms away), so there is no "
        "SGBM reference"
    )
    if state.undecodable.get(right_topic):  # its own right image may be the one skipped
        return (
            f"{start}; {state.undecodable[right_topic]} of {right_topic}'s messages read so far "
            "do not decode (damaged, or bytes of another type): this frame's may be one of them, "
            "so no tolerance is advised; evaluate a log with ground truth or pass "
            "--reference-topic"
        )
    if gap >= MAX_ADVISED_TOLERANCE_NS:  # no tolerance of a second or more is advised
        return (
            f"{start}; a second or more: the right images are not this frame's (stamped on "
            "another clock, or its own is missing); evaluate a log with ground truth or pass "
            "--reference-topic"
        )
    return f"{start}; pass --stamp-tolerance-ms {math.ceil(gap / 1e6)}" + (
        " (as densify was given)" if state.tolerance_from.startswith("the default") else ""
    )
