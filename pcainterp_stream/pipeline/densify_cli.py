"""The ``densify`` command's own options and its run for one log (``cli.py`` calls these).

Kept apart from ``cli.py`` (argparse for every command) because one log has several ways
in and out: a file or standard input (``-``); an MCAP file, standard output (``-o -``)
or none; and a live Foxglove WebSocket server (``--foxglove``), paced (``--rate``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from pcainterp_stream import defaults
from pcainterp_stream.errors import PcaInterpError, StreamError
from pcainterp_stream.io.foxglove import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    INTERRUPTED_STOP_TIMEOUT_S,
    FoxgloveLive,
    ServeAddress,
)

if TYPE_CHECKING:
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.densify import DensifySummary
    from pcainterp_stream.pipeline.processor import ProcessorConfig

STREAM = Path("-")
"""INPUT ``-``: standard input; ``-o -``: standard output."""


def add_densify_arguments(densify: argparse.ArgumentParser) -> None:
    """Add the options of ``pcainterp densify`` that are its own (not shared with learn)."""
    densify.add_argument(
        "input",
        type=Path,
        nargs="+",
        metavar="INPUT",
        help="one log ('-': an MCAP stream on standard input), or several with --out-dir",
    )
    target = densify.add_mutually_exclusive_group()
    target.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        metavar="OUTPUT",
        help="the densified .mcap ('-': standard output); optional with --foxglove",
    )
    target.add_argument(
        "--out-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="write DIR/<stem>_dense.mcap per input, the logs densified in parallel on Dask",
    )
    live = densify.add_argument_group("live view in Foxglove (docs/viewing.md)")
    live.add_argument(
        "--foxglove",
        nargs="?",
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
        help="pace at R x the log's rate: 1 = as recorded, 0 = as fast as processed "
        "(default: 0 with -o, else 1)",
    )
    live.add_argument(
        "--wait-for-client",
        action="store_true",
        help="hold the first frame until a client subscribed to an output channel",
    )
    live.add_argument(
        "--exit-when-done",
        action="store_true",
        help="stop serving after the last frame (default without -o: serve until Ctrl-C)",
    )
    densify.add_argument(
        "--basis",
        type=Path,
        default=None,
        metavar="BASIS.npz",
        help="the basis: a file; 'builtin' for the built-in ones as they are (the street or "
        "the indoor one, whichever fits the first frames better), 'builtin-street' or "
        "'builtin-indoor' for that one (default: the built-in street basis, checked on the "
        "first frames against linear interpolation; when it does not fit, the indoor one and "
        "a basis learned from the log's own stereo are tried and the best is used; pcainterp "
        "info describes them)",
    )
    densify.add_argument("--rerun", action="store_true", help="stream to a Rerun viewer")
    densify.add_argument("--rrd", type=Path, default=None, metavar="FILE", help="write .rrd")
    _add_estimate_arguments(densify)
    densify.add_argument(
        "--features-topic",
        default=None,
        metavar="TOPIC",
        help="take measurements from this PointCloud2 stream instead of GFTT + SGBM",
    )
    densify.add_argument(
        "--output-prefix",
        default="/pcainterp",
        metavar="PREFIX",
        help="prefix of the output topics (default: %(default)s)",
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
        "of the posterior std, a 16UC1 mm depth for viewers: ~0.7 MB of output per KITTI "
        "frame. full: every channel float32, ~7.3 MB per KITTI frame (docs/benchmarks.md, "
        "'Output encodings')",
    )
    densify.add_argument(
        "--outputs",
        default=None,
        metavar="CHANNELS",
        help="comma-separated output channels to write, of depth, depth_std, disparity, "
        "disparity_std, features, camera_info (default: depth, disparity_std, features, "
        "camera_info at compact precision, all at full; evaluate needs depth or disparity, "
        "disparity_std, features, camera_info; depth and disparity are reciprocal)",
    )


def _add_estimate_arguments(densify: argparse.ArgumentParser) -> None:
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
        "--sigma",
        default="auto",
        metavar="PX|evidence|auto",
        help="measurement noise std: a number (px), 'evidence' (fitted per frame) or 'auto' "
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
    estimate.add_argument(
        "--robust",
        choices=["none", "huber", "cauchy"],
        default=defaults.ROBUST,
        help="IRLS against wrong SGBM lookups (default: %(default)s)",
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


@dataclass(frozen=True)
class LiveOptions:
    """The live-view options of one densify run.

    Attributes:
        address: where the server listens.
        rate: pace (x the log's rate; 0 = as fast as processed).
        wait_for_client: hold the first frame until a client subscribed to an output.
        keep_serving: serve after the last frame until Ctrl-C.
    """

    address: ServeAddress
    rate: float
    wait_for_client: bool
    keep_serving: bool


def live_options(args: argparse.Namespace) -> LiveOptions | None:
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
    if not 0 <= rate < float("inf"):  # also refuses nan
        raise StreamError(f"--rate must be a finite number >= 0, got {args.rate}")
    return LiveOptions(
        address=address,
        rate=rate,
        wait_for_client=args.wait_for_client,
        keep_serving=args.output is None and not args.exit_when_done,
    )


def run_densify(
    args: argparse.Namespace,
    *,
    processor: ProcessorConfig,
    pairing: PairingConfig,
    topics: OutputTopics,
    live: LiveOptions | None,
) -> int:
    """Densify one log as the command line asks; print the summary; return the exit code.

    With ``-o -`` everything printed goes to standard error: standard output carries the
    MCAP. With ``--foxglove`` the server starts first (its URL is printed), and without
    ``-o`` it serves after the last frame until Ctrl-C (exit code 0) unless
    ``--exit-when-done``.
    """
    from pcainterp_stream.pipeline.densify import densify

    to_stdout = args.output == STREAM
    output: Path | IO[bytes] | None = sys.stdout.buffer if to_stdout else args.output
    source: Path | IO[bytes] = sys.stdin.buffer if args.input[0] == STREAM else args.input[0]
    with contextlib.ExitStack() as stack:
        if to_stdout:
            stack.enter_context(contextlib.redirect_stdout(sys.stderr))
        server = None
        if live is not None:
            server = stack.enter_context(
                FoxgloveLive(
                    live.address,
                    rate=live.rate,
                    wait_for=topics.all() if live.wait_for_client else (),
                )
            )
            pace = f"{live.rate:g}x the log's rate" if live.rate > 0 else "as fast as processed"
            _echo(f"foxglove: serving on {server.url} ({pace}); in Foxglove: Open connection")
            if live.wait_for_client:
                prefix = topics.depth.rsplit("/", 1)[0]
                _echo(f"foxglove: waiting for a client to subscribe to a {prefix}/* channel")
        summary = densify(
            source,
            output,
            args.basis,
            pairing=pairing,
            processor=processor,
            topics=topics,
            rrd=args.rrd,
            spawn_viewer=args.rerun,
            live=server,
            echo=_echo,
        )
        _print_summary(summary, processor)
        if args.rrd is not None:
            _echo(f"wrote {args.rrd}")
        if server is not None:
            stats = server.stats
            _echo(
                f"foxglove: published {stats.frames} frames ({stats.messages} messages) to "
                f"{stats.clients} client(s)"
            )
            for client, count in sorted(stats.overflows.items()):
                _echo(
                    f"foxglove: client {client} fell behind: its queue overflowed {count} "
                    "time(s), its oldest messages were dropped"
                )
            if live is not None and live.keep_serving:
                try:  # a Ctrl-C right after the line below is caught too
                    _echo(f"foxglove: still serving on {server.url}; Ctrl-C to stop")
                    server.serve_forever()
                except KeyboardInterrupt:
                    _echo("foxglove: stopped")
                    server.close(drain_s=0.0, stop_timeout_s=INTERRUPTED_STOP_TIMEOUT_S)
                    # Nothing is left to write in this mode (no -o), and the SDK's threads
                    # can still be calling back into Python while the interpreter shuts
                    # down: end here, so that Ctrl-C always ends the process.
                    sys.stdout.flush()
                    sys.stderr.flush()
                    os._exit(0)
    return 0


def _echo(text: str) -> None:
    print(text, flush=True)  # sys.stdout at the time of the call: stderr with -o -


def _print_summary(summary: DensifySummary, processor: ProcessorConfig) -> None:
    dense = processor.measurements == "dense"
    _echo(
        f"densified {summary.frames} frames of {summary.input} in {summary.seconds:.1f} s "
        f"({summary.frames_per_second:.1f} frames/s), "
        f"{summary.measurements / max(summary.frames, 1):.0f} points per frame"
        + (", fused with the whole SGBM map (dense)" if dense else "")
    )
    _echo(f"pairing: {summary.pairing.summary()}")
    if processor.robust != "none":
        _echo(
            f"robust ({processor.robust}): {summary.downweighted} measurements down-weighted "
            f"({summary.downweighted / max(summary.frames, 1):.1f} per frame, at most "
            f"{summary.most_downweighted} in one frame)"
        )
    if processor.temporal:
        _echo(f"temporal prior: reset {summary.temporal_resets} times (scene changes)")
    if processor.carry.frames:
        _echo(
            f"carried from the {processor.carry.frames} previous frames: "
            f"{summary.carried / max(summary.frames, 1):.0f} points per frame; "
            f"ego-motion lost {summary.carry_resets} times"
        )
    for line in summary.prior_lines:
        _echo(line)
    if summary.basis_written is not None:
        _echo(
            f"wrote {summary.basis_written}: the basis learned from this log's first frames "
            "(the output names it; evaluate re-densifies with it)"
        )
    if summary.final_basis_written is not None:
        _echo(
            f"wrote {summary.final_basis_written}: the basis relearned from all of this "
            "log's maps (densify --basis with it for other logs of this camera)"
        )
    elif summary.basis_written is not None:
        _echo("  (densify --basis with it for other logs of this camera)")
    for line in summary.damage:
        _echo(f"damage: {line}")
    for line in summary.warnings:
        _echo(f"warning: {line}")
    written = summary.written
    if written is not None:
        duration = ((written.end_ns or 0) - (written.start_ns or 0)) / 1e9
        _echo(f"wrote {written.path}: {written.message_count} messages, {duration:.1f} s of log")
