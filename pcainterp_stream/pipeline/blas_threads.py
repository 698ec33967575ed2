"""The caller's BLAS thread counts, given back when the last job of the process returns.

A job holds every BLAS at one thread (:class:`~.threads.ThreadLimits`: its bytes do not
depend on the machine's core count), and the solver holds scipy's OpenBLAS, loaded inside
the first job, at one thread for the process (``estimate/compiled.py``). The ``densify``
and ``evaluate`` jobs and every command :func:`pcainterp_stream.cli.main` runs in-process
(``learn`` too) run within :class:`BlasThreads`: a caller's own ``scipy.linalg`` work
afterwards is not left single-threaded (bug hunt 10A F1, review 58a R7).
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
    """The BLAS thread counts a caller had when the first job of the process began.

    When the last job running in the process returns, each BLAS the caller had gets its
    count back and one loaded during the jobs the count the caller's environment gives a
    new one (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``, else the CPUs this process may
    run on). Jobs nest and may run concurrently: a process-wide count of those running
    (like ``ThreadLimits``), so one ending does not disturb another.
    """

    lock: ClassVar[threading.Lock] = threading.Lock()
    running: ClassVar[int] = 0
    before: ClassVar[dict[str, int]] = {}
    default: ClassVar[int] = 1

    @classmethod
    def enter(cls) -> None:
        """A job begins: the first of those running notes the caller's counts."""
        with cls.lock:
            if cls.running == 0:
                cls.before = {lib.filepath: lib.num_threads for lib in _blas_libraries()}
                cls.default = _default_blas_threads()
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
    """Run the block within :class:`BlasThreads`: the caller's BLAS counts come back after."""
    BlasThreads.enter()
    try:
        yield
    finally:
        BlasThreads.leave()


def restoring_blas_threads(job: Callable[_P, _R]) -> Callable[_P, _R]:
    """Run ``job`` within :class:`BlasThreads` (:func:`blas_threads_given_back`)."""

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
