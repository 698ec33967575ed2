"""Interrupting ``pcainterp learn``: nothing at the target, one clear line, a rerun works.

``tests/test_cli.py`` sends SIGINT and SIGTERM to ``synth`` and ``densify`` (each with a
rerun); this file does the same for ``learn``, whose only output is written at the very
end (``Basis.save``: a temporary beside the target, renamed), so the signal lands while it
reads the log and runs SGBM. A second test interrupts the save itself.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream import cli, rosmsg
from pcainterp_stream.basis import Basis
from pcainterp_stream.jobs import synth
from pcainterp_stream.logreader import open_log
from pcainterp_stream.logwriter import open_writer

INTERRUPTED = "pcainterp: interrupted; no partial output was left at the target"
SMALL_FRAMES = 8
REPEATS = 20  # the long log: 160 quarter-size pairs, a few seconds of learning

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/fd").is_dir(), reason="needs /proc to see when the log is open"
)


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "small.mcap"
    synth(path, frames=SMALL_FRAMES, seed=3, scale=0.25, fmt="mcap")
    return path


@pytest.fixture(scope="module")
def long_log(small_log: Path) -> Path:
    """The small log repeated REPEATS times, stamps shifted so every pair is distinct."""
    path = small_log.with_name("long.mcap")
    with open_log(small_log) as reader:
        raws = list(reader.messages())
    span_ns = raws[-1].log_time_ns - raws[0].log_time_ns + 100_000_000
    with open_writer(path, "mcap") as writer:
        for repeat in range(REPEATS):
            for raw in raws:
                writer.add_raw(_shifted(raw, repeat * span_ns))
    return path


def _shifted(raw: Any, shift_ns: int) -> Any:
    """Return a raw message with log time and header stamp moved by ``shift_ns``."""
    message = rosmsg.deserialize(raw.data, raw.msgtype)
    stamp = rosmsg.stamp_ns(message) + shift_ns
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10**9)
    return raw._replace(
        data=rosmsg.serialize(message),
        log_time_ns=raw.log_time_ns + shift_ns,
        publish_time_ns=raw.publish_time_ns + shift_ns,
    )


def _has_open(pid: int, path: Path) -> bool:
    """Return whether process ``pid`` has ``path`` open (Linux ``/proc/PID/fd``)."""
    try:
        return any(
            os.readlink(f"/proc/{pid}/fd/{fd}") == str(path) for fd in os.listdir(f"/proc/{pid}/fd")
        )
    except OSError:  # the process or one of its descriptors went away meanwhile
        return False


def _pcainterp(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pcainterp_stream.cli", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
    )


def _interrupt_while_reading(
    args: list[str | Path], log: Path, sig: signal.Signals
) -> tuple[int, str]:
    """Start ``pcainterp ARGS``, send ``sig`` once it reads ``log``; return (code, stderr)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "pcainterp_stream.cli", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while not _has_open(process.pid, log.resolve()):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the log was never opened"
            time.sleep(0.02)
        time.sleep(0.3)  # into the SGBM pass
        assert process.poll() is None, "finished before the signal; make the log longer"
        process.send_signal(sig)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return process.returncode, err


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_learn(sig: signal.Signals, long_log: Path, tmp_path: Path) -> None:
    target = tmp_path / "basis.npz"
    target.write_bytes(b"an older basis")  # an existing target must be left as it was
    args: list[str | Path] = ["learn", long_log, "-o", target, "--components", "5"]
    code, err = _interrupt_while_reading(args, long_log, sig)
    assert code == 130, err
    assert err.strip() == INTERRUPTED
    assert target.read_bytes() == b"an older basis"
    assert [p.name for p in tmp_path.iterdir()] == [target.name]  # no temporary beside it
    rerun = _pcainterp(*args)
    assert rerun.returncode == 0, rerun.stderr
    assert Basis.load(target).n_train == SMALL_FRAMES * REPEATS
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def test_interrupt_while_learn_saves(
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C during the write of the basis (the only moment a file exists) leaves nothing."""
    target = tmp_path / "basis.npz"

    def interrupted_savez(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", interrupted_savez)
    code = cli.main(["learn", str(small_log), "-o", str(target), "--components", "3"])
    assert code == 130
    assert capsys.readouterr().err.strip() == INTERRUPTED
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    assert cli.main(["learn", str(small_log), "-o", str(target), "--components", "3"]) == 0
    assert Basis.load(target).n_train == SMALL_FRAMES
    assert [p.name for p in tmp_path.iterdir()] == [target.name]
