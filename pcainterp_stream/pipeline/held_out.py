"""The held-out frames ``learn`` fits the prior on, measured as ``densify`` measures them.

A function of the log alone (:func:`measure_held_out`), so a cluster's worker runs it as well
as the process that learns (:mod:`~pcainterp_stream.pipeline.learn`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy.typing as npt

from pcainterp_stream.estimate.adapt import FitCheck, HeldOut
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig, StereoFrontEnd
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline.common import _echo, _require_topics

__all__ = [
    "CALIBRATION_EVERY",
    "FIT_SEQUENCE_FRAMES",
    "HeldOutFrame",
    "MeasureOptions",
    "choose_kernel",
    "measure_held_out",
    "score_fit",
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
        check: the frame's held-out SGBM pixels away from the measurements (every frame,
            as ``densify``'s fit check holds them out: :class:`~.adapt.HeldOut`), what
            :func:`score_fit` scores a fitted prior on; None: not sampled.
    """

    pixels: npt.NDArray[Any]
    disparities: npt.NDArray[Any]
    image_size: tuple[int, int]
    focal_baseline: float
    reference: npt.NDArray[Any] | None
    check: HeldOut | None = None


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
                    HeldOut.of(measured.disparity_map, measured.pixels, measured.disparities),
                )
            )
            if progress is not None:
                progress()
    return frames


def score_fit(
    basis: Basis, frames: Sequence[HeldOutFrame], fitted: dict[str, Any], *, robust: str
) -> FitCheck:
    """Score a fitted prior (``meta["prior"]``) on the held-out frames' SGBM pixels.

    Each frame is densified from its measurements with the fitted kernel and sigma (as the
    fit's calibration frames are) and scored at its held-out SGBM pixels against linear
    and nearest interpolation of the same measurements, as ``densify``'s fit check scores.
    """
    from pcainterp_stream.estimate.estimator import densify

    local = LocalPrior.from_meta(fitted["local"]) if fitted.get("local") else None
    sigma = float(fitted["sigma"] if local is not None else fitted["plain_sigma"])
    checks = []
    for frame in frames:
        if frame.check is None or frame.check.flat.size == 0:
            continue
        result = densify(
            basis,
            frame.pixels,
            frame.disparities,
            sigma=sigma,
            local_prior=local,
            robust=robust,
            uncertainty="none",
            image_size=frame.image_size,
            focal_baseline=frame.focal_baseline,
            zero_is_match=True,
        )
        checks.append(frame.check.score(result.disparity))
    return FitCheck.combine(checks)


def choose_kernel(
    basis: Basis,
    frames: list[HeldOutFrame],
    kept: dict[str, Any],
    rough: dict[str, Any],
    robust: str,
) -> dict[str, Any]:
    """Return the fit (``kept``: the indoor basis's kernel, or ``rough``) that errs less.

    Both are scored at the held-out frames' SGBM pixels (:func:`score_fit`, as
    ``densify``'s fit check scores); the indoor basis's kernel stays on a tie or when
    nothing could be scored. The choice is printed and recorded as ``local_choice``.
    """
    checks = {"indoor": score_fit(basis, frames, kept, robust=robust)}
    checks["rough"] = score_fit(basis, frames, rough, robust=robust)
    scored = all(check.frames for check in checks.values())
    chosen = "rough" if scored and checks["rough"].prior < checks["indoor"].prior else "indoor"
    fitted = rough if chosen == "rough" else kept

    def kernel(fit: dict[str, Any]) -> str:
        local = fit["local"]
        return f"{local['kernel']}, {local['length_scale']:g} px, {local['variance']:.3g} px^2"

    names = {
        "indoor": f"the built-in indoor basis's own kernel ({kernel(kept)})",
        "rough": f"densify's rougher kernel for it ({kernel(rough)})",
    }
    other = "indoor" if chosen == "rough" else "rough"
    if scored:
        check, against = checks[chosen], checks[other]
        digits = 2 if f"{check.prior:.2f}" != f"{against.prior:.2f}" else 4
        why = (
            f"{check.prior:.{digits}f} px against {against.prior:.{digits}f} with "
            f"{names[other].split(' (')[0]} on the held-out frames' SGBM pixels "
            f"({check.ratio:.2f}x linear; {check.frames} frames)"
        )
    else:
        why = "no held-out frame had SGBM pixels to score the two on"
    _echo(f"prior: local kernel {names[chosen]}: {why}")
    fitted["local_kept_from"] = (
        "adapt.ROUGH_KERNEL, densify's rougher kernel for the indoor basis (learn, held out)"
        if chosen == "rough"
        else "the fine-tuned basis (learn --with-synthetic)"
    )
    fitted["local_choice"] = {
        "chosen": chosen,
        "rule": "the lower mean |d - SGBM| at the held-out frames' SGBM pixels",
        "frames": checks[chosen].frames,
        "pixels": checks[chosen].pixels,
        "linear_px": checks[chosen].linear if scored else None,
        "kernels": {
            name: {
                "local": fit["local"],
                "held_out_px": checks[name].prior if scored else None,
                "std_scale": fit.get("std_scale"),
                "innovation_std_scale": fit.get("innovation_std_scale"),
            }
            for name, fit in (("indoor", kept), ("rough", rough))
        },
    }
    return fitted
