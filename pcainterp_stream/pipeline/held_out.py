"""The held-out frames ``learn`` fits the prior on, measured as ``densify`` measures them.

A function of the log alone (:func:`measure_held_out`), so a cluster's worker runs it as well
as the process that learns (:mod:`~pcainterp_stream.pipeline.learn`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy.typing as npt

from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig, StereoFrontEnd
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline.common import _require_topics

__all__ = [
    "CALIBRATION_EVERY",
    "FIT_SEQUENCE_FRAMES",
    "HeldOutFrame",
    "MeasureOptions",
    "measure_held_out",
]


class MeasureOptions(Protocol):
    """What measuring needs of the learning options (``learn.LearnOptions`` has both)."""

    @property
    def gftt(self) -> GfttConfig:
        """The corner options."""
        ...

    @property
    def sgbm(self) -> SgbmConfig:
        """The matcher options."""
        ...


CALIBRATION_EVERY = 4
"""Every N-th held-out frame is densified to calibrate the std (``fitting.fit_std_scale``)."""


FIT_SEQUENCE_FRAMES = 16
"""Consecutive held-out frames measured per log (with --fit-logs: per fit log); they are the
fit's frames and the sequences of the temporal process-noise fit."""


@dataclass(frozen=True)
class HeldOutFrame:
    """One held-out frame measured as ``densify`` measures it.

    Attributes:
        pixels: (k, 2) float, (x, y) of the measurements (px).
        disparities: (k,) float, their disparities (px).
        image_size: (height, width) of the camera (px).
        focal_baseline: f*b of the camera (px*m).
        reference: (H, W) float32 SGBM map of a calibration frame (every
            :data:`CALIBRATION_EVERY`-th), else None.
    """

    pixels: npt.NDArray[Any]
    disparities: npt.NDArray[Any]
    image_size: tuple[int, int]
    focal_baseline: float
    reference: npt.NDArray[Any] | None


def measure_held_out(
    log: Path,
    first: int,
    options: MeasureOptions,
    pairing: PairingConfig,
    progress: Callable[[], None] | None = None,
) -> list[HeldOutFrame]:
    """Measure up to :data:`FIT_SEQUENCE_FRAMES` consecutive pairs of a log from ``first`` on.

    GFTT corners looked up in the SGBM map, as ``densify`` measures; a function of the log
    alone, so a cluster's worker runs it as well as this process.

    Args:
        log: the log.
        first: index of the first stereo pair to measure.
        options: the learning options (SGBM and GFTT settings).
        pairing: topics of the stereo pairs.
        progress: called after each frame.

    Returns:
        The frames, in log order.
    """
    front_end = StereoFrontEnd(options.gftt, options.sgbm)
    frames: list[HeldOutFrame] = []
    with open_log(log) as reader:
        if pairing.discover:  # the log's own pair (learn_pairing printed it)
            pairing = resolve_pairing(reader, pairing)
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        for frame in iter_stereo_frames(reader, pairing):
            if frame.index < first:
                continue
            if len(frames) >= FIT_SEQUENCE_FRAMES:
                break
            measured = front_end.measure(frame.left, frame.right)
            calibrates = (frame.index - first) % CALIBRATION_EVERY == 0
            frames.append(
                HeldOutFrame(
                    measured.pixels,
                    measured.disparities,
                    frame.camera.image_size,
                    frame.camera.focal_baseline,
                    measured.disparity_map if calibrates else None,
                )
            )
            if progress is not None:
                progress()
    return frames
