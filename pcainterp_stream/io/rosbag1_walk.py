"""ROS 1 bags without a usable index, read record by record in file order.

A bag whose recorder was killed (``rosbag record``'s ``.bag.active`` file, a robot powered
off) has no index: its bag header says ``index_pos=0`` and the connection and chunk-info
records that end a bag were never written. rosbags refuses such a bag ("Bag is not
indexed"). This reader walks the records from the start instead, one chunk in memory at a
time, and stops at the first incomplete record. Bag format 2.0: a version line
``#ROSBAG V2.0``, then records of ``header_len (u32), header, data_len (u32), data``; a header
is ``field_len (u32), name=value`` fields, ``op`` giving the record kind. Connection records
(op 0x07) precede the first message of their connection, inside a chunk (op 0x05, its data
``none``, ``bz2`` or ``lz4`` compressed) or at the top level; message data records (op 0x02)
sit in chunks, or at the top level after the zero-size chunk header a killed ``rosbag
record`` leaves for the chunk it was writing uncompressed.

Messages come in file order, which is time order for a recorder's file (it writes its
chunks in time order). Damage is recorded, not raised: :func:`open_ros1_bag` opens an
indexed bag with rosbags and falls back to this reader when its index is missing or
unreadable.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, NamedTuple

from rosbags.rosbag1.reader import normalize

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.reader_base import (
    LogFormat,
    LogReader,
    TopicInfo,
    _add_once,
    _one_line,
    _Ros1Converter,
    _TimeOrder,
    merge_topic,
    ros1_channel_metadata,
    ros1_type_name,
    ros2_type_name,
)
from pcainterp_stream.io.rosbags_reader import (
    Ros1Definition,
    convert_ros1,
    judge_ros1_definition,
)
from pcainterp_stream.records import RawMessage

try:  # lz4 chunks: python-lz4 is installed with rosbags
    import lz4.frame as lz4_frame  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover
    lz4_frame = None

__all__ = ["BagHeader", "Ros1WalkReader", "open_ros1_bag", "read_bag_header"]

VERSION_LINE = b"#ROSBAG V2.0\n"

_OP_MESSAGE_DATA = 0x02
_OP_BAG_HEADER = 0x03
_OP_CHUNK = 0x05
_OP_CHUNK_INFO = 0x06
_OP_CONNECTION = 0x07

_U32 = struct.Struct("<I")
_TIME = struct.Struct("<II")  # sec, nsec

_MAX_HEADER_BYTES = 1 << 24  # a record header holds a few names (a definition is data)


@dataclass(frozen=True)
class BagHeader:
    """The bag header record of a ROS 1 bag.

    Attributes:
        index_pos: byte offset of the index section (0: the bag was never closed).
        conn_count: connections in the index (0 when unindexed).
        chunk_count: chunks in the index (0 when unindexed).
        encryptor: the encryptor plugin's name ("" for a plain bag).
        records_start: byte offset of the first record after the bag header.
        size: the file's size in bytes.
    """

    index_pos: int
    conn_count: int
    chunk_count: int
    encryptor: str
    records_start: int
    size: int


class _Connection(NamedTuple):
    conn_id: int
    topic: str
    msgtype: str  # ROS 2 spelling, as the bag names it
    msgdef: str
    latching: bool
    md5sum: str  # as recorded ("" when the record has none)

    @property
    def ros2_msgtype(self) -> str:
        """The type its messages have once converted (:func:`ros1_type_name`)."""
        return ros1_type_name(self.msgtype)


class _Message(NamedTuple):
    conn_id: int
    offset: int  # of the top-level record holding it (its chunk, or the message)
    time_ns: int
    data: memoryview  # ROS 1 serialized


class _Stop(Exception):
    """The walk ends here: the record at this offset is incomplete.

    Attributes:
        cause: what was found, worded to follow "read N messages up to byte B".
        cut: for a chunk cut short, (its header fields, the data it still has, its offset);
            else None.
    """

    def __init__(self, cause: str, cut: tuple[dict[str, bytes], bytes, int] | None = None) -> None:
        super().__init__(cause)
        self.cause = cause
        self.cut = cut


def _fields(header: bytes | memoryview) -> dict[str, bytes]:
    """Return a record header's ``name=value`` fields.

    Raises:
        ValueError: a field runs past the header or has no ``=``.
    """
    fields: dict[str, bytes] = {}
    position, end = 0, len(header)
    while position < end:
        if position + 4 > end:
            raise ValueError("header field length runs past the header")
        (length,) = _U32.unpack_from(header, position)
        position += 4
        if position + length > end:
            raise ValueError("header field runs past the header")
        name, sep, value = bytes(header[position : position + length]).partition(b"=")
        if not sep:
            raise ValueError("header field without '='")
        fields[name.decode("latin-1")] = value
        position += length
    return fields


def _uint(fields: dict[str, bytes], name: str, width: int) -> int:
    value = fields.get(name)
    if value is None or len(value) != width:
        raise ValueError(f"header field {name!r} missing or not {width} bytes")
    return int.from_bytes(value, "little")


def _op(fields: dict[str, bytes]) -> int:
    return _uint(fields, "op", 1)


def read_bag_header(path: Path) -> BagHeader | None:
    """Return the bag header of a ROS 1 bag, None when it cannot be read.

    Reads the version line and the first record only.
    """
    try:
        with path.open("rb") as f:
            size = path.stat().st_size
            if f.read(len(VERSION_LINE)) != VERSION_LINE:
                return None
            head = f.read(4)
            if len(head) < 4:
                return None
            (header_length,) = _U32.unpack(head)
            if header_length > min(_MAX_HEADER_BYTES, size):
                return None
            fields = _fields(f.read(header_length))
            if _op(fields) != _OP_BAG_HEADER:
                return None
            length_bytes = f.read(4)
            if len(length_bytes) < 4:
                return None
            (data_length,) = _U32.unpack(length_bytes)
            records_start = len(VERSION_LINE) + 4 + header_length + 4 + data_length
            return BagHeader(
                index_pos=_uint(fields, "index_pos", 8),
                conn_count=_uint(fields, "conn_count", 4),
                chunk_count=_uint(fields, "chunk_count", 4),
                encryptor=fields.get("encryptor", b"").decode("utf-8", "replace"),
                records_start=records_start,
                size=size,
            )
    except (OSError, ValueError):
        return None


def open_ros1_bag(path: Path) -> LogReader:
    """Open a ROS 1 bag: through rosbags' index, else (no usable index) in file order.

    Raises:
        LogReadError: the bag header is unreadable, or the bag is unreadable for another
            reason than its index (rosbags' error, one line).
    """
    from pcainterp_stream.io.rosbags_reader import RosbagsLogReader

    header = read_bag_header(path)
    reason = None if header is None else _index_problem(header)
    if reason is None:
        reader = RosbagsLogReader(path, LogFormat.ROS1)
        try:
            reader.open()
        except LogReadError:
            # the index unreadable, the records may be intact: read them; else rosbags' error
            reason = None if header is None else _unreadable_index(path, header)
            if reason is None:
                raise
        else:
            return reader
    assert header is not None
    walker = Ros1WalkReader(path, header, reason)
    walker.open()
    return walker


def _index_problem(header: BagHeader) -> str | None:
    """Describe why a bag's header points to no index, None when it points to one."""
    if header.encryptor:
        return None  # rosbags names the encryption it does not support
    if header.index_pos == 0:
        return "unindexed (recording cut off?)"
    # a bag without connections ends with its header; its (empty) index is at the end
    if header.index_pos > header.size or (
        header.index_pos == header.size and (header.conn_count or header.chunk_count)
    ):
        return f"index missing (the bag header puts it at byte {header.index_pos}: file cut short?)"
    return None


def _unreadable_index(path: Path, header: BagHeader) -> str | None:
    """Return a reason when rosbags' own ROS 1 reader fails on the bag's index or chunks.

    None when that reader opens the bag (the error was elsewhere: a message definition
    rosbags cannot parse, which reading in file order would not mend).
    """
    if header.encryptor:
        return None
    from rosbags.rosbag1 import Reader, ReaderError

    from pcainterp_stream.io.rosbags_reader import _rosbags_path

    try:
        with Reader(_rosbags_path(path, LogFormat.ROS1)):
            return None
    except ReaderError as err:
        return f"index unreadable ({_one_line(err)})"
    except Exception:  # anything else is not the index's fault
        return None


class Ros1WalkReader(LogReader):
    """Reads a ROS 1 bag record by record in file order (see the module docstring)."""

    format = LogFormat.ROS1

    def __init__(self, path: Path, header: BagHeader, reason: str) -> None:
        super().__init__(path)
        self._header = header
        self._reason = reason
        self._file: IO[bytes] | None = None
        self._ros1 = _Ros1Converter(self._warn_once)
        self._topics: dict[str, TopicInfo] | None = None
        self._definitions: dict[int, Ros1Definition] = {}  # judged as the indexed reader does
        # the index section starts at index_pos when there is one: stop there
        inside = 0 < header.index_pos <= header.size
        self._end = header.index_pos if inside else header.size

    def _open(self) -> None:
        try:
            self._file = self.path.open("rb")
        except OSError as err:
            raise LogReadError(f"cannot open {self.path}: {_one_line(err)}") from err

    def _close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def _damage(self, offset: int, what: str) -> None:
        _add_once(self.damage, f"{self.path.name}: {what} at byte {offset} of {self._header.size}")

    def topics(self) -> dict[str, TopicInfo]:
        """See :meth:`LogReader.topics`; reads the whole bag once (it has no index)."""
        self._check_open()
        if self._topics is None:
            connections: dict[int, _Connection] = {}
            counts: dict[int, int] = {}
            for item in self._walk():
                if isinstance(item, _Connection):
                    connections.setdefault(item.conn_id, item)
                else:
                    counts[item.conn_id] = counts.get(item.conn_id, 0) + 1
            topics: dict[str, TopicInfo] = {}
            for conn_id, connection in connections.items():
                judged = self._judged(connection)
                if judged.problem is not None:
                    _add_once(self.damage, judged.left_out(counts.get(conn_id, 0)))
                info = TopicInfo(
                    connection.topic,
                    connection.ros2_msgtype,
                    counts.get(conn_id, 0),
                    "cdr",
                    "ros2msg",
                )
                topics[connection.topic] = merge_topic(topics.get(connection.topic), info)
            self._topics = topics
        return self._topics

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """See :meth:`LogReader.messages`: file order, one chunk in memory at a time."""
        self._check_open()
        self.topics()  # one full walk first: the damage note says how far the bag reads
        wanted = None if topics is None else set(topics)
        connections: dict[int, _Connection] = {}
        unconverted: set[str] = set()  # topics noted as damage once
        order = _TimeOrder()
        for item in self._walk():
            if isinstance(item, _Connection):
                connections.setdefault(item.conn_id, item)
                continue
            offset, time_ns = item.offset, item.time_ns
            connection = connections.get(item.conn_id)
            if connection is None:
                self._damage(offset, f"message on connection {item.conn_id} before its definition")
                continue
            if wanted is not None and connection.topic not in wanted:
                continue
            judged = self._judged(connection)
            if judged.problem is not None:  # left out, said by topics()
                continue
            try:
                cdr, schema = convert_ros1(
                    self._ros1, item.data, connection.msgtype, judged, self._warn_once
                )
            except Exception as err:  # rosbags TypesysError, SerdeError, struct.error...
                if connection.topic not in unconverted:
                    unconverted.add(connection.topic)
                    self._damage(
                        offset,
                        f"ROS 1 messages on {connection.topic} do not convert "
                        f"({_one_line(err)}); the first",
                    )
                continue
            order.see(time_ns)
            yield RawMessage(
                topic=connection.topic,
                msgtype=connection.ros2_msgtype,
                schema_name=connection.ros2_msgtype,
                schema_encoding="ros2msg",
                schema_data=schema,
                message_encoding="cdr",
                channel_metadata=ros1_channel_metadata({}, latching=connection.latching),
                data=cdr,
                log_time_ns=time_ns,
                publish_time_ns=time_ns,
                sequence=0,
            )
        order.report(self)

    def _judged(self, connection: _Connection) -> Ros1Definition:
        """Judge a connection's definition once (:func:`judge_ros1_definition`), warning so."""
        judged = self._definitions.get(connection.conn_id)
        if judged is None:
            judged = judge_ros1_definition(
                self.path.name,
                connection.topic,
                connection.msgtype,
                connection.msgdef,
                connection.md5sum,
            )
            self._definitions[connection.conn_id] = judged
            if judged.warning is not None:
                self._warn_once(judged.warning)
        return judged

    # the walk ----------------------------------------------------------------------------
    def _walk(self) -> Iterator[_Connection | _Message]:
        """Yield the connections and messages of the bag in file order; note how far it read.

        Top-level records are read one at a time, their lengths checked against the bytes
        left (a garbage length cannot make it allocate); a chunk is inflated whole (the
        size its header states bounds the output). A corrupt chunk whose framing is intact
        is skipped; an incomplete record ends the walk, after the complete records a chunk
        cut short still holds.
        """
        assert self._file is not None
        f = self._file
        offset = self._header.records_start
        count = 0
        cause = ""
        while offset < self._end:
            try:
                fields, data_offset, data = self._record_at(f, offset)
                op = _op(fields)
                if op == _OP_CHUNK:
                    for item in self._chunk_items(fields, data, offset):
                        count += isinstance(item, _Message)
                        yield item
                elif op == _OP_CONNECTION:
                    yield _connection(fields, data)
                elif op == _OP_MESSAGE_DATA:
                    count += 1
                    yield _message(fields, offset, memoryview(data))
                elif op == _OP_CHUNK_INFO:
                    break  # the index section: everything before it has been read
            except _Stop as stop:
                cause = stop.cause
                if stop.cut is not None:  # a chunk cut short: its complete records
                    salvaged = 0
                    for item in self._chunk_items(*stop.cut, truncated=True):
                        salvaged += isinstance(item, _Message)
                        yield item
                    count += salvaged
                    if salvaged:
                        cause = f"{cause[:-1]}; {salvaged} messages read from it)"
                break
            except (ValueError, UnicodeDecodeError, IndexError) as err:
                cause = f" (then a corrupt record: {err})"
                break
            offset = data_offset + len(data)
        offset = min(offset, self._header.size)  # a bag header cut short: nothing read
        name = self.path.name
        _add_once(
            self.damage,
            f"{name}: {self._reason}: read {count} messages in file order up to byte {offset} "
            f"of {self._header.size}{cause}; rosbag reindex {name} restores its index",
        )

    def _record_at(self, f: IO[bytes], offset: int) -> tuple[dict[str, bytes], int, bytes]:
        """Read the record at ``offset``; return (header fields, data offset, data).

        Its length checked first, the data is read whatever the record (the few index
        records before a bag's index section are small).

        Raises:
            _Stop: the record is incomplete (a chunk cut short carries what it still has).
            ValueError: the header does not parse.
        """
        f.seek(offset)
        head = f.read(4)
        if len(head) < 4:
            raise _Stop(" (then the file ends inside a record header)")
        (header_length,) = _U32.unpack(head)
        if 4 + header_length + 4 > self._end - offset:
            raise _Stop(f" (then a record header of {header_length} bytes: cut short)")
        if header_length > _MAX_HEADER_BYTES:
            raise ValueError(f"a record header of {header_length} bytes")
        fields = _fields(f.read(header_length))
        (data_length,) = _U32.unpack(f.read(4))
        data_offset = offset + 4 + header_length + 4
        remaining = self._end - data_offset
        is_chunk = fields.get("op") == bytes([_OP_CHUNK])
        if data_length > remaining:
            what = "chunk" if is_chunk else "record"
            cut = (fields, f.read(remaining), offset) if is_chunk else None
            raise _Stop(
                f" (then a {what} of {data_length} bytes, {remaining} left: cut short)", cut
            )
        return fields, data_offset, f.read(data_length)

    def _chunk_items(
        self, fields: dict[str, bytes], data: bytes, offset: int, *, truncated: bool = False
    ) -> Iterator[_Connection | _Message]:
        """Yield the connections and messages of the chunk record at ``offset``.

        A corrupt chunk is skipped with a damage note; a ``truncated`` one (the file ends
        inside it, noted by the caller) yields the complete records at its start.
        """
        try:
            records = _inflate(fields, data, truncated=truncated)
        except Exception as err:  # bz2 OSError, lz4 RuntimeError, ValueError
            if not truncated:
                self._damage(offset, f"corrupt chunk skipped ({_one_line(err)})")
            return
        view = memoryview(records)
        position = 0
        while position < len(records):
            try:
                if position + 4 > len(records):
                    raise ValueError("record header length runs past the chunk")
                (header_length,) = _U32.unpack_from(records, position)
                start = position + 4
                if start + header_length + 4 > len(records):
                    raise ValueError("record header runs past the chunk")
                inner = _fields(view[start : start + header_length])
                (data_length,) = _U32.unpack_from(records, start + header_length)
                data_start = start + header_length + 4
                if data_start + data_length > len(records):
                    raise ValueError("record data runs past the chunk")
                position = data_start + data_length
                body = view[data_start:position]
                op = _op(inner)
                if op == _OP_CONNECTION:
                    yield _connection(inner, body)
                elif op == _OP_MESSAGE_DATA:
                    yield _message(inner, offset, body)
            except (ValueError, UnicodeDecodeError, IndexError) as err:
                if not truncated:
                    self._damage(
                        offset, f"corrupt record inside a chunk, rest of chunk skipped ({err})"
                    )
                return


def _connection(fields: dict[str, bytes], data: bytes | memoryview) -> _Connection:
    """Return the connection of a connection record (its data: a header of its type)."""
    conn_id = _uint(fields, "conn", 4)
    described = _fields(data)
    topic = fields.get("topic")
    msgtype = described.get("type")
    msgdef = described.get("message_definition")
    if not topic or not msgtype or msgdef is None:
        raise ValueError("connection record without topic, type or message_definition")
    latching = described.get("latching", b"").strip() not in (b"", b"0")
    return _Connection(
        conn_id,
        normalize(topic.decode()),
        ros2_type_name(msgtype.decode()),
        msgdef.decode(),
        latching,
        described.get("md5sum", b"").decode("utf-8", "replace").strip(),
    )


def _message(fields: dict[str, bytes], offset: int, data: memoryview) -> _Message:
    """Return the message of a message data record (header fields ``conn``, ``time``)."""
    time = fields.get("time")
    if time is None or len(time) != _TIME.size:
        raise ValueError("message record without an 8-byte time")
    sec, nsec = _TIME.unpack(time)
    return _Message(_uint(fields, "conn", 4), offset, sec * 1_000_000_000 + nsec, data)


MAX_CHUNK_BYTES = 1 << 30
"""The largest chunk the walker decompresses (rosbag record's chunks are 768 KiB)."""


def _inflate(fields: dict[str, bytes], data: bytes, *, truncated: bool) -> bytes:
    """Return the records of a chunk: ``data`` decompressed, at most its stated size.

    A ``truncated`` chunk gives what its data still decompresses to (complete compressed
    blocks); a complete one must decompress to exactly its stated size.

    Raises:
        ValueError: an unknown compression or a size that does not match.
        OSError, RuntimeError: the data does not decompress (bz2, lz4).
    """
    compression = fields.get("compression", b"").decode("utf-8", "replace")
    size = _uint(fields, "size", 4)
    if size == 0 and not data:  # the header a killed recorder left for the chunk it wrote
        return b""
    if size > MAX_CHUNK_BYTES:  # rosbag's chunks hold 768 KiB: a damaged size, not a chunk
        raise ValueError(f"chunk claims {size} bytes, more than {MAX_CHUNK_BYTES}")
    if compression == "none":
        records = data[:size]
        ended = len(data) == size
    elif compression in ("bz2", "lz4"):
        if compression == "bz2":
            decompressor = bz2.BZ2Decompressor()
        elif lz4_frame is not None:
            decompressor = lz4_frame.LZ4FrameDecompressor()
        else:  # pragma: no cover - python-lz4 is installed with rosbags
            raise ValueError("lz4 chunk but python-lz4 is not installed")
        records = decompressor.decompress(data, max_length=size)
        if not truncated and not decompressor.eof:  # the stream's end (bz2: its CRC) is
            records += decompressor.decompress(b"", max_length=1)  # checked when reached
        ended = decompressor.eof
    else:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    if not truncated and (len(records) != size or not ended):
        raise ValueError(f"chunk data does not hold the {size} bytes its header says")
    return bytes(records)
