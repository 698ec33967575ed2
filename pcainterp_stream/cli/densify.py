"""``pcainterp densify``: a stereo log densified, with depth and uncertainty channels added.

The options, their checks and the estimate's config are here; one log's ways in and out
(a file or standard input; a file, standard output or a live Foxglove server) are in
:mod:`pcainterp_stream.cli.densify_one`, several logs go to Dask
(:mod:`pcainterp_stream.pipeline.distributed`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from pcainterp_stream import defaults
from pcainterp_stream.cli.common import (
    DOCS_NOTE,
    STREAM,
    Commands,
    add_cluster_options,
    add_stereo_options,
    basis_option,
    check_cluster_options,
    cluster_notes,
    echo,
    file_output_arg,
    formatter,
    gftt_config,
    path_arg,
    refuse_overwrites,
    sgbm_config,
    warn,
    worker_wait,
)
from pcainterp_stream.cli.densify_one import LiveOptions, densify_one
from pcainterp_stream.cli.pairing import add_topic_options, pairing_config
from pcainterp_stream.errors import LogReadError, LogWriteError, PcaInterpError
from pcainterp_stream.io.foxglove import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    MAX_GAP_S,
    MAX_RATE,
    MIN_RATE,
    ServeAddress,
    check_rate,
    log_given_as_address,
)
from pcainterp_stream.io.path_text import shown

if TYPE_CHECKING:
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.densify_fleet import DensifyOutcome
    from pcainterp_stream.pipeline.processor import ProcessorConfig


def add_parser(commands: Commands) -> None:
    """Add ``densify`` to the commands."""
    densify = commands.add_parser(
        "densify",
        formatter_class=formatter,
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
            "  pcainterp densify run_0.bag run_1.bag -o run_dense.mcap   # one split recording\n"
            "  pcainterp densify drive.mcap --foxglove      # live in Foxglove: ws://127.0.0.1:8765\n"
            "  cat drive.mcap | pcainterp densify - -o - > drive_dense.mcap\n"
            "\n" + DOCS_NOTE
        ),
    )
    densify.add_argument(
        "input",
        type=path_arg,
        nargs="+",
        metavar="INPUT",
        help="one log ('-': an MCAP stream on standard input); with -o or --foxglove, several "
        "are the parts of one split recording (rosbag record --split: a_0.bag a_1.bag), read "
        "as one log in log-time order (a warning when parts are over 60 s apart); with "
        "--out-dir, several logs densified apart",
    )
    target = densify.add_mutually_exclusive_group()
    target.add_argument(
        "-o",
        "--output",
        type=file_output_arg(
            "densify writes one MCAP file", "-o {0}x_dense.mcap, or --out-dir {0} for several logs"
        ),
        default=None,
        metavar="OUTPUT",
        help="the densified .mcap ('-': standard output, piped or redirected); optional with "
        "--foxglove",
    )
    target.add_argument(
        "--out-dir",
        type=path_arg,
        default=None,
        metavar="DIR",
        help="write DIR/<stem>_dense.mcap per input, the logs densified in parallel on Dask",
    )
    live = densify.add_argument_group("live view in Foxglove (docs/viewing.md)")

    class AddressOption(argparse.Action):
        """``--foxglove [HOST:PORT]``; a log taken as its address ends the parse in one line."""

        def __call__(
            self,
            parser: argparse.ArgumentParser,
            namespace: argparse.Namespace,
            values: object,
            option_string: str | None = None,
        ) -> None:
            error = log_given_as_address(str(values), option_string or "--foxglove")
            if error is not None:
                parser.exit(2, f"{parser.prog}: error: {error}\n")
            setattr(namespace, self.dest, values)

    live.add_argument(
        "--foxglove",
        nargs="?",
        action=AddressOption,
        const=f"{DEFAULT_HOST}:{DEFAULT_PORT}",
        default=None,
        metavar="HOST:PORT",
        help="serve the stream over the Foxglove WebSocket protocol (default address "
        f"{DEFAULT_HOST}:{DEFAULT_PORT}, this machine only; 0.0.0.0:PORT for every interface)",
    )
    live.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="R",
        help=f"pace at R x the log's rate, {MIN_RATE:g} to {MAX_RATE:g}: 1 = as recorded, 0 = "
        f"as fast as processed; a gap over {MAX_GAP_S:g} s of log is skipped with a line "
        "(default: 0 with -o, else 1)",
    )
    live.add_argument(
        "--wait-for-client",
        action="store_true",
        help="hold the first message until a client subscribed to an output channel",
    )
    live.add_argument(
        "--exit-when-done",
        action="store_true",
        help="stop serving after the last frame (default without -o: serve until Ctrl-C)",
    )
    densify.add_argument(
        "--basis",
        type=path_arg,
        default=None,
        metavar="BASIS.npz",
        help="the basis: a file; 'builtin' for the built-in ones as they are (the street or "
        "the indoor one, whichever fits the first frames better), 'builtin-street' or "
        "'builtin-indoor' for that one (default: the built-in street basis, checked on the "
        "first frames against linear interpolation; when it does not fit, the indoor one and "
        "(not with --measurements dense) a basis learned from the log's own stereo are tried "
        "and the best is used; pcainterp info describes them)",
    )
    densify.add_argument("--rerun", action="store_true", help="stream to a Rerun viewer")
    densify.add_argument(
        "--rrd",
        type=file_output_arg("--rrd writes one Rerun recording", "--rrd {}drive.rrd"),
        default=None,
        metavar="FILE.rrd",
        help="write a Rerun recording; one that cannot be written is refused before any "
        "work, one that fails later (a full disk, its folder removed) is a warning and the "
        "exit status stays 0 with the MCAP written: a script should check the file is there",
    )
    _add_estimate_options(densify)
    densify.add_argument(
        "--features-topic",
        default=None,
        metavar="TOPIC",
        help="take measurements from this PointCloud2 stream instead of GFTT + SGBM (the "
        "stereo front end's options, --edge-aware and --near-reach are then refused: SGBM "
        "does not run)",
    )
    densify.add_argument(
        "--max-features",
        type=int,
        default=None,
        metavar="N",
        help="with --features-topic: most points measured per frame; a denser cloud (a LiDAR "
        "scan, stereo_image_proc's points2) keeps one point per cell of a grid, and points "
        "on one pixel keep the nearest (default "
        f"{defaults.MAX_FEATURES}: the estimate's cost grows with the square of the points)",
    )
    densify.add_argument(
        "--output-prefix",
        default="/pcainterp",
        metavar="PREFIX",
        help="prefix of the output topics, a ROS 2 topic name (default: %(default)s)",
    )
    densify.add_argument(
        "--depth-mm",
        action="store_true",
        help="also write a 16UC1 millimetre depth for viewers (always written at compact "
        "precision)",
    )
    densify.add_argument(
        "--precision",
        choices=["compact", "full"],
        default="compact",
        help="compact (default): depth and disparity_std as compressedDepth PNG within 1/64 "
        "of the posterior std (coarser where a near disparity needs it to fit 16 bits): "
        "~0.8 MB of output per KITTI frame. full: every channel "
        "float32, ~7.3 MB per KITTI frame (docs/benchmarks.md, "
        "'Output encodings')",
    )
    densify.add_argument(
        "--outputs",
        default=None,
        metavar="CHANNELS",
        help="comma-separated output channels to write, of depth, depth_std, disparity, "
        "disparity_std, features, camera_info, depth_mm (default: depth, disparity_std, "
        "features, camera_info and depth_mm at compact precision, all but depth_mm at full; "
        "depth_mm also comes with depth at compact precision; evaluate needs depth or "
        "disparity, disparity_std, features, camera_info; depth and disparity are "
        "reciprocal)",
    )
    add_cluster_options(densify, command="densify")
    add_topic_options(densify)
    add_stereo_options(densify, command="densify")


def _add_estimate_options(densify: argparse.ArgumentParser) -> None:
    estimate = densify.add_argument_group(
        "estimate (defaults: the best measured combination, docs/results.md)"
    )
    estimate.add_argument(
        "--measurements",
        choices=["sparse", "dense"],
        default="sparse",
        help="sparse = the paper's: GFTT corners looked up in the SGBM map (default); dense = "
        "every valid SGBM pixel, fused with the prior: SGBM's accuracy where it matched, the "
        "prior's fill in its holes, at full SGBM resolution (docs/estimator.md)",
    )
    estimate.add_argument(
        "--dense-matcher",
        choices=["refined", "full"],
        default=None,
        help="with --measurements dense: refined = SGBM over the whole range at half "
        "resolution, refined at full resolution within +-8 px of it (default); full = SGBM "
        "over the whole range at full resolution: ~1.8x the matching time, no more accurate "
        "(docs/dense.md). With --stereo-downscale 2 dense mode matches the whole range at "
        "half resolution",
    )
    estimate.add_argument(
        "--sigma",
        default="auto",
        metavar="PX|evidence|auto",
        help="measurement noise std: a number (px of the basis's camera: on a log of another "
        "f*b it is sigma * f*b_log / f*b_basis), 'evidence' (fitted per frame) or 'auto' "
        "(the basis's fitted value, else 2 px; default)",
    )
    estimate.add_argument(
        "--uncertainty",
        choices=["exact-coarse", "exact", "paper", "none"],
        default="exact-coarse",
        help="posterior std: 'exact-coarse' = exact on a grid 1/16 of the image, resampled "
        "(default); 'exact' = exact at every pixel (0.06-2.4 s per KITTI-size frame); 'paper' = "
        "the paper's diagonal approximation; 'none' (docs/estimator.md)",
    )
    estimate.add_argument(
        "--prior",
        choices=["auto", "paper", "hybrid"],
        default="auto",
        help="hybrid = basis + fitted local kernel (fitted by learn); auto uses it when the "
        "basis has one (default)",
    )
    # default None, read as on: given, either way, with --features-topic it is refused
    estimate.add_argument(
        "--edge-aware",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="cut the local kernel along SGBM's depth edges when the basis's prior has a cell "
        "weight (the built-in street basis): ~2-3%% lower error for ~2%% more CPU; "
        "--no-edge-aware: the stationary kernel (default: True; docs/sharper_sparse.md)",
    )
    estimate.add_argument(
        "--near-reach",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also match at quarter resolution (twice SGBM's range) on frames whose map "
        "nears the range's end, and measure the surfaces nearer than the range there (each "
        "value checked against the right view's quarter map): ~24%% "
        "lower error on drives with such surfaces, none elsewhere; at most 1250 points per "
        "frame (the fill lattice's count at 1920x1080; a near surface over more than ~30%% of "
        "a 1920x1080 image gets a coarser grid); --no-near-reach: off "
        "(default: True; docs/sharper_sparse_2.md)",
    )
    estimate.add_argument(
        "--robust",
        choices=["none", "huber", "cauchy"],
        default=defaults.ROBUST,
        help="IRLS against wrong SGBM lookups, run on a frame only when one of its points is "
        "4 predictive std or more from what the others predict (default: %(default)s)",
    )
    estimate.add_argument(
        "--temporal",
        action=argparse.BooleanOptionalAction,
        default=defaults.TEMPORAL,
        help="previous frame's posterior as the prior (default: %(default)s)",
    )
    estimate.add_argument(
        "--carry-frames",
        type=int,
        default=defaults.CARRY_FRAMES,
        metavar="N",
        help="add the measurements of the N previous frames, moved by the ego-motion tracked "
        "between the left images, with noise growing with their age (default: %(default)s; "
        "0: off)",
    )
    estimate.add_argument(
        "--calibrate",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="scale the std by the factor learn calibrated on held-out frames, "
        "and per frame by the covariance scale its measurements' innovation gives "
        "(default: %(default)s; --no-calibrate reports the posterior std itself)",
    )
    estimate.add_argument(
        "--process-noise",
        type=float,
        default=None,
        metavar="Q",
        help="temporal prior's process noise, fraction of the eigenvalues (default: fitted)",
    )


def run(args: argparse.Namespace) -> int:
    """Check the options, build the estimate's config and densify; return the exit code."""
    check_cluster_options(args)
    if args.process_noise is not None and not 0 < args.process_noise < float("inf"):
        raise PcaInterpError(f"--process-noise must be finite and > 0, got {args.process_noise}")
    if args.process_noise is not None and not args.temporal:
        raise PcaInterpError(
            f"--process-noise {args.process_noise:g} is the temporal prior's and applies with "
            "--temporal only; add --temporal or drop --process-noise"
        )
    if args.carry_frames < 0:
        raise PcaInterpError(f"--carry-frames must be >= 0, got {args.carry_frames}")
    live = _live_options(args)
    if args.out_dir is not None and STREAM in args.input:
        raise PcaInterpError("standard input (-) is one log; pass -o OUTPUT, not --out-dir")
    if STREAM in args.input and sys.stdin is None:  # closed at start (<&-, a daemon's)
        raise PcaInterpError(
            "densify -: standard input is closed; pipe a log into it (densify - < log.mcap) "
            "or name the log"
        )
    if args.measurements == "dense" and args.features_topic:
        raise PcaInterpError(
            "--measurements dense fuses the whole SGBM map of the stereo pair; "
            "drop --features-topic (a feature stream is sparse)"
        )
    if args.features_topic:
        _refuse_stereo_options(args)
    sparse_only = [
        (flag if value else flag.replace("--", "--no-", 1))
        for flag, value in (("--edge-aware", args.edge_aware), ("--near-reach", args.near_reach))
        if value is not None
    ]
    if args.measurements == "dense" and sparse_only:
        raise PcaInterpError(
            f"{' and '.join(sparse_only)} shape{'s' if len(sparse_only) == 1 else ''} sparse "
            "mode's estimate, which --measurements dense does not use: drop "
            + ("it" if len(sparse_only) == 1 else "them")
        )
    if args.max_features is not None and not args.features_topic:
        raise PcaInterpError(
            f"--max-features {args.max_features} caps the points of a feature stream; "
            "add --features-topic or drop --max-features"
        )
    if args.max_features is not None and args.max_features < 1:
        raise PcaInterpError(f"--max-features must be at least 1, got {args.max_features}")
    if args.dense_matcher is not None and args.measurements != "dense":
        raise PcaInterpError(
            f"--dense-matcher {args.dense_matcher} chooses dense mode's matcher; "
            "add --measurements dense"
        )
    # --basis builtin: the built-in bases as they are (checked, the street or the indoor
    # one chosen, never replaced by the log's own); builtin-street/-indoor: that one
    args.basis, kind = basis_option(args.basis)
    builtin = kind is not None
    if args.basis is None:  # read while the log is opened and its first pair read
        from pcainterp_stream.estimate.basis import preload_builtin

        preload_builtin("street" if kind in (None, "auto") else kind)
    # only the default basis (the built-in street one, checked) may give way to the log's
    # own, learned from its stereo maps: not a basis chosen, not dense mode, not a feature stream
    may_adapt = kind is None and args.basis is None
    may_adapt = may_adapt and args.measurements != "dense" and not args.features_topic
    _check_paths(args, may_adapt=may_adapt)  # after the preload: the basis loads meanwhile
    processor = _processor_config(
        args, adapt="check" if builtin else "auto", builtin=kind or "auto"
    )
    _check_estimate(processor, args.basis)
    topics = _output_topics(args)
    if args.out_dir is not None:
        return _densify_many(args, processor, topics)
    if len(args.input) > 1 and STREAM in args.input:
        raise PcaInterpError(
            "standard input (-) is one whole log, not a part of one; pass the parts of a split "
            "recording as files (densify a_0.bag a_1.bag -o OUTPUT)"
        )
    if args.scheduler is not None or args.workers is not None:
        raise PcaInterpError("--scheduler/--workers need --out-dir DIR instead of -o")
    if args.output is not None and args.output != STREAM and not args.output.suffix:
        # an MCAP all the same, as a user may mean; the readers that go by the suffix do not
        warn(
            f"output {args.output} has no suffix: it is an MCAP, but Foxglove's file dialog "
            f"and rerun know one by its .mcap suffix; name it {args.output}.mcap to open it there"
        )
    return densify_one(
        # several inputs with -o: the parts of one split recording, read as one log
        args.input if len(args.input) > 1 else args.input[0],
        args.output,
        args.basis,
        processor=processor,
        pairing=pairing_config(args, args.features_topic),
        topics=topics,
        live=live,
        rrd=args.rrd,
        spawn_viewer=args.rerun,
    )


STEREO_OPTIONS = (
    ("--corners", "corners"),
    ("--quality", "quality"),
    ("--min-distance", "min_distance"),
    ("--fill-spacing", "fill_spacing"),
    ("--fill-placement", "fill_placement"),
    ("--num-disparities", "num_disparities"),
    ("--block-size", "block_size"),
    ("--sgbm-mode", "sgbm_mode"),
    ("--stereo-downscale", "stereo_downscale"),
    ("--edge-aware", "edge_aware"),
    ("--near-reach", "near_reach"),
)
"""The options of the stereo front end (GFTT corners, SGBM lookups and maps): a feature
stream's points replace it, so with ``--features-topic`` none of them changes the output."""


def _refuse_stereo_options(args: argparse.Namespace) -> None:
    """Refuse, in one line, the stereo front end's options given with ``--features-topic``.

    A feature stream's points are the measurements: no corner is detected, SGBM never runs
    (no lookup, no held-out pixels, no depth edges, no near-reach match; dense mode is
    refused), so these options would be accepted and do nothing.
    """
    given = []
    for flag, name in STEREO_OPTIONS:
        value = getattr(args, name, None)
        if value is None:
            continue
        if isinstance(value, bool):  # --edge-aware / --no-edge-aware
            given.append(flag if value else flag.replace("--", "--no-", 1))
        else:
            given.append(f"{flag} {value:g}" if isinstance(value, float) else f"{flag} {value}")
    if given:
        verb = "applies" if len(given) == 1 else "apply"
        raise PcaInterpError(
            f"{', '.join(given)} {verb} to the stereo front end (GFTT corners, SGBM and its "
            f"maps), which --features-topic {args.features_topic} replaces: its points are "
            "the measurements and SGBM does not run; drop "
            + ("it" if len(given) == 1 else "them")
            + " or --features-topic"
        )


def _check_paths(args: argparse.Namespace, *, may_adapt: bool = True) -> None:
    """Refuse, before any work, an output densify cannot write or that replaces what it reads.

    The outputs are ``-o`` (or each ``--out-dir`` output), the adapted basis written beside
    each when the run may adapt (``may_adapt``: ``OUTPUT.basis.npz``,
    ``OUTPUT.final.basis.npz``, and the name of a later adoption's,
    ``OUTPUT.final.basis-2.npz``, the longest up to ``-9``, for its length) and ``--rrd``;
    what it reads is the input logs, ``--basis`` and ``--calibration``.

    Raises:
        LogWriteError: an output that is a folder, not named .mcap, or one of those files.
    """
    from pcainterp_stream.pipeline.densify import final_basis_path, own_basis_path

    _check_targets(args)
    output: Path | None = args.output
    if output is not None and output != STREAM:
        if output.is_dir():
            raise LogWriteError(
                f"output {output} is a folder but densify writes one MCAP file; "
                "choose a file path ending in .mcap"
            )
        if output.suffix and output.suffix.lower() != ".mcap":
            raise LogWriteError(
                f"output {shown(output)} is named {shown(output.suffix)} but densify writes "
                f"MCAP; name the output .mcap, e.g. -o {shown(_renamed(output, '.mcap'))}"
            )
    reads: list[tuple[str, Path | None]] = [("the input", path) for path in args.input]
    reads.append(("the --basis file", args.basis))
    reads.extend(("the --calibration file", path) for path in args.calibration or ())
    if args.out_dir is not None:
        from pcainterp_stream.pipeline.distributed import output_path

        # two inputs of one stem are refused by name where the logs are handed out
        outputs = list(dict.fromkeys(output_path(path, args.out_dir) for path in args.input))
        fix = "choose a different --out-dir"
    else:
        outputs = [output] if output is not None and output != STREAM else []
        fix = "choose a different output path"
    writes: list[tuple[str, Path | None, str]] = [("the output", path, fix) for path in outputs]
    for path in outputs if may_adapt else []:
        for side in (own_basis_path(path), final_basis_path(path), final_basis_path(path, 2)):
            writes.append(
                (
                    f"the adapted basis {side.name}",
                    side,
                    f"{fix} (a run that adapts its basis writes it beside the output)",
                )
            )
    writes.append(("the --rrd recording", args.rrd, "choose a different --rrd path"))
    refuse_overwrites(writes, reads)
    _check_rrd_name(args.rrd)  # after: "onto the input drive.mcap" says more than the suffix


LOG_SUFFIXES = (".mcap", ".bag", ".db3")
"""The suffixes of the logs densify reads and writes: never a --rrd recording's."""


def _renamed(path: Path, suffix: str) -> Path:
    """Return ``path`` with ``suffix`` in place of its own, or added when it has none."""
    return path.with_suffix(suffix) if path.suffix else path.with_name(path.name + suffix)


def _check_rrd_name(rrd: Path | None) -> None:
    """Refuse a ``--rrd`` that is a folder, ``-`` or not named ``.rrd``.

    A recording named like a log would replace that log (``--rrd drive_dense.mcap``) with a
    file its readers cannot open; ``-`` would be a file named ``-``, not standard output.

    Raises:
        LogWriteError: naming the value and the fix.
    """
    if rrd is None:
        return
    if rrd == STREAM:
        raise LogWriteError(
            "--rrd - would write a file named '-': the recording cannot go to standard "
            "output (-o - is the MCAP's); name a file, e.g. --rrd densify.rrd, or view it "
            "live with --rerun"
        )
    if rrd.is_dir():
        raise LogWriteError(
            f"--rrd {rrd} is a folder; name the recording's file, e.g. --rrd {rrd / 'densify.rrd'}"
        )
    suffix = rrd.suffix.lower()
    if suffix == ".rrd":
        return
    if suffix in LOG_SUFFIXES:  # it would replace a log with a file no log reader opens
        named = f"is named {rrd.suffix}, as a log is, but the recording is a Rerun file"
    else:
        named = ("is named " + rrd.suffix if suffix else "has no suffix") + " but the "
        named += "recording is a Rerun .rrd file"
    raise LogWriteError(f"--rrd {rrd} {named}; name it .rrd, e.g. --rrd {_renamed(rrd, '.rrd')}")


def _check_targets(args: argparse.Namespace) -> None:
    """Refuse a device, a pipe or a folder in the way as -o, --rrd or --out-dir, up front.

    ``-o /dev/stdout`` (``/dev/fd/1``) becomes ``-o -``; an ``-o`` or ``--rrd`` that is a
    symbolic link is written through (the file it points to is replaced, the link kept).
    """
    from pcainterp_stream.io.output_paths import (
        check_output_file,
        check_output_folder,
        is_standard_output,
    )

    discard = "to discard or pipe the output, pass -o - (e.g. -o - > /dev/null)"
    if args.output is not None and args.output != STREAM:
        if is_standard_output(args.output):
            args.output = STREAM
        else:
            check_output_file(args.output, fix=discard)
    if args.output == STREAM and sys.stdout is None:  # closed at start (>&-, a daemon's)
        raise LogWriteError(
            "-o -: standard output is closed; redirect it to a file (-o - > out.mcap) "
            "or use -o FILE"
        )
    if args.output == STREAM and sys.stdout.isatty():  # binary would scroll over it
        raise LogWriteError(
            f"-o {args.output} writes the MCAP to standard output, which is a terminal; "
            "redirect it (-o - > out.mcap) or pipe it into a reader"
        )
    if args.rrd is not None:
        args.rrd = check_output_file(args.rrd, fix="drop --rrd, or name a file")
    if args.out_dir is not None:
        check_output_folder(args.out_dir)
        if args.out_dir.is_dir():  # its outputs are staged in it: a link is not followed
            from pcainterp_stream.pipeline.distributed import output_path

            for path in args.input:
                check_output_file(output_path(path, args.out_dir), links=False)


def _processor_config(
    args: argparse.Namespace, *, adapt: str, builtin: str = "auto"
) -> ProcessorConfig:
    """Return the estimate's config the options ask for (``adapt``: see ``ProcessorConfig``)."""
    from pcainterp_stream.frontend.matchers import DENSE_MATCHERS, dense_matcher, dense_points
    from pcainterp_stream.frontend.near import NearConfig
    from pcainterp_stream.pipeline.processor import MeasurementSource, ProcessorConfig

    source = MeasurementSource.FEATURES if args.features_topic else MeasurementSource.STEREO
    dense = args.measurements == "dense"
    sgbm = sgbm_config(
        args,
        DENSE_MATCHERS[dense_matcher(args.dense_matcher, args.stereo_downscale)]
        if dense
        else ProcessorConfig().sgbm,
    )
    near = NearConfig() if getattr(args, "near_reach", None) is not False else None
    return ProcessorConfig(
        builtin=builtin,
        adapt=adapt,
        gftt=gftt_config(args, dense_points(args.stereo_downscale) if dense else None),
        sgbm=sgbm,  # dense mode outputs the SGBM map itself where valid: full resolution
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
        max_features=args.max_features or defaults.MAX_FEATURES,
        edge_aware=args.edge_aware is not False,  # None: not given, on
        near=near,
    )


def _live_options(args: argparse.Namespace) -> LiveOptions | None:
    """Check the live-view options of a parsed command line; None without ``--foxglove``.

    Raises:
        PcaInterpError: a live option without ``--foxglove``, no output at all, or a bad
            address or rate (:class:`StreamError`).
    """
    if args.foxglove is None:
        others = [
            name
            for name, given in (
                ("--rate", args.rate is not None),
                ("--wait-for-client", args.wait_for_client),
                ("--exit-when-done", args.exit_when_done),
            )
            if given
        ]
        if others:
            verb = "needs" if len(others) == 1 else "need"
            raise PcaInterpError(f"{', '.join(others)} {verb} --foxglove [HOST:PORT]")
        if args.output is None and args.out_dir is None:
            raise PcaInterpError(
                "densify needs an output: pass -o OUTPUT (a .mcap, or - for standard output), "
                "--out-dir DIR, or --foxglove to serve it live"
            )
        return None
    if args.out_dir is not None:
        raise PcaInterpError("--foxglove serves one log; use -o OUTPUT instead of --out-dir")
    address = ServeAddress.parse(args.foxglove)
    rate = args.rate if args.rate is not None else (0.0 if args.output is not None else 1.0)
    return LiveOptions(
        address=address,
        rate=check_rate(rate),
        wait_for_client=args.wait_for_client,
        keep_serving=args.output is None and not args.exit_when_done,
    )


def _sigma_option(value: str) -> float | str:
    """``densify --sigma``: a number of px > 0, "evidence" or "auto"."""
    if value in ("auto", "evidence"):
        return value
    try:
        sigma = float(value)
    except ValueError:
        sigma = float("nan")
    if not 0 < sigma < float("inf"):
        raise PcaInterpError(f"--sigma must be a number > 0 px, 'evidence' or 'auto', got {value}")
    return sigma


def _check_estimate(processor: ProcessorConfig, basis_path: Path | None) -> None:
    """Refuse estimate options that do not fit the basis, before any work is done."""
    from pcainterp_stream.estimate.basis import Basis, builtin_basis, builtin_basis_installed

    if processor.prior == "paper" and not processor.temporal:
        return
    kind = "street" if processor.builtin == "auto" else processor.builtin
    if processor.prior == "auto" and processor.uncertainty != "paper":
        # "auto" takes the prior the basis has: nothing to refuse (the basis is read
        # later, and a missing built-in file is reported now)
        if basis_path is None and not builtin_basis_installed(kind):
            builtin_basis(kind)  # raises, naming the file and the fix
        return
    if basis_path is None:
        basis, name = builtin_basis(kind), f"the built-in {kind} basis"  # raises if missing
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


def _output_topics(args: argparse.Namespace) -> OutputTopics:
    """Return the output topics of ``densify``: --output-prefix, --depth-mm, --outputs."""
    from pcainterp_stream.io.outputs import OutputTopics

    try:
        topics = OutputTopics.with_prefix(
            args.output_prefix,
            depth_mm=args.depth_mm,
            precision=getattr(args, "precision", "full"),
        )
    except ValueError as err:
        raise PcaInterpError(f"--output-prefix {err}") from None
    if args.outputs is None:
        return topics
    try:
        return topics.only(name.strip() for name in args.outputs.split(",") if name.strip())
    except ValueError as err:
        raise PcaInterpError(f"--outputs: {err}") from None


def _check_inputs(paths: list[Path]) -> None:
    """Refuse a missing input or one that is not a log, by its format, as ``-o`` does.

    Cheap (a file's first bytes, a folder's listing); a pipe or a device is left to its
    job, which reads it once. Not with ``--scheduler``: its workers may see files this
    machine does not, and each task checks its paths on its worker (docs/cluster.md).

    Raises:
        LogReadError: the first such input, in one line naming it and the fix (and, of
            several inputs, that none was densified).
    """
    from pcainterp_stream.io.logreader import sniff_format

    for path in paths:
        if path.exists() and not (path.is_file() or path.is_dir()):
            continue
        try:
            sniff_format(path)
        except LogReadError as err:
            if len(paths) == 1:
                raise
            # all or nothing: say the other logs were not densified either (review 15e R3)
            raise LogReadError(
                f"{err}; none of the {len(paths)} logs was densified (every input is checked "
                "before the first)"
            ) from err


def _hint_split(paths: list[Path]) -> None:
    """Warn when logs given to --out-dir look like the parts of one split recording."""
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.logreader_parts import seams

    for parts, gaps in seams(paths, open_log):
        if len(parts) == 2:
            follow = f"{parts[1].name} starts {gaps[0] / 1e9:.3g} s after {parts[0].name} ends"
        else:  # one warning for the chain: each part starts where the one before ends
            names = f"{', '.join(p.name for p in parts[:-1])} and {parts[-1].name}"
            follow = (
                f"{names} follow each other (each starting at most {max(gaps) / 1e9:.3g} s "
                "after the one before ends)"
            )
        warn(
            f"{follow}: they look like the parts of one split recording, which --out-dir "
            "densifies as separate logs (each choosing its basis from its own start); to "
            f"read them as one log: pcainterp densify {' '.join(map(str, parts))} -o OUTPUT"
        )


def _densify_many(
    args: argparse.Namespace, processor: ProcessorConfig, topics: OutputTopics
) -> int:
    """Densify several logs into ``--out-dir`` on Dask; exit code 1 if any log failed."""
    from pcainterp_stream.pipeline import distributed

    if args.rrd is not None or args.rerun:
        raise PcaInterpError("--rrd/--rerun take one log; use -o OUTPUT without --out-dir")
    if args.workers is not None and args.workers < 1:
        raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
    if args.basis is not None:
        from pcainterp_stream.estimate.basis import check_basis_file

        check_basis_file(args.basis)
    if args.scheduler is None:  # a local cluster reads this machine's files: checked first
        _check_inputs(args.input)  # before the cluster starts and DIR is made
    _hint_split(args.input)
    started = time.perf_counter()
    report = _OutcomeReport(len(args.input))
    with distributed.connect(
        args.scheduler, args.workers, worker_wait=worker_wait(args), say=cluster_notes
    ) as client:
        outcomes = distributed.densify_many(
            # absolute (workers may run in another folder), links not followed: an output
            # is named after the log as given, not after the file a link points to
            [path.absolute() for path in args.input],
            args.out_dir.absolute(),
            args.basis.resolve() if args.basis is not None else None,
            client,
            on_outcome=report.print,
            pairing=pairing_config(args, args.features_topic),
            processor=processor,
            topics=topics,
        )
    frames = sum(outcome.frames for outcome in outcomes)
    failed = [outcome for outcome in outcomes if outcome.error is not None]
    tail = f"; {len(failed)} failed:" if failed else ""
    echo(
        f"{len(outcomes) - len(failed)} of {len(outcomes)} logs densified, {_frames(frames)} in "
        f"{time.perf_counter() - started:.1f} s{tail}"
    )
    for outcome in failed:
        echo(f"failed: {_error_line(outcome, hint=False)}")
    return 1 if failed else 0


@dataclasses.dataclass
class _OutcomeReport:
    """Prints each log's lines of ``densify --out-dir`` as its task is done, with a count."""

    total: int
    done: int = 0

    def print(self, outcome: DensifyOutcome) -> None:
        """Print a log's lines: ``densified ...`` (or its error), then adapted and warnings."""
        self.done += 1
        count = f"({self.done} of {self.total} logs done)"
        if outcome.error is not None:
            print(f"pcainterp: error: {_error_line(outcome)} {count}", file=sys.stderr, flush=True)
            return
        echo(f"densified {_frames(outcome.frames)} of {outcome.input} -> {outcome.output} {count}")
        if outcome.adapted is not None:
            wrote = " and ".join(str(path) for path in outcome.bases)
            echo(f"adapted: {outcome.input.name}: {outcome.adapted}; wrote {wrote}")
        for line in outcome.warnings:
            warn(f"{outcome.input.name}: {line}")


def _error_line(outcome: DensifyOutcome, *, hint: bool = True) -> str:
    """Return a failed log's error, naming the log (with ``hint``: how to see a bug's cause)."""
    error = outcome.error or ""
    if outcome.input.name not in error:
        error = f"{outcome.input}: {error}"
    if hint and outcome.unexpected:  # a bug or a dead worker: one process shows where
        error += (
            f"; densify this log alone (pcainterp densify {outcome.input} -o OUTPUT) "
            "to see where it failed"
        )
    return error


def _frames(count: int) -> str:
    """Return "1 frame", "2 frames"."""
    return f"{count} frame{'' if count == 1 else 's'}"
