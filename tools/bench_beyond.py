"""Speed of densification with every addition of issue 7, at KITTI size, exact uncertainty.

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

import argparse
import cProfile
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np
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


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a Markdown table."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="run_beyond.py's folder")
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=3, help="best of N rounds")
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument(
        "--blas-threads", type=int, default=1, help="1 = as in the stream processor"
    )
    parser.add_argument(
        "--basis", type=Path, default=None,
        help="basis with a fitted prior (default: WORK/basis_synthetic.npz)",
    )
    parser.add_argument(
        "--system-malloc", action="store_true",
        help="leave glibc's malloc untuned (densify tunes it, ProcessorConfig.keep_freed_memory)",
    )
    parser.add_argument(
        "--configs", nargs="+", default=None, metavar="CONFIG",
        help="only these rows (configuration names; default: all)",
    )
    parser.add_argument(
        "--profile", default=None, metavar="CONFIG",
        help="profile one configuration (a row name) instead and print where the time goes",
    )
    args = parser.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run_beyond import prepare_log

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
    print("| configuration | wall ms/frame | CPU ms/frame | frames/s (wall) |")
    print("| --- | ---: | ---: | ---: |")
    if not args.system_malloc:
        keep_freed_memory()  # as the stream processor does (ProcessorConfig.keep_freed_memory)
    with threadpool_limits(args.blas_threads, user_api="blas"):
        motions: list[Motion | None] = []
        best = float("inf")
        for _ in range(args.repeat):
            started = time.perf_counter()
            motions = [None]
            motions += [
                estimate_motion(
                    images[i - 1], images[i], data.pixels[i], data.disparities[i], data.camera
                )
                for i in frames[1:]
            ]
            best = min(best, (time.perf_counter() - started) / max(len(frames) - 1, 1))
        print(
            f"| odometry for carried points (in the stereo workers) | {1000 * best:.1f} | "
            f"| {1 / best:.1f} |"
        )
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
            best_wall, best_cpu = float("inf"), float("inf")
            profiler = cProfile.Profile() if args.profile is not None else None
            for _ in range(1 if profiler else args.repeat):
                if profiler is not None:
                    profiler.enable()
                state = (
                    TemporalPrior(process_noise=float(fitted["process_noise"]))
                    if config.get("temporal")
                    else None
                )
                carrier = CarriedPoints(ProcessorConfig().carry) if config.get("carry") else None
                wall, cpu = time.perf_counter(), time.thread_time()
                for start in range(0, len(frames), args.batch):
                    batch = frames[start : start + args.batch]
                    pixels = [data.pixels[i] for i in batch]
                    disparities = [data.disparities[i] for i in batch]
                    noise_stds = None
                    if carrier is not None:
                        noise_stds = []
                        for slot, i in enumerate(batch):
                            pixels[slot], disparities[slot], noise, _ = carrier.carry(
                                None, pixels[slot], disparities[slot], data.camera,
                                motion=motions[i],
                            )
                            noise_stds.append(noise)
                    densify_batch(
                        basis,
                        pixels,
                        disparities,
                        sigma=sigma,  # type: ignore[arg-type]
                        local_prior=local,
                        robust=str(config.get("robust", "none")),
                        temporal=state,
                        image_size=data.camera.image_size,
                        focal_baseline=data.camera.focal_baseline,
                        # the std as densify calibrates it
                        std_scale=calibration.std_scale,
                        scale_by_innovation=calibration.scale_by_innovation,
                        noise_stds=noise_stds,
                    )
                if profiler is not None:
                    profiler.disable()
                best_wall = min(best_wall, (time.perf_counter() - wall) / len(frames))
                best_cpu = min(best_cpu, (time.thread_time() - cpu) / len(frames))
            if profiler is not None:
                pstats.Stats(profiler).sort_stats("tottime").print_stats(12)
            print(
                f"| {name} | {1000 * best_wall:.1f} | {1000 * best_cpu:.1f} | "
                f"{1 / best_wall:.1f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
