r"""The ``pcainterp`` program's standard output and error: a reader that goes away costs no job.

A command's report is read through a pipe that may close before the command ends
(``pcainterp densify in.mcap -o out.mcap | head -1``, a CI step's ``grep -m1 prior:``, a
``tee`` that dies). The report is for the reader; the job is for the output: once the reader
is gone, the lines it would have read are dropped, the command goes on, writes its output and
exits 0 as it would have. :func:`guard` wraps both standard streams of the process so that
every line printed to them (the command's, the library's, argparse's) is covered. A stream
whose reader is gone has its descriptor pointed at ``/dev/null``, so that what is buffered and
the interpreter's own flush at exit go there too; one note on standard error says so, for
the commands that write an output.

A name the stream's encoding cannot hold (a latin-1 file name on a UTF-8 desktop, whose
standard output is strict; any non-ASCII name with ``PYTHONIOENCODING=ascii``) is printed
with those characters escaped (``caf\udce9.mcap``), as Python's standard error does:
a report line never ends a command whose work is done. Names come from the file system and
the logs (topics, frame ids); the program's own text is ASCII.

The MCAP of ``densify -o -`` goes to standard output's binary buffer, not through these
wrappers: when *its* reader goes away, the output is lost and the command ends (exit 1).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any, TextIO, cast

__all__ = ["ReportStream", "guard"]


class ReportStream:
    """A text stream that drops what it is given once its reader has gone away.

    Everything but ``write`` and ``flush`` is the wrapped stream's (``buffer``, ``fileno``,
    ``isatty``, ``encoding``).

    Args:
        stream: the stream wrapped (``sys.stdout`` or ``sys.stderr`` of the process).
        note: said once on standard error when a line written here is dropped; None:
            nothing is said.

    Attributes:
        reader_gone: the reader went away; what is written since is dropped.
    """

    def __init__(self, stream: TextIO, *, note: str | None = None) -> None:
        self._stream = stream
        self.note = note
        self.reader_gone = False
        self._unflushed = False  # text written here since the last flush

    def write(self, text: str) -> int:
        """Write ``text``; drop it (and say so once) when the reader is gone."""
        try:
            count = self._stream.write(text)
        except UnicodeEncodeError:
            count = self._write_escaped(text)
        except BrokenPipeError:
            self._gone(dropped_text=True)
            return len(text)
        self._unflushed = self._unflushed or bool(text)
        return count

    def flush(self) -> None:
        """Flush the stream; what the reader no longer takes is dropped."""
        try:
            self._stream.flush()
        except BrokenPipeError:
            # bytes of ``buffer`` (densify -o -'s MCAP, after its own error) are no report line
            self._gone(dropped_text=self._unflushed)
        self._unflushed = False

    def _write_escaped(self, text: str) -> int:
        r"""Write ``text`` with what the stream's encoding cannot hold escaped (``\xe9``)."""
        encoding = getattr(self._stream, "encoding", None) or "utf-8"
        escaped = text.encode(encoding, "backslashreplace").decode(encoding)
        try:
            self._stream.write(escaped)
        except BrokenPipeError:
            self._gone(dropped_text=True)
        return len(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)

    def _gone(self, *, dropped_text: bool) -> None:
        """Point the stream's descriptor at /dev/null; say so when a report line was lost."""
        if self.reader_gone:
            return
        self.reader_gone = True
        with contextlib.suppress(OSError, ValueError):  # ValueError: no descriptor (closed)
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, self._stream.fileno())
            finally:
                os.close(null)
            self._stream.flush()  # what was buffered for the gone reader: to /dev/null
        if dropped_text and self.note is not None:
            print(self.note, file=sys.stderr, flush=True)


def guard() -> None:
    """Wrap ``sys.stdout`` and ``sys.stderr`` of the process in :class:`ReportStream`.

    For the ``pcainterp`` program only: a caller running :func:`~.app.main` in its own
    program keeps its streams as they are. Set the standard output's ``note`` once the
    command is known.
    """
    wrapped = []
    for stream in (sys.stdout, sys.stderr):
        _escape_unencodable(stream)
        # None: started without the stream (``>&-``), where print() already prints nothing
        if stream is not None and not isinstance(stream, ReportStream):
            stream = cast("TextIO", ReportStream(stream))
        wrapped.append(stream)
    sys.stdout, sys.stderr = wrapped


def _escape_unencodable(stream: TextIO | None) -> None:
    """Make a strict text stream escape what its encoding cannot hold (``backslashreplace``).

    Covers what bypasses :class:`ReportStream` (a library writing to ``sys.__stdout__``); a
    stream that escapes or passes surrogates already (``surrogateescape`` on a C.UTF-8
    locale: a latin-1 name printed as its own bytes) is left as it is.
    """
    if stream is None or getattr(stream, "errors", None) != "strict":
        return
    with contextlib.suppress(AttributeError, ValueError, OSError):  # no reconfigure(): kept
        stream.reconfigure(errors="backslashreplace")  # type: ignore[attr-defined]
