"""Golden files: save a log's summary with its tolerances, check a log against one.

A golden file is JSON (format :data:`FORMAT`); with ``arrays=True`` a compressed ``.npz``
of the same name sits beside it and holds every array for an element-wise check. Both are
written to temporary files first and renamed into place, so a failure never leaves half a
golden file.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import GoldenError
from pcainterp_stream.golden.comparison import DEFAULT_TOLERANCE, Difference, compare
from pcainterp_stream.golden.summary import LogSummary, Progress, summarize_log
from pcainterp_stream.interrupt import raise_if_signalled
from pcainterp_stream.version import __version__

__all__ = [
    "FORMAT",
    "CheckResult",
    "arrays_path",
    "check_log",
    "compare_documents",
    "load_golden",
    "save_golden",
]

FORMAT_NAME = "pcainterp-golden"
FORMAT_VERSION = 2
FORMAT = f"{FORMAT_NAME}/{FORMAT_VERSION}"
"""The format string this version writes and reads."""


@dataclass
class CheckResult:
    """What :func:`check_log` found.

    Attributes:
        golden: the golden file checked against.
        differences: every difference beyond tolerance (empty: the log matches).
        updated: True when the golden file was rewritten (``update=True``).
        notes: one-line notes on parts of the log that did not decode.
    """

    golden: Path
    differences: list[Difference]
    updated: bool = False
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """Return True when the log matches its golden file within tolerance."""
        return not self.differences


def arrays_path(golden: str | Path) -> Path:
    """Return the ``.npz`` beside a golden JSON (``a.golden.json`` -> ``a.golden.npz``)."""
    golden = Path(golden)
    return golden.with_suffix(".npz")


@contextmanager
def _replacing(target: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    Raises:
        GoldenError: the file cannot be written (a full disk, a read-only folder, a file
            where a folder should be); nothing is left at or beside ``target``.
    """
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        handle, name = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    except OSError as err:
        raise _write_error(target, err) from err
    os.close(handle)
    temporary = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    temporary.chmod(0o666 & ~umask)  # mkstemp makes it private; a golden file is shared
    try:
        yield temporary
        raise_if_signalled()  # never committed after a signal
        temporary.replace(target)
    except OSError as err:
        raise _write_error(target, err) from err
    finally:
        temporary.unlink(missing_ok=True)


def _write_error(target: Path, err: OSError) -> GoldenError:
    return GoldenError(
        f"cannot write {target}: {err.strerror or err}; free some space, or write it elsewhere"
    )


def _document(
    log: Path,
    summary: LogSummary,
    *,
    topics: list[str] | None,
    tolerance: Mapping[str, Any],
    arrays_file: str | None,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "created_by": f"pcainterp-stream {__version__}",
        "log": log.name,
        "topics": topics,
        "arrays_file": arrays_file,
        "tolerance": dict(tolerance),
        "channels": summary.channels,
    }


def _write(golden: Path, document: dict[str, Any], arrays: Mapping[str, npt.NDArray[Any]]) -> None:
    array_file = arrays_path(golden)
    with _replacing(golden) as json_tmp:
        json_tmp.write_text(json.dumps(document, indent=1, allow_nan=True) + "\n")
        if document["arrays_file"]:
            with _replacing(array_file) as npz_tmp:
                with npz_tmp.open("wb") as stream:
                    np.savez_compressed(stream, **arrays)  # type: ignore[arg-type]
        elif array_file.exists() and _owned_arrays(array_file):
            array_file.unlink()


def _owned_arrays(path: Path) -> bool:
    """Return True for an .npz this package wrote (keys a0, a1, ...), safe to remove."""
    try:
        with np.load(path) as data:
            return all(key[:1] == "a" and key[1:].isdigit() for key in data.files)
    except (OSError, ValueError):
        return False


def save_golden(
    log: str | Path,
    golden: str | Path,
    *,
    topics: Iterable[str] | None = None,
    arrays: bool = False,
    tolerance: Mapping[str, Any] | None = None,
    progress: Progress | None = None,
) -> LogSummary:
    """Summarise a log and write it as a golden file.

    Args:
        log: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        golden: the JSON file to write (its folder is created).
        topics: record only these channels (all when None).
        arrays: also store every array in a compressed ``.npz`` beside the JSON, for an
            element-wise check (see :func:`arrays_path`).
        tolerance: the tolerances to write (default :data:`~.comparison.DEFAULT_TOLERANCE`);
            the keys given replace the defaults'.
        progress: called after each message with (messages done, total or None).

    Returns:
        The summary written.

    Raises:
        LogReadError: the log is missing, not a log or damaged.
        TopicNotFoundError: a topic in ``topics`` is not in the log.

    Examples:
        >>> from pcainterp_stream.golden import save_golden, check_log
        >>> save_golden("drive_dense.mcap", "drive.golden.json")  # doctest: +SKIP
        >>> check_log("drive_dense.mcap", "drive.golden.json").passed  # doctest: +SKIP
        True
    """
    log, golden = Path(log), Path(golden)
    selected = None if topics is None else list(topics)
    summary = summarize_log(log, topics=selected, keep_arrays=arrays, progress=progress)
    merged = dict(DEFAULT_TOLERANCE)
    merged.update(tolerance or {})
    arrays_file = arrays_path(golden).name if arrays else None
    document = _document(log, summary, topics=selected, tolerance=merged, arrays_file=arrays_file)
    _write(golden, document, summary.arrays)
    return summary


def load_golden(golden: str | Path) -> dict[str, Any]:
    """Read a golden file and check its format.

    Raises:
        GoldenError: the file is missing, not JSON, not a golden file, of a newer format
            version than this package reads, or of an older one.
    """
    golden = Path(golden)
    try:
        document = json.loads(golden.read_text())
    except FileNotFoundError as err:
        raise GoldenError(
            f"golden file {golden} does not exist; write it with `pcainterp golden save`"
        ) from err
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise GoldenError(f"golden file {golden} is not readable JSON ({err})") from err
    fmt = document.get("format") if isinstance(document, dict) else None
    name, _, version = str(fmt).partition("/")
    if name != FORMAT_NAME or not version.isdigit():
        raise GoldenError(f"{golden} is not a golden file (format {fmt!r}, expected {FORMAT!r})")
    if int(version) > FORMAT_VERSION:
        raise GoldenError(
            f"{golden} has format {fmt}, newer than this pcainterp-stream {__version__} "
            f"reads ({FORMAT}); upgrade pcainterp-stream"
        )
    if int(version) < FORMAT_VERSION:
        raise GoldenError(
            f"{golden} has the old format {fmt}; write it again with "
            f"`pcainterp golden save LOG -o {golden.name}` (this version reads {FORMAT})"
        )
    if not isinstance(document.get("channels"), dict):
        raise GoldenError(f"{golden} has no channels; write it again with `pcainterp golden save`")
    return dict(document)


@contextmanager
def _open_arrays(
    golden: Path, document: Mapping[str, Any]
) -> Iterator[Mapping[str, npt.NDArray[Any]] | None]:
    """Yield a golden file's stored arrays, read one by one on access (None without any)."""
    if not document.get("arrays_file"):
        yield None
        return
    path = golden.parent / str(document["arrays_file"])
    try:
        data = np.load(path)
    except FileNotFoundError as err:
        raise GoldenError(
            f"{golden.name} stores its arrays in {path.name}, which is missing; copy it "
            "beside the golden file or save again"
        ) from err
    except (OSError, ValueError) as err:
        raise GoldenError(f"arrays file {path} does not load ({err})") from err
    with data:
        yield data


def compare_documents(
    golden: Mapping[str, Any], golden_path: Path, actual: Mapping[str, Any], actual_path: Path
) -> list[Difference]:
    """Compare two golden documents (as :func:`load_golden` returns them), arrays included.

    The element-wise check runs when both store their arrays.

    Raises:
        GoldenError: a stored arrays file is missing or does not load.
    """
    with _open_arrays(golden_path, golden) as expected, _open_arrays(actual_path, actual) as got:
        both = expected is not None and got is not None
        return compare(
            golden,
            actual,
            golden_arrays=expected if both else None,
            actual_arrays=got if both else None,
        )


def check_log(
    log: str | Path,
    golden: str | Path,
    *,
    topics: Iterable[str] | None = None,
    update: bool = False,
    progress: Progress | None = None,
) -> CheckResult:
    """Check a log against a golden file, within the tolerances the file states.

    Args:
        log: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        golden: a file :func:`save_golden` wrote.
        topics: check only these channels (default: those the golden file records).
        update: rewrite the golden file from this log when they differ (same channel
            selection, tolerances and arrays option); the differences are still returned.
        progress: called after each message with (messages done, total or None).

    Returns:
        The differences (none when the log matches) and whether the file was rewritten.

    Raises:
        GoldenError: the golden file is missing, malformed or of another format version,
            or a topic in ``topics`` is not in it.
        LogReadError: the log is missing, not a log or damaged.
        TopicNotFoundError: a topic in ``topics`` is not in the log.
    """
    log, golden = Path(log), Path(golden)
    document = load_golden(golden)
    recorded = document.get("topics")
    selected = list(topics) if topics is not None else recorded
    if topics is not None:
        unknown = [t for t in selected or [] if t not in document["channels"]]
        if unknown:
            listed = ", ".join(document["channels"]) or "none"
            raise GoldenError(
                f"topic {unknown[0]} is not in the golden file {golden.name}; channels "
                f"recorded: {listed}"
            )
    with_arrays = bool(document.get("arrays_file"))
    with _open_arrays(golden, document) as golden_arrays:
        summary = summarize_log(
            log,
            topics=selected,
            keep_arrays=with_arrays,
            skip_missing=topics is None,
            progress=progress,
        )
        expected = document
        if topics is not None:
            channels = {t: document["channels"][t] for t in selected or []}
            expected = dict(document, channels=channels)
        differences = compare(
            expected,
            {"channels": summary.channels},
            golden_arrays=golden_arrays,
            actual_arrays=summary.arrays if with_arrays else None,
            std_channels=document["channels"],
        )
    result = CheckResult(golden=golden, differences=differences, notes=summary.notes)
    if update and differences:
        save_golden(
            log,
            golden,
            topics=recorded,
            arrays=with_arrays,
            tolerance=document.get("tolerance"),
        )
        result.updated = True
    return result
