"""Checks of a stereo pair that keep running past the first frames' row check.

The row check (:mod:`.row_check`) refuses a pair that is swapped, not rectified or one
view twice on its first frames only. A pair can go wrong later: a driver restarted with the
cameras' device ids exchanged (left and right swapped), a republish of the wrong camera (one
view on both topics), a bumped right camera (its rows drifted). SGBM, whose range starts at
0, matched a swapped KITTI pair at disparity ~0: depth "too far" over nearly the whole image
with a 1.25 px std (+-2 sigma covered 0.9 % of the truth), and nothing said so; a right camera
3 px lower from frame 5 on gave 2.5-3x the error, again without a line.

:class:`PairWatch` looks at every frame with a small block matcher whose range is signed
(:func:`signed_shares`: ~1.4 ms a KITTI pair at 1/8 resolution, ~0.3 ms at 620x188): on a
pair as recorded 82-89 % of its matched blocks lie at positive disparities and none at
negative ones; swapped, 79-86 % at negative ones; one view twice, all at 0 with the images
equal. A scene beyond stereo range looks like one view twice at that size and to the
corners too: one view twice also needs one image twice, pixel for pixel (:func:`one_image`).
A frame that looks so, while an earlier frame of the log looked right, is confirmed with the
row check's own corner matching (:func:`.rectify.correspondences`, 40-70 ms, only then) and
is not matched (its right image blanked, as a stale one: no estimate, depth NaN). Once per
:data:`ROW_WATCH_SECONDS` of log time the corners are matched in a thread, and a row
offset that moved by more than :data:`~.row_check.MAX_ROW_OFFSET_PX` since the first such
check is warned of once (those frames keep their estimate: the warning says they err more).
The first check falls on the first frame, which the pairer's row check has matched already:
with :attr:`PairWatch.row_corners` the watch takes that frame's corners from it (the same
:func:`.rectify.correspondences` of the same images, bit for bit) instead of matching again.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.grey import is_blank, to_grey8_pair
from pcainterp_stream.frontend.row_check import (
    MAX_ROW_OFFSET_PX,
    MIN_MEDIAN_DISPARITY_PX,
    ROW_CHECK_MIN_MATCHES,
    SAME_VIEW_CHANGE,
    SAME_VIEW_PX,
    SAME_VIEW_SHARE,
    Corners,
)
from pcainterp_stream.records import StereoFrame

__all__ = ["PairWatch", "frame_ranges", "one_image", "signed_shares"]

WATCH_WIDTH = 160
"""The block matcher sees the pair downscaled to about this width (px)."""

WATCH_RANGE = 16
"""Its disparity range, each sign (px of the downscaled pair: 128 px on KITTI)."""

GOOD_SHARE = 0.5
"""A frame looks as recorded when more than this share of its matched blocks is at positive
disparities (KITTI 0.82-0.84, synthetic streets 0.87-0.89, a synthetic room 0.69-0.72)."""

SWAPPED_SHARE = 0.5
"""A frame looks swapped when more than this share is at negative disparities, and more
than :data:`SWAPPED_RATIO` times the positive share (swapped KITTI 0.79-0.81, synthetic
0.85-0.86; pairs as recorded 0.00, a synthetic room 0.24-0.27, a textureless wall 0.36-0.65
at 1.5-2.2x its positive share)."""

SWAPPED_RATIO = 3.0

SAME_VIEW_THUMB = 0.5
"""Largest mean |left - right| over the mean |left - left moved a column| of the
downscaled pair that says one view twice (identical images 0; pairs 2.0-7.0; a flat
noisy wall ~1)."""

COPY_SHIFT_PX = 0.1
"""Largest horizontal shift (px, full resolution) fitted to left - right of one image twice.
An exact or re-encoded copy: ~0; a far scene matched by two cameras at 0.5 px (96 m on a
VI-sensor, 780 m on KITTI): 0.4-0.5 (its ``same`` thumbnail ratio 0.1, like a copy's)."""

COPY_MEAN_LEVELS = 0.5
"""Largest difference of the two images' mean grey levels (0-255) of one image twice: a copy
or re-encoding keeps the mean; two cameras' gain, exposure and vignetting do not."""

MIN_VALID_SHARE = 0.05
"""Fewer matched blocks than this share of the image: the test says nothing (blank, wall)."""

ROW_WATCH_SECONDS = 5.0
"""The corners are matched for the row offset once per this much log time (40-70 ms a KITTI
pair in a thread: once a second cost the default densify ~10 % more CPU per frame)."""


def signed_shares(
    grey_left: npt.NDArray[np.uint8], grey_right: npt.NDArray[np.uint8]
) -> tuple[float, float, float, float]:
    """Return (matched, positive, negative, same) of a grey pair at ~:data:`WATCH_WIDTH` px.

    ``matched``: share of the image's blocks a signed-range block matcher matched;
    ``positive`` / ``negative``: the shares of those at disparities above 1 / below -1 px;
    ``same``: mean |left - right| over mean |left - left moved by one column|.
    """
    factor = max(1, round(grey_left.shape[1] / WATCH_WIDTH))
    size = (grey_left.shape[1] // factor, grey_left.shape[0] // factor)
    if size[1] < 16 or size[0] <= 2 * WATCH_RANGE + 16:
        return 0.0, 0.0, 0.0, float("inf")  # too small to say anything
    a = cv2.resize(grey_left, size, interpolation=cv2.INTER_AREA)
    b = cv2.resize(grey_right, size, interpolation=cv2.INTER_AREA)
    texture = float(np.mean(np.abs(np.diff(a.astype(np.int16), axis=1))))
    same = float(np.mean(cv2.absdiff(a, b))) / max(texture, 1e-6)
    matcher = cv2.StereoBM.create(numDisparities=2 * WATCH_RANGE, blockSize=9)
    matcher.setMinDisparity(-WATCH_RANGE)
    matcher.setTextureThreshold(10)
    matcher.setUniquenessRatio(15)
    disparity = matcher.compute(a, b).astype(np.float32) / 16.0
    valid = disparity[disparity > -WATCH_RANGE]
    if not valid.size:
        return 0.0, 0.0, 0.0, same
    return (
        valid.size / disparity.size,
        float(np.mean(valid > 1.0)),
        float(np.mean(valid < -1.0)),
        same,
    )


def one_image(grey_left: npt.NDArray[np.uint8], grey_right: npt.NDArray[np.uint8]) -> bool:
    """Whether a grey pair is one image twice (a copy or re-encoding), at full resolution.

    A scene beyond stereo range looks like that at the watch's thumbnail size and to ORB's
    corners (all within :data:`~.row_check.SAME_VIEW_PX`), but two cameras' images differ
    pixel for pixel: by a sub-pixel shift (:data:`COPY_SHIFT_PX`), their mean level
    (:data:`COPY_MEAN_LEVELS`) or noise (:func:`~.row_check.view_change` at
    :data:`~.row_check.SAME_VIEW_CHANGE`). ~2-4 ms a KITTI pair, run only on such a frame.
    """
    a = grey_left[::2].astype(np.float32)  # every other row: half the cost, same shift
    b = grey_right[::2].astype(np.float32)
    if abs(float(np.mean(a)) - float(np.mean(b))) > COPY_MEAN_LEVELS:
        return False
    diff = a[:, 1:-1] - b[:, 1:-1]
    slope = (a[:, 2:] - a[:, :-2]) / 2  # left(x + s) ~ left(x) + s * slope
    texture = float(np.mean(np.abs(a[:, 1:] - a[:, :-1])))
    if float(np.mean(np.abs(diff))) >= SAME_VIEW_CHANGE * max(texture, 1e-6):
        return False
    energy = float(np.sum(slope * slope))
    shift = float(np.sum(diff * slope)) / energy if energy > 0 else 0.0
    return abs(shift) < COPY_SHIFT_PX


def frame_ranges(frames: list[int]) -> str:
    """Return sorted frame indices as "3, 5-7, 12" (at most 6 runs, then "...")."""
    runs: list[list[int]] = []
    for index in sorted(frames):
        if runs and index == runs[-1][1] + 1:
            runs[-1][1] = index
        else:
            runs.append([index, index])
    text = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:6]]
    return ", ".join(text) + (", ..." if len(runs) > 6 else "")


@dataclass
class _Drift:
    """The row offsets the watch measured (signed median y_left - y_right, px)."""

    first: float | None = None  # the first check's: what the log started with
    last_good: int | None = None  # the last frame checked within the limit
    frame: int | None = None  # the first frame checked beyond it
    offset: float = 0.0  # its offset
    checks: int = 0  # checks after the first
    beyond: int = 0  # of those, beyond the limit


class PairWatch:
    """Watch every frame of a stereo stream for a swapped pair, one view twice, drifted rows.

    Attributes:
        swapped: frame -> median x_left - x_right (px) of the frames found swapped.
        same_view: frames found to carry one view on both topics.
        row_corners: frame index -> the corners the row check matched on that frame
            (:meth:`.StereoPairer.row_corners`), None for one it did not: a row offset
            check on such a frame takes them. None: every check matches its own.
        corner_matches: the row offset checks that matched their own corners.
    """

    def __init__(self, row_corners: Callable[[int], Corners | None] | None = None) -> None:
        self.swapped: dict[int, float] = {}
        self.same_view: list[int] = []
        self.row_corners = row_corners
        self.corner_matches = 0
        self._good = False  # a frame of the log looked as recorded
        self._next_ns: int | None = None  # log time of the next row offset check
        self._pending: list[tuple[int, Future[npt.NDArray[np.float64]]]] = []
        self._executor: ThreadPoolExecutor | None = None
        self._drift = _Drift()

    def broken(self, frame: StereoFrame) -> bool:
        """Whether ``frame``'s pair looks swapped or one view twice (then not to be matched)."""
        self._collect(wait=False)
        left, right = to_grey8_pair(frame.left, frame.right)
        if left.shape != right.shape or is_blank(left) or is_blank(right):
            return False
        self._watch_rows(frame, left, right)
        matched, positive, negative, same = signed_shares(left, right)
        if matched < MIN_VALID_SHARE:
            return False
        if positive > GOOD_SHARE:
            self._good = True
            return False
        if not self._good:  # a log that never looked right: the row check's business
            return False
        if negative > SWAPPED_SHARE and negative > SWAPPED_RATIO * positive:
            points = rect.correspondences(left, right)  # confirmed as the row check would
            offset = rect.row_offset(points)
            if offset.matches >= ROW_CHECK_MIN_MATCHES and (
                offset.median_dx < MIN_MEDIAN_DISPARITY_PX
            ):
                self.swapped[frame.index] = offset.median_dx
                return True
        elif same < SAME_VIEW_THUMB and one_image(left, right):  # ORB only on a copy
            points = rect.correspondences(left, right)
            if points.shape[0] >= ROW_CHECK_MIN_MATCHES:
                near = np.abs(points[:, :2] - points[:, 2:]).max(axis=1) < SAME_VIEW_PX
                if float(np.mean(near)) >= SAME_VIEW_SHARE:
                    self.same_view.append(frame.index)
                    return True
        return False

    def _watch_rows(
        self, frame: StereoFrame, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]
    ) -> None:
        """Match the corners in the thread once per :data:`ROW_WATCH_SECONDS` of log time."""
        at = frame.log_time_ns
        if self._next_ns is not None and at < self._next_ns:
            return
        self._next_ns = at + round(ROW_WATCH_SECONDS * 1e9)
        matching = None
        if self.row_corners is not None and frame.left.dtype == np.uint8:
            # 8-bit: the row check's grey images (rect.grey8) are these, its corners ours
            matching = self.row_corners(frame.index)
        if matching is None:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(1, thread_name_prefix="pair-watch")
            matching = self._executor.submit(rect.correspondences, left, right)
            self.corner_matches += 1
        self._pending.append((frame.index, matching))

    def _collect(self, *, wait: bool) -> None:
        """Take the row offsets matched so far, in frame order (``wait``: all of them)."""
        while self._pending and (wait or self._pending[0][1].done()):
            index, future = self._pending.pop(0)
            if not future.cancelled():  # (the row check's, had it stopped before matching)
                self._rows(index, future.result())

    def _rows(self, index: int, points: npt.NDArray[np.float64]) -> None:
        if points.shape[0] < ROW_CHECK_MIN_MATCHES:
            return
        offset = float(np.median(points[:, 1] - points[:, 3]))
        drift = self._drift
        if drift.first is None:
            drift.first, drift.last_good = offset, index
            return
        drift.checks += 1
        if abs(offset - drift.first) <= MAX_ROW_OFFSET_PX:
            if drift.frame is None:
                drift.last_good = index
            return
        drift.beyond += 1
        if drift.frame is None:
            drift.frame, drift.offset = index, offset

    def close(self) -> None:
        """Wait for the row offsets being matched and stop the thread."""
        try:
            self._collect(wait=True)
        finally:
            self._pending.clear()
            if self._executor is not None:
                self._executor.shutdown(wait=False, cancel_futures=True)
                self._executor = None

    def warnings(self, frames: int, outcome: str) -> list[str]:
        """The watch's warnings (``outcome``: what the frames not matched got)."""
        self.close()
        lines = []
        if self.swapped:
            dx = float(np.median(list(self.swapped.values())))
            lines.append(
                f"{len(self.swapped)} of {frames} frames ({frame_ranges(list(self.swapped))}) "
                "looked swapped after earlier frames had not: their matched corners lie at "
                f"negative disparities (x_left - x_right {dx:.1f} px), left and right "
                "exchanged mid-log (a driver restarted with the cameras' ids exchanged?); "
                f"such a pair is not matched: {outcome}"
            )
        if self.same_view:
            lines.append(
                f"{len(self.same_view)} of {frames} frames ({frame_ranges(self.same_view)}) "
                "carried one view on both image topics after earlier frames had not (the "
                "right topic republishing the left camera?); such a pair is not matched: "
                f"{outcome}"
            )
        drift = self._drift
        if drift.frame is not None and drift.first is not None:
            good = drift.last_good
            since = f" (frame {good} was within it)" if good is not None else ""
            lines.append(
                f"from frame {drift.frame} the matched corners are {abs(drift.offset):.1f} px "
                f"apart vertically, {abs(drift.offset - drift.first):.1f} px more than on the "
                f"first frames{since}; in {drift.beyond} of {drift.checks} checks (one per "
                f"{ROW_WATCH_SECONDS:g} s of log) beyond {MAX_ROW_OFFSET_PX:g} px: the "
                "calibration has drifted (a camera bumped or loose); those frames were densified "
                "with more error (a 3 px drift on KITTI: 2.5-3x): calibrate the pair again and "
                "densify with the new camera infos (or --calibration files)"
            )
        return lines
