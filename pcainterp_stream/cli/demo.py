"""``pcainterp demo``: a generated drive densified with the built-in basis, and its summary."""

from __future__ import annotations

import argparse
from pathlib import Path

from pcainterp_stream.cli.common import Commands, echo, formatter, path_arg
from pcainterp_stream.errors import PcaInterpError


def add_parser(commands: Commands) -> None:
    """Add ``demo`` to the commands."""
    demo = commands.add_parser(
        "demo",
        formatter_class=formatter,
        help="densify a generated drive with the built-in basis and print a summary",
        description=(
            "Render a synthetic drive the built-in basis never saw, densify it with the\n"
            "built-in basis and compare with ground truth (PCA-MAP against nearest neighbour,\n"
            "coverage of the std): about a minute. --learn runs the whole job instead:\n"
            "render training drives, learn a basis and fit its prior, then the same (~3 min)."
        ),
        epilog=(
            "examples:\n  pcainterp demo\n  pcainterp demo --out /tmp/demo --rerun\n"
            "  pcainterp demo --learn\n"
        ),
    )
    demo.add_argument(
        "--out",
        type=path_arg,
        default=Path("demo_out"),
        metavar="DIR",
        help="folder for the logs, the Rerun recording and the report (default: %(default)s)",
    )
    demo.add_argument("--rerun", action="store_true", help="watch the densified log in Rerun")
    demo.add_argument(
        "--learn", action="store_true", help="learn a basis from rendered drives first (~3 min)"
    )


def run(args: argparse.Namespace) -> int:
    """Run the demo; return the exit code."""
    from pcainterp_stream.io.rerun_sink import VIEWER_PORT, display_problem, viewer_listening
    from pcainterp_stream.pipeline.jobs import demo

    problem = display_problem() if args.rerun and not viewer_listening(VIEWER_PORT) else None
    if problem is not None:  # before the drive is rendered, not after
        raise PcaInterpError(
            f"{problem}; drop --rerun: the demo records {args.out / 'heldout.rrd'} anyway, "
            "open it with `rerun` where there is a display"
        )
    echo(demo(args.out, spawn_viewer=args.rerun, learn_basis=args.learn))
    return 0
