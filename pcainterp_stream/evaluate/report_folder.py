"""The report folder of ``pcainterp evaluate``: which folder it may write, and how.

A report is written into a staging folder beside the target (``.NAME.partial-XXXX``) and
moved onto it only once complete, as densify writes its outputs: a stopped or failed run
leaves the folder as it was, and a re-run leaves no figure of an earlier one. A folder that
holds files a report does not write (a user's notes, another tool's output) is refused.
``results.json`` is strict JSON (RFC 8259): non-finite numbers are written as ``null``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.evaluate.figures import FIGURE_NAMES
from pcainterp_stream.interrupt import track_partial, untrack_partial

__all__ = ["REPORT_FILES", "check_report_folder", "report_json", "write_report_folder"]

REPORT_FILES: tuple[str, ...] = ("results.md", "results.json", *FIGURE_NAMES)
"""Every file a report folder may hold."""


def check_report_folder(folder: Path) -> None:
    """Refuse a report folder evaluate must not write (before the log is evaluated).

    Allowed: a path that does not exist yet (its parent folder must), an empty folder, or a
    folder of an earlier report (only :data:`REPORT_FILES`).

    Raises:
        PcaInterpError: no parent folder, a file, or a folder holding other files.
    """
    if not folder.parent.is_dir():
        raise PcaInterpError(
            f"cannot write the report to {folder}: folder {folder.parent} does not exist"
        )
    if folder.exists() and not folder.is_dir():
        raise PcaInterpError(
            f"cannot write the report to {folder}: it is a file, the report is a folder; "
            "pass a folder path"
        )
    if not folder.is_dir():
        return
    others = sorted(entry.name for entry in folder.iterdir() if entry.name not in REPORT_FILES)
    if others:
        shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
        raise PcaInterpError(
            f"cannot write the report to {folder}: it holds files a report does not write "
            f"({shown}); pass -o with a new or empty folder, or an earlier report's folder"
        )
    if (folder / "results.md").is_file() and not _is_report_json(folder / "results.json"):
        raise PcaInterpError(
            f"cannot write the report to {folder}: its results.md is not an evaluate "
            "report's (no results.json of one beside it); pass -o with a new or empty folder"
        )


def _is_report_json(path: Path) -> bool:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"log", "mode", "methods"} <= data.keys()


def _finite(value: Any) -> Any:
    """Return ``value`` with every non-finite float replaced by None (JSON ``null``)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def report_json(summary: dict[str, Any]) -> str:
    """Return ``results.json``: strict JSON, ``null`` for NaN and infinity (an open bin edge).

    >>> report_json({"edge": float("inf"), "nll": float("nan")}).split()
    ['{', '"edge":', 'null,', '"nll":', 'null', '}']
    """
    return json.dumps(_finite(summary), indent=1, allow_nan=False) + "\n"


def write_report_folder(folder: Path, write: Callable[[Path], None]) -> None:
    """Run ``write`` on a staging folder and move it onto ``folder`` once it is complete.

    An existing ``folder`` (checked by :func:`check_report_folder`) is replaced as a whole,
    so no file of an earlier report stays beside the new one.

    Raises:
        PcaInterpError: the staging folder cannot be made or moved (permissions).
    """
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.partial-", dir=folder.parent))
    except OSError as err:
        raise PcaInterpError(
            f"cannot write the report to {folder}: {err.strerror}; choose a writable folder"
        ) from err
    track_partial(staging)  # removed even if a signal forces the end
    try:
        write(staging)
        os.chmod(staging, 0o777 & ~_umask())  # mkdtemp's 0700 would hide the report
        if folder.is_dir():
            check_report_folder(folder)  # nothing was added while the log was evaluated
            old = staging.with_name(staging.name + ".replaced")
            os.replace(folder, old)
            try:
                os.replace(staging, folder)
            except OSError:
                os.replace(old, folder)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(staging, folder)
    except OSError as err:
        raise PcaInterpError(
            f"cannot move the finished report onto {folder}: {err.strerror}; check the "
            "folder's permissions"
        ) from err
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        untrack_partial(staging)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
