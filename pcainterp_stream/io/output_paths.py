"""Where an output log may be written: never onto one of its inputs, nor around one."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from pcainterp_stream.errors import LogWriteError


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_not_input(target: Path, inputs: Iterable[str | os.PathLike[str]]) -> None:
    """Refuse a target that is, or contains, one of the inputs.

    Raises:
        LogWriteError: naming the path and the fix.
    """
    resolved = target.resolve()
    for item in inputs:
        source = Path(item)
        same = resolved == source.resolve() or _inside(source.resolve(), resolved)
        if not same and target.exists() and source.exists():
            try:
                same = os.path.samefile(target, source)
            except OSError:
                same = False
        if same:
            raise LogWriteError(
                f"refusing to write the output onto the input {source}; "
                "choose a different output path"
            )
