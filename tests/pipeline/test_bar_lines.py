"""Lines printed while densify's progress bar is drawn (bug hunt 16C F5)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.pipeline import densify as densify_module
from pcainterp_stream.pipeline.jobs import synth


class _Bar:
    """A terminal's bar as densify drives it: what was drawn, cleared and printed, in order."""

    def __init__(self, events: list[str], description: str) -> None:
        self.events, self.description = events, description

    def __enter__(self) -> _Bar:
        self.events.append("drawn")
        return self

    def __exit__(self, *exc: object) -> None:
        self.events.append("closed")

    def update(self, n: int = 1) -> None:
        pass

    def clear(self) -> None:
        self.events.append("cleared")

    def refresh(self) -> None:
        self.events.append("drawn")


def test_a_line_said_at_the_first_pair_goes_above_the_bar(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`densify mid.mcap:   0%|   | 0/60 [00:00<?, ?frame/s]rectify auto: ...`: the
    pairer's line was printed after the bar's text without clearing it."""
    log = tmp_path / "a.mcap"
    synth(log, frames=2, seed=3, scale=0.25, fmt="mcap")
    events: list[str] = []

    def bar(total: int | None, description: str, unit: str = "frame") -> Any:
        return _Bar(events, description)

    monkeypatch.setattr(densify_module, "_bar", bar)
    densify_module.densify(log, tmp_path / "o.mcap", echo=lambda line: events.append(line))
    said = [i for i, event in enumerate(events) if event.startswith("rectify auto:")]
    assert said, events
    start = events.index("drawn")
    for i in said:
        if i > start:  # while the bar is shown: cleared first, drawn again after
            assert events[i - 1] == "cleared"
            assert events[i + 1] == "drawn"


@pytest.mark.parametrize(
    ("columns", "shown"),
    [(120, "densify a_long_log_name.mcap"), (60, "densify"), (20, "")],
)
def test_a_narrow_terminal_keeps_the_count_not_the_name(
    monkeypatch: pytest.MonkeyPatch, columns: int, shown: str
) -> None:
    """At 20 columns the bar was `densify mid.mcap:  `: the name took the whole width."""
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=1: os.terminal_size((columns, 24)))
    name = "densify a_long_log_name.mcap"
    assert densify_module._bar_description(name) == shown
