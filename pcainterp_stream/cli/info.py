"""``pcainterp info``: what a log or a basis file holds."""

from __future__ import annotations

import argparse

from pcainterp_stream.cli.common import Commands, echo, formatter, path_arg


def add_parser(commands: Commands) -> None:
    """Add ``info`` to the commands."""
    info = commands.add_parser(
        "info",
        formatter_class=formatter,
        help="describe a log (topics, counts, duration), a basis file or a golden file",
        description=(
            "Describe a log (its topics with their message counts and types, start, end and\n"
            "duration, an MCAP log's attachments and metadata records and, for a densified\n"
            "log, the bases it was densified with) or a basis file (its camera, grid,\n"
            "components, fitted prior and how it was learned; a fine-tuned basis also the\n"
            "camera of the maps it learned from); with no file, the two built-in bases and\n"
            "their recipes."
        ),
        epilog=(
            "examples:\n  pcainterp info drive.mcap\n  pcainterp info basis.npz\n"
            "  pcainterp info                  # the two built-in bases\n"
        ),
    )
    info.add_argument(
        "file",
        type=path_arg,
        nargs="?",
        default=None,
        metavar="FILE",
        help="a log (MCAP, ROS 1 bag, ROS 2 bag), a basis .npz or a golden file (default: the "
        "built-in bases)",
    )


def run(args: argparse.Namespace) -> int:
    """Describe the file (default: the built-in bases); return the exit code."""
    from pcainterp_stream.pipeline.jobs import info

    echo(info(args.file))
    return 0
