"""How the adaptation's summary lines word figures and counts."""

from __future__ import annotations


def figures(first: float, second: float) -> tuple[str, str]:
    """Format two errors (px) with 2 decimals, or 4 when 2 would print them alike.

    "better (0.30 px against 0.30)" would tell the reader nothing.
    """
    digits = 2 if f"{first:.2f}" != f"{second:.2f}" else 4
    return f"{first:.{digits}f}", f"{second:.{digits}f}"


def count(number: int, noun: str) -> str:
    """Return "1 frame", "2 frames"."""
    return f"{number} {noun}{'' if number == 1 else 's'}"
