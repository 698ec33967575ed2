"""``pcainterp info``: what a log or a basis file holds."""

from __future__ import annotations

import argparse
from pathlib import Path

from pcainterp_stream.cli.common import Commands, echo, formatter


def add_parser(commands: Commands) -> None:
    """Add ``info`` to the commands."""
    info = commands.add_parser(
        "info",
        formatter_class=formatter,
        help="describe a log (topics, counts, duration) or a basis file",
        epilog=(
            "examples:\n  pcainterp info drive.mcap\n  pcainterp info basis.npz\n"
            "  pcainterp info                  # the built-in basis\n"
        ),
    )
    info.add_argument(
        "file", type=Path, nargs="?", default=None, metavar="FILE", help="default: built-in basis"
    )


def run(args: argparse.Namespace) -> int:
    """Describe the file (default: the built-in basis); return the exit code."""
    from pcainterp_stream.pipeline.jobs import info

    echo(info(args.file))
    return 0
