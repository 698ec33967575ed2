"""ROS 1 bags and rosbag2 folders or storage files, read through rosbags.

A rosbag2 log is read through rosbags' ``AnyReader``; an indexed ROS 1 bag through rosbags'
ROS 1 ``Reader`` (its index and chunk headers), its chunks inflated here one at a time, so
that one damaged chunk, one message that does not convert or one topic whose definition
does not match its md5sum is skipped, counted and named, and the rest of the bag read.
ROS 1 messages are converted to CDR with a ``ros2msg`` schema, so the rest of the pipeline
sees one kind of log; damage is recorded, not raised.
"""

from __future__ import annotations

import functools
import heapq
import io
import os
import shlex
import sqlite3
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path, PosixPath
from typing import IO, Any, NamedTuple

import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinition, MessageDefinitionFormat
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32
from rosbags.typesys import Stores, get_typestore

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
    _store_from_msg,
    _TimeOrder,
    merge_topic,
    ros1_channel_metadata,
    ros1_type_name,
    ros2_type_name,
)
from pcainterp_stream.io.rosbag2_record import qos_yaml
from pcainterp_stream.io.rosbag2_wal import WalView
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


SQLITE_DAMAGE = ("disk I/O error", "database disk image is malformed", "file is not a database")
"""sqlite's words for a storage file it cannot read: damaged, truncated, or on a failing disk."""

class RosbagsLogReader(LogReader):
    """Reads a ROS 1 bag, a rosbag2 folder or a lone ``.db3`` through rosbags' ``AnyReader``."""

    def __init__(self, path: Path, log_format: LogFormat) -> None:
        super().__init__(path)
        self.format = log_format
        self._reader: AnyReader | Ros1Reader | None = None
        self._wal: WalView | None = None  # rosbag2 sqlite3: a WAL beside it merged in a copy
        self._ros1 = _Ros1Converter(self._warn_once)
        self._schemas: dict[str, bytes] = {}
        # ROS 1: the connections read (definitions mended), those left out and why
        self._connections: dict[int, Any] = {}
        self._definitions: dict[int, Ros1Definition] = {}
        self._left_out: dict[int, str] = {}
        self._topic_totals: dict[str, int] = {}  # messages per topic on connections read
        # ROS 1: messages skipped while reading, by cause: (chunk, offset)s and their line
        self._skipped: dict[str, set[tuple[int, int]]] = {}
        self._skip_lines: dict[str, str] = {}

    def _open(self) -> None:
        if self.format is LogFormat.ROSBAG2:
            self._wal = WalView(self.path)
        try:
            self._reader = self._open_any(self.path)
        except BaseException:
            self._close()
            raise
        try:
            if self.format is LogFormat.ROS1:
                self._check_ros1_definitions()
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

    def _open_any(self, path: Path) -> AnyReader | Ros1Reader:
        """Open rosbags' reader: ``AnyReader`` for rosbag2, its ROS 1 ``Reader`` for a bag.

        ``AnyReader`` refuses a whole ROS 1 bag when one connection's definition does not
        parse or does not match its md5sum (rosserial records an empty one); the ROS 1
        reader opens the index alone, and :meth:`_check_ros1_definitions` judges each
        connection.
        """
        _bound_rosbags_decompressors()
        reader: AnyReader | Ros1Reader
        try:
            if self.format is LogFormat.ROS1:
                reader = Ros1Reader(_rosbags_path(path, self.format))
            else:
                reader = AnyReader(
                    [_rosbags_path(self._wal_source(path), self.format)],
                    default_typestore=rosmsg.TYPESTORE,
                )
            reader.open()
        except Exception as err:  # AnyReaderError, ReaderError, sqlite3, yaml, OSError...
            raise LogReadError(self._open_error(path, err)) from err
        return reader

    def _wal_source(self, path: Path) -> Path:
        """Return where rosbags reads ``path`` from: a private copy with its WAL merged.

        See :mod:`pcainterp_stream.io.rosbag2_wal`; the notes go to the warnings (merged)
        or the damage (a WAL that could not be merged: its messages are not read).
        """
        if self._wal is None:
            return path
        self._wal.source()
        for note in self._wal.notes:
            _add_once(self.warnings, f"{self.path.name}: {note}" if path.is_dir() else note)
        for note in self._wal.failures:
            _add_once(self.damage, note)
        return self._wal.viewed(path)

    def _check_ros1_definitions(self) -> None:
        """Judge each ROS 1 connection's definition; leave out the topics it cannot decode.

        See :func:`judge_ros1_definition` (the walker of unindexed bags judges them so too):
        a definition that cannot decode its messages is replaced by ROS 1 Noetic's when
        that has the recorded md5sum, else the topic is left out, as damage, and the rest
        of the bag read.
        """
        assert isinstance(self._reader, Ros1Reader)
        counts = {c.id: len(self._reader.indexes.get(c.id, ())) for c in self._reader.connections}
        self._topic_totals = {}
        for connection in self._reader.connections:
            judged = judge_ros1_definition(
                self.path.name,
                connection.topic,
                str(connection.msgtype),
                str(connection.msgdef.data),
                str(connection.digest or ""),
            )
            if judged.warning is not None:
                _add_once(self.warnings, judged.warning)
            if judged.text != str(connection.msgdef.data):
                connection = connection._replace(
                    msgdef=MessageDefinition(MessageDefinitionFormat.MSG, judged.text)
                )
            self._connections[connection.id] = connection
            self._definitions[connection.id] = judged
            if judged.problem is None:
                continue
            self._left_out[connection.id] = judged.problem
            _add_once(
                self.damage,
                judged.left_out(counts[connection.id]),
            )
        for connection in self._connections.values():
            if connection.id not in self._left_out:
                self._topic_totals[connection.topic] = self._topic_totals.get(
                    connection.topic, 0
                ) + counts.get(connection.id, 0)

    def _open_error(self, path: Path, err: BaseException) -> str:
        said = str(err) if self._wal is None else self._wal.named(str(err))
        text = _one_line(err, said)
        if self.format is LogFormat.ROS1:
            return (
                f"cannot read ROS 1 bag {path} ({text}); if it is damaged, "
                f"`rosbag reindex {path}` may repair it"
            )
        storage = _storage_files(path) if path.is_dir() else []
        missing = _missing_parts(path) if path.is_dir() else None
        if missing is not None:
            absent, present = missing
            names = ", ".join(p.name for p in absent)
            listed = len(absent) + len(present)
            text = (
                f"cannot read rosbag2 folder {path}: metadata.yaml lists {listed} storage files "
                f"and {names} {'is' if len(absent) == 1 else 'are'} missing (an interrupted "
                "copy?); copy the missing part in"
            )
            if not present:
                return f"{text} (no part it lists is there)"
            parts = " ".join(shlex.quote(str(p)) for p in present)
            return (
                f"{text}, or pass the parts present instead of the folder to read them alone: "
                f"{parts}"
            )
        if storage and "Could not parse" in str(err):
            return (
                f"cannot read rosbag2 folder {path}: rosbags cannot parse a message definition "
                f"in it ({text}); pass the storage file {storage[0]} to read it directly"
            )
        if any(words in said for words in SQLITE_DAMAGE):
            return (
                f"cannot read rosbag2 log {path} ({text}): its storage file is damaged or "
                "cannot be read (an interrupted copy, a failing disk); copy the bag again"
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
        if self._wal is not None:
            self._wal.close()
            self._wal = None

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
        assert isinstance(self._reader, AnyReader)  # rosbag2 only
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
        wanted = None if topics is None else set(topics)
        if isinstance(self._reader, Ros1Reader):
            yield from self._ros1_messages(self._reader, wanted)
            return
        reader = self._reader
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
                metadata = _connection_metadata(connection)
            except (Exception, sqlite3.Error) as err:  # ReaderError, sqlite3, zstd...
                _add_once(
                    self.damage,
                    f"{self.path.name}: unreadable after message {count} ({_one_line(err)})",
                )
                break
            count += 1
            order.see(int(timestamp))
            yield _cdr_message(
                connection.topic, (msgtype, schema_encoding, schema), metadata, data, int(timestamp)
            )
        order.report(self)

    def _ros1_messages(self, bag: Ros1Reader, wanted: set[str] | None) -> Iterator[RawMessage]:
        """Yield an indexed ROS 1 bag's messages in log-time order, skipping what is damaged.

        The index (read at open) gives each message's time, chunk and offset in it; a chunk
        is inflated when its first message is due (one at a time, as rosbags does). A chunk
        that does not inflate, a message record that does not parse and a message that does
        not convert are skipped, each cause counted on one damage line; the walk goes on.
        """
        connections = [
            c
            for c in self._connections.values()
            if (wanted is None or c.topic in wanted) and c.id not in self._left_out
        ]
        if not connections:
            return
        order = _TimeOrder()
        chunk_sizes = {info.pos: sum(info.connection_counts.values()) for info in bag.chunk_infos}
        current: tuple[int, io.BytesIO | None] = (-1, None)
        bad_chunks: dict[int, str] = {}
        entries = heapq.merge(*(bag.indexes.get(c.id, []) for c in connections))
        for entry in entries:
            place = (entry.chunk_pos, entry.offset)
            if entry.chunk_pos in bad_chunks:
                continue
            if current[0] != entry.chunk_pos:
                try:
                    current = (entry.chunk_pos, io.BytesIO(_inflate_chunk(bag, entry.chunk_pos)))
                except Exception as err:  # ReaderError, bz2 OSError, lz4 RuntimeError...
                    bad_chunks[entry.chunk_pos] = _one_line(err)
                    current = (-1, None)
                    _add_once(
                        self.damage,
                        f"{self.path.name}: chunk at byte {entry.chunk_pos} unreadable "
                        f"({_one_line(err)}): its {chunk_sizes.get(entry.chunk_pos, 0)} "
                        "messages skipped",
                    )
                    continue
            assert current[1] is not None
            try:
                conn_id, data = _message_record(current[1], entry.offset)
                connection = self._connections[conn_id]
            except Exception as err:  # ReaderError, KeyError (an unknown connection)
                self._skip(
                    f"record {entry.chunk_pos}",
                    place,
                    "{n} of the "
                    f"{chunk_sizes.get(entry.chunk_pos, 0)} messages in the chunk at byte "
                    f"{entry.chunk_pos} unreadable ({_one_line(err)}); skipped",
                )
                continue
            if connection.id in self._left_out:
                continue
            try:
                msgtype, schema_encoding, schema = self._schema(connection)
                data, schema = convert_ros1(  # the type and key _schema used
                    self._ros1,
                    data,
                    ros2_type_name(str(connection.msgtype)),
                    self._definitions[connection.id],
                    self._warn_once,
                )
            except Exception as err:  # rosbags SerdeError, TypesysError, struct.error...
                total = self._topic_totals.get(connection.topic, 0)
                self._skip(
                    f"convert {connection.topic}",
                    place,
                    "{n} of the "
                    f"{total} messages on {connection.topic} do not convert "
                    f"({_one_line(err)}); skipped",
                )
                continue
            metadata = ros1_channel_metadata(
                _connection_metadata(connection),
                latching=bool(getattr(connection.ext, "latching", None)),
            )
            order.see(int(entry.time))
            yield _cdr_message(
                connection.topic,
                (msgtype, schema_encoding, schema),
                metadata,
                data,
                int(entry.time),
            )
        order.report(self)

    def _skip(self, cause: str, place: tuple[int, int], line: str) -> None:
        """Count a skipped message under ``cause``; its damage line says how many so far.

        ``line`` starts with ``{n}``, the count. A message is counted once however often the
        log is read (``place``: its chunk and offset); the cause's line is replaced as the
        count grows.
        """
        places = self._skipped.setdefault(cause, set())
        places.add(place)
        text = f"{self.path.name}: {line.replace('{n}', str(len(places)), 1)}"
        old = self._skip_lines.get(cause)
        self._skip_lines[cause] = text
        if old is not None and old in self.damage:
            self.damage[self.damage.index(old)] = text
        else:
            _add_once(self.damage, text)


def _inflate_chunk(bag: Ros1Reader, position: int) -> bytes:
    """Return the records of the ROS 1 chunk at ``position`` (its data, decompressed).

    Raises:
        ReaderError: the data is cut short; the decompressor's error when it does not inflate.
    """
    assert bag.bio is not None
    chunk = bag.chunks[position]
    bag.bio.seek(chunk.datapos)
    return chunk.decompressor(read_bytes(bag.bio, chunk.datasize))


def _message_record(chunk: io.BytesIO, offset: int) -> tuple[int, bytes]:
    """Return (connection id, data) of the message data record at ``offset`` of a chunk.

    Connection records before it are passed over, as rosbags' reader does.

    Raises:
        ReaderError: the records there do not parse or are no message data.
    """
    from rosbags.rosbag1 import ReaderError

    chunk.seek(offset)
    while True:
        header = Header.read(chunk)
        kind = header.get_uint8("op")
        if kind != RecordType.CONNECTION:
            break
        chunk.seek(read_uint32(chunk), os.SEEK_CUR)
    if kind != RecordType.MSGDATA:
        raise ReaderError("expected message data")
    return header.get_uint32("conn"), read_bytes(chunk, read_uint32(chunk))


class Ros1Definition(NamedTuple):
    """How the messages of a ROS 1 connection are read (see :func:`judge_ros1_definition`).

    Attributes:
        name: the bag's file name, which the lines about it start with.
        topic: the connection's topic.
        msgtype: its type as the bag names it (ROS 2 spelling).
        text: the definition its messages are converted with (the bag's or Noetic's).
        problem: what is wrong with the bag's definition when neither decodes its messages
            (the topic is left out), else None.
        warning: the warning of a definition read though its md5sum is not the recorded one.
        fallback: ROS 1 Noetic's definition of the recorded md5sum, for the messages a whole
            definition that contradicts that md5sum does not fit; else None.
    """

    name: str
    topic: str
    msgtype: str
    text: str
    problem: str | None = None
    warning: str | None = None
    fallback: str | None = None

    def left_out(self, count: int) -> str:
        """The damage line of a topic left out: ``count`` messages not decoded."""
        return (
            f"{self.name}: {self.topic} ({count} messages of {self.msgtype}) left out: its "
            f"definition {self.problem}, so its messages cannot be decoded; the other topics "
            "are read"
        )


def judge_ros1_definition(
    name: str, topic: str, msgtype: str, text: str, digest: str
) -> Ros1Definition:
    """Judge a ROS 1 connection's definition ``text`` against its recorded md5sum ``digest``.

    Both ROS 1 readers (indexed, and the walker of unindexed bags) judge each connection so.
    A definition that does not parse, or is empty while the connection records the md5sum
    of another, cannot decode its messages. rosserial records the right md5sum with an
    empty definition: when ROS 1 Noetic's type of that name has that md5sum, its definition
    is used (what ``fix_msg_defs.py`` of rosbag does), with a warning; else the topic is
    left out (``problem``). A whole definition whose md5sum merely differs from the recorded
    one (a writer that computed it wrongly) is used, as rosbag itself reads it, with a
    warning; a message it does not fit is read with Noetic's definition when that has the
    recorded md5sum (``fallback``, :func:`convert_ros1`), else skipped and counted.
    ``name`` is the bag's file name.
    """
    problem, usable = _judge_definition(msgtype, text, digest)
    if problem is None:
        return Ros1Definition(name, topic, msgtype, text)
    noetic = _noetic_definition(msgtype, digest) if digest else None
    said = f"{name}: {topic}: the bag's definition of {msgtype} {problem}; read with"
    if usable:
        fit = "read with ROS 1 Noetic's definition, which has that md5sum"
        return Ros1Definition(
            name,
            topic,
            msgtype,
            text,
            warning=f"{said} the bag's definition (a message it does not fit is "
            f"{fit if noetic is not None else 'counted as damage'})",
            fallback=noetic,
        )
    if noetic is not None:
        return Ros1Definition(
            name,
            topic,
            msgtype,
            noetic,
            warning=f"{said} ROS 1 Noetic's definition, which has that md5sum",
        )
    return Ros1Definition(name, topic, msgtype, text, problem=problem)


def convert_ros1(
    converter: _Ros1Converter,
    data: bytes | memoryview,
    msgtype: str,
    definition: Ros1Definition,
    warn: Callable[[str], None],
) -> tuple[bytes, bytes]:
    """Return (CDR bytes, ros2msg schema) of a ROS 1 message of a judged connection.

    ``msgtype`` as :meth:`_Ros1Converter.convert` takes it. A message the definition does
    not fit is converted with the connection's ``fallback`` (Noetic's definition of the
    recorded md5sum) when it has one, warned of once through ``warn``.

    Raises:
        Exception: the definition's error (rosbags SerdeError ...) when neither fits.
    """
    topic = definition.topic
    try:
        return converter.convert(data, msgtype, definition.text, topic)
    except Exception as err:  # rosbags SerdeError, TypesysError, struct.error...
        failure = err
    if definition.fallback is not None:
        try:
            converted = converter.convert(data, msgtype, definition.fallback, topic)
        except Exception:  # neither fits: the bag's definition's error is the one to name
            pass
        else:
            warn(
                f"{definition.name}: {topic}: messages the bag's definition of "
                f"{definition.msgtype} does not fit are read with ROS 1 Noetic's definition, "
                "which has the md5sum recorded"
            )
            return converted
    raise failure


@functools.lru_cache(maxsize=1024)
def _judge_definition(msgtype: str, text: str, recorded: str) -> tuple[str | None, bool]:
    """What is wrong with a ROS 1 definition of ``msgtype``, whether it decodes (parsed once).

    (None, True) for a definition that parses and has the ``recorded`` md5sum, or when the
    connection records none to check it against.

    A bag repeats one definition on many connections, and a command opens a bag several
    times: parsing each anew made opening a bag of 300 connections twice as slow.
    """
    try:
        digest = str(_store_from_msg(text, msgtype).generate_msgdef(msgtype)[1])
    except Exception as err:  # rosbags TypesysError: the definition does not parse
        return f"does not parse ({_one_line(err)})", False
    if recorded and digest != recorded:
        if not text.strip():
            return (
                f"has md5sum {digest}, not the {recorded} recorded (it is empty, as rosserial "
                "records it)"
            ), False
        return f"has md5sum {digest}, not the {recorded} recorded", True
    return None, True


def _noetic_definition(msgtype: str, digest: str) -> str | None:
    """Return ROS 1 Noetic's definition of ``msgtype`` when its md5sum is ``digest``."""
    store = _noetic_store()
    if msgtype not in store.fielddefs:
        return None
    try:
        text, noetic_digest = store.generate_msgdef(msgtype)
    except Exception:  # pragma: no cover - the store's own types generate
        return None
    return str(text) if noetic_digest == digest else None


_NOETIC: list[Any] = []


def _noetic_store() -> Any:
    if not _NOETIC:
        _NOETIC.append(get_typestore(Stores.ROS1_NOETIC))
    return _NOETIC[0]


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


def _missing_parts(folder: Path) -> tuple[list[Path], list[Path]] | None:
    """Return (missing, present) storage files metadata.yaml lists; None if none is missing."""
    try:
        text = (folder / "metadata.yaml").read_text()
        info = yaml.safe_load(text)["rosbag2_bagfile_information"]
        listed = [folder / str(name) for name in info["relative_file_paths"]]
    except Exception:  # OSError, YAMLError, KeyError, TypeError: rosbags' error stands
        return None
    absent = [p for p in listed if not p.exists()]
    return (absent, [p for p in listed if p.exists()]) if absent else None


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file())


def _cdr_message(
    topic: str,
    schema: tuple[str, str, bytes],
    metadata: dict[str, str],
    data: bytes | bytearray | memoryview,
    time_ns: int,
) -> RawMessage:
    """A message of a bag as the readers hand it on: CDR, logged and published at ``time_ns``."""
    msgtype, encoding, text = schema
    return RawMessage(
        topic=topic,
        msgtype=msgtype,
        schema_name=msgtype,
        schema_encoding=encoding,
        schema_data=text,
        message_encoding="cdr",
        channel_metadata=metadata,
        data=bytes(data),
        log_time_ns=time_ns,
        publish_time_ns=time_ns,
        sequence=0,
    )
