"""A rosbag2 folder whose storage is MCAP, read through its storage files.

ROS 2's default storage since Iron is MCAP: a folder holds ``metadata.yaml`` and one MCAP
file per split. Read through rosbags, such a folder lost what the same file given directly
keeps: its attachments and metadata records (``ros2 bag record`` writes a ``rosbag2``
record in every file; ``mcap add attachment`` adds a URDF), and each message's publish time
and sequence (rosbags yields the log time only). So the storage files are read with
:class:`~.mcap_reader.McapLogReader`, one per file, their messages merged in log-time order;
``metadata.yaml`` only names them. A folder this reader does not take (sqlite3 storage, a
file-compressed bag, a file missing) is read through rosbags as before
(:func:`mcap_storage_files` says which).
"""

from __future__ import annotations

import dataclasses
import heapq
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from pcainterp_stream.io.mcap_extras import ChannelInfo, McapExtras
from pcainterp_stream.io.mcap_reader import McapLogReader
from pcainterp_stream.io.reader_base import (
    MCAP_MAGIC,
    LogFormat,
    LogReader,
    TopicInfo,
    merge_topic,
)
from pcainterp_stream.records import RawMessage

__all__ = ["Rosbag2McapReader", "mcap_storage_files"]


def mcap_storage_files(folder: Path) -> list[Path] | None:
    """Return a rosbag2 folder's MCAP storage files, None when it is not such a folder.

    None (read the folder through rosbags) when ``metadata.yaml`` does not parse, names
    another storage, compresses whole files, lists no file, or a listed file is missing or
    does not start with the MCAP magic.
    """
    import yaml

    try:
        text = (folder / "metadata.yaml").read_text()
        info = yaml.safe_load(text)["rosbag2_bagfile_information"]
        if info.get("storage_identifier") != "mcap" or str(info.get("compression_mode") or ""):
            return None
        files = [folder / str(name) for name in info["relative_file_paths"]]
        for path in files:
            with path.open("rb") as f:
                if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                    return None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError, AttributeError):
        return None
    return files or None


class Rosbag2McapReader(LogReader):
    """Reads a rosbag2 folder's MCAP storage files as one log (see the module docstring).

    Damage and warnings name the storage file they were found in.
    """

    format = LogFormat.ROSBAG2

    def __init__(self, path: Path, files: list[Path]) -> None:
        super().__init__(path)
        self._parts = [McapLogReader(file) for file in files]
        for part in self._parts:  # one list for the folder: notes name their file
            part.damage = self.damage
            part.warnings = self.warnings

    def _open(self) -> None:
        try:
            for part in self._parts:
                part.open()
        except BaseException:
            self._close()
            raise

    def _close(self) -> None:
        for part in self._parts:
            part.close()

    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`: the topics of every storage file, counts summed."""
        self._check_open()
        topics: dict[str, TopicInfo] = {}
        for part in self._parts:
            for name, info in part.topics().items():
                topics[name] = merge_topic(topics.get(name), info)
        return topics

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """See :meth:`LogReader.message_stats`: None unless every file's index says so."""
        self._check_open()
        stats = [part.message_stats() for part in self._parts]
        if any(item is None for item in stats):
            return None
        count, starts, ends = 0, [], []
        for item in stats:
            assert item is not None
            count += item[0]
            starts += [item[1]] if item[1] is not None else []
            ends += [item[2]] if item[2] is not None else []
        if not count:
            return (0, None, None)
        return (count, min(starts), max(ends))

    def indexed(self) -> bool:
        """See :meth:`LogReader.indexed`: every storage file is."""
        self._check_open()
        return all(part.indexed() for part in self._parts)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """See :meth:`LogReader.messages`: each file's, merged by log time (file order on ties).

        The publish time and sequence are the storage file's.
        """
        self._check_open()
        wanted = None if topics is None else list(topics)
        streams = [part.messages(wanted) for part in self._parts]
        merged: Iterator[RawMessage] = (
            streams[0] if len(streams) == 1 else heapq.merge(*streams, key=_log_time)
        )
        yield from merged
        self.backward_log_times = max(part.backward_log_times for part in self._parts)

    def extras(self, *, verify: bool = False) -> McapExtras:
        """See :meth:`LogReader.extras`: every storage file's, in file order.

        A channel several files repeat (a split bag's) is listed once; each attachment
        names the file it is in.
        """
        self._check_open()
        channels: list[ChannelInfo] = []
        extras = McapExtras(self.path, channels)
        for part in self._parts:
            found = part.extras(verify=verify)
            channels += [channel for channel in found.channels if channel not in channels]
            extras.attachments.extend(
                dataclasses.replace(item, file=part.path) for item in found.attachments
            )
            extras.metadata.extend(found.metadata)
        return extras


def _log_time(raw: RawMessage) -> Any:
    return raw.log_time_ns
