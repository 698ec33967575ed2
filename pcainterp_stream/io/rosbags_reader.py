"""ROS 1 bags and rosbag2 folders or storage files, read through rosbags' ``AnyReader``.

ROS 1 messages are converted to CDR with a ``ros2msg`` schema, so the rest of the pipeline
sees one kind of log; damage is recorded, not raised.
"""

from __future__ import annotations

import io
import os
import sqlite3
from collections.abc import Iterable, Iterator
from pathlib import Path, PosixPath
from typing import IO, Any

from rosbags.highlevel import AnyReader

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.mcap_reader import _unlz4, _unzstd
from pcainterp_stream.io.reader_base import (
    MCAP_MAGIC,
    LogFormat,
    LogReader,
    TopicInfo,
    _add_once,
    _matches_humble,
    _one_line,
    _Ros1Converter,
    _TimeOrder,
    merge_topic,
    ros1_channel_metadata,
    ros1_type_name,
    ros2_type_name,
)
from pcainterp_stream.io.rosbag2_record import qos_yaml
from pcainterp_stream.records import RawMessage

try:  # lz4 chunks are rare (the ROS 2 writers use zstd); lz4 is optional, as in mcap
    import lz4.frame as lz4_frame  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover - lz4 is installed with rosbags
    lz4_frame = None


def _bound_rosbags_decompressors() -> None:
    """Make rosbags inflate lz4 and zstd chunks with :func:`_unlz4` and :func:`_unzstd`.

    rosbags inflates ROS 1 lz4 chunks with ``lz4.frame.decompress`` and rosbag2 MCAP chunks
    with it or ``zstandard.decompress``, which allocate the size a frame header states: one
    damaged header made a small bag allocate gigabytes. It looks its decompressors up per
    chunk in module tables; replacing the entries (idempotent; the same bytes for intact
    data) is the one place to bound them short of forking rosbags.
    """
    from rosbags.rosbag1 import reader as rosbag1_reader
    from rosbags.rosbag2 import storage_mcap

    # rosbags 0.11 names; if a release renames them, reading works unbounded as before
    # (and test_rosbags_decompressors_do_not_allocate_stated_sizes fails)
    ros1_table = getattr(rosbag1_reader, "decompressors", None)
    mcap_table = getattr(storage_mcap, "DECOMPRESSORS", None)
    if isinstance(ros1_table, dict) and lz4_frame is not None:
        ros1_table["lz4"] = _unlz4
    if isinstance(mcap_table, dict):
        if lz4_frame is not None:
            mcap_table["lz4"] = lambda data, _size: _unlz4(data)
        mcap_table["zstd"] = _unzstd


class RosbagsLogReader(LogReader):
    """Reads a ROS 1 bag, a rosbag2 folder or a lone ``.db3`` through rosbags' ``AnyReader``."""

    def __init__(self, path: Path, log_format: LogFormat) -> None:
        super().__init__(path)
        self.format = log_format
        self._reader: AnyReader | None = None
        self._ros1 = _Ros1Converter(self._warn_once)
        self._schemas: dict[str, bytes] = {}

    def _open(self) -> None:
        self._reader = self._open_any(self.path)
        try:
            self._check_connections()
            if self.format is LogFormat.ROSBAG2 and self.path.is_dir():
                self._check_folder_yields()
        except BaseException:
            self._close()
            raise

    def _check_connections(self) -> None:
        """Refuse a topic name that is not text; note a message count that is not a count.

        rosbags takes both from a rosbag2 folder's metadata.yaml as YAML gives them; a
        damaged file (a topic ``name: 12``, ``message_count: abc``) would otherwise fail
        later with a TypeError or ValueError. A bad count is damage (the messages are in the
        storage file and still read); :meth:`topics` reports it as unknown.
        """
        assert self._reader is not None
        where = "metadata.yaml" if self.path.is_dir() else "the storage file"
        for connection in self._reader.connections:
            topic, count = connection.topic, connection.msgcount
            if not isinstance(topic, str):
                raise LogReadError(
                    f"cannot read rosbag2 log {self.path}: {where} has a topic named {topic!r}, "
                    f"not text; fix {where}"
                )
            if _message_count(count) is None:
                _add_once(
                    self.damage,
                    f"{self.path.name}: {where} gives topic {topic} a message count of {count!r}",
                )

    def _open_any(self, path: Path) -> AnyReader:
        _bound_rosbags_decompressors()
        try:
            reader = AnyReader(
                [_rosbags_path(path, self.format)], default_typestore=rosmsg.TYPESTORE
            )
            reader.open()
        except Exception as err:  # AnyReaderError, ReaderError, sqlite3, yaml, OSError...
            raise LogReadError(self._open_error(path, err)) from err
        return reader

    def _open_error(self, path: Path, err: BaseException) -> str:
        text = _one_line(err)
        if self.format is LogFormat.ROS1:
            return (
                f"cannot read ROS 1 bag {path} ({text}); if it is damaged, "
                f"`rosbag reindex {path}` may repair it"
            )
        storage = _storage_files(path) if path.is_dir() else []
        if storage and "Could not parse" in str(err):
            return (
                f"cannot read rosbag2 folder {path}: rosbags cannot parse a message definition "
                f"in it ({text}); pass the storage file {storage[0]} to read it directly"
            )
        return f"cannot read rosbag2 log {path} ({text}); check metadata.yaml and the storage"

    def _check_folder_yields(self) -> None:
        """Work around rosbags' silent 0 messages when metadata.yaml's QoS differs."""
        assert self._reader is not None
        reader = self._reader
        if reader.message_count == 0:
            return
        try:
            first = next(iter(reader.messages()), None)
        except Exception as err:  # rosbags ReaderError, sqlite3.Error
            raise LogReadError(self._open_error(self.path, err)) from err
        if first is not None:
            return
        storage = _storage_files(self.path)
        if len(storage) != 1:
            _add_once(
                self.damage,
                f"{self.path.name}: metadata.yaml lists {reader.message_count} messages but "
                "none can be read through it",
            )
            return
        reader.close()
        self._reader = self._open_any(storage[0])
        _add_once(
            self.warnings,
            f"{self.path.name}: metadata.yaml does not match its storage file (rosbags reads no "
            f"messages through it); read {storage[0].name} directly",
        )

    def _close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def _schema(self, connection: Any) -> tuple[str, str, bytes]:
        """Return (ros2 type name, schema encoding, schema) of a connection.

        The schema is ``ros2msg`` text. A rosbag2 type whose definition the bag does not
        store and rosbags does not know (a custom type in a Humble sqlite3 bag) has none:
        its messages are copied with an empty schema (encoding and data ""), as rosbag2's
        own MCAP storage writes a type whose definition it lacks, with one warning.
        """
        assert self._reader is not None
        msgtype = ros2_type_name(str(connection.msgtype))
        if self.format is LogFormat.ROS1:  # named as converted: tf/tfMessage is tf2_msgs'
            schema = self._ros1.schema(msgtype, str(connection.msgdef.data))
            return ros1_type_name(msgtype), "ros2msg", schema
        schema = self._definition(msgtype)
        if not schema:
            _add_once(
                self.warnings,
                f"{self.path.name}: {connection.topic} has type {msgtype}, whose definition the "
                "bag does not store; copied without one (an empty schema, as rosbag2 records it)",
            )
            return msgtype, "", b""
        return msgtype, "ros2msg", schema

    def _definition(self, msgtype: str) -> bytes:
        """Return the ros2msg text of a rosbag2 type, b"" when rosbags cannot give one."""
        assert self._reader is not None
        if msgtype not in self._schemas:
            store = self._reader.typestore
            if _matches_humble(store, msgtype):
                self._schemas[msgtype] = rosmsg.schema_text(msgtype).encode()
            else:
                try:
                    text = str(store.generate_msgdef(msgtype, ros_version=2)[0])
                except Exception:  # rosbags TypesysError: the type (or a field's) is unknown
                    text = ""
                self._schemas[msgtype] = text.encode()
        return self._schemas[msgtype]

    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`."""
        self._check_open()
        assert self._reader is not None
        topics: dict[str, TopicInfo] = {}
        for connection in self._reader.connections:
            msgtype = ros2_type_name(str(connection.msgtype))
            if self.format is LogFormat.ROS1:
                msgtype = ros1_type_name(msgtype)
            count = _message_count(connection.msgcount)
            known = self.format is LogFormat.ROS1 or bool(self._definition(msgtype))
            topics[connection.topic] = merge_topic(
                topics.get(connection.topic),
                TopicInfo(connection.topic, msgtype, count, "cdr", "ros2msg" if known else ""),
            )
        return topics

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """See :meth:`LogReader.message_stats`."""
        self._check_open()
        assert self._reader is not None
        try:
            count = int(self._reader.message_count)
            if count == 0:
                return (0, None, None)
            return (count, int(self._reader.start_time), int(self._reader.end_time) - 1)
        except Exception:  # rosbags raises on bags without an index; count instead
            return None

    def indexed(self) -> bool:
        """See :meth:`LogReader.indexed`: a ROS 1 bag's connection index finds a topic's chunks."""
        return self.format is LogFormat.ROS1

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """See :meth:`LogReader.messages`."""
        self._check_open()
        assert self._reader is not None
        reader = self._reader
        wanted = None if topics is None else set(topics)
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not connections:
            return
        order = _TimeOrder()
        iterator = reader.messages(connections=connections)
        count = 0
        while True:
            try:
                item = next(iterator, None)
                if item is None:
                    break
                connection, timestamp, data = item
                msgtype, schema_encoding, schema = self._schema(connection)
                if self.format is LogFormat.ROS1:
                    data, schema = self._ros1.convert(  # the type and key _schema used
                        data,
                        ros2_type_name(str(connection.msgtype)),
                        str(connection.msgdef.data),
                        connection.topic,
                    )
                metadata = _connection_metadata(connection)
                if self.format is LogFormat.ROS1:
                    metadata = ros1_channel_metadata(
                        metadata, latching=bool(getattr(connection.ext, "latching", None))
                    )
            except (Exception, sqlite3.Error) as err:  # ReaderError, SerdeError, lz4/bz2...
                _add_once(
                    self.damage,
                    f"{self.path.name}: unreadable after message {count} ({_one_line(err)})",
                )
                break
            count += 1
            order.see(int(timestamp))
            yield RawMessage(
                topic=connection.topic,
                msgtype=msgtype,
                schema_name=msgtype,
                schema_encoding=schema_encoding,
                schema_data=schema,
                message_encoding="cdr",
                channel_metadata=metadata,
                data=bytes(data),
                log_time_ns=int(timestamp),
                publish_time_ns=int(timestamp),
                sequence=0,
            )
        order.report(self)


def _message_count(value: Any) -> int | None:
    """Return a connection's message count, None when it is not a count (damaged YAML)."""
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    return None


def _connection_metadata(connection: Any) -> dict[str, str]:
    """Return MCAP channel metadata for a rosbags connection (rosbag2 QoS as YAML text).

    rosbags hands older bags' QoS over as the YAML text rosbag2 stored, newer ones' parsed:
    those are written back in the numeric form rosbag2 writes and every release reads, so
    that a latched topic (``/tf_static``) replays latched from the output too.
    """
    qos = getattr(connection.ext, "offered_qos_profiles", None)
    if isinstance(qos, str) and qos:
        return {"offered_qos_profiles": qos}
    if isinstance(qos, list) and qos:
        try:
            return {"offered_qos_profiles": "\n".join(map(qos_yaml, qos))}
        except (AttributeError, TypeError, ValueError):
            return {}  # a form of a future rosbags: leave it out rather than guess
    return {}


class _ClampedReader(io.BufferedReader):
    """A binary file whose ``read(n)`` never asks for more than the bytes left in the file.

    CPython's ``read(n)`` allocates n bytes before it reads; rosbags reads record lengths
    from the file and passes them to ``read``, so a damaged length field of 2^31 made a few
    kB bag allocate 2 GiB (or fail with ``MemoryError`` under a memory limit). Clamping
    returns the same bytes (a read past the end is short either way).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__(io.FileIO(path, "rb"))
        self._size = os.fstat(self.fileno()).st_size

    def read(self, size: int | None = -1, /) -> bytes:
        """Read up to ``size`` bytes (all that is left when negative or None)."""
        if size is not None and size > 0:
            left = self._size - self.tell()
            if size > left:  # the file may have grown since it was opened
                self._size = os.fstat(self.fileno()).st_size
                size = max(0, min(size, self._size - self.tell()))
        return super().read(size)


class _RosbagsPath(PosixPath):
    """The path handed to rosbags: its binary files clamp reads (see :class:`_ClampedReader`).

    Paths made from it (a rosbag2 folder's storage files) are of this class too. rosbags
    also picks its reader by suffix (``.bag`` for ROS 1, ``.db3`` / ``.mcap`` for rosbag2
    storage); a file whose format was sniffed from its magic bytes gets the matching
    ``suffix`` here, whatever its name, so that ``drive`` (a ROS 1 bag without ``.bag``)
    reads as what it is.
    """

    forced_suffix: str | None = None

    @property
    def suffix(self) -> str:
        """Return the forced suffix when set, else the name's."""
        return self.forced_suffix if self.forced_suffix is not None else super().suffix

    def open(  # type: ignore[override]  # only "rb" differs; text and write modes as Path
        self,
        mode: str = "r",
        buffering: int = -1,
        encoding: str | None = None,
        errors: str | None = None,
        newline: str | None = None,
    ) -> IO[Any]:
        """Open the file; ``"rb"`` gives a :class:`_ClampedReader`."""
        if mode == "rb" and buffering == -1:
            return _ClampedReader(self)
        return super().open(mode, buffering, encoding, errors, newline)


def _rosbags_path(path: Path, log_format: LogFormat) -> Path:
    """Return ``path`` as a :class:`_RosbagsPath` (unchanged where that class cannot be)."""
    if not isinstance(path, PosixPath):  # pragma: no cover - Windows: no clamping
        return path
    wrapped = _RosbagsPath(path)
    if path.is_file():
        if log_format is LogFormat.ROS1:
            wrapped.forced_suffix = ".bag"
        elif path.suffix not in (".db3", ".mcap"):
            with path.open("rb") as f:
                head = f.read(len(MCAP_MAGIC))
            wrapped.forced_suffix = ".mcap" if head.startswith(MCAP_MAGIC) else ".db3"
    return wrapped


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file())
