"""A rosbag2 folder whose storage is MCAP, read through its storage files.

ROS 2's default storage since Iron is MCAP: a folder holds ``metadata.yaml`` and one MCAP
file per split. Read through rosbags, such a folder lost what the same file given directly
keeps: its attachments and metadata records (``ros2 bag record`` writes a ``rosbag2``
record in every file; ``mcap add attachment`` adds a URDF), and each message's publish time
and sequence (rosbags yields the log time only). So the storage files are read with
:class:`~.mcap_reader.McapLogReader`, one per file, their messages merged in log-time order;
``metadata.yaml`` only names them. A bag recorded with zstd compression is read so too:
``--compression-mode message``, each message's payload decompressed; ``file``, each
storage file decompressed into the temporary folder first (as rosbags did). A folder this
reader does not take (sqlite3 storage, another compression, a file missing) is read
through rosbags as before (:func:`mcap_storage_files` says which).

:func:`lone_storage_problem` refuses the storage file of a compressed bag given without
its folder: only ``metadata.yaml`` says how its messages are compressed.
"""

from __future__ import annotations

import dataclasses
import errno
import heapq
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.mcap_extras import ChannelInfo, McapExtras
from pcainterp_stream.io.mcap_reader import McapLogReader
from pcainterp_stream.io.output_paths import private_folder, remove_private_folder
from pcainterp_stream.io.reader_base import (
    MCAP_MAGIC,
    LogFormat,
    LogReader,
    TopicInfo,
    _one_line,
    merge_topic,
)
from pcainterp_stream.records import RawMessage

__all__ = ["Rosbag2McapReader", "lone_storage_problem", "mcap_storage_files", "message_zstd"]

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
"""The first bytes of a zstd frame: a file-compressed storage file, a compressed message."""


def _bag_info(folder: Path) -> dict[str, Any] | None:
    """``metadata.yaml``'s ``rosbag2_bagfile_information`` of a folder, None when unreadable."""
    import yaml

    try:
        info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return None
    return info if isinstance(info, dict) else None


def compression(folder: Path) -> str:
    """A rosbag2 folder's compression, as ``metadata.yaml`` gives it.

    "" (none), "message" or "file" (zstd); "other" for another format or mode.
    """
    info = _bag_info(folder) or {}
    mode = str(info.get("compression_mode") or "").lower()
    if not mode or mode == "none":
        return ""
    form = str(info.get("compression_format") or "").lower()
    return mode if form == "zstd" and mode in ("message", "file") else "other"


def message_zstd(folder: Path) -> bool:
    """Whether a rosbag2 folder's ``metadata.yaml`` says its messages are zstd-compressed."""
    return compression(folder) == "message"


def mcap_storage_files(folder: Path) -> list[Path] | None:
    """Return a rosbag2 folder's MCAP storage files, None when it is not such a folder.

    None (read the folder through rosbags) when ``metadata.yaml`` does not parse, names
    another storage or a compression other than zstd by message or file, lists no file, or
    a listed file is missing or does not start with the MCAP magic (the zstd magic when
    files are compressed).
    """
    info = _bag_info(folder)
    mode = compression(folder)
    if info is None or info.get("storage_identifier") != "mcap" or mode == "other":
        return None
    magic = ZSTD_MAGIC if mode == "file" else MCAP_MAGIC
    try:
        files = [folder / str(name) for name in info["relative_file_paths"]]
        for path in files:
            with path.open("rb") as f:
                if f.read(len(magic)) != magic:
                    return None
    except (OSError, KeyError, TypeError):
        return None
    return files or None


class Rosbag2McapReader(LogReader):
    """Reads a rosbag2 folder's MCAP storage files as one log (see the module docstring).

    Damage and warnings name the storage file they were found in.
    """

    format = LogFormat.ROSBAG2

    def __init__(self, path: Path, files: list[Path], *, message_zstd: bool = False) -> None:
        super().__init__(path)
        self._files = files
        self._parts: list[McapLogReader] = []
        self._message_zstd = message_zstd  # each payload is a zstd frame (metadata.yaml)
        self._temporary: Path | None = None  # the files of a file-compressed bag, decompressed

    def _open(self) -> None:
        try:
            for file in self._files:
                part = McapLogReader(self._decompressed_file(file))
                part.damage = self.damage  # one list for the folder: notes name their file
                part.warnings = self.warnings
                self._parts.append(part)
                part.open()
        except BaseException:
            self._close()
            raise

    def _decompressed_file(self, file: Path) -> Path:
        """A storage file as MCAP: a file-compressed bag's (``NAME.mcap.zstd``) decompressed.

        It is decompressed into a private folder of the temporary folder (``TMPDIR``), as
        rosbags did, removed on close; the folder is named after the process and registered
        as a partial output (removed when a signal forces the end), and the folders of runs
        that were killed are removed first (as :mod:`.rosbag2_wal` does its copies). When
        the zstd frame gives its decompressed size and the temporary folder has not that
        much room, it is refused before writing.
        """
        with file.open("rb") as f:
            if f.read(len(ZSTD_MAGIC)) != ZSTD_MAGIC:
                return file
            f.seek(0)
            head = f.read(18)  # a frame header: its decompressed size when it says it
        import shutil
        import tempfile

        import zstandard

        base = Path(tempfile.gettempdir())
        plain = file.name.removesuffix(".zstd")
        try:
            size = zstandard.frame_content_size(head) if len(head) >= 6 else -1
        except zstandard.ZstdError:  # a header cut short or damaged: the copy says so below
            size = -1
        free = shutil.disk_usage(base).free if base.is_dir() else -1
        if self._temporary is None:
            if 0 <= free < size:
                raise LogReadError(_no_room(file, plain, base, size, free))
            self._temporary = private_folder(STEM)  # killed runs' copies removed first
        elif 0 <= free < size:
            raise LogReadError(_no_room(file, plain, base, size, free))
        target = self._temporary / plain
        try:
            with file.open("rb") as source, target.open("wb") as sink:
                zstandard.ZstdDecompressor().copy_stream(source, sink)
        except zstandard.ZstdError as err:
            target.unlink(missing_ok=True)
            raise LogReadError(
                f"cannot decompress {file} (a rosbag2 bag recorded with --compression-mode "
                f"file): {_one_line(err)} (a damaged or cut file?)"
            ) from err
        except OSError as err:
            target.unlink(missing_ok=True)
            if err.errno == errno.EFBIG:
                raise LogReadError(
                    f"cannot decompress {file} (a rosbag2 bag recorded with --compression-mode "
                    f"file) into the temporary folder {base}: a file-size limit (ulimit -f) "
                    f"stopped it: raise it, or run `zstd -d {file}` and pass the decompressed "
                    f"{file.parent / plain}"
                ) from err
            if err.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise LogReadError(
                    f"cannot decompress {file} into the temporary folder {base}: "
                    f"{err.strerror or _one_line(err)}; set TMPDIR to a folder you can write, "
                    f"or run `zstd -d {file}` and pass the decompressed {file.parent / plain}"
                ) from err
            raise LogReadError(_no_room(file, plain, base, size, free, _one_line(err))) from err
        if target.stat().st_size < len(MCAP_MAGIC):  # a frame cut inside its header
            target.unlink(missing_ok=True)
            raise LogReadError(
                f"cannot decompress {file} (a rosbag2 bag recorded with --compression-mode "
                "file): it holds no whole zstd frame (a damaged or cut file?)"
            )
        return target

    def _close(self) -> None:
        for part in self._parts:
            part.close()
        self._parts = []
        if self._temporary is not None:
            remove_private_folder(self._temporary)
            self._temporary = None

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
        if self._message_zstd:
            merged = self._decompressed(merged)
        yield from merged
        self.backward_log_times = max(part.backward_log_times for part in self._parts)

    def _decompressed(self, stream: Iterator[RawMessage]) -> Iterator[RawMessage]:
        """The messages of a ``--compression-mode message`` bag, their payloads decompressed.

        A payload that is not a zstd frame (or not a whole one) is passed on as it is: its
        decoding fails and is counted as any damaged message is.
        """
        import zstandard

        for raw in stream:
            try:
                data = zstandard.ZstdDecompressor().decompressobj().decompress(raw.data)
            except zstandard.ZstdError as err:
                self._warn_once(
                    f"{self.path.name}: a message on {raw.topic} at log time "
                    f"{raw.log_time_ns} ns is not zstd-compressed as metadata.yaml says "
                    f"(compression_mode: message): {err}"
                )
                yield raw
                continue
            yield raw._replace(data=data)

    def extras(self, *, verify: bool = False) -> McapExtras:
        """See :meth:`LogReader.extras`: every storage file's, in file order.

        A channel several files repeat (a split bag's) is listed once; each attachment
        names the file it is in.
        """
        self._check_open()
        channels: list[ChannelInfo] = []
        extras = McapExtras(self.path, channels)
        for part, file in zip(self._parts, self._files, strict=True):
            found = part.extras(verify=verify)
            channels += [channel for channel in found.channels if channel not in channels]
            extras.attachments.extend(
                dataclasses.replace(item, file=file) for item in found.attachments
            )
            extras.metadata.extend(found.metadata)
        return extras


def _log_time(raw: RawMessage) -> Any:
    return raw.log_time_ns


def lone_storage_problem(path: Path, *, sqlite: bool) -> str | None:
    """Why a rosbag2 storage file given alone cannot be read as it is, else None.

    Its messages compressed one by one (``--compression-mode message``) say so only in
    ``metadata.yaml`` (and in the file's own metadata, which rosbags does not read given the
    file alone): every message would fail to decode as "damaged". Known from a
    ``metadata.yaml`` beside it that lists it, else from the first message's payload
    starting with the zstd magic (a CDR payload starts with its encapsulation header).
    """
    info = _bag_info(path.parent)
    names = info.get("relative_file_paths") if info is not None else None
    listed = isinstance(names, list) and path.name in [str(name) for name in names]
    if listed and message_zstd(path.parent):
        found = "its folder's metadata.yaml says compression_mode: message"
    else:
        first = _first_payload_db3(path) if sqlite else _first_payload_mcap(path)
        if first is None or not first.startswith(ZSTD_MAGIC):
            return None
        found = "its first message starts with the zstd magic bytes"
    folder = f"its folder {path.parent}" if listed else "the bag's folder (with its metadata.yaml)"
    return (
        f"{path} is the storage file of a rosbag2 bag recorded with per-message zstd "
        f"compression ({found}), read only through the bag's folder; pass {folder} "
        "instead of the storage file"
    )


STEM = "pcainterp-rosbag2"
"""The start of the name of a process's folder of decompressed storage files."""


def _no_room(
    file: Path, plain: str, base: Path, size: int, free: int, error: str | None = None
) -> str:
    """The line that says a file-compressed storage file could not be decompressed."""
    needs = f"it needs {_amount(size)}" if size >= 0 else "its decompressed size is not known"
    has = f"{_amount(free)} free" if free >= 0 else "room unknown"
    why = f" ({error}; {needs}, {has} before)" if error else f": {needs}, it has {has}"
    return (
        f"cannot decompress {file} (a rosbag2 bag recorded with --compression-mode file) into "
        f"the temporary folder {base}{why}; set TMPDIR to a folder with room for it, or run "
        f"`zstd -d {file}` and pass the decompressed {file.parent / plain} (the folder still "
        "lists the .zstd)"
    )


def _amount(size: int) -> str:
    """A size in bytes as people say it: MB above a megabyte, else kB."""
    return f"{size / 1e6:.0f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"


def _first_payload_db3(path: Path) -> bytes | None:
    """The first message's payload of a rosbag2 sqlite3 file, None when there is none.

    Read as immutable: nothing is written beside the bag (no ``-shm`` file), and a
    write-ahead log's messages are not seen (the file's own decide, or nothing does).
    """
    import sqlite3
    from contextlib import closing
    from urllib.parse import quote

    uri = f"file:{quote(str(path.resolve()))}?mode=ro&immutable=1"
    try:
        with closing(sqlite3.connect(uri, uri=True)) as db:
            row = db.execute("SELECT data FROM messages ORDER BY id LIMIT 1").fetchone()
    except sqlite3.Error:
        return None
    return bytes(row[0]) if row and isinstance(row[0], bytes | memoryview) else None


def _first_payload_mcap(path: Path) -> bytes | None:
    """The first bytes of a rosbag2 MCAP file's first message payload; None: not found cheaply.

    Opened with every MCAP, so it reads little: the records before the first message or
    chunk, and of a chunk its first :data:`_CHUNK_PREFIX` bytes (decompressed as far as they
    go; lz4 chunks are not looked into). A message not found there decides nothing, nor one
    of a file whose profile is not ``ros2`` or on a channel whose encoding is not ``cdr``
    (only a CDR payload, which starts with its encapsulation header, tells the zstd magic
    from data: another channel's payload may be any bytes, zstd data too).
    """
    import struct

    cdr: set[int] = set()
    try:
        with path.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                return None
            head = f.read(9)
            if len(head) < 9 or head[0] != _HEADER:
                return None
            (length,) = struct.unpack_from("<Q", head, 1)
            if _string(f.read(min(length, 4096)), 0)[0] != b"ros2":
                return None
            f.seek(len(MCAP_MAGIC) + 9 + length)
            for _ in range(64):  # schemas, channels, metadata: a few records
                head = f.read(9)
                if len(head) < 9:
                    return None
                opcode, length = struct.unpack("<BQ", head)
                if length > size - f.tell():  # damaged or cut: the reader says what
                    return None
                if opcode in (_MESSAGE, _CHANNEL):  # a channel's encoding, or the answer
                    body = f.read(min(length, _CHUNK_PREFIX))
                    f.seek(length - len(body), 1)
                    first = _first_in_records(head + body, cdr)
                    if opcode == _MESSAGE:
                        return first
                    continue
                if opcode == _CHUNK:
                    records = _chunk_records(f.read(min(length, _CHUNK_PREFIX)))
                    return _first_in_records(records, cdr)
                f.seek(length, 1)
    except (OSError, ValueError, OverflowError, struct.error):
        return None
    return None


def _string(data: bytes, offset: int) -> tuple[bytes, int]:
    """An MCAP string (u32 length, bytes) at ``offset``, and the offset after it."""
    import struct

    (length,) = struct.unpack_from("<I", data, offset)
    return data[offset + 4 : offset + 4 + length], offset + 4 + length


_HEADER, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x04, 0x05, 0x06
_MESSAGE_DATA = 22  # a message record's channel id, sequence, log and publish times
_CHUNK_PREFIX = 1 << 18  # bytes of a chunk read: more than one zstd block (128 kB)


def _chunk_records(body: bytes) -> bytes:
    """The start of a chunk's records (from the start of its body), decompressed."""
    import io
    import struct

    import zstandard

    try:
        (name_length,) = struct.unpack_from("<I", body, 28)
        name = body[32 : 32 + name_length]
        data = body[32 + name_length + 8 :]
        if name == b"":
            return data
        if name == b"zstd":
            reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data))
            return bytes(reader.read(_CHUNK_PREFIX))  # bounded, whatever the data claims
    except (struct.error, zstandard.ZstdError):
        pass
    return b""


def _first_in_records(records: bytes, cdr: set[int]) -> bytes | None:
    """The first bytes of the first message's payload among some records, None: none.

    ``cdr``: the ids of the channels seen so far whose encoding is ``cdr`` (the records'
    channels are added); a first message on another channel decides nothing (None).
    """
    import struct

    offset = 0
    try:
        while offset + 9 <= len(records):
            opcode, length = struct.unpack_from("<BQ", records, offset)
            body = offset + 9
            if opcode == _CHANNEL:
                (channel,) = struct.unpack_from("<H", records, body)
                _, after_topic = _string(records, body + 4)  # after its id and schema id
                if _string(records, after_topic)[0] == b"cdr":
                    cdr.add(channel)
            if opcode == _MESSAGE:
                (channel,) = struct.unpack_from("<H", records, body)
                if channel not in cdr:
                    return None
                start = body + _MESSAGE_DATA
                return records[start : min(start + 8, body + length)]
            offset = body + length
    except struct.error:
        return None
    return None
