"""How narrow an image SGBM can match: OpenCV's matcher needs more columns than its range.

On a narrower pair OpenCV 5's SGBM fails with an absurd allocation or, in 3-way mode,
crashes the process; :class:`~.stereo.StereoFrontEnd` refuses such a pair with
:class:`ImageTooNarrowError` instead, ``densify`` names the widest range that fits
(:func:`fitting`) and ``evaluate`` matches its reference with it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, TypeVar

import cv2

from pcainterp_stream.errors import PcaInterpError

Config = TypeVar("Config")
"""A :class:`~.stereo.SgbmConfig` (not imported here: the stereo module imports this one)."""


class ImageTooNarrowError(PcaInterpError, ValueError):
    """A pair narrower than SGBM's disparity range (OpenCV's matcher would fail or crash).

    Attributes:
        width: the images' width (px) at the matching resolution.
        needed: the width that configuration needs there (px).
    """

    def __init__(self, width: int, needed: int, num_disparities: int) -> None:
        # 16 is SGBM's smallest range (and the refined matcher's +-8 px pass, whatever
        # --num-disparities): no smaller one to advise
        fix = (
            "pass a smaller --num-disparities"
            if num_disparities > 16
            else "no disparity range fits images this narrow (16 is the smallest)"
        )
        super().__init__(
            f"images {width} px wide (at the matching resolution) are narrower than the "
            f"{needed} px SGBM needs for {num_disparities} disparities; {fix}"
        )
        self.width = width
        self.needed = needed


def needed_width(config: Any) -> int:
    """The narrowest image (px, at the matching resolution) ``config`` matches.

    OpenCV's SGBM needs more columns than its range: 3-way (and HH4) one more than the
    largest disparity, the others half a block more; narrower images make it fail, or, in
    3-way mode, crash the process (measured with OpenCV 5.0, every mode and width).
    """
    largest = max(int(config.min_disparity), 0) + int(config.num_disparities)
    if config.mode.value in (cv2.STEREO_SGBM_MODE_SGBM_3WAY, cv2.STEREO_SGBM_MODE_HH4):
        return largest + 1
    return largest + int(config.block_size) // 2 + 1


def fitting(config: Config, width: int) -> Config | None:
    """Return ``config`` with the widest range images ``width`` px wide can be matched with.

    The range is a multiple of 16 and at most ``config``'s own; None when none fits.
    """
    settings: Any = config
    for count in range(settings.num_disparities, 0, -16):
        fits: Config = replace(settings, num_disparities=count)
        if narrowest_width(fits) <= width:
            return fits
    return None


def narrowest_width(config: Any) -> int:
    """Return the narrowest image (px, full resolution) the front end matches with ``config``.

    With ``full_width`` the padding gives SGBM its columns; at half resolution the range and
    the image are both halved; the refined matcher's bound is its +-range pass.
    """
    if config.refine_range and config.downscale == 1:
        reach = config.refine_range
        passes = (
            replace(
                config,
                min_disparity=-reach,
                num_disparities=2 * reach,
                refine_range=0,
                full_width=False,
            ),
            replace(config, downscale=2, refine_range=0),
        )
        return max(narrowest_width(one) for one in passes)
    matched = config.matched()
    needed = needed_width(matched)
    if config.full_width:  # the padding is the left band
        needed = max(needed - max(matched.band, 0), 1)
    # at the matching resolution the image's width is ceil(W / downscale)
    return int(config.downscale) * (needed - 1) + 1
