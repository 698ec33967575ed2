"""``pcainterp synth``: a synthetic stereo log with ground truth."""

from __future__ import annotations

import argparse

from pcainterp_stream.cli.common import (
    Commands,
    check_log_output,
    formatter,
    path_arg,
    print_written,
)
from pcainterp_stream.errors import PcaInterpError


def add_parser(commands: Commands) -> None:
    """Add ``synth`` to the commands."""
    synth = commands.add_parser(
        "synth",
        formatter_class=formatter,
        help="write a synthetic stereo log with ground truth (a street drive or indoors)",
        description="Render a procedural street world (or an indoor scene, --scene) and write "
        "a stereo log with ground truth.",
        epilog=(
            "examples:\n"
            "  pcainterp synth drive.mcap                       # 100 frames at KITTI size\n"
            "  pcainterp synth small.mcap --frames 10 --scale 0.25\n"
            "  pcainterp synth drive_bag --format rosbag2 --seed 3\n"
            "  pcainterp synth drive.bag --format ros1\n"
            "  pcainterp synth lidar.mcap --frames 10 --scale 0.5 --lidar  # + sparse LiDAR truth\n"
            "  pcainterp synth raw.mcap --frames 10 --scale 0.5 --raw      # as a driver records\n"
            "  pcainterp synth room.mcap --scene indoor --camera 752x480 --frames 50  # indoor\n"
        ),
    )
    synth.add_argument("out", type=path_arg, metavar="OUT", help="output log path")
    synth.add_argument(
        "--frames",
        type=int,
        default=100,
        metavar="N",
        help="frames to render: 10 per second of log, 20 with --scene indoor "
        "(default: %(default)s)",
    )
    synth.add_argument("--seed", type=int, default=0, metavar="S", help="world seed (default: 0)")
    synth.add_argument(
        "--scale",
        type=float,
        default=1.0,
        metavar="F",
        help="image scale: 1 = 1241x376, or the --camera size (default: %(default)s)",
    )
    synth.add_argument(
        "--format",
        choices=["mcap", "rosbag2", "rosbag2-sqlite3", "ros1"],
        default=None,
        help="log format (default: from OUT's suffix; .mcap -> mcap, .bag -> ros1)",
    )
    synth.add_argument(
        "--lidar",
        action="store_true",
        help="also write /ground_truth/lidar_depth: the true depth where a 64-beam scanner "
        "would return (scan lines, ~4 %% of the pixels at any --scale; NaN elsewhere)",
    )
    synth.add_argument(
        "--raw",
        nargs="?",
        const="plumb_bob",
        default=None,
        choices=["plumb_bob", "equidistant"],
        help="record it as a stereo driver does: raw images through a distorting lens "
        "(default plumb_bob) slightly rotated from the rectified pair, on "
        "/camera/{left,right}/image_raw with their CameraInfo; the truth is the rectified "
        "left camera's",
    )
    synth.add_argument(
        "--scene",
        choices=["street", "indoor", "room", "corridor", "hall"],
        default="street",
        help="street (default) or indoor: a room, corridor or hall with clutter (indoor picks "
        "one by --seed), 20 Hz",
    )
    synth.add_argument(
        "--camera",
        choices=["kitti", "752x480", "640x480", "1280x720", "fisheye-752x480"],
        default="kitti",
        help="stereo camera: KITTI's grey pair (default, 1241x376, b 0.54 m), a VI-sensor "
        "(752x480, b 0.11 m), a depth camera (640x480, b 0.05 m), a wide pair (1280x720, "
        "b 0.12 m), a rectified fisheye (752x480, wide field of view)",
    )
    synth.add_argument(
        "--platform",
        choices=["auto", "handheld", "drone", "robot"],
        default="auto",
        help="indoor: what carries the camera, its height and pitch (default: by --seed)",
    )


def run(args: argparse.Namespace) -> int:
    """Render the world asked for and write its log; return the exit code."""
    if args.seed < 0:
        raise PcaInterpError(f"--seed must be >= 0, got {args.seed}")
    check_log_output(args.out, args.format, "synth")
    if args.raw is not None:
        return _run_raw(args)
    from pcainterp_stream.pipeline.jobs import synth

    print_written(
        synth(
            args.out,
            frames=args.frames,
            seed=args.seed,
            scale=args.scale,
            fmt=args.format,
            lidar=args.lidar,
            scene=args.scene,
            camera=args.camera,
            platform=args.platform,
        )
    )
    return 0


def _run_raw(args: argparse.Namespace) -> int:
    """``synth --raw``: the street drive as a stereo driver records it."""
    from pcainterp_stream.pipeline.jobs import synth_raw

    if args.lidar:
        raise PcaInterpError("--lidar is not written with --raw; drop one of them")
    if (args.scene, args.camera, args.platform) != ("street", "kitti", "auto"):
        raise PcaInterpError(
            "--raw records the street drive through the KITTI-like camera; "
            "drop --scene, --camera and --platform, or --raw"
        )
    print_written(
        synth_raw(
            args.out,
            frames=args.frames,
            seed=args.seed,
            scale=args.scale,
            fmt=args.format,
            model=args.raw,
        )
    )
    return 0
