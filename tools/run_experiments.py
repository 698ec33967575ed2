"""Run the evaluation experiments of ``docs/results.md`` (the paper's setup) end to end.

1. Synthetic (the Virtual-KITTI analogue): a basis learned from the ground-truth depth of
   ``--train-frames`` synthetic frames (seeds 101..), densify and evaluate ``--test-frames``
   frames of another seed (201), temporal mode (view B = next frame, ground-truth poses).
2. Real KITTI (the KITTI analogue): bases learned from SGBM maps of the same synthetic
   frames plus one real KITTI log; evaluation in stereo mode against dense SGBM:
   a) basis synthetic + raw drive 2011_09_26_0001, evaluated on the odometry clip;
   b) (the reverse split) basis synthetic + odometry clip, evaluated on the raw drive.
   The KITTI logs have other image sizes and f*b than the synthetic camera: each map is
   preprocessed straight onto the basis grid and its disparities scaled by
   (f*b)_basis / (f*b)_log (docs/estimator.md, "Camera mapping").

Every stage is skipped when its output exists, so an interrupted run resumes. Outputs
(logs, bases, reports, ``summary.json``) go to ``--work`` (keep it out of the repository).

    python tools/run_experiments.py --work /tmp/exp/run [--scale 1.0]
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import grid_size_for
from pcainterp_stream.estimate.learning import learn_basis, preprocess_disparity
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline import jobs

KITTI_RAW = harness.REALDATA / harness.KITTI_RAW_0001
KITTI_ODOMETRY = harness.REALDATA / harness.KITTI_ODOMETRY_CLIP
TRAIN_SEEDS_FROM = 101
TEST_SEED = 201
GRID_SCALE = 0.25


def _timed(summary: dict[str, Any], key: str, work: Callable[..., Any]) -> Any:
    """Run ``work``; record its wall seconds in ``summary["seconds"][key]`` and log them."""
    with harness.Stopwatch() as watch:
        result = work()
    summary.setdefault("seconds", {})[key] = round(watch.wall, 1)
    harness.log(f"{key}: {summary['seconds'][key]} s")
    return result


def _sgbm_grid_maps(
    log: Path, grid_size: tuple[int, int], focal_baseline: float
) -> Iterator[npt.NDArray[np.float32]]:
    """Yield SGBM maps of a log's pairs, preprocessed onto the grid, in the basis's f*b."""
    with open_log(log) as reader:
        for frame in iter_stereo_frames(reader, PairingConfig()):
            disparity = compute_disparity(frame.left, frame.right, SgbmConfig())
            scale = focal_baseline / frame.camera.focal_baseline
            yield preprocess_disparity(disparity * np.float32(scale), grid_size)


def _cached_maps(
    logs: list[Path], cache: Path, grid_size: tuple[int, int], focal_baseline: float
) -> npt.NDArray[np.float32]:
    """Return the stacked grid maps of logs, computing them once into ``cache`` (.npy)."""

    def build(path: Path) -> None:
        maps = [m for log in logs for m in _sgbm_grid_maps(log, grid_size, focal_baseline)]
        np.save(path, np.stack(maps).astype(np.float32))

    return np.asarray(np.load(harness.cached(cache, build)), dtype=np.float32)


def main(argv: list[str] | None = None) -> int:
    """Run the experiments; return the exit code."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, flag="--work", description="output folder")
    parser.add_argument("--scale", type=float, default=1.0, help="synthetic image scale")
    parser.add_argument("--train-frames", type=int, default=2000)
    parser.add_argument("--train-logs", type=int, default=4)
    parser.add_argument("--test-frames", type=int, default=201)
    parser.add_argument("--components", type=int, default=500)
    parser.add_argument("--sweep-every", type=int, default=10)
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work)
    summary_path = work / "summary.json"
    summary: dict[str, Any] = harness.read_json(summary_path, {})
    summary["args"] = {k: str(v) for k, v in vars(args).items()}

    def save() -> None:
        harness.write_json(summary_path, summary)

    def once(path: Path, key: str, build: harness.Builder) -> Path:
        """Build ``path`` unless it exists, timed as ``key`` in the summary."""

        def timed_build(target: Path) -> None:
            _timed(summary, key, lambda: build(target))
            save()

        return harness.cached(path, timed_build)

    # ------------------------------------------------------------------ synthetic logs
    per_log = -(-args.train_frames // args.train_logs)
    train_logs = [work / f"train_{TRAIN_SEEDS_FROM + i}.mcap" for i in range(args.train_logs)]
    for i, log in enumerate(train_logs):
        seed = TRAIN_SEEDS_FROM + i
        once(
            log,
            f"synth {log.name}",
            harness.build_synth(frames=per_log, seed=seed, scale=args.scale),
        )
    test_log = work / f"test_{TEST_SEED}.mcap"
    build = harness.build_synth(frames=args.test_frames, seed=TEST_SEED, scale=args.scale)
    once(test_log, f"synth {test_log.name}", build)

    # ------------------------------------------------------------------ 1. synthetic
    basis_synth = work / "basis_synth_gt.npz"
    options = jobs.LearnOptions(
        n_components=args.components, grid_scale=GRID_SCALE, depth_topic="/ground_truth/depth"
    )
    once(
        basis_synth,
        "learn synthetic (ground-truth depth)",
        lambda path: jobs.learn(train_logs, path, options, PairingConfig()),
    )
    runs: list[tuple[str, Path, Path, str | None]] = [("synthetic", test_log, basis_synth, None)]

    # ------------------------------------------------------------------ 2. KITTI
    kitti: dict[str, Path] = {}
    for name, folder in (("raw", KITTI_RAW), ("odometry", KITTI_ODOMETRY)):
        if not folder.is_dir():
            harness.log(f"{folder} missing: KITTI experiments skipped")
            break
        kitti[name] = harness.cached(work / f"kitti_{name}.mcap", harness.build_kitti(folder))
    if len(kitti) == 2:
        from pcainterp_stream.estimate.basis import Basis

        reference = Basis.load(basis_synth)
        grid_size = grid_size_for(reference.image_size, GRID_SCALE)
        synthetic_maps = _timed(
            summary,
            "SGBM maps of the synthetic training frames",
            lambda: _cached_maps(
                train_logs, work / "synth_sgbm_grid.npy", grid_size, reference.focal_baseline
            ),
        )
        for split, (train_name, test_name) in {
            "kitti_a": ("raw", "odometry"),
            "kitti_b": ("odometry", "raw"),
        }.items():
            basis_path = work / f"basis_{split}.npz"
            if not basis_path.is_file():
                real = np.stack(
                    list(_sgbm_grid_maps(kitti[train_name], grid_size, reference.focal_baseline))
                )
                basis = _timed(
                    summary,
                    f"learn {split} (SGBM: synthetic + {train_name})",
                    lambda real=real, train_name=train_name: learn_basis(
                        iter([*synthetic_maps, *real]),
                        n_components=args.components,
                        grid_scale=GRID_SCALE,
                        preprocessed=True,
                        image_size=reference.image_size,
                        focal_baseline=reference.focal_baseline,
                        meta={
                            "source": {
                                "maps": "SGBM",
                                "logs": [*map(str, train_logs), str(kitti[train_name])],
                            }
                        },
                    ),
                )
                basis.save(basis_path)
                summary.setdefault("bases", {})[split] = {
                    "synthetic_maps": int(synthetic_maps.shape[0]),
                    "real_maps": int(real.shape[0]),
                }
                save()
            runs.append((split, kitti[test_name], basis_path, "stereo"))

    # ------------------------------------------------------------------ densify + evaluate
    for name, log, basis_path, mode in runs:
        dense = work / f"{name}_dense.mcap"
        if not dense.is_file():
            result = _timed(
                summary,
                f"densify {name}",
                lambda log=log, dense=dense, b=basis_path: jobs.densify(log, dense, b),
            )
            summary.setdefault("densify", {})[name] = {
                "frames": result.frames,
                "frames_per_second": round(result.frames_per_second, 2),
                "points_per_frame": round(result.measurements / max(result.frames, 1), 1),
            }
            save()
        report = work / f"report_{name}"
        _, table = _timed(
            summary,
            f"evaluate {name}",
            lambda dense=dense, report=report, b=basis_path, mode=mode: jobs.evaluate(
                dense, report, basis=b, mode=mode, sweep_every=args.sweep_every
            ),
        )
        harness.log(f"{name}:\n{table}")
        summary.setdefault("reports", {})[name] = str(report)
        save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
