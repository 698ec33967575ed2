"""What the commands share: the help layout, printing, and the stereo and cluster options.

Each option group is added by one function and read back into a typed config by another
beside it, so that a command which takes the group gets the same flags, help and checks.
Heavy modules load only when a command runs, so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gc
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from pcainterp_stream import defaults
from pcainterp_stream.errors import LogWriteError, PcaInterpError
from pcainterp_stream.io.output_paths import input_bag, name_too_long, symlink_loop

if TYPE_CHECKING:
    from types import FrameType

    from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig
    from pcainterp_stream.io.logwriter import WriteSummary

PROG = "pcainterp"

Commands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"
"""What ``ArgumentParser.add_subparsers`` returns: each command module adds its parser to it."""


OWN_PROCESS = False
"""True when the process is the ``pcainterp`` program itself (:func:`app.console`), not a
caller running :func:`app.main` in its own program."""


def path_arg(value: str) -> Path:
    """A path on the command line; an empty one (an unset shell variable) is refused.

    ``Path("")`` is ``Path(".")``: without this the error would name a folder "." never given.
    A path through a symbolic link loop, which no command can read or write, ends the
    parse with one line (exit 2), as a bad option value would without the usage lines; so
    does a ``~`` the shell did not expand (``--output=~/x.mcap``: :func:`unexpanded_home`).
    The string as typed decides what is a stream or a built-in basis: ``./-`` is the file
    named ``-`` and ``./builtin`` the file named ``builtin`` (pathlib spells both without
    ``./``, so they are made absolute here).
    """
    if not value:
        raise argparse.ArgumentTypeError("the path is empty (an unset shell variable?)")
    refusal = symlink_loop(value) or unexpanded_home(value)
    if refusal is not None:
        _end_parse(refusal)
    path = Path(value)
    if value != str(path) and (path == STREAM or str(path) in BUILTIN_BASIS_NAMES):
        return path.absolute()  # ./- or ./builtin: the file, not the stream or the basis
    return path


def file_output_arg(writes: str, example: str) -> Callable[[str], Path]:
    """Return the type of an option naming one output file (``-o``, ``--rrd``).

    :func:`path_arg`, and a path ending in ``/`` (a folder meant) refused: it would write a
    file of that name.

    Args:
        writes: what the command writes there (``densify writes one MCAP file``).
        example: the fix, with ``{}`` for the path as given (``-o {}x_dense.mcap``).
    """

    def output_arg(value: str) -> Path:
        path = path_arg(value)
        if value.endswith("/") and value.strip("/"):
            _end_parse(
                f"{value} ends with / so names a folder, but {writes}; name the file, "
                f"e.g. {example.format(value)}"
            )
        return path

    return output_arg


def unexpanded_home(value: str) -> str | None:
    """Say why a path starting with a ``~`` the shell did not expand is refused (else None).

    The shell expands ``~`` only at the start of a word (``-o ~/x.mcap``), not after ``=``
    (``--output=~/x.mcap``) nor inside quotes; the program would read or write a folder
    literally named ``~`` in the working folder. A path whose first name exists as typed (a
    folder ``./~``) is taken as it is, and so is ``~name`` when no user is called ``name``.
    """
    head, _, rest = value.partition("/")
    if not head.startswith("~") or os.path.lexists(head) or os.path.expanduser(head) == head:
        return None
    home = "$HOME" if head == "~" else os.path.expanduser(head)
    option = _parsed_option()
    if option is None:  # not through argparse: no option to name
        how = "unquoted at the start of a word"
    elif option:
        how = f"unquoted after a space ({option} {value}, not {option}={value} nor quoted)"
    else:  # a positional argument
        how = f"unquoted ({value}, not '{value}')"
    return (
        f"{value}: the shell did not expand {head} (it does not after = nor inside quotes); "
        f"write it {how} or as " + f"{home}/{rest}".rstrip("/")
    )


def _parsed_option() -> str | None:
    """The option whose value argparse is converting now ("" for a positional), else None.

    A ``type=`` callable is not told which argument it converts: the argparse frame that
    calls it (``_get_value(action, arg_string)``) is, so its action's long option is read
    there (the first of its names when it has no long one).
    """
    frame: FrameType | None = sys._getframe(1)
    while frame is not None:
        action = frame.f_locals.get("action") if frame.f_code.co_name == "_get_value" else None
        if isinstance(action, argparse.Action):
            names = action.option_strings
            return next(
                (name for name in names if name.startswith("--")), names[0] if names else ""
            )
        frame = frame.f_back
    return None


def _end_parse(line: str) -> None:
    """End the parse of the command line with one error line (exit 2)."""
    with contextlib.suppress(OSError):
        print(f"{PROG}: error: {line}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def settle_heap() -> None:
    """Move what the imports made out of the garbage collector's sight (own process only).

    The collector traverses every tracked object in its full collections and once more at
    exit; the modules' tens of thousands of objects live as long as the program. Frozen
    (:func:`gc.freeze`) after a job's imports, they are never traversed: ~0.05 s of a
    KITTI densify job's collections and exit (measured). A caller's program is left as it is.
    """
    if OWN_PROCESS:
        gc.freeze()


def formatter(prog: str) -> argparse.HelpFormatter:
    """Return the help layout of every command: descriptions and examples as written."""
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


DOCS_NOTE = (
    "docs/*.md: the pages of that name in the docs/ folder of pcainterp's source\n"
    "repository, beside its README (an installed package does not include them)\n"
)
"""The end of the help of a command whose options cite the docs (``densify``, ``learn``)."""


def echo(text: str) -> None:
    """Print one line of a command's report at once (standard error with ``-o -``).

    A line whose reader is gone (``| head -1``) is dropped and the command goes on
    (:mod:`pcainterp_stream.cli.streams`).

    Raises:
        PcaInterpError: standard output cannot be written (a full disk, ``> /dev/full``).
    """
    _print(text, sys.stdout, "standard output")  # sys.stdout at the time of the call


def warn(text: str) -> None:
    """Print a ``warning:`` line on standard error, where ``error:`` lines go.

    ``text`` is the warning without its prefix. The report stays on standard output, so
    ``> run.log`` keeps the warnings on the terminal and ``2> warnings.txt`` collects them.

    Raises:
        PcaInterpError: standard error cannot be written (a full disk).
    """
    _print(f"warning: {text}", sys.stderr, "standard error")


def report_line(line: str) -> None:
    """Print a line the library made for the report; a ``warning:`` one as :func:`warn` does."""
    if line.startswith("warning: "):
        warn(line.removeprefix("warning: "))
    else:
        echo(line)


def _print(text: str, stream: Any, name: str) -> None:
    try:
        try:
            print(text, file=stream, flush=True)
        except UnicodeEncodeError:  # a name the stream cannot encode (in-process callers')
            encoding = getattr(stream, "encoding", None) or "utf-8"
            escaped = text.encode(encoding, "backslashreplace").decode(encoding)
            print(escaped, file=stream, flush=True)
    except BrokenPipeError:
        pass  # the reader is gone; the job is not (outside the program: in-process callers)
    except OSError as err:
        raise PcaInterpError(
            f"cannot print to {name}: {err.strerror or err}; redirect it to a "
            "writable file (outputs already complete are kept, partial ones removed)"
        ) from None


def print_written(summary: WriteSummary) -> None:
    """Print the line that closes a command which wrote a log."""
    duration = ((summary.end_ns or 0) - (summary.start_ns or 0)) / 1e9
    echo(f"wrote {summary.path}: {summary.message_count} messages, {duration:.1f} s of log")


# ----------------------------------------------------------------------------- outputs


STREAM = Path("-")
"""A log named ``-``: standard input (INPUT) or standard output (``-o``), not a file."""


FILE_INPUTS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "learn": (
        ("logs", "LOG", "the logs to learn from"),
        ("fit_logs", "--fit-logs", "the logs to fit on"),
        ("calibration", "--calibration", "the calibration YAML files"),
    ),
    "densify": (
        ("basis", "--basis", "a basis .npz (or builtin)"),
        ("calibration", "--calibration", "the calibration YAML files"),
    ),
    "evaluate": (
        ("input", "DENSIFIED.mcap", "the densified log"),
        ("basis", "--basis", "a basis .npz (or builtin)"),
        ("calibration", "--calibration", "the calibration YAML files"),
    ),
    "info": (("file", "FILE", "a log, a basis .npz or a golden file"),),
    "golden": (("log", "LOG", "the log"), ("golden", "GOLDEN.json", "the golden file")),
    "import-kitti": (("kitti_dir", "KITTI_DIR", "the KITTI folder"),),
}
"""Command -> (attribute, its name on the command line, what to pass) of each input that is
read as a file or folder, never from standard input (only ``densify``'s INPUT is)."""


def refuse_stdin_inputs(args: argparse.Namespace) -> None:
    """Refuse ``-`` (:data:`STREAM`) given for an input that is not read from standard input.

    Without this, ``pcainterp info -`` said "- does not exist", as if a file were missing.

    Raises:
        PcaInterpError: "FILE is -, but info does not read standard input ...".
    """
    for attribute, name, what in FILE_INPUTS.get(args.command, ()):
        value = getattr(args, attribute, None)
        values = value if isinstance(value, list | tuple) else [value]
        if any(isinstance(given, Path) and given == STREAM for given in values):
            command = " ".join([args.command, getattr(args, "golden_command", None) or ""])
            only = "its" if args.command == "densify" else "densify's"
            raise PcaInterpError(
                f"{name} is -, but {command.strip()} does not read standard input (only "
                f"{only} INPUT does); name {what} by path (a file named -: ./-)"
            )


def same_file(first: Path, second: Path) -> bool:
    """Return whether two paths name one file: one inode where both exist, else one path."""
    with contextlib.suppress(OSError):  # exists() raises for a name too long (ENAMETOOLONG)
        if first.exists() and second.exists():
            return os.path.samefile(first, second)
    return os.path.realpath(first) == os.path.realpath(second)  # resolve(): a loop raises


def refuse_overwrites(
    writes: Iterable[tuple[str, Path | None, str]], reads: Iterable[tuple[str, Path | None]]
) -> None:
    """Refuse, before any work, a file a command writes that it also reads or writes already.

    Args:
        writes: (what it is, its path, the fix) of each file the command writes, in the
            order it writes them; each is checked against ``reads`` and the writes before it.
        reads: (what it is, its path) of each file the command reads.
        None and ``-`` (:data:`STREAM`) are not files and are skipped.

    Raises:
        LogWriteError: "refusing to write the --rrd recording onto the input drive.mcap;
            choose a different --rrd path".
    """
    others = [(what, path) for what, path in reads if path is not None and path != STREAM]
    read_paths = list(others)
    for what, path, fix in writes:
        if path is None or path == STREAM:
            continue
        too_long = name_too_long(path)  # a side file's (OUT.final.basis.npz): before any work
        if too_long is not None:
            named = what if path.name in what else f"{what} {path}"
            why = fix[fix.find("(") :] if "(" in fix else ""  # why a side file is written
            raise LogWriteError(f"cannot write {named}: {too_long} {why}".rstrip())
        for other, other_path in others:
            if same_file(path, other_path):
                raise LogWriteError(f"refusing to write {what} onto {other} {other_path}; {fix}")
        for _, read in others[: len(read_paths)]:
            bag = input_bag(path, read)
            if bag is not None:
                raise LogWriteError(
                    f"refusing to write {what} {path} inside the input bag {bag}: it would "
                    f"replace or join the recording's own files; {fix} outside the bag"
                )
        others.append((what, path))


def refuse_stream_output(path: Path, option: str, writes: str, example: str) -> None:
    """Refuse ``-`` (:data:`STREAM`) as the output of a command that writes no stream.

    Only ``densify -o -`` writes standard output; elsewhere ``-`` would be a file or folder
    named ``-`` that no one asked for.

    Args:
        path: the output given.
        option: how the command line names it (``-o``, ``OUT``).
        writes: what the command writes (``learn writes a basis file (.npz)``).
        example: a path to suggest (``basis.npz``).

    Raises:
        LogWriteError: ``path`` is ``-``.
    """
    if path == STREAM:
        name = f"{option} " if option.startswith("-") else ""
        raise LogWriteError(
            f"{option} is -, but {writes}, which cannot go to standard output; "
            f"name a path, e.g. {name}{example}"
        )


def check_log_output(path: Path, log_format: str | None, command: str) -> None:
    """Refuse, before any work, a log output (``synth``, ``import-kitti``) it cannot write.

    Args:
        path: OUT as given.
        log_format: ``--format``, or None for the format ``path``'s name says.
        command: the command, for the message.

    Raises:
        LogWriteError: OUT is ``-``, its suffix names no log format (without ``--format``),
            or it is an existing file where a rosbag2 bag (a folder) would go.
    """
    from pcainterp_stream.io.logwriter import LogFormat, format_from_path

    refuse_stream_output(
        path, "OUT", f"{command} writes a log file (.mcap, .bag) or a rosbag2 folder", "drive.mcap"
    )
    if log_format is not None:
        chosen = LogFormat(log_format)
    else:
        try:
            chosen = format_from_path(path)
        except LogWriteError:  # the library's words: "pass the format explicitly"
            fix = ", or pass --format" if command == "synth" else ""
            raise LogWriteError(
                f"output {path} is named {path.suffix}, which is no log format; name it .mcap "
                f"or .bag, or without a suffix for a rosbag2 folder{fix}"
            ) from None
    if chosen in (LogFormat.ROSBAG2, LogFormat.ROSBAG2_SQLITE3) and path.is_file():
        how, fix = (
            (f"--format {chosen.value}", "choose another path")
            if log_format is not None
            else ("a name without a suffix", f"name the output {path}.mcap or {path}.bag")
        )
        raise LogWriteError(
            f"output {path} is an existing file, but {how} writes a rosbag2 bag, which is a "
            f"folder; {fix}, or remove the file"
        )


BUILTIN_BASIS_NAMES = {
    "builtin": "auto",
    "builtin-street": "street",
    "builtin-indoor": "indoor",
}
"""What ``--basis`` takes besides a file (densify, evaluate) -> the built-in basis kind;
``auto``: the one the command chooses (densify: by the fit check)."""


def basis_option(value: Path | None) -> tuple[Path | None, str | None]:
    """Read ``--basis``: the name of a built-in basis, or the path of a basis file.

    The file is checked where it is read; only a missing one named like a built-in basis
    (``builtin-indor``, ``built-in``) is refused here, with the names listed.

    Returns:
        (None, kind) for a name of :data:`BUILTIN_BASIS_NAMES`, (the path, None) for a file,
        (None, None) when ``--basis`` was not given.

    Raises:
        BasisError: a missing file named like a built-in basis.
    """
    if value is None:
        return None, None
    kind = BUILTIN_BASIS_NAMES.get(str(value))
    if kind is not None:
        return None, kind
    if value.name.lower().startswith("built") and not value.exists():
        from pcainterp_stream.errors import BasisError
        from pcainterp_stream.estimate.basis import check_basis_file

        try:
            check_basis_file(value)
        except BasisError as err:
            *first, last = BUILTIN_BASIS_NAMES
            raise BasisError(f"{err}, or one of {', '.join(first)} and {last}") from None
    return value, None


# ----------------------------------------------------------------------------- stereo front end


def add_stereo_options(parser: argparse.ArgumentParser, *, command: str) -> None:
    """Add the GFTT and SGBM options of ``learn`` and ``densify`` (``command``)."""
    densify = command == "densify"
    dense = "; --measurements dense: {}" if densify else ""
    group = parser.add_argument_group(
        "stereo front end (GFTT corners, SGBM lookups)"
        if densify
        else "stereo front end (SGBM maps; GFTT corners of the frames the prior is fitted on)"
    )
    group.add_argument(
        "--corners",
        type=int,
        default=None,
        metavar="N",
        help="max GFTT corners, 0 = none (default 250"
        + ("; --measurements dense at full resolution: 0, the lattice alone)" if densify else ")"),
    )
    group.add_argument(
        "--quality",
        type=float,
        default=None,
        metavar="Q",
        help="GFTT quality level: a corner's least response as a share of the strongest's, "
        "in (0, 1) (default 0.01)",
    )
    group.add_argument(
        "--min-distance",
        type=float,
        default=None,
        metavar="PX",
        help="GFTT min distance between two corners, px (default 10)",
    )
    group.add_argument(
        "--fill-spacing",
        type=float,
        default=None,
        metavar="PX",
        help="lattice of extra lookups in the corners' gaps, side in px (default 40"
        + ("; --measurements dense at full resolution: 34" if densify else "")
        + "; 0 = off); denser is sharper and slower: 36 measured 4-7 %% lower error on "
        "KITTI and synthetic drives for 1.2x the estimate's CPU, 30 11-17 %% on KITTI; at "
        f"least {defaults.MIN_FILL_SPACING:g}, GFTT's default min corner distance (denser "
        "lookups share their SGBM windows, and the estimate's cost grows faster than the "
        "points: 10 px is ~10 s per KITTI frame); on images larger than ~1920x1080 the side "
        "grows with the image, so the lattice keeps 1920x1080's points (4096x2160: x2.06)",
    )
    group.add_argument(
        "--fill-placement",
        choices=["nudged", "lattice"],
        default=None,
        help="nudged (default" + dense.format("lattice") + "): a lattice point whose lookup "
        "fails is moved a quarter side to where one passes; lattice: such a point is dropped",
    )
    group.add_argument(
        "--num-disparities",
        type=int,
        default=None,
        metavar="N",
        help="SGBM disparity range, px, a multiple of 16 (default 128"
        + dense.format("160, matched at half resolution and refined at full")
        + ")",
    )
    group.add_argument(
        "--block-size",
        type=int,
        default=None,
        metavar="N",
        help="SGBM matching block side, px, odd (default 5)",
    )
    group.add_argument(
        "--sgbm-mode",
        choices=["sgbm", "hh", "sgbm_3way", "hh4"],
        default=None,
        help="SGBM variant: sgbm (5 directions in one pass), hh (8, much more memory), "
        "sgbm_3way (3, parallel over strips; the default), hh4 (4)",
    )
    group.add_argument(
        "--stereo-downscale",
        type=_downscale if densify else int,
        choices=None if densify else [1, 2],
        default=None,
        metavar="{auto,1,2}" if densify else None,
        help="match at 1/N resolution: 2 is ~4x cheaper SGBM for lookups biased by +0.1-0.3 "
        "px, as good a dense map on KITTI-like cameras (default "
        + (
            f"auto: 1 when the camera's f*b is below {defaults.FULL_RESOLUTION_FB:g} px*m "
            "(small disparities) and its images at most 1280x720, else 2; "
            "--measurements dense: 1; docs/results.md); at 1, given or chosen, SGBM also "
            "matches its left band x < --num-disparities"
            if densify
            else "1; docs/benchmarks.md)"
        ),
    )


def _downscale(value: str) -> int | None:
    """``--stereo-downscale``: 1 or 2; ``auto`` (densify's default) is None."""
    if value in ("1", "2"):
        return int(value)
    if value == "auto":
        return None
    raise argparse.ArgumentTypeError(f"expected auto, 1 or 2, got {value!r}")


def sgbm_config(args: argparse.Namespace, base: SgbmConfig | None = None) -> SgbmConfig:
    """Return ``base`` (default: ``SgbmConfig()``) with the SGBM options given changed.

    Raises:
        PcaInterpError: a disparity range or block size SGBM does not take.
    """
    from pcainterp_stream.frontend.stereo import SgbmConfig, SgbmMode

    changes: dict[str, Any] = {}
    if args.num_disparities is not None:
        if args.num_disparities < 16 or args.num_disparities % 16:
            raise PcaInterpError(
                f"--num-disparities must be a positive multiple of 16, got {args.num_disparities}"
            )
        changes["num_disparities"] = args.num_disparities
    if args.block_size is not None:
        if args.block_size < 1 or args.block_size % 2 == 0:
            raise PcaInterpError(f"--block-size must be odd and positive, got {args.block_size}")
        changes["block_size"] = args.block_size
    if args.sgbm_mode is not None:
        changes["mode"] = SgbmMode[args.sgbm_mode.upper()]
    if args.stereo_downscale is not None:  # given: not chosen per camera
        changes["downscale"] = args.stereo_downscale
        changes["by_camera"] = False
    return dataclasses.replace(SgbmConfig() if base is None else base, **changes)


def gftt_config(args: argparse.Namespace, base: GfttConfig | None = None) -> GfttConfig:
    """Return ``base`` (None: ``GfttConfig()``) with the corner options given changed.

    Raises:
        PcaInterpError: a corner count, quality or distance out of its range, or neither
            corners nor a lattice.
    """
    from pcainterp_stream.frontend.stereo import GfttConfig

    changes: dict[str, Any] = {}
    if args.corners is not None:
        if args.corners < 0:
            raise PcaInterpError(f"--corners must be at least 0, got {args.corners}")
        changes["max_corners"] = args.corners
    if args.quality is not None:
        if not 0 < args.quality < 1:
            raise PcaInterpError(f"--quality must be in (0, 1), got {args.quality}")
        changes["quality_level"] = args.quality
    if args.min_distance is not None:
        if not args.min_distance >= 0:
            raise PcaInterpError(f"--min-distance must be >= 0 px, got {args.min_distance}")
        changes["min_distance"] = args.min_distance
    if args.fill_spacing is not None:
        low = defaults.MIN_FILL_SPACING
        if not (args.fill_spacing == 0 or args.fill_spacing >= low):
            raise PcaInterpError(
                f"--fill-spacing must be 0 (no lattice) or at least {low:g} px (GFTT's "
                f"default min corner distance; see --help), got {args.fill_spacing:g}"
            )
        changes["fill_spacing"] = args.fill_spacing
    if getattr(args, "fill_placement", None) is not None:
        changes["fill_placement"] = args.fill_placement
    config = GfttConfig() if base is None else base
    if changes.get("max_corners", config.max_corners) == 0:
        if changes.get("fill_spacing", config.fill_spacing) <= 0:
            raise PcaInterpError(
                "--corners 0 --fill-spacing 0 leaves no point to measure; "
                "give corners or a lattice spacing"
            )
    return dataclasses.replace(config, **changes)


# ----------------------------------------------------------------------------- Dask


def add_cluster_options(parser: argparse.ArgumentParser, *, command: str) -> None:
    """Add ``--scheduler`` and ``--workers`` (``learn``, ``densify --out-dir``: ``command``)."""
    group = parser.add_argument_group(
        "scale-out on Dask (with --out-dir; default: 2 local workers)"
        if command == "densify"
        else "scale-out on Dask (default: this process)"
    )
    where = group.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler", default=None, metavar="ADDRESS", help="a running Dask scheduler"
    )
    where.add_argument(
        "--workers", type=int, default=None, metavar="N", help="a local cluster of N processes"
    )
    group.add_argument(
        "--worker-wait",
        type=float,
        default=None,
        metavar="SECONDS",
        help="with --scheduler: how long to wait for a worker while the scheduler has none "
        "(default 60)",
    )


def check_cluster_options(args: argparse.Namespace) -> None:
    """Check ``--scheduler`` and ``--worker-wait`` before any input is read.

    Raises:
        PcaInterpError: a malformed address, or a wait that is not a positive number.
    """
    if args.worker_wait is not None:
        if args.scheduler is None:
            raise PcaInterpError(
                "--worker-wait is the wait for a --scheduler's workers; add --scheduler"
            )
        if not 0 < args.worker_wait < float("inf"):
            raise PcaInterpError(f"--worker-wait must be > 0 seconds, got {args.worker_wait:g}")
    if args.scheduler is None:
        return
    from pcainterp_stream.pipeline.scheduler import check_address

    try:
        args.scheduler = check_address(args.scheduler)
    except PcaInterpError as err:
        raise PcaInterpError(f"--scheduler {err}") from None


def cluster_notes(line: str) -> None:
    """Print a note on the cluster (connecting, waiting for workers) on standard error."""
    print(line, file=sys.stderr, flush=True)


def worker_wait(args: argparse.Namespace) -> float:
    """Return ``--worker-wait`` or the default (seconds)."""
    from pcainterp_stream.pipeline.scheduler import DEFAULT_WORKER_WAIT

    return float(args.worker_wait) if args.worker_wait is not None else DEFAULT_WORKER_WAIT
