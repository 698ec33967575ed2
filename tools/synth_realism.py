"""How KITTI-like are the synthetic frames? SGBM accuracy, pixel classes, disparity histograms.

Usage:
    python tools/synth_realism.py [--frames N] [--stride K] [--seeds 0 1] [--out docs/img]
        [--realdata ../shared/realdata]

(a) OpenCV SGBM (numDisparities=128, blockSize=5, P1=8*25, P2=32*25, SGBM_3WAY,
    uniquenessRatio=10, speckle filter 100/2) on full-size synthetic pairs; the share of its
    valid, non-occluded pixels within 1 px of the true disparity. Occluded: the left pixel's
    surface point, projected into the right image with its true disparity, is hidden there
    by a nearer surface (from a right-camera depth render).
(b) Shares of sky / road / vertical-structure pixels and SGBM disparity histograms of the
    synthetic frames next to the real KITTI frames (no ground truth there). One heuristic for
    both: sky = no valid SGBM disparity, above the principal point, low local texture
    (7x7 std < 4 grey levels); road = SGBM 3-D point 1.65 m +- 0.3 m below the camera;
    vertical = every other pixel with a valid disparity (pixels that are neither remain
    "unknown"). For synthetic frames the same classes from the ground-truth depth are shown too.
(c) Example figures: synthetic left/right/true disparity/SGBM, and a real KITTI frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.synth import (
    SynthConfig,
    World,
    generate,
    non_occluded,
    render_view,
    right_pose,
)

F32 = npt.NDArray[np.float32]
CAMERA_HEIGHT = 1.65
NUM_DISPARITIES = 128


def sgbm(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]) -> F32:
    """Return SGBM disparity (px, float32), NaN where invalid."""
    block = 5
    matcher = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=0,
        numDisparities=NUM_DISPARITIES,
        blockSize=block,
        P1=8 * block**2,
        P2=32 * block**2,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    disparity = matcher.compute(left, right).astype(np.float32) / 16.0
    disparity[disparity <= 0] = np.nan
    result: F32 = disparity
    return result


def classify(
    image: npt.NDArray[np.uint8], disparity: F32, fx: float, cy: float, baseline: float
) -> npt.NDArray[np.int8]:
    """Heuristic classes (0 unknown, 1 sky, 2 road, 3 vertical) from a disparity map."""
    height = image.shape[0]
    grey = image.astype(np.float32)
    mean = cv2.blur(grey, (7, 7))
    std = np.sqrt(np.maximum(cv2.blur(grey * grey, (7, 7)) - mean * mean, 0.0))
    rows = np.arange(height, dtype=np.float32)[:, None]
    valid = np.isfinite(disparity)
    with np.errstate(invalid="ignore", divide="ignore"):
        below = baseline * (rows - cy) / disparity  # metres below the camera
    classes = np.zeros(image.shape, dtype=np.int8)
    classes[~valid & (rows < cy) & (std < 4.0)] = 1
    road = valid & (np.abs(below - CAMERA_HEIGHT) < 0.3)
    classes[road] = 2
    classes[valid & ~road] = 3
    return classes


def _shares(classes: npt.NDArray[np.int8]) -> list[float]:
    return [float((classes == k).mean()) for k in (1, 2, 3, 0)]


def _kitti_pairs(realdata: Path) -> dict[str, tuple[list[Path], float, float, float]]:
    """Real KITTI pair lists with (fx, cy, baseline) from their calibrations."""
    found: dict[str, tuple[list[Path], float, float, float]] = {}
    raw = realdata / harness.KITTI_RAW_0001
    if raw.is_dir():
        found["KITTI raw 0001"] = (
            sorted((raw / "image_00" / "data").glob("*.png")),
            721.5377,
            172.854,
            0.5372,
        )
    odo = realdata / harness.KITTI_ODOMETRY_CLIP
    if odo.is_dir():
        found["KITTI odometry clip"] = (
            sorted((odo / "image_0").glob("*.png")),
            707.0912,
            183.1104,
            379.8145 / 707.0912,
        )
    return found


def _right_of(path: Path) -> Path:
    parts = list(path.parts)
    for index, part in enumerate(parts):
        if part in ("image_00", "image_0"):
            parts[index] = {"image_00": "image_01", "image_0": "image_1"}[part]
    return Path(*parts)


def _colour(disparity: F32, maximum: float) -> npt.NDArray[np.uint8]:
    scaled = np.clip(np.nan_to_num(disparity, nan=0.0) / maximum * 255, 0, 255).astype(np.uint8)
    coloured = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[:, :, ::-1]
    coloured[~np.isfinite(disparity)] = 0
    return np.asarray(coloured, dtype=np.uint8)


def main() -> None:  # noqa: D103 - documented by the module docstring
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--stride", type=int, default=10)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--out", type=Path, default=Path("docs/img"))
    harness.add_realdata(parser)
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = np.arange(0, NUM_DISPARITIES + 1, 2)
    histograms: dict[str, npt.NDArray[np.float64]] = {}
    shares: dict[str, list[list[float]]] = {}
    within_all: list[float] = []
    example: dict[str, Any] = {}
    for seed in args.seeds:
        config = SynthConfig(seed=seed, frames=args.frames)
        world = World(seed)
        for frame in generate(config):
            if frame.index % args.stride:
                continue
            camera = frame.camera
            right_depth = render_view(
                world, camera, right_pose(frame.camera_to_world, camera.baseline)
            ).depth
            visible, truth = non_occluded(frame.depth, right_depth, camera.focal_baseline)
            estimate = sgbm(frame.left, frame.right)
            valid = visible & np.isfinite(estimate)
            share = float((np.abs(estimate[valid] - truth[valid]) <= 1.0).mean())
            within_all.append(share)
            print(
                f"seed {seed} frame {frame.index}: SGBM within 1 px on {share:.1%} of "
                f"{valid.sum()} valid non-occluded px ({valid.sum() / visible.sum():.1%} of "
                f"non-occluded have an SGBM value)"
            )
            key = "synthetic (SGBM heuristic)"
            classes = classify(frame.left, estimate, camera.fx, camera.cy, camera.baseline)
            shares.setdefault(key, []).append(_shares(classes))
            true_classes = classify(frame.left, truth, camera.fx, camera.cy, camera.baseline)
            true_classes[np.isnan(frame.depth)] = 1
            shares.setdefault("synthetic (ground truth)", []).append(_shares(true_classes))
            hist, _ = np.histogram(estimate[np.isfinite(estimate)], bins=bins)
            histograms[key] = histograms.get(key, 0) + hist
            if not example:
                example = {"frame": frame, "truth": truth, "estimate": estimate}
    print(f"\nmean share within 1 px: {np.mean(within_all):.1%} over {len(within_all)} frames")
    real_example: dict[str, tuple[npt.NDArray[np.uint8], F32]] = {}
    for name, (paths, fx, cy, baseline) in _kitti_pairs(args.realdata).items():
        for path in paths[:: max(1, len(paths) // 10)]:
            left = np.asarray(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), dtype=np.uint8)
            right = np.asarray(
                cv2.imread(str(_right_of(path)), cv2.IMREAD_GRAYSCALE), dtype=np.uint8
            )
            estimate = sgbm(left, right)
            shares.setdefault(name, []).append(_shares(classify(left, estimate, fx, cy, baseline)))
            hist, _ = np.histogram(estimate[np.isfinite(estimate)], bins=bins)
            histograms[name] = histograms.get(name, 0) + hist
            if name not in real_example:
                real_example[name] = (left, estimate)
    print("\n" + harness.table_header(["frames", "sky", "road", "vertical", "unknown"]))
    for name, rows in shares.items():
        mean = np.mean(rows, axis=0)
        print(harness.table_row([f"{name} ({len(rows)})", *(f"{v:.1%}" for v in mean)]))

    harness.work_dir(args.out)
    figure, axis = plt.subplots(figsize=(7, 3.2), dpi=90)
    for name, hist in histograms.items():
        axis.plot(bins[:-1] + 1, hist / hist.sum(), label=name)
    axis.set_yscale("log")
    axis.set_xlabel("SGBM disparity (px)")
    axis.set_ylabel("share of valid pixels")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(args.out / "synth_disparity_hist.png")
    plt.close(figure)

    frame = example["frame"]
    panels: list[tuple[str, npt.NDArray[np.uint8], str | None]] = [
        ("synthetic left", frame.left, "gray"),
        ("synthetic right", frame.right, "gray"),
        ("true disparity", _colour(example["truth"], 64.0), None),
        ("SGBM disparity", _colour(example["estimate"], 64.0), None),
    ]
    for name, (left, estimate) in real_example.items():
        panels.append((f"{name} left", left, "gray"))
        panels.append((f"{name} SGBM", _colour(estimate, 64.0), None))
    figure, axes = plt.subplots(len(panels) // 2, 2, figsize=(11, 1.75 * len(panels) // 2), dpi=60)
    for axis, (title, image, cmap) in zip(axes.ravel(), panels, strict=True):
        half = cv2.resize(np.asarray(image), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        axis.imshow(half, cmap=cmap, vmin=0, vmax=255)
        axis.set_title(title, fontsize=8)
        axis.axis("off")
    figure.tight_layout()
    figure.savefig(args.out / "synth_examples.png")
    plt.close(figure)
    for name in ("synth_disparity_hist.png", "synth_examples.png"):
        print(f"{args.out / name}: {(args.out / name).stat().st_size / 1000:.0f} kB")


if __name__ == "__main__":
    main()
