"""The cached inputs of ``run_beyond.py``: per-log front-end data, bases, hyperparameters.

Each log is measured once into its cache (:func:`prepare_log`, :func:`prepare_motions`):
the measurements of the densify front end, a dense set of strongest-first lookups for the
points sweep, the reference (ground truth for synthetic logs, SGBM otherwise), poses and the
maps preprocessed onto the basis grid. ``bench_beyond.py`` and ``bench_variance_grid.py``
read the same caches.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.fitting import CalibrationFrame, fit_frame, fit_prior
from pcainterp_stream.estimate.learning import learn_basis, preprocess_disparity
from pcainterp_stream.evaluate.metrics import disparity_from_depth
from pcainterp_stream.frontend.motion import estimate_motion
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
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth import SynthConfig, camera_pose
from pcainterp_stream.synth.render import render_view
from pcainterp_stream.synth.world import World

GRID_SCALE = 0.25
SWEEP_POINTS = (50, 100, 200, 400, 800)
"""Points of the sweep: the strongest N lookups of each frame."""
DRIVE_SEED = 1000
"""First seed of the synthetic drives rendered for the synthetic basis (``--drives``)."""
FloatArray = npt.NDArray[np.float64]
CARRY = ProcessorConfig().carry
"""Carried points as ``densify`` carries them by default."""


# ----------------------------------------------------------------------------- logs


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

    def measured(self, index: int) -> tuple[FloatArray, FloatArray]:
        """Return a frame's measurements as ``densify`` takes them: pixels, disparities."""
        return self.pixels[index], self.disparities[index]

    def strongest(self, index: int, n: int) -> tuple[FloatArray, FloatArray]:
        """Return a frame's ``n`` strongest lookups (of the dense set of the points sweep)."""
        return self.many_pixels[index][:n], self.many_disparities[index][:n]

    def reference(self) -> npt.NDArray[np.float32]:
        """Return the (F, H, W) reference disparities, memory-mapped."""
        return np.load(self.reference_path, mmap_mode="r")  # type: ignore[no-any-return]


def _split(arrays: list[FloatArray]) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    lengths = np.array([a.shape[0] for a in arrays], dtype=np.int64)
    joined = np.concatenate(arrays) if arrays else np.zeros(0)
    return joined, np.concatenate([[0], np.cumsum(lengths)])


def _unsplit(joined: FloatArray, offsets: npt.NDArray[np.int64]) -> list[FloatArray]:
    return [joined[a:b] for a, b in itertools.pairwise(offsets)]


def _truth_and_poses(log: Path, camera_fb: float) -> tuple[list[FloatArray], list[FloatArray]]:
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
    """Compute (once) and return the cached per-frame data of a log.

    Args:
        log: the stereo log.
        cache: the cache files' path without suffix: ``CACHE.npz`` and
            ``CACHE_reference.npy``.
        basis_camera: the basis's image size and f*b (the grid maps are in its units).
        truth: the log has ground truth (a synthetic log): reference and grid maps from it,
            and the poses; else the reference is the SGBM map.
    """
    npz = cache.with_suffix(".npz")
    reference_path = cache.with_name(cache.name + "_reference.npy")
    harness.cached(npz, partial(_measure_log, log, reference_path, basis_camera, truth=truth))
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


def _measure_log(
    log: Path,
    reference_path: Path,
    basis_camera: tuple[tuple[int, int], float],
    npz: Path,
    *,
    truth: bool,
) -> None:
    """Run the front end over a log; write the arrays of :func:`prepare_log`'s cache."""
    basis_size, basis_fb = basis_camera
    grid = grid_size_for(basis_size, GRID_SCALE)
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
            [
                camera.width,
                camera.height,
                camera.fx,
                camera.fy,
                camera.cx,
                camera.cy,
                camera.baseline,
            ]
        ),
        "grid_sgbm": np.stack(grid_sgbm),
    }
    for name, values in (
        ("pixels", pixels),
        ("disparities", disparities),
        ("many_pixels", many_pixels),
        ("many_disparities", many_disparities),
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


def prepare_motions(log: Path, cache: Path, data: LogData) -> LogData:
    """Add (computed once) the visual odometry ``densify`` runs to carry points over."""
    path = harness.cached(
        cache.with_name(cache.name + "_motion.npz"), partial(_measure_motions, log, data)
    )
    cached = np.load(path)
    return dataclasses.replace(data, motions=cached["motions"], motion_seconds=cached["seconds"])


def _measure_motions(log: Path, data: LogData, path: Path) -> None:
    """Write the odometry of each frame from the one before (NaN: none) and its seconds."""
    motions = np.full((data.frames, 4, 4), np.nan)
    seconds = np.zeros(data.frames)
    previous = None
    with open_log(log) as reader:
        frames = iter_stereo_frames(reader, PairingConfig())
        for index, frame in zip(range(data.frames), frames, strict=False):
            image = to_grey8(frame.left)
            with harness.Stopwatch() as watch:
                if previous is not None:
                    motion = estimate_motion(
                        previous,
                        image,
                        data.pixels[index],
                        data.disparities[index],
                        data.camera,
                        config=CARRY,
                    )
                    if motion is not None:
                        motions[index] = motion.transform
            seconds[index] = watch.wall
            previous = image
    np.savez(path, motions=motions, seconds=seconds)


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
                harness.log(f"  rendered {done}/{len(missing)} drives")
    return np.concatenate([np.load(path) for path in paths])


def learn_grid_basis(
    maps: npt.NDArray[np.float32],
    basis_camera: tuple[tuple[int, int], float],
    components: int,
    source: str,
) -> Basis:
    """Learn a basis from maps already on the grid (``meta["source"]`` says from what)."""
    size, fb = basis_camera
    return learn_basis(
        iter(maps),
        n_components=min(components, maps.shape[0] - 1),
        grid_scale=GRID_SCALE,
        preprocessed=True,
        image_size=size,
        focal_baseline=fb,
        meta={"source": source},
        # the exact Gram path up to 15,000 maps (10,000 peaked at ~9.4 GB; 20,000 ran out
        # of 24 GB in the eigendecomposition), the streaming SVD beyond
        exact_max_maps=15_000,
        exact_max_bytes=8 << 30,
    )


FIT_MAX_FRAMES = 40
FIT_SEQUENCE_FRAMES = 30
CALIBRATION_EVERY = 4


def fit_hyperparameters(basis: Basis, fit_logs: Sequence[tuple[LogData, slice]]) -> dict[str, Any]:
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
                    basis,
                    data.pixels[i],
                    data.disparities[i],
                    image_size=size,
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
    with harness.Stopwatch() as watch:
        meta = fit_prior(
            basis,
            sequences,
            calibration,
            max_frames=FIT_MAX_FRAMES,
            sequence_frames=FIT_SEQUENCE_FRAMES,
            robust="cauchy",
        )
    meta["fit_seconds"] = round(watch.wall, 1)
    return meta


if __name__ == "__main__":
    harness.module_main(__doc__, "run_beyond.py, bench_beyond.py and bench_variance_grid.py")
