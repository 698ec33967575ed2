"""BLAS held at one thread while any job runs, and the caller's counts given back after.

A job holds every BLAS at one thread (its bytes do not depend on the machine's core count),
and the solver holds scipy's OpenBLAS, loaded inside the first job, at one thread
(``compiled.py``). Two kinds of job count here, in one process-wide count
(:class:`BlasThreads`): the frame processors (:class:`~.threads.ThreadLimits`, also one a
caller opens itself) and the ``densify``, ``evaluate``, ``learn`` and ``demo`` jobs and
every command :func:`pcainterp_stream.cli.main` runs in-process (:func:`restoring_blas_threads`).
When the last of either kind returns, a caller's own ``scipy.linalg`` work is not left
single-threaded (bug hunt 10A F1, review 58a R7), and no job's BLAS gets several threads
back while another job still runs (review 58c C1). OpenBLAS (0.3.30 measured) takes a count
set from the main thread only: a last job leaving in another thread cannot give it back.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar, ParamSpec, TypeVar

_P = ParamSpec("_P")
_R = TypeVar("_R")


class BlasThreads:
    """The one process-wide count of the jobs holding BLAS at a few threads.

    The first to enter notes the caller's counts and sets every loaded BLAS to its
    ``threads``; later ones share that count (jobs nest and run concurrently, in the
    threads of one process as a Dask worker runs them). When the last leaves, each BLAS
    the caller had gets its count back and one loaded during the jobs the count the
    caller's environment gives a new one (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``,
    else the CPUs this process may run on).
    """

    lock: ClassVar[threading.Lock] = threading.Lock()
    running: ClassVar[int] = 0
    before: ClassVar[dict[str, int]] = {}
    default: ClassVar[int] = 1
    threads: ClassVar[int] = 1

    @classmethod
    def enter(cls, threads: int = 1) -> None:
        """A job begins: the first of those running notes the counts and sets ``threads``.

        Every later one sets the first one's count on the BLAS loaded since: the command
        line enters before it imports NumPy (its imports are lazy), and a frame processor
        entering after it found numpy's OpenBLAS at the machine's thread count, which then
        spun two threads through every product (the whole job at 1.3x its CPU).
        """
        with cls.lock:
            libraries = _blas_libraries()
            if cls.running == 0:
                cls.before = {lib.filepath: lib.num_threads for lib in libraries}
                cls.default = _default_blas_threads()
                cls.threads = threads
            for lib in libraries:
                if lib.num_threads != cls.threads:
                    lib.set_num_threads(cls.threads)
            cls.running += 1

    @classmethod
    def leave(cls) -> None:
        """A job returns: after the last of those running, the caller's counts come back."""
        with cls.lock:
            cls.running -= 1
            if cls.running:
                return  # another job still runs: its BLAS stays at one thread
            for lib in _blas_libraries():
                wanted = cls.before.get(lib.filepath, cls.default)
                if lib.num_threads != wanted:
                    lib.set_num_threads(wanted)


@contextmanager
def blas_threads_given_back() -> Iterator[None]:
    """Run the block as a job of :class:`BlasThreads`: BLAS at one thread, given back after."""
    BlasThreads.enter()
    try:
        yield
    finally:
        BlasThreads.leave()


def restoring_blas_threads(job: Callable[_P, _R]) -> Callable[_P, _R]:
    """Run ``job`` as a job of :class:`BlasThreads` (:func:`blas_threads_given_back`)."""

    @functools.wraps(job)
    def run(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with blas_threads_given_back():
            return job(*args, **kwargs)

    return run


def _blas_libraries() -> list[Any]:
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return []
    return list(ThreadpoolController().select(user_api="blas").lib_controllers)


def _default_blas_threads() -> int:
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(name, "").split(",")[0].strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    if hasattr(os, "sched_getaffinity"):
        return max(len(os.sched_getaffinity(0)), 1)
    return max(os.cpu_count() or 1, 1)  # pragma: no cover - not Linux
