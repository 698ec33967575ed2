"""What an MCAP log holds besides messages: attachments, metadata records, every channel.

``densify`` writes its output as a copy of the input plus its own channels; the message
readers yield messages only, so this module finds the rest of an MCAP input and writes it
into an MCAP output:

- **attachments** (a robot's URDF, calibration files): found from the summary's attachment
  index when the summary is complete, else by walking the file's top-level records (they
  never sit inside chunks). Only their headers are held; each one's data is read when it is
  copied, one at a time, so large attachments never pile up in memory.
- **metadata records** (name and key/values; rosbag2 writes some): read whole, they are small.
- **channels**, those without a single message too, as the reader yields their messages
  (:class:`ChannelInfo`), so that registering them in the output adds only the channels no
  message registers.

:meth:`McapLogReader.extras <pcainterp_stream.io.mcap_reader.McapLogReader.extras>` returns
an :class:`McapExtras`; :meth:`McapLogWriter.add_extras
<pcainterp_stream.io.logwriter.McapLogWriter.add_extras>` writes it through
:func:`write_extras`. Damage is reported, never raised: a damaged attachment or metadata
record is left out and named.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Metadata
from zlib_ng.zlib_ng import crc32

from pcainterp_stream.io import rosmsg

if TYPE_CHECKING:
    from mcap.writer import Writer as McapWriter

_RECORD_HEADER = struct.Struct("<BQ")  # opcode, record length
_TIMES = struct.Struct("<QQ")  # an attachment's log time, create time
_MAGIC_LENGTH = 8
_BLOCK = 1 << 20  # attachment data is read (and CRC-checked) 1 MiB at a time
_MAX_METADATA_BYTES = 1 << 26  # a metadata record claiming more than 64 MiB is damage


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of an input log as the reader yields its messages (``RawMessage`` fields).

    Attributes:
        topic: the channel's topic.
        message_encoding: ``cdr``, ``json``, ...
        schema_name: the schema's name, "" for a channel without schema.
        schema_encoding: ``ros2msg``, ``jsonschema``, ..., "" without schema.
        schema_data: the schema's bytes, b"" without schema.
        metadata: the channel's metadata (ROS 2 QoS profiles, ...).
    """

    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    metadata: dict[str, str]


@dataclass(frozen=True)
class AttachmentInfo:
    """An attachment of an MCAP file: its header, and where its data is.

    Attributes:
        name: its name (``robot.urdf``).
        media_type: its media type (``application/xml``), possibly "".
        log_time_ns: its log time (ns).
        create_time_ns: its creation time (ns), 0 when unknown.
        size: its data's length (bytes).
        offset: where its record starts in the file (bytes).
        data_offset: where its data starts in the file (bytes).
        crc: the CRC-32 the file states for the record's fields up to the data's end, 0
            when none.
        file: the MCAP file holding it when that is not :attr:`McapExtras.path` (one of a
            rosbag2 folder's storage files), else None.
    """

    name: str
    media_type: str
    log_time_ns: int
    create_time_ns: int
    size: int
    offset: int
    data_offset: int
    crc: int
    file: Path | None = None


@dataclass(frozen=True)
class McapExtras:
    """What an MCAP log holds besides its messages.

    Attributes:
        path: the log (an MCAP file, or a rosbag2 folder whose storage files are MCAP).
        channels: every channel, in channel-id order, as the reader yields its messages.
        attachments: the attachments, in file (or index) order.
        metadata: the metadata records, in file (or index) order.
    """

    path: Path
    channels: list[ChannelInfo] = field(default_factory=list)
    attachments: list[AttachmentInfo] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)


@dataclass
class FoundRecords:
    """The attachments and metadata records :func:`find_records` found, and the damage."""

    attachments: list[AttachmentInfo] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    damage: list[tuple[int, str]] = field(default_factory=list)
    """(byte offset, description) of each damaged record left out."""


def find_records(
    path: Path, indexed: tuple[Iterable[int], Iterable[int]] | None, *, verify: bool = False
) -> FoundRecords:
    """Find an MCAP file's attachments and metadata records.

    Args:
        path: the MCAP file.
        indexed: (attachment record offsets, metadata record offsets) from a complete
            summary's indexes, or None to walk the top-level records of the data section
            (they end at the data-end record, a footer, or the first damage to the framing,
            which the message reader reports).
        verify: read each attachment's data and check its CRC (a mismatch is damage).

    Returns:
        What was found; records that do not parse are left out and listed as damage.
    """
    found = FoundRecords()
    with path.open("rb") as f:
        size = f.seek(0, io.SEEK_END)
        if indexed is not None:
            attachments, metadata = indexed
            for offset in attachments:
                _take(f, size, offset, Opcode.ATTACHMENT, found, verify)
            for offset in metadata:
                _take(f, size, offset, Opcode.METADATA, found, verify)
            return found
        offset = _MAGIC_LENGTH
        while offset + _RECORD_HEADER.size <= size:
            f.seek(offset)
            opcode, length = _RECORD_HEADER.unpack(f.read(_RECORD_HEADER.size))
            if opcode in (Opcode.DATA_END, Opcode.FOOTER) or length > size - offset - 9:
                break
            if opcode in (Opcode.ATTACHMENT, Opcode.METADATA):
                _take(f, size, offset, opcode, found, verify)
            offset += _RECORD_HEADER.size + length
    return found


def _take(
    f: IO[bytes], size: int, offset: int, expected: int, found: FoundRecords, verify: bool
) -> None:
    """Parse the record at ``offset`` into ``found`` (or note it as damage)."""
    kind = "attachment" if expected == Opcode.ATTACHMENT else "metadata record"
    try:
        if not 0 <= offset <= size - _RECORD_HEADER.size:
            raise ValueError("it lies outside the file")
        f.seek(offset)
        opcode, length = _RECORD_HEADER.unpack(f.read(_RECORD_HEADER.size))
        if opcode != expected:
            raise ValueError(f"the index points to an opcode {opcode:#04x} record")
        if length > size - offset - _RECORD_HEADER.size:
            raise ValueError(f"its length {length} runs past the end of the file")
        if expected == Opcode.METADATA:
            if length > _MAX_METADATA_BYTES:
                raise ValueError(f"it claims {length} bytes")
            body = f.read(length)
            found.metadata.append(Metadata.read(ReadDataStream(io.BytesIO(body))))
        else:
            attachment = _attachment_header(f, offset, length)
            if verify:
                check_crc(f, attachment)
            found.attachments.append(attachment)
    except Exception as err:  # struct.error, EndOfFile, UnicodeDecodeError, ValueError
        detail = " ".join(str(err).split()) or type(err).__name__
        found.damage.append((offset, f"corrupt {kind} left out ({detail})"))


def _attachment_header(f: IO[bytes], offset: int, length: int) -> AttachmentInfo:
    """Parse an attachment record's header (``f`` just past the record's opcode and length).

    Raises:
        ValueError: a field runs past the record.
    """
    end = offset + _RECORD_HEADER.size + length
    log_time, create_time = _TIMES.unpack(f.read(_TIMES.size))
    name = _string(f, end)
    media_type = _string(f, end)
    (data_length,) = struct.unpack("<Q", f.read(8))
    data_offset = f.tell()
    if data_offset + data_length + 4 != end:
        raise ValueError(f"its data length {data_length} does not fit the record")
    f.seek(data_length, io.SEEK_CUR)
    (crc,) = struct.unpack("<I", f.read(4))
    return AttachmentInfo(
        name, media_type, log_time, create_time, data_length, offset, data_offset, crc
    )


def _string(f: IO[bytes], end: int) -> str:
    (length,) = struct.unpack("<I", f.read(4))
    if f.tell() + length > end:
        raise ValueError(f"a string of {length} bytes runs past the record")
    return f.read(length).decode()


def check_crc(f: IO[bytes], attachment: AttachmentInfo) -> None:
    """Check an attachment against its CRC, reading it 1 MiB at a time.

    The CRC covers the record's fields from its log time to the data's end.

    Raises:
        ValueError: the record does not match the CRC (or the file ends inside it).
    """
    if attachment.crc == 0:  # the writer did not compute one
        return
    start = attachment.offset + _RECORD_HEADER.size
    f.seek(start)
    value, left = 0, attachment.data_offset + attachment.size - start
    while left > 0:
        block = f.read(min(left, _BLOCK))
        if not block:
            raise ValueError("the file ends inside its data")
        value = crc32(block, value)
        left -= len(block)
    if value != attachment.crc:
        raise ValueError("CRC mismatch")


def attachment_data(path: Path, attachment: AttachmentInfo) -> bytes:
    """Return an attachment's data, read from the file.

    Raises:
        OSError: the file cannot be read.
        ValueError: the file ends inside the data.
    """
    with path.open("rb") as f:
        f.seek(attachment.data_offset)
        data = f.read(attachment.size)
    if len(data) != attachment.size:
        raise ValueError(f"{path} ends inside attachment {attachment.name}")
    return data


def write_extras(
    extras: McapExtras,
    writer: McapWriter | None,
    schema_id: Callable[[str, str, bytes], int],
    channel_id: Callable[[str, str, int, dict[str, str]], int],
) -> None:
    """Write an input's channels, metadata records and attachments into an MCAP output.

    Args:
        extras: what to write (:meth:`McapLogReader.extras`).
        writer: the output's open mcap writer.
        schema_id: registers a schema (name, encoding, data) once, returning its id (0 for
            none), as the output writer does for the messages it copies.
        channel_id: registers a channel (topic, message encoding, schema id, metadata) once,
            returning its id: a channel of the input is then registered once, whether this
            or its first message comes first.
    """
    assert writer is not None
    for channel in extras.channels:
        schema = schema_id(channel.schema_name, channel.schema_encoding, channel.schema_data)
        channel_id(channel.topic, channel.message_encoding, schema, channel.metadata)
    for record in extras.metadata:
        writer.add_metadata(record.name, dict(record.metadata))
    for attachment in extras.attachments:  # one at a time in memory
        writer.add_attachment(
            create_time=attachment.create_time_ns,
            log_time=attachment.log_time_ns,
            name=attachment.name,
            media_type=attachment.media_type,
            data=attachment_data(attachment.file or extras.path, attachment),
        )


def size_text(size: int) -> str:
    """Return a byte count for people.

    Examples:
        >>> size_text(20), size_text(2048), size_text(5_000_000)
        ('20 bytes', '2.0 KiB', '4.8 MiB')
    """
    if size < 1024:
        return f"{size} bytes"
    value = float(size)
    for unit in ("KiB", "MiB", "GiB"):
        value /= 1024
        if value < 1024 or unit == "GiB":
            break
    return f"{value:.1f} {unit}"


def filled_schema(name: str, encoding: str, data: bytes) -> bytes:
    """Return a schema's text to write: the standard ROS 2 definition for an empty one.

    A writer that lacked the definitions leaves ``ros2msg`` schemas of 0 bytes; the reader
    decodes their messages with the standard definition, and the copy writes it too, so
    that mcap_ros2 and viewers decode the copied topics (``CameraInfo()`` with no fields
    otherwise). A type the standard store does not know keeps its schema as it is.
    """
    if data or encoding != "ros2msg" or not name:
        return data
    if name not in rosmsg.TYPESTORE.fielddefs:
        return data
    return rosmsg.schema_text(name).encode()
