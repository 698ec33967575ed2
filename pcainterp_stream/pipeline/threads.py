"""The frame processor's process-wide thread settings, and futures of work in parts.

OpenCV's and BLAS's thread counts, shared by the processors open at once, the stereo
workers' lower priority, and futures joining work split across a pool.
"""

from __future__ import annotations

import contextlib
import os
import threading
from concurrent.futures import Future
from typing import TypeVar

import cv2

from pcainterp_stream.pipeline.blas_threads import BlasThreads

T = TypeVar("T")


class ThreadLimits:
    """Process-wide OpenCV and BLAS thread counts, set on entry and restored on ``restore``.

    Shared by the processors open at once (several jobs in the threads of one process, as
    a Dask worker runs them): the first to ask sets a count and the last to leave puts the
    count found before back, so no job's BLAS goes back to several threads while another
    still runs (its products and factorisations would round differently). BLAS is counted
    with the jobs of :class:`~.blas_threads.BlasThreads` in one count (review 58c C1).
    """

    _lock = threading.Lock()
    _opencv_users = 0
    _opencv_previous: int | None = None

    def __init__(self, opencv_threads: int | None, blas_threads: int | None) -> None:
        self._opencv = opencv_threads is not None
        self._blas = blas_threads is not None
        cls = type(self)
        with cls._lock:
            if opencv_threads is not None:
                if cls._opencv_users == 0:
                    cls._opencv_previous = cv2.getNumThreads()
                    cv2.setNumThreads(opencv_threads)
                cls._opencv_users += 1
        if blas_threads is not None:
            BlasThreads.enter(blas_threads)

    def restore(self) -> None:
        """Leave; the last to leave puts back the counts found on entry (idempotent)."""
        cls = type(self)
        with cls._lock:
            if self._opencv:
                self._opencv = False
                cls._opencv_users -= 1
                if cls._opencv_users == 0 and cls._opencv_previous is not None:
                    cv2.setNumThreads(cls._opencv_previous)
                    cls._opencv_previous = None
            blas, self._blas = self._blas, False
        if blas:
            BlasThreads.leave()


def lower_priority(niceness: int) -> None:
    """Raise this thread's nice value by ``niceness`` (Linux: per thread; no-op elsewhere)."""
    if niceness <= 0 or not hasattr(os, "setpriority"):
        return
    tid = threading.get_native_id()
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + niceness)


def finished(results: list[T]) -> Future[list[T]]:
    """Return a future already holding ``results`` (work done on the calling thread)."""
    future: Future[list[T]] = Future()
    future.set_result(results)
    return future


def gathered(parts: list[Future[list[T]]]) -> Future[list[T]]:
    """Return a future of the parts' items in order, done when every part is.

    Cancelled when a part is (its pool shut down); failed with the first part's error.
    """
    if len(parts) == 1:
        return parts[0]
    whole: Future[list[T]] = Future()
    left = [len(parts)]
    lock = threading.Lock()

    def part_done(_: Future[list[T]]) -> None:
        with lock:
            left[0] -= 1
            if left[0]:
                return
        if any(part.cancelled() for part in parts):
            whole.cancel()
            return
        failed = next((part.exception() for part in parts if part.exception()), None)
        if failed is not None:
            whole.set_exception(failed)
        else:
            whole.set_result([item for part in parts for item in part.result()])

    for part in parts:
        part.add_done_callback(part_done)
    return whole
