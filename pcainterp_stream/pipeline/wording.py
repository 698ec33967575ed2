"""How the adaptation's summary lines word figures and counts."""

from __future__ import annotations

from pcainterp_stream.estimate.wording import figures as figures

__all__ = ["count", "figures"]


def count(number: int, noun: str) -> str:
    """Return "1 frame", "2 frames"."""
    return f"{number} {noun}{'' if number == 1 else 's'}"
