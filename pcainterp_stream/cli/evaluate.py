"""``pcainterp evaluate``: a densified log measured into a report."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from pcainterp_stream.cli.common import Commands, basis_option, echo, formatter, path_arg
from pcainterp_stream.cli.pairing import (
    add_input_pair_options,
    pairing_config,
    stamp_tolerance_ms,
)
from pcainterp_stream.errors import PcaInterpError

if TYPE_CHECKING:
    from pcainterp_stream.estimate.basis import Basis
    from pcainterp_stream.io.outputs import OutputTopics


def add_parser(commands: Commands) -> None:
    """Add ``evaluate`` to the commands."""
    evaluate = commands.add_parser(
        "evaluate",
        formatter_class=formatter,
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
    evaluate.add_argument(
        "input",
        type=path_arg,
        metavar="DENSIFIED.mcap",
        help="a log written by pcainterp densify (with its input pair, as densify writes it)",
    )
    evaluate.add_argument(
        "-o",
        "--output",
        type=path_arg,
        default=None,
        metavar="REPORT_DIR",
        help="report folder (default: DENSIFIED_report beside the log)",
    )
    evaluate.add_argument(
        "--basis",
        type=path_arg,
        default=None,
        metavar="BASIS.npz",
        help="the basis for the oracle, uncertainty kinds and points sweep: a file; "
        "'builtin' for the built-in one the log records (the indoor one if densify chose "
        "it, else the street one), 'builtin-street' or 'builtin-indoor' for that one "
        "(default: the one the log records it was densified with, looked for at its "
        "recorded path from the log's folder, beside the log, then in the working folder; "
        "the built-in one for older logs)",
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
    evaluate.add_argument(
        "--sigma",
        type=float,
        default=2.0,
        metavar="PX",
        help="measurement noise std (px of the basis's camera, as densify --sigma) of the "
        "rows that densify again with the basis "
        "(paper vs exact uncertainty, points sweep) (default: %(default)s)",
    )
    evaluate.add_argument(
        "--sweep-every",
        type=int,
        default=10,
        metavar="N",
        help="points sweep on every N-th frame, 0 = off (default: %(default)s)",
    )
    evaluate.add_argument(
        "--max-frames",
        type=int,
        default=None,
        metavar="N",
        help="evaluate the first N densified frames only (default: all); temporal mode scores "
        "N-1 of them, as the last has no next frame to be moved into",
    )
    evaluate.add_argument(
        "--reference-topic",
        default=None,
        metavar="TOPIC",
        help="score against this ground-truth image topic of the log, dense or sparse "
        "(e.g. projected LiDAR), each message matched to the frame stamped nearest it "
        "within --stamp-tolerance-ms (default: under half the frame interval): "
        "sensor_msgs/msg/Image "
        "32FC1 depth in m or 16UC1 in mm, or stereo_msgs/msg/DisparityImage; NaN, 0 or "
        "< 0 = no truth at that pixel (default: /ground_truth/depth if present, else "
        "/ground_truth/lidar_depth, as import-kitti writes KITTI's depth truth, else SGBM)",
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
        help="prefix of the densified topics, a ROS 2 topic name (default: %(default)s)",
    )
    add_input_pair_options(evaluate)


def run(args: argparse.Namespace) -> int:
    """Evaluate the log and print the report's table; return the exit code."""
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.jobs import evaluate

    if args.no_basis and args.basis is not None:
        raise PcaInterpError("--no-basis and --basis contradict each other; pass one")
    path, kind = basis_option(args.basis)
    if args.reference_topic is None and args.reference_kind != "auto":
        raise PcaInterpError("--reference-kind needs --reference-topic TOPIC")
    try:
        topics = OutputTopics.with_prefix(args.output_prefix)
    except ValueError as err:
        raise PcaInterpError(f"--output-prefix {err}") from None
    folder, table = evaluate(
        args.input,
        args.output,
        basis=path if kind is None else _builtin_basis(kind, args.input, topics),
        mode=args.mode,
        sigma=args.sigma,
        sweep_every=args.sweep_every,
        max_frames=args.max_frames,
        topics=topics,
        linear=not args.no_linear,
        basis_rows=not args.no_basis,
        reference_topic=args.reference_topic,
        reference_kind=args.reference_kind,
        pairing=pairing_config(args),
        stamp_tolerance_ms=stamp_tolerance_ms(args),
    )
    echo(table)
    echo(f"wrote {folder}/results.md, results.json and figures")
    return 0


def _builtin_basis(kind: str, log: Path, topics: OutputTopics) -> Basis:
    """Return the built-in basis ``--basis builtin[-street|-indoor]`` names.

    ``builtin`` (kind ``auto``) is the one densify chose by its fit check, as the log
    records it: the indoor one if it says so, else the street one (also for a log
    densified with a basis file, or one that cannot be read: evaluate reports that).
    """
    from pcainterp_stream.estimate.basis import BUILT_IN_INDOOR, builtin_basis

    if kind == "auto":
        from pcainterp_stream.io.outputs import BASIS_KEY, recorded_metadata

        try:
            label = recorded_metadata(log, topics).get(BASIS_KEY)
        except PcaInterpError:
            label = None
        kind = "indoor" if label == BUILT_IN_INDOOR else "street"
    return builtin_basis(kind)
