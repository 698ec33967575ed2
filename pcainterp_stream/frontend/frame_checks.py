"""Checks across a stereo stream's frames: a stale right image, surfaces beyond the range.

:class:`StaleRight` notices a right image whose pixels equal the previous frame's while the
left image changed: a stereo driver whose right camera stalled republishes its last image
under a new stamp. Matched against the new left image it gives wrong depth (a synthetic
drive, one stale right image in 4 frames: 33 % median depth error and 68 % of pixels within
2 std of the truth, the other frames 4-5 % and 90-93 %). The frame gets a blank right image
instead, so the front end measures nothing there (:func:`.grey.is_blank`): no estimate,
depth NaN, and one warning line at the end. So does a pair that looks swapped, or one view
twice, after earlier frames looked right (:class:`~.pair_watch.PairWatch`, which also warns of
rows that drifted apart).

:class:`BeyondRange` counts the frames whose measurements come mostly from the near reach
(:mod:`.near`: SGBM's range is too short for them) and names the ``--num-disparities`` that
would cover them: a textured wall at 150 px on a 620 px wide camera (SGBM's range 128 px)
was densified with 21 % median depth error; ``--num-disparities 192`` gave 0.25 %.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.grey import is_blank, to_grey8_pair
from pcainterp_stream.frontend.pair_watch import PairWatch
from pcainterp_stream.frontend.sgbm_limits import narrowest_width
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.records import DensifiedFrame, StereoFrame

__all__ = ["BeyondRange", "StaleRight"]

THUMB_STEP = 8
"""Images are compared first on every 8th row and column (~0.02 ms for a KITTI pair); the
whole right image only when its thumbnails are equal."""

LEFT_CHANGED = 0.01
"""The left image has changed when at least this share of its thumbnail's pixels differ (a
camera's noise alone changes most; a scene standing still before a noiseless simulated
camera, none)."""


def _thumb(image: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
    return image[::THUMB_STEP, ::THUMB_STEP]


class StaleRight:
    """Tell frames whose right image repeats the previous frame's while the left changed.

    And, with ``watch``, the frames whose pair looks swapped or one view twice
    (:class:`~.pair_watch.PairWatch`): they are blanked too, and warned of on their own.

    Attributes:
        stale: indices of the frames whose right image was blanked (stale, or watched).
        repeated: those of them found stale.
        watch: the watch of a broken pair, None when not watched.
    """

    def __init__(self, watch: bool = True) -> None:
        self._previous: StereoFrame | None = None
        self.stale: set[int] = set()
        self.repeated: set[int] = set()
        self.watch = PairWatch() if watch else None

    def is_stale(self, frame: StereoFrame, previous: StereoFrame) -> bool:
        """Whether ``frame``'s right image equals ``previous``'s while its left changed.

        A blank image (:func:`.grey.is_blank`: a black, capped or saturated camera) is not
        stale: it repeats nothing, and the front end measures nothing in its pair anyway
        (counted as a frame without a measurement, not as a stale one).
        """
        right, before = frame.right, previous.right
        if right.shape != before.shape or right.dtype != before.dtype:
            return False
        if frame.left.shape != previous.left.shape:
            return False
        if not np.array_equal(_thumb(right), _thumb(before)):
            return False
        changed = _thumb(frame.left) != _thumb(previous.left)
        if float(np.mean(changed)) < LEFT_CHANGED:
            return False
        if not np.array_equal(right, before):
            return False
        grey_left, grey_right = to_grey8_pair(frame.left, right)  # as the front end sees them
        return not (is_blank(grey_right) or is_blank(grey_left))

    def check(self, frame: StereoFrame) -> StereoFrame:
        """Return the frame, with a blank (all 0) right image when it is stale (or broken)."""
        previous, self._previous = self._previous, frame  # the right image as recorded
        if previous is not None and self.is_stale(frame, previous):
            self.repeated.add(frame.index)
        elif self.watch is None or not self.watch.broken(frame):
            return frame
        self.stale.add(frame.index)
        return frame._replace(right=np.zeros_like(frame.right))

    def warnings(self, frames: int, empty: int) -> list[str]:
        """The warnings for the stale and the broken frames (none when there were none).

        ``empty``: how many of them had no estimate (all, unless earlier frames carried
        measurements or a temporal prior into them; sparse and dense mode alike).
        """
        count = len(self.stale)
        outcome = (
            "those frames have no estimate, their depth is NaN"
            if empty == count
            else f"{empty} of the {count} frames not matched have no estimate (depth NaN), "
            "the others only what earlier frames carried into them (points, or the temporal "
            "prior)"
        )
        lines = self.watch.warnings(frames, outcome) if self.watch is not None else []
        if not self.repeated:
            return lines
        return [
            f"{len(self.repeated)} of {frames} frames had a stale right image (the pixels of "
            "the frame before, while the left image changed: a right camera or driver "
            f"repeating its last image under a new stamp); such a pair is not matched: {outcome}",
            *lines,
        ]


class BeyondRange:
    """Count the frames measured mostly beyond SGBM's range, by the near reach.

    Attributes:
        match_range: SGBM's largest disparity (full-resolution px).
        step: the ``--num-disparities`` granularity that matches as asked (16 x downscale).
        frames: frames whose near-reach points outnumber their own lookups.
        highest: the highest 95th percentile of those frames' disparities (px).
        width: the narrowest of those frames' images (px).
    """

    SHARE = 0.5
    """A frame counts when more than this share of its measurements are near-reach points."""

    REACH = 0.875
    """A range is advised that puts the frames' 95th percentile at this share of it: SGBM
    loses values near its range's end (the near reach's own trigger, ``trigger_at``)."""

    def __init__(self, match_range: float, step: int) -> None:
        self.match_range = match_range
        self.step = step
        self.frames = 0
        self.highest = 0.0
        self.width: int | None = None

    def result(self, result: DensifiedFrame) -> None:
        """Count a densified frame."""
        counts = result.counts
        added = counts.get("near_added", 0)
        total = counts.get("kept", 0) - counts.get("near_dropped", 0) + added
        if not added or added <= self.SHARE * total:
            return
        self.frames += 1
        values = result.disparities[np.isfinite(result.disparities)]
        self.highest = max(self.highest, float(np.percentile(values, 95)))
        width = int(result.frame.left.shape[1])
        self.width = width if self.width is None else min(self.width, width)

    def advised(self) -> int:
        """The ``--num-disparities`` that covers the frames counted (a multiple of ``step``)."""
        return self.step * math.ceil(self.highest / self.REACH / self.step)

    def warnings(self, frames: int, sgbm: SgbmConfig) -> list[str]:
        """The warning for the frames counted (none when there were none).

        ``sgbm``: the matcher's settings, to check that the advised range fits the images.
        """
        if not self.frames:
            return []
        advised = self.advised()
        cost = advised / self.match_range
        fix = f"densify with --num-disparities {advised} (the matching costs ~{cost:.1f}x)"
        width = self.width
        if width is not None and narrowest_width(replace(sgbm, num_disparities=advised)) > width:
            fix = (
                f"--num-disparities {advised} would cover them but does not fit images "
                f"{width} px wide"
            )
        return [
            f"{self.frames} of {frames} frames were measured mostly beyond SGBM's "
            f"{self.match_range:g} px disparity range (surfaces nearer than it, up to "
            f"{self.highest:.0f} px: the near reach's coarse points stand in for them and "
            f"their depth is rough); {fix}"
        ]
