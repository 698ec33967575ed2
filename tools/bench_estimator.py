"""Benchmark the estimator at KITTI size: speed, memory and the accuracy cost of the grid.

Timing rows use random orthonormal bases (QR of random smooth fields) with l components;
accuracy rows use bases learned from generated street-like disparity maps (sky, road plane,
facades on both sides, box obstacles) and held-out maps with GFTT-scattered measurements.
The full-resolution reference is the same MAP estimate with a full-resolution basis and
the exact variance on every pixel. Prints Markdown tables.

    python tools/bench_estimator.py            # the documented run (a few minutes)
    python tools/bench_estimator.py --quick    # a small smoke run
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from typing import Any

import cv2
import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.estimator import densify, densify_batch
from pcainterp_stream.estimate.learning import learn_basis

FOCAL = 720.0
BASELINE = 0.54
CAMERA_HEIGHT = 1.65

Array = npt.NDArray[np.float32]
TIMING_COLUMNS = (
    "configuration",
    "uncertainty",
    "single frames/s",
    "batched frames/s",
    "peak MB (batch)",
)
ACCURACY_COLUMNS = (
    "configuration",
    "learn s",
    "MAE vs truth (px)",
    "RMS disparity vs full-res (px)",
    "RMS std vs full-res (px)",
    "mean std (px)",
)


def street_map(seed: int, image_size: tuple[int, int]) -> Array:
    """Return a random piecewise-planar street-like disparity map (H, W) float32 (px)."""
    rng = np.random.default_rng(seed)
    height, width = image_size
    scale = width / 1241.0
    focal = FOCAL * scale
    cx = width / 2 + rng.uniform(-20, 20) * scale
    cy = height * rng.uniform(0.42, 0.5)
    u = np.arange(width, dtype=np.float32)[None, :]
    v = np.arange(height, dtype=np.float32)[:, None]
    disparity = np.zeros(image_size, dtype=np.float32)  # sky: d = 0
    road = np.where(v > cy, BASELINE * (v - cy) / CAMERA_HEIGHT * (focal / FOCAL), 0.0)
    np.maximum(disparity, np.broadcast_to(road, image_size), out=disparity)
    for side in (-1.0, 1.0):
        lateral = rng.uniform(3.0, 12.0)
        lateral_px = np.maximum(side * (u - cx), 1e-3)
        facade = focal * BASELINE * lateral_px / (focal * lateral)  # d = b (u - cx) / X
        depth = focal * BASELINE / np.maximum(facade, 1e-6)
        roof = np.full(depth.shape, 0.0, dtype=np.float32)
        start = 0.0
        while start < 150.0:  # buildings of random height and length, with gaps
            length = rng.uniform(8.0, 40.0)
            gap = rng.uniform(0.0, 10.0) if rng.random() < 0.4 else 0.0
            height_m = rng.uniform(4.0, 20.0)
            inside = (depth >= start) & (depth < start + length)
            roof = np.where(inside, height_m, roof)
            start += length + gap
        top = cy - (roof - CAMERA_HEIGHT) * facade / BASELINE * (focal / FOCAL)
        bottom = cy + CAMERA_HEIGHT * facade / BASELINE * (focal / FOCAL)
        covered = (side * (u - cx) > 0) & (roof > 0) & (v >= top) & (v <= bottom)
        np.maximum(disparity, np.where(covered, facade, 0.0).astype(np.float32), out=disparity)
    for _ in range(rng.integers(0, 5)):
        depth = rng.uniform(6.0, 40.0)
        x0 = rng.uniform(-4.0, 3.0)
        size = rng.uniform(1.5, 3.0)
        tall = rng.uniform(1.2, 2.5)
        d = focal * BASELINE / depth
        left, right = cx + focal * x0 / depth, cx + focal * (x0 + size) / depth
        top, bottom = (
            cy + focal * (CAMERA_HEIGHT - tall) / depth,
            cy + focal * CAMERA_HEIGHT / depth,
        )
        box = (u >= left) & (u <= right) & (v >= top) & (v <= bottom)
        np.maximum(disparity, np.where(box, d, 0.0).astype(np.float32), out=disparity)
    return disparity


def feature_points(seed: int, image_size: tuple[int, int], k: int) -> npt.NDArray[np.float64]:
    """Return (k, 2) float64 GFTT corners (x, y) of a random texture: well-spread points."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, image_size).astype(np.float32), (0, 0), 2.0)
    corners = cv2.goodFeaturesToTrack(texture, k, 0.01, 10)
    points: npt.NDArray[np.float64] = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    return points


def measure(truth: Array, pixels: npt.NDArray[np.float64], seed: int) -> npt.NDArray[np.float64]:
    """Disparities of ``truth`` at integer ``pixels`` with 0.5 px Gaussian noise."""
    rng = np.random.default_rng(seed)
    rows, cols = np.rint(pixels[:, 1]).astype(int), np.rint(pixels[:, 0]).astype(int)
    noisy: npt.NDArray[np.float64] = truth[rows, cols] + rng.normal(0, 0.5, pixels.shape[0])
    return noisy


def random_basis(
    image_size: tuple[int, int], grid_scale: float, n_components: int, seed: int
) -> Basis:
    """A random orthonormal basis of smooth fields (for timing only)."""
    rng = np.random.default_rng(seed)
    grid = grid_size_for(image_size, grid_scale)
    coarse = rng.normal(size=(n_components, 12, 40)).astype(np.float32)
    fields = np.stack(
        [cv2.resize(c, (grid[1], grid[0]), interpolation=cv2.INTER_CUBIC) for c in coarse]
    ).reshape(n_components, -1)
    fields += 1e-3 * rng.normal(size=fields.shape).astype(np.float32)
    q, _ = np.linalg.qr(fields.T)
    return Basis(
        mean=np.full(grid, 20.0, dtype=np.float32),
        components=np.ascontiguousarray(q.T, dtype=np.float32).reshape(n_components, *grid),
        eigenvalues=np.geomspace(400.0 * grid[0] * grid[1] / 50, 1e-2, n_components),
        total_variance=1e9,
        image_size=image_size,
        focal_baseline=FOCAL * BASELINE,
        n_train=0,
    )


@dataclass(frozen=True)
class Cost:
    """Seconds per frame and the peak traced allocation (MB) of a run."""

    seconds: float
    peak_mb: float


def cost(run: Callable[[], object], n_frames: int, repeat: int = 2) -> Cost:
    """Best of ``repeat`` runs (after a warm-up) of ``run``, per frame; traced peak memory."""
    return Cost(harness.timed(run, repeat).best / n_frames, harness.traced_peak_mb(run))


def densify_each(
    basis: Basis,
    pixels: list[npt.NDArray[np.float64]],
    values: list[npt.NDArray[np.float64]],
    **options: Any,
) -> None:
    """Densify frame by frame (``densify``), for timing against ``densify_batch``."""
    for frame_pixels, frame_values in zip(pixels, values, strict=True):
        densify(basis, frame_pixels, frame_values, **options)


def naive_reference(
    basis: Basis, pixels: npt.NDArray[np.float64], values: npt.NDArray[np.float64], sigma: float
) -> tuple[Array, Array, Array]:
    """Paper-style full-resolution numpy: l-space solve, diagonal and plain exact variance."""
    height, width = basis.image_size
    full = basis.components.reshape(basis.n_components, -1).T  # (s, l)
    index = np.rint(pixels[:, 1]).astype(int) * width + np.rint(pixels[:, 0]).astype(int)
    rows = full[index].astype(np.float64)
    residual = values - basis.mean.reshape(-1)[index]
    system = sigma**2 * np.diag(1.0 / basis.eigenvalues) + rows.T @ rows
    coefficients = np.linalg.solve(system, rows.T @ residual)
    covariance = sigma**2 * np.linalg.inv(system)
    disparity = full @ coefficients.astype(np.float32) + basis.mean.reshape(-1)
    paper = (full * full) @ np.diag(covariance).astype(np.float32)
    exact = np.einsum("sl,sl->s", full @ covariance.astype(np.float32), full)
    shape = (height, width)
    return disparity.reshape(shape), np.sqrt(paper).reshape(shape), np.sqrt(exact).reshape(shape)


def rms(a: npt.NDArray[np.floating], b: npt.NDArray[np.floating]) -> float:
    """Root-mean-square difference."""
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def timing_table(args: argparse.Namespace, image_size: tuple[int, int]) -> None:
    """Frames/s and peak memory per grid scale, uncertainty mode, single and batched."""
    k, n_frames = args.k, args.frames
    rng = np.random.default_rng(1)
    pixels = [
        rng.uniform(0, [image_size[1] - 1, image_size[0] - 1], (k, 2)) for _ in range(n_frames)
    ]
    values = [rng.uniform(1, 80, k) for _ in range(n_frames)]
    print(f"\n### Timing (random orthonormal basis, l = {args.components}, k = {k})\n")
    print(harness.table_header(TIMING_COLUMNS, "llrrr"))
    full = random_basis(image_size, 1.0, args.components, 0)
    few = 2
    with harness.Stopwatch() as naive:
        naive_reference(full, pixels[0], values[0], 2.0)
    label = "naive full-res reference (numpy, l-space, paper + plain exact)"
    print(harness.table_row([label, "both", f"{1 / naive.wall:.2f}", "-", "-"]))
    for scale in args.scales:
        basis = full if scale == 1.0 else random_basis(image_size, scale, args.components, 0)
        strides: list[int | None] = [None]
        if scale == 0.25:
            strides = [1, None, 4]
        for stride in strides:
            label = f"grid 1/{round(1 / scale)}, std stride {stride or 'auto'}"
            for mode in ("none", "paper", "exact"):
                if scale == 1.0 and stride == 1 and mode != "none":
                    continue
                frames = few if scale >= 0.5 else n_frames

                options: dict[str, Any] = {"uncertainty": mode, "variance_stride": stride}
                some = (basis, pixels[:frames], values[:frames])
                single = partial(densify_each, *some, **options)
                batch = partial(densify_batch, *some, **options)
                one = cost(single, frames, repeat=1 if scale >= 0.5 else 2)
                many = cost(batch, frames, repeat=1 if scale >= 0.5 else 2)
                rates = [f"{1 / one.seconds:.1f}", f"{1 / many.seconds:.1f}"]
                print(harness.table_row([label, mode, *rates, f"{many.peak_mb:.0f}"]))
    for name, baseline in (("nearest", nearest), ("linear", linear)):

        def call(function: Callable[..., object] = baseline) -> object:
            return function(pixels[0], values[0], image_size=image_size)

        run = cost(call, 1)
        cells = [f"baseline {name}", "none", f"{1 / run.seconds:.1f}", "-", f"{run.peak_mb:.0f}"]
        print(harness.table_row(cells))


def accuracy_table(args: argparse.Namespace, image_size: tuple[int, int]) -> None:
    """Accuracy of each grid scale against the truth and the full-resolution computation."""
    n_train, n_test, n_comp = args.train, args.test, args.learned_components

    def training() -> Iterator[Array]:
        for i in range(n_train):
            yield street_map(i, image_size)

    tests = [street_map(100_000 + i, image_size) for i in range(n_test)]
    points = [feature_points(200_000 + i, image_size, args.k) for i in range(n_test)]
    values = [
        measure(t, p, 300_000 + i) for i, (t, p) in enumerate(zip(tests, points, strict=True))
    ]
    results: dict[str, list[tuple[Array, Array]]] = {}
    learn_seconds: dict[float, float] = {}
    configs: list[tuple[float, int | None]] = []
    for scale in args.scales:
        configs.extend(
            [(scale, 1), (scale, None)]
            if scale in (0.25, 0.125)
            else [(scale, None if scale < 1 else 1)]
        )
    configs.append((0.25, 4))
    bases: dict[float, Basis] = {}
    for scale in sorted({c[0] for c in configs}, reverse=True):
        with harness.Stopwatch() as learning:
            bases[scale] = learn_basis(
                training(), n_components=n_comp, grid_scale=scale, focal_baseline=FOCAL * BASELINE
            )
        learn_seconds[scale] = learning.wall
    for scale, stride in configs:
        out = densify_batch(bases[scale], points, values, variance_stride=stride)
        key = f"grid 1/{round(1 / scale)}, std stride {stride or 'auto'}"
        results[key] = [
            (r.disparity, r.disparity_std if r.disparity_std is not None else r.disparity)
            for r in out
        ]
    reference = results["grid 1/1, std stride 1"]
    print(
        f"\n### Accuracy (learned bases: {n_train} training maps, l = {n_comp}, "
        f"{n_test} held-out maps, k <= {args.k} GFTT points, noise 0.5 px)\n"
    )
    print(harness.table_header(ACCURACY_COLUMNS, "lrrrrr"))
    for key, maps in results.items():
        scale = 1.0 / float(key.split("/")[1].split(",")[0])
        mae = np.mean([np.abs(d - t).mean() for (d, _), t in zip(maps, tests, strict=True)])
        disp = np.mean([rms(d, r[0]) for (d, _), r in zip(maps, reference, strict=True)])
        std = np.mean([rms(s, r[1]) for (_, s), r in zip(maps, reference, strict=True)])
        mean_std = np.mean([s.mean() for _, s in maps])
        numbers = [f"{learn_seconds[scale]:.1f}", f"{mae:.3f}", f"{disp:.3f}", f"{std:.3f}"]
        print(harness.table_row([key, *numbers, f"{mean_std:.2f}"]))
    for name, baseline in (("nearest", nearest), ("linear", linear)):
        mae = np.mean(
            [
                np.abs(baseline(p, v, image_size=image_size).disparity - t).mean()
                for p, v, t in zip(points, values, tests, strict=True)
            ]
        )
        print(harness.table_row([f"baseline {name}", "-", f"{mae:.3f}", "-", "-", "-"]))


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print Markdown tables."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    parser.add_argument("--components", type=int, default=500, help="l for timing rows")
    parser.add_argument("--learned-components", type=int, default=150, help="l for accuracy rows")
    parser.add_argument("--train", type=int, default=300, help="training maps for accuracy rows")
    parser.add_argument("--test", type=int, default=10, help="held-out maps")
    parser.add_argument("-k", type=int, default=300, help="measurements per frame")
    parser.add_argument("--frames", type=int, default=16, help="frames per timing run")
    parser.add_argument("--skip-timing", action="store_true")
    parser.add_argument("--skip-accuracy", action="store_true")
    args = parser.parse_args(argv)
    image_size = (376, 1241)
    args.scales = [1.0, 0.5, 0.25, 0.125]
    if args.quick:
        image_size = (94, 310)
        args.components, args.learned_components, args.train, args.test = 60, 20, 40, 3
        args.k, args.frames = 40, 4
    if not args.skip_timing:
        timing_table(args, image_size)
    if not args.skip_accuracy:
        accuracy_table(args, image_size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
