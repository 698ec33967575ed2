"""Far surfaces SGBM reads as exactly 0, matched again with a range centred on 0.

OpenCV's SGBM refines a disparity to sub-pixel only strictly inside its range (0 < d <
range - 1 with ``min_disparity`` 0): a pixel whose best integer disparity is 0 comes back as
exactly 0. That is every surface below half a px of the matching resolution: at half
resolution (``SgbmConfig.downscale=2``) below ~1 px of full-resolution disparity, at full
resolution below ~0.5 px. A 5 cm depth camera at 320x240 px sees a wall 16 m away at 0.6 px
(read as 0 at half resolution) and one 25 m away at 0.38 px (read as 0 at full resolution).
Taken as a match, such a lookup pins the estimate at 0 with the ordinary noise: +inf depth
and a std that holds the truth on half the pixels (docs/estimator.md, "Far surfaces").

:func:`rematch_far` runs SGBM once more where such lookups are: at full resolution, over
the rows and columns around them only, with a small range centred on 0
(``[-FAR_REACH, FAR_REACH)``), so that 0 is inside the range and refined like any other
disparity. The map takes that value where it read below half a matching px (:data:`BELOW`),
and the lookups there are read again with the same checks. A lookup the new match cannot
confirm keeps its 0 (:class:`FarZeros` warns when many do). The extra match runs only on
frames where at least :data:`TRIGGER_SHARE` of the lookups read 0 (KITTI's frames have
~0-2 %, all far sky or horizon; the depth camera's hall 86 % at half resolution).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.sgbm_limits import needed_width

Lookup = Any
"""A :class:`~.stereo.Lookup` (not imported here: the stereo module imports this one)."""

SgbmConfig = Any
"""A :class:`~.stereo.SgbmConfig` (likewise)."""

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]

__all__ = [
    "FAR_REACH",
    "TRIGGER_SHARE",
    "FarMatch",
    "FarZeros",
    "rematch_far",
]

TRIGGER_SHARE = 0.05
"""A frame is matched again when at least this share of its lookups read exactly 0."""

TRIGGER_MIN = 4
"""... and at least this many."""

FAR_REACH = 8
"""The full-resolution match searches ``[-FAR_REACH, FAR_REACH)`` px: 0 is inside the range,
so SGBM refines it (a value below 0 is a far surface's noise and is clipped to 0)."""

BELOW = 0.5
"""Values below this many px of the matching resolution (``SgbmConfig.downscale`` full-
resolution px: 1.0 at half resolution, 0.5 at full) are zeros or blends with them."""

TRUSTED = 1.0
"""A new value replaces one below :data:`BELOW` only when it is below this many px of the
matching resolution (2.0 full-resolution px at half resolution, 1.0 at full): the first
match saw no surface nearer there."""

MARGIN = 24
"""Context (px) around the lookups' bounding box given to the full-resolution match."""


class FarMatch:
    """The result of :func:`rematch_far` for one frame.

    Attributes:
        disparity_map: (H, W) float32 the map, the full-resolution values spliced in (px).
        lookup: the lookups with the values read again.
        zeros: lookups that read exactly 0 in the front end's map (at ``downscale``'s
            resolution, half or full).
        rematched: of those, how many were read again in the full-resolution values (a
            far surface's may be 0 again: a value at or below 0, refined, is clipped there).
    """

    def __init__(
        self, disparity_map: FloatArray, lookup: Lookup, zeros: int, rematched: int
    ) -> None:
        self.disparity_map = disparity_map
        self.lookup = lookup
        self.zeros = zeros
        self.rematched = rematched


def _box(points: FloatArray, height: int, width: int, reach: int) -> tuple[int, int, int, int]:
    """Rows and columns (top, bottom, left, right; end exclusive) to match around points."""
    top = max(int(np.floor(points[:, 1].min())) - MARGIN, 0)
    bottom = min(int(np.ceil(points[:, 1].max())) + MARGIN + 1, height)
    # the left band of the range has no match; a negative disparity looks to the right
    left = max(int(np.floor(points[:, 0].min())) - MARGIN - 2 * reach, 0)
    right = min(int(np.ceil(points[:, 0].max())) + MARGIN + reach + 1, width)
    return top, bottom, left, right


def rematch_far(
    left: UInt8Array,
    right: UInt8Array,
    disparity_map: FloatArray,
    found: Lookup,
    sgbm: SgbmConfig,
    *,
    match: Callable[[UInt8Array, UInt8Array, Any, bool], FloatArray],
    look_up: Callable[[FloatArray, FloatArray], Lookup],
) -> FarMatch:
    """Match again, range centred on 0, where the lookups read exactly 0.

    Args:
        left: (H, W) uint8 grey left image.
        right: (H, W) uint8 grey right image.
        disparity_map: (H, W) float32 the map (px, full resolution; upsampled when
            ``sgbm.downscale`` is 2), NaN where invalid.
        found: the lookups in that map.
        sgbm: the front end's matcher settings (``downscale`` 1 or 2: the thresholds
            :data:`BELOW` and :data:`TRUSTED` are in its px).
        match: SGBM at the images' own resolution (``stereo._match``: images, settings,
            full width) -> float32 px, NaN where invalid.
        look_up: (map, points) -> the checked lookups of the points in the map (the front
            end's checks).

    Returns:
        The map and lookups, unchanged when fewer than :data:`TRIGGER_SHARE` (or
        :data:`TRIGGER_MIN`) of the lookups read 0 or the box is too narrow to match.
    """
    values = found.disparities
    zero = values == 0
    zeros = int(zero.sum())
    unchanged = FarMatch(disparity_map, found, zeros, 0)
    if zeros < max(TRIGGER_MIN, TRIGGER_SHARE * values.size):
        return unchanged
    config = replace(
        sgbm,
        min_disparity=-FAR_REACH,
        num_disparities=2 * FAR_REACH,
        downscale=1,
        full_width=False,
        near_at_half=False,
        refine_range=0,
    )
    below = np.float32(BELOW * sgbm.downscale)  # full-resolution px
    trusted = np.float32(TRUSTED * sgbm.downscale)
    low = values < below
    height, width = left.shape
    top, bottom, first, last = _box(found.pixels[low], height, width, FAR_REACH)
    if last - first < needed_width(config) + FAR_REACH:
        return unchanged
    full = match(left[top:bottom, first:last], right[top:bottom, first:last], config, False)
    spliced = disparity_map.copy()
    window = spliced[top:bottom, first:last]  # a view: written through
    with np.errstate(invalid="ignore"):
        take = (window < below) & (full < trusted)
    window[take] = np.maximum(full[take], np.float32(0.0))
    chosen = np.flatnonzero(low)
    again = look_up(spliced, found.pixels[chosen])
    updated = values.copy()
    read = chosen[again.indices]
    updated[read] = again.disparities
    rematched = int(np.count_nonzero(zero[read]))
    return FarMatch(spliced, found._replace(disparities=updated), zeros, rematched)


class FarZeros:
    """Count the frames a large share of whose lookups stay at exactly 0 (:func:`rematch_far`).

    Such a frame's far surfaces read 0 in the front end's match and the match around them
    with a range centred on 0 could not read them again (its box too narrow, its values
    failing the lookup's checks): their estimate stays at 0, "infinitely far".

    Args:
        downscale: the front end's ``SgbmConfig.downscale`` (1 or 2); the warning names
            ``--stereo-downscale 1`` only at 2.

    Attributes:
        frames: frames counted.
        share: the largest share of a counted frame's lookups left at 0.
    """

    def __init__(self, downscale: int = 2) -> None:
        self.downscale = downscale
        self.frames = 0
        self.share = 0.0

    def result(self, counts: Mapping[str, int]) -> None:
        """Count a densified frame by its counts (``DensifiedFrame.counts``)."""
        kept = counts.get("kept", 0)
        left = counts.get("far_zeros", 0) - counts.get("far_rematched", 0)
        if not kept or left < max(TRIGGER_MIN, TRIGGER_SHARE * kept):
            return
        self.frames += 1
        self.share = max(self.share, left / kept)

    def warnings(self, frames: int) -> list[str]:
        """The warning for the frames counted (none when there were none)."""
        if not self.frames:
            return []
        if self.downscale == 2:
            where = "the half-resolution match (surfaces below ~1 px of disparity)"
            advice = (
                "; densify --stereo-downscale 1 matches every pixel at full resolution, the "
                "left band included"
            )
        else:
            where = "the full-resolution match (surfaces below ~0.5 px of disparity)"
            advice = " (nothing nearer than ~0.5 px is measured there)"
        return [
            f"{self.frames} of {frames} frames had up to {100 * self.share:.0f} % of their "
            f"lookups at disparity 0 in {where} that a match around them with a range "
            f"centred on 0 could not measure again: the estimate reads them as infinitely "
            f"far{advice}"
        ]
