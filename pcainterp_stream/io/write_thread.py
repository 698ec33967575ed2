"""The writing thread of a threaded log writer: work items run in order behind a bounded queue.

:class:`pcainterp_stream.io.logwriter.LogWriter` hands its serializing, compressing and
writing to one :class:`WriteThread` when opened with ``threaded=True``.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable

from pcainterp_stream.errors import PcaInterpError

__all__ = ["WriteThread"]


class _Reply:
    """The outcome of one synchronous call, handed back by the writer thread.

    The caller waits on a plain lock, which a signal interrupts cleanly (a condition
    variable's Python code can be left half-way by ``KeyboardInterrupt``).
    """

    def __init__(self) -> None:
        self.error: BaseException | None = None
        self.ready = threading.Lock()
        self.ready.acquire()


class WriteThread:
    """One thread running a writer's work items in order, behind a bounded queue.

    After an error the thread keeps taking items (so the caller never blocks on a full
    queue) but runs none; :meth:`submit` and :meth:`check` raise what ``failed`` makes of
    it (an error naming the output). :meth:`call` runs one item synchronously.

    The hand-off is built from single native calls (:class:`queue.SimpleQueue`, a lock)
    rather than :class:`queue.Queue`: Ctrl-C raises ``KeyboardInterrupt`` between any two
    lines of the caller's Python code, and one raised inside ``Queue.put``'s notify could
    leave the writer asleep with work queued, so the clean-up that followed waited forever.
    Here an interrupt leaves at most one slot of the bound unused.
    """

    def __init__(
        self, failed: Callable[[BaseException], PcaInterpError], *, queue_items: int
    ) -> None:
        """Start the thread.

        Args:
            failed: turns an error of the work into the one raised (it names the output).
            queue_items: work items the queue holds before :meth:`submit` blocks.
        """
        self._failed = failed
        self._items: queue.SimpleQueue[tuple[Callable[[], None], _Reply | None] | None] = (
            queue.SimpleQueue()
        )
        self._slots: queue.SimpleQueue[None] = queue.SimpleQueue()
        for _ in range(queue_items):
            self._slots.put(None)
        self._error: BaseException | None = None
        self._cancelled = False
        self._thread = threading.Thread(target=self._loop, name="log-writer", daemon=True)
        self._thread.start()

    def _put(self, item: tuple[Callable[[], None], _Reply | None] | None) -> None:
        self._slots.get()  # blocks while queue_items items wait
        self._items.put(item)

    def _loop(self) -> None:
        while True:
            item = self._items.get()
            self._slots.put(None)
            if item is None:
                return
            work, reply = item
            if reply is not None:  # a synchronous call runs whatever happened before
                try:
                    work()
                except BaseException as err:  # raised in the caller by call()
                    reply.error = err
                reply.ready.release()
                continue
            if self._error is not None or self._cancelled:
                continue
            try:
                work()
            except BaseException as err:  # raised in the caller by submit / check
                self._error = err

    def _raise(self) -> None:
        if self._error is not None:
            raise self._failed(self._error) from self._error

    def submit(self, work: Callable[[], None]) -> None:
        """Queue ``work`` (blocks while the queue is full); raise an earlier error."""
        self._raise()
        self._put((work, None))

    def call(self, work: Callable[[], None]) -> None:
        """Run ``work`` in the thread after everything queued; raise its exception."""
        reply = _Reply()
        self._put((work, reply))
        reply.ready.acquire()
        if reply.error is not None:
            raise reply.error

    def check(self) -> None:
        """Wait until everything queued has run; raise the first error, if any."""
        self.call(lambda: None)
        self._raise()

    def cancel(self) -> None:
        """Skip the work still queued (synchronous calls still run)."""
        self._cancelled = True

    def stop(self, *, cancel: bool = False) -> None:
        """Stop the thread once it has run (or, with ``cancel``, skipped) what is queued."""
        self._cancelled = self._cancelled or cancel
        self._put(None)
        self._thread.join()
