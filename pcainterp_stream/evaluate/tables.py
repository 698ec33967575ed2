"""The text of an evaluation: the summary table ``evaluate`` prints and ``results.md``."""

from __future__ import annotations

import math
from pathlib import Path

from pcainterp_stream.evaluate.metrics import SWEEP_POINTS, CalibrationStats, MethodStats
from pcainterp_stream.evaluate.per_frame import standout_lines
from pcainterp_stream.evaluate.results import (
    PCA_ON_SGBM,
    SGBM,
    SGBM_NN,
    TARGET_COVERAGE,
    TARGET_RATIO,
    TARGET_SGBM_NN_RATIO,
    Evaluation,
    RangeStats,
    mean_ratio,
)

UNDEFINED = "-"
"""What a table prints for a figure that is undefined (a ratio to 0, a mean of no pixel)."""


def _percent(value: float) -> str:
    return f"{100 * value:.1f} %"


def _number(value: float | None, decimals: int, defined: bool = True) -> str:
    return f"{value:.{decimals}f}" if value is not None and defined else UNDEFINED


def _method_row(name: str, stats: MethodStats, nearest: MethodStats) -> str:
    s = stats.summary()
    timing = f"{s['ms_per_frame']:.0f}" if stats.seconds > 0 else UNDEFINED
    scored, scored_3d = stats.pixels > 0, sum(stats.by_depth_3d_count) > 0
    scored_depth = stats.depth["n"] > 0  # no reference depth up to 80 m: no depth metric
    return (
        f"{name:<12} {_number(s['delta_2d_mean'], 3, scored):>8} "
        f"{_number(mean_ratio(stats, nearest), 2):>6} "
        f"{_number(s['delta_3d_mean'], 2, scored_3d):>8} "
        f"{_number(s['rmse_m'], 2, scored_depth):>8} {_number(s['mae_m'], 2, scored_depth):>7} "
        f"{_number(s['irmse_per_km'], 1, scored_depth):>7} "
        f"{_number(s['imae_per_km'], 1, scored_depth):>7} {timing:>9}"
    )


def _calibration_row(name: str, calibration: CalibrationStats) -> str:
    c = calibration.summary()
    timing = f", {c['ms_per_frame']:.0f} ms/frame" if calibration.seconds > 0 else ""
    certain = ""
    if c["certain"] > 0:  # a basis that never varies at some pixels claims std 0 there
        certain = f" (std 0 at {100 * c['certain']:.3g} % of pixels, left out of the NLL)"
    if c["no_std"] > 0:  # NaN: a compact log's std of 0, or no estimate there
        certain += f" (no std at {100 * c['no_std']:.3g} % of pixels, left out)"
    nll = f"{c['nll']:.2f}" if math.isfinite(c["nll"]) else "- (no pixel has a std)"
    split = ""
    if calibration.has_sgbm_split:
        split = (
            f"; +-2 sigma in SGBM holes {_percent(c['coverage_2sigma_sgbm_holes'])}, "
            f"where SGBM is valid {_percent(c['coverage_2sigma_sgbm_valid'])}"
        )
    return (
        f"uncertainty {name:<7} inside +-1 sigma {_percent(c['coverage_1sigma'])}, "
        f"+-2 sigma {_percent(c['coverage_2sigma'])}, NLL {nll}{certain}{split}{timing}"
    )


def _stereo_lines(result: Evaluation, nearest: MethodStats) -> list[str]:
    if not result.stereo:
        return [f"stereo baselines: {result.stereo_note}"] if result.stereo_note else []
    lines = [_method_row(name, stats, nearest) for name, stats in result.stereo.items()]
    lines.append(
        f"SGBM has a value at {_percent(result.sgbm_fill)} of the counted pixels: {SGBM} and "
        f"{PCA_ON_SGBM} are scored there, {SGBM_NN} (holes filled by the nearest value) on all"
    )
    if result.stereo_note:
        lines.append(f"stereo baselines: {result.stereo_note}")
    return lines


def summary_table(result: Evaluation) -> str:
    """Return the plain-text summary table ``evaluate`` prints."""
    lines = [
        f"{result.frames} frame{'' if result.frames == 1 else 's'} of {result.log}, "
        f"{result.mode} mode, reference: "
        f"{result.reference_label}, {result.points_per_frame:.0f} points per frame",
    ]
    if result.input_pair:
        lines.append(f"input pair: {result.input_pair}")
    if result.skipped:
        lines.append(
            f"{result.skipped} frames skipped: no {result.reference} message within the stamp "
            "tolerance of theirs"
        )
    if result.no_measurement:
        lines.append(result.no_measurement_note)
    if result.no_truth:
        lines.append(result.no_truth_note)
    if result.no_estimate_note:
        lines.append(result.no_estimate_note)
    lines += [f"damage: {line}; only the frames read before it count" for line in result.damage]
    lines += [f"note: {line}" for line in result.notes]
    if result.measurements:
        lines.append(f"measurements of the densified log: {result.measurements}")
    if result.basis_note:
        at = f", at {result.sigma_label}" if result.sigma_log_px is not None else ""
        lines.append(f"basis of the re-densified rows: {result.basis_note}{at}")
    lines.append(
        f"{'method':<12} {'D2D px':>8} {'/NN':>6} {'D3D m':>8} {'RMSE m':>8} {'MAE m':>7} "
        f"{'iRMSE':>7} {'iMAE':>7} {'ms/frame':>9}"
    )
    nearest = result.methods["nearest"]
    lines += [_method_row(name, stats, nearest) for name, stats in result.methods.items()]
    lines += _stereo_lines(result, nearest)
    lines += [_calibration_row(name, stats) for name, stats in result.calibration.items()]
    if result.ranges.counted:
        lines.append(_far_line(result.ranges))
    lines += [f"stands out: {line}" for line in standout_lines(result.per_frame)]
    return "\n".join(lines)


def _far_line(ranges: RangeStats) -> str:
    """Return the summary's "too far" line (a reference that cannot say it is said so)."""
    r = ranges.summary()
    estimate = f"too far (depth +inf): estimate {_percent(r['estimate_far'])} of pixels"
    if ranges.blind:  # review 15d R3: not "0.0 % (0.0 % found)", 0 of 0
        return (
            f'{estimate}; the reference cannot say "too far" (a DisparityImage holds no '
            "truth below its min_disparity, here at or above the estimate's)"
        )
    # a share of none is undefined ("-"), not 0.0 %
    agrees = _percent(r["estimate_far_reference_agrees"]) if ranges.estimate_far else UNDEFINED
    found = _percent(r["reference_far_estimate_agrees"]) if ranges.reference_far else UNDEFINED
    return (
        f"{estimate} ({agrees} far in the reference too), reference "
        f"{_percent(r['reference_far'])} ({found} found)"
    )


def _verdict(value: float, low: float, high: float) -> str:
    if low <= value <= high:
        return "met"
    return f"missed by {100 * (low - value if value < low else value - high):.1f} points"


def _met(ratio: float | None, target: float) -> str:
    if ratio is None:
        return "undefined"
    return "met" if ratio <= target else "missed"


def _targets(result: Evaluation) -> list[str]:
    lines = []
    ratio = result.ratio()
    if result.measurements == "dense":  # the features are the prior's points, not the map's
        verdict = (
            "not graded: in a dense log nearest neighbour interpolates the points that shaped "
            "the prior (/pcainterp/features), not the SGBM pixels the map fused; the dense "
            "targets below are the ones for it"
        )
    elif ratio is None:
        verdict = "undefined, nearest neighbour's mean Delta_2D is 0"
    else:
        verdict = "met" if ratio <= TARGET_RATIO else f"missed by {ratio - TARGET_RATIO:.2f}"
    lines.append(
        f"- PCA-MAP / nearest neighbour mean Delta_2D = {_number(ratio, 2)} (target <= "
        f"{TARGET_RATIO}; paper 0.63 KITTI, 0.61 Virtual KITTI): {verdict}."
    )
    low, high = TARGET_COVERAGE
    if "stored" in result.calibration:  # the std the log carries: what a user gets
        coverage = result.calibration["stored"].summary()["coverage_2sigma"]
        lines.append(
            f"- the log's stored uncertainty: +-2 sigma coverage = {_percent(coverage)} (target "
            f"{100 * low:.0f}-{100 * high:.0f} %): {_verdict(coverage, low, high)}."
        )
    if "exact" in result.calibration:
        coverage = result.calibration["exact"].summary()["coverage_2sigma"]
        graded = "stored" not in result.calibration
        lines.append(
            f"- exact uncertainty of evaluate's re-densification ({result.sigma_label}, no "
            "calibration) "
            f"+-2 sigma coverage = {_percent(coverage)}"
            + (
                f" (target {100 * low:.0f}-{100 * high:.0f} %): {_verdict(coverage, low, high)}."
                if graded
                else "; for the paper's model, not graded."
            )
        )
    if SGBM_NN in result.stereo and result.measurements == "dense":
        filled = mean_ratio(result.methods["pca_map"], result.stereo[SGBM_NN])
        on_sgbm = mean_ratio(result.stereo[PCA_ON_SGBM], result.stereo[SGBM])
        lines += [
            f"- dense mode: PCA-MAP / {SGBM_NN} mean Delta_2D = {_number(filled, 2)} "
            f"(target <= {TARGET_SGBM_NN_RATIO}): "
            + _met(filled, TARGET_SGBM_NN_RATIO)
            + f"; on SGBM's pixels PCA-MAP / {SGBM} = {_number(on_sgbm, 2)} (target <= 1): "
            + _met(on_sgbm, 1.0)
            + ".",
        ]
        stored = result.calibration.get("stored")
        if stored is not None and stored.has_sgbm_split:
            c = stored.summary()
            holes, valid = c["coverage_2sigma_sgbm_holes"], c["coverage_2sigma_sgbm_valid"]
            lines.append(
                f"- dense mode: stored +-2 sigma coverage in SGBM holes "
                f"{_percent(holes)} ({_verdict(holes, low, high)}), where SGBM is valid "
                f"{_percent(valid)} ({_verdict(valid, low, high)}); target "
                f"{100 * low:.0f}-{100 * high:.0f} % each."
            )
    return lines


def _sweep_lines(result: Evaluation) -> list[str]:
    """The points sweep's section: what it measures, and a row per count some frame reached."""
    frames = result.sweep_frames
    corners = result.sweep_corners or [0]
    found = f"{min(corners)}" if min(corners) == max(corners) else f"{min(corners)}-{max(corners)}"
    lines = [
        f"## Error against the number of points ({frames} {'frame' if frames == 1 else 'frames'})",
        "",
        "On the frames --sweep-every picks, the sweep re-densifies from the N strongest "
        "Shi-Tomasi corners with SGBM's disparity (corners only, none of densify's lattice "
        "points) with the paper's estimator (the basis's prior, measurement noise "
        f"{result.sigma_label}) and interpolates the same points with nearest and linear: it "
        "measures the methods against the number of points, not the log's stored estimate, "
        "so its errors are not the table's above. "
        + (
            f"The frame had {found} corners with a disparity; larger counts have no row."
            if frames == 1
            else f"The frames had {found} corners with a disparity; a count is scored on the "
            "frames that had as many (frames column)."
        ),
        "",
        "| points | frames | PCA-MAP D2D px | nearest D2D px | linear D2D px | PCA/NN |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    if not result.sweep:
        return [*lines[:-2], f"No frame had {SWEEP_POINTS[0]} corners: no row.", ""]
    for points, methods in sorted(result.sweep.items()):
        means = {name: stats.summary()["delta_2d_mean"] for name, stats in methods.items()}
        ratio = _number(mean_ratio(methods["pca_map"], methods["nearest"]), 2)
        lines.append(
            f"| {points} | {result.sweep_reached.get(points, 0)} | {means['pca_map']:.3f} | "
            f"{means['nearest']:.3f} | {means['linear']:.3f} | {ratio} |"
        )
    return [*lines, ""]


def results_markdown(result: Evaluation, figures: list[str]) -> str:
    """Return ``results.md`` of a report folder."""
    skipped = (
        f" {result.skipped} frames were skipped: no {result.reference} message within the "
        "stamp tolerance of theirs."
        if result.skipped
        else ""
    )
    for note in (result.no_measurement_note, result.no_truth_note):
        skipped += f" {note[0].upper()}{note[1:]}." if note else ""
    if result.no_estimate_note:
        skipped += f" {result.no_estimate_note[0].upper()}{result.no_estimate_note[1:]}."
    lines = [
        f"# Evaluation of `{Path(result.log).name}`",
        "",
        f"{result.frames} frames, {result.image_size[1]}x{result.image_size[0]} px, "
        f"{result.mode} mode (Delta_2D/Delta_3D of paper section IV-B), reference: "
        f"{result.reference_label}; {result.points_per_frame:.0f} sparse points per frame; "
        f"evaluation took {result.seconds:.0f} s.{skipped}",
        "",
        "```",
        summary_table(result),
        "```",
        "",
        "D2D: mean Delta_2D (px), /NN: ratio to nearest neighbour; D3D: mean Delta_3D (m, "
        "reference depths up to 80 m, estimated depth capped there); RMSE/MAE (m) and "
        "iRMSE/iMAE (1/km) likewise; ms/frame: time of the method during evaluation "
        "(PCA-MAP: see the uncertainty rows, a re-densification with the basis). Every metric "
        "counts only the pixels where the reference holds truth. Coverage: share of "
        "reference disparities within +-1/+-2 posterior std (Gaussian: 68.3 / 95.4 %). "
        f"Stereo baselines: `{SGBM}` is SGBM's full-resolution map of the pair, scored where "
        f"it has a value (`{PCA_ON_SGBM}`: PCA-MAP on those same pixels); `{SGBM_NN}` is that "
        "map with its holes filled by the nearest valid value, scored everywhere.",
        "",
        "## Targets",
        "",
        *_targets(result),
        "",
    ]
    if result.sweep or result.sweep_frames:
        lines += _sweep_lines(result)
    if result.basis is not None:
        b = result.basis
        lines += [
            f"Basis: `{b['path']}`, {b['components']} components on a {b['grid'][1]}x"
            f"{b['grid'][0]} grid from {b['n_train']} maps "
            f"({_percent(b['explained_variance'])} of the training variance).",
            "",
        ]
    lines += ["## Figures", ""] + [f"![{name}]({name})" for name in figures]
    if "uncertainty.png" in figures and set(result.calibration) - {"stored"}:
        lines += [
            "",
            "In `uncertainty.png`, `stored` is the log's own estimate and std; "
            f"{', '.join(f'`{n}`' for n in result.calibration if n != 'stored')} are evaluate's "
            f"re-densifications of the same points with the basis at {result.sigma_label}.",
        ]
    lines += [
        "",
        "All numbers, with the accumulated histograms and each frame's figures (`per_frame`): "
        "`results.json`.",
        "",
    ]
    return "\n".join(lines)
