"""The held-out frames ``learn`` fits the prior on, measured as ``densify`` measures them.

A function of the log alone (:func:`measure_held_out`), so a cluster's worker runs it as well
as the process that learns (:mod:`~pcainterp_stream.pipeline.learn`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.adapt import FitCheck, HeldOut
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.frontend import levels
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.grey import to_grey8_pair
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
    "clipped_pixels",
    "measure_held_out",
    "rough_std_scales",
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


def clipped_pixels(
    left: npt.NDArray[Any], right: npt.NDArray[Any], disparity: npt.NDArray[Any]
) -> npt.NDArray[np.bool_] | None:
    """The pixels a fit check leaves out of an over-exposed pair (None: none, any other pair).

    The pair as recorded, converted as the matcher converts it (:func:`.grey.to_grey8_pair`),
    then :func:`.levels.clipped_pixels`: the left pixels at 255 in either view, only when
    more than half of an image is at 255 (the over-exposure note's trigger). Used by
    densify's fit check (:mod:`.processor`) and learn's held-out frames alike.
    """
    return levels.clipped_pixels(*to_grey8_pair(left, right), disparity)


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
    *,
    sample_check: bool = True,
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
        sample_check: sample each frame's held-out SGBM pixels (``check``), which only the
            kernel choice of a merge into the built-in indoor basis scores
            (:func:`choose_kernel`); False: ``check`` is None (review 58c C4). A cluster's
            workers are called with the default.

    Returns:
        The frames, in log order.
    """
    front_end = StereoFrontEnd(options.gftt, options.sgbm)
    frames: list[HeldOutFrame] = []
    with open_log(log) as reader:
        # the log's own pair, or the named images with their own camera infos (learn_pairing
        # printed it)
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
                    HeldOut.of(
                        measured.disparity_map,
                        measured.pixels,
                        measured.disparities,
                        clipped_pixels(frame.left, frame.right, measured.disparity_map),
                    )
                    if sample_check
                    else None,
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
        checks.append(frame.check.score(result.disparity, result.min_disparity))
    return FitCheck.combine(checks)


def rough_std_scales(
    basis: Basis, frames: Sequence[HeldOutFrame], fitted: dict[str, Any], *, robust: str
) -> dict[str, float]:
    """The rougher kernel's std scales by ``densify``'s rule (``rougher.sgbm_std_scale``).

    The larger of the 95.4 % band's and the Gaussian likelihood's scale
    (``rougher.LIKELIHOOD``: the band's alone made NLL 0.5-0.7 nats worse for this kernel),
    on the calibration frames' SGBM maps of the camera most of them have: ``std_scale``
    plain, ``innovation_std_scale`` per frame (what ``densify`` uses by default).
    """
    from pcainterp_stream.estimate.adapt import Measured
    from pcainterp_stream.estimate.rougher import sgbm_std_scale

    calibration = [frame for frame in frames if frame.reference is not None]
    cameras = Counter((frame.image_size, frame.focal_baseline) for frame in calibration)
    if not cameras:
        return {}
    (size, fb), _ = cameras.most_common(1)[0]
    used = [
        Measured(frame.pixels, frame.disparities, frame.reference)
        for frame in calibration
        if frame.reference is not None and (frame.image_size, frame.focal_baseline) == (size, fb)
    ]
    options = {"local_prior": LocalPrior.from_meta(fitted["local"]), "sigma": fitted["sigma"]}
    return {
        name: sgbm_std_scale(
            basis,
            used,
            options,
            image_size=size,
            focal_baseline=fb,
            robust=robust,
            per_frame=per_frame,
        )
        for name, per_frame in (("std_scale", False), ("innovation_std_scale", True))
    }


def _band_matched(frames: Sequence[HeldOutFrame]) -> bool:
    """Return whether ``densify --stereo-downscale auto`` matches SGBM's left band there.

    On the camera most of the frames have.
    """
    from pcainterp_stream.frontend.sgbm_resolution import full_resolution

    cameras = Counter((frame.image_size, frame.focal_baseline) for frame in frames)
    if not cameras:
        return False
    ((height, width), fb), _ = cameras.most_common(1)[0]
    return full_resolution(fb, width, height)


def choose_kernel(
    basis: Basis,
    frames: list[HeldOutFrame],
    kept: dict[str, Any],
    fit_rough: Callable[[], dict[str, Any]],
    robust: str,
) -> dict[str, Any]:
    """Return the fit (``kept``: the indoor basis's kernel, or the rough one) that errs less.

    ``densify``'s fit check's rule for the built-in indoor basis with
    :data:`~.adapt.ROUGH_KERNEL` (``rougher.try_rougher``), on the held-out frames:

    - not tried (``fit_rough`` not called) when the held-out SGBM pixels leave SGBM's
      unmatched left band out (``rougher.band_left_out``) and ``densify`` leaves it empty
      on this camera too (``--stereo-downscale auto`` at half resolution): the kernel
      would extrapolate there unchecked. ``learn`` matches the held-out frames without the
      band (``SgbmConfig().full_width`` is False); on a camera ``densify`` matches at full
      resolution, its band included (f*b below 90 px*m: the indoor cameras this kernel is
      for), the band holds points when the basis is used, so the choice is made on the
      pixels right of it;
    - else both fits are scored at the held-out frames' SGBM pixels (:func:`score_fit`)
      and the rough one taken when it errs less, its std scales refitted by ``densify``'s
      rule for it (:func:`rough_std_scales`);
    - no ``FITS_BELOW`` gate: ``densify`` tries the kernel only when the indoor basis
      fits badly, to spare its warm-up a second check where there is little to gain;
      ``learn`` pays once, offline, and its fine-tuned basis fits its own logs better
      already (a synthetic room learned from 30 frames: 0.48x linear, and still 9 % less
      error against the truth on its next 10 frames with this kernel).

    The choice is printed (a ``prior:`` line worded as ``densify``'s) and recorded as
    ``local_choice``, with the first column scored.
    """
    from pcainterp_stream.estimate.adapt import ROUGH_KERNEL
    from pcainterp_stream.estimate.rougher import band_left_out, compared, rough_kernel_words

    indoor = score_fit(basis, frames, kept, robust=robust)

    def kernel(fit: dict[str, Any]) -> str:
        local = fit["local"]
        return f"{local['kernel']}, {local['length_scale']:g} px, {local['variance']:.3g} px^2"

    own = f"the built-in indoor basis's own kernel ({kernel(kept)})"
    line = f"prior: the fine-tuned indoor basis with {rough_kernel_words(ROUGH_KERNEL)}"
    left_out = band_left_out(indoor.first_column) if indoor.frames else None
    if left_out is not None and _band_matched(frames):
        left_out = None  # densify matches the band on this camera: points will lie there
    rough: dict[str, Any] | None = None
    check: FitCheck | None = None
    scales: dict[str, float] = {}
    if not indoor.frames:
        line += f": not tried: no held-out frame had SGBM pixels to score it on; {own} kept"
    elif left_out is not None:
        line += f": {left_out}; {own} kept"
    else:
        rough = fit_rough()
        scales = rough_std_scales(basis, frames, rough, robust=robust)
        rough |= scales
        check = score_fit(basis, frames, rough, robust=robust)
    taken = check is not None and check.frames > 0 and check.prior < indoor.prior
    if check is not None:
        where = "the held-out frames' SGBM pixels"
        line += f" {check.describe(where)}; {compared(check, indoor, taken, own)}"
    if taken and scales:
        line += (
            f"; its std scale x{scales['innovation_std_scale']:.2f} per frame, refitted on the "
            "held-out frames' SGBM maps"
        )
    _echo(line)
    fitted = rough if taken and rough is not None else kept
    fitted["local_kept_from"] = (
        "adapt.ROUGH_KERNEL, densify's rougher kernel for the indoor basis (learn, held out)"
        if fitted is rough
        else "the fine-tuned basis (learn --with-synthetic)"
    )
    fits = (
        ("indoor", kept, indoor, "fitting.fit_std_scale: 95.4 % inside +-2 std"),
        ("rough", rough, check, "rougher.sgbm_std_scale: the larger of band and likelihood"),
    )
    fitted["local_choice"] = {
        "chosen": "rough" if fitted is rough else "indoor",
        "tried": rough is not None,
        "rule": (
            "densify's: the lower mean |d - SGBM| at the held-out frames' SGBM pixels; "
            "not tried when they leave SGBM's left band (columns < 16) out and densify "
            "matches this camera at half resolution (its band empty)"
        ),
        "first_column": indoor.first_column if indoor.frames else None,
        "frames": indoor.frames,
        "pixels": indoor.pixels,
        "linear_px": indoor.linear if indoor.frames else None,
        "kernels": {
            name: {
                "local": fit["local"],
                "held_out_px": score.prior if score is not None and score.frames else None,
                "std_scale": fit.get("std_scale"),
                "innovation_std_scale": fit.get("innovation_std_scale"),
                "std_scale_rule": rule,
            }
            for name, fit, score, rule in fits
            if fit is not None
        },
    }
    return fitted
