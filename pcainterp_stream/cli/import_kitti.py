"""``pcainterp import-kitti``: a KITTI raw drive or odometry sequence as an MCAP log."""

from __future__ import annotations

import argparse

from pcainterp_stream.cli.common import (
    Commands,
    check_log_output,
    formatter,
    path_arg,
    print_written,
)


def add_parser(commands: Commands) -> None:
    """Add ``import-kitti`` to the commands."""
    kitti = commands.add_parser(
        "import-kitti",
        formatter_class=formatter,
        help="convert a KITTI raw drive or odometry sequence into an MCAP log",
        description=(
            "Convert a KITTI raw drive folder (<date>/<date>_drive_XXXX_sync) or an odometry\n"
            "sequence (sequences/XX with calib.txt) into the project's MCAP layout: the grey\n"
            "pair (cameras 0/1), or the colour pair (cameras 2/3, converted to grey) in a\n"
            "folder without the grey one or with --colour. An unrectified drive\n"
            "(<date>_drive_XXXX_extract, images of S_00's size) is written as a raw log:\n"
            "/camera/{left,right}/image_raw with each camera's CameraInfo (K, D, R_rect,\n"
            "P_rect of calib_cam_to_cam.txt), which densify rectifies; its cameras' images\n"
            "are paired by their timestamps. Images of another size than S_rect_00 or S_00\n"
            "are refused."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp import-kitti 2011_09_26/2011_09_26_drive_0001_sync drive.mcap\n"
            "  pcainterp import-kitti 2011_09_26/2011_09_26_drive_0001_extract raw.mcap\n"
            "  pcainterp import-kitti dataset/sequences/00 seq00.mcap\n"
            "  pcainterp import-kitti dataset/sequences/00 seq00_colour.mcap --colour\n"
        ),
    )
    kitti.add_argument(
        "kitti_dir",
        type=path_arg,
        metavar="KITTI_DIR",
        help="a raw drive folder (<date>/<date>_drive_XXXX_sync, or the unrectified _extract, "
        "its calibration files in the date folder) or an odometry sequence folder "
        "(sequences/XX with calib.txt)",
    )
    kitti.add_argument(
        "out",
        type=path_arg,
        metavar="OUT",
        help="the log to write: .mcap an MCAP, .bag a ROS 1 bag, a name without a suffix a "
        "rosbag2 folder (MCAP storage)",
    )
    kitti.add_argument(
        "--max-frames",
        type=int,
        default=None,
        metavar="N",
        help="import the first N frames only (default: all)",
    )
    kitti.add_argument(
        "--colour",
        action="store_true",
        help="import the colour pair (image_2/image_3 with P2/P3 of calib.txt; a raw drive's "
        "image_02/image_03 with P_rect_02/P_rect_03) as grey images, also where the grey "
        "pair is there (default: the grey pair, the colour one in a folder without it)",
    )


def run(args: argparse.Namespace) -> int:
    """Convert the KITTI folder; return the exit code."""
    from pcainterp_stream.pipeline.jobs import import_kitti

    check_log_output(args.out, None, "import-kitti")
    print_written(
        import_kitti(args.kitti_dir, args.out, max_frames=args.max_frames, colour=args.colour)
    )
    return 0
