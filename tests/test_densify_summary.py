"""The closing summary of ``densify``: its rate says something for a slow run too."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcainterp_stream.cli.densify_one import _print_summary
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.pipeline.densify import DensifySummary
from pcainterp_stream.pipeline.processor import ProcessorConfig


def _summary(frames: int, seconds: float) -> DensifySummary:
    return DensifySummary(
        Path("w4k.mcap"), None, frames, seconds, 4904 * frames, PairingStats(), [], None
    )


@pytest.mark.parametrize(
    ("frames", "seconds", "pace"),
    [
        (100, 6.6, "15.2 frames/s"),
        (3, 2.0, "1.5 frames/s"),
        (4, 536.8, "0.0075 frames/s, 134 s per frame"),  # 4K under load (bug hunt 5B)
        (2, 3.0, "0.67 frames/s, 1.5 s per frame"),
        (0, 1.0, "0.0 frames/s"),
    ],
)
def test_the_rate_is_never_printed_as_zero_for_a_slow_run(
    frames: int, seconds: float, pace: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _print_summary(_summary(frames, seconds), ProcessorConfig())
    first = capsys.readouterr().out.splitlines()[0]
    assert f"in {seconds:.1f} s ({pace}), " in first
