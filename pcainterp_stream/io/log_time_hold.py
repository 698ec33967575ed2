"""Input messages held back until the outputs of their log time have gone out.

A densified frame's output messages carry the log time of its left image but are made
frames later (stereo matching runs ahead, the prior check's warm-up). Both the output file
and the live server copy the input messages, and both hold them in :class:`LogTimeHold`
until every frame at or before their log time is out, so that a reader (or a viewer) sees
the stream in log-time order, the input's own order kept.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # light to import: the command line's parser reaches the live server
    from pcainterp_stream.records import RawMessage

__all__ = ["HOLD_BYTES", "HOLD_OVERHEAD", "LogTimeHold"]

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
        self.released_early = 0

    def add(self, raw: RawMessage) -> None:
        """Hold one input message (letting the oldest out while over the limit)."""
        self._held.append(raw)
        self._bytes += len(raw.data) + self._overhead
        limit = HOLD_BYTES if self._limit is None else self._limit
        while self._bytes > limit and self._held:
            self.released_early += 1
            self._emit_oldest()

    def release(self, log_time_ns: int | None = None) -> None:
        """Let out the held messages up to ``log_time_ns`` in input order (all with None)."""
        held = self._held
        while held and (log_time_ns is None or held[0].log_time_ns <= log_time_ns):
            self._emit_oldest()

    def _emit_oldest(self) -> None:
        raw = self._held.popleft()
        self._bytes -= len(raw.data) + self._overhead
        self._emit(raw)
