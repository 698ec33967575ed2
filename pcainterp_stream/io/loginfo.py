"""Describe a log for ``pcainterp info FILE``: format, topics, time span, damage.

Uses the log's own index where it has one (MCAP statistics, bag metadata) and otherwise
counts by reading every message once. Nothing here decodes message contents.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Metadata

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.logreader import (
    LogFormat,
    TopicInfo,
    looks_like_kitti,
    open_log,
)
from pcainterp_stream.io.mcap_extras import AttachmentInfo, size_text


@dataclass(frozen=True)
class LogInfo:
    """What :func:`describe` found in a log.

    Attributes:
        path: the log's path.
        format: container format.
        topics: topic -> :class:`~logreader.TopicInfo` (counts as read or indexed).
        message_count: total messages.
        start_ns: first log time (ns), None for an empty log.
        end_ns: last log time (ns), None for an empty log.
        counted: True when the counts come from reading every message, False when from
            the log's index.
        damage: one-line descriptions of damage found.
        warnings: one-line notes that are not damage.
        attachments: an MCAP log's attachments (their headers), a rosbag2 folder's storage
            files' too.
        metadata: an MCAP log's metadata records, a rosbag2 folder's storage files' too.
    """

    path: Path
    format: LogFormat
    topics: dict[str, TopicInfo]
    message_count: int
    start_ns: int | None
    end_ns: int | None
    counted: bool
    damage: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    attachments: list[AttachmentInfo] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)

    @property
    def duration_ns(self) -> int:
        """Return end - start log time (ns); 0 for an empty log."""
        if self.start_ns is None or self.end_ns is None:
            return 0
        return self.end_ns - self.start_ns


def describe(path: str | Path, *, count: bool = False) -> LogInfo:
    """Describe a log: format, topics with types and counts, time span, damage.

    Args:
        path: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder or storage file.
        count: read every message even when the log has an index (finds damage the index
            does not show, at the cost of a full read).

    Raises:
        LogReadError: the path is missing or not a log (a KITTI folder is named as such with
            the ``pcainterp import-kitti`` hint).
    """
    path = Path(path)
    if path.is_dir() and not (path / "metadata.yaml").is_file() and looks_like_kitti(path):
        raise LogReadError(
            f"{path} is a KITTI folder, not a log; convert it with "
            f"`pcainterp import-kitti {path} OUT.mcap`"
        )
    with open_log(path) as reader:
        topics = reader.topics()
        stats = None if count else reader.message_stats()
        counts_known = all(info.message_count is not None for info in topics.values())
        if stats is not None and counts_known and not reader.damage:
            total, start_ns, end_ns = stats
            counted = False
        else:
            per_topic: dict[str, int] = {}
            per_type: dict[str, dict[str, int]] = {}  # topic -> message type -> count
            total, start_ns, end_ns = 0, None, None
            for raw in reader.messages():
                total += 1
                per_topic[raw.topic] = per_topic.get(raw.topic, 0) + 1
                kinds = per_type.setdefault(raw.topic, {})
                kinds[raw.msgtype] = kinds.get(raw.msgtype, 0) + 1
                t = raw.log_time_ns
                start_ns = t if start_ns is None else min(start_ns, t)
                end_ns = t if end_ns is None else max(end_ns, t)
            topics = {
                name: TopicInfo(
                    info.topic,
                    info.msgtype,
                    per_topic.get(name, 0),
                    info.message_encoding,
                    info.schema_encoding,
                    _types_counted(info, per_type.get(name, {})),
                )
                for name, info in topics.items()
            }
            counted = True
        extras = reader.extras()
        return LogInfo(
            path=path,
            format=reader.format,
            topics=topics,
            message_count=total,
            start_ns=start_ns,
            end_ns=end_ns,
            counted=counted,
            damage=list(reader.damage),
            warnings=list(reader.warnings),
            attachments=extras.attachments if extras is not None else [],
            metadata=extras.metadata if extras is not None else [],
        )


def _types_counted(
    info: TopicInfo, counted: dict[str, int]
) -> tuple[tuple[str, int | None], ...]:
    """Return a topic's message types with the counts read (of those its channels name)."""
    if not info.types and len(counted) <= 1:
        return ()
    names = [msgtype for msgtype, _ in info.type_counts()]
    names += [msgtype for msgtype in counted if msgtype not in names]
    return tuple((msgtype, counted.get(msgtype, 0)) for msgtype in names)


def seconds_text(time_ns: int) -> str:
    """Return a time in integer ns as exact seconds with nine decimals.

    A float64 holds about 16 significant digits, so ``time_ns / 1e9`` of an epoch time
    (19 digits) invents its last nanosecond digits; integer division does not.

    Examples:
        >>> seconds_text(1_600_000_000_300_000_000)
        '1600000000.300000000'
        >>> seconds_text(-1)
        '-0.000000001'
    """
    sign = "-" if time_ns < 0 else ""
    whole, fraction = divmod(abs(time_ns), 1_000_000_000)
    return f"{sign}{whole}.{fraction:09d}"


def format_info(info: LogInfo) -> str:
    """Return a log description as text for the terminal (one topic per line)."""
    lines = [f"{info.path}: {info.format.value} log"]
    if info.start_ns is None or info.end_ns is None:
        lines.append("  messages: 0")
    else:
        lines.append(
            f"  messages: {info.message_count} ({'counted' if info.counted else 'from the index'})"
        )
        start, end = seconds_text(info.start_ns), seconds_text(info.end_ns)
        lines.append(f"  start: {start} s   end: {end} s")
        lines.append(f"  duration: {info.duration_ns / 1e9:.3f} s")
    lines.append(f"  topics: {len(info.topics)}")
    width = max((len(name) for name in info.topics), default=0)
    for name, topic in info.topics.items():
        count = "?" if topic.message_count is None else str(topic.message_count)
        kind = topic.msgtype or "(no schema)"
        if topic.types:  # recorded with several message types: each with its count
            kind = " + ".join(
                f"{'?' if number is None else number} {msgtype or '(no schema)'}"
                for msgtype, number in topic.types
            )
        if topic.message_encoding not in ("cdr", ""):
            kind += f" [{topic.message_encoding}]"
        elif topic.msgtype and not topic.schema_encoding:  # copied as it is, not decodable
            kind += " (no definition stored)"
        lines.append(f"    {name:<{width}}  {count:>8}  {kind}")
    if info.attachments:
        lines.append(f"  attachments: {len(info.attachments)}")
        width = max(len(item.name) for item in info.attachments)
        for item in info.attachments:
            kind = item.media_type or "(no media type)"
            lines.append(f"    {item.name:<{width}}  {size_text(item.size):>10}  {kind}")
    if info.metadata:
        lines.append(f"  metadata records: {len(info.metadata)}")
        width = max(len(record.name) for record in info.metadata)
        for record in info.metadata:
            keys = len(record.metadata)
            lines.append(f"    {record.name:<{width}}  {keys} key{'s' if keys != 1 else ''}")
    for note in info.warnings:
        lines.append(f"  note: {note}")
    if info.damage:
        lines.append(f"  DAMAGE ({len(info.damage)}):")
        lines.extend(f"    {note}" for note in info.damage)
    return "\n".join(lines)
