"""The MCAP reader: walks the records itself, one record and at most one chunk in memory.

It does not use ``mcap.reader``: that reader raises ``KeyError`` on files whose summary does
not repeat schemas and channels, and cannot resume after a corrupt chunk. The record classes
of the ``mcap`` package still parse the rare records (schemas, channels, summary); messages,
the hot path, are unpacked with :mod:`struct`. Damage is recorded, not raised.
"""

from __future__ import annotations

import heapq
import io
import struct
from collections.abc import Iterable, Iterator
from operator import itemgetter
from pathlib import Path
from typing import IO, Any, NamedTuple

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
    merge_topic,
    ros1_channel_metadata,
    ros1_type_name,
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


class _MergePlan(NamedTuple):
    """How to read a file whose chunks overlap in time: the chunks by start time.

    Attributes:
        chunks: (message start time ns, offset, record length) of every chunk, sorted.
        definitions: (kind, schema or channel, offset) of the records outside chunks.
    """

    chunks: list[tuple[int, int, int]]
    definitions: list[tuple[str, Any, int]]


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
        self._ros1 = _Ros1Converter(self._warn_once)
        self._merge_plan: _MergePlan | None = None
        self._planned = False
        self._extras_damage = 0  # lines of damage found in attachments and metadata records

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

    def _message_damage(self) -> bool:
        """Whether damage touches the messages or their index (not an attachment's)."""
        return len(self.damage) > self._extras_damage

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
            topics[channel.topic] = merge_topic(
                topics.get(channel.topic),
                TopicInfo(channel.topic, msgtype, count, message_encoding, schema_encoding),
            )
        self._topics = topics
        return topics

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """See :meth:`LogReader.message_stats`."""
        self._check_open()
        stats = self._statistics
        if stats is None or self._message_damage():
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
            and not self._message_damage()
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
            self._extras_damage += 1  # the messages and their index are not touched
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
            metadata = dict(channel.metadata)
            if schema is not None and schema.encoding == "ros1msg" and message_encoding == "cdr":
                try:  # converted to CDR as its messages are
                    data = self._ros1.schema(ros2_type_name(schema.name), schema.data.decode())
                except Exception:  # a bad definition: its messages do not convert either
                    continue
                name = msgtype
                metadata = ros1_channel_metadata(metadata, latching=False)
            infos.append(
                ChannelInfo(
                    channel.topic,
                    message_encoding,
                    name,
                    schema_encoding,
                    data,
                    metadata,
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
                return ros1_type_name(msgtype), "ros2msg", "cdr"  # named as converted
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
        plan = self._plan_merge()
        records = self._records(wanted) if plan is None else self._merged_records(plan, wanted)
        for kind, record, offset in records:
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
        metadata = dict(channel.metadata)
        if schema is not None and schema.encoding == "ros1msg" and message_encoding == "cdr":
            try:
                data, schema_data = self._ros1.convert(
                    data, ros2_type_name(schema.name), schema.data.decode(), channel.topic
                )
            except Exception:  # rosbags SerdeError / TypesysError on a bad definition
                return None
            schema_name = msgtype
            metadata = ros1_channel_metadata(metadata, latching=False)
        return RawMessage(
            topic=channel.topic,
            msgtype=msgtype,
            schema_name=schema_name,
            schema_encoding=schema_encoding,
            schema_data=schema_data,
            message_encoding=message_encoding,
            channel_metadata=metadata,
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

    def _plan_merge(self) -> _MergePlan | None:
        """Return how to merge the chunks when file order is not log-time order, else None.

        The chunk index gives every chunk's time range. When, in file order, no chunk starts
        before an earlier one ended (a log written as it was recorded), file order is time
        order, up to the order inside a chunk, which :meth:`_chunk_records` sorts: None. A
        file written topic by topic, or merged from several recordings without sorting, has
        overlapping chunks: they are merged by :meth:`_merged_records`. Also None (file
        order) without a chunk index, after damage, or with messages outside chunks; a
        walk over the top-level records (headers only; chunks are skipped by seeking)
        checks for those.
        """
        if self._planned:
            return self._merge_plan
        self._planned = True
        if self._message_damage() or not self._chunk_indexes:
            return None
        latest_end = -1
        for offset in sorted(self._chunk_indexes):
            index = self._chunk_indexes[offset]
            if index.message_start_time < latest_end:
                break
            latest_end = max(latest_end, index.message_end_time)
        else:
            return None
        self._merge_plan = self._chunk_layout()
        return self._merge_plan

    def _chunk_layout(self) -> _MergePlan | None:
        """Walk the top-level records: the chunks and definitions, or None to read in order."""
        assert self._file is not None
        f = self._file
        size = self._size
        chunks: list[tuple[int, int, int]] = []
        definitions: list[tuple[str, Any, int]] = []
        offset = len(MCAP_MAGIC)
        f.seek(offset)
        while True:
            head = f.read(_RECORD_HEADER.size)
            if len(head) < _RECORD_HEADER.size:
                return None  # the walk in file order notes the damage
            opcode, length = _RECORD_HEADER.unpack(head)
            if length > size - offset - _RECORD_HEADER.size or opcode == Opcode.MESSAGE:
                return None
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                break
            if opcode == Opcode.CHUNK:
                if length < _CHUNK_HEADER.size:
                    return None
                start_ns = _CHUNK_HEADER.unpack(f.read(_CHUNK_HEADER.size))[0]
                chunks.append((start_ns, offset, length))
                f.seek(offset + _RECORD_HEADER.size + length)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                try:
                    kind, item = _parse_record(opcode, f.read(length))
                except Exception:  # struct.error, EndOfFile, UnicodeDecodeError
                    return None
                definitions.append((kind, item, offset))
            else:
                f.seek(length, io.SEEK_CUR)
            offset += _RECORD_HEADER.size + length
        chunks.sort()
        return _MergePlan(chunks, definitions)

    def _merged_records(
        self, plan: _MergePlan, wanted: set[str] | None
    ) -> Iterator[tuple[str, Any, int]]:
        """Yield the records as :meth:`_records` does, the messages in log-time order.

        A heap merge over the chunks (log time, then file position): a chunk is read and
        inflated when the merge reaches its start time and released when its last message
        is out, so memory holds the chunks that overlap the current time (for a file
        written topic by topic, one chunk per topic; a chunk whose messages span the whole
        log stays open, its messages released as they go out). Chunks without a wanted
        topic are skipped unread, as in file order.
        """
        assert self._file is not None
        f = self._file
        yield from plan.definitions
        heap: list[tuple[int, int, int, list[Any]]] = []  # next log time, offset, position
        chunks = plan.chunks
        next_chunk = 0
        while next_chunk < len(chunks) or heap:
            while next_chunk < len(chunks) and (not heap or chunks[next_chunk][0] <= heap[0][0]):
                _, offset, length = chunks[next_chunk]
                next_chunk += 1
                if self._skippable(offset, wanted):
                    continue
                f.seek(offset + _RECORD_HEADER.size)
                messages: list[Any] = []
                for kind, item, _ in self._chunk_records(f.read(length), offset):
                    if kind != "message":
                        yield kind, item, offset
                    elif wanted is None or self._wanted(item[0], wanted):
                        messages.append(item)
                if messages:
                    heapq.heappush(heap, (messages[0][2], offset, 0, messages))
            if not heap:
                continue
            _, offset, position, messages = heap[0]
            item = messages[position]
            messages[position] = None  # released once it is out
            position += 1
            if position < len(messages):
                heapq.heapreplace(heap, (messages[position][2], offset, position, messages))
            else:
                heapq.heappop(heap)
            yield "message", item, offset

    def _wanted(self, channel_id: int, wanted: set[str]) -> bool:
        """Return False for a message on a known channel of a topic not wanted."""
        channel = self._summary_channels.get(channel_id)
        return channel is None or channel.topic in wanted

    def _records(self, wanted: set[str] | None) -> Iterator[tuple[str, Any, int]]:
        """Yield (kind, record, offset) of schemas, channels and messages in file order.

        Kinds: ("schema", Schema), ("channel", Channel), ("message", (channel_id, sequence,
        log_time, publish_time, data)); offset is that of the top-level record (or chunk).

        The outer loop reads one record at a time (its length is checked against the bytes
        left, so a garbage length cannot make it allocate); damage inside a chunk skips that
        chunk. Damage to the framing (a record's opcode or length) ends the walk, unless the
        summary's chunk index lists the chunks: a chunk it lists at that offset is read with
        the length it gives, else the walk resumes at the next chunk it lists.
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
            indexed = self._indexed_chunk_length(offset, opcode, length)
            if indexed is not None:
                opcode, length = Opcode.CHUNK, indexed
            elif length > remaining and (resume := self._resume_after(offset)) is not None:
                self._damage(
                    offset,
                    f"{_opcode_name(opcode)} record claims {length} bytes but {remaining} remain "
                    f"(corrupt; the walk resumed at byte {resume}, the next chunk the summary's "
                    f"chunk index lists{self._chunks_between(offset, resume)})",
                )
                offset = resume
                f.seek(offset)
                continue
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

    def _indexed_chunk_length(self, offset: int, opcode: int, length: int) -> int | None:
        """Return the record length the chunk index gives a damaged chunk at ``offset``.

        None when the index lists no chunk there, or the record's opcode and length agree
        with it (the usual case), or its length does not fit in the file. A chunk whose
        opcode or length field is damaged is noted and read with the index's length (its
        CRC still checks its records).
        """
        index = self._chunk_indexes.get(offset)
        if index is None:
            return None
        indexed = index.chunk_length - _RECORD_HEADER.size
        if (opcode == Opcode.CHUNK and length == indexed) or not (
            0 < indexed <= self._size - offset - _RECORD_HEADER.size
        ):
            return None
        self._damage(
            offset,
            f"{_opcode_name(opcode)} record of {length} bytes where the summary's chunk index "
            f"lists a chunk of {indexed} (corrupt); read with the index's length",
        )
        return indexed

    def _chunks_between(self, start: int, end: int) -> str:
        """Say how many chunks the chunk index lists from ``start`` up to ``end`` (skipped)."""
        skipped = sum(start <= offset < end for offset in self._chunk_indexes)
        return f"; {skipped} chunks it lists skipped" if skipped else ""

    def _resume_after(self, offset: int) -> int | None:
        """Return the offset of the first chunk the chunk index lists after ``offset``."""
        later = [start for start in self._chunk_indexes if start > offset]
        return min(later) if later and min(later) < self._size else None

    def _chunk_records(
        self, body: bytes, offset: int, *, truncated: bool = False
    ) -> Iterator[tuple[str, Any, int]]:
        """Yield the records of one chunk: schemas and channels, then messages by log time.

        The messages are sorted by log time (stably: a chunk written in time order keeps its
        order), as the spec lets a writer store them in any order. Damage skips the rest of
        the chunk. A ``truncated`` chunk (the file ends inside it, already noted as damage)
        yields the complete records at its start and stops quietly at the cut.
        """
        try:
            records = _inflate_truncated_chunk(body) if truncated else _inflate_chunk(body)
        except Exception as err:  # zstd/lz4 errors, CRC mismatch, struct.error
            if not truncated:
                self._damage(offset, f"corrupt chunk skipped ({_one_line(err)})")
            return
        view = memoryview(records)
        # (log time, channel id, sequence, publish time, data start, data end)
        messages: list[tuple[int, int, int, int, int, int]] = []
        in_order = True
        last_time = 0
        position = 0
        while position < len(records):
            try:
                opcode, length = _RECORD_HEADER.unpack_from(records, position)
                start = position + _RECORD_HEADER.size
                if start + length > len(records):
                    raise ValueError(f"record length {length} runs past the chunk end")
                position = start + length
                if opcode == Opcode.MESSAGE:
                    if length < _MESSAGE_HEADER.size:
                        raise ValueError(f"message record of {length} bytes")
                    channel_id, sequence, log_time, publish_time = _MESSAGE_HEADER.unpack_from(
                        records, start
                    )
                    in_order = in_order and log_time >= last_time
                    last_time = log_time
                    data_start = start + _MESSAGE_HEADER.size
                    messages.append(
                        (log_time, channel_id, sequence, publish_time, data_start, position)
                    )
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    kind, item = _parse_record(opcode, view[start:position])
                    yield kind, item, offset
            except Exception as err:  # struct.error, UnicodeDecodeError, ValueError
                if not truncated:
                    self._damage(
                        offset,
                        f"corrupt record inside a chunk, rest of chunk skipped ({_one_line(err)})",
                    )
                break
        if not in_order:
            messages.sort(key=itemgetter(0))
        for log_time, channel_id, sequence, publish_time, data_start, data_end in messages:
            data = records[data_start:data_end]
            yield "message", (channel_id, sequence, log_time, publish_time, data), offset


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
