"""Input messages held back until the outputs of their log time have gone out.

A densified frame's output messages carry the log time of its left image but are made
frames later (stereo matching runs ahead, the prior check's warm-up). Both the output file
and the live server copy the input messages, and both hold them in :class:`LogTimeHold`
until every frame at or before their log time is out, so that a reader (or a viewer) sees
the stream in log-time order, the input's own order kept.

Only the messages an output may still have to follow are held: those at or after the log
time of the oldest left image read whose frame is not yet written (:meth:`LogTimeHold.expect`),
or, with none, of the message read last (:meth:`LogTimeHold.passed`: inputs are read in
log-time order, and a later left image's outputs take its log time). Before the cameras
start, after they stop and in a gap between them, what is read goes out at once: the memory
held is that of the processing lag, not of the time the cameras are silent.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # light to import: the command line's parser reaches the live server
    from pcainterp_stream.records import RawMessage

__all__ = ["HOLD_BYTES", "HOLD_OVERHEAD", "CamerasRead", "LogTimeHold"]

HOLD_BYTES = 256 << 20
"""Bytes of input held back at most; beyond, the oldest message is let out anyway (it is
then out of log-time order)."""

HOLD_OVERHEAD = 256
"""Bytes a held message counts besides its data (its record), so that a burst of tiny
messages is bounded too."""


class LogTimeHold:
    """Hold input messages until :meth:`release` reaches their log time.

    Args:
        emit: called with each message let out, in input order.
        limit: bytes held at most (default: :data:`HOLD_BYTES`, read at each message).
        overhead: bytes each message counts besides its data.

    Attributes:
        released_early: messages let out because the hold was full.
        most_bytes: the most bytes held at once (data and overhead).
    """

    def __init__(
        self,
        emit: Callable[[RawMessage], None],
        *,
        limit: int | None = None,
        overhead: int = HOLD_OVERHEAD,
    ) -> None:
        self._emit = emit
        self._limit = limit
        self._overhead = overhead
        self._held: deque[RawMessage] = deque()
        self._bytes = 0
        self._expected: deque[int] = deque()  # log times of the left images not yet written
        self._latest = -(2**63)  # the log time read last (passed)
        self._ordered = True  # read in log-time order so far
        self.released_early = 0
        self.most_bytes = 0

    def add(self, raw: RawMessage) -> None:
        """Hold one input message (letting the oldest out while over the limit)."""
        self._held.append(raw)
        self._bytes += len(raw.data) + self._overhead
        self.most_bytes = max(self.most_bytes, self._bytes)
        limit = HOLD_BYTES if self._limit is None else self._limit
        while self._bytes > limit and self._held:
            self.released_early += 1
            self._emit_oldest()

    def expect(self, log_time_ns: int) -> None:
        """Note a left image read: a frame's outputs may still come at its log time.

        It is no longer waited for once a frame at or after its log time is written
        (:meth:`release`): it made that frame, or it makes none (unpaired, a duplicate).
        """
        self._expected.append(log_time_ns)

    def passed(self, log_time_ns: int) -> None:
        """Let out what no output can precede any more, the reader being at ``log_time_ns``.

        That is every held message up to the oldest left image expected (:meth:`expect`),
        or, with none, up to ``log_time_ns``: a left image read later has a log time at
        least this one's, and its outputs come after the inputs up to it. A log read out of
        log-time order (unindexed, stored topic by topic) gives no such bound: from its first
        step back in log time the messages wait for the frames after them (:meth:`release`).
        """
        if log_time_ns < self._latest:
            self._ordered = False
        if self._ordered:
            self._latest = log_time_ns
            self.release_held(self._expected[0] if self._expected else log_time_ns)

    def release(self, log_time_ns: int | None = None) -> None:
        """Let out the held messages up to ``log_time_ns`` in input order (all with None).

        Called before a frame's outputs at ``log_time_ns`` are written: the left images
        expected up to it are no longer waited for.
        """
        expected = self._expected
        while expected and (log_time_ns is None or expected[0] <= log_time_ns):
            expected.popleft()
        self.release_held(log_time_ns)

    def release_held(self, log_time_ns: int | None = None) -> None:
        """Let out the held messages up to ``log_time_ns`` in input order (all with None)."""
        held = self._held
        while held and (log_time_ns is None or held[0].log_time_ns <= log_time_ns):
            self._emit_oldest()

    def notes(self) -> list[str]:
        """The note of the messages let out early (the hold was full), or none."""
        if not self.released_early:
            return []
        return [
            f"{self.released_early} input messages were copied ahead of the outputs of an "
            f"earlier log time: {self.most_bytes / 1e6:.0f} MB of input waited on frames in "
            "the making (the limit held); the output is out of log-time order there"
        ]

    def _emit_oldest(self) -> None:
        raw = self._held.popleft()
        self._bytes -= len(raw.data) + self._overhead
        self._emit(raw)


class CamerasRead:
    """Tell when the topics that make frames have been read whole, by the index's counts.

    Once every such topic's messages are read, no frame can start any more: the frames
    still in the making can be finished then rather than at the log's end, so that a long
    tail of other topics (a LiDAR recorded on after the cameras stop) neither waits in the
    hold nor keeps the progress bar still.

    Args:
        counts: topic -> its message count in the log (None: not indexed, never done).
    """

    def __init__(self, counts: dict[str, int | None]) -> None:
        known = all(isinstance(count, int) and count > 0 for count in counts.values())
        self._left: dict[str, int] | None = (
            {topic: int(count or 0) for topic, count in counts.items()}
            if known and counts
            else None
        )
        self._topics = frozenset(counts)
        self._last_ns: int | None = None  # log time of the last of them
        self.done = False
        self.late = 0  # their messages read after all were counted (the index was wrong)

    def read(self, topic: str, log_time_ns: int) -> bool:
        """Count a message read; True once, at the first message after the last of them.

        A message at the last one's log time does not end them: the inputs at that log
        time go out before its frame's outputs, as at the log's end. Messages of them read
        after that (an index that under-counts them) are counted in :attr:`late` and said
        (:meth:`lines`): their frames come after the others were finished, so the fit check
        may have seen fewer frames than with a right index.
        """
        left = self._left
        if left is None:
            return False
        if self.done:
            self.late += topic in self._topics
            return False
        if self._last_ns is not None and log_time_ns > self._last_ns:
            self.done = True
            return True
        if topic in left:
            left[topic] -= 1
            if all(count <= 0 for count in left.values()):
                self._last_ns = log_time_ns
        return False

    def lines(self) -> list[str]:
        """The warning for frame-topic messages read after the index said they had ended."""
        if not self.late:
            return []
        return [
            f"{self.late} message(s) of the camera topics came after the log's index "
            "said they had ended (its message counts are wrong: a bag whose metadata.yaml was "
            "edited or cut?): the frames in progress were finished before them, as at the "
            "log's end, and the outputs may differ from a right index's; reindex the log "
            "(ros2 bag reindex, rosbag reindex) for the usual output"
        ]
