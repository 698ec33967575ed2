"""Keep freed heap memory for reuse instead of returning it to the OS (glibc only).

Every rendered view allocates a few hundred array temporaries of 0.1-4 MB. With glibc's
defaults most of them are fresh ``mmap`` regions that are given back on free, so each new
temporary page-faults all its pages in again: at KITTI size that was ~20 000 minor page
faults and ~40 % of the time per view in the kernel. Raising the mmap and trim thresholds
makes glibc serve those temporaries from the heap and keep the heap's top, so memory freed
by one view is reused by the next. The peak resident size is unchanged; freed memory is
only returned to the OS when the process ends.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys
from collections.abc import Callable
from typing import cast

#: mallopt parameters (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
#: Allocations up to this size come from the heap (glibc caps it at 32 MiB on 64-bit).
_MMAP_THRESHOLD = 32 * 1024 * 1024
#: Free memory at the heap top kept before trimming, and extra requested when it grows.
_TRIM_THRESHOLD = 1024 * 1024 * 1024
_TOP_PAD = 64 * 1024 * 1024

_state = {"done": False}


def keep_freed_memory() -> bool:
    """Tune glibc's malloc so large numpy temporaries reuse freed heap memory.

    Process-wide and idempotent; a no-op (returning False) where the C library is not glibc.

    Returns:
        True if the allocator was tuned (now or by an earlier call).
    """
    if _state["done"]:
        return True
    mallopt = _mallopt()
    if mallopt is None:
        return False
    ok = (
        mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD) == 1
        and mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD) == 1
        and mallopt(_M_TOP_PAD, _TOP_PAD) == 1
    )
    _state["done"] = bool(ok)
    return bool(ok)


def limit_arenas(arenas: int) -> bool:
    """Cap glibc's malloc arenas at ``arenas`` (process-wide, for the rest of the process).

    glibc gives a thread that finds the arenas in use a new one, up to 8 per core; with
    :func:`keep_freed_memory` each arena keeps the high-water mark of the temporaries its
    threads made. A pipeline of many threads making full-size images then holds one such
    mark per arena: on a two-core machine ``densify`` peaked at 380 MB with glibc's default
    and 330 MB with two arenas, at the same CPU time (KITTI clip, docs/benchmarks.md).
    Arenas made before the call stay. A no-op (False) where the C library is not glibc.
    """
    mallopt = _mallopt()
    return mallopt is not None and mallopt(_M_ARENA_MAX, max(1, int(arenas))) == 1


def release_free_memory() -> bool:
    """Give the free pages inside the heap back to the OS now (glibc's ``malloc_trim``).

    With :func:`keep_freed_memory` freed memory stays resident for reuse; over thousands of
    frames a heap fragments and the resident size creeps up by the holes it keeps (a KITTI
    densify: 350 -> 378 MB over 3,000 frames). Called now and then (every few hundred
    frames), it keeps the resident size at the pipeline's working set for the price of
    faulting the reused pages in once again. A no-op (False) where the C library is not
    glibc.
    """
    libc = _glibc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


def resident_bytes() -> int | None:
    """Return the process's resident set size in bytes (``/proc/self/statm``), or None.

    One small read (~10 us): cheap enough to check every few frames. None where ``/proc``
    is not there (not Linux).
    """
    try:
        with open("/proc/self/statm", "rb") as statm:
            fields = statm.read().split()
        return int(fields[1]) * _PAGE_SIZE
    except (OSError, IndexError, ValueError):
        return None


_PAGE_SIZE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


RELEASE_EVERY = 250
"""Frames between two returns of the heap's free pages to the OS (with the allocator tuned).

Without it a KITTI densify's resident size crept from 350 to 378 MB over 3,000 frames
(fragmentation: holes kept resident); each release costs faulting the reused pages in
again, a fraction of a millisecond per frame at this interval (docs/speed_levers.md)."""

RELEASE_ABOVE_MB = 350
"""Resident size (MB) above which the free pages are given back at once, between the
periodic releases: a KITTI job's heap holds 150-230 MB of freed, reused memory beside the
120-180 MB in use, and its resident size reached 404 MB once."""

RESIDENT_CHECK_EVERY = 4
"""Frames between two reads of the resident size (``/proc/self/statm``, ~10 us)."""

RELEASE_GROWTH_MB = 32
"""Growth (MB) of the resident size after an early release before the next early one (the
pages in use are not given back, so a job that needs them is not trimmed again and again)."""


class Releases:
    """When a long job gives the heap's free pages back (:func:`release_free_memory`).

    Every :data:`RELEASE_EVERY` frames, and early when the resident size, read every
    :data:`RESIDENT_CHECK_EVERY` frames, is over :data:`RELEASE_ABOVE_MB` (then again only
    after it grew :data:`RELEASE_GROWTH_MB` more).
    """

    def __init__(self) -> None:
        self.floor = RELEASE_ABOVE_MB << 20
        """Resident bytes above which the next check releases."""

    def frame(self, count: int) -> None:
        """Release, or not, after the job's ``count``-th frame."""
        if count % RELEASE_EVERY == 0:
            release_free_memory()  # the heap's holes, kept resident, would creep up
            return
        if count % RESIDENT_CHECK_EVERY:
            return
        resident = resident_bytes()
        if resident is not None and resident > self.floor:
            release_free_memory()
            after = resident_bytes() or resident
            self.floor = max(RELEASE_ABOVE_MB << 20, after + (RELEASE_GROWTH_MB << 20))


def _mallopt() -> Callable[[int, int], int] | None:
    """Return glibc's ``mallopt``, or None where the C library is not glibc."""
    libc = _glibc()
    if libc is None:
        return None
    return cast("Callable[[int, int], int]", libc.mallopt)


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """Return the C library if it is glibc's (it has ``mallopt`` and ``malloc_trim``)."""
    if not sys.platform.startswith("linux"):
        return None
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]  # both or neither
        libc.mallopt.restype = ctypes.c_int
        libc.malloc_trim.argtypes = [ctypes.c_size_t]
        libc.malloc_trim.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return libc
