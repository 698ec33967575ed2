"""Score sparse mode (densify's defaults, built-in basis) on real truth, synthetic truth and SGBM.

Four sources, each densified by the frame processor exactly as ``pcainterp densify`` does
(fit check, carried points, hybrid prior, Cauchy IRLS, calibrated std), one variant of the
measurement options at a time:

- ``lidar``: the three KITTI depth-completion frames (``kitti_depth_annotated_07``), against
  their accumulated-LiDAR truth (disparity = f*b / depth);
- ``synth``: synthetic street drives of held-out seeds (the built-in basis learned seeds
  1000-1199), full size, against the renderer's depth;
- ``odometry`` and ``raw``: the two KITTI clips, against the full-resolution SGBM map of the
  same pair (the reference ``evaluate`` uses for a stereo log without truth).

Figures per source: mean |disparity error| (px) over the reference's pixels, at its depth
discontinuities (> 3 px disparity range in the 9x9 window) and the +-2 sigma coverage there
and away from them, the same error for nearest-neighbour interpolation of the frame's own
points (ratio), the share of reference pixels within +-2 sigma, depth RMSE (m, depths capped
at 80 m), the frame's own points, and the processor's wall time relative to the first
variant in the same run.

    python tools/sparse_sharpness.py --variants corners400 default --timing
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.baselines import nearest
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoCamera, StereoFrame

Array = npt.NDArray[np.float32]
DEPTH_CAP_M = 80.0

# variant name -> changes to ProcessorConfig's corner options
VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    # the previous default: 400 strongest corners, no lattice
    "corners400": {"gftt": {"max_corners": 400, "fill_spacing": 0.0}},
    "corners600": {"gftt": {"max_corners": 600, "fill_spacing": 0.0}},
    "buckets12x4": {"gftt": {"max_corners": 400, "fill_spacing": 0.0, "buckets": (12, 4)}},
    "buckets24x6": {"gftt": {"max_corners": 400, "fill_spacing": 0.0, "buckets": (24, 6)}},
    "corners400_fill30": {"gftt": {"max_corners": 400, "fill_spacing": 30.0}},
    "corners400_fill40": {"gftt": {"max_corners": 400, "fill_spacing": 40.0}},
    "corners400_fill50": {"gftt": {"max_corners": 400, "fill_spacing": 50.0}},
    "corners400_fill60": {"gftt": {"max_corners": 400, "fill_spacing": 60.0}},
    "corners300_fill40_any_contrast": {"gftt": {"max_corners": 300, "fill_min_contrast": 0.0}},
    "corners300_fill40_contrast2.5": {"gftt": {"max_corners": 300, "fill_min_contrast": 2.5}},
    "corners300_fill50": {"gftt": {"max_corners": 300, "fill_spacing": 50.0}},
    "corners300_fill40": {"gftt": {"max_corners": 300}},
    "corners300_fill45": {"gftt": {"max_corners": 300, "fill_spacing": 45.0}},
    "buckets24x6_fill50": {"gftt": {"max_corners": 400, "buckets": (24, 6), "fill_spacing": 50.0}},
}


def _variant_config(name: str) -> ProcessorConfig:
    """Return the processor options of variant ``name`` (see :data:`VARIANTS`)."""
    base = ProcessorConfig()
    changes = dict(VARIANTS[name])
    gftt = dataclasses.replace(base.gftt, **changes.pop("gftt", {}))
    return dataclasses.replace(base, gftt=gftt, **changes)


def _lidar_frames(realdata: Path) -> Iterator[tuple[StereoFrame, Array]]:
    from dense_truth import read_annotated

    frames = read_annotated(realdata / "kitti_depth_annotated_07")
    camera = frames.camera
    assert isinstance(camera, StereoCamera)
    for index, (left, right, truth) in enumerate(
        zip(frames.lefts, frames.rights, frames.truths, strict=True)
    ):
        stamp = 1_000_000_000 + index * 100_000_000
        yield _frame(index, stamp, left, right, camera), truth.astype(np.float32)


def _frame(index: int, stamp: int, left: Any, right: Any, camera: StereoCamera) -> StereoFrame:
    return StereoFrame(index, stamp, stamp, "left", left, right, camera)


def _synth_frames(seeds: list[int], frames: int) -> Iterator[tuple[StereoFrame, Array]]:
    from pcainterp_stream.synth import SynthConfig, generate

    for seed in seeds:
        for item in generate(SynthConfig(seed=seed, frames=frames)):
            camera = item.camera
            with np.errstate(divide="ignore", invalid="ignore"):
                truth = (camera.focal_baseline / item.depth).astype(np.float32)
            yield _frame(item.index, item.stamp_ns, item.left, item.right, camera), truth


def _kitti_frames(folder: Path, frames: int) -> Iterator[tuple[StereoFrame, Array]]:
    from pcainterp_stream.io.kitti import iter_frames, open_kitti

    sequence = open_kitti(folder)
    for index, item in enumerate(iter_frames(sequence, max_frames=frames)):
        reference = compute_disparity(item.left, item.right, SgbmConfig())
        yield _frame(index, item.stamp_ns, item.left, item.right, sequence.camera), reference


def _cached(
    work: Path, name: str, make: Callable[[], Iterator[tuple[StereoFrame, Array]]]
) -> list[tuple[StereoFrame, Array]]:
    """Frames and references of a source, kept in ``work`` after the first run."""
    path = work / f"{name}.npz"
    if path.exists():
        data = np.load(path, allow_pickle=True)
        cameras = data["cameras"]
        return [
            (
                _frame(
                    i,
                    int(data["stamps"][i]),
                    data["lefts"][i],
                    data["rights"][i],
                    StereoCamera(*cameras[i]),
                ),
                data["truths"][i],
            )
            for i in range(len(data["stamps"]))
        ]
    items = list(make())
    np.savez(
        path,
        stamps=np.array([f.stamp_ns for f, _ in items]),
        lefts=np.stack([f.left for f, _ in items]),
        rights=np.stack([f.right for f, _ in items]),
        truths=np.stack([t for _, t in items]),
        cameras=np.array([dataclasses.astuple(f.camera) for f, _ in items]),
    )
    return items


def _depth_edges(truth: Array, valid: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Reference pixels at a depth discontinuity (> 3 px range in their 9x9 window).

    The range is taken over the valid reference pixels of the window only.
    """
    import cv2

    kernel = np.ones((9, 9), np.uint8)
    high = cv2.dilate(np.where(valid, truth, 0.0).astype(np.float32), kernel)
    low = cv2.erode(np.where(valid, truth, 1e6).astype(np.float32), kernel)
    return np.asarray(valid & (high - low > 3.0))


def score(items: list[tuple[StereoFrame, Array]], config: ProcessorConfig) -> dict[str, float]:
    """Densify the frames with ``config``; return the figures against their references."""
    started = time.perf_counter()
    with FrameProcessor(None, config) as processor:
        results = list(processor.process([frame for frame, _ in items]))
    seconds = time.perf_counter() - started
    sums = dict.fromkeys(
        ("px", "err", "nn", "inside", "sq_depth", "edge_px", "edge_err", "edge_inside"), 0.0
    )
    points = 0
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        estimate = result.disparity
        error = np.abs(estimate - truth)[valid]
        near = nearest(result.pixels, result.disparities, image_size=truth.shape).disparity
        std = result.disparity_std[valid]
        inside = error <= 2.0 * std
        sums["px"] += valid.sum()
        sums["err"] += error.sum()
        sums["nn"] += np.abs(near - truth)[valid].sum()
        sums["inside"] += inside.sum()
        edge = _depth_edges(truth, valid)[valid]
        sums["edge_px"] += edge.sum()
        sums["edge_err"] += error[edge].sum()
        sums["edge_inside"] += inside[edge].sum()
        depth_true = np.minimum(frame.camera.focal_baseline / truth[valid], DEPTH_CAP_M)
        with np.errstate(divide="ignore"):
            depth_est = np.minimum(
                frame.camera.focal_baseline / np.maximum(estimate[valid], 0), DEPTH_CAP_M
            )
        sums["sq_depth"] += ((depth_est - depth_true) ** 2).sum()
        points += len(result.pixels)
    return {
        "error_px": sums["err"] / sums["px"],
        "nearest_px": sums["nn"] / sums["px"],
        "ratio_nn": sums["err"] / sums["nn"],
        "coverage_2sigma": 100.0 * sums["inside"] / sums["px"],
        "edge_error_px": sums["edge_err"] / max(sums["edge_px"], 1.0),
        "edge_coverage": 100.0 * sums["edge_inside"] / max(sums["edge_px"], 1.0),
        "away_coverage": 100.0
        * (sums["inside"] - sums["edge_inside"])
        / max(sums["px"] - sums["edge_px"], 1.0),
        "depth_rmse_m": float(np.sqrt(sums["sq_depth"] / sums["px"])),
        "points": points / len(items),
        "seconds": seconds,
        "frames": float(len(items)),
    }


def guided_filter(guide: Array, image: Array, radius: int, eps: float) -> Array:
    """He et al.'s guided filter of ``image`` with ``guide`` (box windows of side 2r + 1)."""
    import cv2

    size = (2 * radius + 1, 2 * radius + 1)

    def box(x: Array) -> Array:
        return np.asarray(cv2.boxFilter(x, -1, size, borderType=cv2.BORDER_REFLECT), np.float32)

    mean_i, mean_p = box(guide), box(image)
    slope = (box(guide * image) - mean_i * mean_p) / (box(guide * guide) - mean_i**2 + eps)
    offset = mean_p - slope * mean_i
    return np.asarray(box(slope) * guide + box(offset), np.float32)


GUIDED = [(4, 1e-3), (8, 1e-3), (8, 1e-2), (16, 1e-3), (16, 1e-2), (32, 1e-2)]
"""(radius px, eps) of the guided-filter rows (``--guided``)."""


def guided_rows(items: list[tuple[StereoFrame, Array]], config: ProcessorConfig) -> list[str]:
    """Mean error and +-2 sigma coverage of the estimate refined by a guided filter.

    The left image (0-1) guides; the refined map q is blended by the posterior std s,
    f + w (q - f) with w = s^2 / (s^2 + s0^2) (s0 = 1, 3 px) or w = 1; the std is kept.
    """
    with FrameProcessor(None, config) as processor:
        results = list(processor.process([frame for frame, _ in items]))
    sums: dict[str, list[float]] = {}
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        guide = np.asarray(frame.left, np.float32) / 255.0
        estimate = np.asarray(result.disparity, np.float32)
        std = result.disparity_std

        rows: dict[str, Array] = {"none": estimate}
        for radius, eps in GUIDED:
            refined = guided_filter(guide, estimate, radius, eps)
            rows[f"r {radius}, eps {eps:g}, w = 1"] = refined
            for s0 in (1.0, 3.0):
                weight = std * std / (std * std + s0 * s0)
                rows[f"r {radius}, eps {eps:g}, s0 {s0:g}"] = estimate + weight * (
                    refined - estimate
                )
        for name, refined in rows.items():
            error = np.abs(refined - truth)[valid]
            row = sums.setdefault(name, [0.0, 0.0, 0.0])
            row[0] += error.sum()
            row[1] += valid.sum()
            row[2] += (error <= 2.0 * std[valid]).sum()
    return [f"| {k} | {e / n:.3f} | {100 * c / n:.1f} |" for k, (e, n, c) in sums.items()]


def estimate_seconds(
    items: list[tuple[StereoFrame, Array]], configs: list[ProcessorConfig], repeats: int = 3
) -> list[float]:
    """CPU seconds per frame of the estimate alone, for each configuration's points.

    ``densify_batch`` of 4 frames at a time, one BLAS thread, the processor's settings, no
    carried points; the configurations are timed in turns, the best of ``repeats`` kept.
    """
    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.basis import Basis
    from pcainterp_stream.estimate.estimator import densify_batch
    from pcainterp_stream.frontend.stereo import StereoFrontEnd
    from pcainterp_stream.pipeline.processor import resolve_settings

    basis = Basis.default()
    measured = []
    for config in configs:
        front_end = StereoFrontEnd(config.gftt, config.sgbm)
        measured.append([front_end.measure(frame.left, frame.right) for frame, _ in items])
    best = [np.inf] * len(configs)
    camera = items[0][0].camera
    with threadpool_limits(1):
        for _ in range(repeats):
            for index, config in enumerate(configs):
                options = resolve_settings(basis, config).densify_options()
                started = time.process_time()
                for start in range(0, len(items), 4):
                    batch = measured[index][start : start + 4]
                    densify_batch(
                        basis,
                        [m.pixels for m in batch],
                        [m.disparities for m in batch],
                        image_size=camera.image_size,
                        focal_baseline=camera.focal_baseline,
                        robust=config.robust,
                        **options,
                    )
                best[index] = min(best[index], (time.process_time() - started) / len(items))
    return best


def main(argv: list[str] | None = None) -> int:
    """Run the variants on the sources; print one Markdown table per source."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/sparse_sharpness"))
    harness.add_realdata(parser)
    parser.add_argument("--variants", nargs="+", default=["default"], choices=sorted(VARIANTS))
    parser.add_argument(
        "--sources",
        nargs="+",
        default=["lidar", "synth", "odometry", "raw"],
        choices=["lidar", "synth", "odometry", "raw"],
    )
    parser.add_argument("--synth-seeds", type=int, nargs="+", default=[9001, 9002])
    parser.add_argument("--synth-frames", type=int, default=20)
    parser.add_argument("--kitti-frames", type=int, default=40)
    parser.add_argument(
        "--timing", action="store_true", help="also time the estimate alone per variant"
    )
    parser.add_argument(
        "--guided",
        action="store_true",
        help="also score a guided filter of the first variant's maps with the left image",
    )
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    realdata: Path = args.realdata
    makers: dict[str, Callable[[], Iterator[tuple[StereoFrame, Array]]]] = {
        "lidar": lambda: _lidar_frames(realdata),
        "synth": lambda: _synth_frames(args.synth_seeds, args.synth_frames),
        "odometry": lambda: _kitti_frames(
            realdata / harness.KITTI_ODOMETRY_CLIP, args.kitti_frames
        ),
        "raw": lambda: _kitti_frames(realdata / harness.KITTI_RAW_0001, args.kitti_frames),
    }
    keys = (
        "error_px",
        "edge_error_px",
        "edge_coverage",
        "away_coverage",
        "nearest_px",
        "ratio_nn",
        "coverage_2sigma",
        "depth_rmse_m",
        "points",
        "seconds",
    )
    for source in args.sources:
        tag = (
            source
            if source != "synth"
            else f"synth_{'_'.join(map(str, args.synth_seeds))}_{args.synth_frames}"
        )
        if source in ("odometry", "raw"):
            tag = f"{source}_{args.kitti_frames}"
        items = _cached(work, tag, makers[source])
        print(f"\n{source}: {len(items)} frames")
        print("| variant | " + " | ".join(keys) + " | time ratio |")
        print("| --- |" + " ---: |" * (len(keys) + 1))
        first = None
        for variant in args.variants:
            figures = score(items, _variant_config(variant))
            first = first or figures["seconds"]
            cells = " | ".join(f"{figures[k]:.3f}" for k in keys)
            print(f"| {variant} | {cells} | {figures['seconds'] / first:.2f} |", flush=True)
        if args.guided:
            print("\n| guided filter (first variant) | error_px | coverage_2sigma |")
            print("| --- | ---: | ---: |")
            print("\n".join(guided_rows(items, _variant_config(args.variants[0]))), flush=True)
        if args.timing:
            configs = [_variant_config(v) for v in args.variants]
            seconds = estimate_seconds(items, configs)
            print(
                "estimate CPU ms/frame: "
                + ", ".join(
                    f"{v} {1000 * t:.1f} ({t / seconds[0]:.2f}x)"
                    for v, t in zip(args.variants, seconds, strict=True)
                ),
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
