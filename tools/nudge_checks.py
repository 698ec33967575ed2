"""Checks behind docs/sharper_sparse_2.md that ``sparse_sharpness.py`` does not print.

Nine reports on the sources of ``tools/sparse_sharpness.py`` (the same frames, cached in
the same work folder; run that tool once first, or let this one build them):

* ``counts`` -- per frame, the lattice's points, how many fail their lookup or contrast,
  and how many the default nudged lattice moves to where a lookup passes;
* ``moves`` -- the mean |disparity error| of the default with other move sets for a
  failed point (the axes alone; eighth-side moves before the quarter-side ones);
* ``near-std`` -- the +-2 sigma coverage and the mean Gaussian negative log-likelihood of
  the posterior std (the widening near the matcher's range turned off) and of that std
  widened as std'^2 = std^2 + (k max(0, d - (range - w)))^2 for several (w, k), the
  default's (``variance.widen_near_range``: w = range / 4, k = 1) among them, per
  source, over all pixels and over those whose truth lies beyond the range;
* ``std-scale`` -- the same for the calibrated std times a common factor (< 1: narrower),
  the near-range widening as shipped;
* ``where-error`` -- the default's mean error by the distance of a truth pixel to the
  nearest measurement and by how far SGBM's map (as the front end matched it) is from the
  truth there;
* ``near-points`` -- the points the near reach adds (``frontend/near.py``) under several
  settings (none; without the right view's check; that with only the added points within
  3 px of the truth kept, an oracle; the default; a 1 quarter px check; no drops; 3 px
  noise; margin 0; a 14 px grid): how many, how many more than 3 and 10 px from the truth,
  the mean |disparity error| by the truth's depth, +-2 sigma, the Gaussian NLL (all and
  by depth), and how often and at what thread CPU the right view is matched
  (``--sources demo``: the demo's held-out drive, seed 9001, 40 frames);
* ``robust-from`` -- the default with the IRLS reweighting run only on frames where some
  point's leave-one-out standardised residual reaches T (``prior.Model.robust_from``;
  T = 0: always, inf: never), per T: the error, +-2 sigma, depth RMSE and the frames that
  reweighted; ``robust-from-timing``: the estimate's CPU per frame alone for each T (one
  thread, the settings in turns, best of 3; as ``sparse_sharpness.py --timing``);
* ``extra-points`` -- the default with m more lookups (30, 60) placed greedily among a
  10 px lattice's passing lookups, weighted by how far each one's value is from the linear
  interpolant of the frame's points (where those points say least of SGBM's map), or by
  1 (the gap to the nearest point alone): whether it matters where the extra points go.

Examples::

    python tools/nudge_checks.py counts
    python tools/nudge_checks.py moves --sources lidar synth
    python tools/nudge_checks.py near-std
    python tools/nudge_checks.py std-scale
    python tools/nudge_checks.py where-error --sources lidar
    python tools/nudge_checks.py near-points --sources demo synth
    python tools/nudge_checks.py robust-from
    python tools/nudge_checks.py robust-from-timing --sources odometry raw
    python tools/nudge_checks.py extra-points --sources lidar synth
"""

from __future__ import annotations

import dataclasses
import itertools
import threading
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any
from unittest import mock

import harness
import numpy as np
import numpy.typing as npt
import sparse_sharpness as sharpness
import sparse_timing
from scipy.spatial import cKDTree

import pcainterp_stream.estimate.solve as solve
import pcainterp_stream.estimate.variance as variance
import pcainterp_stream.frontend.fill as fill
import pcainterp_stream.frontend.near as near_module
import pcainterp_stream.frontend.stereo as stereo_module
import pcainterp_stream.pipeline.adaptation as adaptation
import pcainterp_stream.pipeline.processor as processor
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.frontend.corners import lattice_points, patch_contrast
from pcainterp_stream.frontend.near import NearConfig, extend_near
from pcainterp_stream.frontend.stereo import (
    LookupConfig,
    StereoFrontEnd,
    compute_disparity,
    detect_corners,
    lookup_disparities,
    to_grey8,
)
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig, resolve_settings

Items = list[tuple[Any, Any]]

AXES = [(1, 0), (-1, 0), (0, 1), (0, -1)]
DIAGONALS = [(1, 1), (-1, 1), (1, -1), (-1, -1)]
MOVE_SETS = {
    "default": AXES + DIAGONALS,
    "axes_only": AXES,
    "eighth_then_quarter": [(a / 2, b / 2) for a, b in AXES + DIAGONALS] + AXES + DIAGONALS,
}
"""Move sets for a failed lattice point, in units of a quarter side, tried in order."""

NEAR_STD = [(16, 1.0), (32, 1.0), (48, 0.5), (48, 1.0), (64, 0.5), (64, 1.0), (80, 0.5), (96, 0.5)]
"""(w px, k) of the near-range std term; (32, 1) is the default's at SGBM's 128 px."""

STD_SCALES = [1.0, 0.97, 0.95, 0.92, 0.9]
"""Common factors on the built-in basis's calibrated std (the near-range term as shipped)."""

Array = npt.NDArray[np.float64]
Widen = Callable[[Array, Array], Array]
"""The std a check reports, from the estimate and the posterior std (px, valid pixels)."""


def counts(items: Items) -> str:
    """Lattice points, failed and moved ones per frame, with the default settings."""
    config = ProcessorConfig()
    gftt, checks = config.gftt, LookupConfig()
    nodes = failed = moved = 0
    for frame, _ in items:
        grey = to_grey8(frame.left)
        disparity = compute_disparity(frame.left, frame.right, config.sgbm)
        min_x = config.sgbm.valid_min_x
        corners = lookup_disparities(disparity, detect_corners(grey, gftt, min_x=min_x))
        height, width = grey.shape
        area = (max(gftt.border, min_x), gftt.border, width - gftt.border, height - gftt.border)
        lattice = lattice_points(corners.pixels, gftt.fill_spacing, area)
        look_up = partial(
            lookup_disparities,
            disparity,
            max_gradient=checks.max_gradient,
            discontinuity_radius=checks.discontinuity_radius,
        )
        textured = patch_contrast(grey, lattice) >= gftt.fill_min_contrast
        passed = look_up(lattice[textured]).counts.kept
        placed = fill.nudged_lattice(grey, disparity, gftt, area, lattice, look_up)
        nodes += len(lattice)
        failed += len(lattice) - passed
        moved += len(placed) - passed
    frames = len(items)
    return (
        f"lattice points {nodes / frames:.1f}, failed {failed / frames:.1f}, "
        f"moved {moved / frames:.1f} per frame"
    )


def moves(items: Items) -> str:
    """Mean |disparity error| (px) of the default with each move set."""
    saved = fill.NUDGES
    parts = []
    try:
        for name, steps in MOVE_SETS.items():
            fill.NUDGES = np.array(steps, np.float32)
            figures = sharpness.score(items, ProcessorConfig(), None)
            parts.append(f"{name} {figures['error_px']:.3f}")
    finally:
        fill.NUDGES = saved
    return "mean |disparity error| px: " + ", ".join(parts)


def near_std(items: Items) -> str:
    """+-2 sigma coverage and NLL, all pixels and beyond the range, with the near-range term."""
    reach = ProcessorConfig().sgbm.band

    def widen(width: int, k: float) -> Widen:
        return lambda estimate, std: np.sqrt(
            std**2 + (k * np.maximum(estimate - (reach - width), 0.0)) ** 2
        )

    settings = {"posterior std": widen(0, 0.0)}
    settings.update({f"w {width} k {k:g}": widen(width, k) for width, k in NEAR_STD})
    return _std_table(items, settings, reach)


def std_scale(items: Items) -> str:
    """+-2 sigma coverage and NLL with the built-in basis's std scaled by a common factor."""
    config = ProcessorConfig()
    start = variance.NEAR_RANGE_START * config.sgbm.band

    def scaled(factor: float) -> Widen:
        def widen(estimate: Array, std: Array) -> Array:
            near = np.maximum(estimate - start, 0.0) * variance.NEAR_RANGE_SLOPE
            return np.sqrt((factor * std) ** 2 + near**2)

        return widen

    return _std_table(items, {f"std x {f:g}": scaled(f) for f in STD_SCALES}, config.sgbm.band)


def _std_table(items: Items, settings: dict[str, Widen], reach: float) -> str:
    """Coverage and NLL of each way of widening the posterior std (the default's widening off)."""
    saved = variance.NEAR_RANGE_SLOPE
    variance.NEAR_RANGE_SLOPE = 0.0  # the posterior std as the model gives it
    try:
        with FrameProcessor(None, ProcessorConfig()) as processor:
            results = list(processor.process([frame for frame, _ in items]))
    finally:
        variance.NEAR_RANGE_SLOPE = saved
    sums = {label: np.zeros(6) for label in settings}
    for (_, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        estimate = result.disparity[valid].astype(np.float64)
        std = result.disparity_std[valid].astype(np.float64)
        error = np.abs(estimate - truth[valid])
        beyond = truth[valid] >= reach
        for label, widen in settings.items():
            widened = widen(estimate, std)
            inside = error <= 2.0 * widened
            nll = np.log(widened) + 0.5 * np.log(2 * np.pi) + 0.5 * (error / widened) ** 2
            sums[label] += (
                valid.sum(),
                inside.sum(),
                beyond.sum(),
                inside[beyond].sum(),
                (widened > std).sum(),
                nll.sum(),
            )
    lines = []
    for label, (px, inside, beyond, inside_beyond, touched, nll) in sums.items():
        near = f"{100 * inside_beyond / beyond:.1f} %" if beyond else "none"
        lines.append(
            f"  {label}: {100 * inside / px:.2f} %, NLL {nll / px:.4f} (beyond the range: "
            f"{near} of {int(beyond)} px; std raised at {100 * touched / px:.2f} % of the pixels)"
        )
    return "+-2 sigma coverage\n" + "\n".join(lines)


def where_error(items: Items) -> str:
    """The default's error by distance to the nearest point and by SGBM's own error there."""
    config = ProcessorConfig()
    with FrameProcessor(None, config) as processor:
        results = list(processor.process([frame for frame, _ in items]))
    groups: dict[str, list[float]] = {}
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        rows, cols = np.nonzero(valid)
        error = np.abs(result.disparity[valid] - truth[valid])
        gap, _ = cKDTree(result.pixels).query(np.stack([cols, rows], axis=1))
        sgbm = compute_disparity(frame.left, frame.right, config.sgbm)[valid]
        matched = np.isfinite(sgbm) & (sgbm > 0)
        sgbm_error = np.abs(sgbm - truth[valid])
        masks = {
            "all": np.ones(error.shape, bool),
            "< 10 px from a point": gap < 10,
            "10-20 px": (gap >= 10) & (gap < 20),
            "20-40 px": (gap >= 20) & (gap < 40),
            ">= 40 px": gap >= 40,
            "SGBM (as matched) within 1 px of the truth": matched & (sgbm_error < 1),
            "SGBM 1-3 px off": matched & (sgbm_error >= 1) & (sgbm_error < 3),
            "SGBM >= 3 px off": matched & (sgbm_error >= 3),
            "SGBM has no value": ~matched,
        }
        for name, mask in masks.items():
            counts = groups.setdefault(name, [0.0, 0.0, 0.0, 0.0])
            counts[0] += mask.sum()
            counts[1] += error[mask].sum()
            counts[2] += (mask & matched).sum()
            counts[3] += sgbm_error[mask & matched].sum()
    pixels, total = groups["all"][0], groups["all"][1]
    lines = [
        f"  {name}: {100 * n / pixels:.1f} % of the truth px, mean error {err / max(n, 1):.2f} px "
        f"({100 * err / total:.1f} % of the error); SGBM's own "
        + (f"{sgbm / on:.2f} px at its {100 * on / max(n, 1):.0f} %" if on else "none")
        for name, (n, err, on, sgbm) in groups.items()
    ]
    return "where the default errs\n" + "\n".join(lines)


DEPTH_BINS = (0.0, 5.0, 10.0, 20.0, 40.0, np.inf)
"""Truth depth bins (m) of ``near-points``."""


def near_points(items: Items) -> str:
    """The near reach's added points against the truth, per setting, and the maps' errors."""
    truths = {id(frame.left): truth for frame, truth in items}
    added: list[tuple[Any, Any]] = []  # (values, truth there) per frame with points added
    oracle = [False]  # keep only the added points within 3 px of the truth
    right_views: list[float] = []  # thread CPU seconds of each right-view quarter match
    quarter = near_module.quarter_disparity

    def recording(left: Any, *args: Any) -> Any:
        pixels, values, noise, found = extend_near(left, *args)
        if noise is None:
            return pixels, values, noise, found
        rows, cols = np.rint(pixels[:, 1]).astype(int), np.rint(pixels[:, 0]).astype(int)
        there = truths[id(left)][rows, cols]
        if oracle[0]:
            with np.errstate(invalid="ignore"):
                keep = (noise == 0) | (np.abs(values - there) <= 3.0)
            pixels, values, noise, there = pixels[keep], values[keep], noise[keep], there[keep]
        added.append((values[noise > 0], there[noise > 0]))
        return pixels, values, noise, found

    def timed(*args: Any, right_view: bool = False) -> Any:
        start = time.thread_time()
        disparity = quarter(*args, right_view=right_view)
        if right_view:
            right_views.append(time.thread_time() - start)
        return disparity

    base = ProcessorConfig()
    settings: dict[str, tuple[NearConfig | None, bool]] = {
        "none": (None, False),
        "unchecked": (NearConfig(lr_max_diff=0.0), False),
        "oracle": (NearConfig(lr_max_diff=0.0), True),
        "checked": (NearConfig(), False),
        "lr1": (NearConfig(lr_max_diff=1.0), False),
        "no_drops": (NearConfig(drop_below=0.0), False),
        "noise3": (NearConfig(noise=3.0), False),
        "margin0": (NearConfig(margin=0.0), False),
        "grid14": (NearConfig(spacing=14.0), False),
    }
    focal_baseline = items[0][0].camera.focal_baseline
    lines = []
    with (
        mock.patch.object(processor, "extend_near", recording),
        mock.patch.object(near_module, "quarter_disparity", timed),
    ):
        for name, (near, oracle[0]) in settings.items():
            added.clear()
            right_views.clear()
            with FrameProcessor(None, dataclasses.replace(base, near=near)) as densifier:
                results = list(densifier.process([frame for frame, _ in items]))
            sums = np.zeros((4, len(DEPTH_BINS) - 1))  # pixels, |error|, inside +-2 std, NLL
            for (_, truth), result in zip(items, results, strict=True):
                valid = np.isfinite(truth) & (truth > 0)
                where = np.digitize(focal_baseline / truth[valid], DEPTH_BINS) - 1
                error = np.abs(result.disparity[valid] - truth[valid]).astype(np.float64)
                std = result.disparity_std[valid].astype(np.float64)
                nll = np.log(std) + 0.5 * np.log(2 * np.pi) + 0.5 * (error / std) ** 2
                for row, weights in enumerate((None, error, error <= 2 * std, nll)):
                    sums[row] += np.bincount(where, weights, sums.shape[1])
            values = np.concatenate([v for v, _ in added]) if added else np.zeros(0)
            there = np.concatenate([t for _, t in added]) if added else np.zeros(0)
            with np.errstate(invalid="ignore"):
                off = np.abs(values - there)
                known = max(int(np.isfinite(off).sum()), 1)
                wrong = np.sum(off > 3) / known, np.sum(off > 10) / known
            pixels = sums[0].sum()
            bins = " ".join(f"{e:.3f}" for e in sums[1] / np.maximum(sums[0], 1))
            nll_bins = " ".join(f"{e:.2f}" for e in sums[3] / np.maximum(sums[0], 1))
            matched = sum(result.counts.get("near_matched", 0) for result in results)
            cost = f"{1e3 * np.mean(right_views):.1f} ms" if right_views else "-"
            lines.append(
                f"  {name:9s} added {values.size:4d}, > 3 px off {wrong[0]:6.1%}, > 10 px "
                f"{wrong[1]:6.1%}; |error| {sums[1].sum() / pixels:.3f} px, by depth {bins}; "
                f"+-2 sigma {sums[2].sum() / pixels:.2%}, NLL {sums[3].sum() / pixels:.3f} "
                f"(by depth {nll_bins}); quarter match on {matched} frames, the right view's "
                f"on {len(right_views)} ({cost} each)"
            )
    edges = ", ".join(f"{a:g}-{b:g}" for a, b in itertools.pairwise(DEPTH_BINS))
    return f"depth bins (m) {edges}\n" + "\n".join(lines)


ROBUST_FROM = [0.0, 3.0, 4.0, 5.0, np.inf]
"""Thresholds T of ``robust-from``: reweight a frame only when some |t_j| >= T."""


def robust_from(items: Items) -> str:
    """Error, coverage and estimate CPU with the reweighting only on frames with an outlier.

    The threshold applies to the job's estimates and to its fit check's solves alike; the
    count is of the job's own frames (one solve each), and of those that reweighted.
    """
    counts = [0, 0]  # frames reweighted, frames solved
    job = threading.local()  # set while the job's own estimate runs in this thread
    weights: Callable[[Array, Any], Array] = getattr(solve, "robust_weights")  # noqa: B009
    estimate = getattr(processor, "densify_batch")  # noqa: B009 (not exported)
    check = getattr(adaptation, "densify_batch")  # noqa: B009

    def counted(standardised: Array, robust: Any) -> Array:
        counts[0] += int(getattr(job, "on", False))
        return weights(standardised, robust)

    def solved(*args: Any, **kwargs: Any) -> Any:
        job.on = True
        try:
            results = estimate(*args, **kwargs)
        finally:
            job.on = False
        counts[1] += len(results)
        return results

    lines = []
    for threshold in ROBUST_FROM:
        counts[:] = [0, 0]
        with (
            mock.patch.object(solve, "robust_weights", counted),
            mock.patch.object(processor, "densify_batch", partial(solved, robust_from=threshold)),
            mock.patch.object(adaptation, "densify_batch", partial(check, robust_from=threshold)),
        ):
            figures = sharpness.score(items, ProcessorConfig())
        lines.append(
            f"  T {threshold:g}: {figures['error_px']:.4f} px, +-2 sigma "
            f"{figures['coverage_2sigma']:.2f} %, depth RMSE {figures['depth_rmse_m']:.3f} m, "
            f"reweighted {counts[0]} of {counts[1]} frames"
        )
    return "\n".join(lines)


def robust_from_timing(items: Items) -> str:
    """The estimate's CPU per frame alone for each threshold of ``robust-from``."""
    seconds = _estimate_cpu(items, ROBUST_FROM)
    return "estimate alone, CPU ms per frame: " + ", ".join(
        f"T {t:g} {1000 * s:.1f} ({s / seconds[0]:.2f}x)"
        for t, s in zip(ROBUST_FROM, seconds, strict=True)
    )


def _estimate_cpu(items: Items, thresholds: list[float], repeats: int = 3) -> list[float]:
    """CPU seconds per frame of ``densify_batch`` (4 frames a call) for each threshold."""
    from threadpoolctl import threadpool_limits

    config = ProcessorConfig()
    basis = Basis.default()
    front_end = StereoFrontEnd(config.gftt, config.sgbm)
    measured = [front_end.measure(frame.left, frame.right) for frame, _ in items]
    camera = items[0][0].camera
    parts = [sparse_timing._partition(m, camera.image_size, basis.grid_size) for m in measured]
    options = resolve_settings(basis, config).densify_options()
    best = [np.inf] * len(thresholds)
    with threadpool_limits(1):
        for _ in range(repeats):
            for index, threshold in enumerate(thresholds):
                started = time.process_time()
                for start in range(0, len(items), 4):
                    batch = measured[start : start + 4]
                    densify_batch(
                        basis,
                        [m.pixels for m in batch],
                        [m.disparities for m in batch],
                        partitions=parts[start : start + 4],
                        image_size=camera.image_size,
                        focal_baseline=camera.focal_baseline,
                        robust=config.robust,
                        robust_from=threshold,
                        **options,
                    )
                spent = (time.process_time() - started) / len(items)
                best[index] = min(best[index], spent)
    return best


EXTRA_POINTS = [(0, "residual"), (30, "residual"), (30, "gap"), (60, "residual"), (60, "gap")]
"""(m, weight) of ``extra-points``: m extra lookups, weighted by the residual or by 1."""


def extra_points(items: Items) -> str:
    """The default with m extra lookups where the points' linear interpolant misses most."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    fill_points = getattr(stereo_module, "fill_points")  # noqa: B009 (not exported)
    setting: list[Any] = [0, "residual"]

    def with_extra(
        grey: Any, disparity: Any, gftt: Any, area: Any, kept: Any, look_up: Any, *rest: Any
    ) -> Any:
        nodes = fill_points(grey, disparity, gftt, area, kept, look_up, *rest)
        count, weight = setting
        if not count:
            return nodes
        have = look_up(np.concatenate([kept, nodes]).astype(np.float32))
        side = gftt.fill_spacing / 4.0
        candidates = lattice_points(np.zeros((0, 2), np.float32), side, area)
        candidates = candidates[fill.valid_share(disparity, candidates) >= 0.9]
        found = look_up(candidates)
        textured = patch_contrast(grey, found.pixels) >= gftt.fill_min_contrast
        pixels, values = found.pixels[textured], found.disparities[textured]
        weights = np.ones(values.size)
        if weight == "residual":
            guess = LinearNDInterpolator(have.pixels, have.disparities)(pixels)
            outside = ~np.isfinite(guess)
            guess[outside] = NearestNDInterpolator(have.pixels, have.disparities)(pixels[outside])
            residual = np.abs(values - guess)
            weights = np.where(residual >= 1.0, residual, 0.0)
        chosen = fill.weighted_fill(
            have.pixels, pixels, weights.astype(np.float32), count, area, min_gap=side
        )
        return np.ascontiguousarray(np.concatenate([nodes, pixels[chosen]]), np.float32)

    lines = []
    with mock.patch.object(stereo_module, "fill_points", with_extra):
        for count, weight in EXTRA_POINTS:
            setting[:] = [count, weight]
            figures = sharpness.score(items, ProcessorConfig())
            lines.append(
                f"  {count} by {weight}: {figures['error_px']:.3f} px (nearest "
                f"neighbour {figures['nearest_px']:.3f}, {figures['ratio_nn']:.3f}x), +-2 sigma "
                f"{figures['coverage_2sigma']:.2f} %, depth RMSE {figures['depth_rmse_m']:.2f} m, "
                f"{figures['points']:.1f} points"
            )
    return "\n".join(lines)


REPORTS: dict[str, Callable[[Items], str]] = {
    "counts": counts,
    "moves": moves,
    "near-std": near_std,
    "std-scale": std_scale,
    "where-error": where_error,
    "near-points": near_points,
    "robust-from": robust_from,
    "robust-from-timing": robust_from_timing,
    "extra-points": extra_points,
}


def main(argv: list[str] | None = None) -> int:
    """Print the chosen report for each source."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("report", choices=sorted(REPORTS))
    harness.add_work_dir(parser, Path("/tmp/sparse_sharpness"))
    harness.add_realdata(parser)
    parser.add_argument(
        "--sources",
        nargs="+",
        default=["lidar", "synth", "odometry", "raw"],
        choices=["lidar", "synth", "odometry", "raw", "demo"],
    )
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    realdata: Path = args.realdata
    makers: dict[str, tuple[str, Callable[[], Iterator[tuple[Any, Any]]]]] = {
        "lidar": ("lidar", lambda: sharpness._lidar_frames(realdata)),
        "synth": ("synth_9001_9002_20", lambda: sharpness._synth_frames([9001, 9002], 20)),
        "demo": ("synth_9001_40", lambda: sharpness._synth_frames([9001], 40)),
        "odometry": (
            "odometry_40",
            lambda: sharpness._kitti_frames(realdata / harness.KITTI_ODOMETRY_CLIP, 40),
        ),
        "raw": (
            "raw_40",
            lambda: sharpness._kitti_frames(realdata / harness.KITTI_RAW_0001, 40),
        ),
    }
    for source in args.sources:
        tag, make = makers[source]
        items = sharpness._cached(work, tag, make)
        print(f"{source} ({len(items)} frames): {REPORTS[args.report](items)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
