"""Dense mode's measurements in docs/results.md, "Dense mode", and docs/dense.md.

Two sections:

- ``calibration``: the frames ``DenseModel``'s constants were chosen on (seeds 9001-9003,
  every 10th of 31 full-size frames), SGBM at full and at half resolution, scored against
  the ground truth: dense mode against SGBM with nearest-filled holes, on SGBM's pixels,
  the +-2 sigma coverage in and out of the holes, and where the holes are (left band, sky,
  close objects, the rest) with each filler's error there.
- ``cli``: the real command line on a held-out synthetic drive (seed 9100, with the LiDAR
  topic) and on both KITTI clips: ``densify`` sparse and dense, then ``evaluate`` (its
  printed tables are the results).

    python tools/dense_results.py --work-dir /tmp/dense_results
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import harness
import numpy as np

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.dense import field_options, find_holes, fuse_dense
from pcainterp_stream.estimate.estimator import densify
from pcainterp_stream.evaluate.metrics import disparity_from_depth, fill_nearest
from pcainterp_stream.frontend.matchers import (
    DEFAULT_DENSE_MATCHER,
    DENSE_MATCHERS,
    dense_matcher,
    dense_points,
)
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    SgbmConfig,
    compute_disparity,
    compute_weak_disparity,
    sparse_lookups,
    to_grey8,
)
from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings
from pcainterp_stream.synth import SynthConfig, generate

CALIBRATION_SEEDS = (9001, 9002, 9003)
HELD_OUT_SEED = 9100
REGIONS = ("left band", "sky", "close (> 90 px)", "other")


def calibration(
    downscale: int, matcher: str = DEFAULT_DENSE_MATCHER, gftt: GfttConfig | None = None
) -> tuple[dict[str, float], dict[str, list[float]]]:
    """Score dense mode on the calibration frames with SGBM at 1/``downscale`` resolution.

    ``matcher``: dense mode's matcher by ``--dense-matcher`` name (``DENSE_MATCHERS``);
    ``gftt``: the sparse estimate's points (None: densify's own, ``dense_points``), looked
    up as densify does.
    """
    gftt = gftt or dense_points(downscale)
    basis = Basis.default()
    options = resolve_settings(basis, ProcessorConfig(measurements="dense")).densify_options()
    sgbm = SgbmConfig(downscale=downscale)
    # as densify: at half resolution there is nothing to refine (the whole range, halved)
    name = dense_matcher(matcher, downscale)
    dense_sgbm = dataclasses.replace(DENSE_MATCHERS[name], downscale=downscale)
    sums = dict.fromkeys(
        ("pixels", "valid", "holes", "dense", "nearest", "dense valid", "sgbm valid"), 0.0
    )
    sums.update({"inside valid": 0.0, "inside holes": 0.0})
    regions = {name: [0.0, 0.0, 0.0, 0.0] for name in REGIONS}  # pixels, nearest, sparse, dense
    for seed in CALIBRATION_SEEDS:
        for frame in generate(SynthConfig(seed=seed, frames=31)):
            if frame.index % 10:
                continue
            truth = disparity_from_depth(frame.depth, frame.camera.focal_baseline)
            # dense mode matches the left band too; SGBM's holes are the plain matcher's
            matched, weak = compute_weak_disparity(frame.left, frame.right, dense_sgbm)
            plain = compute_disparity(frame.left, frame.right, sgbm)
            found = sparse_lookups(
                to_grey8(frame.left), matched, gftt, min_x=dense_sgbm.valid_min_x
            )
            estimate = densify(
                basis,
                found.pixels,
                found.disparities,
                robust=ProcessorConfig().robust,
                image_size=matched.shape,
                focal_baseline=frame.camera.focal_baseline,
                **options,
                **field_options(basis),
            )
            fused = fuse_dense(
                estimate, matched, holes=find_holes(matched, weak, zero_is_match=True)
            )
            filled = fill_nearest(plain)
            assert fused.disparity_std is not None
            assert filled is not None
            valid = np.isfinite(plain)
            error = np.abs(fused.disparity - truth)
            nearest = np.abs(filled - truth)
            inside = error <= 2 * fused.disparity_std
            sums["pixels"] += truth.size
            sums["valid"] += valid.sum()
            sums["holes"] += (~valid).sum()
            sums["dense"] += error.sum()
            sums["nearest"] += nearest.sum()
            sums["dense valid"] += error[valid].sum()
            sums["sgbm valid"] += np.abs(plain - truth)[valid].sum()
            sums["inside valid"] += inside[valid].sum()
            sums["inside holes"] += inside[~valid].sum()
            columns = np.arange(truth.shape[1])[None, :]
            band = ~valid & (columns < SgbmConfig().band)
            rest = ~valid & ~band
            masks = {
                "left band": band,
                "sky": rest & (truth == 0),
                "close (> 90 px)": rest & (truth > 90),
                "other": rest & (truth > 0) & (truth <= 90),
            }
            sparse = np.abs(estimate.disparity - truth)
            for name, mask in masks.items():
                row = regions[name]
                row[0] += mask.sum()
                row[1] += nearest[mask].sum()
                row[2] += sparse[mask].sum()
                row[3] += error[mask].sum()
            harness.log(f"downscale {downscale}: seed {seed} frame {frame.index}")
    scores = {
        "dense all": sums["dense"] / sums["pixels"],
        "nearest all": sums["nearest"] / sums["pixels"],
        "dense valid": sums["dense valid"] / sums["valid"],
        "sgbm valid": sums["sgbm valid"] / sums["valid"],
        "coverage valid": sums["inside valid"] / sums["valid"],
        "coverage holes": sums["inside holes"] / max(sums["holes"], 1.0),
        "fill": sums["valid"] / sums["pixels"],
    }
    return scores, {
        name: [row[0] / sums["pixels"], *(value / max(row[0], 1.0) for value in row[1:])]
        for name, row in regions.items()
    }


def print_calibration(matcher: str = DEFAULT_DENSE_MATCHER, gftt: GfttConfig | None = None) -> None:
    """Print the calibration-frame tables (dense mode with the ``matcher`` named)."""
    print("\n## Calibration frames (seeds 9001-9003, frames 0, 10, 20, 30; ground truth)\n")
    headers = [
        "SGBM",
        "dense all px",
        "SGBM nearest-filled px",
        "ratio",
        "dense on SGBM px",
        "SGBM on its px",
        "+-2 sigma holes",
        "+-2 sigma valid",
    ]
    print(harness.table_header(headers))
    breakdowns = {}
    for downscale in (1, 2):
        scores, breakdowns[downscale] = calibration(downscale, matcher, gftt)
        print(
            harness.table_row(
                [
                    "full" if downscale == 1 else "half",
                    f"{scores['dense all']:.3f}",
                    f"{scores['nearest all']:.3f}",
                    f"{scores['dense all'] / scores['nearest all']:.3f}",
                    f"{scores['dense valid']:.3f}",
                    f"{scores['sgbm valid']:.3f}",
                    f"{100 * scores['coverage holes']:.1f} %",
                    f"{100 * scores['coverage valid']:.1f} %",
                ]
            )
        )
    print("\nWhere the holes of full-resolution SGBM are (mean abs. error px there):\n")
    print(harness.table_header(["region", "share of pixels", "nearest fill", "sparse", "dense"]))
    for name, (share, nearest, sparse, dense) in breakdowns[1].items():
        print(
            harness.table_row(
                [name, f"{100 * share:.1f} %", f"{nearest:.2f}", f"{sparse:.2f}", f"{dense:.2f}"]
            )
        )


def run_commands(
    work: Path,
    realdata: Path,
    matcher: str = DEFAULT_DENSE_MATCHER,
    gftt: GfttConfig | None = None,
) -> None:
    """Run the real command line of the held-out table (evaluate prints the results).

    ``matcher``: ``--dense-matcher`` of the dense runs; ``gftt``: their points (None:
    densify's own, so no option is passed).
    """
    points: tuple[str | int | float, ...] = ()
    if gftt is not None:
        points = ("--corners", gftt.max_corners, "--fill-spacing", gftt.fill_spacing)
    syn = work / "syn.mcap"
    if not syn.exists():
        harness.run_cli(
            "synth", syn, "--seed", HELD_OUT_SEED, "--frames", 40, "--lidar", quiet=True
        )
    logs = {"syn": syn}
    for name, folder in (
        ("raw", realdata / harness.KITTI_RAW_0001),
        ("odo", realdata / harness.KITTI_ODOMETRY_CLIP),
    ):
        logs[name] = work / f"{name}.mcap"
        if not logs[name].exists():
            harness.run_cli("import-kitti", folder, logs[name], quiet=True)
    evaluate = ("--mode", "stereo", "--no-basis", "--no-linear")
    for name, log in logs.items():
        runs: dict[str, tuple[str | int | float, ...]] = {
            "sparse": (),
            "dense": ("--measurements", "dense"),
        }
        if name != "syn":  # against full-resolution SGBM: dense matches at half resolution
            runs = {"sparse": (), "dense2": ("--measurements", "dense", "--stereo-downscale", 2)}
        for label, extra in runs.items():
            if label != "sparse" and matcher != DEFAULT_DENSE_MATCHER:
                extra = (*extra, "--dense-matcher", matcher)
            if label != "sparse":
                extra = (*extra, *points)
            out = work / f"{name}_{label}.mcap"
            out.unlink(missing_ok=True)
            print(f"\n## {name}, {label}\n")
            harness.run_cli("densify", log, "-o", out, *extra)
            harness.run_cli("evaluate", out, "-o", work / f"report_{name}_{label}", *evaluate)
            if name == "syn":
                harness.run_cli(
                    "evaluate",
                    out,
                    "-o",
                    work / f"report_{name}_{label}_lidar",
                    *evaluate,
                    "--reference-topic",
                    "/ground_truth/lidar_depth",
                )


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables of docs/results.md, "Dense mode", and docs/dense.md."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser)
    harness.add_realdata(parser)
    parser.add_argument(
        "--sections", nargs="+", choices=["calibration", "cli"], default=["calibration", "cli"]
    )
    parser.add_argument(
        "--matcher",
        choices=sorted(DENSE_MATCHERS),
        default=DEFAULT_DENSE_MATCHER,
        help="dense mode's matcher (densify --dense-matcher; default refined)",
    )
    harness.add_dense_points(parser)
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    gftt = harness.dense_points(args)
    if "calibration" in args.sections:
        print_calibration(args.matcher, gftt)
    if "cli" in args.sections:
        if not (args.realdata / harness.KITTI_RAW_0001).is_dir():
            parser.error(f"{args.realdata / harness.KITTI_RAW_0001} not found; pass --realdata")
        run_commands(work, args.realdata, args.matcher, gftt)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
