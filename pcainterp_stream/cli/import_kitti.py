"""``pcainterp import-kitti``: a KITTI raw drive or odometry sequence as an MCAP log."""

from __future__ import annotations

import argparse
from pathlib import Path

from pcainterp_stream.cli.common import Commands, formatter, print_written


def add_parser(commands: Commands) -> None:
    """Add ``import-kitti`` to the commands."""
    kitti = commands.add_parser(
        "import-kitti",
        formatter_class=formatter,
        help="convert a KITTI raw drive or odometry sequence into an MCAP log",
        description=(
            "Convert a KITTI raw drive folder (<date>/<date>_drive_XXXX_sync) or an odometry\n"
            "sequence (sequences/XX with calib.txt) into the project's MCAP layout."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp import-kitti 2011_09_26/2011_09_26_drive_0001_sync drive.mcap\n"
            "  pcainterp import-kitti dataset/sequences/00 seq00.mcap\n"
        ),
    )
    kitti.add_argument("kitti_dir", type=Path, metavar="KITTI_DIR")
    kitti.add_argument("out", type=Path, metavar="OUT")
    kitti.add_argument("--max-frames", type=int, default=None, metavar="N")


def run(args: argparse.Namespace) -> int:
    """Convert the KITTI folder; return the exit code."""
    from pcainterp_stream.pipeline.jobs import import_kitti

    print_written(import_kitti(args.kitti_dir, args.out, max_frames=args.max_frames))
    return 0
