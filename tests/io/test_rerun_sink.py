"""The Rerun sink's failures: never a traceback, never the job's other outputs lost."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io import rerun_sink
from pcainterp_stream.io.rerun_sink import RerunSink


class _StuckRecording:
    """A recording whose last bytes never arrive: flush times out, as on a full disk."""

    def __init__(self) -> None:
        self.disconnected = False

    def flush(self, *, timeout_sec: float) -> None:
        raise RuntimeError("Flush timed out - not all log messages were sent")

    def disconnect(self) -> None:
        self.disconnected = True


def test_a_viewer_without_a_display_is_refused_before_any_work(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert not rerun_sink.has_display()
    with pytest.raises(LogWriteError, match=r"needs a display.*--rrd"):
        RerunSink(spawn=True).__enter__()
    monkeypatch.setenv("DISPLAY", ":0")
    assert rerun_sink.has_display()


def test_a_recording_that_cannot_finish_is_a_warning_and_leaves_no_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "run.rrd"
    sink = RerunSink(rrd_path=target)
    sink.__enter__()
    assert sink._partial is not None
    assert sink._partial.exists()
    stuck = _StuckRecording()
    sink._recording = stuck  # type: ignore[assignment]
    sink.__exit__(None, None, None)  # no exception: the MCAP beside it is committed
    assert stuck.disconnected
    assert not target.exists()
    assert not sink._partial.exists()
    err = capsys.readouterr().err
    assert f"warning: the recording {target} did not take the last frames" in err
    assert "Flush timed out" in err
    assert "nothing was written there" in err


def test_a_viewer_that_went_away_is_a_warning(capsys: pytest.CaptureFixture[str]) -> None:
    sink = RerunSink(spawn=True)
    sink._recording = _StuckRecording()  # type: ignore[assignment]
    sink.__exit__(None, None, None)
    assert "warning: the Rerun viewer did not take the last frames" in capsys.readouterr().err
