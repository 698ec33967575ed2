"""The MCAP reader: walks the records itself, one record and at most one chunk in memory.

It does not use ``mcap.reader``: that reader raises ``KeyError`` on files whose summary does
not repeat schemas and channels, and cannot resume after a corrupt chunk. The record classes
of the ``mcap`` package still parse the rare records (schemas, channels, summary); messages,
the hot path, are unpacked with :mod:`struct`. Damage is recorded, not raised.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    ChunkIndex,
    Footer,
    MetadataIndex,
    Schema,
    Statistics,
)
from zlib_ng.zlib_ng import crc32

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.mcap_extras import ChannelInfo, McapExtras, find_records
from pcainterp_stream.io.reader_base import (
    MCAP_MAGIC,
    ROS2_SCHEMA_ENCODINGS,
    LogFormat,
    LogReader,
    TopicInfo,
    _add_once,
    _one_line,
    _Ros1Converter,
    _TimeOrder,
    ros2_type_name,
)
from pcainterp_stream.records import RawMessage

_FOOTER_LENGTH = 9 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc

try:  # lz4 chunks are rare (the ROS 2 writers use zstd); lz4 is optional, as in mcap
    import lz4.frame as lz4_frame  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover - lz4 is installed with rosbags
    lz4_frame = None


_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


_RECORD_HEADER = struct.Struct("<BQ")  # opcode, record length


_CHUNK_HEADER = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc


_MAX_CHUNK_BYTES = 1 << 32  # refuse to inflate a chunk that claims more than 4 GiB


_MAX_SALVAGE_BYTES = 1 << 28  # read at most 256 MiB of a chunk cut short by truncation


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
        self._attachment_offsets: list[int] = []  # of the summary's attachment index
        self._metadata_offsets: list[int] = []  # of the summary's metadata index
        self._summary_complete = False
        self._topics: dict[str, TopicInfo] | None = None
        self._channel_records: tuple[list[Channel], dict[int, Schema]] = ([], {})
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
                elif opcode == Opcode.ATTACHMENT_INDEX:
                    self._attachment_offsets.append(AttachmentIndex.read(stream).offset)
                elif opcode == Opcode.METADATA_INDEX:
                    self._metadata_offsets.append(MetadataIndex.read(stream).offset)
                offset += 9 + length
        except Exception as err:  # struct.error, EndOfFile, UnicodeDecodeError...
            self._damage(offset, f"corrupt summary section ({_one_line(err)})")
            self._summary_channels.clear()
            self._summary_schemas.clear()
            self._statistics = None
            self._chunk_indexes.clear()
            self._attachment_offsets.clear()
            self._metadata_offsets.clear()
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
        self._channel_records = (channels, schemas)
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

    def indexed(self) -> bool:
        """See :meth:`LogReader.indexed`: chunks without a wanted topic are skipped unread."""
        self._check_open()
        indexes = self._chunk_indexes.values()
        return (
            self._summary_complete
            and not self.damage
            and bool(indexes)
            and all(index.message_index_offsets for index in indexes)
        )

    def extras(self, *, verify: bool = False) -> McapExtras:
        """Return what the log holds besides messages (:mod:`~pcainterp_stream.io.mcap_extras`).

        Every channel (those without messages too) as :meth:`messages` yields its messages,
        the attachments' headers and the metadata records: from the summary's indexes when
        the summary is complete, else by walking the file's top-level records. A record that
        does not parse (with ``verify``, an attachment whose data fails its CRC) is left out
        and added to :attr:`damage`.
        """
        self._check_open()
        stats = self._statistics
        indexed = None
        if (
            self._summary_complete
            and stats is not None
            and stats.attachment_count == len(self._attachment_offsets)
            and stats.metadata_count == len(self._metadata_offsets)
        ):
            indexed = (self._attachment_offsets, self._metadata_offsets)
        found = find_records(self.path, indexed, verify=verify)
        for offset, what in found.damage:
            self._damage(offset, what)
        return McapExtras(self.path, self._channel_infos(), found.attachments, found.metadata)

    def _channel_infos(self) -> list[ChannelInfo]:
        """Return every channel as :meth:`messages` yields its messages, in id order."""
        self.topics()  # reads the channel records of a log without a complete summary
        channels, schemas = self._channel_records
        infos: list[ChannelInfo] = []
        for channel in sorted(channels, key=lambda c: c.id):
            schema = schemas.get(channel.schema_id) if channel.schema_id != 0 else None
            msgtype, schema_encoding, message_encoding = self._channel_kind(channel, schema)
            name = schema.name if schema is not None else ""
            data = bytes(schema.data) if schema is not None else b""
            if schema is not None and schema.encoding == "ros1msg" and message_encoding == "cdr":
                try:  # converted to CDR as its messages are
                    data = self._ros1.schema(msgtype, schema.data.decode())[1]
                except Exception:  # a bad definition: its messages do not convert either
                    continue
                name = msgtype
            infos.append(
                ChannelInfo(
                    channel.topic,
                    message_encoding,
                    name,
                    schema_encoding,
                    data,
                    dict(channel.metadata),
                )
            )
        return infos

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
    if crc != 0 and crc32(records) != crc:
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
