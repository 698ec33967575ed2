"""Which resolution ``densify``'s SGBM matches a camera at (``--stereo-downscale auto``).

Half resolution (``downscale=2``) costs ~1/4 of the full-resolution match. On a KITTI-like
camera (f*b ~390 px*m, disparities of tens of px) its dense map is as good: the error is set
by the interpolation. Its lookups are biased by +0.1-0.3 px (SGBM's sub-pixel steps at half
resolution, doubled by the upsampling), which on a camera whose disparities are a few px (a
VI-sensor or a depth camera indoors) is 5-30 % of a disparity: the dense map's error there was
up to 1.9x full resolution's and fewer pixels inside +-2 sigma (docs/results.md). The rule
(:func:`by_camera`): full resolution when the camera's f*b is below
:data:`~pcainterp_stream.defaults.FULL_RESOLUTION_FB` px*m and its images are at most
:data:`~pcainterp_stream.defaults.FULL_RESOLUTION_MAX_PIXELS`; half resolution otherwise.

At full resolution the left band x < min_disparity + num_disparities is matched too
(``SgbmConfig.full_width``, bug hunt 9B F6): SGBM leaves it empty otherwise, which at these
image sizes is a sixth to a third of the image with no lookups, filled by the prior's
extrapolation (1.6-2.3x nearest neighbour's error there on indoor halls) and never scored by the
fit check (it holds out SGBM pixels). The match costs (W + band) / W, +3-14 % of densify's
CPU on 376-752 px wide images; half resolution (KITTI-like cameras, where the street basis's
band is 2-2.4x better than nearest) keeps the band empty as before. A given
``--stereo-downscale 1`` matches the band too (review 57c F1): it is what ``auto`` picks on
those cameras, and without the band it was up to 3.8x worse than ``auto`` (worse than nearest
neighbour on a 752x480 indoor log).
"""

from __future__ import annotations

from dataclasses import replace

from pcainterp_stream import defaults
from pcainterp_stream.frontend.stereo import SgbmConfig

__all__ = ["by_camera", "full_resolution"]


def by_camera(
    config: SgbmConfig, focal_baseline: float, width: int, height: int
) -> tuple[SgbmConfig, str | None]:
    """Return ``config`` with its resolution chosen for a camera, and the phrase saying so.

    Only a ``config`` with ``by_camera`` set is resolved (``--stereo-downscale 1`` or ``2``
    given: no phrase); the result has ``by_camera`` cleared and, at full resolution, chosen or
    given, ``full_width`` set (the left band matched too), so a given ``1`` is ``auto``'s
    full-resolution choice.

    Args:
        config: the matcher settings.
        focal_baseline: the camera's f*b (px*m) at the images' size.
        width: the images' width (px).
        height: the images' height (px).

    Returns:
        The settings to match with (``downscale`` chosen; ``full_width`` at full
        resolution) and, when chosen here, the phrase for the camera line
        (``SGBM at full resolution (--stereo-downscale auto: f*b 24 < 90 px*m)``).
    """
    if not config.by_camera:
        if config.downscale == 1 and not config.full_width:
            return replace(config, full_width=True), None
        return config, None
    threshold = defaults.FULL_RESOLUTION_FB
    small = 0 < focal_baseline < threshold
    if full_resolution(focal_baseline, width, height):
        downscale, why = 1, f"f*b {focal_baseline:.3g} < {threshold:g} px*m"
    elif small:
        downscale, why = defaults.STEREO_DOWNSCALE, f"{width}x{height} px images"
    else:
        downscale, why = defaults.STEREO_DOWNSCALE, f"f*b {focal_baseline:.3g} >= {threshold:g}"
        why += " px*m"
    resolution = "full" if downscale == 1 else "half"
    phrase = f"SGBM at {resolution} resolution (--stereo-downscale auto: {why})"
    full_width = config.full_width or downscale == 1
    return replace(config, downscale=downscale, by_camera=False, full_width=full_width), phrase


def full_resolution(focal_baseline: float, width: int, height: int) -> bool:
    """Return whether ``auto`` matches this camera at full resolution, its left band too."""
    small = 0 < focal_baseline < defaults.FULL_RESOLUTION_FB
    return small and width * height <= defaults.FULL_RESOLUTION_MAX_PIXELS
