"""The stamp of an image whose header stamp does not place it: on the image clock, or log time.

An image whose header stamp is 0 (not set) or its previous image's (a coarse device clock, a
simulator whose ``/clock`` ticks slower than the camera, a stamp missed once) tells nothing of
when it was taken. densify stamps the outputs of such a frame (``StereoPairer.full_result``)
and ``evaluate`` finds its input images (``evaluate.log_frames``) by the same rule, one
:class:`ImageClock` per image topic fed its images in log order, copies left out:

- once an image of the topic had a stamp of its own (the log has a header clock), an unplaced
  image stays on that clock, after the last stamp of its own ``s`` (logged at ``l``):
  ``s + rate * (log time - l)``, ``rate`` the clock's: the median, over its last
  :data:`RATE_SPAN` advances, of the stamp advance over the log-time advance between two
  images with stamps of their own, at most 1 (a clock that jumped ahead is taken at log-time
  rate). A coarse clock's 1000.0, 1000.0, 1000.2 s at 10 Hz (rate 1) give 1000.1 for the
  repeat; a simulator at half real time whose stamps repeat (1000.0, 1000.0, 1000.1,
  1000.1 ...: rate 0.5) gives 1000.05, 1000.15 ...: between the stamps of their own around
  it. The ``k``-th image of a run stays short of ``s`` plus the clock's tick (the least of
  its last :data:`RATE_SPAN` advances): at most ``s + tick * (1 - TICK_MARGIN / k)``, so a
  clock that pauses (a simulator paused amid a run: its stamp repeats for seconds, then
  goes on one tick later) has its repeats placed within one tick of ``s``, before its next
  stamp, not at rate 1 past the stamps of the frames after the pause. A stamp missed once
  is placed at least :data:`TICK_MARGIN` of the tick short of ``s`` plus the least of its
  last advances: 0.5 ms early on an even 10 Hz clock, on an uneven one by its jitter too
  (stamps +-5 ms at 10 Hz: about 92-95 ms after ``s``). Stamps missed on several images in a
  row are all placed within that one tick (10 Hz: 99.5, 99.75 ... ms after ``s``), so
  ``evaluate`` takes their time as unknown from the second on;
- while no rate is measured yet (one stamp of its own so far), the ``k``-th image after it
  is placed at ``s + (log time - l) / (k + 1)``: at a steady frame rate within one frame
  interval of ``s`` (1000.05, 1000.067, 1000.075 ... s at 10 Hz), short of the next stamp
  of any clock that ticks no finer than the frames come (a simulator paused at start);
- each placed stamp is later than the one placed before it (by 1 ns at least) and than the
  last stamp of its own; an image's own stamp at or before the last stamp placed (a clock
  that advanced by less than its tick, or after some hundred thousand repeats) is placed
  1 ns after it instead. So the stamps given out never repeat or go back, except where the
  clock itself goes back (restarted: its stamps are kept and measured again) and at its
  first stamp after images placed at their log times (below);
- before any stamp of its own (a camera that stamps nothing, all 0; or the images before a
  clock's first stamp) the log time is the only clock there is: the image's log time.

A clock stuck for a whole log (every image the same stamp, no rate ever measured) has its
images placed ever closer within one frame interval of the stamp: ``evaluate`` gives each
truth or pose message to the one frame stamped nearest it, so such frames are left out
there and said, never scored against another frame's truth.

No image is held back: the rule looks only at the images before. A clock that starts at 0
(a simulator's first frame stamped 0.0 s, then 0.1, 0.2 ...) therefore still places that
first frame at its log time: telling it from a camera that never stamps needs the next image;
and a clock that slows down amid a run of repeats can still be passed by its placed stamps.
"""

from __future__ import annotations

from collections import deque
from statistics import median
from typing import NamedTuple

RATE_SPAN = 5
"""The clock's rate is the median of its rate over this many last advances."""

TICK_MARGIN = 0.005
"""The first repeat stays this share of the clock's tick short of its next stamp."""


class Restamp(NamedTuple):
    """Where an unplaced image is placed: ``stamp_ns``, on the image clock or by log time."""

    stamp_ns: int
    by_log_time: bool


class ImageClock:
    """One image topic's images in log order: where each image whose stamp does not place it is.

    See the module docstring for the rule.
    """

    def __init__(self) -> None:
        self._previous: int | None = None  # the header stamp of the topic's previous image
        self._own: tuple[int, int] | None = None  # (stamp, log time) of the last own stamp
        self._rates: deque[float] = deque(maxlen=RATE_SPAN)  # stamp / log-time advances
        self._run = 0  # images placed since the last own stamp
        self._placed = 0  # the last stamp placed (or own) since that one
        self._ticks: deque[int] = deque(maxlen=RATE_SPAN)  # the stamp advances
        self._given = -1  # the last stamp given out on this clock (-1: none yet)
        self.squeezed = False
        """Whether the last image was placed with no rate measured (within one frame of its
        stamp), or as the second or later of a run cut by the tick (within one tick: review
        16e R1): its time is not known, only its order."""

    def place(self, stamp_ns: int, log_time_ns: int) -> Restamp | None:
        """Take the topic's next image; return where it is placed, None: at its own stamp."""
        previous, self._previous = self._previous, stamp_ns
        self.squeezed = False
        if stamp_ns not in (0, previous):
            passed = self._own is not None and self._own[0] <= stamp_ns <= self._given
            self._see_own(stamp_ns, log_time_ns)
            if passed:  # the placed stamps passed it: after them, in order
                self._placed = self._given = self._given + 1
                return Restamp(self._given, by_log_time=False)
            self._given = stamp_ns
            return None
        if self._own is None:
            return Restamp(log_time_ns, by_log_time=True)
        own_ns, own_log_ns = self._own
        if stamp_ns == own_ns and log_time_ns <= own_log_ns:
            return None  # its stamp again at the same log time: that message logged twice
        self._run += 1
        since = max(0, log_time_ns - own_log_ns)
        if self._rates:  # on the clock, short of its next tick
            tick = min(self._ticks)
            short = tick - round(tick * TICK_MARGIN / self._run)
            at_rate = round(min(1.0, median(self._rates)) * since)
            placed = own_ns + min(at_rate, short)
            self.squeezed = self._run > 1 and at_rate > short  # a later one of a run, cut
        else:  # no rate yet: within one frame interval of the stamp
            placed = own_ns + since // (self._run + 1)
            self.squeezed = True
        self._placed = self._given = max(placed, self._placed + 1)
        return Restamp(self._placed, by_log_time=False)

    def stamp(self, stamp_ns: int, log_time_ns: int) -> int:
        """Take the topic's next image; return the stamp it is placed at (its own or not)."""
        restamp = self.place(stamp_ns, log_time_ns)
        return stamp_ns if restamp is None else restamp.stamp_ns

    def _see_own(self, stamp_ns: int, log_time_ns: int) -> None:
        """Take a stamp of the image's own: the clock's rate since the last one."""
        if self._own is not None:
            own_ns, own_log_ns = self._own
            if stamp_ns > own_ns and log_time_ns > own_log_ns:
                self._rates.append((stamp_ns - own_ns) / (log_time_ns - own_log_ns))
                self._ticks.append(stamp_ns - own_ns)
            elif stamp_ns < own_ns:  # the clock restarted: its rate is measured again
                self._rates.clear()
                self._ticks.clear()
        self._own = (stamp_ns, log_time_ns)
        self._run = 0
        self._placed = stamp_ns
