"""``pcainterp learn``: a PCA basis (and its fitted prior) from the disparity maps of logs."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pcainterp_stream.cli.common import (
    DOCS_NOTE,
    Commands,
    add_cluster_options,
    add_stereo_options,
    check_cluster_options,
    cluster_notes,
    echo,
    file_output_arg,
    formatter,
    gftt_config,
    path_arg,
    refuse_overwrites,
    refuse_stream_output,
    same_file,
    sgbm_config,
    worker_wait,
)
from pcainterp_stream.cli.pairing import add_topic_options, pairing_config
from pcainterp_stream.errors import ClusterTaskError, LogReadError, LogWriteError, PcaInterpError

if TYPE_CHECKING:
    from pcainterp_stream.estimate.basis import Basis


def add_parser(commands: Commands) -> None:
    """Add ``learn`` to the commands."""
    learn = commands.add_parser(
        "learn",
        formatter_class=formatter,
        help="learn a PCA basis from the disparity maps of logs",
        description=(
            "Learn a PCA basis of dense disparity maps from stereo logs: SGBM on every pair\n"
            "(or a ground-truth depth topic), the paper's preprocessing, streaming PCA; then\n"
            "fit the hybrid prior, sigma and the std calibration on held-out frames\n"
            "(--no-fit-prior: the paper's model alone). With few maps of your own (fewer\n"
            "than 1000) it fine-tunes a built-in basis with them instead, and says so: the\n"
            "one of your camera's kind (KITTI-like: street; 752x480 VI-sensor-like: indoor),\n"
            "or the other when the held-out frames find it clearly better, or for a camera\n"
            "like neither the one that beats linear interpolation there (--with-synthetic\n"
            "auto, the default; 0 turns it off)."
        ),
        epilog=(
            "examples:\n"
            "  pcainterp learn a.mcap b.mcap -o basis.npz --components 300\n"
            "  pcainterp learn drive.mcap -o basis.npz --variance 0.95 --grid-scale 0.125\n"
            "  pcainterp learn synth.mcap -o basis.npz --depth-topic /ground_truth/depth\n"
            "  pcainterp learn a.mcap -o basis.npz --no-fit-prior     # the paper's model\n"
            "  pcainterp learn short.mcap -o basis.npz --with-synthetic 0  # your maps alone\n"
            "  pcainterp learn fleet/*.mcap -o basis.npz --scheduler tcp://10.0.0.5:8786\n"
            "\n" + DOCS_NOTE
        ),
    )
    learn.add_argument(
        "logs",
        type=path_arg,
        nargs="+",
        metavar="LOG",
        help="the stereo logs to learn from (MCAP, ROS 1 bag or ROS 2 bag), one camera",
    )
    learn.add_argument(
        "-o",
        "--output",
        type=file_output_arg("learn writes one basis file", "-o {}basis.npz"),
        required=True,
        metavar="BASIS.npz",
        help="the basis file to write (required); densify --basis reads it",
    )
    size = learn.add_mutually_exclusive_group()
    size.add_argument(
        "--components",
        type=int,
        default=None,
        metavar="L",
        help="the most components to keep (default 500); fewer when the maps do not "
        "support them: N training maps give at most N - 1, a fine-tuned basis "
        "(--with-synthetic) at most the built-in basis's plus N",
    )
    size.add_argument(
        "--variance",
        type=float,
        default=None,
        metavar="R",
        help="keep the fewest components (at most 500) explaining this share of the maps' "
        "variance, in (0, 1] (default: off, --components decides)",
    )
    learn.add_argument(
        "--grid-scale",
        type=float,
        default=None,
        metavar="G",
        help="basis grid pixels per image pixel, in (0, 1] (default 0.25: a 1241x376 image "
        "gives a 310x94 grid); a fine-tuned basis keeps the built-in basis's grid",
    )
    learn.add_argument(
        "--depth-topic",
        default=None,
        metavar="TOPIC",
        help="learn from this depth image topic instead of SGBM maps: 32FC1 in m, 16UC1 in mm "
        "(0: none), or either as compressedDepth (pcainterp's own /pcainterp/depth and "
        "depth_mm); camera images (mono8, rgb8, png, jpeg) are refused. A log of one "
        "camera (an RGB-D camera: one camera_info) needs --baseline, the baseline its "
        "disparities fx * baseline / depth are in (the one densify will use for this "
        "camera; a basis merged into a built-in one is put in that basis's f*b anyway), "
        "and --no-fit-prior or --fit-logs STEREO_LOG (the prior is fitted on stereo pairs)",
    )
    learn.add_argument(
        "--every", type=int, default=1, metavar="N", help="use every N-th frame (default: 1, all)"
    )
    learn.add_argument(
        "--with-synthetic",
        default="auto",
        metavar="N|auto",
        help="fine-tune a built-in basis (learned from synthetic streets, or rooms for the "
        "indoor one) with these logs' maps, counting it as N maps, and keep its local "
        "kernel; the result is on that basis's grid and camera and applies to yours as any "
        "basis does. Which one: your camera's kind (aspect ratio within 10 %%, f*b per "
        "image width within 1.5x of the basis's), unless on the held-out frames it loses "
        "to linear interpolation or the other errs at most 0.8x as much; for a camera like "
        "neither, the one that beats linear interpolation there (with --no-fit-prior, "
        "which holds no frames out: the closest camera). auto (default): N = 1000 when "
        "the logs give fewer than 1000 maps and a built-in basis is chosen, else the maps "
        "alone; 0: the maps alone",
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
        type=path_arg,
        nargs="+",
        default=(),
        metavar="LOG",
        help="fit on these logs instead of a held-out share",
    )
    add_cluster_options(learn, command="learn")
    add_topic_options(learn)
    add_stereo_options(learn, command="learn")


def run(args: argparse.Namespace) -> int:
    """Learn the basis (here or on Dask), save it and describe it; return the exit code."""
    from pcainterp_stream.pipeline.common import damage_at_open
    from pcainterp_stream.pipeline.jobs import describe_basis
    from pcainterp_stream.pipeline.learn import LearnOptions, learn, learn_pairing

    check_cluster_options(args)
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
    _check_paths(args)
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
        sgbm=sgbm_config(args),
        gftt=gftt_config(args),
        fit_prior=args.fit_prior is not False,
        holdout=args.holdout,
        fit_logs=tuple(args.fit_logs),
        with_synthetic=with_synthetic,
    )
    pairing = learn_pairing([*args.logs, *args.fit_logs], pairing_config(args), args.depth_topic)
    for line in damage_at_open([*args.logs, *args.fit_logs]):
        echo(f"damage: {line}; learn uses the frames before it")
    if args.workers is not None and args.workers < 1:
        raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
    if on_cluster:  # the same learn, the maps' statistics gathered by the workers
        from pcainterp_stream.pipeline import distributed

        try:
            with distributed.connect(
                args.scheduler, args.workers, worker_wait=worker_wait(args), say=cluster_notes
            ) as client:
                basis = distributed.learn_distributed(
                    args.logs, args.output, options, pairing, client
                )
        except ClusterTaskError as err:  # a bug or a dead worker: one process shows where
            raise ClusterTaskError(
                f"{err}; run learn without --scheduler/--workers to see where it failed"
            ) from err
    else:
        basis = learn(args.logs, args.output, options, pairing)
    echo(f"wrote {args.output}")
    echo(describe_basis(args.output))
    shortfall = components_note(basis, args.components)
    if shortfall:
        echo(shortfall)
    del basis
    return 0


def components_note(basis: Basis, asked: int | None) -> str:
    """Return a note on why the basis has fewer components than asked, or ""."""
    learning = basis.meta.get("learning", {})
    wanted = asked or int(learning.get("n_components_requested") or 0)
    kept = basis.n_components
    if kept >= wanted:
        return ""
    what = f"--components {asked}" if asked else f"the default {wanted} components"
    variance = learning.get("variance_requested")
    if variance is not None and basis.explained_variance_ratio >= variance - 1e-9:
        why = f"the fewest that explain --variance {variance:g} of the maps' variance"
    elif "finetune" in basis.meta:
        merged = basis.meta["finetune"]
        from pcainterp_stream.estimate.basis import BUILT_IN_INDOOR

        indoor = basis.meta.get("source", {}).get("with_synthetic_basis") == BUILT_IN_INDOOR
        why = (
            f"the built-in{' indoor' * indoor} basis's {merged['prior_basis']['n_components']} "
            "components and "
            f"{merged['n_maps']} maps of your own span no more; learn from more frames"
        )
    else:
        why = f"{basis.n_train} maps span no more directions; learn from more frames"
    return f"note: {kept} component{'s' * (kept != 1)}, not {what}: {why}"


def _check_paths(args: argparse.Namespace) -> None:
    """Refuse, before any work, a -o learn cannot write or that replaces a file it reads.

    Raises:
        LogWriteError: -o is ``-``, a folder, is named other than .npz, or is one of the
            logs, --fit-logs or --calibration.
        LogReadError: a --fit-logs log does not exist.
    """
    refuse_stream_output(args.output, "-o", "learn writes a basis file (.npz)", "basis.npz")
    if args.output.is_dir():
        raise LogWriteError(
            f"output {args.output} is a folder but learn writes one basis file; "
            f"choose a file path, e.g. -o {args.output / 'basis.npz'}"
        )
    for log in args.fit_logs:
        if not log.exists():
            raise LogReadError(f"--fit-logs log {log} does not exist; pass an existing log")
    for index, log in enumerate(args.logs):
        twin = next((other for other in args.logs[:index] if same_file(other, log)), None)
        if twin is not None:
            raise LogReadError(
                f"{log} is {twin} again: its maps would count twice; pass each log once"
            )
    reads: list[tuple[str, Path | None]] = [("the input", log) for log in args.logs]
    reads.extend(("the --fit-logs log", log) for log in args.fit_logs)
    reads.extend(("the --calibration file", path) for path in args.calibration or ())
    refuse_overwrites([("the output", args.output, "choose a different -o path")], reads)
    suffix = args.output.suffix
    if suffix and suffix.lower() != ".npz":
        raise LogWriteError(
            f"output {args.output} is named {suffix} but learn writes a basis (.npz); "
            f"choose a name ending in .npz, e.g. -o {args.output.with_suffix('.npz')}"
        )


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
