"""Experiments of issue 7 (beyond the paper): every addition on held-out synthetic and KITTI.

Stages, each cached in ``--work`` (an interrupted run resumes):

1. ``prepare``: synthetic logs (basis training seeds 101-104, a fitting log of seed 150, a
   test log of seed 201) and the two real KITTI clips of ``../shared/realdata`` as MCAP;
   per frame the measurements of the densify front end (GFTT + SGBM lookups, default
   settings), a dense set of strongest-first lookups for the points sweep, the reference
   (ground truth for synthetic, SGBM for KITTI), poses, and every map preprocessed onto the
   basis grid (SGBM and, for synthetic, ground truth).
2. ``bases``: bases on the synthetic camera's grid (310x94): synthetic ground truth,
   real-only, and synthetic+real mixes; their hyperparameters (local kernel, sigma,
   process noise) fitted by the evidence on frames outside each basis.
3. ``evaluate``: plain PCA-MAP, each addition alone, all together, nearest neighbour and
   linear on the held-out splits; mean Delta_2D (the paper's, via
   ``pcainterp_stream.evaluate.metrics``), depth RMSE, +-2 sigma coverage, time per frame; the
   points sweep (50-800); the training-mix table. Writes ``results.json`` and
   ``results.md``.

    python tools/run_beyond.py --work /tmp/beyond            # all stages
    python tools/run_beyond.py --work /tmp/beyond --stages depth-bins irls   # analyses

Splits: synthetic: basis from seeds 101-104 (ground truth), hyperparameters fitted on
seed 150, tested on seed 201 (temporal mode, ground truth). KITTI A: basis from the raw
drive (first 80 % of its frames; the last 20 % fit the hyperparameters), tested on the
odometry clip (stereo mode, SGBM reference); KITTI B the reverse.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.estimate.fitting import CalibrationFrame, fit_frame, fit_prior
from pcainterp_stream.estimate.learning import learn_basis, preprocess_disparity
from pcainterp_stream.estimate.prior import LocalPrior, TemporalPrior
from pcainterp_stream.evaluate.metrics import (
    ReferenceView,
    calibration_sums,
    depth_errors,
    disparity_from_depth,
    oracle_disparity,
    projection_errors,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.frontend.motion import CarriedPoints, CarryConfig, Motion, estimate_motion
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    StereoFrontEnd,
    detect_corners,
    lookup_disparities,
    to_grey8,
)
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.pipeline.processor import EstimateSettings, ProcessorConfig, resolve_settings
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth import SynthConfig, camera_pose
from pcainterp_stream.synth.render import render_view
from pcainterp_stream.synth.world import World

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
KITTI = {
    "raw": REALDATA / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync",
    "odometry": REALDATA / "kitti_odometry_clip" / "sequences" / "a",
}
TRAIN_SEEDS = (101, 102, 103, 104)
FIT_SEED = 150
TEST_SEED = 201
GRID_SCALE = 0.25
SWEEP_POINTS = (50, 100, 200, 400, 800)
IRLS_SPLITS = ("synthetic", "kitti_a", "kitti_b_mix")
"""Splits of the reweighting-count check (``--stages irls``)."""
DRIVE_SEED = 1000
"""First seed of the synthetic drives rendered for the synthetic basis (``--drives``)."""
MAIN_MIX = 1000
"""Synthetic SGBM maps added to the real training frames of the ``*_mix`` splits."""
FloatArray = npt.NDArray[np.float64]
CARRY = ProcessorConfig().carry
"""Carried points as ``densify`` carries them by default."""


def _log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


# ----------------------------------------------------------------------------- prepare


@dataclass
class LogData:
    """Cached per-frame data of one log."""

    camera: StereoCamera
    pixels: list[FloatArray]
    disparities: list[FloatArray]
    many_pixels: list[FloatArray]
    many_disparities: list[FloatArray]
    poses: FloatArray | None  # (F, 4, 4) camera to world
    reference_path: Path  # (F, H, W) float32 .npy, NaN where invalid
    grid_sgbm: npt.NDArray[np.float32]  # (F, gh, gw), basis units
    grid_truth: npt.NDArray[np.float32] | None
    # (F, 4, 4) visual odometry from frame i-1 to i (NaN: none), and its seconds per frame
    motions: FloatArray | None = None
    motion_seconds: FloatArray | None = None

    @property
    def frames(self) -> int:
        """Return the number of stereo pairs."""
        return len(self.pixels)

    def reference(self) -> npt.NDArray[np.float32]:
        """Return the (F, H, W) reference disparities, memory-mapped."""
        return np.load(self.reference_path, mmap_mode="r")  # type: ignore[no-any-return]


def _split(arrays: list[FloatArray]) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    lengths = np.array([a.shape[0] for a in arrays], dtype=np.int64)
    joined = np.concatenate(arrays) if arrays else np.zeros(0)
    return joined, np.concatenate([[0], np.cumsum(lengths)])


def _unsplit(joined: FloatArray, offsets: npt.NDArray[np.int64]) -> list[FloatArray]:
    return [joined[a:b] for a, b in itertools.pairwise(offsets)]


def _truth_and_poses(
    log: Path, camera_fb: float
) -> tuple[list[FloatArray], list[FloatArray]]:
    depths: list[FloatArray] = []
    poses: list[FloatArray] = []
    with open_log(log) as reader:
        for raw in reader.messages(["/ground_truth/depth", "/ground_truth/pose"]):
            message = reader.decode(raw)
            if raw.topic == "/ground_truth/depth":
                depth = rosmsg.image_array(message).astype(np.float32)
                depths.append(disparity_from_depth(depth, camera_fb))
            else:
                poses.append(rosmsg.pose_matrix(message))
    return depths, poses


def prepare_log(
    log: Path, cache: Path, basis_camera: tuple[tuple[int, int], float], *, truth: bool
) -> LogData:
    """Compute (once) and return the cached per-frame data of a log."""
    npz = cache.with_suffix(".npz")
    reference_path = cache.with_name(cache.name + "_reference.npy")
    basis_size, basis_fb = basis_camera
    grid = grid_size_for(basis_size, GRID_SCALE)
    if not npz.is_file():
        front_end = StereoFrontEnd()
        sweep_gftt = GfttConfig(max_corners=4 * max(SWEEP_POINTS), min_distance=5.0)
        camera: StereoCamera | None = None
        pixels, disparities, many_pixels, many_disparities = [], [], [], []
        grid_sgbm, sgbm_maps = [], []
        with open_log(log) as reader:
            for frame in iter_stereo_frames(reader, PairingConfig()):
                camera = frame.camera
                measured = front_end.measure(frame.left, frame.right)
                pixels.append(measured.pixels.astype(np.float64))
                disparities.append(measured.disparities.astype(np.float64))
                corners = detect_corners(
                    to_grey8(frame.left), sweep_gftt, min_x=front_end.sgbm.valid_min_x
                )
                found = lookup_disparities(measured.disparity_map, corners)
                many_pixels.append(found.pixels.astype(np.float64))
                many_disparities.append(found.disparities.astype(np.float64))
                scale = np.float32(basis_fb / camera.focal_baseline)
                grid_sgbm.append(preprocess_disparity(measured.disparity_map * scale, grid))
                if not truth:
                    sgbm_maps.append(measured.disparity_map.astype(np.float32))
        assert camera is not None
        arrays: dict[str, Any] = {
            "camera": np.array(
                [camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
                 camera.baseline]
            ),
            "grid_sgbm": np.stack(grid_sgbm),
        }
        for name, values in (
            ("pixels", pixels), ("disparities", disparities),
            ("many_pixels", many_pixels), ("many_disparities", many_disparities),
        ):
            arrays[name], arrays[name + "_offsets"] = _split(values)
        if truth:
            references, poses = _truth_and_poses(log, camera.focal_baseline)
            references = references[: len(pixels)]
            scale = np.float32(basis_fb / camera.focal_baseline)
            arrays["grid_truth"] = np.stack(
                [preprocess_disparity(r.astype(np.float32) * scale, grid) for r in references]
            )
            arrays["poses"] = np.stack(poses[: len(pixels)])
            np.save(reference_path, np.stack(references).astype(np.float32))
        else:
            np.save(reference_path, np.stack(sgbm_maps))
        np.savez(npz, **arrays)
    data = np.load(npz)
    c = data["camera"]
    camera = StereoCamera(int(c[0]), int(c[1]), *map(float, c[2:]))
    return LogData(
        camera=camera,
        pixels=_unsplit(data["pixels"], data["pixels_offsets"]),
        disparities=_unsplit(data["disparities"], data["disparities_offsets"]),
        many_pixels=_unsplit(data["many_pixels"], data["many_pixels_offsets"]),
        many_disparities=_unsplit(data["many_disparities"], data["many_disparities_offsets"]),
        poses=data["poses"] if "poses" in data.files else None,
        reference_path=reference_path,
        grid_sgbm=data["grid_sgbm"],
        grid_truth=data["grid_truth"] if "grid_truth" in data.files else None,
    )


def prepare_motions(log: Path, cache: Path, data: LogData) -> LogData:
    """Add (computed once) the visual odometry ``densify`` runs to carry points over."""
    path = cache.with_name(cache.name + "_motion.npz")
    if not path.is_file():
        motions = np.full((data.frames, 4, 4), np.nan)
        seconds = np.zeros(data.frames)
        previous = None
        with open_log(log) as reader:
            frames = iter_stereo_frames(reader, PairingConfig())
            for index, frame in zip(range(data.frames), frames, strict=False):
                image = to_grey8(frame.left)
                started = time.perf_counter()
                if previous is not None:
                    motion = estimate_motion(
                        previous, image, data.pixels[index], data.disparities[index],
                        data.camera, config=CARRY,
                    )
                    if motion is not None:
                        motions[index] = motion.transform
                seconds[index] = time.perf_counter() - started
                previous = image
        np.savez(path, motions=motions, seconds=seconds)
    cached = np.load(path)
    return dataclasses.replace(data, motions=cached["motions"], motion_seconds=cached["seconds"])


# ----------------------------------------------------------------------------- bases


def _drive_maps(job: tuple[int, int, int, tuple[int, int]]) -> npt.NDArray[np.float32]:
    """Ground-truth grid maps of one synthetic drive: every ``step``-th of ``frames``."""
    seed, frames, step, grid = job
    config = SynthConfig(seed=seed, frames=frames)
    camera = config.camera
    world = World(seed)
    maps = []
    for index in range(0, frames, step):
        view = render_view(world, camera, camera_pose(world, config, index))
        disparity = disparity_from_depth(view.depth, camera.focal_baseline).astype(np.float32)
        maps.append(preprocess_disparity(disparity, grid))
    return np.stack(maps)


def render_drives(work: Path, drives: int, frames: int, step: int) -> npt.NDArray[np.float32]:
    """Ground-truth grid maps of ``drives`` synthetic drives (seeds from DRIVE_SEED), cached.

    Only the left depth is rendered (no images, no stereo): the basis needs nothing else,
    and distinct drives give far more varied scenes than consecutive frames of a few.
    """
    folder = work / "drives"
    folder.mkdir(exist_ok=True)
    paths = [folder / f"seed{DRIVE_SEED + i}_{frames}_step{step}.npy" for i in range(drives)]
    camera = SynthConfig().camera
    grid = grid_size_for(camera.image_size, GRID_SCALE)
    missing = [i for i, path in enumerate(paths) if not path.is_file()]
    jobs_ = [(DRIVE_SEED + i, frames, step, grid) for i in missing]
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        rendered = zip(missing, pool.map(_drive_maps, jobs_), strict=True)
        for done, (i, part) in enumerate(rendered, start=1):
            np.save(paths[i], part)  # one file per drive: a larger --drives reuses them
            if done % 20 == 0 or done == len(missing):
                _log(f"  rendered {done}/{len(missing)} drives")
    return np.concatenate([np.load(path) for path in paths])


def _learn(
    maps: npt.NDArray[np.float32], basis_camera: tuple[tuple[int, int], float], components: int,
    source: str,
) -> Basis:
    size, fb = basis_camera
    return learn_basis(
        iter(maps), n_components=min(components, maps.shape[0] - 1), grid_scale=GRID_SCALE,
        preprocessed=True, image_size=size, focal_baseline=fb, meta={"source": source},
        # the exact Gram path up to 15,000 maps (10,000 peaked at ~9.4 GB; 20,000 ran out
        # of 24 GB in the eigendecomposition), the streaming SVD beyond
        exact_max_maps=15_000, exact_max_bytes=8 << 30,
    )


FIT_MAX_FRAMES = 40
FIT_SEQUENCE_FRAMES = 30
CALIBRATION_EVERY = 4


def fit_hyperparameters(
    basis: Basis, fit_logs: Sequence[tuple[LogData, slice]]
) -> dict[str, Any]:
    """``fitting.fit_prior`` (as ``learn --fit-prior``) on the cached held-out frames.

    The calibration reference is each fit frame's reference (ground truth on the synthetic
    fitting log, SGBM on KITTI), every 4th frame.
    """
    sequences, calibration = [], []
    for data, frames in fit_logs:
        indices = list(range(data.frames))[frames]
        size, fb = data.camera.image_size, data.camera.focal_baseline
        sequences.append(
            [
                fit_frame(
                    basis, data.pixels[i], data.disparities[i], image_size=size,
                    focal_baseline=fb,
                )
                for i in indices
            ]
        )
        reference = data.reference()
        calibration += [
            CalibrationFrame(data.pixels[i], data.disparities[i], size, fb, reference[i])
            for i in indices[::CALIBRATION_EVERY]
        ]
    started = time.perf_counter()
    meta = fit_prior(
        basis, sequences, calibration, max_frames=FIT_MAX_FRAMES,
        sequence_frames=FIT_SEQUENCE_FRAMES, robust="cauchy",
    )
    meta["fit_seconds"] = round(time.perf_counter() - started, 1)
    return meta


# ----------------------------------------------------------------------------- evaluate


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
        local=True, robust="cauchy", temporal=True, fitted_sigma=True,
    ),
    Method("hybrid + Cauchy + fitted sigma", local=True, robust="cauchy", fitted_sigma=True),
    Method("hybrid + temporal + fitted sigma", local=True, temporal=True, fitted_sigma=True),
    Method(f"+ carried points ({CARRY.frames} frames)", carry=True),
    Method(
        f"hybrid + Cauchy + carried ({CARRY.frames} frames) + fitted sigma",
        local=True, robust="cauchy", fitted_sigma=True, carry=True,
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


def _add_frame(
    sums: Sums, data: LogData, index: int, mode: str, reference: npt.NDArray[Any],
    estimate: npt.NDArray[Any], std: npt.NDArray[Any] | None, view: ReferenceView | None = None,
) -> None:
    """Add one frame's mean Delta_2D and (with a std) +-sigma coverage terms to ``sums``."""
    transform = _transform(data, index, mode)
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


def _transform(data: LogData, index: int, mode: str) -> FloatArray:
    if mode == "stereo":
        return stereo_transform(data.camera)
    assert data.poses is not None
    return relative_transform(data.poses[index], data.poses[index + 1])


def _calibration(basis: Basis, hybrid: bool) -> EstimateSettings:
    """The std calibration ``densify`` applies by default with this basis."""
    return resolve_settings(basis, ProcessorConfig(prior="hybrid" if hybrid else "paper"))


def _estimates(
    method: Method, basis: Basis, hyper: dict[str, Any], data: LogData,
    points: Callable[[int], tuple[FloatArray, FloatArray]], frames: Sequence[int],
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
    state = (
        TemporalPrior(process_noise=float(hyper["process_noise"])) if method.temporal else None
    )
    calibration = _calibration(basis, local is not None)
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
            result = interpolate(pixels, disparities, image_size=camera.image_size)
            seconds = time.perf_counter() - started
            yield index, result.disparity.astype(np.float64), None, seconds, {}
            continue
        estimate = densify_batch(
            basis, [pixels], [disparities], sigma=sigma, local_prior=local,
            robust=method.robust, temporal=state, image_size=camera.image_size,
            focal_baseline=camera.focal_baseline,
            std_scale=calibration.std_scale,
            scale_by_innovation=calibration.scale_by_innovation,
            noise_stds=[noise],
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
            index, estimate.disparity.astype(np.float64),
            estimate.disparity_std.astype(np.float64), seconds, extras,
        )


def _test_frames(data: LogData, mode: str, max_frames: int | None) -> list[int]:
    """Frames evaluated: temporal mode needs the next frame's pose."""
    count = data.frames - (1 if mode == "temporal" else 0)
    return list(range(count if max_frames is None else min(count, max_frames)))


def evaluate_split(
    basis: Basis, hyper: dict[str, Any], data: LogData, mode: str,
    methods: Sequence[Method], max_frames: int | None,
) -> dict[str, dict[str, float]]:
    """Run every method over a test log; return its metrics."""
    frames = _test_frames(data, mode, max_frames)
    references = data.reference()
    views = {}
    for index in frames:
        transform = _transform(data, index, mode)
        views[index] = reference_view(references[index], data.camera, transform)
    results: dict[str, dict[str, float]] = {}
    for method in methods:
        sums = Sums()

        def points(index: int) -> tuple[FloatArray, FloatArray]:
            return data.pixels[index], data.disparities[index]

        for index, estimate, std, seconds, extras in _estimates(
            method, basis, hyper, data, points, frames
        ):
            view = views[index]
            _add_frame(sums, data, index, mode, references[index], estimate, std, view)
            depth = depth_errors(
                estimate, view.disparity, view.counted,
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
        _log(f"  {method.name}: {results[method.name]}")
    return results


def sweep_split(
    basis: Basis, hyper: dict[str, Any], data: LogData, mode: str,
    methods: Sequence[Method], max_frames: int | None,
) -> dict[str, dict[str, float]]:
    """Mean Delta_2D against the number of points (strongest-first lookups)."""
    frames = _test_frames(data, mode, max_frames)
    references = data.reference()
    out: dict[str, dict[str, float]] = {}
    for n_points in SWEEP_POINTS:
        row: dict[str, float] = {}
        for method in methods:

            def points(index: int, n: int = n_points) -> tuple[FloatArray, FloatArray]:
                return data.many_pixels[index][:n], data.many_disparities[index][:n]

            total, n = 0.0, 0.0
            for index, estimate, _, _, _ in _estimates(
                method, basis, hyper, data, points, frames
            ):
                transform = _transform(data, index, mode)
                view = reference_view(references[index], data.camera, transform)
                delta_2d, _ = projection_errors(estimate, view, data.camera, transform)
                total += float(np.nansum(delta_2d))
                n += float(np.isfinite(delta_2d).sum())
            row[method.name] = total / max(n, 1.0)
        out[str(n_points)] = row
        _log(f"  sweep {n_points}: {row}")
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
    for index in _test_frames(data, "temporal", None)[::every]:
        transform = _transform(data, index, "temporal")
        view = reference_view(references[index], data.camera, transform)
        depth = fb / np.maximum(np.nan_to_num(view.disparity), 1e-6)
        size = data.camera.image_size
        pixels, disparities = data.pixels[index], data.disparities[index]
        estimates = {
            "plain": densify_batch(basis, [pixels], [disparities], uncertainty="none")[0],
            "hybrid": densify_batch(
                basis, [pixels], [disparities], uncertainty="none", local_prior=local,
                sigma=float(hyper["sigma"]),
            )[0],
        }
        maps = {name: e.disparity for name, e in estimates.items()}
        maps["nearest"] = nearest(pixels, disparities, image_size=size).disparity
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
        _log(f"  {name}: {[round(v, 2) for v in out[name]]}")
    return out


def irls_iterations(
    splits: Sequence[tuple[str, str, str, Basis, dict[str, Any]]], data: dict[str, LogData],
    frames: int = 40,
) -> dict[str, dict[str, list[float]]]:
    """Hybrid + Cauchy with 1, 2 and 4 reweightings: mean Delta_2D and +-2 sigma coverage."""
    out: dict[str, dict[str, list[float]]] = {}
    for split, test, mode, basis, hyper in splits:
        local = LocalPrior.from_meta(hyper["local"]) if hyper.get("local") else None
        settings = _calibration(basis, local is not None)
        for iterations in (1, 2, 4):
            sums = Sums()
            references = data[test].reference()
            for index in _test_frames(data[test], mode, frames):
                item = data[test]
                result = densify_batch(
                    basis, [item.pixels[index]], [item.disparities[index]],
                    sigma=float(hyper["sigma"]), local_prior=local, robust="cauchy",
                    robust_iterations=iterations, image_size=item.camera.image_size,
                    focal_baseline=item.camera.focal_baseline,
                    std_scale=settings.std_scale,
                    scale_by_innovation=settings.scale_by_innovation,
                )[0]
                _add_frame(
                    sums, item, index, mode, references[index], result.disparity,
                    result.disparity_std,
                )
            summary = sums.summary()
            out.setdefault(split, {})[str(iterations)] = [
                summary["delta_2d_mean"], summary["coverage_2"]
            ]
            _log(f"  {split} {iterations} reweightings: {out[split][str(iterations)]}")
    return out


CARRY_SWEEP = (
    (0, 30.0, 1.0), (2, 30.0, 1.0), (4, 30.0, 1.0), (8, 30.0, 1.0),
    (4, 20.0, 1.0), (4, 40.0, 1.0), (4, 30.0, 0.5), (4, 30.0, 2.0),
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

            def points(index: int, data: LogData = data) -> tuple[FloatArray, FloatArray]:
                return data.pixels[index], data.disparities[index]

            for index, estimate, std, _, extras in _estimates(
                method, basis, hyper, data, points, frames, carry=options
            ):
                carried += int(extras["carried"])
                _add_frame(sums, data, index, mode, references[index], estimate, std)
            summary = sums.summary()
            key = f"{n_frames}/{gap:g}/{age_std:g}"
            out.setdefault(split, {})[key] = [
                summary["delta_2d_mean"], summary["coverage_2"], carried / max(len(frames), 1)
            ]
            _log(f"  {split} carry {key}: {out[split][key]}")
    return out


# ----------------------------------------------------------------------------- report

SPLIT_TITLES = {
    "synthetic": "synthetic (temporal, ground truth)",
    "kitti_a": "KITTI A: raw drive -> odometry clip (real-only basis)",
    "kitti_b": "KITTI B: odometry clip -> raw drive (real-only basis)",
    "kitti_a_mix": "KITTI A, basis + 1,000 synthetic maps",
    "kitti_b_mix": "KITTI B, basis + 1,000 synthetic maps",
}


def hyperparameter_table(work: Path) -> list[str]:
    """The fitted hyperparameters of every basis in ``work`` (from their ``meta["prior"]``)."""
    lines = [
        "**Fitted hyperparameters** (`meta[\"prior\"]` of each basis)",
        "",
        "| basis | maps | kernel, ell, v | sigma (plain sigma) px | evidence gain, nats "
        "| q | std scale (with covariance scale) |",
        "| --- | ---: | --- | --- | ---: | ---: | --- |",
    ]
    for path in sorted(work.glob("basis_*.npz")):
        basis = Basis.load(path)
        prior = basis.meta.get("prior", {})
        local = prior.get("local")
        kernel = (
            f"{local['kernel']}, {local['length_scale']:g} px, {local['variance']:.2g} px^2"
            if local else "none"
        )
        gain = prior.get("log_evidence", 0.0) - prior.get("plain_log_evidence", 0.0)
        nan = float("nan")
        lines.append(
            f"| {path.stem.removeprefix('basis_')} | {basis.n_train} | {kernel} "
            f"| {prior.get('sigma', nan):.2f} ({prior.get('plain_sigma', nan):.2f}) "
            f"| {gain:+.0f} | {prior.get('process_noise', nan):g} "
            f"| {prior.get('std_scale', nan):.2f} ({prior.get('innovation_std_scale', nan):.2f}) |"
        )
    return [*lines, ""]


def report(results: dict[str, Any], work: Path | None = None) -> str:
    """Return the Markdown tables of a results.json (and of the bases in ``work``)."""
    lines: list[str] = [] if work is None else hyperparameter_table(work)
    for split, methods in results.get("evaluate", {}).items():
        nearest_mean = methods.get("nearest neighbour", {}).get("delta_2d_mean", float("nan"))
        lines += [
            f"**{SPLIT_TITLES.get(split, split)}**",
            "",
            "| method | mean Delta_2D px | / nearest | depth RMSE m | +-1 / +-2 sigma % "
            "| ms/frame | down-weighted/frame | resets |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for name, m in methods.items():
            coverage = (
                f"{100 * m['coverage_1']:.1f} / {100 * m['coverage_2']:.1f}"
                if m["coverage_2"] == m["coverage_2"]
                else "-"
            )
            lines.append(
                f"| {name} | {m['delta_2d_mean']:.2f} | {m['delta_2d_mean'] / nearest_mean:.2f} "
                f"| {m['depth_rmse']:.2f} | {coverage} | {m['ms_per_frame']:.0f} "
                f"| {m['downweighted_per_frame']:.1f} | {m['temporal_resets']:.0f} |"
            )
        lines.append("")
    for split, rows in results.get("sweep", {}).items():
        names = list(next(iter(rows.values())).keys())
        lines += [
            f"**Points sweep, {SPLIT_TITLES.get(split, split)}** (mean Delta_2D px)",
            "",
            "| points | " + " | ".join(names) + " |",
            "| ---: | " + " | ".join("---:" for _ in names) + " |",
        ]
        for points, row in rows.items():
            lines.append(
                f"| {points} | " + " | ".join(f"{row.get(n, float('nan')):.2f}" for n in names)
                + " |"
            )
        lines.append("")
    if results.get("mix"):
        lines += [
            "**Training mix** (KITTI, SGBM maps; mean Delta_2D px on the other clip)",
            "",
            "| basis | synthetic maps | real maps | plain | hybrid + Cauchy | nearest "
            "| hybrid / nearest |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for name, m in results["mix"].items():
            plain = m[METHODS[0].name]["delta_2d_mean"]
            hybrid = m[METHODS[8].name]["delta_2d_mean"]
            nearest_mean = m["nearest neighbour"]["delta_2d_mean"]
            lines.append(
                f"| {name} | {m['synthetic_maps']} | {m['real_maps']} | {plain:.2f} "
                f"| {hybrid:.2f} | {nearest_mean:.2f} | {hybrid / nearest_mean:.2f} |"
            )
        lines.append("")
    if results.get("carry"):
        splits = list(results["carry"])
        lines += [
            "**Carried points on the fitting frames** (hybrid + Cauchy; mean Delta_2D px, "
            "+-2 sigma %, carried points/frame)",
            "",
            "| frames / gap px / age std px | " + " | ".join(splits) + " |",
            "| --- |" + " ---: |" * len(splits),
        ]
        for key in results["carry"][splits[0]]:
            cells = [
                "{:.3f} ({:.1f} %, {:.0f})".format(
                    results["carry"][split][key][0], 100 * results["carry"][split][key][1],
                    results["carry"][split][key][2],
                )
                for split in splits
            ]
            lines.append(f"| {key} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    """Run the experiments; return the exit code."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="cache and output folder")
    parser.add_argument("--train-frames", type=int, default=300, help="per training seed")
    parser.add_argument(
        "--drives", type=int, default=400,
        help="synthetic drives rendered for the synthetic basis (0: seeds 101-104 only)",
    )
    parser.add_argument("--drive-frames", type=int, default=300, help="frames per drive")
    parser.add_argument("--drive-step", type=int, default=6, help="every N-th frame kept")
    parser.add_argument("--fit-frames", type=int, default=60)
    parser.add_argument("--test-frames", type=int, default=101)
    parser.add_argument("--components", type=int, default=500)
    parser.add_argument("--max-test-frames", type=int, default=None)
    parser.add_argument("--sweep-frames", type=int, default=20)
    parser.add_argument(
        "--stages", nargs="+", default=["prepare", "bases", "evaluate", "sweep", "mix"]
    )
    parser.add_argument("--methods", nargs="*", default=None, help="names of METHODS to run")
    parser.add_argument(
        "--results", nargs="+", default=["results.json"],
        help="results file(s) in WORK: a run writes the first; the report merges them all "
        "(runs of different --splits side by side)",
    )
    parser.add_argument(
        "--splits", nargs="+", default=None,
        help="only these splits: synthetic, kitti_a, kitti_a_mix, kitti_b, kitti_b_mix "
        "(default: all)",
    )
    args = parser.parse_args(argv)
    work: Path = args.work
    if args.stages == ["report"]:
        merged: dict[str, Any] = {}
        for name in args.results:  # runs of different splits, merged by split
            for key, value in json.loads((work / name).read_text()).items():
                if isinstance(value, dict):
                    merged.setdefault(key, {}).update(value)
                else:
                    merged[key] = value
        print(report(merged, work))
        return 0
    work.mkdir(parents=True, exist_ok=True)
    results_path = work / args.results[0]
    results: dict[str, Any] = (
        json.loads(results_path.read_text()) if results_path.is_file() else {}
    )

    def save() -> None:
        results_path.write_text(json.dumps(results, indent=1) + "\n")

    # synthetic logs
    logs = {f"train_{s}": (s, args.train_frames) for s in TRAIN_SEEDS}
    logs[f"fit_{FIT_SEED}"] = (FIT_SEED, args.fit_frames)
    logs[f"test_{TEST_SEED}"] = (TEST_SEED, args.test_frames)
    for name, (seed, frames) in logs.items():
        path = work / f"{name}.mcap"
        if not path.is_file():
            _log(f"synth {name}")
            jobs.synth(path, frames=frames, seed=seed, scale=1.0, fmt="mcap")
    real = {}
    for name, folder in KITTI.items():
        if folder.is_dir():
            path = work / f"kitti_{name}.mcap"
            if not path.is_file():
                jobs.import_kitti(folder, path, max_frames=None)
            real[name] = path
    with open_log(work / f"test_{TEST_SEED}.mcap") as reader:
        first = next(iter_stereo_frames(reader, PairingConfig()))
    basis_camera = (first.camera.image_size, first.camera.focal_baseline)

    data: dict[str, LogData] = {}
    for name in logs:
        _log(f"prepare {name}")
        data[name] = prepare_log(work / f"{name}.mcap", work / f"cache_{name}", basis_camera,
                                 truth=True)
        if name.startswith("test"):
            data[name] = prepare_motions(work / f"{name}.mcap", work / f"cache_{name}", data[name])
    for name, path in real.items():
        _log(f"prepare kitti {name}")
        data[f"kitti_{name}"] = prepare_motions(
            path, work / f"cache_kitti_{name}",
            prepare_log(path, work / f"cache_kitti_{name}", basis_camera, truth=False),
        )
    if "prepare" in args.stages and len(args.stages) == 1:
        return 0

    # bases and their hyperparameters
    def basis_for(
        name: str, maps: npt.NDArray[np.float32], source: str,
        fit_logs: Sequence[tuple[LogData, slice]],
    ) -> tuple[Basis, dict[str, Any]]:
        path = work / f"basis_{name}.npz"
        if not path.is_file():
            _log(f"learn {name}")
            basis = _learn(maps, basis_camera, args.components, source)
            _log(f"fit hyperparameters {name}")
            prior = fit_hyperparameters(basis, fit_logs)
            basis = dataclasses.replace(basis, meta={**basis.meta, "prior": prior})
            basis.save(path)
        basis = Basis.load(path)
        shown = {k: v for k, v in basis.meta["prior"].items() if k not in ("table", "candidates")}
        _log(f"{name}: prior {json.dumps(shown)}")
        return basis, basis.meta["prior"]

    synth_sgbm = np.concatenate([data[f"train_{s}"].grid_sgbm for s in TRAIN_SEEDS])
    splits: list[tuple[str, str, str, Basis, dict[str, Any]]] = []

    def wanted(split: str) -> bool:
        return args.splits is None or split in args.splits

    if not wanted("synthetic"):
        pass
    elif args.drives:
        _log(f"render {args.drives} drives")
        synth_truth = render_drives(work, args.drives, args.drive_frames, args.drive_step)
        basis_name = f"synthetic_drives{args.drives}"
        source = (
            f"synthetic ground truth, {args.drives} drives (seeds {DRIVE_SEED}-"
            f"{DRIVE_SEED + args.drives - 1}), every {args.drive_step}th of "
            f"{args.drive_frames} frames"
        )
    else:
        synth_truth = np.concatenate([data[f"train_{s}"].grid_truth for s in TRAIN_SEEDS])
        basis_name, source = "synthetic", "synthetic ground truth, seeds 101-104"
    if wanted("synthetic"):
        basis, hyper = basis_for(
            basis_name, synth_truth, source, [(data[f"fit_{FIT_SEED}"], slice(None))]
        )
        splits.append(("synthetic", f"test_{TEST_SEED}", "temporal", basis, hyper))
    if len(real) == 2:
        for split, train, test in (("kitti_a", "raw", "odometry"), ("kitti_b", "odometry", "raw")):
            train_data = data[f"kitti_{train}"]
            cut = round(0.8 * train_data.frames)
            basis, hyper = basis_for(
                f"{split}_real", train_data.grid_sgbm[:cut],
                f"SGBM, KITTI {train} frames 0-{cut - 1}",
                [(train_data, slice(cut, None))],
            )
            splits.append((split, f"kitti_{test}", "stereo", basis, hyper))
            # the same real frames with 1,000 synthetic SGBM maps (see the mix stage)
            step = max(1, synth_sgbm.shape[0] // MAIN_MIX)
            synthetic_part = synth_sgbm[::step][:MAIN_MIX]
            basis, hyper = basis_for(
                f"{split}_mix{MAIN_MIX}",
                np.concatenate([synthetic_part, train_data.grid_sgbm[:cut]]),
                f"SGBM: {synthetic_part.shape[0]} synthetic + {cut} KITTI {train}",
                [(train_data, slice(cut, None))],
            )
            splits.append((f"{split}_mix", f"kitti_{test}", "stereo", basis, hyper))

    splits = [split for split in splits if wanted(split[0])]
    methods = [m for m in METHODS if args.methods is None or m.name in args.methods]
    if "evaluate" in args.stages:
        for split, test, mode, basis, hyper in splits:
            _log(f"evaluate {split} on {test} ({mode})")
            results.setdefault("evaluate", {}).setdefault(split, {}).update(
                evaluate_split(basis, hyper, data[test], mode, methods, args.max_test_frames)
            )
            save()
    if "sweep" in args.stages:
        for split, test, mode, basis, hyper in splits:
            _log(f"sweep {split}")
            sweep = results.setdefault("sweep", {}).setdefault(split, {})
            swept = sweep_split(
                basis, hyper, data[test], mode,
                [m for m in methods if m.name in {
                    METHODS[0].name, METHODS[7].name, METHODS[8].name, METHODS[9].name,
                    METHODS[11].name, METHODS[14].name, "nearest neighbour", "linear"}],
                args.sweep_frames,
            )
            for points, row in swept.items():
                sweep.setdefault(points, {}).update(row)
            save()
    synthetic = [split for split in splits if split[0] == "synthetic"]
    if "depth-bins" in args.stages and synthetic:
        _log("depth bins (synthetic)")
        results["depth_bins"] = depth_bins(synthetic[0][3], data[synthetic[0][1]])
        save()
    if "carry" in args.stages:
        _log("carried points on the fitting frames")
        fits = []
        for split, _, mode, basis, hyper in splits:
            if split == "synthetic":
                fit_name = f"fit_{FIT_SEED}"
                data[fit_name] = prepare_motions(
                    work / f"{fit_name}.mcap", work / f"cache_{fit_name}", data[fit_name]
                )
                fit_data = data[fit_name]
                frames = _test_frames(fit_data, mode, None)
            else:
                # the held-out 20 % of the training clip the hyperparameters were fitted on
                fit_data = data["kitti_raw" if split.startswith("kitti_a") else "kitti_odometry"]
                frames = list(range(round(0.8 * fit_data.frames), fit_data.frames))
            fits.append((split, basis, hyper, fit_data, mode, frames))
        results["carry"] = carry_sweep(fits)
        save()
    if "irls" in args.stages:
        _log("IRLS reweightings")
        results["irls"] = irls_iterations(
            [splits[i] for i in range(len(splits)) if splits[i][0] in IRLS_SPLITS], data
        )
        save()
    if "mix" in args.stages and len(real) == 2 and (wanted("kitti_a") or wanted("kitti_b")):
        mix_methods = [METHODS[0], METHODS[8], METHODS[10]]
        for split, train, test in (("kitti_a", "raw", "odometry"), ("kitti_b", "odometry", "raw")):
            train_data = data[f"kitti_{train}"]
            cut = round(0.8 * train_data.frames)
            real_maps = train_data.grid_sgbm[:cut]
            for share in (0, 250, 1000):
                name = f"{split}_mix{share}"
                step = max(1, synth_sgbm.shape[0] // max(share, 1))
                synthetic_part = synth_sgbm[::step][:share]
                basis, hyper = basis_for(
                    name, np.concatenate([synthetic_part, real_maps]),
                    f"SGBM: {synthetic_part.shape[0]} synthetic + {cut} KITTI {train}",
                    [(train_data, slice(cut, None))],
                )
                _log(f"mix {name}")
                results.setdefault("mix", {})[name] = {
                    "synthetic_maps": int(synthetic_part.shape[0]),
                    "real_maps": int(real_maps.shape[0]),
                    **evaluate_split(basis, hyper, data[f"kitti_{test}"], "stereo",
                                     mix_methods, args.max_test_frames),
                }
                save()
            # synthetic only
            name = f"{split}_synthonly"
            basis, hyper = basis_for(
                name, synth_sgbm, "SGBM: synthetic only",
                [(train_data, slice(cut, None))],
            )
            results.setdefault("mix", {})[name] = {
                "synthetic_maps": int(synth_sgbm.shape[0]), "real_maps": 0,
                **evaluate_split(basis, hyper, data[f"kitti_{test}"], "stereo", mix_methods,
                                 args.max_test_frames),
            }
            save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
