"""How the fit check's lines word two errors: shared by ``estimate`` and ``pipeline``."""

from __future__ import annotations


def figures(first: float, second: float) -> tuple[str, str]:
    """Format two errors (px) with 2 decimals, or 4 when 2 would print them alike.

    "better (0.30 px against 0.30)" would tell the reader nothing.
    """
    digits = 2 if f"{first:.2f}" != f"{second:.2f}" else 4
    return f"{first:.{digits}f}", f"{second:.{digits}f}"
