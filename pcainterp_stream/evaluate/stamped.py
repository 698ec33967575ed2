"""Match messages by header stamp while a densified log is read back (``evaluate``).

A message is matched to its frame by header stamp; a stamp that does not place it (0, a
stamp repeated by a coarse or restarted clock) falls back to the log time as densify's
pairing does (:class:`UnplacedStamps`); each topic matched by stamp keeps its latest
messages (:class:`Stamped`) and counts its repeated stamps (:class:`SeenStamps`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Container, Iterable
from typing import Any

import numpy as np

from pcainterp_stream.frontend.image_clock import ImageClock
from pcainterp_stream.frontend.pair_forms import same_image_message
from pcainterp_stream.io import rosmsg

__all__ = ["CROWDED_SHARE", "SeenStamps", "Stamped", "UnplacedStamps", "crowded_stamp"]


class UnplacedStamps:
    """Put at its log time a message whose header stamp does not place it, as densify does.

    densify stamps the outputs of a frame whose left image's header stamp is 0 (not set) or
    that of the image before it on the images' clock, or with the left image's log time when
    no image before had a stamp (``StereoPairer.full_result``, :mod:`frontend.image_clock`);
    its left image is placed so here, and so are a right image (the pair was made by log
    time), truth, poses and a reference topic's messages (each on its own clock: a coarse or
    simulator clock repeats their stamps too). An image that is its
    topic's previous one again (same stamp, size, encoding and bytes: a re-send, a merged bag) is a
    copy, which densify drops (``StereoPairer``'s duplicates): :meth:`copy` tells it.

    The first left image stamped 0 (a clock that starts at 0, or none) is placed at its log
    time, and so is the first message stamped 0 of every other topic, at its own log time:
    densify paired the first right image with the left by their equal stamps, whatever their
    log times, so a first message stamped 0 of another topic logged beside it (neither
    topic's second message read before the other's first) is placed with the left image.
    When it was read before the left one, :meth:`moved` says where it went.
    """

    def __init__(self, *clocked: str) -> None:
        self._clocks = {topic: ImageClock() for topic in clocked}
        self._last_image: dict[str, Any] = {}
        self._left = clocked[0] if clocked else ""
        self._read: dict[str, int] = {}  # messages read (copies not) of each topic
        self._first_zero: dict[str, int] = {}  # where a topic's first message stamped 0 went
        self._moved: list[tuple[str, int, int]] = []
        self._squeezed: dict[int, None] = {}  # left stamps placed with no rate measured

    def copy(self, topic: str, stamp_ns: int, message: Any, log_time_ns: int) -> bool:
        """Return True for an image that repeats its topic's previous one (densify's rule).

        Stamped 0, the same log time too (``frontend.pair_forms.is_copy``).
        """
        last, last_log_time = self._last_image.get(topic, (None, 0))
        if (
            last is not None
            and (stamp_ns or log_time_ns == last_log_time)
            and _same_image(message, last, stamp_ns)
        ):
            return True
        self._last_image[topic] = (message, log_time_ns)
        return False

    def stamp(self, topic: str, stamp_ns: int, log_time_ns: int) -> int:
        """Return the stamp to match a message of ``topic`` by: its header stamp or log time."""
        clock = self._clocks.get(topic)
        if clock is None:
            return log_time_ns if stamp_ns == 0 else stamp_ns
        placed = clock.stamp(stamp_ns, log_time_ns)
        if topic == self._left and clock.squeezed:
            self._squeezed[placed] = None
            if len(self._squeezed) > SeenStamps.LIMIT:
                del self._squeezed[next(iter(self._squeezed))]
        read = self._read[topic] = self._read.get(topic, 0) + 1
        left = self._first_zero.get(self._left) if self._read.get(self._left) == 1 else None
        if read == 1 and stamp_ns == 0 and topic == self._left:
            for other, first in self._first_zero.items():  # read before it, beside it
                if self._read.get(other) == 1:
                    self._moved.append((other, first, placed))
                    self._first_zero[other] = placed
        elif read == 1 and stamp_ns == 0 and left is not None:
            placed = left  # beside the first left image, stamped 0 too: with it
        if read == 1 and stamp_ns == 0:
            self._first_zero[topic] = placed
        return placed

    def squeezed(self, stamp_ns: int) -> bool:
        """Whether the left image placed at ``stamp_ns`` was placed with its time unknown.

        Its clock's stamp repeated before it measured a rate (paused at start, or stuck for
        the whole log): it was put within one frame interval of the stamp; or it is the
        second or later of a run of missed stamps cut by the clock's tick (review 16e R1):
        put within one tick. Its order is known, its time not (:attr:`ImageClock.squeezed`).
        """
        return stamp_ns in self._squeezed

    def moved(self) -> list[tuple[str, int, int]]:
        """Return (and forget) the messages placed again: (topic, placed stamp, new stamp)."""
        moved, self._moved = self._moved, []
        return moved


def _same_image(message: Any, last: Any, stamp_ns: int) -> bool:
    """Whether an image is ``last`` again: its stamp, size, encoding and bytes (densify's rule)."""
    return rosmsg.stamp_ns(last) == stamp_ns and same_image_message(message, last)


class SeenStamps:
    """The stamps seen lately of each topic matched by stamp, to count the repeats of each.

    Every message is kept (:class:`Stamped`), a repeat of a stamp too; only the count of
    repeats (``log_frames.ReadState.repeated``) comes from here.
    """

    LIMIT = 4096
    """Stamps remembered per topic (the oldest forgotten beyond it)."""

    def __init__(self) -> None:
        self._seen: dict[str, dict[int, None]] = {}

    def first(self, topic: str, stamp: int, repeated: dict[str, int]) -> bool:
        """Count a repeat of ``stamp`` on ``topic`` in ``repeated``; return whether it is the first.

        The callers keep every message whatever this returns.
        """
        seen = self._seen.setdefault(topic, {})
        if stamp in seen:
            repeated[topic] = repeated.get(topic, 0) + 1
            return False
        seen[stamp] = None
        if len(seen) > self.LIMIT:
            del seen[next(iter(seen))]
        return True


class Stamped:
    """The latest messages of a topic matched by stamp, with their log times.

    Stamps may repeat (stamps that restart mid-log, a message logged twice): every message
    is kept, the oldest in log order dropped beyond ``limit``, and a frame takes the one
    nearest its stamp and, of those, nearest its log time (:meth:`nearest`).
    """

    def __init__(self, limit: int) -> None:
        self._limit = limit
        self._messages: deque[tuple[int, int, Any]] = deque()  # stamp, log time, message
        self._changes = 0  # messages kept, restamped or claimed: what :meth:`settled` found
        self._found: tuple[tuple[int, int, int], int | None] = ((-1, -1, -1), None)

    def add(self, stamp: int, log_time_ns: int, message: Any) -> None:
        """Keep a message (the oldest one dropped beyond the limit)."""
        self._messages.append((stamp, log_time_ns, message))
        self._changes += 1
        if len(self._messages) > self._limit:
            self._messages.popleft()

    def restamp(self, stamp: int, new_stamp: int) -> None:
        """Match the messages kept with ``stamp`` by ``new_stamp`` instead."""
        self._messages = deque(
            (new_stamp if kept == stamp else kept, log_time, message)
            for kept, log_time, message in self._messages
        )
        self._changes += 1

    def settled(self, stamp: int, log_time_ns: int, read_ns: int) -> bool:
        """Whether no message of the topic still to be read can be nearer the frame.

        ``read_ns`` is the log time of the topic's last message read (a topic is logged in
        order, so the next ones are logged at or after it). True when the message a frame
        of ``stamp`` and ``log_time_ns`` would take (:meth:`nearest`) is logged at or after
        the frame's left image, or when the topic is read as far past the frame as that
        message is before it: a message of its stamp read later (stamps that restarted) is
        nearer the frame's log time only before then. Whether a nearer stamp may still come
        is the caller's (one at or after the frame's was read).
        """
        key = (stamp, log_time_ns, self._changes)
        if self._found[0] != key:  # one scan per frame and message kept
            index = self._index(stamp, log_time_ns)
            self._found = (key, None if index is None else self._messages[index][1])
        found = self._found[1]
        return found is not None and (
            found >= log_time_ns or read_ns - log_time_ns >= log_time_ns - found
        )

    def _index(self, stamp: int, log_time_ns: int) -> int | None:
        """Return the index of the message nearest ``stamp``, then ``log_time_ns`` (the first)."""
        best: tuple[int, int] | None = None
        found = None
        for index, (kept, log_time, _) in enumerate(self._messages):
            key = (abs(kept - stamp), abs(log_time - log_time_ns))
            if best is None or key < best:
                best, found = key, index
        return found

    def nearest(
        self, stamp: int, tolerance_ns: int, log_time_ns: int
    ) -> tuple[Any, int | None, tuple[int, int] | None]:
        """Return the message nearest ``stamp`` within the tolerance (else None), gap, key.

        The gap is in ns; the key tells which message it is: (its stamp as kept, its log
        time; None: none within the tolerance). Of messages of the nearest stamp, the one
        nearest ``log_time_ns`` (the first of a tie).
        """
        index = self._index(stamp, log_time_ns)
        if index is None:
            return None, None, None
        kept, log_time, message = self._messages[index]
        gap = abs(kept - stamp)
        if gap > tolerance_ns:
            return None, gap, None
        return message, gap, (kept, log_time)

    def nearest_own(
        self,
        stamp: int,
        log_time_ns: int,
        tolerance_ns: int,
        neighbours: Iterable[tuple[int, int]] = (),
        taken: Container[tuple[int, int]] = (),
    ) -> tuple[Any, int | None, tuple[int, int] | None, bool]:
        """Return the message of this frame nearest ``stamp`` within the tolerance, gap, key, lost.

        As :meth:`nearest`, but one message is the truth of one frame: the frame nearest it by
        stamp, then by log time (a tie: the earlier logged). A message nearer a neighbour
        frame (``neighbours``: the frames before and after, (stamp, log time) each) or in
        ``taken`` (keys an earlier frame took) is not this frame's. ``lost``: with no message
        of its own, one within the tolerance was another frame's. The message is kept.
        """
        others = list(neighbours)
        best: tuple[int, int] | None = None
        found: tuple[Any, int, tuple[int, int]] | None = None
        lost = False
        for kept, log_time, message in self._messages:
            gap = abs(kept - stamp)
            if gap > tolerance_ns:
                continue
            mine = (gap, abs(log_time - log_time_ns))
            if (kept, log_time) in taken or any(
                (abs(kept - s), abs(log_time - t)) < mine
                or ((abs(kept - s), abs(log_time - t)) == mine and (t, s) < (log_time_ns, stamp))
                for s, t in others
            ):
                lost = True
                continue
            if best is None or mine < best:
                best, found = mine, (message, gap, (kept, log_time))
        if found is not None:
            return *found, False
        index = self._index(stamp, log_time_ns)
        gap_of = None if index is None else abs(self._messages[index][0] - stamp)
        return None, gap_of, None, lost

    def claim(
        self, stamp: int, log_time_ns: int, tolerance_ns: int, neighbours: Iterable[int] = ()
    ) -> tuple[Any, int | None]:
        """Remove and return the message nearest ``stamp`` within the tolerance, and its gap.

        Each message goes to one frame, the one stamped nearest it: one nearer a neighbour
        frame's stamp (``neighbours``: the frames before and after; a tie goes to the
        earlier frame) is not this frame's. Of messages of the nearest stamp, the one nearest
        ``log_time_ns``. Without one: None and the gap of the nearest message kept (None:
        none kept).
        """
        others = list(neighbours)
        best: tuple[int, int] | None = None
        found = None
        for index, (kept, log_time, _) in enumerate(self._messages):
            gap = abs(kept - stamp)
            if gap > tolerance_ns or any(
                abs(kept - other) < gap or (abs(kept - other) == gap and other < stamp)
                for other in others
            ):
                continue
            key = (gap, abs(log_time - log_time_ns))
            if best is None or key < best:
                best, found = key, index
        if found is None:
            nearest = self._index(stamp, log_time_ns)
            return None, None if nearest is None else abs(self._messages[nearest][0] - stamp)
        kept, _, message = self._messages[found]
        del self._messages[found]
        self._changes += 1
        return message, abs(kept - stamp)


CROWDED_SHARE = 0.1
"""A frame stamped less than this share of the median frame step after the frame before it
was placed by densify (:func:`crowded_stamp`)."""


def crowded_stamp(stamp: int, before: list[int], steps: Iterable[int]) -> bool:
    """Whether a frame's stamp is far closer to the frame before than the frames' interval.

    Such a stamp was placed by densify, not given by the camera: of a run of missed stamps
    (repeated or 0) once the clock's rate is known, the second and later are placed within
    0.25 % of the clock's tick after the first (``frontend.image_clock``: the k-th at most
    ``s + tick * (1 - 0.005 / k)``), all short of the next stamp, so their time is not known
    (review 16e R1: in ``log_frames`` the 900 ms image, placed at 799.75 ms, took the 800 ms
    truth). A camera's own steps stay near the median interval (jitter, a drop: more):
    under 10 % of it would need jitter of 45 % of the interval, and the placed steps are
    40 times below it.
    ``before``: the stamp of the last frame not crowded (empty: none); ``steps``: the
    forward steps between such frames.
    """
    known = list(steps)
    if not before or not known or stamp < before[-1]:
        return False
    return stamp - before[-1] < CROWDED_SHARE * float(np.median(known))
