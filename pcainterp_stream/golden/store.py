"""Golden files: save a log's summary with its tolerances, check a log against one.

A golden file is JSON (format :data:`FORMAT`); with ``arrays=True`` a compressed
``.golden.npz`` of the same stem sits beside it (:func:`arrays_path`) and holds every array
for an element-wise check, with a marker key (:data:`ARRAYS_MARKER`) that says it is one.
Both are written to temporary files first and renamed into place, so a failure never leaves
half a golden file; a file in the way that this package did not write (a basis, the log
itself) is never overwritten.
"""

from __future__ import annotations

import difflib
import json
import math
import numbers
import os
import zipfile
import zlib
from collections.abc import Collection, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import GoldenError, GoldenToleranceError
from pcainterp_stream.golden.comparison import DEFAULT_TOLERANCE, Difference, compare
from pcainterp_stream.golden.replacing import replacing_together, staged_at, write_error
from pcainterp_stream.golden.shape import damaged_golden, malformed
from pcainterp_stream.golden.summary import LogSummary, Progress, summarize_log
from pcainterp_stream.version import __version__

__all__ = [
    "ARRAYS_MARKER",
    "FORMAT",
    "CheckResult",
    "arrays_path",
    "check_log",
    "checked_tolerance",
    "compare_documents",
    "describe_golden_file",
    "is_golden_arrays",
    "load_golden",
    "save_golden",
]

FORMAT_NAME = "pcainterp-golden"
FORMAT_VERSION = 3
FORMAT = f"{FORMAT_NAME}/{FORMAT_VERSION}"
"""The format string this version writes (it reads :data:`OLDEST_FORMAT_VERSION` too)."""
OLDEST_FORMAT_VERSION = 2
"""The oldest format this version checks: format 2 recorded an Image of an encoding outside
:data:`~pcainterp_stream.io.rosmsg.IMAGE_ENCODINGS` and a payload that did not decode by its
size only, a point field of ``count`` > 1 by its first element, a cloud with one field of
an unknown datatype by its size, and a sequence of more than 64 messages by its length. A
format-2 file is checked as it was written (:func:`~.decode.message_content` ``legacy``),
with a note on what it leaves out; ``--update`` (or a save) rewrites it in format 3."""

ARRAYS_MARKER = "__pcainterp_golden_arrays__"
"""The key of a golden arrays file that marks it as one: a JSON string naming the format
(``pcainterp-golden-arrays/1``) and the golden JSON it belongs to."""
ARRAYS_FORMAT = "pcainterp-golden-arrays/1"

_NPZ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)
"""What ``np.load`` of a damaged or cut-off ``.npz`` raises (a zip without its directory
raises :class:`zipfile.BadZipFile`, a damaged member :class:`zlib.error`)."""


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
    """Return the arrays file beside a golden JSON, always ending in ``.golden.npz``.

    ``a.golden.json`` -> ``a.golden.npz``, ``kitti.json`` -> ``kitti.golden.npz`` (not
    ``kitti.npz``, the natural name of a basis learned from the same drive). Golden files
    written before this naming keep the name they record (``"arrays_file"``).
    """
    golden = Path(golden)
    stem = golden.name.removesuffix(".json").removesuffix(".golden")
    return golden.with_name(f"{stem}.golden.npz")


def is_golden_arrays(path: str | Path) -> bool:
    """Return True for an ``.npz`` this package wrote as a golden file's arrays.

    Recognised by content: the key :data:`ARRAYS_MARKER`, or (files written before the
    marker) only keys ``a0``, ``a1``, ... A basis, a log or any other file is not one.
    """
    try:
        with Path(path).open("rb") as stream:
            if stream.read(4) != b"PK\x03\x04":  # an .npz is a zip; a .npy, a log are not
                return False
            stream.seek(0)
            with np.load(stream) as data:  # our stream: closed also when np.load fails
                keys = list(data.files)
    except _NPZ_ERRORS:  # not readable, cut off, or a zip that is not an npz
        return False
    if ARRAYS_MARKER in keys:
        return True
    return bool(keys) and all(key[:1] == "a" and key[1:].isdigit() for key in keys)


def _same_path(first: Path, second: Path) -> bool:
    """Whether two paths lead to one place (``Path.resolve()`` raises on a link loop)."""
    return os.path.realpath(first) == os.path.realpath(second)


def _is_golden_json(path: Path) -> bool:
    """Return True for a golden JSON of any format version (a file this package wrote)."""
    try:
        with path.open("rb") as stream:
            if stream.read(1) != b"{":
                return False
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    fmt = document.get("format") if isinstance(document, dict) else None
    return str(fmt).startswith(f"{FORMAT_NAME}/")


def _check_writable(golden: Path, array_file: Path | None, log: Path) -> None:
    """Refuse to write over the log, or over an arrays path holding a file not ours.

    Raises:
        GoldenError: ``golden`` or ``array_file`` is the log, ``golden`` exists and is not
            a golden file, or ``array_file`` exists and is not a golden arrays file or
            holds the arrays of another golden file beside it (:func:`_other_owner`);
            ``golden`` is a folder; either is a device or a pipe, or lies below a file or
            in a folder that cannot be written.
    """
    for target in (golden, array_file):
        if target is not None and _same_path(target, log):
            raise GoldenError(
                f"{target} is the log {log.name} itself; give the golden file another name"
            )
    if golden.is_dir():
        raise GoldenError(
            f"{golden} is a folder; name the golden file, e.g. {golden / 'log.golden.json'}"
        )
    for target in (golden, array_file):
        if target is not None:
            staged_at(target)  # a device, or a folder missing or not writable: refused now
    if golden.is_file() and not _is_golden_json(golden):
        raise GoldenError(
            f"{golden} exists and is not a golden file, so it is not overwritten; move it, "
            "or give the golden file another name"
        )
    if array_file is None or not array_file.exists():
        return
    if not is_golden_arrays(array_file):
        raise GoldenError(
            f"{array_file} exists and is not a golden arrays file (a basis? a log? a "
            f"damaged file?), so it is not overwritten with {golden.name}'s arrays; move it, "
            "or give the golden file another name"
        )
    owner = _other_owner(array_file, golden)
    if owner is not None:
        raise GoldenError(
            f"{array_file} holds the arrays of the golden file {owner} beside it, so it is "
            f"not overwritten with {golden.name}'s arrays; give the golden file another name"
        )


def _owner(path: Path) -> str | None:
    """Return the golden JSON a marked arrays file names (None: unmarked or unreadable)."""
    try:
        with path.open("rb") as stream, np.load(stream) as data:
            if ARRAYS_MARKER not in data.files:
                return None
            owner = json.loads(str(data[ARRAYS_MARKER])).get("golden")
    except (*_NPZ_ERRORS, AttributeError):
        return None
    return owner if isinstance(owner, str) and owner else None


def _other_owner(path: Path, golden: Path, channels: Mapping[str, Any] | None = None) -> str | None:
    """Return the name of another golden JSON beside ``path`` that keeps its arrays there.

    ``a.json`` and ``a.golden.json`` both keep their arrays in ``a.golden.npz``; the marker
    says whose they are. None when they are ``golden``'s, unmarked (written before the
    marker), their golden JSON is gone or names another arrays file (``golden`` was
    renamed or copied from it), or (``channels`` given: a check) it summarises the same
    channels as ``golden``, so its arrays fit ``golden`` too.
    """
    owner = _owner(path)
    if owner is None or owner == golden.name or Path(owner).name != owner:
        return None
    other = path.parent / owner
    if _same_path(other, golden) or not _is_golden_json(other):
        return None
    try:
        document = json.loads(other.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if document.get("arrays_file") != path.name:
        return None
    if channels is not None and document.get("channels") == channels:
        return None
    return owner


_CHANNEL_TOLERANCE = {k: v for k, v in DEFAULT_TOLERANCE.items() if k not in ("note", "channels")}
"""What a per-channel override (``tolerance["channels"][topic]``) may set."""
_LISTED_CHANNELS = 12


def _key(path: str, key: object) -> str:
    return f"{path}[{json.dumps(key) if isinstance(key, str) else repr(key)}]"


def _shown(value: object) -> str:
    text = json.dumps(value) if isinstance(value, str) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _near(word: object, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(str(word), list(choices), n=1, cutoff=0.6)
    return f" (did you mean {json.dumps(close[0])}?)" if close else ""


def _is_tolerance(value: object) -> bool:
    """Return True for a finite number >= 0 (not a bool, not a string of one)."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    number = float(value)
    return math.isfinite(number) and number >= 0


def _checked_group(
    value: object, template: Mapping[str, Any], path: str, source: str | Path
) -> dict[str, Any]:
    """Return ``value`` checked against the keys of ``template``, numbers as int or float."""
    if not isinstance(value, Mapping):
        raise GoldenToleranceError(
            f"{source}: {path} is {_shown(value)}, not a group of tolerances; give e.g. "
            f"{json.dumps(template)}"
        )
    checked: dict[str, Any] = {}
    for key, item in value.items():
        where = _key(path, key)
        if key not in template:
            raise GoldenToleranceError(
                f"{source}: {where} is not a tolerance{_near(key, template)}; the keys of "
                f"{path} are {', '.join(template)}"
            )
        default = template[key]
        if isinstance(default, Mapping):
            checked[key] = _checked_group(item, default, where, source)
        elif isinstance(default, str):  # the note
            if not isinstance(item, str):
                raise GoldenToleranceError(f"{source}: {where} is {_shown(item)}, not a string")
            checked[key] = item
        elif _is_tolerance(item):
            checked[key] = int(item) if isinstance(item, numbers.Integral) else float(item)
        else:
            raise GoldenToleranceError(
                f"{source}: {where} is {_shown(item)}, not a finite number >= 0; give a number "
                f"such as {default!r} (the default)"
            )
    return checked


def checked_tolerance(
    tolerance: object,
    source: str | Path,
    *,
    channels: Collection[str] | None = None,
    of: str = "of the golden file",
) -> dict[str, Any]:
    """Return a tolerance tree checked against :data:`DEFAULT_TOLERANCE`'s keys.

    Every key must be one of the defaults' (at any depth), every value a finite number
    >= 0 (the note a string), and every key of ``"channels"`` a topic with an override of
    the same groups (the note and ``"channels"`` left out). Keys may be missing: a check
    takes the defaults' for them.

    Args:
        tolerance: the tree, as a golden file's ``"tolerance"`` holds it.
        source: where it comes from, to start a message with (a golden file).
        channels: the channels an override may name (None: any).
        of: what ``channels`` are, for the message ("of the golden file").

    Returns:
        A copy with its numbers as int or float (numpy scalars too) and ``"channels"`` set.

    Raises:
        GoldenToleranceError: naming ``source``, the key and the valid keys.
    """
    if not isinstance(tolerance, Mapping):
        raise GoldenToleranceError(
            f"{source}: tolerance is {_shown(tolerance)}, not a mapping of tolerance groups; "
            'give e.g. {"float": {"rel": 0.01}}, or leave it out for the defaults'
        )
    overrides: object = {}
    if "channels" in tolerance:
        overrides = tolerance["channels"]
        tolerance = {k: v for k, v in tolerance.items() if k != "channels"}
    checked = _checked_group(tolerance, DEFAULT_TOLERANCE, "tolerance", source)
    where = _key("tolerance", "channels")
    if not isinstance(overrides, Mapping):
        raise GoldenToleranceError(
            f"{source}: {where} is {_shown(overrides)}, not a mapping of topic to tolerances; "
            'give e.g. {"/pcainterp/depth": {"float": {"rel": 0.01}}}'
        )
    checked["channels"] = {}
    for topic, override in overrides.items():
        if channels is not None and topic not in channels:
            listed = sorted(channels)
            shown = ", ".join(listed[:_LISTED_CHANNELS]) or "none"
            if len(listed) > _LISTED_CHANNELS:
                shown += f" and {len(listed) - _LISTED_CHANNELS} more"
            raise GoldenToleranceError(
                f"{source}: {_key(where, topic)} names no channel {of}"
                f"{_near(topic, listed)}; channels: {shown}; rename or remove the override"
            )
        checked["channels"][topic] = _checked_group(
            override, _CHANNEL_TOLERANCE, _key(where, topic), source
        )
    return checked


def _document(
    log: Path,
    summary: LogSummary,
    *,
    topics: list[str] | None,
    tolerance: Mapping[str, Any],
    arrays_file: str | None,
    version: int = FORMAT_VERSION,
) -> dict[str, Any]:
    return {
        "format": f"{FORMAT_NAME}/{version}",
        "created_by": f"pcainterp-stream {__version__}",
        "log": log.name,
        "topics": topics,
        "arrays_file": arrays_file,
        "tolerance": dict(tolerance),
        "channels": summary.channels,
    }


def _write(
    golden: Path,
    document: dict[str, Any],
    arrays: Mapping[str, npt.NDArray[Any]],
    *,
    log: Path,
) -> None:
    """Write the JSON (and the arrays); remove arrays files of ours it no longer names.

    The arrays file an older golden file at ``golden`` named (``kitti.npz`` before the
    ``.golden.npz`` naming) is removed when it is ours, never otherwise.
    """
    array_file = arrays_path(golden)
    _check_writable(golden, array_file if document["arrays_file"] else None, log)  # again
    stale = {array_file}
    previous = _recorded_arrays(golden)
    if previous is not None:
        stale.add(previous)
    if document["arrays_file"]:
        stale.discard(array_file)
    marker = json.dumps({"format": ARRAYS_FORMAT, "golden": golden.name})
    # the arrays renamed first, the JSON naming them last: both or neither (16C F9)
    targets = (array_file, golden) if document["arrays_file"] else (golden,)
    with replacing_together(*targets) as temporaries:
        if document["arrays_file"]:
            stored = {**arrays, ARRAYS_MARKER: np.array(marker)}
            try:
                with temporaries[0].open("wb") as stream:
                    np.savez_compressed(stream, **stored)  # type: ignore[arg-type]
            except OSError as err:  # a full disk, a file-size limit
                raise write_error(array_file, err) from err
        try:
            temporaries[-1].write_text(json.dumps(document, indent=1, allow_nan=True) + "\n")
        except OSError as err:
            raise write_error(golden, err) from err
    for path in stale:
        if path.exists() and not _same_path(path, log) and _arrays_of(path, golden):
            path.unlink()


def _arrays_of(path: Path, golden: Path) -> bool:
    """Return True when ``path`` holds ``golden``'s arrays (safe to remove with it).

    Marked files name their golden JSON; unmarked ones (written before the marker) count
    only under their old name, ``golden`` with the suffix ``.npz``, never another golden
    file's arrays that a copied JSON names.
    """
    if not is_golden_arrays(path):
        return False
    try:
        with path.open("rb") as stream, np.load(stream) as data:
            if ARRAYS_MARKER not in data.files:
                return path.name == golden.with_suffix(".npz").name
            owner = json.loads(str(data[ARRAYS_MARKER])).get("golden")
    except (*_NPZ_ERRORS, AttributeError):
        return False
    return bool(owner == golden.name)


def _recorded_arrays(golden: Path) -> Path | None:
    """Return the arrays file an existing golden file at ``golden`` names, if any."""
    try:
        name = json.loads(golden.read_text()).get("arrays_file")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        return None
    if not isinstance(name, str) or not name or Path(name).name != name:
        return None
    return golden.parent / name


def topic_selection(topics: Iterable[str] | str | None) -> list[str] | None:
    """Return the channels ``topics`` selects: None for all, a single name as a list of one.

    Raises:
        GoldenError: ``topics`` selects no channel, or holds something that is not a name.

    Examples:
        >>> topic_selection("/pcainterp/depth")
        ['/pcainterp/depth']
        >>> topic_selection(None) is None
        True
    """
    if topics is None:
        return None
    selected = [topics] if isinstance(topics, str) else list(topics)
    if not selected:
        raise GoldenError(
            "topics=[] selects no channel, so the golden file would guard nothing; give "
            "topic names, or None for every channel"
        )
    odd = [t for t in selected if not isinstance(t, str) or not t]
    if odd:
        raise GoldenError(f"topics must be topic names (str), got {odd[0]!r}")
    return selected


def save_golden(
    log: str | Path,
    golden: str | Path,
    *,
    topics: Iterable[str] | str | None = None,
    arrays: bool = False,
    tolerance: Mapping[str, Any] | None = None,
    progress: Progress | None = None,
    format_version: int = FORMAT_VERSION,
) -> LogSummary:
    """Summarise a log and write it as a golden file.

    Args:
        log: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        golden: the JSON file to write (its folder is created).
        topics: record only these channels (all when None; one name may be given as a str).
        arrays: also store every array in a compressed ``.npz`` beside the JSON, for an
            element-wise check (see :func:`arrays_path`).
        tolerance: the tolerances to write (default :data:`~.comparison.DEFAULT_TOLERANCE`);
            the keys given replace the defaults'. Only the defaults' keys, finite numbers
            >= 0, and under ``"channels"`` channels the golden file records.
        progress: called after each message with (messages done, total or None).
        format_version: :data:`FORMAT_VERSION`, or :data:`OLDEST_FORMAT_VERSION` to write
            what an older golden file records (to compare a log with one).

    Returns:
        The summary written.

    Raises:
        LogReadError: the log is missing, not a log or damaged.
        TopicNotFoundError: a topic in ``topics`` is not in the log.
        GoldenError: ``golden`` or its arrays file would overwrite the log, or either
            exists and is not a golden file of this package (nothing is written).
        GoldenToleranceError: ``tolerance`` has a key the defaults do not have, a value
            that is not a finite number >= 0, or an override of a channel not recorded.

    Examples:
        >>> from pcainterp_stream.golden import save_golden, check_log
        >>> save_golden("drive_dense.mcap", "drive.golden.json")  # doctest: +SKIP
        >>> check_log("drive_dense.mcap", "drive.golden.json").passed  # doctest: +SKIP
        True
    """
    log, golden = Path(log), Path(golden)
    selected = topic_selection(topics)
    if format_version not in (OLDEST_FORMAT_VERSION, FORMAT_VERSION):
        raise GoldenError(
            f"format_version={format_version!r}: this version writes format "
            f"{OLDEST_FORMAT_VERSION} or {FORMAT_VERSION}"
        )
    _check_writable(golden, arrays_path(golden) if arrays else None, log)  # before the work
    given = {} if tolerance is None else tolerance
    checked_tolerance(given, golden)  # before the work
    legacy = format_version < FORMAT_VERSION
    summary = summarize_log(
        log, topics=selected, keep_arrays=arrays, progress=progress, legacy=legacy
    )
    merged = checked_tolerance(
        {**DEFAULT_TOLERANCE, **given},
        golden,
        channels=summary.channels,
        of=f"recorded from {log.name}",
    )
    arrays_file = arrays_path(golden).name if arrays else None
    document = _document(
        log,
        summary,
        topics=selected,
        tolerance=merged,
        arrays_file=arrays_file,
        version=format_version,
    )
    _write(golden, document, summary.arrays, log=log)
    return summary


def _not_golden(golden: Path, err: Exception) -> str:
    """Return the one-line error for a golden file that is not JSON: name what it is."""
    if is_golden_arrays(golden):
        owner = _owner(golden) or _arrays_owner_guess(golden)
        return (
            f"{golden} is the arrays file of the golden file {owner}, not a golden file: "
            f"pass {owner} (the arrays file is read beside it)"
        )
    from pcainterp_stream.errors import LogReadError
    from pcainterp_stream.io.logreader import sniff_format

    try:
        sniff_format(golden)
    except LogReadError:
        return f"golden file {golden} is not readable JSON ({err}); pass a .golden.json"
    return (
        f"{golden} is a log, not a golden file: the arguments are LOG GOLDEN.json (the log first)"
    )


def _arrays_owner_guess(path: Path) -> str:
    """Return the golden JSON name an unmarked arrays file's name suggests."""
    stem = path.name.removesuffix(".npz").removesuffix(".golden")
    return f"{stem}.golden.json"


def _refuse_malformed(golden: Path, document: Mapping[str, Any]) -> None:
    """Refuse a golden document whose shape the comparison cannot read (:func:`malformed`)."""
    wrong = malformed(document)
    if wrong is not None:
        raise GoldenError(
            f"{golden} is a malformed golden file ({document.get('format')}): {wrong}; write "
            "it again with `pcainterp golden save`"
        )


def format_version(document: Mapping[str, Any]) -> int:
    """Return the format version of a document :func:`load_golden` returned."""
    return int(str(document.get("format", FORMAT)).partition("/")[2])


def load_golden(golden: str | Path) -> dict[str, Any]:
    """Read a golden file and check its format.

    A file of format :data:`OLDEST_FORMAT_VERSION` up to :data:`FORMAT_VERSION` is read
    (:func:`format_version` tells which).

    Raises:
        GoldenError: the file is missing, not JSON (a log or an arrays file given in its
            place is named so), not a golden file, of a newer format version than this
            package reads, or of an older one.
        GoldenToleranceError: its ``"tolerance"`` (edited by hand) has a key the defaults
            do not have, a value that is not a finite number >= 0, or an override of a
            channel the file does not record.
    """
    golden = Path(golden)
    try:
        document = json.loads(golden.read_text())
    except FileNotFoundError as err:
        raise GoldenError(
            f"golden file {golden} does not exist; write it with `pcainterp golden save`"
        ) from err
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise GoldenError(_not_golden(golden, err)) from err
    fmt = document.get("format") if isinstance(document, dict) else None
    name, _, version = str(fmt).partition("/")
    if name != FORMAT_NAME or not version.isdigit():
        raise GoldenError(f"{golden} is not a golden file (format {fmt!r}, expected {FORMAT!r})")
    if int(version) > FORMAT_VERSION:
        raise GoldenError(
            f"{golden} has format {fmt}, newer than this pcainterp-stream {__version__} "
            f"reads ({FORMAT}); upgrade pcainterp-stream"
        )
    if int(version) < OLDEST_FORMAT_VERSION:
        raise GoldenError(
            f"{golden} has the old format {fmt}; write it again with "
            f"`pcainterp golden save LOG -o {golden.name}` (this version reads {FORMAT})"
        )
    if not isinstance(document.get("channels"), dict):
        raise GoldenError(f"{golden} has no channels; write it again with `pcainterp golden save`")
    _refuse_malformed(golden, document)  # a channel entry a string, a count "4"
    if "tolerance" in document:
        document["tolerance"] = checked_tolerance(
            document["tolerance"], golden, channels=document["channels"]
        )
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
        stream = path.open("rb")
    except FileNotFoundError as err:
        raise GoldenError(
            f"{golden.name} stores its arrays in {path.name}, which is missing; copy it "
            "beside the golden file or save again"
        ) from err
    except OSError as err:
        raise GoldenError(f"arrays file {path} is not readable ({err})") from err
    try:
        data = np.load(stream)
    except _NPZ_ERRORS as err:
        stream.close()
        raise GoldenError(
            f"arrays file {path} does not load ({err}); it is damaged or cut off: save "
            f"{golden.name} again with --arrays"
        ) from err
    with stream, data:
        owner = _other_owner(path, golden, document.get("channels"))
        if owner is not None:
            raise GoldenError(
                f"{path} holds the arrays of the golden file {owner}, not those of "
                f"{golden.name} (both name it); save {golden.name} again under another name "
                "with --arrays"
            )
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
    topics: Iterable[str] | str | None = None,
    update: bool = False,
    progress: Progress | None = None,
) -> CheckResult:
    """Check a log against a golden file, within the tolerances the file states.

    Args:
        log: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        golden: a file :func:`save_golden` wrote (of format 2 too: checked as it was
            written, with a note on what it leaves out).
        topics: check only these channels (default: those the golden file records; one
            name may be given as a str).
        update: rewrite the golden file from this log when they differ, or when it is of
            an older format: with ``topics``, only the channels checked (the others keep
            what the file recorded, and the file its format); without, every channel the
            file records, in the current format (same tolerances and arrays option; the
            arrays go to :func:`arrays_path`, an older file's arrays of ours under another
            name are removed). The differences are still returned.
        progress: called after each message with (messages done, total or None).

    Returns:
        The differences (none when the log matches), notes on what is not guarded, and
        whether the file was rewritten.

    Raises:
        GoldenError: the golden file is missing, malformed or of another format version,
            a topic in ``topics`` is not in it, or (``update``) the rewrite would overwrite
            the log or a file that is not a golden arrays file.
        GoldenToleranceError: the golden file's tolerances are not valid (an unknown key,
            a value that is not a finite number >= 0, an override of a channel it does not
            record; with ``update``, of a channel the log does not have).
        LogReadError: the log is missing, not a log or damaged.
        TopicNotFoundError: a topic in ``topics`` is not in the log.
    """
    log, golden = Path(log), Path(golden)
    document = load_golden(golden)
    recorded = document.get("topics")
    selected = topic_selection(topics) if topics is not None else recorded
    if topics is not None:
        unknown = [t for t in selected or [] if t not in document["channels"]]
        if unknown:
            listed = ", ".join(document["channels"]) or "none"
            raise GoldenError(
                f"topic {unknown[0]} is not in the golden file {golden.name}; channels "
                f"recorded: {listed}"
            )
    with_arrays = bool(document.get("arrays_file"))
    version = format_version(document)
    partial = topics is not None and set(selected or []) != set(document["channels"])
    if update:  # refuse before the work, not after it
        _check_writable(golden, arrays_path(golden) if with_arrays else None, log)
    with _open_arrays(golden, document) as golden_arrays:
        summary = summarize_log(
            log,
            topics=selected,
            keep_arrays=with_arrays,
            skip_missing=topics is None,
            progress=progress,
            legacy=version < FORMAT_VERSION,
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
        notes = list(summary.notes)
        if version < FORMAT_VERSION and notes:
            notes.append(
                f"{golden.name} has the older format {document['format']}, which leaves "
                f"these out; rewrite it in {FORMAT} with `pcainterp golden check LOG "
                f"{golden.name} --update` (or save it again) to guard them"
            )
        result = CheckResult(golden=golden, differences=differences, notes=notes)
        if update and partial and differences:
            _update_channels(log, golden, document, summary, golden_arrays)
            result.updated = True
    if update and not partial and (differences or version < FORMAT_VERSION):
        save_golden(
            log,
            golden,
            topics=recorded,
            arrays=with_arrays,
            tolerance=document.get("tolerance"),
        )
        result.updated = True
    return result


def _update_channels(
    log: Path,
    golden: Path,
    document: Mapping[str, Any],
    summary: LogSummary,
    golden_arrays: Mapping[str, npt.NDArray[Any]] | None,
) -> None:
    """Rewrite the channels of ``summary`` in a golden file; keep its other channels."""
    arrays: dict[str, npt.NDArray[Any]] = {}

    def renumbered(channel: Mapping[str, Any], source: Mapping[str, Any]) -> dict[str, Any]:
        messages = []
        for message in channel["messages"]:
            message = dict(message)
            if "array_keys" in message:
                keys = {}
                for name, key in message["array_keys"].items():
                    if key in source:
                        keys[name] = f"a{len(arrays)}"
                        arrays[keys[name]] = np.asarray(source[key])
                message["array_keys"] = keys
            messages.append(message)
        return dict(channel, messages=messages)

    channels = {}
    for topic, channel in document["channels"].items():
        if topic in summary.channels:
            channels[topic] = renumbered(summary.channels[topic], summary.arrays)
        else:
            channels[topic] = renumbered(channel, golden_arrays or {})
    updated = dict(document, channels=channels, created_by=f"pcainterp-stream {__version__}")
    _write(golden, updated, arrays, log=log)


def describe_golden_file(path: str | Path) -> str | None:
    """Return a few lines on a golden file or a golden arrays file (None: it is neither).

    For ``pcainterp info``: a golden JSON (any format version) or an ``.npz`` that
    :func:`is_golden_arrays` recognises; any other file, or a folder, gives None.
    """
    path = Path(path)
    if not path.is_file():
        return None
    if is_golden_arrays(path):
        with path.open("rb") as stream, np.load(stream) as data:
            count = sum(1 for key in data.files if key != ARRAYS_MARKER)
        owner = _owner(path)
        of = f"the golden file {owner}" if owner else "a golden file"
        return (
            f"{path}: the arrays of {of} ({count} arrays, for its element-wise check), "
            f"written by `pcainterp golden save --arrays`; not a basis. Check a log with "
            f"`pcainterp golden check LOG {owner or 'GOLDEN.json'}`"
        )
    if not _is_golden_json(path):
        damaged = damaged_golden(path, FORMAT)  # cut off, a list, {}: not "not a log"
        if damaged is not None:
            raise GoldenError(damaged)
        return None
    document = json.loads(path.read_text())
    fmt = document["format"]
    if not isinstance(document.get("channels"), dict):
        document["channels"] = {}  # info says 0 channels; check says "has no channels"
    _refuse_malformed(path, document)
    channels = document["channels"]
    messages = sum(int(c.get("message_count", 0)) for c in channels.values())
    arrays = document.get("arrays_file")
    lines = [
        f"{path}: pcainterp golden file ({fmt}, written by "
        f"{document.get('created_by', 'an unknown version')} from {document.get('log', '?')})",
        f"  channels: {len(channels)}, messages: {messages}",
        f"  arrays: {arrays} (element-wise check)" if arrays else "  arrays: none (statistics)",
        f"  check a log against it: pcainterp golden check LOG {path.name}",
    ]
    return "\n".join(lines)
