"""Timing behind ``tools/sparse_sharpness.py --timing`` and ``--pool-timing``.

CPU seconds per frame of the estimate alone, of the estimate pool with carried points, of
the sparse lookups against a full SGBM map, and of the edge-aware prior's seedings, each on
the same frames and settings as the scores (moved out of ``sparse_sharpness.py``, which the
900-line module budget bounds).
"""

from __future__ import annotations

import time
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.variance import prior_std_map
from pcainterp_stream.frontend.stereo import StereoFrontEnd
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoFrame

Array = npt.NDArray[np.float32]


def estimate_seconds(
    items: list[tuple[StereoFrame, Array]],
    configs: list[ProcessorConfig],
    bases: list[Basis | None],
    repeats: int = 3,
) -> list[float]:
    """CPU seconds per frame of the estimate alone, for each configuration's points.

    ``densify_batch`` of 4 frames at a time, one BLAS thread, the processor's settings, no
    carried points; the configurations are timed in turns, the best of ``repeats`` kept.
    An edge-aware prior's seedings (its map on the cell grid) are made beforehand, as the
    stereo workers make them (:func:`partition_seconds` times that); the label search is
    part of the estimate, a batch's frames at once, as in the estimate pool.
    """
    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.estimator import densify_batch
    from pcainterp_stream.frontend.stereo import StereoFrontEnd
    from pcainterp_stream.pipeline.processor import resolve_settings

    measured = []
    for config, basis in zip(configs, bases, strict=True):
        prior_std = None
        if config.gftt.fill_placement == "prior_std":
            prior_std = prior_std_map(basis or Basis.default())
        front_end = StereoFrontEnd(config.gftt, config.sgbm, prior_std=prior_std)
        measured.append([front_end.measure(frame.left, frame.right) for frame, _ in items])
    best = [np.inf] * len(configs)
    camera = items[0][0].camera
    grid = Basis.default().grid_size
    partitions = [
        [_partition(m, camera.image_size, grid) if config.edge_aware else None for m in frames]
        for config, frames in zip(configs, measured, strict=True)
    ]
    with threadpool_limits(1):
        for _ in range(repeats):
            for index, config in enumerate(configs):
                basis = bases[index] or Basis.default()
                options = resolve_settings(basis, config).densify_options()
                started = time.process_time()
                for start in range(0, len(items), 4):
                    batch = measured[index][start : start + 4]
                    densify_batch(
                        basis,
                        [m.pixels for m in batch],
                        [m.disparities for m in batch],
                        partitions=partitions[index][start : start + 4],
                        image_size=camera.image_size,
                        focal_baseline=camera.focal_baseline,
                        robust=config.robust,
                        **options,
                    )
                best[index] = min(best[index], (time.process_time() - started) / len(items))
    return best


def pool_seconds(
    items: list[tuple[StereoFrame, Array]],
    configs: list[ProcessorConfig],
    bases: list[Basis | None],
    rounds: int = 5,
) -> list[list[float]]:
    """CPU seconds per frame of the estimate pool's own batches, per configuration and round.

    Each configuration's job runs once through the frame processor (fit check, carried
    points and all), its estimate batches (``densify_batch`` calls) recorded; then the
    batches are replayed in one thread, one BLAS thread, the configurations in turns for
    ``rounds`` rounds. Unlike :func:`estimate_seconds` the cells then hold carried points
    too, as in a job.
    """
    import copy

    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.estimator import densify_batch
    from pcainterp_stream.pipeline import processor

    recorded: list[list[tuple[Basis, Any, Any, dict[str, Any]]]] = []
    for config, basis in zip(configs, bases, strict=True):
        batches: list[tuple[Basis, Any, Any, dict[str, Any]]] = []

        def recording(
            basis: Basis,
            pixels: Any,
            disparities: Any,
            batches: list[tuple[Basis, Any, Any, dict[str, Any]]] = batches,
            **options: Any,
        ) -> Any:
            batches.append((basis, copy.deepcopy(pixels), copy.deepcopy(disparities), options))
            return densify_batch(basis, pixels, disparities, **options)

        setattr(processor, "densify_batch", recording)  # noqa: B010
        try:
            with FrameProcessor(basis, config) as job:
                list(job.process([frame for frame, _ in items]))
        finally:
            setattr(processor, "densify_batch", densify_batch)  # noqa: B010
        recorded.append(batches)
    seconds: list[list[float]] = [[] for _ in configs]
    with threadpool_limits(1):
        for _ in range(rounds):
            for index, batches in enumerate(recorded):
                started = time.thread_time()
                for basis, pixels, disparities, options in batches:
                    densify_batch(basis, pixels, disparities, **copy.copy(options))
                seconds[index].append((time.thread_time() - started) / len(items))
    return seconds


def lookup_seconds(
    items: list[tuple[StereoFrame, Array]],
    configs: list[ProcessorConfig],
    bases: list[Basis | None],
    repeats: int = 3,
) -> tuple[list[float], float]:
    """CPU seconds per frame of the front end's lookups (corners and fill), per configuration.

    ``sparse_lookups`` on each frame's SGBM map (made beforehand), the configurations in
    turns, the best of ``repeats``; and the SGBM map itself (the same matcher settings as
    the first configuration), the reference the lookups' cost is read against.
    """
    import cv2

    from pcainterp_stream.frontend.stereo import compute_disparity, sparse_lookups, to_grey8

    sgbm = configs[0].sgbm
    greys = [to_grey8(frame.left) for frame, _ in items]
    maps = [compute_disparity(frame.left, frame.right, sgbm) for frame, _ in items]
    stds = [
        prior_std_map(basis or Basis.default())
        if config.gftt.fill_placement == "prior_std"
        else None
        for config, basis in zip(configs, bases, strict=True)
    ]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        best = [np.inf] * len(configs)
        matching = np.inf
        for _ in range(repeats):
            started = time.process_time()
            for frame, _ in items:
                compute_disparity(frame.left, frame.right, sgbm)
            matching = min(matching, (time.process_time() - started) / len(items))
            for index, config in enumerate(configs):
                started = time.process_time()
                for grey, disparity in zip(greys, maps, strict=True):
                    sparse_lookups(
                        grey,
                        disparity,
                        config.gftt,
                        min_x=config.sgbm.valid_min_x,
                        prior_std=stds[index],
                    )
                best[index] = min(best[index], (time.process_time() - started) / len(items))
    finally:
        cv2.setNumThreads(threads)
    return best, matching


def _partition(measured: Any, image_size: tuple[int, int], grid: tuple[int, int]) -> Any:
    """What a stereo worker makes of a frame for an edge-aware prior (cells.Seeding)."""
    from pcainterp_stream.estimate.cells import Seeding

    return Seeding.along(measured.disparity_map, measured.pixels, image_size, grid)


def partition_seconds(items: list[tuple[StereoFrame, Array]], repeats: int = 3) -> float:
    """CPU seconds per frame of the stereo workers' seedings (the best of ``repeats``)."""
    config = ProcessorConfig()
    front_end = StereoFrontEnd(config.gftt, config.sgbm)
    measured = [front_end.measure(frame.left, frame.right) for frame, _ in items]
    camera, grid = items[0][0].camera, Basis.default().grid_size
    best = np.inf
    for _ in range(repeats):
        started = time.process_time()
        for one in measured:
            _partition(one, camera.image_size, grid)
        best = min(best, (time.process_time() - started) / len(items))
    return best


if __name__ == "__main__":
    harness.module_main(__doc__, "sparse_sharpness.py and nudge_checks.py")
