"""The shape of a golden document: what a hand-edited or damaged file got wrong.

:func:`load_golden <pcainterp_stream.golden.store.load_golden>` checks the format and the
tolerances; :func:`malformed` checks the rest the comparison reads (each channel's
schema, encodings, message count and messages, each message's times, values and array
statistics), so that a wrong type is a one-line refusal (exit 2 from ``golden check``),
never a traceback that exits 1 as a difference would.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pcainterp_stream.golden.summary import QUANTILES

__all__ = ["damaged_golden", "malformed"]

_ENCODINGS = ("schema", "schema_encoding", "message_encoding")
_COUNTS = ("nan", "posinf", "neginf")
_STATS = ("mean", "std", "median", "mad")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _kind(value: Any) -> str:
    """How JSON names ``value``'s type: an object, a list, a string, ..."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return "a string"
    return "a number"


def malformed(document: Mapping[str, Any]) -> str | None:
    """Return what is wrong with a golden document's shape (None: nothing).

    ``document`` is a JSON object whose format :func:`load_golden` accepted. The text
    names the place: ``channel /cam/image message 3: log_time_ns is a string, expected
    an integer``.
    """
    topics = document.get("topics")
    if topics is not None and not (
        isinstance(topics, list) and all(isinstance(t, str) for t in topics)
    ):
        return f"topics is {_kind(topics)}, expected a list of topic names or null"
    arrays_file = document.get("arrays_file")
    if arrays_file is not None and not isinstance(arrays_file, str):
        return f"arrays_file is {_kind(arrays_file)}, expected a file name or null"
    channels = document.get("channels")
    if not isinstance(channels, dict):
        return f"channels is {_kind(channels)}, expected an object"
    for topic, channel in channels.items():
        wrong = _channel(channel)
        if wrong is not None:
            return f"channel {topic} {wrong}"
    return None


def _channel(channel: Any) -> str | None:
    if not isinstance(channel, dict):
        return f"is {_kind(channel)}, expected an object"
    for key in _ENCODINGS:
        if key not in channel:
            return f"has no {key}"
        if channel[key] is not None and not isinstance(channel[key], str):
            return f"{key} is {_kind(channel[key])}, expected a string"
    count: Any = channel.get("message_count")
    if count is None:
        return "has no message count"
    if not (_is_int(count) and count >= 0):
        return f"message_count is {count!r}, expected an integer >= 0"
    messages = channel.get("messages")
    if not isinstance(messages, list):
        return f"messages is {_kind(messages)}, expected a list"
    for index, message in enumerate(messages):
        wrong = _message(message)
        if wrong is not None:
            return f"message {index} {wrong}"
    return None


def _message(message: Any) -> str | None:
    if not isinstance(message, dict):
        return f"is {_kind(message)}, expected an object"
    for key in ("log_time_ns", "stamp_ns"):
        if (key in message or key == "log_time_ns") and not _is_int(message.get(key)):
            return f"{key} is {_kind(message.get(key))}, expected an integer"
    for key in ("values", "arrays", "array_keys"):
        if key in message and not isinstance(message[key], dict):
            return f"{key} is {_kind(message[key])}, expected an object"
    for name, stats in message.get("arrays", {}).items():
        wrong = _statistics(stats)
        if wrong is not None:
            return f"array {name} {wrong}"
    return None


def _statistics(stats: Any) -> str | None:
    if not isinstance(stats, dict):
        return f"is {_kind(stats)}, expected an object"
    if not isinstance(stats.get("dtype"), str):
        return "has no dtype"
    shape = stats.get("shape")
    if not (isinstance(shape, list) and all(_is_int(n) and n >= 0 for n in shape)):
        return "has no shape (a list of sizes)"
    for key in _COUNTS:
        if not _is_number(stats.get(key)):
            return f"has no {key} count"
    if "mean" not in stats:  # no finite element: no statistics
        return None
    for key in _STATS:
        if not _is_number(stats.get(key)):
            return f"{key} is {_kind(stats.get(key))}, expected a number"
    quantiles = stats.get("quantiles")
    if not (
        isinstance(quantiles, list)
        and len(quantiles) == len(QUANTILES)
        and all(_is_number(q) for q in quantiles)
    ):
        return f"quantiles is not a list of {len(QUANTILES)} numbers"
    return None if "blocks" not in stats else _blocks(stats["blocks"])


def _blocks(blocks: Any) -> str | None:
    """Block means: ``{"grid": [rows, columns], "means": [[a number or null per cell]...]}``."""
    grid = blocks.get("grid") if isinstance(blocks, dict) else None
    if not (isinstance(grid, list) and len(grid) == 2 and all(_is_int(n) for n in grid)):
        return "blocks has no grid [rows, columns]"
    cells = grid[0] * grid[1]
    means = blocks.get("means")
    if not (
        isinstance(means, list)
        and all(
            isinstance(row, list)
            and len(row) == cells
            and all(m is None or _is_number(m) for m in row)
            for row in means
        )
    ):
        return f"blocks means are not lists of {cells} numbers (one per cell of the grid)"
    return None


def damaged_golden(path: Path, expected: str) -> str | None:
    """Return the refusal of ``info`` for a file named like a golden file that is not one.

    For a ``.json`` file that is not a golden JSON of format ``expected`` (or an older
    one): cut off, a list, ``{}``. None for any other file, and for a log whatever its
    name (the log reader describes it).
    """
    if path.suffix.lower() != ".json":
        return None
    from pcainterp_stream.errors import LogReadError
    from pcainterp_stream.io.logreader import sniff_format

    with contextlib.suppress(LogReadError):
        sniff_format(path)
        return None  # a log named .json: the log reader's business
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as err:
        what = f"not readable: {err}"
    except json.JSONDecodeError as err:
        what = f"not readable JSON, cut off or edited: {err}"
    else:
        if isinstance(document, dict):
            fmt = document.get("format")
            what = f"format {fmt!r}, expected {expected!r}" if fmt else "no format"
        else:
            what = f"{_kind(document)}, not an object"
    again = f"write it again with `pcainterp golden save LOG -o {path.name}`"
    if path.name.lower().endswith(".golden.json"):
        return f"{path} is a damaged golden file ({what}); {again}"
    return (
        f"{path} is JSON but not a golden file ({what}); info describes a log, a basis file "
        f"or a golden file (a damaged golden file: {again})"
    )
