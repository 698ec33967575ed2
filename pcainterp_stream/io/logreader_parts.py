"""The parts of one split recording read as one log (``rosbag record --split``: a_0.bag, a_1.bag).

``rosbag record --split`` (and ``--duration`` / ``--size``) writes one recording as several
bags, each a log of its own; a rosbag2 recording's splits are named by its folder's
``metadata.yaml`` and read as one already (:mod:`.rosbag2_mcap`). :class:`PartsLogReader`
reads files of one format given together as one log: its parts in the order of their first
log time (a shell's ``a_*.bag`` puts ``a_10.bag`` before ``a_2.bag``), their messages one part
after the other, which is log-time order because the parts of one recording do not overlap in
log time, but for the seam: a recorder stamps each message's receive time on one of several
threads before queueing it (ROS 1's recorder on its 10 spinner threads, before taking the
queue lock) and splits between two messages in queue order, so the last messages of one part
can carry a receive time microseconds later than the first of the next. Parts that overlap
by up to :data:`SEAM_OVERLAP_NS` (1 s: such jitter is micro- to milliseconds, while two
recordings of one time overlap by much of a part's length) are read with their messages merged
in log-time order. Parts that overlap by more, or by half of one of them (two recordings, not
one split; a part shorter than twice :data:`SEAM_JITTER_NS`, such as a last part of one message,
may overlap by that 10 ms), mixed formats or a file given twice are refused with a one-line
error; parts more than :data:`GAP_WARN_NS` (60 s) apart are read as one log with a one-line
warning (a recording's parts follow each other without a gap, unless nothing was recorded for
that long).
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.mcap_extras import ChannelInfo, McapExtras
from pcainterp_stream.io.reader_base import LogFormat, LogReader, TopicInfo, merge_topic
from pcainterp_stream.records import RawMessage

__all__ = [
    "FOLLOW_NS",
    "GAP_WARN_NS",
    "SEAM_JITTER_NS",
    "SEAM_OVERLAP_NS",
    "PartsLogReader",
    "parts_name",
    "seams",
]

SEAM_OVERLAP_NS = 1_000_000_000
"""How far two parts may overlap in log time at the seam and still be one recording (1 s)."""
SEAM_JITTER_NS = 10_000_000
"""The overlap any part may have, however short (10 ms): a seam's stamp jitter, not half a part.

A recording stopped right after a split leaves a last part of one message (a span of 0), which
its stamp may still put microseconds before the previous part's end.
"""
GAP_WARN_NS = 60_000_000_000
"""A gap between two parts longer than this (60 s) is named in a warning."""

FOLLOW_NS = 2_000_000_000
"""Two logs of which one starts within this (2 s) of the other's end look like one split."""

_SEPARATE = "to densify them as separate logs, pass --out-dir DIR"


def parts_name(paths: Sequence[Path]) -> Path:
    """Return the name the parts are shown by: ``a_0.bag + a_1.bag`` (in the first's folder).

    Examples:
        >>> str(parts_name([Path("d/a_0.bag"), Path("d/a_1.bag")]))
        'd/a_0.bag + a_1.bag'
        >>> str(parts_name([Path(f"a_{k}.bag") for k in range(4)]))
        'a_0.bag + ... + a_3.bag (4 parts)'
    """
    first, last = paths[0], paths[-1]
    if len(paths) == 2:
        return first.with_name(f"{first.name} + {last.name}")
    return first.with_name(f"{first.name} + ... + {last.name} ({len(paths)} parts)")


class PartsLogReader(LogReader):
    """Reads several logs of one format as the parts of one recording (module docstring).

    Attributes:
        parts: the parts' paths, in log-time order (the order they are read in).

    Damage and warnings name the part they were found in.
    """

    def __init__(
        self,
        paths: Sequence[Path],
        formats: Sequence[LogFormat],
        files: Sequence[Sequence[Path]],
        opener: Callable[[Path], LogReader],
    ) -> None:
        """Check the parts (not opened yet).

        Args:
            paths: the parts, in any order.
            formats: each part's format (``logreader.sniff_format``).
            files: the files each part reads (``logreader.log_files``).
            opener: opens one part (``logreader.open_log``).

        Raises:
            LogReadError: parts of several formats, or a file given twice.
        """
        if len(paths) < 2:
            raise ValueError("PartsLogReader reads two logs or more")
        # one log given twice first: a rosbag2 folder and its own storage file differ in format
        seen: dict[Path, int] = {}  # file -> the part that reads it
        for index, (path, read) in enumerate(zip(paths, files, strict=True)):
            for file in read:
                given = paths[seen.setdefault(file.resolve(), index)]
                if seen[file.resolve()] != index:
                    twice = (
                        f"{path} is given twice"
                        if given == path
                        else f"{given} and {path} are one log given twice (both read {file.name})"
                    )
                    raise LogReadError(f"{twice}; pass each part of the recording once")
        for path, log_format in zip(paths[1:], formats[1:], strict=True):
            if log_format is not formats[0]:
                raise LogReadError(
                    f"{paths[0]} is {_kind(formats[0])} but {path} is {_kind(log_format)}: "
                    f"the parts of one recording are of one format; {_SEPARATE}"
                )
        super().__init__(parts_name(list(paths)))
        self.format = formats[0]
        self.parts = list(paths)
        self._opener = opener
        self._readers: list[LogReader] = []
        self._merge = False  # some parts overlap at the seam: merge their messages by log time

    def _open(self) -> None:
        try:
            for path in self.parts:
                reader = self._opener(path)
                self._readers.append(reader)
                # one list for the log: notes name their part
                self.damage.extend(note for note in reader.damage if note not in self.damage)
                self.warnings.extend(note for note in reader.warnings if note not in self.warnings)
                reader.damage, reader.warnings = self.damage, self.warnings
            self._order()
        except BaseException:
            self._close()
            raise

    def _close(self) -> None:
        for reader in self._readers:
            reader.close()
        self._readers = []

    def _order(self) -> None:
        """Sort the parts by their first log time; refuse parts that overlap in log time."""
        spans = [(_span(reader), index) for index, reader in enumerate(self._readers)]
        # by first log time, then as given; empty parts last
        spans.sort(key=lambda item: (item[0] is None, item[0][0] if item[0] else 0, item[1]))
        self._readers = [self._readers[index] for _, index in spans]
        self.parts = [reader.path for reader in self._readers]
        self.path = parts_name(self.parts)
        self._merge = False
        previous: tuple[Path, tuple[int, int]] | None = None
        for (span, _), reader in zip(spans, self._readers, strict=True):
            if span is None:  # an empty part: nothing to order
                continue
            if previous is not None:
                first, (start, end) = previous
                overlap = end - span[0]
                # a seam's few messages, not a share of a part: two recordings of one time
                half = max(SEAM_JITTER_NS, min(end - start, span[1] - span[0]) // 2)
                if overlap > min(SEAM_OVERLAP_NS, half):
                    raise LogReadError(
                        f"{first} (log time {_seconds(start)} to {_seconds(end)} s) and "
                        f"{reader.path} ({_seconds(span[0])} to {_seconds(span[1])} s) overlap "
                        f"by {_duration(overlap)}: they are not the parts of one split "
                        "recording (each part starts where the one before ends, give or take "
                        f"the messages at the seam: at most {_duration(SEAM_OVERLAP_NS)} and "
                        f"half a part, or {_duration(SEAM_JITTER_NS)} for a shorter part); "
                        f"{_SEPARATE}"
                    )
                if span[0] < end:
                    self._merge = True
                elif span[0] - end > GAP_WARN_NS:
                    self._warn_once(
                        f"{reader.path.name} starts {_duration(span[0] - end)} after "
                        f"{first.name} ends: read as parts of one recording, but a split "
                        f"recording's parts follow each other (to densify them as separate "
                        "logs, pass --out-dir DIR)"
                    )
            previous = (reader.path, span if previous is None else (span[0], max(span[1], end)))

    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`: every part's, counts summed."""
        self._check_open()
        topics: dict[str, TopicInfo] = {}
        for reader in self._readers:
            for name, info in reader.topics().items():
                topics[name] = merge_topic(topics.get(name), info)
        return topics

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """See :meth:`LogReader.message_stats`: None unless every part's index says so."""
        self._check_open()
        count, starts, ends = 0, [], []
        for reader in self._readers:
            stats = reader.message_stats()
            if stats is None:
                return None
            count += stats[0]
            starts += [stats[1]] if stats[1] is not None else []
            ends += [stats[2]] if stats[2] is not None else []
        if not count:
            return (0, None, None)
        return (count, min(starts), max(ends))

    def indexed(self) -> bool:
        """See :meth:`LogReader.indexed`: every part is."""
        self._check_open()
        return all(reader.indexed() for reader in self._readers)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """See :meth:`LogReader.messages`: each part's in turn, the parts in log-time order."""
        self._check_open()
        wanted = None if topics is None else list(topics)
        if self._merge:  # parts overlap at a seam: in log-time order (ties: the earlier part's)
            yield from heapq.merge(
                *(reader.messages(wanted) for reader in self._readers),
                key=lambda raw: raw.log_time_ns,
            )
        else:
            for reader in self._readers:
                yield from reader.messages(wanted)
        self.backward_log_times = max(reader.backward_log_times for reader in self._readers)

    def extras(self, *, verify: bool = False) -> McapExtras | None:
        """See :meth:`LogReader.extras`: every MCAP part's, in log-time order; else None."""
        self._check_open()
        found = [reader.extras(verify=verify) for reader in self._readers]
        if all(item is None for item in found):
            return None
        channels: list[ChannelInfo] = []
        extras = McapExtras(self.path, channels)
        for reader, item in zip(self._readers, found, strict=True):
            if item is None:
                continue
            channels += [channel for channel in item.channels if channel not in channels]
            extras.attachments.extend(
                dataclasses.replace(attachment, file=reader.path) for attachment in item.attachments
            )
            extras.metadata.extend(item.metadata)
        return extras


def seams(
    paths: Sequence[Path], opener: Callable[[Path], LogReader]
) -> list[tuple[tuple[Path, ...], tuple[int, ...]]]:
    """Return the chains of logs that look like consecutive parts of one split recording.

    Each is ``(parts, gaps_ns)``: two or more logs in log-time order, each starting between
    :data:`SEAM_JITTER_NS` before and :data:`FOLLOW_NS` after the one before ends (by their
    indexes; a log without one, or one that does not open, is left out: this is a hint,
    never a check), and the gap at each seam (``len(parts) - 1`` of them). Three parts of
    one recording are one chain, never two pairs.
    """
    spans: list[tuple[int, int, Path]] = []
    for path in dict.fromkeys(paths):
        try:
            with opener(path) as reader:
                stats = reader.message_stats()
        except (LogReadError, OSError):  # the job itself reports a log that does not open
            continue
        if stats is not None and stats[1] is not None and stats[2] is not None:
            spans.append((stats[1], stats[2], path))
    spans.sort(key=lambda item: (item[0], item[1]))
    chains: list[tuple[list[Path], list[int]]] = []
    for (_, end, first), (start, _, after) in itertools.pairwise(spans):
        if not -SEAM_JITTER_NS <= start - end <= FOLLOW_NS:
            continue
        if chains and chains[-1][0][-1] == first:  # the next part of the chain before
            chains[-1][0].append(after)
            chains[-1][1].append(start - end)
        else:
            chains.append(([first, after], [start - end]))
    return [(tuple(parts), tuple(gaps)) for parts, gaps in chains]


def _span(reader: LogReader) -> tuple[int, int] | None:
    """Return a part's first and last log time (ns), None for an empty part.

    From its index where it has one, else read once (a bag without its index).
    """
    stats = reader.message_stats()
    if stats is not None:
        _, start, end = stats
        return None if start is None or end is None else (start, end)
    start_ns: int | None = None
    end_ns: int | None = None
    for raw in reader.messages():
        t = raw.log_time_ns
        start_ns = t if start_ns is None else min(start_ns, t)
        end_ns = t if end_ns is None else max(end_ns, t)
    return None if start_ns is None or end_ns is None else (start_ns, end_ns)


def _seconds(time_ns: int) -> str:
    """A log time in seconds to the microsecond (``1317046453.600030``)."""
    return f"{time_ns // 1_000_000_000}.{time_ns % 1_000_000_000 // 1000:06d}"


def _duration(span_ns: int) -> str:
    """A duration in the unit that shows it: ``0.030 ms``, ``2.500 s``.

    Examples:
        >>> _duration(30_000), _duration(2_500_000_000), _duration(3_600_100_000_000)
        ('0.030 ms', '2.500 s', '3600.1 s')
    """
    if span_ns < 1_000_000_000:
        return f"{span_ns / 1e6:.3f} ms"
    return f"{span_ns / 1e9:.3f} s" if span_ns < 60_000_000_000 else f"{span_ns / 1e9:.1f} s"


def _kind(log_format: LogFormat) -> str:
    return {
        LogFormat.MCAP: "an MCAP file",
        LogFormat.ROS1: "a ROS 1 bag",
        LogFormat.ROSBAG2: "a rosbag2 bag",
    }[log_format]
