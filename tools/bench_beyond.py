"""Speed of densification with every estimate option beyond the paper, KITTI size, exact std.

Uses the frames and fitted bases cached by ``tools/run_beyond.py`` (real GFTT + SGBM
measurements of the synthetic test log, 1241x376, and the basis learned from synthetic
ground truth with its evidence-fitted hyperparameters), and times ``densify_batch`` as the
stream processor calls it: batches of 4 frames in stream order, BLAS on one thread, the
temporal state carried across batches. Carried points use the visual odometry of the log's
left images (``motion.estimate_motion``); ``densify`` runs it in the stereo worker threads
beside SGBM, so it is timed apart, on its own row. Reports wall and CPU (this thread) time
per frame.

    python tools/bench_beyond.py --work /tmp/beyond [--frames 100] [--repeat 3]
"""

from __future__ import annotations

import cProfile
import os
import pstats
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

import harness
import numpy as np
from beyond_data import LogData, prepare_log
from threadpoolctl import threadpool_limits

from pcainterp_stream.allocator import keep_freed_memory
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.estimate.prior import LocalPrior, TemporalPrior
from pcainterp_stream.frontend.motion import CarriedPoints, Motion, estimate_motion
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.stereo import to_grey8
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings

COLUMNS = ("configuration", "wall ms/frame", "CPU ms/frame", "frames/s (wall)")
CONFIGS: dict[str, dict[str, object]] = {
    "plain (paper)": {},
    "hybrid": {"local": True},
    "robust cauchy": {"robust": "cauchy"},
    "temporal": {"temporal": True},
    "sigma evidence": {"sigma": "evidence"},
    "hybrid + cauchy": {"local": True, "robust": "cauchy"},
    "hybrid + temporal": {"local": True, "temporal": True},
    "hybrid + cauchy + temporal": {"local": True, "robust": "cauchy", "temporal": True},
    # the default: + the measurements of the 4 previous frames, odometry included
    "hybrid + cauchy + carried": {"local": True, "robust": "cauchy", "carry": True},
}


def densify_stream(
    basis: Basis,
    data: LogData,
    frames: list[int],
    motions: list[Motion | None],
    config: dict[str, object],
    options: dict[str, Any],
    process_noise: float,
    batch: int,
) -> None:
    """Densify ``frames`` as the stream processor does: in batches, in stream order.

    A fresh temporal state (``config["temporal"]``) and carrier of points
    (``config["carry"]``, moved by ``motions``) per call; ``options`` are the other keywords
    of ``densify_batch``.
    """
    state = TemporalPrior(process_noise=process_noise) if config.get("temporal") else None
    carrier = CarriedPoints(ProcessorConfig().carry) if config.get("carry") else None
    for start in range(0, len(frames), batch):
        indices = frames[start : start + batch]
        pixels = [data.pixels[i] for i in indices]
        disparities = [data.disparities[i] for i in indices]
        noise_stds = None
        if carrier is not None:
            noise_stds = []
            for slot, i in enumerate(indices):
                pixels[slot], disparities[slot], noise, _ = carrier.carry(
                    None, pixels[slot], disparities[slot], data.camera, motion=motions[i]
                )
                noise_stds.append(noise)
        densify_batch(basis, pixels, disparities, temporal=state, noise_stds=noise_stds, **options)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a Markdown table."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, flag="--work", description="run_beyond.py's folder")
    parser.add_argument("--frames", type=int, default=100)
    harness.add_batch_timing(parser, repeat=3)
    parser.add_argument(
        "--basis",
        type=Path,
        default=None,
        help="basis with a fitted prior (default: WORK/basis_synthetic.npz)",
    )
    parser.add_argument(
        "--system-malloc",
        action="store_true",
        help="leave glibc's malloc untuned (densify tunes it, ProcessorConfig.keep_freed_memory)",
    )
    parser.add_argument(
        "--configs",
        nargs="+",
        default=None,
        metavar="CONFIG",
        help="only these rows (configuration names; default: all)",
    )
    parser.add_argument(
        "--profile",
        default=None,
        metavar="CONFIG",
        help="profile one configuration (a row name) instead and print where the time goes",
    )
    args = parser.parse_args(argv)
    basis = Basis.load(args.basis or args.work / "basis_synthetic.npz")
    fitted = basis.meta["prior"]
    camera_of_basis = (basis.image_size, basis.focal_baseline)
    data = prepare_log(
        args.work / "test_201.mcap", args.work / "cache_test_201", camera_of_basis, truth=True
    )
    frames = list(range(min(args.frames, data.frames)))
    images = []  # left images for the odometry of the carried points
    with open_log(args.work / "test_201.mcap") as reader:
        for _, frame in zip(frames, iter_stereo_frames(reader, PairingConfig()), strict=False):
            images.append(to_grey8(frame.left))
    points = np.mean([data.pixels[i].shape[0] for i in frames])
    print(
        f"{len(frames)} frames, {points:.0f} points/frame, l = {basis.n_components}, "
        f"image {basis.image_size[1]}x{basis.image_size[0]}, grid "
        f"{basis.grid_size[1]}x{basis.grid_size[0]}, BLAS threads {args.blas_threads}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    print(harness.table_header(COLUMNS, "lrrr"))
    if not args.system_malloc:
        keep_freed_memory()  # as the stream processor does (ProcessorConfig.keep_freed_memory)
    with threadpool_limits(args.blas_threads, user_api="blas"):
        motions: list[Motion | None] = [None]

        def odometry() -> None:
            motions[1:] = [
                estimate_motion(
                    images[i - 1], images[i], data.pixels[i], data.disparities[i], data.camera
                )
                for i in frames[1:]
            ]

        best = harness.timed(odometry, args.repeat, warmup=False).best / max(len(frames) - 1, 1)
        label = "odometry for carried points (in the stereo workers)"
        print(harness.table_row([label, f"{1000 * best:.1f}", "", f"{1 / best:.1f}"]))
        for name, config in CONFIGS.items():
            if args.profile is not None and name != args.profile:
                continue
            if args.configs is not None and name not in args.configs:
                continue
            local = LocalPrior.from_meta(fitted["local"]) if config.get("local") else None
            calibration = resolve_settings(
                basis, ProcessorConfig(prior="hybrid" if local is not None else "paper")
            )
            sigma = config.get("sigma", fitted["sigma"] if local else fitted["plain_sigma"])
            options: dict[str, Any] = {
                "sigma": sigma,
                "local_prior": local,
                "robust": str(config.get("robust", "none")),
                "image_size": data.camera.image_size,
                "focal_baseline": data.camera.focal_baseline,
                # the std as densify calibrates it
                "std_scale": calibration.std_scale,
                "scale_by_innovation": calibration.scale_by_innovation,
                "zero_is_match": True,  # SGBM's 0 is a match, as in densify
            }
            noise = float(fitted["process_noise"])
            run = partial(
                densify_stream, basis, data, frames, motions, config, options, noise, args.batch
            )
            profiler = cProfile.Profile() if args.profile is not None else None
            if profiler is not None:
                run = partial(profiler.runcall, run)
            rounds = 1 if profiler else args.repeat
            timing = harness.timed(run, rounds, warmup=False, cpu_clock=time.thread_time)
            if profiler is not None:
                pstats.Stats(profiler).sort_stats("tottime").print_stats(12)
            wall, cpu = timing.best / len(frames), timing.best_cpu / len(frames)
            cells = [f"{1000 * wall:.1f}", f"{1000 * cpu:.1f}", f"{1 / wall:.1f}"]
            print(harness.table_row([name, *cells]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
