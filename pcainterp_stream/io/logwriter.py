"""Log writers: MCAP (ROS 2 profile), rosbag2 (MCAP or SQLite 3 storage) and ROS 1 bags.

One small interface hides the format: ::

    with open_writer("out.mcap", LogFormat.MCAP, inputs=["in.mcap"]) as writer:
        writer.add_raw(raw)                                  # copy an input message unchanged
        writer.add_message("/pcainterp/depth", message, log_time_ns)

Messages are rosbags typestore objects of :data:`rosmsg.TYPESTORE` (ROS 2 Humble); a
channel (connection) is registered on first use of a topic with a message type.

Output is atomic: everything is written into a hidden folder beside the target
(``.OUT.partial-PID@HOST-XXXX``) and moved onto the target only once complete and closed;
one left by a killed run is removed when the next run writes the same target. An
exception or KeyboardInterrupt inside the ``with`` block removes the partial output and
leaves an existing target untouched. The writer refuses to write onto one of its inputs.

``open_writer(..., threaded=True)`` serializes, compresses and writes in one thread of its
own behind a bounded queue (:data:`WRITE_QUEUE_ITEMS` messages), so the caller's thread only
hands messages over; zstd and file writes release the GIL. An error in that thread is
raised, as a :class:`LogWriteError` naming the output, by the next ``add_*`` call or by
``close``, and the partial output is removed as for any other error. Without the thread, the
disk's own errors (a full disk: ``OSError``, SQLite's "database or disk is full") become
the same :class:`LogWriteError` (:meth:`LogWriter.failed`). MCAP chunks are
compressed with zstd at ``zstd_level`` (:data:`MCAP_ZSTD_LEVEL` by default).

This module knows message layouts only through :mod:`rosmsg`; it never reads a log.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import struct
import tempfile
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, Self

import mcap.writer
import zstandard
from mcap._chunk_builder import ChunkBuilder
from mcap.data_stream import RecordBuilder
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore
from zlib_ng import zlib_ng

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.interrupt import raise_if_signalled, track_partial, untrack_partial
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.mcap_extras import McapExtras, filled_schema, write_extras
from pcainterp_stream.io.output_paths import (
    check_not_input,
    check_output_file,
    full_disk_advice,
    partial_prefix,
    remove_stale_partials,
    removed_meanwhile,
    staged_for,
    write_advice,
)
from pcainterp_stream.io.rosbag2_record import ROSBAG2_RECORD, Rosbag2Record
from pcainterp_stream.io.write_thread import WriteThread
from pcainterp_stream.records import RawMessage
from pcainterp_stream.version import __version__

if TYPE_CHECKING:  # rosbags' bag writers are imported when used (~65 ms with its readers)
    from rosbags.interfaces import Connection
    from rosbags.rosbag1 import Writer as Rosbag1Writer
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Rosbag2Writer

ProgressCallback = Callable[[int, int | None], None]
"""Called as ``progress(done, total)`` after each unit of work; ``total`` None if unknown."""

LIBRARY = f"pcainterp_stream {__version__}"
MCAP_CHUNK_SIZE = 4 * 1024 * 1024
"""Uncompressed MCAP chunk size (bytes): a few KITTI images per zstd chunk."""
MCAP_ZSTD_LEVEL = -1
"""zstd level of MCAP chunks: -1, zstd's first fast level. The float32 output images hardly
compress at any level (level 1 keeps 87 % of their bytes at ~5 ms per KITTI image, -1 keeps
all of them at ~1 ms); on a densified log -1 writes 14 % more bytes than level 1 for ~16
CPU ms per frame less (docs/benchmarks.md, "CRC-32 and zstd level -1")."""
WRITE_QUEUE_ITEMS = 32
"""Messages a threaded writer holds before ``add_*`` blocks (bounds its memory: ~60 MB of
KITTI-size float32 images)."""
PARTIAL_CHECK_S = 1.0
"""How often (s) a writer checks that its partial output is still there: a folder removed
under the job stops it within a second, not after writing the rest into an unlinked file."""


class _ZstdAtLevel:
    """Stand-in for ``mcap.writer``'s ``zstandard`` module: compress at a per-thread level.

    mcap's ``Writer`` compresses chunks with ``zstandard.compress(data)`` (level 3) and has
    no level option. This object replaces that module name once; a thread that has not
    chosen a level (:func:`_zstd_level`) gets zstd's default as before, so other users of
    mcap in the process are unaffected.
    """

    def __init__(self) -> None:
        self._local = threading.local()

    def set_level(self, level: int | None) -> None:
        """Compress this thread's chunks at ``level`` (None: zstd's default).

        A compressor is not safe to share between threads: each thread keeps its own.
        """
        if level is None:
            self._local.compressor = None
            return
        cache: dict[int, zstandard.ZstdCompressor] | None = getattr(self._local, "cache", None)
        if cache is None:
            cache = self._local.cache = {}
        if level not in cache:
            cache[level] = zstandard.ZstdCompressor(level=level)
        self._local.compressor = cache[level]

    def compress(self, data: bytes, level: int = 3) -> bytes:
        """Compress one chunk (the signature of ``zstandard.compress``)."""
        compressor: zstandard.ZstdCompressor | None = getattr(self._local, "compressor", None)
        if compressor is None:
            return zstandard.compress(data, level)
        return compressor.compress(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(zstandard, name)


_ZSTD = _ZstdAtLevel()
mcap.writer.zstandard = _ZSTD  # type: ignore[attr-defined,assignment]
# mcap's Writer checksums every chunk with ``zlib.crc32``: zlib-ng's is the same CRC-32 at
# ~4.5x the speed (6 CPU ms per KITTI frame of output less; docs/benchmarks.md, "CRC-32
# and zstd level -1")
mcap.writer.zlib = zlib_ng  # type: ignore[attr-defined]


class _PartsRecordBuilder(RecordBuilder):
    """mcap's ``RecordBuilder`` for a chunk's records, keeping the written parts, joined once.

    mcap's builder copies every message into a growing ``BytesIO`` (the copy and each
    regrowth hold the GIL: ~2 CPU ms per KITTI frame of output, measured with yappi); this
    one keeps references to the parts (each record's header is packed once its length is
    known) and joins them once when the chunk ends, into the same bytes. Only parts that
    cannot change are kept by reference (``bytes``, and views of ``bytes`` such as a
    message of a decoded input chunk); any other buffer is copied when written, as
    ``BytesIO`` copies it, since mcap's writer is patched for the whole process.
    """

    def __init__(self) -> None:
        self._parts: list[bytes | bytearray | memoryview] = []
        self._size = 0
        self._header = -1
        self._opcode = 0
        self._record_start_offset = 0

    @property
    def count(self) -> int:
        return self._size

    def start_record(self, opcode: Any) -> None:
        self._header = len(self._parts)
        self._opcode = int(opcode)
        self._record_start_offset = self._size
        self._parts.append(b"")  # the opcode and length, packed by finish_record
        self._size += 9

    def finish_record(self) -> None:
        length = self._size - self._record_start_offset - 9
        self._parts[self._header] = struct.pack("<BQ", self._opcode, length)

    def end(self) -> bytes:
        data = b"".join(self._parts)
        self._parts = []
        self._size = 0
        return data

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if isinstance(data, memoryview) and isinstance(data.obj, bytes):
            self._size += data.nbytes
        else:
            if type(data) is not bytes:
                data = bytes(data)  # its owner may change it before the chunk ends
            self._size += len(data)
        self._parts.append(data)


class _PartsChunkBuilder(ChunkBuilder):
    """mcap's ``ChunkBuilder`` with :class:`_PartsRecordBuilder` for its records."""

    def __init__(self) -> None:
        super().__init__()
        self.record_writer = _PartsRecordBuilder()


mcap.writer.ChunkBuilder = _PartsChunkBuilder  # type: ignore[attr-defined]


class LogFormat(Enum):
    """Output log formats."""

    MCAP = "mcap"
    """A single ``.mcap`` file, ``ros2`` profile, CDR messages, zstd chunks."""
    ROSBAG2 = "rosbag2"
    """A rosbag2 folder (``metadata.yaml`` + one ``.mcap`` storage file)."""
    ROSBAG2_SQLITE3 = "rosbag2-sqlite3"
    """A rosbag2 folder with SQLite 3 storage (``.db3``)."""
    ROS1 = "ros1"
    """A ROS 1 ``.bag`` file (format 2.0, uncompressed chunks)."""


def format_from_path(path: str | os.PathLike[str]) -> LogFormat:
    """Choose the output format from a path's name.

    ``.mcap`` -> MCAP, ``.bag`` -> ROS 1, an existing folder or a name without a suffix ->
    rosbag2 (MCAP storage).

    Raises:
        LogWriteError: for any other suffix.
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix == ".mcap":
        return LogFormat.MCAP
    if suffix == ".bag":
        return LogFormat.ROS1
    if target.is_dir() or not suffix:
        return LogFormat.ROSBAG2
    raise LogWriteError(
        f"cannot tell the log format of {target} from its suffix {target.suffix!r}; "
        "name it .mcap or .bag, use a folder name without a suffix for rosbag2, "
        "or pass the format explicitly"
    )


@dataclass(frozen=True)
class WriteSummary:
    """What a writer wrote.

    Attributes:
        path: the finished output (file or rosbag2 folder).
        format: its format.
        message_count: number of messages.
        topic_counts: messages per topic, in order of first appearance.
        start_ns: smallest log time (ns), 0 when empty.
        end_ns: largest log time (ns), 0 when empty.
    """

    path: Path
    format: LogFormat
    message_count: int
    topic_counts: dict[str, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0


class LogWriter(ABC):
    """Common interface of every format's writer; use as a context manager.

    Subclasses write into :attr:`partial_path` (inside a hidden folder beside the target);
    :meth:`close` moves it onto :attr:`path`, :meth:`abort` deletes it.
    """

    format: LogFormat

    def __init__(self, path: Path) -> None:
        self.path = path
        self._partial_dir: Path | None = None
        self._thread: WriteThread | None = None
        self._write_errors: tuple[type[Exception], ...] = (OSError,)
        """What the format's writer raises when the disk refuses bytes (a full disk)."""
        self.threaded = False
        """Write in a thread of its own (set before :meth:`open`; :func:`open_writer`)."""
        self._topic_counts: Counter[str] = Counter()
        self._start_ns: int | None = None
        self._end_ns = 0
        self._next_check = 0.0  # time.monotonic() of the next check of the partial output
        self.channel_metadata: dict[str, dict[str, str]] = {}
        """Metadata of the channels :meth:`add_message` registers, by topic (MCAP only: the
        bag formats have no channel metadata). Set it before a topic's first message."""

    @property
    def partial_path(self) -> Path:
        """The file or folder being written (inside the hidden partial folder)."""
        if self._partial_dir is None:
            raise LogWriteError(f"writer for {self.path} is not open; use it in a with block")
        return self._partial_dir / self.path.name

    def open(self) -> None:
        """Create the hidden partial folder and open the format's writer in it."""
        parent = self.path.parent
        if not parent.is_dir():
            raise LogWriteError(
                f"cannot write {self.path}: folder {parent} does not exist; create it first"
            )
        remove_stale_partials(self.path)  # a killed earlier run's (never a live one's)
        try:
            self._partial_dir = Path(tempfile.mkdtemp(prefix=partial_prefix(self.path), dir=parent))
            track_partial(self._partial_dir)  # removed even if a signal forces the end
        except OSError as err:
            raise LogWriteError(
                f"cannot write {self.path}: {err.strerror}; {write_advice(err)}"
            ) from err
        try:
            if self.threaded:
                self._thread = WriteThread(self.failed, queue_items=WRITE_QUEUE_ITEMS)
            self._call(self._open_partial)
        except BaseException:
            try:
                self._drop_partial()  # closes the file the format's writer began
            finally:
                self._stop_thread()
                self._remove_partial()
            raise

    def _run(self, work: Callable[[], None]) -> None:
        """Run ``work`` now, or hand it to the writer thread (in order) when threaded.

        Raises:
            LogWriteError: the disk (or stream) refused the bytes (:meth:`failed`), here or,
                threaded, in earlier work.
        """
        if self._thread is None:
            try:
                work()
            except BrokenPipeError:  # the reader of a stream went away: it wants no more
                raise
            except self._write_errors as err:
                raise self.failed(err) from err
        else:
            self._thread.submit(work)

    def _call(self, work: Callable[[], None]) -> None:
        """Run ``work`` now, in the writer thread when threaded (after what is queued).

        The format's writer is opened, closed and aborted in the thread that writes: SQLite
        connections (rosbag2 ``.db3``) must stay in the thread that made them.

        Raises:
            LogWriteError: the disk (or stream) refused the bytes (:meth:`failed`).
        """
        try:
            if self._thread is None:
                work()
            else:
                self._thread.call(work)
        except BrokenPipeError:
            raise
        except self._write_errors as err:
            raise self.failed(err) from err

    def _drop_partial(self) -> None:
        """Close what the format's writer left open; an error doing so changes nothing.

        The partial output is removed next: a full disk refusing its last bytes (or a
        closed stream) must not hide the error that ended the writing.
        """
        with contextlib.suppress(LogWriteError):
            self._call(self._abort_partial)

    def failed(self, error: BaseException) -> LogWriteError:
        """Return the error that reports ``error``, raised while writing, to the user.

        One sentence naming the output: the partial output is removed, so nothing was
        written at the target.
        """
        return self._removed() or write_failed(self.path, error)

    def _removed(self) -> LogWriteError | None:
        """Return the error when the partial output (or its folder) was removed, else None."""
        if self._partial_dir is None:
            return None
        during = "the output was being written"
        named = staged_for(self.path)  # --out-dir: the user's folder, not the staging one
        folder = self.path.parent
        if named != self.path and not os.path.isdir(named.parent):
            folder = named.parent
        reason = removed_meanwhile(self._partial_dir, folder, during)
        return (
            None
            if reason is None
            else LogWriteError(f"cannot write {named}: {reason}; nothing was written")
        )

    def _stop_thread(self) -> None:
        """Drop the writer thread's queued work and stop it (no-op when not threaded)."""
        if self._thread is not None:
            thread, self._thread = self._thread, None
            thread.stop(cancel=True)

    def add_message(
        self, topic: str, message: Any, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """Serialize and write a typestore message, registering its channel on first use.

        Args:
            topic: channel topic.
            message: a :data:`rosmsg.TYPESTORE` message (``message.__msgtype__`` names it).
            log_time_ns: log time (ns).
            publish_time_ns: publish time (ns); the log time when None (MCAP only; the bag
                formats store one time).
        """
        msgtype = str(message.__msgtype__)
        log_time = int(log_time_ns)
        publish_time = int(log_time_ns if publish_time_ns is None else publish_time_ns)
        self._run(
            lambda: self._add_message(
                topic, msgtype, rosmsg.serialize(message), log_time, publish_time
            )
        )
        self._count(topic, log_time)

    def add_raw(self, raw: RawMessage) -> None:
        """Copy a message of an input log unchanged (schema, encoding, metadata, times).

        MCAP keeps everything; the bag formats keep topic, type, data and log time, and
        accept CDR (``ros2msg``) messages only.
        """
        self._run(lambda: self._add_raw(raw))
        self._count(raw.topic, int(raw.log_time_ns))

    def close(self) -> WriteSummary:
        """Finish the output and move it onto the target; return what was written."""
        try:
            if self._thread is not None:
                self._thread.check()  # once everything queued ran: its error, if any
            self._call(self._close_partial)
            if self._thread is not None:
                thread, self._thread = self._thread, None
                thread.stop()
            raise_if_signalled()  # never commit an output after a signal
            self._commit()
        except BaseException:
            try:
                self._drop_partial()  # closes what a failed thread left open
            finally:
                self._stop_thread()
                self._remove_partial()
            raise
        return self.summary()

    def abort(self) -> None:
        """Drop the partial output; the target is left as it was."""
        try:
            if self._thread is not None:
                self._thread.cancel()
            self._drop_partial()
        finally:
            self._stop_thread()
            self._remove_partial()

    def summary(self) -> WriteSummary:
        """Return the counts written so far."""
        return WriteSummary(
            path=self.path,
            format=self.format,
            message_count=sum(self._topic_counts.values()),
            topic_counts=dict(self._topic_counts),
            start_ns=self._start_ns or 0,
            end_ns=self._end_ns,
        )

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _count(self, topic: str, log_time_ns: int) -> None:
        raise_if_signalled()  # a signal whose KeyboardInterrupt was lost still stops the job
        if self._partial_dir is not None and (now := time.monotonic()) >= self._next_check:
            self._next_check = now + PARTIAL_CHECK_S
            if (removed := self._removed()) is not None:
                raise removed
        self._topic_counts[topic] += 1
        self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
        self._end_ns = max(self._end_ns, log_time_ns)

    def _commit(self) -> None:
        """Move the finished partial output onto the target (replacing an old one)."""
        assert self._partial_dir is not None
        partial = self.partial_path
        target = self.path
        try:
            if target.is_dir() and not target.is_symlink():
                _check_replaceable_folder(target)
                old = self._partial_dir / ".replaced"
                os.replace(target, old)
                os.replace(partial, target)
            else:
                os.replace(partial, target)
        except OSError as err:
            raise self._removed() or LogWriteError(
                f"cannot move the finished output onto {target}: {err.strerror}; "
                f"{write_advice(err)}"
            ) from err
        self._remove_partial()

    def _remove_partial(self) -> None:
        if self._partial_dir is not None:
            shutil.rmtree(self._partial_dir, ignore_errors=True)
            untrack_partial(self._partial_dir)
            self._partial_dir = None

    @abstractmethod
    def _open_partial(self) -> None: ...

    @abstractmethod
    def _add_message(
        self, topic: str, msgtype: str, data: bytes, log_time_ns: int, publish_time_ns: int
    ) -> None: ...

    @abstractmethod
    def _add_raw(self, raw: RawMessage) -> None: ...

    @abstractmethod
    def _close_partial(self) -> None: ...

    @abstractmethod
    def _abort_partial(self) -> None: ...


def write_failed(path: Path, error: BaseException) -> LogWriteError:
    """Return the error of a file output whose writing failed (its partial output removed).

    Args:
        path: the output's target (in a staging folder of ``densify --out-dir``: the file
            it is moved to is named, :func:`staged_for`).
        error: what the writing raised (a full disk: ``OSError`` ``ENOSPC``: the message
            says to free some space).
    """
    return LogWriteError(
        f"writing {staged_for(path)} failed: {type(error).__name__}: {error}; nothing was "
        f"written there{full_disk_advice(error)}"
    )


def _check_replaceable_folder(target: Path) -> None:
    """Refuse to replace a folder that is not a rosbag2 bag (it may hold anything)."""
    if not (target / "metadata.yaml").is_file():
        raise LogWriteError(
            f"output {target} is an existing folder that is not a rosbag2 bag (no "
            "metadata.yaml); remove it or choose another output path"
        )


class McapLogWriter(LogWriter):
    """MCAP in the ``ros2`` profile: ``ros2msg`` schemas, CDR messages, zstd chunks.

    The summary repeats schemas and channels and holds statistics and a chunk index, so
    seeking readers (mcap ``make_reader``, Foxglove, Rerun) can use it. Channels with rosbag2
    QoS profiles get them in numbers and a ``rosbag2`` record saying so (version 8) unless
    the input brought its own (:mod:`.rosbag2_record`): :meth:`add_extras` comes first.
    """

    format = LogFormat.MCAP

    def __init__(self, path: Path, *, zstd_level: int | None = None) -> None:
        super().__init__(path)
        self.zstd_level = MCAP_ZSTD_LEVEL if zstd_level is None else zstd_level
        """zstd level of the chunks (None at construction: :data:`MCAP_ZSTD_LEVEL`)."""
        self._stream: IO[bytes] | None = None
        self._writer: McapWriter | None = None
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, str, int, tuple[tuple[str, str], ...]], int] = {}
        self._rosbag2 = Rosbag2Record()

    def _open_partial(self) -> None:
        self._stream = self.partial_path.open("xb")
        self._writer = McapWriter(
            self._stream, chunk_size=MCAP_CHUNK_SIZE, compression=CompressionType.ZSTD
        )
        self._writer.start(profile="ros2", library=LIBRARY)

    def _schema_id(self, name: str, encoding: str, data: bytes) -> int:
        if not name and not encoding and not data:
            return 0  # a channel without a schema
        key = (name, encoding, filled_schema(name, encoding, data))  # an empty one: filled
        if key not in self._schemas:
            assert self._writer is not None
            self._schemas[key] = self._writer.register_schema(*key)
            self._rosbag2.schema_names[self._schemas[key]] = name
        return self._schemas[key]

    def _channel_id(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str]
    ) -> int:
        key = (topic, message_encoding, schema_id, tuple(sorted(metadata.items())))
        if key not in self._channels:
            assert self._writer is not None
            written = self._rosbag2.metadata(dict(metadata))
            channel = self._writer.register_channel(topic, message_encoding, schema_id, written)
            self._rosbag2.add_channel(channel, topic, schema_id, message_encoding, written)
            self._channels[key] = channel
        return self._channels[key]

    def _add_message(
        self, topic: str, msgtype: str, data: bytes, log_time_ns: int, publish_time_ns: int
    ) -> None:
        schema_id = self._schema_id(msgtype, "ros2msg", rosmsg.schema_text(msgtype).encode())
        metadata = self.channel_metadata.get(topic, {})
        channel_id = self._channel_id(topic, "cdr", schema_id, metadata)
        assert self._writer is not None
        self._rosbag2.count(channel_id, log_time_ns)
        with self._zstd_level():
            self._writer.add_message(channel_id, log_time_ns, data, publish_time_ns)

    @contextlib.contextmanager
    def _zstd_level(self) -> Iterator[None]:
        """Compress the chunks mcap finishes inside the block at :attr:`zstd_level`."""
        _ZSTD.set_level(self.zstd_level)
        try:
            yield
        finally:
            _ZSTD.set_level(None)

    def _add_raw(self, raw: RawMessage) -> None:
        schema_id = self._schema_id(raw.schema_name, raw.schema_encoding, bytes(raw.schema_data))
        channel_id = self._channel_id(
            raw.topic, raw.message_encoding, schema_id, raw.channel_metadata
        )
        assert self._writer is not None
        self._rosbag2.count(channel_id, int(raw.log_time_ns))
        with self._zstd_level():
            self._writer.add_message(
                channel_id,
                int(raw.log_time_ns),
                raw.data,  # a view of the decoded input chunk: copied once, into the chunk
                int(raw.publish_time_ns),
                sequence=int(raw.sequence),
            )

    def add_metadata(self, name: str, record: dict[str, str]) -> None:
        """Write a metadata record (name and string key/values)."""
        writer = self._writer
        assert writer is not None
        self._rosbag2.see([name])
        self._run(lambda: writer.add_metadata(name, record))

    def add_extras(self, extras: McapExtras) -> None:
        """Copy an MCAP input's channels, metadata records and attachments (its order: first)."""
        self._rosbag2.see(record.name for record in extras.metadata)  # its QoS then stay
        self._run(lambda: write_extras(extras, self._writer, self._schema_id, self._channel_id))

    def _close_partial(self) -> None:
        assert self._writer is not None
        assert self._stream is not None
        try:
            if (record := self._rosbag2.record(self.path.name)) is not None:
                self._writer.add_metadata(ROSBAG2_RECORD, record)
            with self._zstd_level():
                self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._stream.close()
            self._writer = None
            self._stream = None

    def _abort_partial(self) -> None:
        if self._stream is not None:
            self._stream.close()
        self._writer = None
        self._stream = None


def _raw_typestore(raw: RawMessage, base: Typestore) -> Typestore:
    """Return ``base`` if it knows ``raw.msgtype``, else a copy extended by the raw schema."""
    if raw.msgtype in base.fielddefs:
        return base
    if raw.message_encoding != "cdr" or raw.schema_encoding != "ros2msg":
        raise LogWriteError(
            f"topic {raw.topic} has {raw.message_encoding!r} messages with a "
            f"{raw.schema_encoding!r} schema; bag outputs take ROS (cdr/ros2msg) messages "
            "only; write an .mcap output to copy it"
        )
    store = get_typestore(Stores.EMPTY)
    store.register(dict(base.fielddefs))
    try:
        store.register(get_types_from_msg(bytes(raw.schema_data).decode(), raw.msgtype))
    except Exception as err:
        raise LogWriteError(
            f"cannot parse the ros2msg schema of {raw.msgtype} on topic {raw.topic}: {err}; "
            "write an .mcap output to copy it unchanged"
        ) from err
    return store


class Rosbag2LogWriter(LogWriter):
    """A rosbag2 folder (version 9) with MCAP or SQLite 3 storage, CDR messages."""

    def __init__(self, path: Path, storage: StoragePlugin) -> None:
        from rosbags.rosbag2 import StoragePlugin

        super().__init__(path)
        self.format = (
            LogFormat.ROSBAG2 if storage == StoragePlugin.MCAP else LogFormat.ROSBAG2_SQLITE3
        )
        self._storage = storage
        if storage != StoragePlugin.MCAP:
            import sqlite3  # SQLite's "database or disk is full"

            self._write_errors = (OSError, sqlite3.Error)
        self._writer: Rosbag2Writer | None = None
        self._connections: dict[tuple[str, str], Connection] = {}

    def _open_partial(self) -> None:
        from rosbags.rosbag2 import Writer as Rosbag2Writer

        self._writer = Rosbag2Writer(
            self.partial_path, version=Rosbag2Writer.VERSION_LATEST, storage_plugin=self._storage
        )
        self._writer.open()

    def _connection(self, topic: str, msgtype: str, typestore: Typestore) -> Connection:
        key = (topic, msgtype)
        if key not in self._connections:
            assert self._writer is not None
            self._connections[key] = self._writer.add_connection(
                topic, msgtype, typestore=typestore
            )
        return self._connections[key]

    def _add_message(
        self, topic: str, msgtype: str, data: bytes, log_time_ns: int, publish_time_ns: int
    ) -> None:
        assert self._writer is not None
        self._writer.write(self._connection(topic, msgtype, rosmsg.TYPESTORE), log_time_ns, data)

    def _add_raw(self, raw: RawMessage) -> None:
        store = _raw_typestore(raw, rosmsg.TYPESTORE)
        assert self._writer is not None
        self._writer.write(
            self._connection(raw.topic, raw.msgtype, store), int(raw.log_time_ns), raw.data
        )

    def _close_partial(self) -> None:
        assert self._writer is not None
        self._writer.close()
        self._writer = None  # kept until then: a failed close is aborted (file closed)

    def _abort_partial(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            writer.abort()


class Ros1LogWriter(LogWriter):
    """A ROS 1 bag (format 2.0): messages converted from CDR to the ROS 1 wire format.

    Connections use the ROS 1 Noetic definitions (and MD5 sums) whenever the ROS 2 type has
    the same wire format there (Image, CameraInfo, PointCloud2, DisparityImage, PoseStamped
    do: ``std_msgs/Header`` gains ``seq = 0``, CameraInfo's fields are spelt ``K``, ``P``).
    Other types keep their ROS 2 definition with the ROS 1 header, as ``rosbags-convert``
    does.
    """

    format = LogFormat.ROS1

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self._writer: Rosbag1Writer | None = None
        self._connections: dict[tuple[str, str], Connection] = {}
        self._noetic = get_typestore(Stores.ROS1_NOETIC)

    def _open_partial(self) -> None:
        from rosbags.rosbag1 import Writer as Rosbag1Writer

        self._writer = Rosbag1Writer(self.partial_path)
        self._writer.open()

    def _ros1_store(self, msgtype: str, source: Typestore) -> Typestore:
        from rosbags.convert.converter import is_same_wireformat

        if msgtype in self._noetic.fielddefs and is_same_wireformat(
            source, self._noetic, msgtype, msgtype
        ):
            return self._noetic
        store = get_typestore(Stores.EMPTY)
        store.register(
            {
                **source.fielddefs,
                "std_msgs/msg/Header": self._noetic.fielddefs["std_msgs/msg/Header"],
            }
        )
        return store

    def _write(
        self, topic: str, msgtype: str, cdr: bytes, log_time_ns: int, source: Typestore
    ) -> None:
        key = (topic, msgtype)
        if key not in self._connections:
            assert self._writer is not None
            self._connections[key] = self._writer.add_connection(
                topic, msgtype, typestore=self._ros1_store(msgtype, source)
            )
        assert self._writer is not None
        data = source.cdr_to_ros1(cdr, msgtype)
        self._writer.write(self._connections[key], log_time_ns, data)

    def _add_message(
        self, topic: str, msgtype: str, data: bytes, log_time_ns: int, publish_time_ns: int
    ) -> None:
        self._write(topic, msgtype, data, log_time_ns, rosmsg.TYPESTORE)

    def _add_raw(self, raw: RawMessage) -> None:
        store = _raw_typestore(raw, rosmsg.TYPESTORE)
        self._write(raw.topic, raw.msgtype, bytes(raw.data), int(raw.log_time_ns), store)

    def _close_partial(self) -> None:
        assert self._writer is not None
        self._writer.close()
        self._writer = None  # kept until then: a failed close is aborted (file closed)

    def _abort_partial(self) -> None:
        if self._writer is not None and self._writer.bio is not None:
            self._writer.bio.close()
        self._writer = None


def open_writer(
    path: str | os.PathLike[str],
    format: LogFormat | str | None = None,
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    threaded: bool = False,
) -> LogWriter:
    """Return a writer for ``path``; use it as a context manager.

    Args:
        path: output file (MCAP, ROS 1) or rosbag2 folder.
        format: a :class:`LogFormat` or its value (``"mcap"``, ``"rosbag2"``,
            ``"rosbag2-sqlite3"``, ``"ros1"``); chosen by :func:`format_from_path` if None.
        inputs: the input logs of this run; writing onto one of them is refused.
        threaded: serialize, compress and write in a thread of the writer's own (see the
            module docstring); messages must not be changed after ``add_*``.

    Raises:
        LogWriteError: bad format name, the output is an input, its folder is missing, or
            the target is a folder that is not a rosbag2 bag, or a device, pipe or socket.
    """
    target = Path(path)
    if format is None:
        chosen = format_from_path(target)
    elif isinstance(format, LogFormat):
        chosen = format
    else:
        try:
            chosen = LogFormat(format)
        except ValueError:
            names = ", ".join(item.value for item in LogFormat)
            raise LogWriteError(
                f"unknown log format {format!r} for {target}; choose one of {names}"
            ) from None
    check_not_input(target, inputs)
    target = check_output_file(target)  # a device refused; through a link: its file replaced
    if target.is_dir() and not target.is_symlink():
        if chosen in (LogFormat.MCAP, LogFormat.ROS1):
            raise LogWriteError(
                f"output {target} is a folder but format {chosen.value} writes a file; "
                "choose a file path"
            )
        _check_replaceable_folder(target)
    writer: LogWriter
    if chosen == LogFormat.MCAP:
        writer = McapLogWriter(target)
    elif chosen == LogFormat.ROS1:
        writer = Ros1LogWriter(target)
    else:
        from rosbags.rosbag2 import StoragePlugin

        storage = StoragePlugin.MCAP if chosen == LogFormat.ROSBAG2 else StoragePlugin.SQLITE3
        writer = Rosbag2LogWriter(target, storage)
    writer.threaded = threaded
    return writer
