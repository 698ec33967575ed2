"""The end of a densify run that streams to a Rerun viewer which does not answer (review 59b).

F2: the wait for the viewer comes after the MCAP and the ``.rrd`` are committed and says so
after half a second; a Ctrl-C in it keeps both. F3: the summary's seconds leave it out.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fake_port import loopback_port

from pcainterp_stream import cli
from pcainterp_stream.io import rerun_sink
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.rerun_sink import RerunSink
from pcainterp_stream.pipeline import densify as densify_module
from pcainterp_stream.pipeline.jobs import synth

FRAMES = 4


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "small.mcap"
    synth(path, frames=FRAMES, seed=3, scale=0.25, fmt="mcap")
    return path


@pytest.fixture
def silent_viewer(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """A loopback port that accepts and never answers (a suspended viewer), densify's viewer."""
    monkeypatch.setattr(rerun_sink, "spawn_viewer", lambda port: None)
    monkeypatch.setattr(rerun_sink, "has_display", lambda: True)
    monkeypatch.setattr(rerun_sink, "VIEWER_FLUSH_S", 1.0)

    def sink(**options: Any) -> RerunSink:
        return RerunSink(viewer_port=port, **options)

    with loopback_port("hold") as port:
        monkeypatch.setattr(densify_module, "RerunSink", sink)
        yield port


def _densify(log: Path, out: Path, rrd: Path) -> int:
    return cli.main(["densify", str(log), "-o", str(out), "--rerun", "--rrd", str(rrd)])


def _messages(path: Path) -> int:
    with open_log(path) as reader:
        return sum(1 for _ in reader.messages())


@pytest.mark.usefixtures("silent_viewer")
def test_ctrl_c_while_waiting_for_the_viewer_keeps_the_mcap_and_the_rrd(
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # was: "interrupted; nothing was written": the .rrd, complete, and the MCAP discarded
    out, rrd = tmp_path / "o.mcap", tmp_path / "o.rrd"
    seen: list[tuple[bool, bool]] = []
    real_wait = rerun_sink._Closer.wait

    def wait(self: Any, *args: Any) -> str | None:
        if self.flush_s != rerun_sink.VIEWER_FLUSH_S:  # the file's close
            return real_wait(self, *args)
        seen.append((out.is_file(), rrd.is_file()))
        raise KeyboardInterrupt  # Ctrl-C in the wait for the viewer

    monkeypatch.setattr(rerun_sink._Closer, "wait", wait)
    assert _densify(small_log, out, rrd) == 130
    assert seen == [(True, True)]  # both in place before the wait
    err = capsys.readouterr().err
    assert f"interrupted; {out}, {rrd} were finished before the signal and kept" in err
    assert _messages(out) > 0
    assert rrd.stat().st_size > 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial left


@pytest.mark.usefixtures("silent_viewer")
def test_the_wait_for_the_viewer_is_said_and_not_counted_as_processing(
    small_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # was: 10 s of silence, and "4 frames in 12.2 s (0.33 frames/s)" for 0.4 s of work
    out, rrd = tmp_path / "o.mcap", tmp_path / "o.rrd"
    started = time.monotonic()
    assert _densify(small_log, out, rrd) == 0
    elapsed = time.monotonic() - started
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    waiting = (
        "rerun: waiting up to 1 s for the viewer to take the last frames; the outputs are "
        "written, Ctrl-C stops the wait and keeps them"
    )
    assert waiting in lines
    summary = next(line for line in lines if line.startswith("densified "))
    assert lines.index(waiting) < lines.index(summary)
    seconds = float(summary.split(" in ")[1].split(" s ")[0])
    # the viewer is waited for until its deadline (1 s and a second more)
    assert seconds < elapsed - 1.5, (seconds, elapsed)
    assert "warning: the Rerun viewer did not take the last frames" in captured.err
    assert _messages(out) > 0
