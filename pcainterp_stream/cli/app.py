"""The ``pcainterp`` parser and the run of a parsed command line.

One module per command (``synth``, ``import_kitti``, ``learn``, ``densify``, ``evaluate``,
``info``, ``demo``, ``golden``), each with ``add_parser(commands)`` and ``run(args)``;
:data:`COMMANDS` lists them in the order ``pcainterp --help`` shows them. The work is done
by :mod:`pcainterp_stream.pipeline`, imported when a command runs so that ``--help`` stays
fast.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import errno
import os
import stat
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

from pcainterp_stream.cli import (
    common,
    demo,
    densify,
    evaluate,
    golden,
    import_kitti,
    info,
    learn,
    streams,
    synth,
)
from pcainterp_stream.cli.common import PROG, formatter
from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.interrupt import (
    EXIT_INTERRUPTED,
    Interrupted,
    InterruptedAfterOutput,
    InterruptedStreamOutput,
    end_if_signalled,
    resource_tracker_survives_hang_up,
    signalled,
    stop_on_signals,
)
from pcainterp_stream.version import __version__

COMMANDS: dict[str, ModuleType] = {
    "synth": synth,
    "import-kitti": import_kitti,
    "learn": learn,
    "densify": densify,
    "evaluate": evaluate,
    "info": info,
    "demo": demo,
    "golden": golden,
}
"""Command name -> its module (``add_parser``, ``run``), in the order of ``--help``."""

REPORT_GONE = (
    f"{PROG}: standard output was closed by its reader; the rest of the report is not "
    "printed, and the command goes on to write its output"
)
"""Said on standard error when a report line finds standard output closed (:mod:`.streams`)."""


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``pcainterp``."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        formatter_class=formatter,
        description=(
            "Densify sparse depth in stereo-camera logs (MCAP, ROS 1 .bag, rosbag2) with a\n"
            "learned PCA basis and a MAP estimate with per-pixel uncertainty\n"
            "(Ochs, Bradler & Mester, IEEE IV 2017)."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp demo                  # a generated drive densified, in about a minute\n"
            "  pcainterp densify drive.mcap -o drive_dense.mcap          # the built-in basis\n"
            "  pcainterp evaluate drive_dense.mcap -o report\n"
            "  pcainterp synth train.mcap --frames 200 --seed 1\n"
            "  pcainterp learn train.mcap -o basis.npz --components 200  # a basis of your own\n"
            "  pcainterp densify drive.mcap -o drive_dense.mcap --basis basis.npz --rrd drive.rrd\n"
            "  pcainterp info drive_dense.mcap\n"
            "  pcainterp golden save drive_dense.mcap -o drive.golden.json  # then golden check\n"
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS.values():
        module.add_parser(commands)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the job a parsed command line asks for; return the exit code.

    Every command gives the caller's BLAS thread counts back when it returns (a caller
    in-process: ``learn``, ``evaluate`` and ``densify`` leave scipy's OpenBLAS, which the
    solver holds at one thread, at the count the caller's environment gives a new one:
    ``pipeline/blas_threads``).
    """
    from pcainterp_stream.pipeline.blas_threads import blas_threads_given_back

    command: Callable[[argparse.Namespace], int] = COMMANDS[args.command].run
    common.refuse_stdin_inputs(args)
    with blas_threads_given_back():
        return command(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``pcainterp``; return the exit code, also 2 for a usage error.

    argparse ends a bad command line (an unknown option, a value that does not parse) with
    ``SystemExit(2)`` after printing the usage line; that is returned as 2 here, so that a
    caller in-process (a test: ``assert main([...]) == 0``) gets the code rather than the
    exception. ``--help`` and ``--version`` print and end with ``SystemExit(0)``, as
    argparse does.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:
        if done.code in (0, None):  # --help, --version
            raise
        return done.code if isinstance(done.code, int) else 2  # usage error, already printed
    if isinstance(sys.stdout, streams.ReportStream) and _writes(args):
        sys.stdout.note = REPORT_GONE
    # SIGTERM takes the same clean-up path as Ctrl-C: temporaries removed, target untouched;
    # a second signal ends at once, and densify (native threads: the Foxglove server, the
    # writer, SGBM) has a watchdog that ends it within a few seconds whatever blocks
    # (pcainterp_stream/interrupt.py). The previous handlers come back afterwards, for
    # callers that run main() in-process.
    targets = None
    if _writes(args):
        with contextlib.suppress(OSError, ValueError):  # the line then says what it always did
            targets = _Targets(args)
    if getattr(args, "workers", None) or getattr(args, "scheduler", None):
        resource_tracker_survives_hang_up()  # worker processes: a hang-up costs no traceback
    try:
        with stop_on_signals(watchdog=args.command == "densify"):
            return run(args)
    except KeyboardInterrupt as interruption:
        return _interrupted(interruption, writes=_writes(args), targets=targets)
    except Exception as err:
        # A signal that lands inside an import of a compiled module surfaces as
        # "ImportError: initialization failed", inside other native code as whatever it
        # raises: once a signal was handled, every error is the interruption's.
        if signalled():
            return _interrupted(writes=_writes(args), targets=targets)
        if isinstance(err, PcaInterpError):
            print(f"{PROG}: error: {err}", file=sys.stderr)
            return 2
        if isinstance(err, OSError) and err.errno == errno.ENAMETOOLONG:
            # wherever a path is looked at (an input's exists(), an output's folder, PATH_MAX)
            print(f"{PROG}: error: {_too_long_line(err)}", file=sys.stderr)
            return 2
        if isinstance(err, BrokenPipeError):  # the reader of densify -o -'s MCAP went away
            return 1
        raise


def _too_long_line(err: OSError) -> str:
    """The line a path too long for the file system ends a command with (ENAMETOOLONG)."""
    from pcainterp_stream.io.path_text import shown, too_long

    if err.filename is None:
        return "a path is too long for the file system: choose a shorter name or path"
    return f"cannot use {shown(err.filename)}: {too_long(err.filename)}"


def console() -> int:
    """Run the ``pcainterp`` program (its console script and ``python -m``).

    :func:`main` for a process of its own: settings that are the process's, like freezing
    the garbage collector's view of the imports (:func:`common.settle_heap`), apply only here.
    """
    common.OWN_PROCESS = True
    streams.guard()  # a reader of the report that goes away costs no job
    code = main()
    _end_without_teardown(code)
    return code  # pragma: no cover - only when a thread of the job is still running


def _end_without_teardown(code: int) -> None:
    """End the program now, skipping the interpreter's teardown of every module.

    The command is done: its outputs are closed and its threads have ended. The exit
    handlers still run (``atexit``: removing temporaries, flushing viewers' streams) and
    the standard streams are flushed; what is skipped is freeing the imported modules
    one by one, ~0.1 s of a KITTI densify job (measured). A non-daemon thread still
    running leaves the normal exit to wait for it.
    """
    if any(
        t.is_alive() and not t.daemon
        for t in threading.enumerate()
        if t is not threading.main_thread()
    ):
        return
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _writes(args: argparse.Namespace) -> bool:
    """Whether the command writes a file (``info`` and ``golden check`` only read)."""
    if args.command == "info":
        return False
    return not (args.command == "golden" and args.golden_command == "check" and not args.update)


NOTHING_LEFT = "no partial output was left at the target"
"""What an interruption leaves at new targets (each output is renamed in place once whole)."""


def _state(path: Path) -> object:
    """What is at ``path`` now, to tell later whether it changed (None: no file or folder).

    A file: its inode, size and modification time (an output is renamed onto its target,
    a new inode). A folder: the same of each entry not hidden (its staging folders are).
    """
    try:
        found = path.stat()
    except OSError:
        return None
    if stat.S_ISREG(found.st_mode):
        return (found.st_ino, found.st_size, found.st_mtime_ns)
    if not stat.S_ISDIR(found.st_mode):
        return None  # a device or a pipe: nothing the command stages and renames
    try:
        entries = [entry for entry in os.scandir(path) if not entry.name.startswith(".")]
        return frozenset(
            (entry.name, (info.st_ino, info.st_size, info.st_mtime_ns))
            for entry in entries
            for info in [entry.stat(follow_symlinks=False)]
        )
    except OSError:
        return None


class _Targets:
    """The outputs a command line names and what was at them before it ran.

    An interruption then says what is at each (:meth:`detail`): an earlier run's output,
    left unchanged; an output of this run, finished (renamed into place whole) before the
    signal; or nothing. For ``demo`` the outputs are the entries of its folder.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.folder: Path | None = args.out if args.command == "demo" else None
        paths: list[Path] = []
        if self.folder is None:
            for name in ("out", "output", "rrd"):
                value = getattr(args, name, None)
                if isinstance(value, Path) and str(value) != "-":
                    paths.append(value)
            if args.command == "evaluate" and args.output is None:
                paths.append(args.input.with_name(args.input.stem + "_report"))
            if args.command == "golden" and getattr(args, "update", False):
                paths.append(args.golden)
        self.paths = paths
        # densify --out-dir: its run names the outputs it kept (interrupt.Interrupted)
        self.in_folder = getattr(args, "out_dir", None) is not None
        self.before = self._now()

    def _now(self) -> dict[Path, object]:
        if self.folder is None:
            return {path: _state(path) for path in self.paths}
        try:
            names = sorted(e.name for e in os.scandir(self.folder) if not e.name.startswith("."))
        except OSError:
            return {}
        return {self.folder / name: _state(self.folder / name) for name in names}

    def detail(self) -> str:
        """What is at the targets now, as the end of the "interrupted" line."""
        after = self._now()
        if self.folder is None and not self.paths:
            return NOTHING_LEFT if self.in_folder else "nothing was written"
        kept = [
            str(p)
            for p, state in after.items()
            if state is not None and state != self.before.get(p)
        ]
        old = [
            str(p)
            for p, state in self.before.items()
            if state is not None and after.get(p) == state
        ]
        parts = []
        if kept:
            parts.append(
                ", ".join(kept)
                + (" was" if len(kept) == 1 else " were")
                + " finished before the signal and kept"
            )
        if old:
            parts.append(
                ", ".join(old)
                + (
                    " was not changed (it holds"
                    if len(old) == 1
                    else " were not changed (they hold"
                )
                + " an earlier run's output)"
            )
        if not parts:
            return NOTHING_LEFT if self.folder is None else f"nothing was written in {self.folder}"
        new = [str(p) for p in self.paths if after.get(p) is None]
        if new:
            parts.append(f"nothing was written at {', '.join(new)}")
        return "; ".join(parts)


def _interrupted(
    interruption: KeyboardInterrupt | None = None,
    *,
    writes: bool = True,
    targets: _Targets | None = None,
) -> int:
    """Say the command was interrupted (and what it kept); end at once after a real signal.

    Args:
        interruption: what was raised (its kind says what was kept).
        writes: the command writes an output (False: the line says no more).
        targets: the outputs and what was at them before the run (None: not known).

    Returns:
        130.
    """
    detail = NOTHING_LEFT
    if not writes:
        detail = ""
    elif isinstance(interruption, InterruptedAfterOutput):  # the signal came after the commit
        detail = f"{interruption.kept} was complete and is kept"
    elif isinstance(interruption, Interrupted | InterruptedStreamOutput):
        detail = str(interruption)  # which outputs were kept; what standard output holds
    elif targets is not None:
        with contextlib.suppress(OSError):
            detail = targets.detail()
    # after a SIGHUP standard error may be a terminal that went away: the clean-up is done,
    # a line that can go nowhere changes nothing
    with contextlib.suppress(OSError, ValueError):
        print(f"{PROG}: interrupted" + (f"; {detail}" if detail else ""), file=sys.stderr)
    # A Ctrl-C that lands inside code run by exec() (rosbags generates its message
    # decoders that way) sets a flag that makes `python -m` re-raise SIGINT at exit
    # (CPython bpo-41602) although we handled it; any exec() of a string clears it.
    exec("")
    end_if_signalled(EXIT_INTERRUPTED)  # a real signal: no interpreter shutdown to wait for
    return EXIT_INTERRUPTED
