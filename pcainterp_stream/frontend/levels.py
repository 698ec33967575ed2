"""Grey levels outside the normal: a 16-bit offset, dark images, a left/right mismatch.

:func:`.grey.to_grey8_pair` calls these; each acts only when the pair is outside the levels
a well-exposed camera gives, so a normal log is converted exactly as before, and says so
once per process (:func:`note_once`, on stderr, prefixed ``note:``) when it acts.

* :func:`sixteen_bit_range`: a 16-bit pair whose darkest used level (0.1st percentile) is
  above :data:`FLOOR_SHARE` of its brightest (99.9th) is mapped from that floor, not from 0:
  a thermal camera or a large black level (300 counts of signal at 30000) kept 2-16 of 256
  grey levels before and was judged blank.
* :func:`stretch_dark`: an 8-bit pair whose 99.9th percentile is under :data:`DARK_TOP` is
  stretched linearly (one mapping for both views) to 0..255: the front end's contrast
  thresholds are absolute.
* :func:`match_right_levels`: a right image whose grey levels differ from the left's by more
  than :data:`MISMATCH_LEVELS` (median over five percentiles) has its histogram mapped onto
  the left's (gain, offset, gamma, per-camera auto-exposure).
* :func:`saturation_share`: the share of the pair at 255; :func:`over_exposed_share` leaves
  out a blank image (a flat 16-bit pair scaled to all 255 is blank, not over-exposed) for
  densify's over-exposure note.
* :func:`clipped_pixels`: on an over-exposed pair only (the note's trigger), the left pixels
  at 255 in either view, which the fit check leaves out: SGBM's values there are streaks
  (:func:`pcainterp_stream.pipeline.held_out.clipped_pixels` of the pair as recorded).
"""

from __future__ import annotations

import sys
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "DARK_TOP",
    "FLOOR_SHARE",
    "MISMATCH_LEVELS",
    "SATURATED_SHARE",
    "adjust_pair",
    "clipped_pixels",
    "match_right_levels",
    "note_once",
    "over_exposed_share",
    "saturation_share",
    "sixteen_bit_range",
    "stretch_dark",
]

UInt8Array = npt.NDArray[np.uint8]

FLOOR_SHARE = 0.1
"""A 16-bit pair whose 0.1st percentile is above this share of its 99.9th is mapped from
that floor (scaling from 0 would waste more than this share of the 256 grey levels). A
camera with a small black level (64 of 4095) is far below it and is converted as before."""

MIN_RANGE_16 = 64
"""The floor mapping needs this many counts between the pair's floor and top (a narrower
range is mostly noise: it is converted as before)."""

DARK_TOP = 96
"""An 8-bit pair whose 99.9th percentile is under this grey level is stretched. The real logs
measured (KITTI depth, raw and odometry drives, EuRoC, a fisheye pair: 165 pairs) all had a
99.9th percentile of 255, the synthetic scenes 218-229; a 0..40 image has 40."""

MIN_DARK_RANGE = 8
"""A dark pair is stretched only when its used range spans at least this many levels."""

MISMATCH_LEVELS = 15.0
"""The right image's levels are mapped onto the left's when the median, over the 10th, 25th,
50th, 75th and 90th percentiles, of their differences exceeds this many grey levels. The real
logs' natural left/right difference is at most 7 levels (KITTI odometry, 51 pairs; KITTI
raw 6, EuRoC 1, the synthetic scenes 0-1): twice that leaves a margin."""

SATURATED_SHARE = 0.5
"""A pair with more than this share of one image at 255 is noted as over-exposed (a fisheye
pair's white border outside its image circle: 39 %; KITTI at most 11 %)."""

_MATCH_QUANTILES = np.array([10.0, 25.0, 50.0, 75.0, 90.0])
_DARK_QUANTILES = np.array([0.1, 99.9])
_LUT_QUANTILES = np.linspace(0.5, 99.5, 67)
_said: set[str] = set()


def note_once(kind: str, text: str) -> None:
    """Write ``note: text`` on stderr the first time ``kind`` is noted in this process."""
    if kind in _said:
        return
    _said.add(kind)
    sys.stderr.write(f"note: {text}\n")


def _sample(grey: npt.NDArray[Any]) -> npt.NDArray[Any]:
    return np.ascontiguousarray(grey[::4, ::4]).reshape(-1)


def _counts(*samples: npt.NDArray[Any]) -> npt.NDArray[np.int64]:
    """Cumulative histogram of 8-bit samples (256 bins)."""
    hist = sum(np.bincount(sample, minlength=256) for sample in samples)
    return np.cumsum(np.asarray(hist, np.int64))


def _levels_at(counts: npt.NDArray[np.int64], percents: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """The grey levels at these percentiles of a cumulative histogram.

    No interpolation: within a level of ``np.percentile``, and much faster.
    """
    ranks = np.asarray(percents, np.float64) / 100.0 * max(int(counts[-1]) - 1, 0)
    return np.searchsorted(counts, ranks, side="right").astype(np.float64)


def _is_flat(sample: npt.NDArray[Any], levels: float) -> bool:
    if not sample.size:
        return True
    if sample.dtype == np.uint8:
        low, high = _levels_at(_counts(sample), np.array([1.0, 99.0]))
    else:
        low, high = np.percentile(sample, [1.0, 99.0])
    return bool(high - low <= levels)


def sixteen_bit_range(
    grey_left: npt.NDArray[Any], grey_right: npt.NDArray[Any], top: float
) -> tuple[float, float] | None:
    """Return (floor, top) counts to map to 0..255 when the pair sits on an offset, else None.

    ``top`` is the pair's 99.9th percentile (as :func:`.grey.to_grey8_pair` measured it).
    """
    samples = np.concatenate([_sample(grey_left), _sample(grey_right)])
    floor = float(np.percentile(samples, 0.1))
    if floor <= FLOOR_SHARE * top or top - floor < MIN_RANGE_16:
        return None
    note_once(
        "floor16",
        f"16-bit images use counts {floor:.0f}..{top:.0f} only (an offset or black level): "
        "mapped from that range to 8 bit, not from 0",
    )
    return floor, top


def stretch_dark(
    left: UInt8Array, right: UInt8Array, samples: tuple[UInt8Array, UInt8Array] | None = None
) -> tuple[UInt8Array, UInt8Array]:
    """Stretch a dark 8-bit pair (99.9th percentile under :data:`DARK_TOP`) to 0..255.

    One linear mapping for both views, the levels under the pair's 0.1st percentile clipped
    to 0 (a black pixel in a 10..40 pair is 0, not mirrored to 85); a pair that is not dark,
    spans fewer than :data:`MIN_DARK_RANGE` levels, or has a blank image, is returned as is.
    ``samples``: the two images' 4x subsampled pixels when already taken.
    """
    sample_left, sample_right = samples or (_sample(left), _sample(right))
    if not sample_left.size:
        return left, right
    low, top = (float(v) for v in _levels_at(_counts(sample_left, sample_right), _DARK_QUANTILES))
    if top >= DARK_TOP or top - low < MIN_DARK_RANGE:
        return left, right
    if _is_flat(sample_left, 2) or _is_flat(sample_right, 2):
        return left, right
    scale = 255.0 / (top - low)
    note_once(
        "dark",
        f"dark images (grey levels {low:.0f}..{top:.0f} of 255): stretched to 0..255, "
        "one mapping for both views",
    )
    # convertScaleAbs mirrors the levels under ``low`` (a whole level): clip them to it first,
    # in a lookup table (the same values, one pass per image)
    clipped = np.maximum(np.arange(256, dtype=np.uint8), np.uint8(low))
    lut = np.asarray(cv2.convertScaleAbs(clipped, alpha=scale, beta=-low * scale), np.uint8)
    return np.asarray(cv2.LUT(left, lut), np.uint8), np.asarray(cv2.LUT(right, lut), np.uint8)


def level_difference(sample_left: UInt8Array, sample_right: UInt8Array) -> float:
    """Median over the 10/25/50/75/90th percentiles of |left - right| (grey levels)."""
    if not sample_left.size or not sample_right.size:
        return 0.0
    ql = _levels_at(_counts(sample_left), _MATCH_QUANTILES)
    qr = _levels_at(_counts(sample_right), _MATCH_QUANTILES)
    return float(np.median(np.abs(ql - qr)))


def match_right_levels(
    left: UInt8Array, right: UInt8Array, samples: tuple[UInt8Array, UInt8Array] | None = None
) -> UInt8Array:
    """Map the right image's grey levels onto the left's when they differ clearly.

    Histogram matching by percentiles (a lookup table through 67 matched percentiles),
    which undoes a gain, offset or gamma difference; a right image within
    :data:`MISMATCH_LEVELS` of the left, or a blank image, is returned as is.
    """
    sample_left, sample_right = samples or (_sample(left), _sample(right))
    difference = level_difference(sample_left, sample_right)
    if difference <= MISMATCH_LEVELS:
        return right
    if _is_flat(sample_left, 2) or _is_flat(sample_right, 2):
        return right
    ql = np.percentile(sample_left, _LUT_QUANTILES)
    qr = np.percentile(sample_right, _LUT_QUANTILES)
    qr = np.maximum.accumulate(qr + np.arange(qr.size) * 1e-6)  # strictly increasing for interp
    lut = np.clip(np.round(np.interp(np.arange(256), qr, ql)), 0, 255).astype(np.uint8)
    note_once(
        "mismatch",
        f"the right images' grey levels differ from the left's (by {difference:.0f} levels "
        "over their percentiles: a gain, exposure or gamma mismatch): the right ones are "
        "mapped onto the left's levels before matching",
    )
    return np.asarray(cv2.LUT(right, lut), np.uint8)


def saturation_share(sample_left: UInt8Array, sample_right: UInt8Array) -> float:
    """The larger share of the two images' (4x subsampled) pixels at 255."""
    shares = [
        float(np.count_nonzero(s == 255)) / s.size if s.size else 0.0
        for s in (sample_left, sample_right)
    ]
    return max(shares)


def over_exposed_share(sample_left: UInt8Array, sample_right: UInt8Array) -> float:
    """:func:`saturation_share` of the images that are not blank (0 when both are).

    A blank image (its 1st to 99th percentile within 2 levels: a capped or dropped-out
    camera, a flat 16-bit pair that the 8-bit scale put at 255) is no exposure to judge:
    the front end measures nothing in its pair (:func:`.grey.is_blank`) and says so.
    """
    kept = [s for s in (sample_left, sample_right) if not _is_flat(s, 2)]
    empty = np.zeros(0, np.uint8)
    return saturation_share(kept[0], kept[-1]) if kept else saturation_share(empty, empty)


def _normal(sample_left: UInt8Array, sample_right: UInt8Array) -> bool:
    """Whether no step of :func:`adjust_pair` would act: one histogram of each image.

    The same tests as the steps' own first ones (levels within :data:`MISMATCH_LEVELS`, the
    pair's 99.9th percentile at or above :data:`DARK_TOP`, at most :data:`SATURATED_SHARE`
    at 255), so every pair of normal levels (every frame of the real logs) costs one
    histogram per image instead of one per step.
    """
    if not sample_left.size or not sample_right.size:
        return False
    counts_left, counts_right = _counts(sample_left), _counts(sample_right)
    ql = _levels_at(counts_left, _MATCH_QUANTILES)
    qr = _levels_at(counts_right, _MATCH_QUANTILES)
    if float(np.median(np.abs(ql - qr))) > MISMATCH_LEVELS:
        return False
    top = _levels_at(counts_left + counts_right, _DARK_QUANTILES[1:])[0]
    if top < DARK_TOP:
        return False
    at_255 = [
        float(counts[-1] - counts[-2]) / float(counts[-1]) for counts in (counts_left, counts_right)
    ]
    return max(at_255) <= SATURATED_SHARE


def adjust_pair(left: UInt8Array, right: UInt8Array) -> tuple[UInt8Array, UInt8Array]:
    """Undo a left/right level mismatch, stretch a dark pair, note over-exposure.

    A pair within normal levels is returned as is. Over-exposure is judged on the images
    that are not blank (:func:`over_exposed_share`).
    """
    samples = _sample(left), _sample(right)
    if _normal(*samples):
        return left, right
    if left is not right:
        matched = match_right_levels(left, right, samples)
        if matched is not right:
            right = matched
            samples = samples[0], _sample(right)
    stretched = stretch_dark(left, right, samples)
    if stretched[0] is not left:
        left, right = stretched
        samples = _sample(left), _sample(right)
    share = over_exposed_share(*samples)
    if share > SATURATED_SHARE:
        note_once(
            "saturated",
            f"over-exposed images: {100 * share:.0f} % of an image is at 255; depth there is "
            "the prior's guess, and the fit check and the result cannot be trusted there",
        )
    return left, right


def clipped_pixels(
    grey_left: UInt8Array, grey_right: UInt8Array, disparity: npt.NDArray[Any]
) -> npt.NDArray[np.bool_] | None:
    """The left pixels clipped at 255 in either view, on an over-exposed pair only, else None.

    Over-exposed is the note's trigger (more than :data:`SATURATED_SHARE` of an image that is
    not blank at 255, :func:`over_exposed_share`);
    any other pair gives None, so a normal log's fit check (a fisheye's white border: 39 %)
    is untouched. A left pixel is clipped when it is at 255 or its match in the right image
    (``x - disparity``, rounded; the same column where the disparity is not finite) is:
    SGBM's values there are streaks (bug hunt 16F F1), which the fit check must not score a
    basis against.

    Args:
        grey_left: the pair's left image as the matcher takes it (:func:`.grey.to_grey8_pair`).
        grey_right: its right image, alike.
        disparity: (H, W) left disparity map (px), NaN or <= 0 where invalid.
    """
    if over_exposed_share(_sample(grey_left), _sample(grey_right)) <= SATURATED_SHARE:
        return None
    height, width = grey_left.shape[:2]
    shift = np.nan_to_num(np.asarray(disparity, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    columns = np.arange(width)[None, :] - np.rint(np.maximum(shift, 0.0)).astype(np.intp)
    columns = np.clip(columns, 0, width - 1)
    rows = np.arange(height)[:, None]
    return np.asarray((grey_left == 255) | (grey_right[rows, columns] == 255), np.bool_)
