"""A half-resolution disparity map refined at full resolution near its value.

``SgbmConfig.refine_range`` (:mod:`.stereo`): SGBM matches the whole range at half
resolution; that map, its holes filled along the row and box-smoothed, warps the right image
(sub-pixel), and SGBM matches the left image against the warped one again at full
resolution over a small range around zero. The map is the warp plus that residual: SGBM's
smoothness and checks at full resolution, at a fraction of the whole range's cost. The
matcher itself stays in :mod:`.stereo`; this module does the warp and the residual's
bookkeeping, given a function that runs the residual match.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]
FixedArray = npt.NDArray[np.int16]

REFINE_SMOOTHING = 5
"""Side (px, at half resolution) of the box filter that smooths the half-resolution map
before it warps the right image (3-9 px alike on real truth; docs/dense.md)."""


def fill_rows(disparity: FloatArray) -> FloatArray:
    """Fill NaN with the nearest valid value to the left in the row (right where none).

    In the left view, the pixels SGBM leaves beside a nearer surface are mostly the
    background it hides from the right camera, which continues on their left. A row
    without any valid value becomes 0.
    """
    height, width = disparity.shape
    valid = np.isfinite(disparity)
    columns = np.arange(width)
    # nearest valid column at or left of each pixel, and at or right of it (width: none)
    seen = np.where(valid, columns, -1)
    np.maximum.accumulate(seen, axis=1, out=seen)
    left = np.where(seen < 0, width, seen)
    right = np.where(valid, columns, width)
    right = np.minimum.accumulate(right[:, ::-1], axis=1)[:, ::-1]
    padded = np.full((height, width + 1), np.nan, np.float32)
    padded[:, :width] = disparity
    filled = np.take_along_axis(padded, left, 1)
    missing = np.isnan(filled)
    filled[missing] = np.take_along_axis(padded, right, 1)[missing]
    filled[np.isnan(filled)] = 0.0
    return filled


def refine_disparity(
    left: UInt8Array,
    right: UInt8Array,
    coarse: FloatArray,
    residual: Callable[[UInt8Array, UInt8Array], FixedArray],
    *,
    reach: int,
    min_disparity: int,
    speckle_window_size: int,
    speckle_range: int,
) -> FloatArray:
    """Refine a half-resolution map at full resolution within +-``reach`` px of it.

    Args:
        left: (H, W) uint8 left image at full resolution.
        right: (H, W) uint8 right image.
        coarse: (ceil(H/2), ceil(W/2)) float32 disparity of the half-resolution pair, in
            half-resolution px, NaN where it has none.
        residual: SGBM of (left, warped right) over [-reach, reach), OpenCV's int16 output
            (16 x disparity; below -16 * reach where invalid), speckle filter off.
        reach: the residual range (px).
        min_disparity: smallest disparity of the whole range; smaller values are removed.
        speckle_window_size: SGBM's speckle filter's largest region (px), run on the
            whole map; 0: off.
        speckle_range: its largest disparity variation inside a region (px).

    Returns:
        (H, W) float32 disparity (px), NaN where removed: the half-resolution map's holes
        (each hole pixel its 2x2 full-resolution pixels), invalid residuals and those at
        the small range's ends (the match may lie beyond), values d > x (left of the right
        image) or below ``min_disparity``, and speckles.
    """
    height, width = left.shape
    guide = cv2.blur(fill_rows(coarse), (REFINE_SMOOTHING, REFINE_SMOOTHING))
    scale = np.float32(width / coarse.shape[1])
    shift = np.asarray(cv2.resize(guide, (width, height), interpolation=cv2.INTER_LINEAR))
    shift = shift.astype(np.float32) * scale
    holes = np.isnan(coarse).repeat(2, axis=0).repeat(2, axis=1)[:height, :width]
    # right image warped by the guide: pixel x of the warped image is right pixel x - shift
    map_x = np.arange(width, dtype=np.float32)[None, :] - shift
    map_y = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
    warped = cv2.remap(right, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    fixed = residual(left, np.asarray(warped, np.uint8))
    disparity = fixed.astype(np.float32)
    disparity *= np.float32(1.0 / 16.0)
    disparity += shift
    removed = holes | (fixed < (1 - reach) * 16) | (fixed > (reach - 2) * 16)
    columns = np.arange(width, dtype=np.float32)
    removed |= (disparity > columns) | (disparity < min_disparity)
    if speckle_window_size > 0:
        marker = (min_disparity - 1) * 16
        sixteenths = np.rint(disparity * 16.0).astype(np.int16)
        sixteenths[removed] = marker
        cv2.filterSpeckles(sixteenths, marker, speckle_window_size, speckle_range * 16)
        removed |= sixteenths == marker
    disparity[removed] = np.nan
    return disparity
