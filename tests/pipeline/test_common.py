"""The jobs' shared helpers: progress off a terminal (a CI log must not stay silent)."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from pcainterp_stream.pipeline import common, jobs


class _Clock:
    """A monotonic clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_off_a_terminal_a_plain_line_comes_every_interval() -> None:
    clock, out = _Clock(), io.StringIO()
    bar = common._PlainProgress(72000, "densify drive.mcap", every_s=60, clock=clock, stream=out)
    for _ in range(1199):  # the first minute: nothing
        clock.now += 0.049
        bar.update(1)
    assert out.getvalue() == ""
    clock.now = 1000.0 + 60.0
    bar.update(1)
    assert out.getvalue() == "densify drive.mcap: 1200/72000 frames, 20.0 frames/s, ETA 59 min\n"
    clock.now += 59.0  # not yet a minute since that line
    bar.update(1)
    assert out.getvalue().count("\n") == 1
    clock.now += 1.0
    bar.update(1)
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    assert lines[1].startswith("densify drive.mcap: 1202/72000 frames, 10.0 frames/s, ETA 2.0 h")
    assert "\r" not in out.getvalue()


def test_an_unknown_total_gives_no_eta() -> None:
    clock, out = _Clock(), io.StringIO()
    bar = common._PlainProgress(None, "import drive", every_s=30, clock=clock, stream=out)
    clock.now += 45
    bar.update(90)
    assert out.getvalue() == "import drive: 90 frames, 2.0 frames/s\n"


@pytest.mark.parametrize(
    ("seconds", "said"),
    [(40, "40 s"), (89, "89 s"), (90, "2 min"), (3540, "59 min"), (7200, "2.0 h")],
)
def test_durations(seconds: float, said: str) -> None:
    assert common._duration(seconds) == said


def test_the_bar_is_tqdm_on_a_terminal_and_plain_lines_off_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(common.sys, "stderr", _Stream(tty=False))
    assert isinstance(common._bar(10, "densify x.mcap"), common._PlainProgress)
    monkeypatch.setattr(common.sys, "stderr", _Stream(tty=True))
    with common._bar(10, "densify x.mcap") as bar:
        assert type(bar).__name__ == "tqdm"


def test_a_densify_run_off_a_terminal_prints_progress_lines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "s.mcap"
    jobs.synth(log, frames=3, seed=3, scale=0.25, fmt="mcap")
    capsys.readouterr()
    monkeypatch.setattr(common, "PLAIN_PROGRESS_EVERY_S", 0.0)  # a line per frame
    jobs.densify(log, tmp_path / "d.mcap", None)
    err = capsys.readouterr().err.splitlines()
    progress = [line for line in err if line.startswith("densify s.mcap: ")]
    assert [line.split(",")[0] for line in progress] == [
        f"densify s.mcap: {n}/3 frames" for n in (1, 2, 3)
    ]


def test_a_short_run_prints_no_progress_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "s.mcap"
    jobs.synth(log, frames=3, seed=3, scale=0.25, fmt="mcap")
    capsys.readouterr()
    jobs.densify(log, tmp_path / "d.mcap", None)
    assert "frames/s" not in capsys.readouterr().err
