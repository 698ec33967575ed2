"""``pcainterp golden save`` and ``pcainterp golden check``: golden-file tests of logs.

Options are declared beside the function that runs them; the work is one call into
:mod:`pcainterp_stream.golden.store`. Exit codes: 0 the log matches (or was saved), 1 it
differs (the differences are printed), 2 bad input (printed by the caller as one line).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

from pcainterp_stream.cli.common import (
    Commands,
    echo,
    file_output_arg,
    formatter,
    path_arg,
    refuse_stream_output,
    same_file,
)
from pcainterp_stream.errors import PcaInterpError

DEFAULT_MAX_LINES = 20


def add_parser(commands: Commands) -> None:
    """Add ``golden`` and its actions ``save`` and ``check`` to the commands."""
    golden = commands.add_parser(
        "golden",
        formatter_class=formatter,
        help="snapshot a log in a golden file, or check a log against one",
        description=(
            "Golden-file tests of logs. `save` records what a log contains (channels,\n"
            "schemas, message counts, log times, header stamps, values, and robust\n"
            "statistics of every image, point cloud and numeric array) with the\n"
            "tolerances it is checked within; `check` compares a later log with it.\n"
            "Any MCAP, ROS 1 .bag or rosbag2 works."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp golden save drive_dense.mcap -o drive.golden.json\n"
            "  pcainterp golden save drive_dense.mcap -o drive.golden.json --arrays\n"
            "  pcainterp golden check drive_dense.mcap drive.golden.json\n"
            "  pcainterp golden check drive_dense.mcap drive.golden.json "
            "--topics /pcainterp/depth\n"
            "  pcainterp golden check drive_dense.mcap drive.golden.json --update\n"
            "exit codes: 0 matches, 1 differs (differences printed), 2 bad input"
        ),
    )
    actions = golden.add_subparsers(dest="golden_command", metavar="ACTION", required=True)
    save = actions.add_parser(
        "save",
        formatter_class=formatter,
        help="write the golden file of a log",
        description="Write the golden file of a log: what it contains and the tolerances a "
        "later log is checked within.",
        epilog="example:\n  pcainterp golden save drive_dense.mcap -o drive.golden.json --arrays",
    )
    save.add_argument("log", type=path_arg, metavar="LOG", help="MCAP file, ROS 1 .bag or rosbag2")
    save.add_argument(
        "-o",
        "--output",
        type=file_output_arg("golden save writes one JSON file", "-o {}drive.golden.json"),
        required=True,
        metavar="GOLDEN.json",
        help="file to write",
    )
    save.add_argument(
        "--arrays",
        action="store_true",
        help="also store every array (compressed <stem>.golden.npz beside the JSON) for an "
        "element-wise check with atol/rtol (depth: in units of its published std)",
    )
    save.add_argument(
        "--topics", nargs="+", default=None, metavar="TOPIC", help="record only these channels"
    )
    check = actions.add_parser(
        "check",
        formatter_class=formatter,
        help="check a log against its golden file (exit 1 and the differences when it differs)",
        description="Check a log against its golden file: exit 0 when it matches within the "
        "file's tolerances, else exit 1 and the differences.",
        epilog="example:\n  pcainterp golden check drive_dense.mcap drive.golden.json",
    )
    check.add_argument("log", type=path_arg, metavar="LOG", help="MCAP file, ROS 1 .bag or rosbag2")
    check.add_argument("golden", type=path_arg, metavar="GOLDEN.json", help="a golden file")
    check.add_argument(
        "--topics", nargs="+", default=None, metavar="TOPIC", help="check only these channels"
    )
    check.add_argument(
        "--update",
        action="store_true",
        help="rewrite the golden file from LOG when they differ (with --topics: only those "
        "channels, the others keep what the file recorded)",
    )
    check.add_argument(
        "--max-lines",
        type=int,
        default=DEFAULT_MAX_LINES,
        metavar="N",
        help="print at most N differences, then their count (default: %(default)s)",
    )


@contextmanager
def _progress(description: str) -> Iterator[Callable[[int, int | None], None]]:
    """Yield a progress callback ``(done, total)`` for the messages read.

    The bar the other jobs show (:func:`pcainterp_stream.pipeline.common._bar`): ``tqdm``
    on a terminal, off one a plain line a minute; made at the first call, which knows the
    total.
    """
    from pcainterp_stream.pipeline.common import _bar

    bar: Any = None
    with ExitStack() as closing:

        def update(done: int, total: int | None) -> None:
            nonlocal bar
            if bar is None:
                bar = closing.enter_context(_bar(total, description, unit="message"))
            bar.update(done - bar.n)

        yield update


def run(args: argparse.Namespace) -> int:
    """Run ``pcainterp golden save|check``; return the exit code (0, 1, or raise for 2).

    Raises:
        PcaInterpError: bad input (a missing or damaged log, a golden file of another
            format version, a missing channel, a bad option); the caller prints it.
    """
    from pcainterp_stream.golden.comparison import count_differences, format_differences
    from pcainterp_stream.golden.store import arrays_path, check_log, save_golden

    if args.golden_command == "save":
        refuse_stream_output(
            args.output, "-o", "golden save writes a golden file (.json)", "drive.golden.json"
        )
        if same_file(args.output, args.log):
            raise PcaInterpError(f"-o {args.output} is the log itself; name another file")
        with _progress(f"summarising {args.log.name}") as progress:
            summary = save_golden(
                args.log, args.output, topics=args.topics, arrays=args.arrays, progress=progress
            )
        messages = sum(c["message_count"] for c in summary.channels.values())
        extra = f" and {arrays_path(args.output).name}" if args.arrays else ""
        echo(f"wrote {args.output}{extra}: {len(summary.channels)} channels, {messages} messages")
        for note in summary.notes[:5]:
            echo(f"note: {note}")
        return 0
    if args.max_lines < 0:
        raise PcaInterpError(f"--max-lines must be >= 0, got {args.max_lines}")
    with _progress(f"checking {args.log.name}") as progress:
        result = check_log(
            args.log, args.golden, topics=args.topics, update=args.update, progress=progress
        )
    for note in result.notes[:5]:
        echo(f"note: {note}")
    if len(result.notes) > 5:
        echo(f"note: ... and {len(result.notes) - 5} more notes")
    if result.passed:
        echo(f"{args.log.name} matches {args.golden.name}")
        if result.updated:
            echo(f"rewrote {args.golden} from {args.log.name} in the current format")
        return 0
    echo(format_differences(result.differences, args.max_lines))
    count = len(result.differences)
    plural = "s" if count > 1 else ""
    if result.updated:
        what = f" (channels {', '.join(args.topics)} only)" if args.topics else ""
        echo(f"{count} difference{plural}; rewrote {args.golden}{what} from {args.log.name}")
        return 0
    echo(
        f"{args.log.name} differs from {args.golden.name} in "
        f"{count_differences(result.differences)} (pass --update to accept the log as the new "
        "golden)"
    )
    return 1
