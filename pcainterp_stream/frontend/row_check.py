"""The guard against an unrectified or swapped stereo pair (``PairingConfig.check_rows``).

The pairer shows it the first frames of a pair: matched corners of a rectified pair lie on
the same rows, with non-negative disparities, and not all at one pixel in both images (one
camera's images on both topics). A pair that fails is refused with the fix. The
check goes on past frames that give few matches (a camera's dark start-up, a lens cap) until
enough frames have given some, within the first :data:`ROW_CHECK_MAX_FRAMES`; a log that never
gives enough is densified unchecked, and :attr:`RowCheck.undecided` says why.

Each frame's matched corners are kept for the pair watch (:meth:`RowCheck.corners`), whose
first row offset is measured on the first frame too: it takes them instead of matching
the frame again (~55 ms a KITTI pair).
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeAlias

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.levels import note_once

__all__ = ["Corners", "RowCheck", "exchanged_offset"]

Corners: TypeAlias = Future[npt.NDArray[np.float64]]
_Matched: TypeAlias = tuple[npt.NDArray[np.float64], float, npt.NDArray[np.float64]]
"""One frame's matched corners, (n, 4) x_left, y_left, x_right, y_right (being) matched."""

ROW_CHECK_FRAMES = 5
"""How many frames with matches the row check looks at (it decides earlier with enough)."""

ROW_CHECK_FRAME_MATCHES = 10
"""A frame with fewer matches than this (dark, blank) does not count in :data:`ROW_CHECK_FRAMES`."""

ROW_CHECK_MAX_FRAMES = 100
"""The row check decides by this frame at the latest (5 s at 20 Hz, 3.3 s at 30 Hz)."""

ROW_CHECK_MATCHES = 150
"""Matches after which the row check decides."""

ROW_CHECK_MIN_MATCHES = 30
"""Fewer matches than this when it decides: no verdict (dark, textureless, unrelated images)."""

MAX_ROW_OFFSET_PX = 1.0
"""Largest median vertical offset (px) of matched corners a rectified pair may have."""

MIN_MEDIAN_DISPARITY_PX = -1.0
"""A median disparity of matched corners below this says left and right are swapped."""

SAME_VIEW_PX = 2.0
"""Matched corners closer than this in x and y (px) lie where the other image has them too."""

SAME_VIEW_SHARE = 0.9
"""This share of matched corners within :data:`SAME_VIEW_PX`, with :data:`SAME_VIEW_CHANGE`,
says both topics carry one camera (real pairs: 0-4 % of their corners)."""

SAME_VIEW_CHANGE = 1.0
"""Largest mean |left - right| over the mean |left - left shifted by 1 px| of one view twice.

One image and its JPEG copy: 0.3-0.7; real pairs (KITTI, EuRoC): 3.5-7.6; an image against
itself shifted by 2 px: 1.6."""


class RowCheck:
    """The guard against an unrectified or swapped pair (``PairingConfig.check_rows``).

    A frame's matching (ORB corners, a RANSAC fundamental matrix: ~30-60 ms a KITTI frame,
    in OpenCV without the interpreter lock) runs in a thread of its own while the frame goes
    on to stereo matching; the next frame waits for it, so the check looks at the same
    frames and decides at the same one as a check in line would. A bad pair is refused
    when the next frame arrives, or by :meth:`finish` at the end of the stream.

    Args:
        left_topic: the left image topic (named in the error).
        right_topic: the right image topic.
        info_topics: the left and right camera info topics; None when the calibration comes
            from files.

    Attributes:
        undecided: why the check gave no verdict (too few matches), else None.
    """

    def __init__(
        self, left_topic: str, right_topic: str, *, info_topics: tuple[str, str] | None
    ) -> None:
        self.pair = f"{left_topic} / {right_topic}"
        self.topics = (left_topic, right_topic)
        self.info_topics = info_topics
        self.frames = 0
        self.frames_with_matches = 0
        self.points: list[tuple[Any, rect.StereoRectifier | None]] = []
        self.changes: list[float] = []  # per frame: :func:`view_change`
        self.refined: list[
            npt.NDArray[np.float64]
        ] = []  # per frame: the same-level |dy| (:func:`same_level_dy`)
        self.done = False
        self.undecided: str | None = None
        self._pending: tuple[Future[Any], rect.StereoRectifier | None] | None = None
        self._executor: ThreadPoolExecutor | None = None
        # frame index -> its matching, for :meth:`corners` (only frames before the verdict)
        self._by_frame: dict[int, Future[_Matched]] = {}

    def see(
        self,
        left: Any,
        right: Any,
        *,
        rectifier: rect.StereoRectifier | None,
        index: int | None = None,
    ) -> None:
        """Start matching one frame's corners, once the frame before has been decided on.

        Args:
            left: the left image as densified (rectified by ``rectifier``, in its box).
            right: the right image.
            rectifier: the rectifier that remapped the raw pair, None when used as recorded.
            index: the frame's index, under which :meth:`corners` gives its corners.

        Raises:
            CalibrationError: the pair does not look rectified, or looks swapped.
        """
        self._decide()  # the frame before says whether this one is needed
        if self.done:
            return
        if self._executor is None:
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="row-check")
        matching = self._executor.submit(_match, left, right)
        self._pending = (matching, rectifier)
        if index is not None:
            self._by_frame[index] = matching

    def corners(self, index: int) -> Corners | None:
        """Return the corners matched on frame ``index`` (maybe still being matched), else None.

        They are :func:`~rect.correspondences` of the images given to :meth:`see`, as the pair
        watch would match them itself (8-bit images: its grey conversion is
        :func:`~rect.grey8`'s). None for a frame this check did not match (after its
        verdict, or not given). Each frame's are given once; earlier frames' are let go.
        """
        for earlier in [seen for seen in self._by_frame if seen < index]:
            del self._by_frame[earlier]
        matching = self._by_frame.pop(index, None)
        if matching is None:
            return None
        corners: Corners = Future()

        def hand_on(done: Future[_Matched]) -> None:
            if done.cancelled():
                corners.cancel()
            elif (error := done.exception()) is not None:
                corners.set_exception(error)
            else:
                corners.set_result(done.result()[0])

        matching.add_done_callback(hand_on)
        return corners

    def finish(self) -> None:
        """Decide with the frames matched so far (end of the stream).

        Raises:
            CalibrationError: the pair does not look rectified, or looks swapped.
        """
        try:
            self._decide()
            if not self.done and self.frames:
                self._judge(end=True)
        finally:
            self._close()

    def _decide(self) -> None:
        try:
            if self._pending is not None:
                (future, rectifier), self._pending = self._pending, None
                self._add(future.result(), rectifier)
        finally:
            if self.done:
                self._close()

    def _close(self) -> None:
        self._pending = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def _add(self, matched: _Matched, rectifier: rect.StereoRectifier | None) -> None:
        """Add one frame's correspondences and change; decide once there are enough."""
        matches, change, refined = matched
        self.refined.append(refined)
        if matches.shape[0]:  # a dark frame (change 0) says nothing of the two views
            self.changes.append(change)
        self.frames += 1
        self.frames_with_matches += int(matches.shape[0] >= ROW_CHECK_FRAME_MATCHES)
        self.points.append((matches, rectifier))
        if (
            sum(points.shape[0] for points, _ in self.points) < ROW_CHECK_MATCHES
            and self.frames_with_matches < ROW_CHECK_FRAMES
            and self.frames < ROW_CHECK_MAX_FRAMES
        ):
            return
        self._judge(end=False)

    def _judge(self, *, end: bool) -> None:
        """Give the verdict on the frames matched (``end``: the stream ended first)."""
        self.done = True
        chunks, self.points = self.points, []
        points = np.concatenate([points for points, _ in chunks])
        frames = f"the first {self.frames} frames"
        if end:
            frames = "the log's only frame" if self.frames == 1 else f"all {self.frames} frames"
        if points.shape[0] < ROW_CHECK_MIN_MATCHES:
            self.undecided = (
                f"could not check that {self.pair} is rectified and not swapped: "
                f"{points.shape[0]} matched corners in {frames}, {ROW_CHECK_MIN_MATCHES} "
                "needed (dark, blank or unrelated images); it was densified unchecked: if "
                "the depth looks wrong, check the camera infos and which camera each topic "
                "carries"
            )
            return
        offset = rect.row_offset(points)
        where = f"median over {offset.matches} matched corners of the first {self.frames} frame(s)"
        if offset.median_abs_dy > MAX_ROW_OFFSET_PX and not self._rows_refined(offset):
            matched = [(p, r) for p, r in chunks if p.shape[0]]
            remapped = [(p, r) for p, r in matched if r is not None]
            if remapped and len(remapped) == len(matched):  # raw pairs: were the sides crossed?
                exchanged = exchanged_offset(remapped)
                if (
                    exchanged.median_abs_dy <= MAX_ROW_OFFSET_PX
                    and exchanged.median_dx >= MIN_MEDIAN_DISPARITY_PX
                ):
                    raise CalibrationError(
                        f"the stereo pair {self.pair} does not look rectified: matched corners "
                        f"are {offset.median_abs_dy:.2f} px apart vertically ({where}), but "
                        f"{exchanged.median_abs_dy:.2f} px with the two images exchanged: left "
                        "and right look swapped (each topic carries the other camera's "
                        f"images); pass {self.swap_flags()}"
                    )
            if remapped:
                fix = "the calibration does not fit these images: check the camera infos" + (
                    " (or the --calibration files)" if self.info_topics is None else ""
                )
            else:
                fix = (
                    "pass --rectify always to remap them with their CameraInfo (or "
                    "--calibration files), or check the CameraInfo"
                )
            raise CalibrationError(
                f"the stereo pair {self.pair} does not look rectified: matched corners are "
                f"{offset.median_abs_dy:.2f} px apart vertically ({where}; rectified < "
                f"{MAX_ROW_OFFSET_PX:g} px); {fix}; --rectify never uses the pair as "
                "recorded, unchecked"
            )
        same = float(np.mean(np.abs(points[:, :2] - points[:, 2:]).max(axis=1) < SAME_VIEW_PX))
        if same >= SAME_VIEW_SHARE and float(np.median(self.changes or [0.0])) < SAME_VIEW_CHANGE:
            right = self.topics[1]
            raise CalibrationError(
                f"the stereo pair {self.pair} shows one view twice: {same:.0%} of "
                f"{offset.matches} matched corners of the first {self.frames} frame(s) are "
                f"within {SAME_VIEW_PX:g} px of each other and the images barely differ, so "
                f"{right} carries the left camera's images (a remap or republish of the wrong "
                "camera); pass the right camera's image topic as --right-topic (only a scene "
                "beyond stereo range everywhere looks like this; --rectify never uses the "
                "pair as recorded, unchecked)"
            )
        if offset.median_dx < MIN_MEDIAN_DISPARITY_PX:
            raise CalibrationError(
                f"the stereo pair {self.pair} has negative disparities: x_left - x_right = "
                f"{offset.median_dx:.1f} px ({where}): left and right look swapped; pass "
                f"{self.swap_flags()} (or fix the baseline sign of the right camera's P); "
                "--rectify never uses the pair as recorded, unchecked"
            )

    def _rows_refined(self, offset: rect.RowOffset) -> bool:
        """Whether the matches found on one pyramid level in both images lie on one row.

        Only asked of a pair the ORB positions would refuse; says so once when they are.
        """
        refined = np.concatenate(self.refined) if self.refined else np.zeros(0)
        refined = refined[np.isfinite(refined)]
        if refined.size < ROW_CHECK_MIN_MATCHES:
            return False
        median = float(np.median(refined))
        if median > SAME_LEVEL_MAX_PX:
            return False
        note_once(
            "rows_refined",
            f"the stereo pair {self.pair}'s ORB corners are {offset.median_abs_dy:.2f} px apart "
            f"vertically, but {median:.2f} px for the {refined.size} found on the same pyramid "
            "level in both images: rectified (one image is blurred or softer than the other)",
        )
        return True

    def swap_flags(self) -> str:
        """Return the options that exchange the two image topics, the camera infos kept."""
        left, right = self.topics
        flags = f"--left-topic {right} --right-topic {left}"
        if self.info_topics is None:
            return flags
        left_info, right_info = self.info_topics
        return f"{flags} --left-info-topic {left_info} --right-info-topic {right_info}"


def view_change(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic]) -> float:
    """Return mean |left - right| over mean |left - left shifted by one column| (grey levels).

    Below 1 the two images differ less than one of them does from itself moved by a pixel:
    one camera's view twice (with coding noise), not two cameras'. inf when the sizes differ.
    """
    a = rect.grey8(left).astype(np.float32)
    b = rect.grey8(right).astype(np.float32)
    if a.shape != b.shape or a.shape[1] < 2:
        return float("inf")
    texture = float(np.mean(np.abs(a[:, 1:] - a[:, :-1])))
    return float(np.mean(np.abs(a - b))) / max(texture, 1e-6)


def _match(
    left: npt.NDArray[np.generic], right: npt.NDArray[np.generic]
) -> tuple[npt.NDArray[np.float64], float, npt.NDArray[np.float64]]:
    """Return one frame's correspondences, :func:`view_change` and :func:`same_level_dy`."""
    points = rect.correspondences(left, right)
    return points, view_change(left, right), same_level_dy(left, right, points)


def same_level_dy(
    left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], points: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Return |y_left - y_right| of the ORB matches found on one pyramid level in both images.

    ORB places a keypoint found on pyramid level L to that level's pixel (1.2**L px): with
    one side blurred vertically (motion blur, 15 px) its corners are found on other levels
    than the sharp side's, and the |dy| of a rectified pair came in steps of 0, 1.2, 1.44,
    1.73 px, median 1.44 (a synthetic indoor pair and street drive); the matches found on
    the same level in both images had a median of 0 (96 of 120). A frame whose ``points``
    (:func:`~rect.correspondences`) have a median |dy| under :data:`SAME_LEVEL_FROM_PX` is
    not matched again: their |dy| is returned.
    """
    dy = np.abs(points[:, 1] - points[:, 3])
    if not dy.size or float(np.median(dy)) < SAME_LEVEL_FROM_PX:
        return dy
    orb = cv2.ORB.create(nfeatures=1500)  # as rect.correspondences, with the levels kept
    a, b = cv2.equalizeHist(rect.grey8(left)), cv2.equalizeHist(rect.grey8(right))
    kp_l, des_l = orb.detectAndCompute(a, None)
    kp_r, des_r = orb.detectAndCompute(b, None)
    if des_l is None or des_r is None or len(kp_l) < 8 or len(kp_r) < 8:
        return np.zeros(0)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(des_l, des_r)
    if len(matches) < 15:
        return np.zeros(0)
    pts = np.array([[*kp_l[m.queryIdx].pt, *kp_r[m.trainIdx].pt] for m in matches])
    _, mask = cv2.findFundamentalMat(pts[:, :2], pts[:, 2:], cv2.FM_RANSAC, 1.0, 0.999)
    if mask is None or mask.sum() < rect.MIN_INLIER_SHARE * len(matches):
        return np.zeros(0)
    same = np.array([kp_l[m.queryIdx].octave == kp_r[m.trainIdx].octave for m in matches])
    keep = mask.ravel().astype(bool) & same
    return np.asarray(np.abs(pts[keep, 1] - pts[keep, 3]), dtype=np.float64)


SAME_LEVEL_MAX_PX = 0.5
"""Largest median |dy| (px) of the matches found on one level (:func:`same_level_dy`) with
which a pair the ORB positions refuse is taken as rectified: such matches share one pixel
grid, so a rectified pair's are 0 (the synthetic indoor pair, its right side blurred 15 px:
0.00 over 196); its raw (unrectified) images, blurred alike: 1.00 px over 148."""

SAME_LEVEL_FROM_PX = 0.5
"""A checked frame whose matched corners' median |dy| reaches this (px) is matched again for
:func:`same_level_dy` (a sharp rectified pair's median is 0: 85 % of its |dy| are 0)."""


def exchanged_offset(
    chunks: list[tuple[npt.NDArray[np.float64], rect.StereoRectifier]],
) -> rect.RowOffset:
    """Return the row offset of matched corners of remapped pairs with the raw images exchanged.

    A raw pair whose topics carry each other's camera (crossed cables) is remapped with the
    wrong calibration on both sides: its corners are rows apart, not at negative disparities.
    Each corner is taken back to its raw image through its side's maps and rectified with the
    other side's calibration: a swapped pair is then on one row.

    Args:
        chunks: per frame, (n, 4) float64 x_left, y_left, x_right, y_right of matched
            corners (px in the rectifier's box) and the rectifier that remapped the frame.

    Returns:
        The offset of the exchanged pair (px of the rectified image).
    """
    exchanged = []
    for points, rectifier in chunks:
        calibration = rectifier.aligned  # the maps' (the right on the left's cx)
        box_x, box_y, _, _ = rectifier.box
        raw: list[npt.NDArray[np.float64]] = []
        for cal, xy in ((calibration.left, points[:, :2]), (calibration.right, points[:, 2:])):
            map_x, map_y = cal.rectification_maps(calibration.left)  # the left's image
            at_x = (xy[:, :1].T + box_x).astype(np.float32)  # (1, n): remap reads a map at them
            at_y = (xy[:, 1:].T + box_y).astype(np.float32)
            raw_x = cv2.remap(map_x, at_x, at_y, cv2.INTER_LINEAR).ravel()
            raw_y = cv2.remap(map_y, at_x, at_y, cv2.INTER_LINEAR).ravel()
            roi_x, roi_y, _, _ = cal.region()
            bin_x, bin_y = cal.binning  # the maps are in binned pixels of the ROI
            full = np.stack([raw_x * bin_x + roi_x, raw_y * bin_y + roi_y], axis=1)
            raw.append(full.astype(np.float64))
        # the left image was taken by the right camera, and the other way round
        new_left = calibration.left.raw_to_rectified(raw[1])
        new_right = calibration.right.raw_to_rectified(raw[0])
        bin_x, bin_y = calibration.left.binning
        exchanged.append(np.hstack([new_left, new_right]) / [bin_x, bin_y, bin_x, bin_y])
    return rect.row_offset(np.concatenate(exchanged))
