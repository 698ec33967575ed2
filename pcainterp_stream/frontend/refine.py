"""A half-resolution disparity map refined at full resolution near its value.

``SgbmConfig.refine_range`` (:mod:`.stereo`): SGBM matches the whole range at half
resolution; that map, its holes filled along the row and box-smoothed, warps the right image
(sub-pixel), and SGBM matches the left image against the warped one again at full
resolution over a small range around zero. The map is the warp plus that residual: SGBM's
smoothness and checks at full resolution, at a fraction of the whole range's cost. Pixels
without texture at half resolution are removed (the sky, blank walls), and pixels next to
the half-resolution map's holes or far from the guide are marked weak (:class:`Refined`).
:mod:`.stereo` passes in SGBM itself (:func:`refined_match`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import replace
from typing import Any, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]
FixedArray = npt.NDArray[np.int16]

BoolArray = npt.NDArray[np.bool_]

REFINE_SMOOTHING = 3
"""Side (px, at half resolution) of the box filter that smooths the half-resolution map
before it warps the right image (3 px: better than 1, 5 or 7 on real truth and on the
synthetic frames, with textureless pixels removed; docs/dense.md)."""

TEXTURELESS = 3.0
"""A pixel whose half-resolution neighbourhood (:data:`TEXTURE_SIDE` px square at half
resolution) has a mean |x-gradient| (3x3 Sobel of the 8-bit image: 8 for a ramp of one
grey level per px) below this is removed, as full-resolution SGBM's uniqueness check would
leave it: the sky and blank walls, where a small range's match is a guess. At half
resolution the image's noise is averaged out, so weak but real texture (a road) stays above
it (docs/dense.md)."""

TEXTURE_SIDE = 7
"""Side (px, at half resolution) of the box over which :data:`TEXTURELESS` averages."""

WEAK_HOLE_REACH = 2
"""A refined pixel within this many half-resolution px of a half-resolution hole is weak
(:class:`Refined`): occlusion edges and surfaces the half-resolution map missed, where the
guide may belong to the other surface."""

WEAK_RESIDUAL = 3.0
"""A refined pixel whose residual is at least this (px) away from the guide is weak: far
from the guide, towards the small range's ends, matches are less often right."""


def fill_rows(disparity: FloatArray) -> FloatArray:
    """Fill NaN with the nearest valid value to the left in the row (right where none).

    In the left view, the pixels SGBM leaves beside a nearer surface are mostly the
    background it hides from the right camera, which continues on their left. A row
    without any valid value becomes 0.
    """
    height, width = disparity.shape
    filled = np.array(disparity, np.float32)
    # the runs of missing values along the rows: +1 where one starts, -1 one past its end
    padded = np.zeros((height, width + 2), np.int8)
    np.logical_not(np.isfinite(filled), out=padded[:, 1:-1].view(bool))
    change = np.diff(padded, axis=1).ravel()
    starts = np.flatnonzero(change == 1)  # flat in the (H, W + 1) change image
    row = starts // (width + 1)
    first = starts - row * (width + 1)
    past = np.flatnonzero(change == -1) - row * (width + 1)
    row *= width
    flat = filled.ravel()
    # a run's value: the pixel before it, else the one after it, else 0
    source = np.where(first > 0, row + first - 1, row + past)
    none = (first == 0) & (past == width)
    source[none] = 0
    value = flat.take(source)
    value[none] = 0.0
    flat[padded[:, 1:-1].view(bool).ravel()] = np.repeat(value, past - first)
    return filled


def textureless(image: UInt8Array) -> BoolArray:
    """Where ``image`` (half resolution) has too little texture to match: :data:`TEXTURELESS`."""
    gradient = np.abs(np.asarray(cv2.Sobel(image, cv2.CV_16S, 1, 0, ksize=3), np.int16))
    mean = cv2.blur(gradient.astype(np.float32), (TEXTURE_SIDE, TEXTURE_SIDE))
    return np.asarray(mean < np.float32(TEXTURELESS), bool)


class Refined(NamedTuple):
    """A refined disparity map and where its values are weak.

    Attributes:
        disparity: (H, W) float32 disparity (px), NaN where removed.
        weak: (H, W) bool, True at valid pixels whose value is less sure than a matched
            pixel's (next to a half-resolution hole, or far from the guide): dense fusion
            widens their std (``DenseModel.weak_std``).
    """

    disparity: FloatArray
    weak: BoolArray


def _full_size(mask: BoolArray, height: int, width: int) -> BoolArray:
    """A half-resolution mask at full resolution (each pixel its 2x2 pixels)."""
    doubled = cv2.resize(mask.view(np.uint8), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    return np.asarray(doubled, np.uint8)[:height, :width].view(bool)


@functools.lru_cache(maxsize=8)
def _grid(height: int, width: int, lowest: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Read-only (H, W) float32 images of each pixel's row, its column, and ``lowest``."""
    rows = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
    columns = np.repeat(np.arange(width, dtype=np.float32)[None, :], height, axis=0)
    constant = np.full((height, width), np.float32(lowest))
    for image in (rows, columns, constant):
        image.flags.writeable = False
    return rows, columns, constant


def refine_disparity(
    left: UInt8Array,
    right: UInt8Array,
    coarse: FloatArray,
    residual: Callable[[UInt8Array, UInt8Array], FixedArray],
    *,
    halved_left: UInt8Array,
    reach: int,
    min_disparity: int,
    speckle_window_size: int,
    speckle_range: int,
) -> Refined:
    """Refine a half-resolution map at full resolution within +-``reach`` px of it.

    Args:
        left: (H, W) uint8 left image at full resolution.
        right: (H, W) uint8 right image.
        coarse: (ceil(H/2), ceil(W/2)) float32 disparity of the half-resolution pair, in
            half-resolution px, NaN where it has none.
        residual: SGBM of (left, warped right) over [-reach, reach), OpenCV's int16 output
            (16 x disparity; below -16 * reach where invalid), speckle filter off.
        halved_left: the left image at half resolution (the one ``coarse`` was matched on).
        reach: the residual range (px).
        min_disparity: smallest disparity of the whole range; smaller values are removed.
        speckle_window_size: SGBM's speckle filter's largest region (px), run on the
            whole map; 0: off.
        speckle_range: its largest disparity variation inside a region (px).

    Returns:
        The map (:class:`Refined`): float32 disparity (px), NaN where removed: the
        half-resolution map's holes and its textureless pixels (:data:`TEXTURELESS`; each
        half-resolution pixel its 2x2 full-resolution pixels), invalid residuals and those
        at the small range's ends (the match may lie beyond), values d > x (left of the
        right image) or below ``min_disparity``, and speckles; and its weak pixels.
    """
    height, width = left.shape
    guide = cv2.blur(fill_rows(coarse), (REFINE_SMOOTHING, REFINE_SMOOTHING))
    scale = np.float32(width / coarse.shape[1])
    shift = np.asarray(
        cv2.resize(guide, (width, height), interpolation=cv2.INTER_LINEAR), np.float32
    )
    shift *= scale
    coarse_holes = np.isnan(coarse)
    holes = _full_size(coarse_holes | textureless(halved_left), height, width)
    reach_side = 2 * WEAK_HOLE_REACH + 1
    near_holes = cv2.dilate(
        coarse_holes.view(np.uint8), np.ones((reach_side, reach_side), np.uint8)
    )
    weak = _full_size(near_holes.view(bool), height, width)
    # right image warped by the guide: pixel x of the warped image is right pixel x - shift
    rows, columns, lowest = _grid(height, width, min_disparity)
    map_x = np.subtract(columns, shift)
    warped = cv2.remap(right, map_x, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    fixed = residual(left, np.asarray(warped, np.uint8))
    # fixed / 16 + shift (the division is exact: one rounding, as in two steps)
    disparity = np.asarray(cv2.scaleAdd(fixed.astype(np.float32), 1.0 / 16.0, shift), np.float32)
    # kept (255): a residual inside the small range, not at its ends ...
    kept = np.asarray(cv2.inRange(fixed, (1 - reach) * 16, (reach - 2) * 16), np.uint8)
    # ... and a disparity in [min_disparity, x] (a larger one matches left of the right image)
    kept &= np.asarray(cv2.inRange(disparity, lowest, columns), np.uint8)
    removed = holes | (kept == 0)
    far = int(WEAK_RESIDUAL * 16)
    weak |= cv2.inRange(fixed, 1 - far, far - 1) == 0  # |residual| >= WEAK_RESIDUAL
    if speckle_window_size > 0:
        marker = (min_disparity - 1) * 16
        # 16 x disparity (+ 0 x disparity), exact, rounded half to even as np.rint
        sixteenths = np.asarray(
            cv2.addWeighted(disparity, 16.0, disparity, 0.0, 0.0, dtype=cv2.CV_16S), np.int16
        )
        sixteenths[removed] = marker
        cv2.filterSpeckles(sixteenths, marker, speckle_window_size, speckle_range * 16)
        removed |= sixteenths == marker
    disparity[removed] = np.nan
    weak &= ~removed
    return Refined(disparity, weak)


def halved(image: UInt8Array) -> UInt8Array:
    """Return ``image`` at half resolution (INTER_AREA, odd sizes rounded up)."""
    height, width = image.shape
    size = (-(-width // 2), -(-height // 2))
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), np.uint8)


def refined_match(
    left: UInt8Array,
    right: UInt8Array,
    config: Any,
    match: Callable[[UInt8Array, UInt8Array, Any, bool], FloatArray],
    matcher: Callable[[Any], Any],
) -> Refined:
    """``SgbmConfig.refine_range``: the whole range at half resolution, refined near it.

    ``config`` is the matcher's :class:`.stereo.SgbmConfig` (not imported here: stereo
    imports this module), ``match`` SGBM at the images' resolution for a configuration
    (NaN where invalid; the last argument pads the left band) and ``matcher`` the
    ``cv2.StereoSGBM`` of a configuration.
    """
    coarse_config = replace(config, downscale=2, refine_range=0, near_at_half=False)
    halved_left = halved(left)
    coarse = match(halved_left, halved(right), coarse_config.matched(), config.full_width)
    reach = config.refine_range
    residual_config = replace(
        config,
        min_disparity=-reach,
        num_disparities=2 * reach,
        speckle_window_size=0,
        full_width=False,
        near_at_half=False,
        refine_range=0,
    )

    def residual(image: UInt8Array, warped: UInt8Array) -> FixedArray:
        return np.asarray(matcher(residual_config).compute(image, warped), np.int16)

    return refine_disparity(
        left,
        right,
        coarse,
        residual,
        halved_left=halved_left,
        reach=reach,
        min_disparity=config.min_disparity,
        speckle_window_size=config.speckle_window_size,
        speckle_range=config.speckle_range,
    )
