"""Summarise a log for a golden file: channels, times, values and robust array statistics.

:func:`summarize_log` reads any log :func:`~pcainterp_stream.io.logreader.open_log` opens,
decodes every ROS message generically (:mod:`.decode`) and returns a JSON-ready summary:
per channel its schema, encodings and message count, and per message its log time, header
stamp, flattened values and for every numeric array the statistics of
:func:`array_statistics`. Messages that are not ROS CDR (JSON, protobuf...) are recorded by
count and log time only.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, TopicNotFoundError
from pcainterp_stream.golden.decode import message_content
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_cameras import FrameCameras
from pcainterp_stream.io.outputs import FOCAL_BASELINE_KEY
from pcainterp_stream.io.reader_base import ROS2_SCHEMA_ENCODINGS

__all__ = [
    "BLOCK_GRID",
    "QUANTILES",
    "LogSummary",
    "Progress",
    "array_statistics",
    "summarize_log",
]

Progress = Callable[[int, int | None], None]
"""A progress callback: (messages done, total messages or None when the log has no index)."""

COMPLETE_READS = (
    # a ROS 1 bag whose recorder was killed after its last chunk: every record read to its end
    re.compile(
        r".+: unindexed \(recording cut off\?\): read \d+ messages in file order up to byte "
        r"(\d+) of \1; rosbag reindex .+ restores its index"
    ),
    # an MCAP whose writer stopped after a whole record (a killed recorder's, without its
    # data-end record; or after it, without summary, footer or end magic): the walk met no
    # cut record, or it would note that as well
    re.compile(
        r".+: (no MCAP magic at the end, no footer or summary|file ends without a data-end "
        r"record or footer) \(truncated\) at byte (\d+) of \2"
    ),
)
"""Damage notes (of :mod:`.io.rosbag1_walk`, :mod:`.io.mcap_reader`) that leave out no
message: a log without its index read to the end of the file. A golden summary of it is
the whole log's (bug hunt 17A F2); any other note refuses it."""

QUANTILES = (0.01, 0.1, 0.25, 0.5, 0.75, 0.9, 0.99)
"""The quantiles every array summary records (of its finite values)."""

BLOCK_GRID = 4
"""An image's spatial summary: the means of a BLOCK_GRID x BLOCK_GRID grid of blocks."""


@dataclass
class LogSummary:
    """A log as a golden file records it.

    Attributes:
        channels: topic -> {"schema", "schema_encoding", "message_encoding",
            "message_count", "messages": [per-message dicts]}, in the log's topic order;
            plus ``"focal_baseline"`` (f*b, px*m) where the channel's metadata states it
            (the depth of a densified log), to turn a disparity std into a depth std; a
            message of a log whose camera changed has its own where it differs.
        arrays: array key -> the array itself, filled only when asked for (``keep_arrays``);
            each message dict names its keys under ``"array_keys"``.
        notes: one-line notes on parts that did not decode.
    """

    channels: dict[str, dict[str, Any]]
    arrays: dict[str, npt.NDArray[Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def array_statistics(values: npt.NDArray[Any]) -> dict[str, Any]:
    """Return robust statistics of an array, JSON-ready.

    Args:
        values: any numeric array (image, point field, sequence).

    Returns:
        ``dtype``, ``shape``, counts of ``nan``, ``posinf`` and ``neginf`` elements, and over
        the finite elements ``mean``, ``std``, ``median``, ``mad`` (median absolute
        deviation) and ``quantiles`` (at :data:`QUANTILES`); the last five only when some
        element is finite. An image ((H, W) or (H, W, C)) with a finite element also gets
        ``blocks``, where its values are (:func:`block_means`).
    """
    data = np.asarray(values, dtype=np.float64)
    finite = data[np.isfinite(data)]
    stats: dict[str, Any] = {
        "dtype": str(values.dtype),
        "shape": list(values.shape),
        "nan": int(np.isnan(data).sum()),
        "posinf": int(np.isposinf(data).sum()),
        "neginf": int(np.isneginf(data).sum()),
    }
    if finite.size:
        median = float(np.median(finite))
        stats.update(
            mean=float(finite.mean()),
            std=float(finite.std()),
            median=median,
            mad=float(np.median(np.abs(finite - median))),
            quantiles=[float(q) for q in np.quantile(finite, QUANTILES)],
        )
        if data.ndim in (2, 3) and min(data.shape[:2]) > 0:
            low, high = stats["quantiles"][0], stats["quantiles"][-1]
            stats["blocks"] = block_means(data, low=low, high=high)
    return stats


def block_means(data: npt.NDArray[Any], *, low: float, high: float) -> dict[str, Any]:
    """Return a coarse spatial summary of an image: block means per channel.

    The pooled statistics of :func:`array_statistics` do not change when the pixels are
    permuted (a mirrored depth map, red and blue exchanged); these do. Values are clipped
    to [low, high] first (winsorised: +inf counts as ``high``, so a pixel that turns
    infinite or a far outlier moves a block mean by at most the spread over the block's
    pixel count); NaN is left out.

    Args:
        data: (H, W) or (H, W, C) array, any numeric dtype.
        low: the clip floor (the image's 1 % quantile).
        high: the clip ceiling (the image's 99 % quantile).

    Returns:
        ``grid``: [rows, columns] of blocks (:data:`BLOCK_GRID` each, fewer for an image
        smaller than that), ``means``: one row-major list of rows x columns block means per
        channel, None for a block without a number.
    """
    values = np.asarray(data, dtype=np.float64)
    if values.ndim == 2:
        values = values[:, :, None]
    height, width = values.shape[:2]
    rows, columns = min(BLOCK_GRID, height), min(BLOCK_GRID, width)
    row_starts = np.linspace(0, height, rows + 1).astype(np.intp)[:-1]
    column_starts = np.linspace(0, width, columns + 1).astype(np.intp)[:-1]
    number = ~np.isnan(values)
    clipped = np.where(number, np.clip(values, low, high), 0.0)

    def block_sums(array: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
        by_rows = np.add.reduceat(array, row_starts, axis=0)
        return np.asarray(np.add.reduceat(by_rows, column_starts, axis=1), dtype=np.float64)

    sums, counts = block_sums(clipped), block_sums(number.astype(np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts
    return {
        "grid": [rows, columns],
        "means": [
            [float(m) if n > 0 else None for m, n in zip(mean, count, strict=True)]
            for mean, count in zip(
                means.reshape(-1, means.shape[2]).T,
                counts.reshape(-1, counts.shape[2]).T,
                strict=True,
            )
        ],
    }


def _json_value(value: Any) -> Any:
    """Return a value JSON can hold exactly (non-finite floats as strings)."""
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    if isinstance(value, list):
        return [_json_value(v) for v in value]
    return value


def _float_or_none(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if np.isfinite(value) and value > 0 else None


def _focal_baseline(
    path: Path,
    raw: Any,
    channel: dict[str, Any],
    entry: dict[str, Any],
    cameras: dict[str, FrameCameras],
) -> None:
    """Record a densified channel's f*b (its first message's) and a message's own if other.

    A log whose camera changed records each camera's f*b (``io.output_cameras``): a message
    of another camera than the channel's first gets ``"focal_baseline"`` of its own.
    """
    if not channel["messages"]:
        focal_baseline = _float_or_none(raw.channel_metadata[FOCAL_BASELINE_KEY])
        if focal_baseline is not None:
            channel["focal_baseline"] = focal_baseline
    prefix = raw.topic.rsplit("/", 1)[0]
    if prefix not in cameras:
        try:
            cameras[prefix] = FrameCameras.of_log(path, prefix)
        except ValueError as err:
            raise LogReadError(str(err)) from None
    if not cameras[prefix]:
        return
    own = cameras[prefix].metadata(raw.channel_metadata, raw.log_time_ns)[FOCAL_BASELINE_KEY]
    value = _float_or_none(own)
    if value is not None and value != channel.get("focal_baseline"):
        entry["focal_baseline"] = value


def summarize_log(
    path: str | Path,
    *,
    topics: Iterable[str] | None = None,
    keep_arrays: bool = False,
    skip_missing: bool = False,
    progress: Progress | None = None,
    legacy: bool = False,
) -> LogSummary:
    """Summarise a log for a golden file.

    Args:
        path: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        topics: summarise only these channels (all when None).
        keep_arrays: also return every array itself (for a per-pixel check).
        skip_missing: leave out topics of ``topics`` that the log lacks instead of raising
            (a check then reports them as missing channels).
        progress: called after each message with (messages done, total or None).
        legacy: summarise as golden files of format 2 did (to check one of them; see
            :func:`~.decode.message_content`).

    Returns:
        The summary; message indices count within each channel from 0.

    Raises:
        LogReadError: the log is missing, not a log, or damaged (truncated, a corrupt
            chunk): a golden summary of part of a log would be wrong. A log missing only
            its index, read to the end of the file (:data:`COMPLETE_READS`), is summarised.
        TopicNotFoundError: a topic asked for is not in the log.
    """
    path = Path(path)
    with open_log(path) as reader:
        present = reader.topics()
        wanted = list(present) if topics is None else list(topics)
        missing = [topic for topic in wanted if topic not in present]
        if skip_missing:
            wanted = [topic for topic in wanted if topic in present]
        elif missing:
            listed = ", ".join(present) or "none"
            raise TopicNotFoundError(
                f"topic {missing[0]} not found in {path.name}; topics present: {listed}"
            )
        channels: dict[str, dict[str, Any]] = {
            topic: {
                "schema": present[topic].msgtype,
                "schema_encoding": present[topic].schema_encoding,
                "message_encoding": present[topic].message_encoding,
                "message_count": 0,
                "messages": [],
            }
            for topic in wanted
        }
        summary = LogSummary(channels=channels)
        cameras: dict[str, FrameCameras] = {}  # by output prefix, read when first needed
        counts = [present[topic].message_count for topic in wanted]
        total = None if None in counts else sum(c or 0 for c in counts)
        for done, raw in enumerate(reader.messages(wanted), start=1):
            if progress is not None:
                progress(done, total)
            channel = channels[raw.topic]
            index = channel["message_count"]
            channel["message_count"] += 1
            entry: dict[str, Any] = {"log_time_ns": raw.log_time_ns}
            if FOCAL_BASELINE_KEY in raw.channel_metadata:
                _focal_baseline(path, raw, channel, entry, cameras)
            channel["messages"].append(entry)
            if raw.message_encoding != "cdr" or raw.schema_encoding not in ROS2_SCHEMA_ENCODINGS:
                continue
            content = message_content(raw.msgtype, reader.decode(raw), legacy=legacy)
            stamp = content.values.pop("header.stamp", None)
            if stamp is not None:
                entry["stamp_ns"] = stamp
            entry["values"] = {k: _json_value(v) for k, v in content.values.items()}
            entry["arrays"] = {k: array_statistics(v) for k, v in content.arrays.items()}
            summary.notes += [f"{raw.topic} #{index}: {note}" for note in content.notes]
            if keep_arrays and content.arrays:
                keys = {}
                for name, values in content.arrays.items():
                    key = f"a{len(summary.arrays)}"
                    summary.arrays[key] = np.asarray(values)
                    keys[name] = key
                entry["array_keys"] = keys
        damage_notes = [
            note for note in reader.damage if not any(p.fullmatch(note) for p in COMPLETE_READS)
        ]
        if damage_notes:
            damage = damage_notes[0].removeprefix(f"{path.name}: ")
            raise LogReadError(
                f"{path.name} is damaged: {damage}; a golden summary needs the whole log "
                "(record or copy it again)"
            )
    return summary
