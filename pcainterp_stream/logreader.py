"""Read recorded logs (MCAP, ROS 1 bags, rosbag2 folders) as a stream of raw messages.

:func:`open_log` looks at a path and returns an opened :class:`LogReader`, a context manager
in the manner of rosbags' ``AnyReader``. Every reader yields :class:`~records.RawMessage`
records in file order with bounded memory, and normalises what it yields so that the rest
of the pipeline sees one kind of log: ROS messages are CDR with a ``ros2msg`` schema and
type names in ROS 2 spelling (``sensor_msgs/msg/Image``), whatever the input format.

Damaged input is read as far as it can be: the reader yields every message before the
damage, then stops (or skips a damaged chunk whose framing is intact) and records a
one-line description in :attr:`LogReader.damage`. Only a path that is not a log at all, or
one that cannot be read from its start, raises :class:`~errors.LogReadError`. No library
exception escapes as such.

The MCAP reader walks the records itself (one record, at most one chunk, in memory at a
time) rather than through ``mcap.reader``: that reader raises ``KeyError`` on files whose
summary does not repeat schemas and channels, and cannot resume after a corrupt chunk.
The record classes of the ``mcap`` package still parse the rare records (schemas, channels,
summary); messages, the hot path, are unpacked with :mod:`struct`.
"""

from __future__ import annotations

import io
import os
import sqlite3
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from enum import Enum
from pathlib import Path, PosixPath
from types import TracebackType
from typing import IO, Any

import cv2
import numpy as np
import numpy.typing as npt
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Footer, Schema, Statistics
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pcainterp_stream import rosmsg
from pcainterp_stream.errors import LogReadError, TopicNotFoundError
from pcainterp_stream.records import RawMessage

try:  # lz4 chunks are rare (the ROS 2 writers use zstd); lz4 is optional, as in mcap
    import lz4.frame as lz4_frame  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover - lz4 is installed with rosbags
    lz4_frame = None

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"

_FOOTER_LENGTH = 9 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc
_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_RECORD_HEADER = struct.Struct("<BQ")  # opcode, record length
_CHUNK_HEADER = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc
_MAX_CHUNK_BYTES = 1 << 32  # refuse to inflate a chunk that claims more than 4 GiB
_MAX_SALVAGE_BYTES = 1 << 28  # read at most 256 MiB of a chunk cut short by truncation

ROS2_SCHEMA_ENCODINGS = ("ros2msg", "ros2idl")
_LOG_KINDS = "an MCAP file, a ROS 1 .bag or a rosbag2 folder"


class LogFormat(Enum):
    """The container format of a log."""

    MCAP = "mcap"
    ROS1 = "ros1"
    ROSBAG2 = "rosbag2"


@dataclass(frozen=True)
class TopicInfo:
    """What a log says about one topic.

    Attributes:
        topic: topic name.
        msgtype: message type in ROS 2 spelling (``sensor_msgs/msg/Image``), or the schema
            name of a non-ROS channel ("" when the channel has no schema).
        message_count: number of messages, or None when the log does not index it.
        message_encoding: encoding of the messages as this reader yields them (``cdr`` for
            every ROS message; the input's encoding for others, e.g. ``json``).
        schema_encoding: ``ros2msg`` for ROS messages, else the input's.
    """

    topic: str
    msgtype: str
    message_count: int | None
    message_encoding: str
    schema_encoding: str


def ros2_type_name(name: str) -> str:
    """Return a type name in ROS 2 spelling (``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``)."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


# --- type layouts -------------------------------------------------------------------------


def _layout(store: Typestore, typename: str) -> Any:
    """Return a hashable wire layout of a type: field kinds in order, names lower-cased.

    Two types with equal layouts serialize to the same bytes, so a message written with one
    can be read with the other (ROS 1's ``CameraInfo.K`` is ROS 2's ``k``).
    """

    def node(desc: Any) -> Any:
        kind, detail = desc
        name = getattr(kind, "name", str(kind))
        if name == "NAME":
            return ("msg", _layout(store, str(detail)))
        if name in ("ARRAY", "SEQUENCE"):
            inner, count = detail
            return (name, node(inner), count)
        return (name, detail)

    fields = store.fielddefs[typename][1]
    return tuple((str(field).lower(), node(desc)) for field, desc in fields)


def _matches_humble(store: Typestore, typename: str) -> bool:
    """Return True when ``typename`` in ``store`` has the wire layout of the Humble type."""
    if typename not in rosmsg.TYPESTORE.fielddefs:
        return False
    try:
        return bool(_layout(store, typename) == _layout(rosmsg.TYPESTORE, typename))
    except KeyError:
        return False


def _store_from_msg(text: str, typename: str, *, ros2_header: bool = False) -> Typestore:
    """Build a typestore from a (concatenated) ``.msg`` definition.

    Args:
        text: message definition with its dependencies (``MSG:`` separated), ROS 1 or 2.
        typename: the top-level type in ROS 2 spelling.
        ros2_header: replace ``std_msgs/msg/Header`` by the ROS 2 one (no ``seq``), which is
            what rosbags' ``ros1_to_cdr`` assumes when it drops ``seq`` on conversion.
    """
    types = dict(get_types_from_msg(text, typename))
    if ros2_header and "std_msgs/msg/Header" in types:
        types["std_msgs/msg/Header"] = rosmsg.TYPESTORE.fielddefs["std_msgs/msg/Header"]
        types.setdefault(
            "builtin_interfaces/msg/Time", rosmsg.TYPESTORE.fielddefs["builtin_interfaces/msg/Time"]
        )
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store


class _Ros1Converter:
    """Convert ROS 1 serialized messages to CDR with a ``ros2msg`` schema, per type."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, str], tuple[Typestore, bytes]] = {}

    def schema(self, typename: str, msgdef: str) -> tuple[Typestore, bytes]:
        """Return (conversion typestore, ros2msg schema text) for a ROS 1 type definition.

        Types whose layout equals the ROS 2 Humble type (after dropping ``Header.seq``) get
        Humble's schema text, so that they read as the ROS 2 type downstream; others get a
        schema generated from the bag's own definition.
        """
        key = (typename, msgdef)
        if key not in self._cache:
            store = _store_from_msg(msgdef, typename, ros2_header=True)
            if _matches_humble(store, typename):
                text = rosmsg.schema_text(typename)
            else:
                text = str(store.generate_msgdef(typename, ros_version=2)[0])
            self._cache[key] = (store, text.encode())
        return self._cache[key]

    def convert(self, data: bytes | memoryview, typename: str, msgdef: str) -> tuple[bytes, bytes]:
        """Return (CDR bytes, ros2msg schema) of one ROS 1 serialized message."""
        store, text = self.schema(typename, msgdef)
        return bytes(store.ros1_to_cdr(data, typename)), text


# --- the reader interface -----------------------------------------------------------------


class LogReader:
    """A log opened for reading; use :func:`open_log` to get one.

    Attributes:
        path: the path given to :func:`open_log`.
        format: the container format.
        damage: one-line descriptions of damage found so far (file and byte offset); grows
            while :meth:`messages` runs.
        warnings: one-line notes that are not damage (non-monotonic log times, a fallback).
    """

    format: LogFormat

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: list[str] = []
        self.warnings: list[str] = []
        self._is_open = False
        self._decoders: dict[tuple[str, str, bytes], Typestore] = {}

    # context manager -------------------------------------------------------------------
    def open(self) -> None:
        """Open the log (idempotent)."""
        if not self._is_open:
            self._open()
            self._is_open = True

    def close(self) -> None:
        """Close the log and release the file (idempotent)."""
        if self._is_open:
            self._close()
            self._is_open = False

    def __enter__(self) -> LogReader:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if not self._is_open:
            raise LogReadError(f"log {self.path} is closed; use it inside `with open_log(...)`")

    # content ----------------------------------------------------------------------------
    def topics(self) -> dict[str, TopicInfo]:
        """Return topic -> :class:`TopicInfo` for every topic of the log, in log order.

        For an MCAP file without a usable summary this reads the whole file once.
        """
        raise NotImplementedError

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Yield the messages of the log in file order, with bounded memory.

        Args:
            topics: yield only these topics (all when None).

        Yields:
            One :class:`~records.RawMessage` per message. Damage met on the way is appended
            to :attr:`damage` and ends (or, for a corrupt chunk with intact framing, skips
            part of) the stream; it never raises a library exception.
        """
        raise NotImplementedError

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """Return (message count, first log time ns, last log time ns) from an index.

        None when the log has no index that says so (then count with :meth:`messages`).
        """
        return None

    def require_topics(self, options: dict[str, str]) -> None:
        """Check that topics exist, for a command-line option each.

        Args:
            options: topic -> the option that names it (``{"/stereo/left/image_rect":
                "--left-topic"}``).

        Raises:
            TopicNotFoundError: for the first topic not in the log, naming the topics present
                and the option to pass.
        """
        present = self.topics()
        for topic, option in options.items():
            if topic not in present:
                listed = ", ".join(sorted(present)) or "none"
                raise TopicNotFoundError(
                    f"topic {topic} not found in {self.path.name}; topics present: {listed}; "
                    f"pass {option}"
                )

    def decode(self, raw: RawMessage) -> Any:
        """Deserialize a CDR message into a rosbags typestore message object.

        Schemas that have the wire layout of a ROS 2 Humble type decode with
        :data:`rosmsg.TYPESTORE`; others with a typestore built from the schema text (cached
        per schema).

        Raises:
            LogReadError: for a non-CDR message, a schema that cannot be parsed, or data that
                does not deserialize with its schema.
        """
        where = f"message on {raw.topic} at log time {raw.log_time_ns} ns in {self.path.name}"
        if raw.message_encoding != "cdr" or raw.schema_encoding not in ROS2_SCHEMA_ENCODINGS:
            raise LogReadError(
                f"cannot decode {where}: encoding {raw.message_encoding!r} with schema "
                f"{raw.schema_encoding!r} is not ROS 2 CDR; only CDR with ros2msg is decoded"
            )
        store = self._decoder_store(raw, where)
        try:
            return store.deserialize_cdr(raw.data, raw.msgtype)
        except Exception as err:  # rosbags raises SerdeError, struct.error, IndexError...
            raise LogReadError(
                f"cannot decode {where} as {raw.msgtype}: {_one_line(err)}; the data does not "
                "match its schema (damaged message?)"
            ) from err

    def _decoder_store(self, raw: RawMessage, where: str) -> Typestore:
        key = (raw.msgtype, raw.schema_encoding, raw.schema_data)
        store = self._decoders.get(key)
        if store is not None:
            return store
        humble = raw.msgtype in rosmsg.TYPESTORE.fielddefs
        if humble and raw.schema_data == rosmsg.schema_text(raw.msgtype).encode():
            store = rosmsg.TYPESTORE
        elif raw.schema_encoding != "ros2msg":
            if not humble:
                raise LogReadError(
                    f"cannot decode {where}: type {raw.msgtype} has a {raw.schema_encoding} "
                    "schema and is not a ROS 2 Humble type; write the log with ros2msg schemas"
                )
            store = rosmsg.TYPESTORE
        else:
            try:
                own = _store_from_msg(raw.schema_data.decode(), raw.msgtype)
            except Exception as err:  # rosbags TypesysError, UnicodeDecodeError
                raise LogReadError(
                    f"cannot decode {where}: its ros2msg schema {raw.schema_name!r} does not "
                    f"parse ({_one_line(err)})"
                ) from err
            store = rosmsg.TYPESTORE if _matches_humble(own, raw.msgtype) else own
        self._decoders[key] = store
        return store


def _one_line(err: BaseException) -> str:
    """Return an exception as one short line: its class and first line of text."""
    text = str(err).strip().splitlines()
    first = text[0] if text else ""
    if len(first) > 160:
        first = first[:157] + "..."
    return f"{type(err).__name__}: {first}" if first else type(err).__name__


def _add_once(notes: list[str], note: str) -> None:
    if note not in notes:
        notes.append(note)


class _TimeOrder:
    """Count messages whose log time goes back in time."""

    def __init__(self) -> None:
        self.last_ns: int | None = None
        self.backwards = 0

    def see(self, log_time_ns: int) -> None:
        if self.last_ns is not None and log_time_ns < self.last_ns:
            self.backwards += 1
        self.last_ns = log_time_ns

    def report(self, reader: LogReader) -> None:
        if self.backwards:
            _add_once(
                reader.warnings,
                f"{reader.path.name}: {self.backwards} messages have a log time earlier than "
                "the message before them (non-monotonic log times)",
            )


# --- MCAP ---------------------------------------------------------------------------------


class McapLogReader(LogReader):
    """Reads an MCAP file record by record (see the module docstring for why)."""

    format = LogFormat.MCAP

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self._file: IO[bytes] | None = None
        self._size = 0
        self._summary_channels: dict[int, Channel] = {}
        self._summary_schemas: dict[int, Schema] = {}
        self._statistics: Statistics | None = None
        self._chunk_indexes: dict[int, ChunkIndex] = {}
        self._summary_complete = False
        self._topics: dict[str, TopicInfo] | None = None
        self._ros1 = _Ros1Converter()

    def _open(self) -> None:
        try:
            self._file = self.path.open("rb")
            self._size = self.path.stat().st_size
            magic = self._file.read(len(MCAP_MAGIC))
        except OSError as err:
            raise LogReadError(f"cannot open {self.path}: {_one_line(err)}") from err
        if magic != MCAP_MAGIC:
            self._close()
            raise LogReadError(
                f"{self.path} is not an MCAP file (it does not start with the MCAP magic); "
                "pass an MCAP file, a ROS 1 .bag or a rosbag2 folder"
            )
        self._read_summary()

    def _close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def _damage(self, offset: int, what: str) -> None:
        _add_once(self.damage, f"{self.path.name}: {what} at byte {offset} of {self._size}")

    # summary ------------------------------------------------------------------------------
    def _read_summary(self) -> None:
        """Read the footer and summary section if they are intact; note damage otherwise."""
        assert self._file is not None
        size = self._size
        if size < 2 * len(MCAP_MAGIC) + _FOOTER_LENGTH:
            self._damage(size, "file too short for a footer (truncated)")
            return
        f = self._file
        f.seek(size - len(MCAP_MAGIC))
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            self._damage(size, "no MCAP magic at the end, no footer or summary (truncated)")
            return
        footer_offset = size - len(MCAP_MAGIC) - _FOOTER_LENGTH
        f.seek(footer_offset)
        head = f.read(_RECORD_HEADER.size)
        opcode, length = _RECORD_HEADER.unpack(head)
        if opcode != Opcode.FOOTER or length != _FOOTER_LENGTH - 9:
            self._damage(footer_offset, "no footer record before the end magic (corrupt)")
            return
        footer = Footer.read(ReadDataStream(io.BytesIO(f.read(length))))
        if footer.summary_start == 0:
            return  # a valid file without summary: read linearly
        if not len(MCAP_MAGIC) <= footer.summary_start <= footer_offset:
            self._damage(footer_offset, f"footer points to a summary at {footer.summary_start}")
            return
        f.seek(footer.summary_start)
        offset = footer.summary_start
        try:
            while offset < footer_offset:
                opcode, length = _RECORD_HEADER.unpack(f.read(_RECORD_HEADER.size))
                if length > footer_offset - offset - 9:
                    raise ValueError(f"record length {length} runs past the footer")
                stream = ReadDataStream(io.BytesIO(f.read(length)))
                if opcode == Opcode.SCHEMA:
                    schema = Schema.read(stream)
                    self._summary_schemas[schema.id] = schema
                elif opcode == Opcode.CHANNEL:
                    channel = Channel.read(stream)
                    self._summary_channels[channel.id] = channel
                elif opcode == Opcode.STATISTICS:
                    self._statistics = Statistics.read(stream)
                elif opcode == Opcode.CHUNK_INDEX:
                    index = ChunkIndex.read(stream)
                    self._chunk_indexes[index.chunk_start_offset] = index
                offset += 9 + length
        except Exception as err:  # struct.error, EndOfFile, UnicodeDecodeError...
            self._damage(offset, f"corrupt summary section ({_one_line(err)})")
            self._summary_channels.clear()
            self._summary_schemas.clear()
            self._statistics = None
            self._chunk_indexes.clear()
            return
        stats = self._statistics
        self._summary_complete = (
            stats is not None
            and len(self._summary_channels) >= stats.channel_count
            and len(self._summary_schemas) >= stats.schema_count
        )

    # topics -------------------------------------------------------------------------------
    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`."""
        self._check_open()
        if self._topics is not None:
            return self._topics
        if self._summary_complete and self._statistics is not None:
            counts: dict[int, int] = dict(self._statistics.channel_message_counts)
            channels = sorted(self._summary_channels.values(), key=lambda c: c.id)
            schemas = self._summary_schemas
            known_counts = bool(counts) or self._statistics.message_count == 0
        else:
            counts = {}
            channels_by_id: dict[int, Channel] = {}
            schemas_by_id: dict[int, Schema] = {}
            for kind, record, _ in self._records(None):
                if kind == "channel":
                    assert isinstance(record, Channel)
                    channels_by_id.setdefault(record.id, record)
                elif kind == "schema":
                    assert isinstance(record, Schema)
                    schemas_by_id.setdefault(record.id, record)
                elif kind == "message":
                    channel_id = int(record[0])
                    counts[channel_id] = counts.get(channel_id, 0) + 1
            channels = list(channels_by_id.values())
            schemas = schemas_by_id
            known_counts = True
        topics: dict[str, TopicInfo] = {}
        for channel in channels:
            schema = schemas.get(channel.schema_id)
            msgtype, schema_encoding, message_encoding = self._channel_kind(channel, schema)
            count = counts.get(channel.id, 0) if known_counts else None
            previous = topics.get(channel.topic)
            if previous is not None and count is not None and previous.message_count is not None:
                count += previous.message_count
            topics[channel.topic] = TopicInfo(
                channel.topic, msgtype, count, message_encoding, schema_encoding
            )
        self._topics = topics
        return topics

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """See :meth:`LogReader.message_stats`."""
        self._check_open()
        stats = self._statistics
        if stats is None or self.damage:
            return None
        if stats.message_count == 0:
            return (0, None, None)
        return (stats.message_count, stats.message_start_time, stats.message_end_time)

    @staticmethod
    def _channel_kind(channel: Channel, schema: Schema | None) -> tuple[str, str, str]:
        """Return (msgtype, schema encoding, message encoding) as this reader yields them."""
        if schema is None:
            return "", "", channel.message_encoding
        if schema.encoding in ROS2_SCHEMA_ENCODINGS or schema.encoding == "ros1msg":
            msgtype = ros2_type_name(schema.name)
            if schema.encoding == "ros1msg" and channel.message_encoding == "ros1":
                return msgtype, "ros2msg", "cdr"
            return msgtype, schema.encoding, channel.message_encoding
        return schema.name, schema.encoding, channel.message_encoding

    # messages -----------------------------------------------------------------------------
    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """See :meth:`LogReader.messages`."""
        self._check_open()
        wanted = None if topics is None else set(topics)
        channels: dict[int, Channel] = {}
        schemas: dict[int, Schema] = {}
        order = _TimeOrder()
        unknown_channels: set[int] = set()
        for kind, record, offset in self._records(wanted):
            if kind == "schema":
                assert isinstance(record, Schema)
                schemas[record.id] = record
            elif kind == "channel":
                assert isinstance(record, Channel)
                channels[record.id] = record
            elif kind == "message":
                channel_id, sequence, log_time, publish_time, data = record
                channel = channels.get(channel_id) or self._summary_channels.get(channel_id)
                if channel is None:
                    if channel_id not in unknown_channels:
                        unknown_channels.add(channel_id)
                        self._damage(offset, f"message on undefined channel id {channel_id}")
                    continue
                if wanted is not None and channel.topic not in wanted:
                    continue
                schema = None
                if channel.schema_id != 0:
                    schema = schemas.get(channel.schema_id) or self._summary_schemas.get(
                        channel.schema_id
                    )
                message = self._raw_message(channel, schema, sequence, log_time, publish_time, data)
                if message is None:
                    self._damage(offset, f"ROS 1 message on {channel.topic} does not convert")
                    continue
                order.see(log_time)
                yield message
        order.report(self)

    def _raw_message(
        self,
        channel: Channel,
        schema: Schema | None,
        sequence: int,
        log_time: int,
        publish_time: int,
        data: bytes,
    ) -> RawMessage | None:
        msgtype, schema_encoding, message_encoding = self._channel_kind(channel, schema)
        schema_name = schema.name if schema is not None else ""
        schema_data = bytes(schema.data) if schema is not None else b""
        if schema is not None and schema.encoding == "ros1msg" and message_encoding == "cdr":
            try:
                data, schema_data = self._ros1.convert(data, msgtype, schema.data.decode())
            except Exception:  # rosbags SerdeError / TypesysError on a bad definition
                return None
            schema_name = msgtype
        return RawMessage(
            topic=channel.topic,
            msgtype=msgtype,
            schema_name=schema_name,
            schema_encoding=schema_encoding,
            schema_data=schema_data,
            message_encoding=message_encoding,
            channel_metadata=dict(channel.metadata),
            data=data,
            log_time_ns=log_time,
            publish_time_ns=publish_time,
            sequence=sequence,
        )

    def _skippable(self, offset: int, wanted: set[str] | None) -> bool:
        """Return True when the chunk at ``offset`` has no message of a wanted topic."""
        if wanted is None or not self._summary_complete:
            return False
        index = self._chunk_indexes.get(offset)
        if index is None or not index.message_index_offsets:
            return False
        return not any(
            (channel := self._summary_channels.get(channel_id)) is None or channel.topic in wanted
            for channel_id in index.message_index_offsets
        )

    def _records(self, wanted: set[str] | None) -> Iterator[tuple[str, Any, int]]:
        """Yield (kind, record, offset) of schemas, channels and messages in file order.

        Kinds: ("schema", Schema), ("channel", Channel), ("message", (channel_id, sequence,
        log_time, publish_time, data)); offset is that of the top-level record (or chunk).

        The outer loop reads one record at a time (its length is checked against the bytes
        left, so a garbage length cannot make it allocate); damage inside a chunk skips that
        chunk, damage to the framing ends the walk.
        """
        assert self._file is not None
        f = self._file
        size = self._size
        offset = len(MCAP_MAGIC)
        f.seek(offset)
        while True:
            head = f.read(_RECORD_HEADER.size)
            if not head:
                self._damage(offset, "file ends without a data-end record or footer (truncated)")
                return
            if len(head) < _RECORD_HEADER.size:
                self._damage(offset, "file ends inside a record header (truncated)")
                return
            opcode, length = _RECORD_HEADER.unpack(head)
            remaining = size - offset - _RECORD_HEADER.size
            if length > remaining:
                self._damage(
                    offset,
                    f"{_opcode_name(opcode)} record claims {length} bytes but {remaining} remain "
                    "(truncated or corrupt)",
                )
                if opcode == Opcode.CHUNK and length <= _MAX_CHUNK_BYTES:
                    # a plausible length: the file was cut inside this chunk; keep the
                    # complete records it still holds
                    body = f.read(min(remaining, _MAX_SALVAGE_BYTES))
                    yield from self._chunk_records(body, offset, truncated=True)
                return
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                return
            if opcode == Opcode.CHUNK and self._skippable(offset, wanted):
                f.seek(length, io.SEEK_CUR)
            elif opcode in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.CHUNK):
                body = f.read(length)
                if opcode == Opcode.CHUNK:
                    yield from self._chunk_records(body, offset)
                else:
                    try:
                        item = _parse_record(opcode, body)
                    except Exception as err:  # struct.error, EndOfFile, UnicodeDecodeError
                        self._damage(
                            offset, f"corrupt {_opcode_name(opcode)} record ({_one_line(err)})"
                        )
                    else:
                        yield item[0], item[1], offset
            else:
                f.seek(length, io.SEEK_CUR)
            offset += _RECORD_HEADER.size + length

    def _chunk_records(
        self, body: bytes, offset: int, *, truncated: bool = False
    ) -> Iterator[tuple[str, Any, int]]:
        """Yield the records of one chunk; damage skips the rest of the chunk.

        A ``truncated`` chunk (the file ends inside it, already noted as damage) yields the
        complete records at its start and stops quietly at the cut.
        """
        try:
            records = _inflate_truncated_chunk(body) if truncated else _inflate_chunk(body)
        except Exception as err:  # zstd/lz4 errors, CRC mismatch, struct.error
            if not truncated:
                self._damage(offset, f"corrupt chunk skipped ({_one_line(err)})")
            return
        view = memoryview(records)
        position = 0
        while position < len(records):
            try:
                opcode, length = _RECORD_HEADER.unpack_from(records, position)
                start = position + _RECORD_HEADER.size
                if start + length > len(records):
                    raise ValueError(f"record length {length} runs past the chunk end")
                position = start + length
                if opcode in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
                    kind, item = _parse_record(opcode, view[start:position])
                else:
                    continue
            except Exception as err:  # struct.error, UnicodeDecodeError, ValueError
                if not truncated:
                    self._damage(
                        offset,
                        f"corrupt record inside a chunk, rest of chunk skipped ({_one_line(err)})",
                    )
                return
            yield kind, item, offset


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace("_", "-")
    except ValueError:
        return f"unknown (opcode {opcode:#04x})"


def _parse_record(opcode: int, body: bytes | memoryview) -> tuple[str, Any]:
    """Parse a message, schema or channel record body."""
    if opcode == Opcode.MESSAGE:
        channel_id, sequence, log_time, publish_time = _MESSAGE_HEADER.unpack_from(body, 0)
        data = bytes(body[_MESSAGE_HEADER.size :])
        return "message", (channel_id, sequence, log_time, publish_time, data)
    stream = ReadDataStream(io.BytesIO(bytes(body)))
    if opcode == Opcode.SCHEMA:
        return "schema", Schema.read(stream)
    return "channel", Channel.read(stream)


def _chunk_payload(body: bytes) -> tuple[int, int, str, bytes]:
    """Split a chunk record body into (uncompressed size, crc, compression, records data).

    The data is what the body holds, which is less than its length field for a cut chunk.
    """
    _, _, uncompressed_size, crc = _CHUNK_HEADER.unpack_from(body, 0)
    position = _CHUNK_HEADER.size
    (name_length,) = struct.unpack_from("<I", body, position)
    position += 4
    compression = body[position : position + name_length].decode()
    position += name_length + 8  # and the records length
    if position > len(body):
        raise ValueError("chunk header runs past the record")
    if uncompressed_size > _MAX_CHUNK_BYTES:
        raise ValueError(f"chunk claims {uncompressed_size} uncompressed bytes")
    return uncompressed_size, crc, compression, body[position:]


def _inflate_truncated_chunk(body: bytes) -> bytes:
    """Return the records a chunk cut short still holds (a prefix, not CRC-checked).

    Raises:
        ValueError: on an unusable header or an unsupported compression.
    """
    uncompressed_size, _, compression, data = _chunk_payload(body)
    if compression == "":
        records = data
    elif compression == "zstd":  # a streaming decompressor yields every complete block
        records = zstandard.ZstdDecompressor().decompressobj().decompress(data)
    elif compression == "lz4" and lz4_frame is not None:
        records = lz4_frame.LZ4FrameDecompressor().decompress(data)
    else:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    return bytes(records[:uncompressed_size])


def _inflate_chunk(body: bytes) -> bytes:
    """Return the uncompressed records of a chunk record body, CRC-checked.

    Raises:
        ValueError: on a bad length, an unknown compression or a CRC mismatch.
    """
    _, _, uncompressed_size, crc = _CHUNK_HEADER.unpack_from(body, 0)
    position = _CHUNK_HEADER.size
    (name_length,) = struct.unpack_from("<I", body, position)
    position += 4
    compression = body[position : position + name_length].decode()
    position += name_length
    (records_length,) = struct.unpack_from("<Q", body, position)
    position += 8
    if position + records_length > len(body):
        raise ValueError(f"chunk records length {records_length} runs past the record")
    if uncompressed_size > _MAX_CHUNK_BYTES:
        raise ValueError(f"chunk claims {uncompressed_size} uncompressed bytes")
    data = body[position : position + records_length]
    if compression == "":
        records = data
    elif compression == "zstd":
        records = _unzstd(data, uncompressed_size)
    elif compression == "lz4" and lz4_frame is not None:
        records = _unlz4(data)
    else:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    if len(records) != uncompressed_size:
        raise ValueError(f"chunk inflates to {len(records)} bytes, header says {uncompressed_size}")
    if crc != 0 and zlib.crc32(records) != crc:
        raise ValueError("chunk CRC mismatch")
    return bytes(records)


def _unzstd(data: bytes, uncompressed_size: int) -> bytes:
    """Decompress a chunk's zstd frame, allocating no more than it really holds.

    ``ZstdDecompressor.decompress`` allocates the size the frame header states before it
    decompresses (a header damaged to say 4 GiB allocates 4 GiB, whatever
    ``max_output_size``), and ``max_output_size`` when the header states none. So it is
    used only when the frame and the chunk header agree; a frame that states no size is
    streamed, at most ``uncompressed_size + 1`` bytes.

    Raises:
        ValueError: the frame states another size than the chunk header.
        zstandard.ZstdError: the data does not decompress.
    """
    content_size = zstandard.frame_content_size(data)  # -1: the frame does not say
    if content_size == uncompressed_size:
        return bytes(
            zstandard.ZstdDecompressor().decompress(data, max_output_size=uncompressed_size)
        )
    if content_size != -1:
        raise ValueError(
            f"zstd frame claims {content_size} bytes, chunk header says {uncompressed_size}"
        )
    parts: list[bytes] = []
    wanted = uncompressed_size + 1  # one more, to notice a frame longer than the header says
    with zstandard.ZstdDecompressor().stream_reader(data) as reader:
        while wanted > 0:
            part = reader.read(min(wanted, 1 << 20))
            if not part:
                break
            parts.append(part)
            wanted -= len(part)
    return b"".join(parts)


def _unlz4(data: bytes) -> bytes:
    """Decompress an lz4 frame, allocating no more than it really holds.

    ``lz4.frame.decompress`` allocates the content size the frame header states before it
    decompresses (a damaged header of 3 GiB allocates 3 GiB); the streaming decompressor
    grows its output with the data.

    Raises:
        ValueError: the frame ends early.
        RuntimeError: the data does not decompress (python-lz4's error).
    """
    assert lz4_frame is not None
    decompressor = lz4_frame.LZ4FrameDecompressor()
    records = bytes(decompressor.decompress(data))
    if not decompressor.eof:
        raise ValueError("lz4 frame ends early")
    return records


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


# --- ROS 1 bags and rosbag2 (rosbags) ------------------------------------------------------


class RosbagsLogReader(LogReader):
    """Reads a ROS 1 bag, a rosbag2 folder or a lone ``.db3`` through rosbags' ``AnyReader``."""

    def __init__(self, path: Path, log_format: LogFormat) -> None:
        super().__init__(path)
        self.format = log_format
        self._reader: AnyReader | None = None
        self._ros1 = _Ros1Converter()
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
            return f"cannot read ROS 1 bag {path} ({text}); check it with `rosbag check`"
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

    def _schema(self, connection: Any) -> tuple[str, bytes]:
        """Return (ros2 type name, ros2msg schema) of a connection."""
        assert self._reader is not None
        msgtype = ros2_type_name(str(connection.msgtype))
        if self.format is LogFormat.ROS1:
            return msgtype, self._ros1.schema(msgtype, str(connection.msgdef.data))[1]
        if msgtype not in self._schemas:
            store = self._reader.typestore
            if _matches_humble(store, msgtype):
                text = rosmsg.schema_text(msgtype)
            else:
                text = str(store.generate_msgdef(msgtype, ros_version=2)[0])
            self._schemas[msgtype] = text.encode()
        return msgtype, self._schemas[msgtype]

    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`."""
        self._check_open()
        assert self._reader is not None
        topics: dict[str, TopicInfo] = {}
        for connection in self._reader.connections:
            msgtype = ros2_type_name(str(connection.msgtype))
            previous = topics.get(connection.topic)
            count = _message_count(connection.msgcount)
            if previous is not None:
                count = None if count is None else _sum_counts(previous.message_count, count)
            topics[connection.topic] = TopicInfo(connection.topic, msgtype, count, "cdr", "ros2msg")
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
                msgtype, schema = self._schema(connection)
                if self.format is LogFormat.ROS1:
                    data, schema = self._ros1.convert(data, msgtype, str(connection.msgdef.data))
                metadata = _connection_metadata(connection)
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
                schema_encoding="ros2msg",
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


def _sum_counts(first: int | None, second: int) -> int | None:
    return None if first is None else first + second


def _connection_metadata(connection: Any) -> dict[str, str]:
    """Return MCAP channel metadata for a rosbags connection (rosbag2 QoS as YAML text)."""
    qos = getattr(connection.ext, "offered_qos_profiles", None)
    if isinstance(qos, str) and qos:
        return {"offered_qos_profiles": qos}
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


# --- opening --------------------------------------------------------------------------------


def sniff_format(path: str | Path) -> LogFormat:
    """Return the format of a log path, by its kind and magic bytes.

    Raises:
        LogReadError: the path does not exist or is not a log (with a hint for a KITTI folder).
    """
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path} does not exist; pass {_LOG_KINDS}")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return LogFormat.ROSBAG2
        storage = _storage_files(path)
        if looks_like_kitti(path):
            hint = "; it looks like a KITTI folder: convert it with `pcainterp import-kitti`"
        elif storage:
            hint = f"; pass its storage file {storage[0]} directly"
        else:
            hint = "; pass an MCAP file, a ROS 1 .bag or a rosbag2 folder (with metadata.yaml)"
        raise LogReadError(f"{path} is a folder but not a rosbag2 bag (no metadata.yaml){hint}")
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except OSError as err:
        raise LogReadError(f"cannot open {path}: {_one_line(err)}") from err
    if head.startswith(MCAP_MAGIC):
        return LogFormat.MCAP
    if head.startswith(ROS1_MAGIC):
        return LogFormat.ROS1
    if head.startswith(SQLITE_MAGIC):
        return LogFormat.ROSBAG2
    if not head:
        raise LogReadError(f"{path} is empty, not a log; pass {_LOG_KINDS}")
    suffix = {".mcap": "an MCAP file", ".bag": "a ROS 1 bag", ".db3": "a rosbag2 sqlite3 file"}
    expected = suffix.get(path.suffix.lower())
    what = (
        f"named like {expected} but does not start with its magic bytes"
        if expected
        else ("not a log (no MCAP, ROS 1 bag or SQLite magic bytes)")
    )
    raise LogReadError(f"{path} is {what}; pass an MCAP file, a ROS 1 .bag or a rosbag2 folder")


def looks_like_kitti(path: str | Path) -> bool:
    """Return True for a KITTI raw drive (``image_00/data``) or odometry sequence folder."""
    path = Path(path)
    if not path.is_dir():
        return False
    markers = [
        path / "image_00" / "data",
        path / "image_0",
        path / "sequences",
        path / "calib_cam_to_cam.txt",
    ]
    if any(p.exists() for p in markers):
        return True
    return any(child.is_dir() and child.name.endswith("_sync") for child in path.iterdir())


def open_log(path: str | Path) -> LogReader:
    """Open a log for reading: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder / ``.db3``.

    The reader is returned open; use it as a context manager to close it::

        with open_log("drive.mcap") as reader:
            for raw in reader.messages(["/stereo/left/image_rect"]):
                image = decode_image(reader.decode(raw))

    Raises:
        LogReadError: the path is missing, not a log, or unreadable from its start.
    """
    path = Path(path)
    log_format = sniff_format(path)
    reader: LogReader
    if log_format is LogFormat.MCAP:
        reader = McapLogReader(path)
    else:
        reader = RosbagsLogReader(path, log_format)
    reader.open()
    return reader


# --- images ---------------------------------------------------------------------------------


def decode_image(message: Any) -> npt.NDArray[np.generic]:
    """Decode a ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` into an array.

    Args:
        message: a typestore ``Image`` (mono8, rgb8, bgr8, mono16 and the other encodings of
            :data:`rosmsg.IMAGE_ENCODINGS`) or ``CompressedImage`` (png, jpeg).

    Returns:
        (H, W) grey or (H, W, 3) RGB array: uint8 for 8-bit encodings, uint16 for 16-bit
        ones (mono16 stays uint16), float32 for 32FC1.

    Raises:
        ValueError: for an unsupported encoding or format (named), or data that does not
            decode.
    """
    if hasattr(message, "encoding"):
        return rosmsg.image_array(message)
    image_format = str(getattr(message, "format", ""))
    kind = image_format.lower().replace(";", " ").split()
    known = {"png", "jpeg", "jpg"}
    if not known.intersection(kind) or "compresseddepth" in kind:
        raise ValueError(
            f"unsupported compressed image format {image_format!r}; supported: png, jpeg"
        )
    data = np.asarray(message.data, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"compressed image ({image_format}) of {data.size} bytes does not decode")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    elif image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return np.asarray(image)
