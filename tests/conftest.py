"""Hypothesis settings profiles for the whole suite.

- ``ci``: derandomized, so a submission never fails on a draw it did not cause; loaded when
  the ``CI`` environment variable is set (``.ci/run`` sets it).
- ``thorough``: ten times the examples of every property test, random seeds; what a
  developer runs before stopping::

      HYPOTHESIS_PROFILE=thorough python -m pytest -q --hypothesis-seed=$RANDOM

- ``default``: hypothesis' defaults with the per-test example counts.

``HYPOTHESIS_PROFILE`` names a profile explicitly and wins over ``CI``.

Also the ``full_disk`` fixture: files written through ``Path.open`` on a disk that fills up.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings
from hypothesis_profiles import PROFILE_VARIABLE, THOROUGH

from pcainterp_stream.interrupt import STALL_DUMP_VARIABLE

# No deadline and no too-slow health check: a property must hold for every example, and a
# loaded machine (two cores running the whole suite) must not turn its speed into a failure.
_UNTIMED = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow], "print_blob": True}
settings.register_profile("ci", derandomize=True, **_UNTIMED)
settings.register_profile(THOROUGH, **_UNTIMED)
settings.register_profile("local", **_UNTIMED)

_profile = os.environ.get(PROFILE_VARIABLE) or ("ci" if os.environ.get("CI") else "local")
settings.load_profile(_profile)


# ------------------------------------------------------------------ stalled commands
# Every command a test starts writes the stack of its threads into one folder when the
# watchdog has to kill it after a signal (see pcainterp_stream.interrupt); the run's summary
# shows any such dump, so a hang seen once in a whole-suite run leaves its evidence.


_made_here: list[Path] = []  # the folder this process made, removed at the end when empty


def pytest_configure(config: pytest.Config) -> None:
    if not os.environ.get(STALL_DUMP_VARIABLE):
        os.environ[STALL_DUMP_VARIABLE] = tempfile.mkdtemp(prefix="pcainterp-stalls-")
        _made_here.append(Path(os.environ[STALL_DUMP_VARIABLE]))


def pytest_unconfigure(config: pytest.Config) -> None:
    for folder in _made_here:  # a dump in it is evidence: the folder stays
        with contextlib.suppress(OSError):
            folder.rmdir()


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    folder = Path(os.environ.get(STALL_DUMP_VARIABLE, ""))
    dumps = sorted(folder.glob("stall-*.txt")) if folder.name else []
    stalled = [(path, path.read_text(errors="replace")) for path in dumps]
    stalled = [(path, text) for path, text in stalled if "hread" in text]
    if not stalled:
        return
    terminalreporter.section("commands the watchdog had to kill after a signal")
    for path, text in stalled:
        terminalreporter.write_line(f"{path}:")
        terminalreporter.write_line(text)


class _FileOnFullDisk:
    """A file opened for writing on a disk with ``room`` bytes left (shared by its files)."""

    def __init__(self, file: Any, room: list[int]) -> None:
        self._file = file
        self._room = room

    def write(self, data: Any) -> int:
        size = len(data) if isinstance(data, str) else memoryview(data).nbytes
        if size > self._room[0]:
            raise OSError(errno.ENOSPC, "No space left on device")
        self._room[0] -= size
        written: int = self._file.write(data)
        return written

    def __getattr__(self, name: str) -> Any:
        return getattr(self._file, name)

    def __enter__(self) -> _FileOnFullDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        self._file.close()


@pytest.fixture
def full_disk(monkeypatch: pytest.MonkeyPatch) -> Callable[[int], None]:
    """Return ``fill(room)``: from then on, files opened with ``Path.open`` for writing share
    ``room`` bytes, and a write past them raises ``OSError(ENOSPC)`` as a full disk does."""

    def fill(room: int) -> None:
        left = [room]
        original = Path.open

        def open_on_full_disk(path: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
            file = original(path, mode, *args, **kwargs)
            return _FileOnFullDisk(file, left) if set(mode) & set("wxa") else file

        monkeypatch.setattr(Path, "open", open_on_full_disk)

    return fill


@pytest.fixture
def umask_027_unchanged(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The umask 027, and any ``os.umask`` call while the test runs an error.

    For code that must read the umask without setting it, which would give other threads'
    files the moment's mask (review 55b R55b-5). Skips where there is no /proc to read it from.
    """
    if not Path("/proc/self/status").exists():
        pytest.skip("no /proc: the umask is read by setting it while single-threaded")
    real = os.umask
    previous = real(0o027)

    def changed(mask: int) -> int:
        raise AssertionError(f"os.umask({mask:#o}) while threads may be making files")

    monkeypatch.setattr(os, "umask", changed)
    try:
        yield
    finally:
        real(previous)
