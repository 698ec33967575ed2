"""How long the stereo pairing holds what waits for its partner, and what it lost.

:class:`frontend.pairing.StereoPairer` reads a log in log-time order. An image waits there for
the other side's image of its stamp, a frame for the feature cloud of its stamp, a cloud for
its frame: for as long as the recording lag between the two streams (two driver nodes, a
recorder over a network, a compressing republisher, a SLAM back end's latency). What waits
is held by log-time span (:attr:`HoldLimits.span_ns`, seconds), not by a count of frames,
and bounded in messages and bytes so that a log with one side missing entirely cannot make
it grow. What the limits give up is remembered (stamp and log time, a bounded number), so
that a partner of its stamp arriving later is counted as lost, with the lag, in
:class:`Lost`: the pairing's warnings say how far apart the streams were logged and which
limit to raise.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from pcainterp_stream.frontend.image_clock import Restamp

MAX_GIVEN_UP = 4096
"""Stamps given up that are remembered per stream (to count a partner arriving later)."""

MAX_LAGS = 1000
"""Lags kept per :class:`Lost` (the counts are exact)."""


class Held(Protocol):
    """What waits in a queue: a stamp and a log time (ns)."""

    @property
    def stamp_ns(self) -> int: ...  # noqa: D102

    @property
    def log_time_ns(self) -> int: ...  # noqa: D102


T = TypeVar("T", bound=Held)


class PendingImage:
    """One image waiting for its partner: the message is decoded only when paired."""

    __slots__ = ("log_time_ns", "message", "miss_ns", "restamp", "stamp_ns")

    def __init__(self, stamp_ns: int, log_time_ns: int, message: Any) -> None:
        self.stamp_ns = stamp_ns
        self.log_time_ns = log_time_ns
        self.message = message
        self.miss_ns = -1  # the nearest other-side image that waited unpaired as it did
        # where it is placed when its header stamp does not (0, or its previous image's
        # stamp): a left image's, see frontend.image_clock; None: at its own stamp
        self.restamp: Restamp | None = None

    def nbytes(self) -> int:
        """Return the bytes of the image's (undecoded) data."""
        return len(getattr(self.message, "data", b""))


class HeldQueue(deque[T]):
    """A deque (oldest first) that keeps the bytes of its items (``nbytes``).

    Only ``append``, ``popleft``, ``remove`` and ``clear`` change it.
    """

    def __init__(self, size: Callable[[T], int]) -> None:
        super().__init__()
        self._size = size
        self.nbytes = 0

    def append(self, item: T) -> None:  # noqa: D102
        super().append(item)
        self.nbytes += self._size(item)

    def popleft(self) -> T:  # noqa: D102
        item = super().popleft()
        self.nbytes -= self._size(item)
        return item

    def remove(self, item: T) -> None:
        """Remove an item by identity (``==`` would compare two clouds' arrays)."""
        index = next((i for i, held in enumerate(self) if held is item), None)
        if index is None:
            raise ValueError("HeldQueue.remove(item): item not in the queue")
        del self[index]
        self.nbytes -= self._size(item)

    def clear(self) -> None:  # noqa: D102
        super().clear()
        self.nbytes = 0


@dataclass(frozen=True)
class HoldLimits:
    """When the oldest item waiting in a queue is given up.

    Attributes:
        window: items of a queue always held, whatever their log-time span and bytes (as
            many as were held before the hold was by log time: never fewer).
        span_ns: beyond ``window`` items, the log time (ns) the oldest may wait, from its
            log time to the newest message read.
        count: items of a queue never exceeded.
        nbytes: bytes (of images, frames and clouds) all the queues together hold at most,
            beyond ``window`` items per queue: a queue that grows beyond it gives up its oldest.
    """

    window: int
    span_ns: int
    count: int
    nbytes: int

    def __post_init__(self) -> None:
        if self.span_ns < 0:
            raise ValueError(f"hold_ns must be >= 0, got {self.span_ns}")
        if self.count < self.window:
            raise ValueError(f"hold_count must be >= window ({self.window}), got {self.count}")
        if self.nbytes < 1:
            raise ValueError(f"hold_bytes must be >= 1, got {self.nbytes}")

    def exceeded(self, queue: HeldQueue[T], now_ns: int, total_bytes: int) -> str | None:
        """Return the limit the queue's oldest item is beyond (span, count, bytes), or None."""
        if len(queue) <= self.window:
            return None
        if len(queue) > self.count:
            return "count"
        if total_bytes > self.nbytes:
            return "bytes"
        if now_ns - queue[0].log_time_ns > self.span_ns:
            return "span"
        return None


class Hold:
    """The queues of a pairing, their limits, and what the limits gave up, by kind.

    Args:
        limits: the limits.
        tolerance_ns: the pairing's stamp tolerance (ns): a later partner within it of an
            item given up is a lost pair.
    """

    def __init__(self, limits: HoldLimits, tolerance_ns: int) -> None:
        self.limits = limits
        self.tolerance_ns = tolerance_ns
        self.now_ns = -(2**63)  # the newest log time read
        self.backwards = False  # a log time before the newest: not read in log-time order
        self._queues: list[HeldQueue[Any]] = []
        self._given_up: dict[str, GivenUp] = {}

    def queue(self, size: Callable[[T], int]) -> HeldQueue[T]:
        """Return a new queue whose items are sized by ``size`` (bytes)."""
        queue: HeldQueue[T] = HeldQueue(size)
        self._queues.append(queue)
        return queue

    def saw(self, log_time_ns: int) -> None:
        """Note a message's log time (a log is read in log-time order if it can be)."""
        self.backwards = self.backwards or log_time_ns < self.now_ns
        self.now_ns = max(self.now_ns, log_time_ns)

    def give_up(self, kind: str, queue: HeldQueue[T]) -> list[T]:
        """Take out (and return) the oldest items of a queue beyond the limits."""
        given: list[T] = []
        while self.oldest_given_up(kind, queue):
            given.append(queue.popleft())
        return given

    def oldest_given_up(self, kind: str, queue: HeldQueue[T]) -> bool:
        """Whether the queue's oldest item is beyond the limits (remembered, not taken out)."""
        limit = self.beyond(queue)
        if limit is not None:
            self.remember(kind, queue, limit)
        return limit is not None

    def beyond(self, queue: HeldQueue[T]) -> str | None:
        """Return the limit the queue's oldest item is beyond (None: none; not remembered)."""
        return self.limits.exceeded(queue, self.now_ns, sum(q.nbytes for q in self._queues))

    def remember(self, kind: str, queue: HeldQueue[T], limit: str) -> None:
        """Remember the queue's oldest item as given up by ``limit`` (before it is taken out)."""
        self._given_up.setdefault(kind, GivenUp()).add(queue[0], limit, queue, self.now_ns)

    def taken(self, kind: str, stamp_ns: int) -> GivenUpItem | None:
        """Return (once) an item of ``kind`` given up within the tolerance of a stamp.

        None also for a log not read in log-time order: its lags mean nothing (the reader's
        warning says what reading it so cost).
        """
        given_up = self._given_up.get(kind)
        if given_up is None or self.backwards:
            return None
        return given_up.take(stamp_ns, self.tolerance_ns)


@dataclass
class Lost:
    """Partners that came after the hold had given up the other one (an accumulator).

    Attributes:
        count: pairs (or frame and cloud) lost so.
        lags_ns: log time of the later one minus that of the one given up (ns), the first
            :data:`MAX_LAGS`; negative: the one given up was logged later (a cloud before
            its frame).
        limits: the limits that gave them up (``span``, ``count``, ``bytes``).
        bytes_per_s: the largest rate of held bytes per second of log of a queue given up
            by its byte limit (0: none).
    """

    count: int = 0
    lags_ns: list[int] = field(default_factory=list)
    limits: set[str] = field(default_factory=set)
    bytes_per_s: float = 0.0

    def add(self, lag_ns: int, given_up: GivenUpItem) -> None:
        """Count one lost pair whose partner came ``lag_ns`` of log after the one given up."""
        self.count += 1
        if len(self.lags_ns) < MAX_LAGS:
            self.lags_ns.append(lag_ns)
        self.limits.add(given_up.limit)
        self.bytes_per_s = max(self.bytes_per_s, given_up.bytes_per_s)

    def lag_s(self) -> float:
        """Return the median lag (s), 0 when none was lost."""
        lags = sorted(self.lags_ns)
        return lags[len(lags) // 2] / 1e9 if lags else 0.0

    def beyond(self, limits: HoldLimits, held: str) -> str:
        """Return the limits that gave ``held`` up (e.g. "an image for its partner"), and the fix.

        Such as "beyond the 3 s of log the pairing holds an image for its partner; pass
        --hold-s 5".
        """
        widest = max((abs(lag) for lag in self.lags_ns), default=0) / 1e9
        parts = []
        # the wait given up can be longer than the lag (a frame is made when its later side
        # arrives), so the advice is never the value in force: at least one step beyond it
        if "span" in self.limits:
            span_s = limits.span_ns / 1e9
            parts.append(
                f"beyond the {span_s:g} s of log the pairing holds {held}; "
                f"pass --hold-s {max(int(widest), int(span_s)) + 1}"
            )
        if "bytes" in self.limits:
            need = self.bytes_per_s * widest * 1.25
            need = (need if need > limits.nbytes else 2 * limits.nbytes) / 2**20
            parts.append(
                f"beyond the {limits.nbytes / 2**20:g} MiB the pairing holds; pass --hold-mib "
                f"{int(need) + 1} if the machine has the memory"
            )
        if "count" in self.limits:
            parts.append(
                f"beyond the {limits.count} messages the pairing holds per stream "
                "(PairingConfig.hold_count)"
            )
        return "; or ".join(parts)


@dataclass(frozen=True)
class GivenUpItem:
    """An item the hold gave up: its stamp, log time, limit and the queue's byte rate."""

    stamp_ns: int
    log_time_ns: int
    limit: str
    bytes_per_s: float


class GivenUp:
    """The last :data:`MAX_GIVEN_UP` items a queue's limits gave up (oldest first)."""

    def __init__(self) -> None:
        self._items: deque[GivenUpItem] = deque(maxlen=MAX_GIVEN_UP)

    def add(self, item: Held, limit: str, queue: HeldQueue[T], now_ns: int) -> None:
        """Remember an item given up by ``limit`` from ``queue`` (before it was taken out)."""
        span_s = max(now_ns - item.log_time_ns, 1) / 1e9
        rate = queue.nbytes / span_s if limit == "bytes" else 0.0
        self._items.append(GivenUpItem(item.stamp_ns, item.log_time_ns, limit, rate))

    def take(self, stamp_ns: int, tolerance_ns: int) -> GivenUpItem | None:
        """Return (once) the nearest item given up within the tolerance of a stamp, or None."""
        best: GivenUpItem | None = None
        for item in self._items:
            gap = abs(item.stamp_ns - stamp_ns)
            if gap <= tolerance_ns and (best is None or gap < abs(best.stamp_ns - stamp_ns)):
                best = item
        if best is not None:
            self._items.remove(best)
        return best
