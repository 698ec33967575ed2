"""Logs through Unix pipes: an MCAP output written to a stream, an input read from one.

Output (``-o -``): :class:`McapStreamWriter` writes the same MCAP as the file writer (``ros2``
profile, zstd chunks, summary and chunk index) straight to a stream that cannot seek, such
as standard output. The mcap library only ever appends, and asks the stream for its
position, which :class:`_CountingStream` answers by counting bytes. A reader of the pipe
needs none of the summary offsets: mcap's stream reader and rosbags read it front to back.

Input (``-``): the log readers need a seekable file (the summary at the end names the
topics and message counts that densify checks before it starts, and chunks are skipped by
seeking), so :func:`spool` copies the stream into a temporary file first, 1 MiB at a time:
memory stays bounded whatever the log's length, the disk holds one copy of the input (in
``TMPDIR``) until the job ends, and densifying starts once the input is complete.
"""

from __future__ import annotations

import contextlib
import errno
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import IO

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from pcainterp_stream.errors import LogReadError, LogWriteError
from pcainterp_stream.interrupt import (
    InterruptedStreamOutput,
    signalled,
    track_partial,
    untrack_partial,
)
from pcainterp_stream.io.logwriter import LIBRARY, MCAP_CHUNK_SIZE, McapLogWriter
from pcainterp_stream.io.output_paths import remove_stale_temporaries, temporary_prefix

STDIN_NAME = "stdin"
"""The name a spooled standard input goes by in messages."""

STDOUT_PATH = Path("<stdout>")
"""The path a :class:`McapStreamWriter`'s summary names."""

_SPOOL_BLOCK = 1 << 20


class _CountingStream:
    """Wrap a binary stream that cannot seek: count bytes for ``tell``, never close it."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Write all of ``data``: an unbuffered stream (``PYTHONUNBUFFERED``) may take part."""
        view = memoryview(data).cast("B")
        while view:
            written = self._stream.write(view)
            if not written:  # None: a non-blocking stream that is full
                raise OSError(errno.EAGAIN, "the stream takes no more bytes")
            self._position += written
            view = view[written:]
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        self._stream.flush()

    def close(self) -> None:
        """Flush only: the stream belongs to the caller (mcap's ``finish`` does the same)."""
        self._stream.flush()


class McapStreamWriter(McapLogWriter):
    """An MCAP writer onto an open binary stream (standard output); no atomic rename.

    The stream is flushed, not closed, at the end. An exception in the ``with`` block
    leaves what was written so far on the stream (a truncated MCAP a reader reports as
    such): a pipe cannot take bytes back. So the errors say so: a failed write raises a
    :class:`LogWriteError` and an interruption an :class:`InterruptedStreamOutput`, each
    naming the bytes sent.
    """

    def __init__(self, stream: IO[bytes], name: Path = STDOUT_PATH) -> None:
        super().__init__(name)
        self._target = stream
        self._counting: _CountingStream | None = None
        self._finished = False

    @property
    def written(self) -> int:
        """Bytes written to the stream so far."""
        return 0 if self._counting is None else self._counting.tell()

    def _description(self) -> str:
        where = "standard output" if self.path == STDOUT_PATH else str(self.path)
        return f"the MCAP written to {where}"

    def failed(self, error: BaseException) -> LogWriteError:
        """Return the error for a failed write: the bytes sent stay on the stream."""
        return LogWriteError(
            f"writing {self.path} failed: {type(error).__name__}: {error}; "
            f"{self._description()} is incomplete ({self.written} bytes); discard it"
        )

    def open(self) -> None:
        """Start the MCAP on the stream."""
        self._open_partial()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Finish the MCAP (or stop it); an interruption says what the stream holds."""
        try:
            super().__exit__(exc_type, exc_value, traceback)
        except KeyboardInterrupt as err:
            raise self._interrupted() from err
        if isinstance(exc_value, KeyboardInterrupt) or (exc_value is not None and signalled()):
            # (a signal inside native code surfaces as that code's error)
            raise self._interrupted() from exc_value

    def _interrupted(self) -> InterruptedStreamOutput:
        return InterruptedStreamOutput(self._description(), self.written, complete=self._finished)

    def _open_partial(self) -> None:
        stream = self._counting = _CountingStream(self._target)
        self._stream = stream  # type: ignore[assignment]
        self._writer = McapWriter(
            stream,  # type: ignore[arg-type]
            chunk_size=MCAP_CHUNK_SIZE,
            compression=CompressionType.ZSTD,
        )
        try:
            self._writer.start(profile="ros2", library=LIBRARY)
        except OSError as err:
            raise LogWriteError(f"cannot write the MCAP output to {self.path}: {err}") from err

    def _close_partial(self) -> None:
        super()._close_partial()
        self._finished = True

    def _commit(self) -> None:
        """Nothing to move: the bytes are already on the stream."""


@contextlib.contextmanager
def spool(stream: IO[bytes], name: str = STDIN_NAME) -> Iterator[Path]:
    """Copy a stream into a temporary file; yield its path, remove it afterwards.

    Args:
        stream: the binary input (standard input).
        name: the file's name (what messages about the log call it).

    Raises:
        LogReadError: the stream is empty or cannot be read, or the disk is full; a reader's
            error in the ``with`` block on bytes that are no log is given as
            :data:`NOT_A_LOG` (standard input, not the temporary copy).
    """
    # owner-named: a killed run's copy of the whole log is removed by the next (bug hunt 9C F5)
    remove_stale_temporaries(Path(tempfile.gettempdir()), "pcainterp-stdin")
    with tempfile.TemporaryDirectory(prefix=temporary_prefix("pcainterp-stdin")) as folder:
        track_partial(Path(folder))  # removed even if a signal forces the end
        try:
            path = Path(folder) / name
            try:
                with path.open("xb") as spooled:
                    shutil.copyfileobj(stream, spooled, _SPOOL_BLOCK)
            except OSError as err:
                raise LogReadError(
                    f"cannot copy standard input to {path} (needed: the readers seek): "
                    f"{err.strerror or err}; set TMPDIR to a folder with room for the log"
                ) from err
            if path.stat().st_size == 0:
                raise LogReadError(
                    "standard input is empty, not a log; pipe an MCAP file (or a ROS 1 bag) into "
                    "`pcainterp densify -`"
                )
            try:
                yield path
            except LogReadError as err:  # the reader's words name the temporary file
                if not _is_log(path):
                    raise LogReadError(NOT_A_LOG) from err
                raise
        finally:
            untrack_partial(Path(folder))


NOT_A_LOG = (
    "standard input is not a log (no MCAP, ROS 1 bag or SQLite magic bytes); pipe an MCAP "
    "file, a ROS 1 bag or a rosbag2 sqlite3 .db3 into `pcainterp densify -` (a rosbag2 "
    "folder cannot be piped: pass its path)"
)
"""The refusal of piped bytes that are no log: not the log reader's, which names the
temporary copy (the user never gave it; it is gone when the command ends) and suggests a
rosbag2 folder, which cannot be piped."""


def _is_log(path: Path) -> bool:
    """Whether the spooled input starts as a log (MCAP, ROS 1 bag, SQLite; or is unreadable)."""
    from pcainterp_stream.io.logreader import ROS1_MAGIC
    from pcainterp_stream.io.reader_base import MCAP_MAGIC, SQLITE_MAGIC

    try:
        with path.open("rb") as spooled:
            head = spooled.read(16)
    except OSError:
        return True  # the reader's error says what is wrong
    return head.startswith((MCAP_MAGIC, ROS1_MAGIC, SQLITE_MAGIC))
