"""Ctrl-C, SIGTERM and SIGHUP end a command within a bounded time, whatever its threads do.

A Python signal handler runs only when the main thread returns to the interpreter. While
the main thread waits in native code (a lock, a join, a call into a native library such
as the Foxglove server, or a native call that holds the interpreter lock and waits for a
thread that needs it), the handler, and so ``KeyboardInterrupt``, never comes. The clean
path stays the usual one: the first signal raises ``KeyboardInterrupt`` in the main thread,
the ``with`` blocks remove what they were writing, the command prints one line. Two
mechanisms bound it:

- the **watchdog**, a small separate process started by :func:`stop_on_signals`. The
  interpreter's C-level handler writes the number of every signal it catches to a pipe
  (:func:`signal.set_wakeup_fd`) from whichever thread the signal interrupted, without the
  interpreter lock; the watchdog reads that pipe. When the command has not ended
  :data:`GRACE_S` after the first signal (or at once after a second one), it removes the
  partial outputs the command registered (:func:`track_partial`), prints one line and
  kills the command. Being a process of its own it works even when every thread of the
  command is stuck;
- a **second signal** handled in the main thread ends the process at once (after removing
  the partial outputs), without waiting for the clean-up of the first.

Outside :func:`stop_on_signals` (library use) :func:`track_partial` only records paths.
"""

from __future__ import annotations

import atexit
import contextlib
import faulthandler
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import IO, Any

GRACE_S = 3.0
"""Time (s) the command gets after the first signal to clean up and end by itself.

A clean-up usually takes a few tenths of a second; on a loaded two-core machine threads
still finishing their task (an SGBM match, a batch's estimate) have made it take over 1.5 s
(a forced kill instead of a clean end, seen in whole test-suite runs)."""

SECOND_SIGNAL_GRACE_S = 0.2
"""After a second signal the watchdog waits this long for the command to end itself."""

EXIT_INTERRUPTED = 130
"""Exit code of an interrupted command (128 + SIGINT, as shells report it)."""

_SIGNALS: tuple[signal.Signals, ...] = (
    signal.SIGINT,
    signal.SIGTERM,
    *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()),
)
"""The signals that stop a command cleanly: Ctrl-C, ``kill``, and the hang-up of a closed
terminal or a dropped ssh session (SIGHUP; left ignored when the command started with it
ignored, as under ``nohup``: :func:`_handled`)."""


def _handled() -> tuple[signal.Signals, ...]:
    """The signals of :data:`_SIGNALS` to handle now: an ignored SIGHUP (``nohup``) stays so."""
    return tuple(
        sig
        for sig in _SIGNALS
        if sig != getattr(signal, "SIGHUP", None) or signal.getsignal(sig) is not signal.SIG_IGN
    )


_WATCHDOG = r"""
import os, select, shutil, signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
if hasattr(signal, "SIGHUP"):
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
parent, grace, second, wake, control = (int(sys.argv[1]), float(sys.argv[2]),
    float(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
watched = {int(n) for n in sys.argv[6].split(",")}
dump = sys.argv[7] == "1"
inputs, partials, pending, deadline, seen = [wake, control], set(), b"", None, 0
while True:
    timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
    ready, _, _ = select.select(inputs, [], [], timeout)
    if wake in ready:
        data = os.read(wake, 64)
        if not data:
            inputs.remove(wake)
        for number in data:
            if number in watched:
                seen += 1
                limit = time.monotonic() + (grace if seen == 1 else second)
                deadline = limit if deadline is None else min(deadline, limit)
    if control in ready:
        data = os.read(control, 65536)
        if not data:
            sys.exit(0)  # the command ended: its end of the pipe closed
        pending += data
        *lines, pending = pending.split(b"\n")
        for line in lines:
            path = os.fsdecode(line[1:])
            (partials.add if line[:1] == b"+" else partials.discard)(path)
    if deadline is not None and time.monotonic() >= deadline:
        for path in partials:
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path, ignore_errors=True)
            else:
                try:
                    os.unlink(path)
                except OSError:
                    pass
        try:  # standard error may be a terminal that hung up (SIGHUP): the kill still comes
            os.write(2, b"pcainterp: stopped: the clean-up after the signal did not end in time; "
                     b"partial output removed\n")
        except OSError:
            pass
        if dump:
            try:
                os.kill(parent, signal.SIGUSR1)  # faulthandler writes every thread's stack
                time.sleep(0.3)
            except OSError:
                pass
        try:
            os.kill(parent, signal.SIGKILL)
        except OSError:
            pass
        sys.exit(0)
"""
"""The watchdog process's program (``python -I -S -c``): no imports beyond the standard
library's core, so it starts in a few milliseconds and never touches the command's files
other than the registered partial outputs."""

STALL_DUMP_VARIABLE = "PCAINTERP_STALL_DUMP"
"""Environment variable naming a folder: when the watchdog has to kill a command, the
command first writes the Python stack of every thread there (``faulthandler``), into
``stall-PID.txt``. For finding out where a command hung; unset, nothing is written."""


class InterruptedAfterOutput(KeyboardInterrupt):
    """A signal after the command's output was complete and in place: the output is kept.

    Attributes:
        kept: the output, complete at its target.
    """

    def __init__(self, kept: Path) -> None:
        super().__init__(str(kept))
        self.kept = kept


class InterruptedStreamOutput(KeyboardInterrupt):
    """A signal while an output went to a stream (standard output), which keeps what it got.

    Bytes sent down a pipe cannot be taken back: the message says how many there are and
    whether they make the whole output.

    Attributes:
        what: the output, as a message names it ("the MCAP written to standard output").
        written: bytes sent before the signal.
        complete: whether they are the whole output.
    """

    def __init__(self, what: str, written: int, *, complete: bool) -> None:
        """Record what was sent; the message says whether to keep it."""
        self.what = what
        self.written = written
        self.complete = complete
        if complete:
            state = f"is complete ({written} bytes)"
        else:
            state = f"is incomplete ({written} bytes); discard it"
        super().__init__(f"{what} {state}")


_lock = threading.Lock()
_stall_dump: IO[str] | None = None
_partials: set[Path] = set()
_control: IO[bytes] | None = None
_signals_seen = 0
_deferring = 0


class Interrupted(KeyboardInterrupt):
    """The interruption of a command that writes several outputs into a folder.

    Raised from the ``KeyboardInterrupt`` once the partial outputs are removed; its message
    says what stayed: the outputs committed before the signal.

    Attributes:
        folder: the folder the outputs go to.
        kept: the outputs finished and committed before the signal.
        total: the outputs the command was to write.
    """

    def __init__(self, folder: Path, kept: Sequence[Path], total: int) -> None:
        """Record where the outputs go, which were kept and how many there were to be."""
        self.folder = folder
        self.kept = tuple(kept)
        self.total = total
        if not self.kept:
            done = "no output was finished before the signal"
        else:
            done = f"kept {len(self.kept)} of {total} outputs, finished before the signal: " + (
                ", ".join(map(str, self.kept))
            )
        super().__init__(f"no partial output was left in {folder}; {done}")


def track_partial(path: Path) -> None:
    """Register a partial output (a file or folder): removed if the command is stopped."""
    with _lock:
        _partials.add(path)
        _send(b"+", path)


def untrack_partial(path: Path) -> None:
    """Forget a partial output (renamed onto its target, or removed)."""
    with _lock:
        _partials.discard(path)
        _send(b"-", path)


def _send(kind: bytes, path: Path) -> None:
    if _control is None:
        return
    try:
        _control.write(kind + os.fsencode(path) + b"\n")
        _control.flush()
    except (OSError, ValueError):  # the watchdog is gone: nothing to tell it
        pass


def remove_partials() -> None:
    """Remove every registered partial output now (a forced stop)."""
    with _lock:
        paths = list(_partials)
    for path in paths:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _on_signal(signum: int, frame: FrameType | None) -> None:
    """First signal: KeyboardInterrupt (the clean path); a second one: end at once."""
    global _signals_seen
    _signals_seen += 1
    if _signals_seen == 1:
        if _deferring:  # raised where the deferring block ends (signals_deferred)
            return
        raise KeyboardInterrupt
    remove_partials()
    with contextlib.suppress(Exception):
        print(
            "pcainterp: stopped at once (second signal); partial output removed",
            file=sys.stderr,
            flush=True,
        )
    _disarm_stall_dump()
    os._exit(EXIT_INTERRUPTED)


def signalled() -> bool:
    """Whether a signal (:data:`_SIGNALS`) was handled inside :func:`stop_on_signals`."""
    return _signals_seen > 0


def raise_if_signalled() -> None:
    """Raise ``KeyboardInterrupt`` if a signal was handled in this command.

    The handler's ``KeyboardInterrupt`` can be lost on its way: raised while the
    interpreter runs code whose errors it only reports or drops (a finaliser, a weak
    reference's callback inside an import, native code that clears errors), it never
    reaches the command, which would go on and finish. Readers and writers call this
    for every message, outputs before they are committed, and :func:`stop_on_signals` at the end of
    its block, so a handled signal always ends the command as an interruption with
    nothing written at the target. Other threads go on: the main thread stops the command.
    """
    if _signals_seen and threading.current_thread() is threading.main_thread():
        raise KeyboardInterrupt


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold a first signal's ``KeyboardInterrupt`` until the block ends (main thread only).

    For a few steps that must happen together or not at all (the renames that commit an
    output and the files beside it): a signal during the block raises ``KeyboardInterrupt``
    once it is done. A second signal still ends the command at once.
    """
    global _deferring
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
    raise_if_signalled()


def end_if_signalled(code: int) -> None:
    """End the process now with ``code`` if a signal was handled (after the clean-up).

    Once the ``with`` blocks have closed or removed what they wrote, nothing is left to do
    but the interpreter's own shutdown, which takes a few tenths of a second of CPU
    (longer on a loaded machine) and can meet native threads still calling back into
    Python (the Foxglove SDK's): the process ends here instead, streams flushed. Without
    a signal (an in-process caller whose code raised ``KeyboardInterrupt``) it returns.
    """
    if not _signals_seen:
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _disarm_stall_dump()
    os._exit(code)


@contextlib.contextmanager
def stop_on_signals(*, watchdog: bool = True) -> Iterator[None]:
    """Handle SIGINT, SIGTERM and SIGHUP as above for the ``with`` block (main thread only).

    SIGHUP (the terminal or ssh session went away) is handled as SIGTERM, unless it was
    ignored when the block began (``nohup``): then it stays ignored.

    Elsewhere (another thread, or signals not available) the block runs unchanged. The
    previous handlers, wake-up descriptor and partial-output registry come back afterwards,
    so callers that run a command in-process (tests) are left as they were.

    Args:
        watchdog: start the watchdog process (False: only the second-signal rule).
    """
    global _control, _signals_seen
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handled = _handled()
    previous = {sig: signal.getsignal(sig) for sig in handled}
    _signals_seen = 0
    process, wake_write, previous_wakeup = _start_watchdog(handled) if watchdog else (None, -1, -1)
    try:
        for sig in handled:
            signal.signal(sig, _on_signal)
        yield
        raise_if_signalled()  # the block ended normally: its KeyboardInterrupt was lost
    finally:
        # After a signal the process is ending: the handlers and the watchdog stay until it
        # has ended (the watchdog sees end of file when the process's descriptors close).
        if not _signals_seen:
            _restore(previous, process, wake_write, previous_wakeup)


def resource_tracker_survives_hang_up() -> None:
    """Have multiprocessing's resource tracker start with SIGHUP blocked, as SIGTERM is.

    For commands that start worker processes (a local Dask cluster). A terminal's hang-up
    goes to its whole process group: the tracker, which blocks only SIGINT and SIGTERM,
    died of it while the command cleaned up, and the tracker started again for the clean-up
    printed a ``KeyError`` traceback for every shared-memory block the workers had
    registered with the first (``learn --workers 2``, measured: 10). Under ``nohup`` (SIGHUP
    ignored) nothing changes. Imports :mod:`multiprocessing.resource_tracker` (~20 ms).
    """
    hang_up = getattr(signal, "SIGHUP", None)
    if hang_up is None or signal.getsignal(hang_up) is signal.SIG_IGN:
        return
    from multiprocessing import resource_tracker

    blocked = getattr(resource_tracker, "_IGNORED_SIGNALS", None)
    if isinstance(blocked, tuple) and hang_up not in blocked:
        resource_tracker._IGNORED_SIGNALS = (*blocked, hang_up)  # type: ignore[attr-defined]


def _restore(
    previous: dict[signal.Signals, Any],
    process: subprocess.Popen[bytes] | None,
    wake_write: int,
    previous_wakeup: int,
) -> None:
    """Put back the handlers and wake-up descriptor; let the watchdog exit."""
    global _control
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    if process is not None:
        signal.set_wakeup_fd(previous_wakeup)
        os.close(wake_write)
        with _lock:
            control, _control = _control, None
        if control is not None:
            with contextlib.suppress(OSError):
                control.close()  # end of file: the watchdog exits
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(timeout=5)
    with _lock:
        _partials.clear()
    _disarm_stall_dump()


def _disarm_stall_dump() -> None:
    """The command ended by itself: no stall to record, its empty dump file goes."""
    global _stall_dump
    if _stall_dump is None:
        return
    faulthandler.unregister(signal.SIGUSR1)
    with contextlib.suppress(OSError):
        _stall_dump.close()
        Path(_stall_dump.name).unlink(missing_ok=True)
    _stall_dump = None


def _stall_dump_opened() -> bool:
    """Arm ``faulthandler`` on SIGUSR1 into the stall-dump folder, if one is named."""
    global _stall_dump
    folder = os.environ.get(STALL_DUMP_VARIABLE)
    if not folder or not hasattr(signal, "SIGUSR1"):
        return False
    if _stall_dump is None:
        try:
            Path(folder).mkdir(parents=True, exist_ok=True)
            _stall_dump = (Path(folder) / f"stall-{os.getpid()}.txt").open("w")
        except OSError:
            return False
        _stall_dump.write(f"pcainterp {' '.join(sys.argv[1:])}\n")
        _stall_dump.flush()
        faulthandler.register(signal.SIGUSR1, file=_stall_dump, all_threads=True)
        # however the command ends by itself (a return after a signal included), the file
        # goes; only a kill after the dump leaves it
        atexit.register(_disarm_stall_dump)
    return True


def _start_watchdog(
    handled: Sequence[signal.Signals],
) -> tuple[subprocess.Popen[bytes] | None, int, int]:
    """Start the watchdog; return it, the wake-up pipe's write end and the previous fd."""
    global _control
    wake_read, wake_write = os.pipe()
    control_read, control_write = os.pipe()
    os.set_blocking(wake_write, False)  # the C handler must never block on it
    try:
        process = subprocess.Popen(
            [
                sys.executable,
                "-I",
                "-S",
                "-c",
                _WATCHDOG,
                str(os.getpid()),
                str(GRACE_S),
                str(SECOND_SIGNAL_GRACE_S),
                str(wake_read),
                str(control_read),
                ",".join(str(int(s)) for s in handled),
                "1" if _stall_dump_opened() else "0",
            ],
            pass_fds=(wake_read, control_read),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            start_new_session=True,  # a terminal's Ctrl-C goes to the command only
        )
    except OSError:  # no watchdog: the command still stops on a signal, unbounded
        os.close(wake_write)
        os.close(control_write)
        return None, -1, -1
    finally:
        os.close(wake_read)
        os.close(control_read)
    with _lock:
        _control = os.fdopen(control_write, "wb")
        for path in _partials:
            _send(b"+", path)
    previous = signal.set_wakeup_fd(wake_write, warn_on_full_buffer=False)
    return process, wake_write, previous
