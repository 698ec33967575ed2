"""The ``pcainterp`` command line.

Parsing and error reporting only; the work is done by :mod:`pcainterp_stream.pipeline.jobs`, which
is imported lazily so that ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pcainterp_stream.golden.commands import add_golden_parser, run_golden
from pcainterp_stream.interrupt import end_if_signalled, stop_on_signals
from pcainterp_stream.pipeline.densify_cli import add_densify_arguments, live_options, run_densify
from pcainterp_stream.pipeline.pair_options import (
    add_input_pair_options,
    add_topic_options,
    learn_pairing,
    pairing_config,
)
from pcainterp_stream.version import __version__

if TYPE_CHECKING:
    from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig
    from pcainterp_stream.io.logwriter import WriteSummary
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.errors import PcaInterpError

PROG = "pcainterp"


def _formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


def _add_stereo_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("stereo front end (GFTT corners, SGBM lookups)")
    group.add_argument("--corners", type=int, default=None, metavar="N", help="max GFTT corners")
    group.add_argument(
        "--quality", type=float, default=None, metavar="Q", help="GFTT quality level"
    )
    group.add_argument(
        "--min-distance", type=float, default=None, metavar="PX", help="GFTT min corner distance"
    )
    group.add_argument(
        "--fill-spacing",
        type=float,
        default=None,
        metavar="PX",
        help="lattice of extra lookups in the corners' gaps, side in px (default 40; 0 = off)",
    )
    group.add_argument(
        "--num-disparities", type=int, default=None, metavar="N", help="SGBM disparity range"
    )
    group.add_argument("--block-size", type=int, default=None, metavar="N", help="SGBM block")
    group.add_argument(
        "--sgbm-mode",
        choices=["sgbm", "hh", "sgbm_3way", "hh4"],
        default=None,
        help="SGBM variant",
    )
    group.add_argument(
        "--stereo-downscale",
        type=int,
        choices=[1, 2],
        default=None,
        help="match at 1/N resolution: 2 is ~4x cheaper SGBM for slightly less exact "
        "lookups, as good a dense map (default: densify 2, learn 1; docs/benchmarks.md)",
    )


def _add_cluster_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "scale-out on Dask (learn: default this process; densify --out-dir: 2 local workers)"
    )
    where = group.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler", default=None, metavar="ADDRESS", help="a running Dask scheduler"
    )
    where.add_argument(
        "--workers", type=int, default=None, metavar="N", help="a local cluster of N processes"
    )


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``pcainterp``."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        formatter_class=_formatter,
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

    synth = commands.add_parser(
        "synth",
        formatter_class=_formatter,
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
    synth.add_argument("out", type=Path, metavar="OUT", help="output log path")
    synth.add_argument("--frames", type=int, default=100, metavar="N", help="(default: 100)")
    synth.add_argument("--seed", type=int, default=0, metavar="S", help="world seed (default: 0)")
    synth.add_argument(
        "--scale", type=float, default=1.0, metavar="F", help="image scale, 1 = 1241x376"
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

    kitti = commands.add_parser(
        "import-kitti",
        formatter_class=_formatter,
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

    learn = commands.add_parser(
        "learn",
        formatter_class=_formatter,
        help="learn a PCA basis from the disparity maps of logs",
        description=(
            "Learn a PCA basis of dense disparity maps from stereo logs: SGBM on every pair\n"
            "(or a ground-truth depth topic), the paper's preprocessing, streaming PCA; then\n"
            "fit the hybrid prior, sigma and the std calibration on held-out frames\n"
            "(--no-fit-prior: the paper's model alone). With few maps of your own (fewer\n"
            "than 1000) from a camera like KITTI's, it fine-tunes the built-in basis with\n"
            "them instead, and says so (--with-synthetic auto, the default; 0 turns it off)."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp learn a.mcap b.mcap -o basis.npz --components 300\n"
            "  pcainterp learn drive.mcap -o basis.npz --variance 0.95 --grid-scale 0.125\n"
            "  pcainterp learn synth.mcap -o basis.npz --depth-topic /ground_truth/depth\n"
            "  pcainterp learn a.mcap -o basis.npz --no-fit-prior     # the paper's model\n"
            "  pcainterp learn short.mcap -o basis.npz --with-synthetic 0  # your maps alone\n"
            "  pcainterp learn fleet/*.mcap -o basis.npz --scheduler tcp://10.0.0.5:8786\n"
        ),
    )
    learn.add_argument("logs", type=Path, nargs="+", metavar="LOG")
    learn.add_argument("-o", "--output", type=Path, required=True, metavar="BASIS.npz")
    size = learn.add_mutually_exclusive_group()
    size.add_argument("--components", type=int, default=None, metavar="L")
    size.add_argument("--variance", type=float, default=None, metavar="R")
    learn.add_argument("--grid-scale", type=float, default=None, metavar="G")
    learn.add_argument(
        "--depth-topic",
        default=None,
        metavar="TOPIC",
        help="learn from this depth image topic (32FC1, m) instead of SGBM maps",
    )
    learn.add_argument("--every", type=int, default=1, metavar="N", help="use every N-th frame")
    learn.add_argument(
        "--with-synthetic",
        default="auto",
        metavar="N|auto",
        help="fine-tune the built-in basis (learned from the synthetic world) with these logs' "
        "maps, counting it as N maps, and keep its local kernel; the result is on the "
        "built-in basis's grid and camera and applies to yours as any basis does. auto "
        "(default): N = 1000 when the logs give fewer than 1000 maps and their camera is "
        "like the built-in basis's (aspect ratio within 10 %%, f*b per image width within "
        "1.5x), else the maps alone; 0: the maps alone",
    )
    fit = learn.add_argument_group("fitted prior (docs/results.md, 'Beyond the paper')")
    fit.add_argument(
        "--fit-prior",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="fit the hybrid local prior, sigma, the temporal process noise and the std "
        "calibration by the evidence on frames the basis does not see (default; densify then "
        "uses them); --no-fit-prior learns the paper's model (basis and eigenvalues) only",
    )
    fit.add_argument(
        "--holdout",
        type=float,
        default=0.2,
        metavar="F",
        help="share of each log's frames (at its end) kept out of the basis for the fit "
        "(default: %(default)s)",
    )
    fit.add_argument(
        "--fit-logs",
        type=Path,
        nargs="+",
        default=(),
        metavar="LOG",
        help="fit on these logs instead of a held-out share",
    )
    _add_cluster_options(learn)
    add_topic_options(learn)
    _add_stereo_options(learn)

    densify = commands.add_parser(
        "densify",
        formatter_class=_formatter,
        help="densify a stereo log: add depth and uncertainty channels",
        description=(
            "Read a stereo log, densify every pair (GFTT + SGBM lookups + MAP), and write a\n"
            "copy of the log with /pcainterp/* depth and uncertainty channels added."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp densify drive.mcap -o drive_dense.mcap      # the built-in basis\n"
            "  pcainterp densify drive.mcap -o drive_dense.mcap --basis basis.npz\n"
            "  pcainterp densify drive.bag -o out.mcap --rerun\n"
            "  pcainterp densify slam.mcap -o out.mcap --features-topic /features\n"
            "  pcainterp densify logs/*.mcap --out-dir dense/ --basis b.npz --workers 2\n"
            "  pcainterp densify drive.mcap --foxglove      # live in Foxglove: ws://127.0.0.1:8765\n"
            "  cat drive.mcap | pcainterp densify - -o - > drive_dense.mcap\n"
        ),
    )
    add_densify_arguments(densify)
    _add_cluster_options(densify)
    add_topic_options(densify)
    _add_stereo_options(densify)

    evaluate = commands.add_parser(
        "evaluate",
        formatter_class=_formatter,
        help="measure a densified log (paper's Delta_2D/Delta_3D, calibration) into a report",
        description=(
            "Evaluate a log written by `pcainterp densify`: the paper's projection errors\n"
            "Delta_2D and Delta_3D against a reference (--reference-topic, any depth or\n"
            "disparity image topic of the log, dense or sparse; else the ground-truth depth\n"
            "when the log has it; else SGBM of the same pair), PCA-MAP against nearest-\n"
            "neighbour and linear interpolation on the same points and against SGBM's own\n"
            "map (sgbm, where it has a value; sgbm_nn, holes filled), depth-completion\n"
            "metrics, uncertainty calibration (also split into SGBM's holes and the rest);\n"
            "with the basis the log was densified with (it records which) also the oracle,\n"
            "paper vs exact uncertainty and the error against the number of points.\n"
            "Writes results.md, results.json and PNGs."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp evaluate drive_dense.mcap -o report/\n"
            "  pcainterp evaluate drive_dense.mcap -o report/ --basis basis.npz\n"
            "  pcainterp evaluate kitti_dense.mcap --mode stereo --max-frames 20 --no-basis\n"
            "  pcainterp evaluate drive_dense.mcap --reference-topic /ground_truth/lidar_depth\n"
            "  pcainterp evaluate kitti_dense.mcap --reference-topic /kitti/disparity_gt \\\n"
            "      --reference-kind disparity --mode stereo\n"
        ),
    )
    evaluate.add_argument("input", type=Path, metavar="DENSIFIED.mcap")
    evaluate.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        metavar="REPORT_DIR",
        help="report folder (default: DENSIFIED_report beside the log)",
    )
    evaluate.add_argument(
        "--basis",
        type=Path,
        default=None,
        metavar="BASIS.npz",
        help="the basis for the oracle, uncertainty kinds and points sweep (default: the one "
        "the log records it was densified with; the built-in one for older logs)",
    )
    evaluate.add_argument(
        "--no-basis",
        action="store_true",
        help="skip the rows that re-densify with a basis (faster)",
    )
    evaluate.add_argument(
        "--no-linear",
        action="store_true",
        help="skip linear interpolation (~0.5 s per KITTI-size frame)",
    )
    evaluate.add_argument(
        "--mode",
        choices=["stereo", "temporal"],
        default=None,
        help="view B: right camera (stereo) or next frame (temporal; needs poses); "
        "default temporal when the log has ground truth and poses",
    )
    evaluate.add_argument("--sigma", type=float, default=2.0, metavar="PX")
    evaluate.add_argument(
        "--sweep-every",
        type=int,
        default=10,
        metavar="N",
        help="points sweep on every N-th frame, 0 = off (default: %(default)s)",
    )
    evaluate.add_argument("--max-frames", type=int, default=None, metavar="N")
    evaluate.add_argument(
        "--reference-topic",
        default=None,
        metavar="TOPIC",
        help="score against this ground-truth image topic of the log, dense or sparse "
        "(e.g. projected LiDAR), matched to frames by header stamp: sensor_msgs/msg/Image "
        "32FC1 depth in m or 16UC1 in mm, or stereo_msgs/msg/DisparityImage; NaN, 0 or "
        "< 0 = no truth at that pixel (default: /ground_truth/depth if present, else SGBM)",
    )
    evaluate.add_argument(
        "--reference-kind",
        choices=["auto", "depth", "disparity"],
        default="auto",
        help="what --reference-topic holds; auto: a DisparityImage disparity, an Image "
        "depth; an Image of disparity (px, 32FC1) needs 'disparity' (default: %(default)s)",
    )
    evaluate.add_argument(
        "--output-prefix",
        default="/pcainterp",
        metavar="PREFIX",
        help="prefix of the densified topics (default: %(default)s)",
    )
    add_input_pair_options(evaluate)

    info = commands.add_parser(
        "info",
        formatter_class=_formatter,
        help="describe a log (topics, counts, duration) or a basis file",
        epilog=(
            "examples:\n  pcainterp info drive.mcap\n  pcainterp info basis.npz\n"
            "  pcainterp info                  # the built-in basis\n"
        ),
    )
    info.add_argument(
        "file", type=Path, nargs="?", default=None, metavar="FILE", help="default: built-in basis"
    )

    demo = commands.add_parser(
        "demo",
        formatter_class=_formatter,
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
    demo.add_argument("--out", type=Path, default=Path("demo_out"), metavar="DIR")
    demo.add_argument("--rerun", action="store_true", help="watch the densified log in Rerun")
    demo.add_argument(
        "--learn", action="store_true", help="learn a basis from rendered drives first (~3 min)"
    )
    add_golden_parser(commands, _formatter)
    return parser


# ----------------------------------------------------------------------------- dispatch
# Configs are built and jobs called here; the heavy modules load only when a command runs,
# so --help stays fast.


def _sgbm_config(args: argparse.Namespace, base: SgbmConfig | None = None) -> SgbmConfig:
    """Return ``base`` (default: ``SgbmConfig()``) with the stereo options given changed."""
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
    if args.stereo_downscale is not None:
        changes["downscale"] = args.stereo_downscale
    return dataclasses.replace(SgbmConfig() if base is None else base, **changes)


def _gftt_config(args: argparse.Namespace) -> GfttConfig:
    from pcainterp_stream.frontend.stereo import GfttConfig

    changes: dict[str, Any] = {}
    if args.corners is not None:
        if args.corners < 1:
            raise PcaInterpError(f"--corners must be at least 1, got {args.corners}")
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
        if not args.fill_spacing >= 0:
            raise PcaInterpError(f"--fill-spacing must be >= 0 px, got {args.fill_spacing}")
        changes["fill_spacing"] = args.fill_spacing
    return dataclasses.replace(GfttConfig(), **changes)


def _sigma_option(value: str) -> float | str:
    if value in ("auto", "evidence"):
        return value
    try:
        sigma = float(value)
    except ValueError:
        sigma = float("nan")
    if not 0 < sigma < float("inf"):
        raise PcaInterpError(f"--sigma must be a number > 0 px, 'evidence' or 'auto', got {value}")
    return sigma


def _with_synthetic(value: str) -> int | Literal["auto"]:
    """``learn --with-synthetic``: "auto", 0 (off) or a number of maps >= 2."""
    if value == "auto":
        return "auto"
    try:
        count = int(value)
    except ValueError:
        count = -1
    if count < 0 or count == 1:
        raise PcaInterpError(
            f"--with-synthetic must be at least 2 maps (0: off; or auto), got {value}"
        )
    return count


def _check_estimate(processor: ProcessorConfig, basis_path: Path | None) -> None:
    """Refuse estimate options that do not fit the basis, before any work is done."""
    from pcainterp_stream.estimate.basis import Basis

    if processor.prior == "paper" and not processor.temporal:
        return
    if basis_path is None:
        basis, name = Basis.default(), "the built-in basis"  # raises if it is missing
    elif not basis_path.is_file():
        return  # a missing basis is reported where it is loaded
    else:
        basis, name = Basis.load(basis_path), str(basis_path)
    from pcainterp_stream.pipeline.processor import resolve_settings

    try:
        settings = resolve_settings(basis, processor)
    except ValueError as err:
        raise PcaInterpError(f"--prior {processor.prior} with {name}: {err}") from err
    if processor.uncertainty == "paper" and (settings.local_prior or processor.temporal):
        raise PcaInterpError(
            "--uncertainty paper is the paper's diagonal approximation of its own prior, but "
            f"{name} has a fitted local prior or --temporal is on; pass --prior paper "
            "--no-temporal with it, or use --uncertainty exact"
        )


def _print_written(summary: WriteSummary) -> None:
    from pcainterp_stream.pipeline.common import _echo

    duration = ((summary.end_ns or 0) - (summary.start_ns or 0)) / 1e9
    _echo(f"wrote {summary.path}: {summary.message_count} messages, {duration:.1f} s of log")


def _output_topics(args: argparse.Namespace) -> OutputTopics:
    """Return the output topics of ``densify``: --output-prefix, --depth-mm, --outputs."""
    from pcainterp_stream.io.outputs import OutputTopics

    topics = OutputTopics.with_prefix(
        args.output_prefix, depth_mm=args.depth_mm, precision=getattr(args, "precision", "full")
    )
    if args.outputs is None:
        return topics
    try:
        return topics.only(name.strip() for name in args.outputs.split(",") if name.strip())
    except ValueError as err:
        raise PcaInterpError(f"--outputs: {err}") from None


def _densify_many(args: argparse.Namespace, processor: ProcessorConfig) -> int:
    """Densify several logs into ``--out-dir`` on Dask; exit code 1 if any log failed."""
    from pcainterp_stream.pipeline import distributed
    from pcainterp_stream.pipeline.common import _echo

    if args.rrd is not None or args.rerun:
        raise PcaInterpError("--rrd/--rerun take one log; use -o OUTPUT without --out-dir")
    if args.workers is not None and args.workers < 1:
        raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
    if args.basis is not None and not args.basis.exists():
        raise PcaInterpError(f"basis {args.basis} does not exist; learn one with pcainterp learn")
    started = time.perf_counter()
    with distributed.connect(args.scheduler, args.workers) as client:
        outcomes = distributed.densify_many(
            [path.resolve() for path in args.input],  # workers may run in another folder
            args.out_dir.resolve(),
            args.basis.resolve() if args.basis is not None else None,
            client,
            pairing=pairing_config(args, args.features_topic),
            processor=processor,
            topics=_output_topics(args),
        )
    failed = 0
    for outcome in outcomes:
        if outcome.error is None:
            _echo(f"densified {outcome.frames} frames of {outcome.input} -> {outcome.output}")
        else:
            failed += 1
            error = outcome.error
            if outcome.input.name not in error:
                error = f"{outcome.input}: {error}"
            print(f"pcainterp: error: {error}", file=sys.stderr)
    frames = sum(outcome.frames for outcome in outcomes)
    _echo(
        f"{len(outcomes) - failed} of {len(outcomes)} logs densified, {frames} frames in "
        f"{time.perf_counter() - started:.1f} s"
    )
    return 1 if failed else 0


def run(args: argparse.Namespace) -> int:
    """Run the job a parsed command line asks for; return the exit code."""
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.common import _echo
    from pcainterp_stream.pipeline.jobs import (
        demo,
        describe_basis,
        evaluate,
        import_kitti,
        info,
        synth,
    )
    from pcainterp_stream.pipeline.learn import LearnOptions, learn
    from pcainterp_stream.pipeline.processor import MeasurementSource, ProcessorConfig

    command = args.command
    if command == "golden":
        return run_golden(args)
    if command == "synth" and args.raw is not None:
        from pcainterp_stream.pipeline.jobs import synth_raw

        if args.lidar:
            raise PcaInterpError("--lidar is not written with --raw; drop one of them")
        if (args.scene, args.camera, args.platform) != ("street", "kitti", "auto"):
            raise PcaInterpError(
                "--raw records the street drive through the KITTI-like camera; "
                "drop --scene, --camera and --platform, or --raw"
            )
        _print_written(
            synth_raw(
                args.out,
                frames=args.frames,
                seed=args.seed,
                scale=args.scale,
                fmt=args.format,
                model=args.raw,
            )
        )
    elif command == "synth":
        _print_written(
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
    elif command == "import-kitti":
        _print_written(import_kitti(args.kitti_dir, args.out, max_frames=args.max_frames))
    elif command == "learn":
        if args.components is not None and args.components < 1:
            raise PcaInterpError(f"--components must be at least 1, got {args.components}")
        if args.variance is not None and not 0 < args.variance <= 1:  # also refuses nan
            raise PcaInterpError(f"--variance must be in (0, 1], got {args.variance}")
        if args.grid_scale is not None and not 0 < args.grid_scale <= 1:
            raise PcaInterpError(f"--grid-scale must be in (0, 1], got {args.grid_scale}")
        on_cluster = args.scheduler is not None or args.workers is not None
        if args.fit_prior is False and args.fit_logs:
            raise PcaInterpError("--fit-logs are for fitting the prior; drop --no-fit-prior")
        with_synthetic = _with_synthetic(args.with_synthetic)
        if with_synthetic not in ("auto", 0) and args.grid_scale is not None:
            raise PcaInterpError(
                "--with-synthetic fine-tunes the built-in basis on its own grid; drop --grid-scale"
            )
        options = LearnOptions(
            n_components=args.components or 500,
            variance=args.variance,
            grid_scale=args.grid_scale or 0.25,
            depth_topic=args.depth_topic,
            every=args.every,
            sgbm=_sgbm_config(args),
            fit_prior=args.fit_prior is not False,
            holdout=args.holdout,
            fit_logs=tuple(args.fit_logs),
            with_synthetic=with_synthetic,
        )
        pairing = learn_pairing(args)
        if args.workers is not None and args.workers < 1:
            raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
        if on_cluster:  # the same learn, the maps' statistics gathered by the workers
            from pcainterp_stream.pipeline import distributed

            with distributed.connect(args.scheduler, args.workers) as client:
                basis = distributed.learn_distributed(
                    args.logs, args.output, options, pairing, client
                )
        else:
            basis = learn(args.logs, args.output, options, pairing)
        _echo(f"wrote {args.output}")
        _echo(describe_basis(args.output))
        del basis
    elif command == "densify":
        source = MeasurementSource.FEATURES if args.features_topic else MeasurementSource.STEREO
        if args.process_noise is not None and not 0 < args.process_noise < float("inf"):
            raise PcaInterpError(f"--process-noise must be > 0, got {args.process_noise}")
        if args.carry_frames < 0:
            raise PcaInterpError(f"--carry-frames must be >= 0, got {args.carry_frames}")
        live = live_options(args)
        if args.out_dir is not None and Path("-") in args.input:
            raise PcaInterpError("standard input (-) is one log; pass -o OUTPUT, not --out-dir")
        if args.measurements == "dense" and args.features_topic:
            raise PcaInterpError(
                "--measurements dense fuses the whole SGBM map of the stereo pair; "
                "drop --features-topic (a feature stream is sparse)"
            )
        dense = args.measurements == "dense"
        # --basis builtin: the built-in basis as it is (checked, never replaced)
        builtin = args.basis is not None and str(args.basis) == "builtin"
        if builtin:
            args.basis = None
        processor = ProcessorConfig(
            adapt="check" if builtin else "auto",
            gftt=_gftt_config(args),
            # dense mode outputs the SGBM map itself where it is valid: full resolution
            sgbm=_sgbm_config(args, None if dense else ProcessorConfig().sgbm),
            measurements=args.measurements,
            sigma=_sigma_option(args.sigma),
            uncertainty=args.uncertainty,
            prior=args.prior,
            robust=args.robust,
            temporal=args.temporal,
            process_noise=args.process_noise,
            carry=dataclasses.replace(ProcessorConfig().carry, frames=args.carry_frames),
            calibrate=args.calibrate,
            source=source,
        )
        _check_estimate(processor, args.basis)
        if args.out_dir is not None:
            return _densify_many(args, processor)
        if len(args.input) > 1:
            raise PcaInterpError(
                f"-o takes one input but {len(args.input)} were given; "
                "pass --out-dir DIR to densify several logs"
            )
        if args.scheduler is not None or args.workers is not None:
            raise PcaInterpError("--scheduler/--workers need --out-dir DIR instead of -o")
        return run_densify(
            args,
            processor=processor,
            pairing=pairing_config(args, args.features_topic),
            topics=_output_topics(args),
            live=live,
        )
    elif command == "evaluate":
        if args.no_basis and args.basis is not None:
            raise PcaInterpError("--no-basis and --basis contradict each other; pass one")
        if args.reference_topic is None and args.reference_kind != "auto":
            raise PcaInterpError("--reference-kind needs --reference-topic TOPIC")
        folder, table = evaluate(
            args.input,
            args.output,
            basis=args.basis,
            mode=args.mode,
            sigma=args.sigma,
            sweep_every=args.sweep_every,
            max_frames=args.max_frames,
            topics=OutputTopics.with_prefix(args.output_prefix),
            linear=not args.no_linear,
            basis_rows=not args.no_basis,
            reference_topic=args.reference_topic,
            reference_kind=args.reference_kind,
            pairing=pairing_config(args),
        )
        _echo(table)
        _echo(f"wrote {folder}/results.md, results.json and figures")
    elif command == "info":
        _echo(info(args.file))
    elif command == "demo":
        _echo(demo(args.out, spawn_viewer=args.rerun, learn_basis=args.learn))
    else:  # pragma: no cover - argparse rejects unknown commands
        raise PcaInterpError(f"unknown command {command}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``pcainterp``; return the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # SIGTERM takes the same clean-up path as Ctrl-C: temporaries removed, target untouched;
    # a second signal ends at once, and densify (native threads: the Foxglove server, the
    # writer, SGBM) has a watchdog that ends it within a few seconds whatever blocks
    # (pcainterp_stream/interrupt.py). The previous handlers come back afterwards, for
    # callers that run main() in-process.
    try:
        with stop_on_signals(watchdog=args.command == "densify"):
            return run(args)
    except PcaInterpError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; no partial output was left at the target", file=sys.stderr)
        # A Ctrl-C that lands inside code run by exec() (rosbags generates its message
        # decoders that way) sets a flag that makes `python -m` re-raise SIGINT at exit
        # (CPython bpo-41602) although we handled it; any exec() of a string clears it.
        exec("")
        end_if_signalled(130)  # a real signal: no interpreter shutdown to wait for
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    sys.exit(main())
