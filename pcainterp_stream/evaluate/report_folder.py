"""The report folder of ``pcainterp evaluate``: which folder it may write, and how.

A report is written into a hidden staging folder (``.NAME.partial-PID@HOST-XXXX``: beside a
new target, inside an existing one; a killed run's is removed by the next run) and moved
into place only once complete, as densify writes its outputs: a stopped or failed run leaves
the folder as it was, and a re-run leaves no figure of an earlier one. An existing folder is
written into, never renamed, so it may be a mount point (a container's volume) or the
current folder. A folder that holds files a report does not write (a user's notes, another
tool's output) is refused; hidden files are ignored.
``results.json`` is strict JSON (RFC 8259): non-finite numbers are written as ``null``.
"""

from __future__ import annotations

import errno
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
from pcainterp_stream.interrupt import signals_deferred, track_partial, untrack_partial
from pcainterp_stream.io.output_paths import (
    name_too_long,
    partial_prefix,
    process_umask,
    remove_stale_partials,
    removed_meanwhile,
    write_advice,
)

__all__ = ["REPORT_FILES", "check_report_folder", "report_json", "write_report_folder"]

REPORT_FILES: tuple[str, ...] = ("results.md", "results.json", *FIGURE_NAMES)
"""Every file a report folder may hold."""


def check_report_folder(folder: Path) -> None:
    """Refuse a report folder evaluate must not write (before the log is evaluated).

    Allowed: a path that does not exist yet (its parent folder must), an empty folder, or a
    folder of an earlier report (only :data:`REPORT_FILES`; hidden files such as
    ``.gitkeep`` are ignored and kept). The folder (or, for a new one, its parent) must be
    writable: that is tried here, so a refusal costs no evaluation.

    Raises:
        PcaInterpError: no parent folder, a name too long for the file system, a file, a
            folder holding other files, or a folder evaluate cannot write.
    """
    path = _absolute(folder)
    if not path.parent.is_dir():
        in_the_way = next((parent for parent in folder.parents if parent.exists()), None)
        if in_the_way is not None and not in_the_way.is_dir():
            raise PcaInterpError(
                f"cannot write the report to {folder}: {in_the_way} is a file, not a folder; "
                "move it, or pass -o with another folder"
            )
        raise PcaInterpError(
            f"cannot write the report to {folder}: folder {folder.parent} does not exist"
        )
    too_long = name_too_long(path)  # first: a look at the path would fail (ENAMETOOLONG)
    if too_long is not None:
        raise PcaInterpError(f"cannot write the report to {folder}: {too_long}")
    if path.exists() and not path.is_dir():
        raise PcaInterpError(
            f"cannot write the report to {folder}: it is a file, the report is a folder; "
            "pass a folder path"
        )
    if path.is_dir():
        _check_contents(folder, path)
    _probe_writable(folder, path if path.is_dir() else path.parent)


def _absolute(folder: Path) -> Path:
    """``folder`` made absolute and normalised (``.`` and ``..`` resolved, links kept)."""
    return Path(os.path.abspath(folder))


def _visible(folder: Path) -> list[str]:
    return sorted(entry.name for entry in folder.iterdir() if not entry.name.startswith("."))


def _check_contents(folder: Path, path: Path) -> None:
    others = [name for name in _visible(path) if name not in REPORT_FILES or (path / name).is_dir()]
    if others:
        shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
        raise PcaInterpError(
            f"cannot write the report to {folder}: it holds files a report does not write "
            f"({shown}); pass -o with a new or empty folder, or an earlier report's folder"
        )
    if (path / "results.md").is_file() and not _is_report_json(path / "results.json"):
        raise PcaInterpError(
            f"cannot write the report to {folder}: its results.md is not an evaluate "
            "report's (no results.json of one beside it); pass -o with a new or empty folder"
        )


def _probe_writable(folder: Path, where: Path) -> None:
    """Make and remove a folder in ``where``: what writing the report will do."""
    try:
        Path(tempfile.mkdtemp(prefix=".pcainterp-probe-", dir=where)).rmdir()
    except OSError as err:
        raise _not_writable(folder, where, err) from err


def _not_writable(folder: Path, where: Path, err: OSError) -> PcaInterpError:
    if err.errno == errno.ENAMETOOLONG:
        return PcaInterpError(
            f"cannot write the report to {folder}: {err.strerror}; {write_advice(err)}"
        )
    which = "it is" if where == _absolute(folder) else f"its folder {folder.parent} is"
    return PcaInterpError(
        f"cannot write the report to {folder}: {which} not writable ({err.strerror}); "
        "choose a writable folder"
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


REPORT_TEXT: dict[str, str] = {"encoding": "utf-8", "errors": "backslashreplace"}
r"""How the report's text files are written: UTF-8 whatever the locale (Markdown and JSON are
read as UTF-8); a name's bytes that are not UTF-8 (``caf\xe9``, held as ``\udce9``) escaped,
so that a report of a whole evaluation is never lost to its log's name."""


def report_json(summary: dict[str, Any]) -> str:
    """Return ``results.json``: strict JSON, ``null`` for NaN and infinity (an open bin edge).

    >>> report_json({"edge": float("inf"), "nll": float("nan")}).split()
    ['{', '"edge":', 'null,', '"nll":', 'null', '}']
    """
    return json.dumps(_finite(summary), indent=1, allow_nan=False) + "\n"


def write_report_folder(folder: Path, write: Callable[[Path], None]) -> None:
    """Run ``write`` on a staging folder and move its files into ``folder`` once complete.

    A new ``folder`` is the staging folder renamed. An existing one (checked by
    :func:`check_report_folder`; it may be a mount point or the current folder) is never
    renamed: the report is staged in a hidden folder inside it, the files of an earlier
    report are moved aside into it, and the new files into place (:func:`_swap`): a move
    that fails puts the earlier report back whole, never half of each; no stale figure of
    the earlier report stays beside the new one.

    Raises:
        PcaInterpError: the staging folder cannot be made, or a file cannot be moved.
    """
    path = _absolute(folder)
    existing = path.is_dir()
    where = path if existing else path.parent
    named = folder if existing else folder.parent  # ``where`` as the user named it

    def removed(during: str) -> PcaInterpError | None:
        """The error when the folder (or the staging in it) was removed under the job."""
        reason = removed_meanwhile(staging, named, during)
        text = f"cannot write the report to {folder}: {reason}; nothing was written"
        return None if reason is None else PcaInterpError(text)

    remove_stale_partials(path, label=str(folder), where=where)  # of a killed earlier run
    try:
        staging = Path(tempfile.mkdtemp(prefix=partial_prefix(path, where), dir=where))
    except OSError as err:
        if not where.is_dir():
            raise PcaInterpError(
                f"cannot write the report to {folder}: folder {named} no longer exists "
                "(removed while the log was evaluated); nothing was written"
            ) from err
        raise _not_writable(folder, where, err) from err
    track_partial(staging)  # removed even if a signal forces the end
    swapping = False  # the files of an earlier report are being swapped (put back on failure)
    try:
        try:
            write(staging)
        except OSError as err:  # the report is not finished: a full disk, not the move
            raise removed("the report was being written") or PcaInterpError(
                f"writing the report into {folder} failed: {err.strerror or err}; "
                f"{write_advice(err)}"
            ) from err
        if not existing:
            os.chmod(staging, 0o777 & ~process_umask())  # mkdtemp's 0700 would hide the report
            try:
                os.replace(staging, path)
                return
            except OSError:
                if not path.is_dir():  # else: made meanwhile, move the files into it
                    raise
        check_report_folder(folder)  # nothing was added while the log was evaluated
        swapping = True
        with signals_deferred():  # a Ctrl-C leaves the whole report, never half of it
            _swap(folder, path, staging)
    except OSError as err:
        kept = "; the earlier report in it is as it was" if swapping else ""
        raise removed("the report was being written") or PcaInterpError(
            f"cannot move the finished report into {folder}: {err.strerror}{kept}; "
            "re-run once it is writable"
        ) from err
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        untrack_partial(staging)


def _swap(folder: Path, path: Path, staging: Path) -> None:
    """Move an earlier report's files aside and the staged ones into ``path``: all or none.

    Every move is a rename within ``path`` (the staging folder is inside it). When one
    fails (a file made immutable or owned by another user in a sticky folder), the files
    moved are moved back, so the folder holds the earlier report as it was; the error is
    raised (an OSError), or a :class:`PcaInterpError` when even moving back failed.
    """
    written = sorted(entry.name for entry in staging.iterdir())
    aside = staging / ".earlier"
    aside.mkdir()
    moved_aside: list[str] = []
    moved_in: list[str] = []
    try:
        for name in REPORT_FILES:
            if os.path.lexists(path / name):
                os.replace(path / name, aside / name)
                moved_aside.append(name)
        for name in written:
            os.replace(staging / name, path / name)
            moved_in.append(name)
    except OSError as err:
        try:
            for name in moved_in:
                os.replace(path / name, staging / name)
            for name in moved_aside:
                os.replace(aside / name, path / name)
        except OSError as again:
            raise PcaInterpError(
                f"cannot move the finished report into {folder}: {err.strerror}, and the "
                f"earlier report could not be put back ({again.strerror}): {folder} holds "
                "parts of both; remove its report files and re-run once it is writable"
            ) from err
        raise
