"""8-bit grey images for the stereo matcher, and the blank-image check.

:func:`to_grey8_pair` converts a pair as :mod:`.stereo` matches it; :func:`is_blank` tells
an image without texture to match (a right camera that dropped out, a capped lens, an
exposure at 0): SGBM resolves the ties of a uniform right image to disparity 0, which
would pass every lookup check as "far" (:class:`.stereo.StereoFrontEnd` measures nothing
on such a pair instead).
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend import levels

__all__ = ["BLANK_SPREAD", "is_blank", "to_grey8", "to_grey8_pair"]

UInt8Array = npt.NDArray[np.uint8]

BLANK_SPREAD = 2
"""An 8-bit grey image whose 1st to 99th percentile (on a 4x subsampled grid) spans at most
this many grey levels is blank (:func:`is_blank`). Measured on a 620x188 synthetic drive,
the left image kept and the right one replaced (4 frames): a right image spanning 0-2 levels
(all 0, any constant, 128 +- 0.5 noise, the image // 128) gave 3-153 lookups per frame of
which 90-100 % were more than 2 px off the true pair's map (a constant one: every lookup
exactly 0); one spanning 3 levels (the image // 64) 28-57 lookups, 60-85 % within 2 px;
6 levels (// 32) 41-56, 87-98 % within 2 px."""

# Percentile of a 16-bit image mapped to 255 when converting it to 8 bit (see to_grey8).
_UINT16_PERCENTILE = 99.9


def _check_image(image: npt.NDArray[Any], name: str) -> None:
    layout_ok = image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))
    if layout_ok and image.dtype in (np.uint8, np.uint16):
        return
    raise ValueError(
        f"{name} image has shape {image.shape} and dtype {image.dtype}; expected (H, W) "
        "uint8/uint16 grey or (H, W, 3) uint8/uint16 RGB"
    )


def _grey_of(image: npt.NDArray[Any]) -> npt.NDArray[Any]:
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    if image.ndim == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
    return image


def to_grey8_pair(left: npt.NDArray[Any], right: npt.NDArray[Any]) -> tuple[UInt8Array, UInt8Array]:
    """Convert a stereo pair to 8-bit grey, both images with the same intensity mapping.

    RGB (channel order R, G, B; for BGR the weights differ slightly, which does not matter
    for matching as both views get the same) is converted with ``cv2.COLOR_RGB2GRAY``.
    16-bit images are scaled linearly so that the 99.9th percentile of the pair (on a 4x
    subsampled grid, for speed) maps to 255, and clipped: ``>> 8`` would leave 12-bit
    cameras with 16 grey levels; a pair on a large offset (a thermal camera, a black level)
    is mapped from its 0.1st percentile instead of 0, the counts under it (a dead pixel at 0)
    clipped to 0, not mirrored. Both views share one scale, so matching
    costs are not biased by a per-image gain. Pairs outside normal levels are then adjusted
    (:mod:`.levels`: each step acts only outside them and notes it once): a right image whose
    levels clearly differ from the left's is mapped onto them, a dark pair is stretched.

    Args:
        left: (H, W) uint8/uint16 grey, (H, W, 1), or (H, W, 3) uint8/uint16 RGB left image.
        right: right image, same shape and dtype as ``left``.

    Returns:
        (left, right): two (H, W) uint8 grey images.

    Raises:
        ValueError: if the shapes or dtypes differ, or an image is not one of the above.
    """
    if left.shape != right.shape or left.dtype != right.dtype:
        raise ValueError(
            f"left image is {left.shape} {left.dtype} but right image is {right.shape} "
            f"{right.dtype}; pass a rectified pair of equal size and type"
        )
    _check_image(left, "left")
    grey_left = _grey_of(left)
    grey_right = _grey_of(right)
    if grey_left.dtype == np.uint8:
        pair = np.ascontiguousarray(grey_left), np.ascontiguousarray(grey_right)
    else:
        pair = _sixteen_to_eight(grey_left, grey_right)
    return levels.adjust_pair(*pair)  # unusual levels only (:mod:`.levels`)


def _sixteen_to_eight(
    grey_left: npt.NDArray[Any], grey_right: npt.NDArray[Any]
) -> tuple[UInt8Array, UInt8Array]:
    top = max(
        float(np.percentile(grey_left[::4, ::4], _UINT16_PERCENTILE)),
        float(np.percentile(grey_right[::4, ::4], _UINT16_PERCENTILE)),
        1.0,
    )
    floor = 0.0
    used = levels.sixteen_bit_range(grey_left, grey_right, top)
    if used is not None:
        floor, top = used
    scale = 255.0 / (top - floor)
    return _scaled(grey_left, floor, scale), _scaled(grey_right, floor, scale)


def _scaled(grey: npt.NDArray[Any], floor: float, scale: float) -> UInt8Array:
    """``(grey - floor) * scale`` to 8 bit, the counts under ``floor`` clipped to 0.

    ``cv2.convertScaleAbs`` takes the absolute value (a dead pixel at 0 would become 255):
    the pixels under the floor are set to 0 after it, in place: ~0.1 ms of CPU per KITTI-size
    pair (a clipped 16-bit copy made before it cost ~3 ms more, in allocation).
    """
    out = np.asarray(cv2.convertScaleAbs(grey, alpha=scale, beta=-floor * scale), np.uint8)
    if floor > 0.0:
        low: Any = math.ceil(floor)  # a scalar, which cv2's stubs do not list
        below = cv2.compare(grey, low, cv2.CMP_LT)  # 255 under the floor, else 0
        cv2.subtract(out, below, dst=out)
    return out


def to_grey8(image: npt.NDArray[Any]) -> UInt8Array:
    """Convert one image to 8-bit grey, as :func:`to_grey8_pair` does for a pair.

    Args:
        image: (H, W) uint8/uint16 grey, (H, W, 1), or (H, W, 3) uint8/uint16 RGB.

    Returns:
        (H, W) uint8 grey image.
    """
    return to_grey8_pair(image, image)[0]


def is_blank(grey: UInt8Array) -> bool:
    """Whether an 8-bit grey image is (nearly) uniform: nothing in it can be matched.

    Its 1st to 99th percentile, on a 4x subsampled grid (a few hot or saturated pixels do
    not count), spans at most :data:`BLANK_SPREAD` grey levels. ~0.1 ms on a KITTI image.
    """
    sample = np.ascontiguousarray(grey[::4, ::4]).reshape(-1)
    if not sample.size:
        return True
    counts = np.cumsum(np.bincount(sample, minlength=256))
    low = int(np.searchsorted(counts, 0.01 * sample.size, side="right"))
    high = int(np.searchsorted(counts, 0.99 * sample.size, side="left"))
    return high - low <= BLANK_SPREAD
