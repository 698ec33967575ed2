"""The estimate configurations of ``run_beyond.py`` and their metrics on cached logs.

:data:`METHODS` lists the configurations compared (the paper's PCA-MAP, each addition alone
and together, and the baselines); :func:`evaluate_split` runs them over a test log
(Delta_2D, depth RMSE, +-sigma coverage, time per frame) and :func:`sweep_split` against the
number of points; :func:`depth_bins`, :func:`irls_iterations` and :func:`carry_sweep` are
the analyses of the ``depth-bins``, ``irls`` and ``carry`` stages.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import harness
import numpy as np
import numpy.typing as npt
from beyond_data import CARRY, SWEEP_POINTS, FloatArray, LogData

from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.estimate.prior import LocalPrior, TemporalPrior
from pcainterp_stream.evaluate.metrics import (
    ReferenceView,
    calibration_sums,
    depth_errors,
    oracle_disparity,
    projection_errors,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.frontend.motion import CarriedPoints, CarryConfig, Motion
from pcainterp_stream.pipeline.processor import EstimateSettings, ProcessorConfig, resolve_settings

# ----------------------------------------------------------------------------- methods


@dataclass(frozen=True)
class Method:
    """One configuration of the estimate (or a baseline)."""

    name: str
    local: bool = False
    robust: str = "none"
    temporal: bool = False
    evidence_sigma: bool = False
    fitted_sigma: bool = False
    baseline: str | None = None
    carry: bool = False


METHODS = (
    Method("plain PCA-MAP (paper, sigma 2 px)"),
    Method("+ hybrid local prior", local=True, fitted_sigma=True),
    Method("+ robust (Cauchy)", robust="cauchy"),
    Method("+ robust (Huber)", robust="huber"),
    Method("+ temporal prior", temporal=True),
    Method("+ sigma by evidence (per frame)", evidence_sigma=True),
    Method("+ sigma by evidence (fitted on training)", fitted_sigma=True),
    Method(
        "all: hybrid + Cauchy + temporal + fitted sigma",
        local=True,
        robust="cauchy",
        temporal=True,
        fitted_sigma=True,
    ),
    Method("hybrid + Cauchy + fitted sigma", local=True, robust="cauchy", fitted_sigma=True),
    Method("hybrid + temporal + fitted sigma", local=True, temporal=True, fitted_sigma=True),
    Method(f"+ carried points ({CARRY.frames} frames)", carry=True),
    Method(
        f"hybrid + Cauchy + carried ({CARRY.frames} frames) + fitted sigma",
        local=True,
        robust="cauchy",
        fitted_sigma=True,
        carry=True,
    ),
    Method("nearest neighbour", baseline="nearest"),
    Method("linear", baseline="linear"),
    # the baseline given the same carried points as the default estimate
    Method(f"nearest neighbour + carried ({CARRY.frames} frames)", baseline="nearest", carry=True),
)


@dataclass
class Sums:
    """Accumulated metrics of one method on one split."""

    delta_2d: float = 0.0
    delta_2d_n: float = 0.0
    depth_sq: float = 0.0
    depth_n: float = 0.0
    inside_2: float = 0.0
    inside_1: float = 0.0
    calibration_n: float = 0.0
    seconds: float = 0.0
    frames: int = 0
    downweighted: int = 0
    resets: int = 0
    sigma_sum: float = 0.0

    def summary(self) -> dict[str, float]:
        """Return the means."""
        n = self.calibration_n
        return {
            "delta_2d_mean": self.delta_2d / max(self.delta_2d_n, 1.0),
            "depth_rmse": float(np.sqrt(self.depth_sq / max(self.depth_n, 1.0))),
            "coverage_1": self.inside_1 / n if n else float("nan"),
            "coverage_2": self.inside_2 / n if n else float("nan"),
            "ms_per_frame": 1000.0 * self.seconds / max(self.frames, 1),
            "downweighted_per_frame": self.downweighted / max(self.frames, 1),
            "temporal_resets": float(self.resets),
            "mean_sigma": self.sigma_sum / max(self.frames, 1),
        }


def add_frame(
    sums: Sums,
    data: LogData,
    index: int,
    mode: str,
    reference: npt.NDArray[Any],
    estimate: npt.NDArray[Any],
    std: npt.NDArray[Any] | None,
    view: ReferenceView | None = None,
) -> None:
    """Add one frame's mean Delta_2D and (with a std) +-sigma coverage terms to ``sums``."""
    transform = reference_transform(data, index, mode)
    if view is None:
        view = reference_view(reference, data.camera, transform)
    delta_2d, _ = projection_errors(estimate, view, data.camera, transform)
    sums.delta_2d += float(np.nansum(delta_2d))
    sums.delta_2d_n += float(np.isfinite(delta_2d).sum())
    if std is not None:
        calibration = calibration_sums(estimate, std, view.disparity, view.counted)
        sums.inside_1 += calibration["inside_1"]
        sums.inside_2 += calibration["inside_2"]
        sums.calibration_n += calibration["n"]


def reference_transform(data: LogData, index: int, mode: str) -> FloatArray:
    """The motion from a frame's left camera to its reference view (the pair, or frame + 1)."""
    if mode == "stereo":
        return stereo_transform(data.camera)
    assert data.poses is not None
    return relative_transform(data.poses[index], data.poses[index + 1])


def std_calibration(basis: Basis, hybrid: bool) -> EstimateSettings:
    """The std calibration ``densify`` applies by default with this basis."""
    return resolve_settings(basis, ProcessorConfig(prior="hybrid" if hybrid else "paper"))


def estimates(
    method: Method,
    basis: Basis,
    hyper: dict[str, Any],
    data: LogData,
    points: Callable[[int], tuple[FloatArray, FloatArray]],
    frames: Sequence[int],
    carry: CarryConfig = CARRY,
) -> Iterator[tuple[int, FloatArray, FloatArray | None, float, dict[str, int | float]]]:
    """Yield (frame, disparity, std, seconds, extras) of a method over frames in order."""
    camera = data.camera
    local = None
    if method.local and hyper.get("local"):
        local = LocalPrior.from_meta(hyper["local"])
    sigma: float | str = 2.0
    if method.evidence_sigma:
        sigma = "evidence"
    elif method.fitted_sigma:
        sigma = float(hyper["sigma"] if method.local else hyper["plain_sigma"])
    state = TemporalPrior(process_noise=float(hyper["process_noise"])) if method.temporal else None
    calibration = std_calibration(basis, local is not None)
    carrier = CarriedPoints(carry) if method.carry else None
    for index in frames:
        pixels, disparities = points(index)
        started = time.perf_counter()
        noise = None
        n_carried = 0
        if carrier is not None:
            assert data.motions is not None
            assert data.motion_seconds is not None
            known = index > 0 and bool(np.all(np.isfinite(data.motions[index])))
            motion = Motion(data.motions[index], 0, 0) if known else None
            pixels, disparities, noise, n_carried = carrier.carry(
                None, pixels, disparities, camera, motion=motion
            )
            started -= float(data.motion_seconds[index])  # the odometry is part of the cost
        if method.baseline is not None:
            interpolate = nearest if method.baseline == "nearest" else linear
            result = interpolate(
                pixels, disparities, image_size=camera.image_size, zero_is_match=True
            )
            seconds = time.perf_counter() - started
            yield index, result.disparity.astype(np.float64), None, seconds, {}
            continue
        estimate = densify_batch(
            basis,
            [pixels],
            [disparities],
            sigma=sigma,
            local_prior=local,
            robust=method.robust,
            temporal=state,
            image_size=camera.image_size,
            focal_baseline=camera.focal_baseline,
            std_scale=calibration.std_scale,
            scale_by_innovation=calibration.scale_by_innovation,
            noise_stds=[noise],
            zero_is_match=True,
        )[0]
        seconds = time.perf_counter() - started
        extras: dict[str, int | float] = {
            "downweighted": estimate.n_downweighted,
            "reset": int(estimate.temporal == "reset"),
            "sigma": estimate.sigma,
            "carried": n_carried,
        }
        assert estimate.disparity_std is not None
        yield (
            index,
            estimate.disparity.astype(np.float64),
            estimate.disparity_std.astype(np.float64),
            seconds,
            extras,
        )


def evaluated_frames(data: LogData, mode: str, max_frames: int | None) -> list[int]:
    """Frames evaluated: temporal mode needs the next frame's pose."""
    count = data.frames - (1 if mode == "temporal" else 0)
    return list(range(count if max_frames is None else min(count, max_frames)))


@dataclass(frozen=True)
class Trial:
    """A basis with its fitted hyperparameters, tested on a log.

    Attributes:
        basis: the basis.
        hyper: its fitted hyperparameters (``meta["prior"]``).
        data: the test log's cached data.
        mode: the reference view: ``temporal`` (the next frame, with ground-truth poses) or
            ``stereo`` (the right camera).
    """

    basis: Basis
    hyper: dict[str, Any]
    data: LogData
    mode: str


def evaluate_split(
    trial: Trial, methods: Sequence[Method], max_frames: int | None
) -> dict[str, dict[str, float]]:
    """Run every method over a test log; return its metrics."""
    basis, hyper, data, mode = trial.basis, trial.hyper, trial.data, trial.mode
    frames = evaluated_frames(data, mode, max_frames)
    references = data.reference()
    views = {}
    for index in frames:
        transform = reference_transform(data, index, mode)
        views[index] = reference_view(references[index], data.camera, transform)
    results: dict[str, dict[str, float]] = {}
    for method in methods:
        sums = Sums()
        for index, estimate, std, seconds, extras in estimates(
            method, basis, hyper, data, data.measured, frames
        ):
            view = views[index]
            add_frame(sums, data, index, mode, references[index], estimate, std, view)
            depth = depth_errors(
                estimate,
                view.disparity,
                view.counted,
                focal_baseline=data.camera.focal_baseline,
            )
            sums.depth_sq += depth["sq"]
            sums.depth_n += depth["n"]
            sums.seconds += seconds
            sums.frames += 1
            sums.downweighted += int(extras.get("downweighted", 0))
            sums.resets += int(extras.get("reset", 0))
            sums.sigma_sum += float(extras.get("sigma", 0.0))
        results[method.name] = sums.summary()
        harness.log(f"  {method.name}: {results[method.name]}")
    return results


def sweep_split(
    trial: Trial, methods: Sequence[Method], max_frames: int | None
) -> dict[str, dict[str, float]]:
    """Mean Delta_2D against the number of points (strongest-first lookups)."""
    data = trial.data
    frames = evaluated_frames(data, trial.mode, max_frames)
    references = data.reference()
    out: dict[str, dict[str, float]] = {}
    for n_points in SWEEP_POINTS:
        points = partial(data.strongest, n=n_points)
        row: dict[str, float] = {}
        for method in methods:
            sums = Sums()
            for index, estimate, *_ in estimates(
                method, trial.basis, trial.hyper, data, points, frames
            ):
                add_frame(sums, data, index, trial.mode, references[index], estimate, None)
            row[method.name] = sums.summary()["delta_2d_mean"]
        out[str(n_points)] = row
        harness.log(f"  sweep {n_points}: {row}")
    return out


# ----------------------------------------------------------------------------- analyses

DEPTH_EDGES = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0, float("inf"))


def depth_bins(basis: Basis, data: LogData, every: int = 5) -> dict[str, list[float]]:
    """Mean Delta_2D by reference depth: plain, hybrid, nearest and the oracle (synthetic).

    Returns per method the overall mean, then the mean and the share of the summed error in
    each bin of :data:`DEPTH_EDGES` (every ``every``-th frame, temporal mode).
    """
    hyper = basis.meta["prior"]
    local = LocalPrior.from_meta(hyper["local"]) if hyper.get("local") else None
    references = data.reference()
    fb = data.camera.focal_baseline
    sums: dict[str, npt.NDArray[np.float64]] = {}
    for index in evaluated_frames(data, "temporal", None)[::every]:
        transform = reference_transform(data, index, "temporal")
        view = reference_view(references[index], data.camera, transform)
        depth = fb / np.maximum(np.nan_to_num(view.disparity), 1e-6)
        size = data.camera.image_size
        pixels, disparities = data.pixels[index], data.disparities[index]
        estimates = {
            "plain": densify_batch(
                basis, [pixels], [disparities], uncertainty="none", zero_is_match=True
            )[0],
            "hybrid": densify_batch(
                basis,
                [pixels],
                [disparities],
                uncertainty="none",
                local_prior=local,
                sigma=float(hyper["sigma"]),
                zero_is_match=True,
            )[0],
        }
        maps = {name: e.disparity for name, e in estimates.items()}
        maps["nearest"] = nearest(
            pixels, disparities, image_size=size, zero_is_match=True
        ).disparity
        maps["oracle"] = oracle_disparity(basis, np.nan_to_num(references[index]))
        for name, estimate in maps.items():
            delta_2d, _ = projection_errors(estimate, view, data.camera, transform)
            row = sums.setdefault(name, np.zeros((len(DEPTH_EDGES) - 1, 2)))
            for b, (low, high) in enumerate(itertools.pairwise(DEPTH_EDGES)):
                counted = np.isfinite(delta_2d) & (depth >= low) & (depth < high)
                row[b] += [delta_2d[counted].sum(), counted.sum()]
    out = {}
    for name, row in sums.items():
        total = row[:, 0].sum()
        out[name] = [
            total / row[:, 1].sum(),
            *(row[:, 0] / np.maximum(row[:, 1], 1)),
            *(row[:, 0] / total),
        ]
        harness.log(f"  {name}: {[round(v, 2) for v in out[name]]}")
    return out


def irls_iterations(
    splits: Sequence[tuple[str, str, str, Basis, dict[str, Any]]],
    data: dict[str, LogData],
    frames: int = 40,
) -> dict[str, dict[str, list[float]]]:
    """Hybrid + Cauchy with 1, 2 and 4 reweightings: mean Delta_2D and +-2 sigma coverage."""
    out: dict[str, dict[str, list[float]]] = {}
    for split, test, mode, basis, hyper in splits:
        local = LocalPrior.from_meta(hyper["local"]) if hyper.get("local") else None
        settings = std_calibration(basis, local is not None)
        for iterations in (1, 2, 4):
            sums = Sums()
            references = data[test].reference()
            for index in evaluated_frames(data[test], mode, frames):
                item = data[test]
                result = densify_batch(
                    basis,
                    [item.pixels[index]],
                    [item.disparities[index]],
                    sigma=float(hyper["sigma"]),
                    local_prior=local,
                    robust="cauchy",
                    robust_iterations=iterations,
                    image_size=item.camera.image_size,
                    focal_baseline=item.camera.focal_baseline,
                    std_scale=settings.std_scale,
                    scale_by_innovation=settings.scale_by_innovation,
                    zero_is_match=True,
                )[0]
                add_frame(
                    sums,
                    item,
                    index,
                    mode,
                    references[index],
                    result.disparity,
                    result.disparity_std,
                )
            summary = sums.summary()
            out.setdefault(split, {})[str(iterations)] = [
                summary["delta_2d_mean"],
                summary["coverage_2"],
            ]
            harness.log(f"  {split} {iterations} reweightings: {out[split][str(iterations)]}")
    return out


CARRY_SWEEP = (
    (0, 30.0, 1.0),
    (2, 30.0, 1.0),
    (4, 30.0, 1.0),
    (8, 30.0, 1.0),
    (4, 20.0, 1.0),
    (4, 40.0, 1.0),
    (4, 30.0, 0.5),
    (4, 30.0, 2.0),
)
"""(frames, gap px, age_std px) of the carried points tried on the fitting frames."""


def carry_sweep(
    fits: Sequence[tuple[str, Basis, dict[str, Any], LogData, str, list[int]]],
) -> dict[str, dict[str, list[float]]]:
    """Hybrid + Cauchy + carried points on each split's fitting frames (not the test log).

    Returns per split and "frames/gap/age_std" the mean Delta_2D, +-2 sigma coverage and
    carried points per frame.
    """
    method = Method("carried", local=True, robust="cauchy", fitted_sigma=True, carry=True)
    out: dict[str, dict[str, list[float]]] = {}
    for split, basis, hyper, data, mode, frames in fits:
        references = data.reference()
        for n_frames, gap, age_std in CARRY_SWEEP:
            options = CarryConfig(frames=n_frames, gap=gap, age_std=age_std)
            sums = Sums()
            carried = 0

            for index, estimate, std, _, extras in estimates(
                method, basis, hyper, data, data.measured, frames, carry=options
            ):
                carried += int(extras["carried"])
                add_frame(sums, data, index, mode, references[index], estimate, std)
            summary = sums.summary()
            key = f"{n_frames}/{gap:g}/{age_std:g}"
            out.setdefault(split, {})[key] = [
                summary["delta_2d_mean"],
                summary["coverage_2"],
                carried / max(len(frames), 1),
            ]
            harness.log(f"  {split} carry {key}: {out[split][key]}")
    return out


if __name__ == "__main__":
    harness.module_main(__doc__, "run_beyond.py")
