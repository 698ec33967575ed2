"""Pair left and right images of a message stream into stereo frames (no I/O).

:class:`StereoPairer` is fed the decoded messages of a log one at a time (in the reader's
order) and emits a :class:`~records.StereoFrame` as soon as a left and a right image with matching
header stamps, and a camera info of each side, are there. What waits for its partner is held
by log time (streams logged seconds apart, with the same stamps, still pair) and bounded in
messages and bytes (:mod:`frontend.pairing_window`), so a stream with a missing side cannot
make it grow; what it drops it counts in :class:`PairingStats`. An optional sparse feature
stream (``/features``, PointCloud2 with x, y, z in the left optical frame) is associated with
the frames by stamp: each takes the cloud nearest its own, held as the images are
(:mod:`~pcainterp_stream.frontend.feature_match`).

A single pass over a log (the processor's loop)::

    pairer = StereoPairer(PairingConfig(features_topic="/features"))
    with open_log(path) as reader:
        reader.require_topics(pairer.config.required_topics())
        for raw in reader.messages():
            writer.add_raw(raw)
            for frame in pairer.push_raw(raw, reader.decode):
                processor.submit(frame, pairer.features_for(frame))
    for frame in pairer.flush():
        processor.submit(frame, pairer.features_for(frame))
    stats = pairer.finish()
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError, LogReadError
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.camera_infos import (
    calibration_values,
    camera_from_infos,
    first_infos,
)
from pcainterp_stream.frontend.feature_match import FeatureMatcher, features_from_pointcloud
from pcainterp_stream.frontend.image_clock import ImageClock
from pcainterp_stream.frontend.pair_forms import (
    describe,
    grey_alike,
    is_copy,
    is_rectified_name,
)
from pcainterp_stream.frontend.pairing_config import PairingConfig as PairingConfig
from pcainterp_stream.frontend.pairing_stats import MAX_CAMERA_LINES, PairingStats, first_clause
from pcainterp_stream.frontend.pairing_window import HeldQueue, Hold, HoldLimits
from pcainterp_stream.frontend.pairing_window import PendingImage as _Pending
from pcainterp_stream.frontend.rect_border import BorderFinder, RectifiedBorder
from pcainterp_stream.frontend.right_cx import as_is_shift, shift_image
from pcainterp_stream.frontend.row_check import Corners, RowCheck
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import LogReader, decode_image
from pcainterp_stream.records import (
    DensifiedFrame,
    RawMessage,
    SparseFeatures,
    StereoCamera,
    StereoFrame,
)

MAX_HELD_RECTIFIERS = 256
"""Frames whose rectifier is kept for :meth:`StereoPairer.full_result` when nobody asks,
beyond the frames the hold may keep waiting for their clouds (``hold_count``)."""

_OTHER = {"left": "right", "right": "left"}

NEAR_MISS_NS = 50_000_000
"""An unpaired image with an other-side image this near (ns) is counted as a near miss."""

RECENT_INTERVALS = 16
"""Log-time intervals of a side kept for its frame interval (their median)."""


class StereoPairer:
    """Incrementally pair stereo images by header stamp; see the module docstring.

    Args:
        config: topics, stamp tolerance, window and options.
    """

    def __init__(
        self, config: PairingConfig | None = None, echo: Callable[[str], None] | None = None
    ) -> None:
        self.config = config or PairingConfig()
        self._echo = echo
        self._rectifier: rect.StereoRectifier | None = None
        self._rect_infos: tuple[Any, Any] | None = None
        self._said: str | None = None
        self._rectify_changes = 0  # rectify lines said after the first one (capped)
        self._mixed_said = False  # the encodings line of a pair of two encodings
        # the frames estimated in a box: remapped, or rectified with a border (rect_border)
        self._frame_rectifier: dict[int, rect.StereoRectifier | RectifiedBorder] = {}
        # frame -> the stamp of its outputs when its left image's does not place it (full_result)
        self._restamped: dict[int, int] = {}
        self._left_clock = ImageClock()  # where such a left image is placed
        self._borders = BorderFinder(echo)
        self._as_is: rect.StereoCalibration | None = None  # of images used as they are
        self._right_shift = 0.0  # px moving their right images onto the left's cx (right_cx)
        self._rows = (
            RowCheck(
                self.config.left_topic,
                self.config.right_topic,
                info_topics=None
                if self.config.calibration is not None
                else (self.config.left_info_topic, self.config.right_info_topic),
            )
            if self.config.check_rows and self.config.rectify != "never"
            else None
        )
        config = self.config
        self.stats = PairingStats(tolerance_ns=config.tolerance_ns, window=config.window)
        limits = HoldLimits(config.window, config.hold_ns, config.hold_count, config.hold_bytes)
        self._hold = Hold(limits, config.tolerance_ns)  # by log time, count and bytes
        self.stats.hold = limits
        self._left: HeldQueue[_Pending] = self._hold.queue(_Pending.nbytes)
        self._right: HeldQueue[_Pending] = self._hold.queue(_Pending.nbytes)
        self._matched: deque[tuple[_Pending, _Pending]] = deque()  # waiting for camera info
        self._left_info: Any = None
        self._right_info: Any = None
        self._camera_cache: dict[tuple[int, int, int, int], StereoCamera] = {}
        # frames waiting for the cloud nearest their stamp, and the clouds waiting for a frame
        self._features = FeatureMatcher(config.tolerance_ns, self._hold, self.stats)
        self._last_stamp = {"left": -(2**63), "right": -(2**63)}
        self._first_dropped_ns: int | None = None  # first pair dropped waiting for infos
        # info topic -> (log time, calibration_values) of the camera info read ahead
        self._ahead: dict[str, tuple[int, tuple[Any, ...]]] = {}
        self._ahead_unseen: set[str] = set()  # read ahead, not yet met in the stream
        self._index = 0
        self._by_log_time = False  # the stamps do not tell the images apart: by log time
        self._last_log = {"left": -1, "right": -1}  # log time of each side's last image
        # each side's last log-time intervals (its frame interval) and image (a duplicate?)
        self._intervals = {side: deque[int](maxlen=RECENT_INTERVALS) for side in _OTHER}
        # each side's last header-stamp intervals (the frame interval the stamps give)
        self._stamp_steps = {side: deque[int](maxlen=RECENT_INTERVALS) for side in _OTHER}
        self._last_image: dict[str, _Pending | None] = {"left": None, "right": None}
        self._lag_ns = 0  # by log time: right minus left log time of the pairs made by stamp
        self._info_stamp = {"left": -1, "right": -1}  # header stamp of each side's last info
        self._infos_follow = False  # infos carry their image's stamp and come after it
        self._paired_by_stamp = 0
        # (stamp, left log time, right log time) of the last pairs made by stamp
        self._recent: deque[tuple[int, int, int]] = deque(maxlen=self.config.window)

    def wants(self, topic: str) -> bool:
        """Return True for a topic this pairer reads (decode only those)."""
        return topic in self.config.required_topics()

    def push_raw(self, raw: RawMessage, decode: Callable[[RawMessage], Any]) -> list[StereoFrame]:
        """Decode a raw message of a wanted topic with ``decode`` and :meth:`push` it.

        Messages of other topics return [] without being decoded; a message that does not
        decode is counted in ``stats.undecodable``.
        """
        if not self.wants(raw.topic):
            return []
        try:
            message = decode(raw)
            stamp = rosmsg.stamp_ns(message)
        except (LogReadError, AttributeError) as err:
            self._undecodable("message does not deserialize", f"{raw.topic}: {err}")
            return []
        return self.push(raw.topic, stamp, raw.log_time_ns, message)

    def push(self, topic: str, stamp_ns: int, log_time_ns: int, message: Any) -> list[StereoFrame]:
        """Add one decoded message; return the frames it completes (often none, or one).

        Args:
            topic: the message's topic; topics outside the configuration are ignored.
            stamp_ns: header stamp (ns).
            log_time_ns: log time (ns).
            message: the decoded typestore message (images are converted to arrays only
                when paired).

        Raises:
            CalibrationError: a camera info without usable fx or baseline (see
                :func:`camera_from_infos`).
            LogReadError: a size mismatch when ``fail_on_size_mismatch`` is set.
        """
        config = self.config
        self._hold.saw(log_time_ns)
        if config.calibration is not None and topic in (
            config.left_info_topic,
            config.right_info_topic,
        ):
            return []  # the calibration files stand for the camera infos
        if topic in (config.left_info_topic, config.right_info_topic):
            if topic == config.left_info_topic:
                self._left_info = message
                self._info_stamp["left"] = stamp_ns
            if topic == config.right_info_topic:  # or one info for both sides (--baseline)
                self._right_info = message
                self._info_stamp["right"] = stamp_ns
            if stamp_ns in (self._last_stamp["left"], self._last_stamp["right"]) and stamp_ns:
                # infos stamped as their images, recorded after them: a pair waits for its own
                self._infos_follow = True
            first = self._first_dropped_ns
            if first is not None and self.stats.info_late_ns < 0 and self._has_infos():
                self.stats.info_late_ns = max(0, log_time_ns - first)
            self._meet_ahead(topic, message)
            return self._release_matched()
        if topic == config.features_topic:
            return self._push_features(message, log_time_ns)
        if topic == config.left_topic:
            return self._push_image("left", _Pending(stamp_ns, log_time_ns, message))
        if topic == config.right_topic:
            return self._push_image("right", _Pending(stamp_ns, log_time_ns, message))
        return []

    def look_ahead(self, topic: str, log_time_ns: int, message: Any) -> None:
        """Take a side's first camera info, read ahead of the stream (:meth:`read_ahead`).

        Until the stream brings a camera info of that side, pairs use this one instead of
        waiting for it (and falling out of the window): a log whose camera infos were
        recorded late is densified whole. The pairs made with it are counted
        (``stats.pairs_before_info``); a camera info of the topic later in the stream with
        another calibration is noted (``stats.changed_info_topics``). Call before the stream.
        """
        config = self.config
        if config.calibration is not None:
            return
        if topic == config.left_info_topic and self._left_info is None:
            self._left_info = message
        if topic == config.right_info_topic and self._right_info is None:
            self._right_info = message
        self._ahead[topic] = (log_time_ns, calibration_values(message))
        self._ahead_unseen.add(topic)

    def read_ahead(self, reader: LogReader) -> None:
        """:meth:`look_ahead` of each side's first camera info, when the log has an index."""
        config = self.config
        if config.calibration is None:
            for topic, log_time_ns, message in first_infos(
                reader, [config.left_info_topic, config.right_info_topic]
            ):
                self.look_ahead(topic, log_time_ns, message)

    def _meet_ahead(self, topic: str, message: Any) -> None:
        """Note a stream camera info of a topic read ahead: met, and changed or not."""
        ahead = self._ahead.get(topic)
        if ahead is None:
            return
        self._ahead_unseen.discard(topic)
        changed = self.stats.changed_info_topics
        if topic not in changed and calibration_values(message) != ahead[1]:
            changed.append(topic)

    def features_for(self, frame: StereoFrame) -> SparseFeatures | None:
        """Return (once) the feature cloud nearest a frame's stamp, or None when there is none.

        With a features topic configured, frames are released only once their cloud is
        known (:class:`~pcainterp_stream.frontend.feature_match.FeatureMatcher`), or they
        were held as long as :attr:`PairingConfig.hold_ns` allows.
        """
        features = self._features.take(frame.index)
        rectifier = self._frame_rectifier.get(frame.index)
        if features is not None and isinstance(rectifier, rect.StereoRectifier):  # raw -> rect
            features = features._replace(points=rectifier.rotate_points(features.points))
        return features

    def row_corners(self, index: int) -> Corners | None:
        """The row check's matched corners of frame ``index`` (:meth:`.RowCheck.corners`)."""
        return self._rows.corners(index) if self._rows is not None else None

    def flush(self) -> list[StereoFrame]:
        """Release the frames still held (call at the end of the stream).

        Those waiting for features, and a last pair waiting for infos of its own stamp.
        """
        frames = self._release_matched(force=True) if self._matched else []
        return frames + self._features.flush()

    def finish(self) -> PairingStats:
        """Count what is left unpaired and return the final statistics.

        Call :meth:`flush` first to get held frames; frames still held are dropped here.

        Raises:
            CalibrationError: the row check, finished here, refuses the pair.
        """
        if self._rows is not None:
            self._rows.finish()
            self.stats.row_check_undecided = self._rows.undecided
        self.flush()
        self.stats.stamp_period_ns = _median(
            [*self._stamp_steps["left"], *self._stamp_steps["right"]]
        )
        self._count_unpaired("left", self._left)
        self._count_unpaired("right", self._right)
        if self._matched:
            self._count_no_info(len(self._matched))
            self.stats.note(
                f"{len(self._matched)} pairs never had a camera info on both "
                f"{self.config.left_info_topic} and {self.config.right_info_topic}"
            )
        self._left.clear()
        self._right.clear()
        self._matched.clear()
        return self.stats

    # images ---------------------------------------------------------------------------
    def _push_image(self, side: str, item: _Pending) -> list[StereoFrame]:
        if is_copy(item, self._last_image[side]):  # the same message again: no frame
            topic = self.config.left_topic if side == "left" else self.config.right_topic
            self.stats.saw_duplicate(topic, item.stamp_ns, item.log_time_ns)
            return []
        self._last_image[side] = item
        if self._last_log[side] >= 0:
            self._intervals[side].append(item.log_time_ns - self._last_log[side])
        frames: list[StereoFrame] = []
        # a header stamp of 0 (not set) or of the side's previous image does not place it
        if side == "left":
            item.restamp = self._left_clock.place(item.stamp_ns, item.log_time_ns)
        if not self._by_log_time and item.stamp_ns == self._last_stamp[side]:
            frames = self._stamps_repeat(side, item.stamp_ns, _median(self._intervals[side]))
        if item.stamp_ns < self._last_stamp[side]:
            self.stats.non_monotonic_stamps += 1
        elif self._last_stamp[side] > 0 and item.stamp_ns > self._last_stamp[side]:
            self._stamp_steps[side].append(item.stamp_ns - self._last_stamp[side])
        self.stats.first_stamps_ns.setdefault(side, item.stamp_ns)
        self._last_stamp[side] = item.stamp_ns
        self._last_log[side] = item.log_time_ns
        return frames + self._match(side, item)

    def _match(self, side: str, item: _Pending) -> list[StereoFrame]:
        """Pair an image with the other side's nearest (by :meth:`_time`), or queue it."""
        own, other = (self._left, self._right) if side == "left" else (self._right, self._left)
        partner = self._closest(other, _OTHER[side], self._time(item, side))
        if partner is None:
            # each waiting image keeps its nearest other-side image (before or after it) that
            # waited too: the partner a wider tolerance would give it, not a paired neighbour
            gaps = [self._time(p, _OTHER[side]) - self._time(item, side) for p in other]
            for waiting, gap in zip(other, gaps, strict=True):
                waiting.miss_ns = _nearer(waiting.miss_ns, abs(gap))
                item.miss_ns = _nearer(item.miss_ns, abs(gap))
            nearest = min(gaps, key=abs, default=None)
            if nearest is not None:
                self.stats.saw_gap(nearest if side == "left" else -nearest, self._by_log_time)
            if other and not self._by_log_time:  # its own frame's: the nearest by log time
                own_frame = min(other, key=lambda p: abs(p.log_time_ns - item.log_time_ns))
                offset = own_frame.stamp_ns - item.stamp_ns
                self.stats.saw_frame_offset(
                    abs(own_frame.log_time_ns - item.log_time_ns),
                    offset if side == "left" else -offset,
                )
            self._lost_partner(side, item)
            own.append(item)
            self._count_unpaired(side, self._hold.give_up(side, own))
            return []
        other.remove(partner)
        left, right = (item, partner) if side == "left" else (partner, item)
        # Stamps before this pair (minus the tolerance) will not pair any more in an
        # ordered stream: drop them now so the counts are exact and the buffers small.
        horizon = self._time(left, "left") - self._tolerance()
        for queue, name in ((self._left, "left"), (self._right, "right")):
            stale = [p for p in queue if self._time(p, name) < horizon]
            for p in stale:
                queue.remove(p)
            self._count_unpaired(name, stale)
        self._matched.append((left, right))
        if len(self._matched) > self.config.window:
            dropped, _ = self._matched.popleft()
            if self._first_dropped_ns is None:
                self._first_dropped_ns = dropped.log_time_ns
            self._count_no_info(1)
        return self._release_matched()

    def _lost_partner(self, side: str, item: _Pending) -> None:
        """Count a pair lost: an unpaired image whose partner of its stamp was given up."""
        given_up = None if self._by_log_time else self._hold.taken(_OTHER[side], item.stamp_ns)
        if given_up is not None:  # right log time minus left log time
            lag = item.log_time_ns - given_up.log_time_ns
            self.stats.lost_pairs.add(lag if side == "right" else -lag, given_up)

    def _tolerance(self) -> int:
        """Return the pairing's tolerance (ns): by log time, at least a quarter frame."""
        return self.stats.log_tolerance_ns if self._by_log_time else self.config.tolerance_ns

    def _time(self, item: _Pending, side: str) -> int:
        """Return what pairs an image: its header stamp, or log time (:meth:`_stamps_repeat`).

        By log time, a right image's is less the sides' lag measured on the pairs by stamp.
        """
        if not self._by_log_time:
            return item.stamp_ns
        return item.log_time_ns - (self._lag_ns if side == "right" else 0)

    def _stamps_repeat(self, side: str, stamp_ns: int, period_ns: int) -> list[StereoFrame]:
        """Pair by log time from now on: an image has its side's previous stamp again.

        Such stamps (all 0 from a driver that sets none, or a coarse clock's) do not tell the
        images of a side apart, so the nearest stamp would pair first-come (after a dropped
        image, each left with the next right). A stamp that is 0 only once pairs as any.
        Pairs made by stamp before the repeat showed that have this stamp are checked by log
        time: those still waiting for camera infos are paired again, those already made are
        counted (``stats.unsure_pairs``). Returns the frames the pairing again completes.

        By log time the tolerance is at least a quarter of the side's frame interval
        (``period_ns``, the median of its last ones, so that no one short gap sets it): the
        two sides of a pair are received apart by their drivers' jitter, often more than the
        stamps' 1 ms, and a quarter frame still never reaches the next frame's image. The
        steady lag of the right images' log times after the left ones, measured on the pairs
        made by (other) stamps, is subtracted: sides logged apart still pair by log time.
        """
        self._by_log_time = True
        self.stats.log_period_ns = max(period_ns, 0)
        self.stats.log_tolerance_ns = max(self.config.tolerance_ns, max(period_ns, 0) // 4)
        tolerance = self.stats.log_tolerance_ns
        lags = [right - left for pair_stamp, left, right in self._recent if pair_stamp != stamp_ns]
        lags += [
            r.log_time_ns - left.log_time_ns
            for left, r in self._matched
            if left.stamp_ns != stamp_ns
        ]
        self._lag_ns = self.stats.log_lag_ns = _median(lags)
        lag = self._lag_ns
        stats = self.stats
        config = self.config
        stats.repeated_stamp_topic = config.left_topic if side == "left" else config.right_topic
        stats.repeated_stamp_ns = stamp_ns
        stats.pairs_by_stamp = self._paired_by_stamp + len(self._matched)
        stats.unsure_pairs = [
            (left_log_ns, abs(right_log_ns - left_log_ns - lag))
            for pair_stamp_ns, left_log_ns, right_log_ns in self._recent
            if pair_stamp_ns == stamp_ns and abs(right_log_ns - left_log_ns - lag) > tolerance
        ]
        unsure = [
            (left, right)
            for left, right in self._matched
            if left.stamp_ns == stamp_ns
            and abs(right.log_time_ns - left.log_time_ns - lag) > tolerance
        ]
        frames: list[StereoFrame] = []
        for left, right in unsure:
            self._matched.remove((left, right))
            stats.pairs_by_stamp -= 1
            for item, item_side in sorted(
                ((left, "left"), (right, "right")), key=lambda pair: pair[0].log_time_ns
            ):
                frames.extend(self._match(item_side, item))
        return frames

    def _has_infos(self) -> bool:
        return self._left_info is not None and self._right_info is not None

    def _count_no_info(self, count: int) -> None:
        """Count pairs dropped for want of a camera info, and the info topics still silent."""
        self.stats.no_camera_info += count
        config, missing = self.config, self.stats.missing_info_topics
        for info, topic in (
            (self._left_info, config.left_info_topic),
            (self._right_info, config.right_info_topic),
        ):
            if info is None and topic not in missing:
                missing.append(topic)

    def _count_unpaired(self, side: str, dropped: Sequence[_Pending]) -> None:
        if side == "left":
            self.stats.unpaired_left += len(dropped)
        else:
            self.stats.unpaired_right += len(dropped)
        self.stats.near_misses_ns.extend(p.miss_ns for p in dropped if p.miss_ns >= 0)

    def _closest(self, queue: deque[_Pending], side: str, time_ns: int) -> _Pending | None:
        best: _Pending | None = None
        best_gap = 0
        for candidate in queue:
            gap = abs(self._time(candidate, side) - time_ns)
            if gap <= self._tolerance() and (best is None or gap < best_gap):
                best, best_gap = candidate, gap
        return best

    def _release_matched(self, *, force: bool = False) -> list[StereoFrame]:
        """Make the frames of the pairs matched, in order, once camera infos are there.

        When the infos carry their images' stamps and are recorded after them (a camera
        publisher's order), the newest pair waits for infos of its own stamp, so that a
        change of calibration or size applies from its own frame; a newer pair (or
        ``force``, at the end) releases it with the infos there are.
        """
        if self.config.calibration is None and not self._has_infos():
            return []
        frames: list[StereoFrame] = []
        while self._matched:
            left, right = self._matched[0]
            if not force and len(self._matched) == 1 and self._info_behind(left.stamp_ns):
                break
            self._matched.popleft()
            if not self._by_log_time:
                self._paired_by_stamp += 1
                self._recent.append((left.stamp_ns, left.log_time_ns, right.log_time_ns))
            frame = self._make_frame(left, right)
            if frame is not None:
                frames.extend(self._hold_for_features(frame))
        return frames

    def _info_behind(self, stamp_ns: int) -> bool:
        """Whether a pair of this stamp should wait for infos stamped as it (see above)."""
        if not self._infos_follow or self.config.calibration is not None or self._by_log_time:
            return False
        return any(self._info_stamp[side] < stamp_ns for side in ("left", "right"))

    def _make_frame(self, left: _Pending, right: _Pending) -> StereoFrame | None:
        try:
            left_image = decode_image(left.message)
        except ValueError as err:
            self._undecodable(_reason(err), f"{self.config.left_topic} at {left.stamp_ns}: {err}")
            return None
        try:
            right_image = decode_image(right.message)
        except ValueError as err:
            self._undecodable(_reason(err), f"{self.config.right_topic} at {right.stamp_ns}: {err}")
            return None
        rectifier = self.rectification()
        if rectifier is not None:  # estimated in the box valid in both cameras, see full_result
            left_image, right_image = rectifier.rectify(left_image, right_image)
            x, y, w, h = rectifier.box
            left_image = left_image[y : y + h, x : x + w]
            right_image = right_image[y : y + h, x : x + w]
        grey_left, grey_right, converted = grey_alike(left_image, right_image)
        if converted and not self._mixed_said and self._echo is not None:  # colour + mono
            self._mixed_said = True  # (not _say: the rectify line is said once by _said)
            self._echo(
                f"encodings: the left images are {describe(left_image)}, the right ones "
                f"{describe(right_image)}: {converted}"
            )
        left_image, right_image = grey_left, grey_right
        if left_image.shape != right_image.shape or left_image.dtype != right_image.dtype:
            sized = left_image.shape[:2] != right_image.shape[:2]
            need = (
                "a rectified pair needs equal sizes"
                if sized
                else "the sizes are equal, the encodings (channels or bit depth) differ"
            )
            problem = (
                f"left image at stamp {left.stamp_ns} is {describe(left_image)} but right "
                f"image at stamp {right.stamp_ns} is {describe(right_image)}; {need}"
            )
            if self.config.fail_on_size_mismatch:
                raise LogReadError(problem)
            if sized:
                self.stats.size_mismatches += 1
            else:
                self.stats.encoding_mismatches += 1
            self.stats.note(problem)
            return None
        height, width = left_image.shape[:2]
        boxed: rect.StereoRectifier | RectifiedBorder | None = rectifier
        if rectifier is not None:
            camera, seen = rectifier.inner, rectifier.camera
        else:
            camera = seen = self._camera(width, height)
            right_image = self.as_is(right_image, "right")  # onto the left's cx
            # a black border, and the columns the shift brings in, are estimated around
            look = self.config.rectify != "never"
            calibration = self._as_is if look else None
            border = self._borders.find(
                left_image, right_image, camera, calibration, shift=self._right_shift, look=look
            )
            if border is not None:
                left_image, right_image = border.crop(left_image), border.crop(right_image)
                camera, boxed = border.inner, border
        # the camera line names the camera the outputs have (full_result pads the box back
        # to it), as the rectify line does, not the box the estimate is made in
        changed = self.stats.saw_camera(seen, self._baseline_source(rectifier), left.log_time_ns)
        if changed is not None and self._echo is not None:
            self._echo(changed)
        frame = StereoFrame(
            index=self._index,
            stamp_ns=left.stamp_ns,
            log_time_ns=left.log_time_ns,
            frame_id=str(left.message.header.frame_id),
            left=left_image,
            right=right_image,
            camera=camera,
        )
        if self._rows is not None:
            self._rows.see(left_image, right_image, rectifier=rectifier, index=self._index)
        keep = MAX_HELD_RECTIFIERS + self.config.hold_count  # frames held for clouds too
        if boxed is not None:
            self._frame_rectifier[self._index] = boxed
            if len(self._frame_rectifier) > 4 * keep:  # nobody asks (learn)
                for index in sorted(self._frame_rectifier)[:-keep]:
                    del self._frame_rectifier[index]
        if left.restamp is not None:
            self._restamped[self._index] = left.restamp.stamp_ns
            self.stats.restamped(by_log_time=left.restamp.by_log_time)
            if len(self._restamped) > 4 * keep:  # nobody asks (learn)
                for index in sorted(self._restamped)[:-keep]:
                    del self._restamped[index]
        self._index += 1
        self.stats.pairs += 1
        self.stats.remapped += rectifier is not None
        if self._ahead_unseen:  # made with a camera info read ahead
            stats = self.stats
            if not stats.pairs_before_info:
                stats.missing_info_topics = sorted(self._ahead_unseen)
                latest = max(self._ahead[topic][0] for topic in self._ahead_unseen)
                stats.info_late_ns = max(0, latest - left.log_time_ns)
            stats.pairs_before_info += 1
        return frame

    def full_result(self, result: DensifiedFrame) -> DensifiedFrame:
        """Return a densified frame at the rectified size ``image_proc`` gives (``image_rect``).

        A remapped pair is estimated in the box of the rectified image that both raw images
        cover (:attr:`frontend.rectify.StereoRectifier.box`: the view a camera with this
        calibration has), a rectified pair with a black border in the box inside the border
        (:mod:`frontend.rect_border`); outside it the outputs have no estimate (NaN).

        A frame whose left image's header stamp does not place it (0, not set, or the stamp
        of the image before it) gets a stamp downstream readers (``evaluate``, a viewer's
        time line, tf) can place it at, the stamp of its outputs: on the images' header clock
        when an image before it had a stamp of its own, else that image's log time
        (:mod:`frontend.image_clock`). Other frames are returned as they are.
        """
        stamp_ns = self._restamped.pop(result.frame.index, None)
        if stamp_ns is not None:
            result = result._replace(frame=result.frame._replace(stamp_ns=stamp_ns))
        rectifier = self._frame_rectifier.pop(result.frame.index, None)
        if rectifier is None:
            return result
        return rect.pad_result(result, rectifier)

    def rectification(self) -> rect.StereoRectifier | None:
        """Return the rectifier of the current calibration, or None when no remap is needed.

        ``auto`` remaps when the calibration files are given, or when the camera infos say
        the images are raw (D != 0, R != I or K != P[:3, :3]), except on topics named as
        rectified (``image_rect``...): ROS publishes those with the raw camera's info.
        ``always`` remaps from the calibration in any case, ``never`` never. The decision is
        printed (through ``echo``) when it is first made and whenever it changes.

        Raises:
            CalibrationError: an unknown distortion model, unusable matrices, or no baseline.
        """
        config = self.config
        if config.rectify == "never":
            shifted = self._shifted()  # then the right ones are not as recorded
            self._say(
                f"rectify never: the images are used as recorded{' but shifted' if shifted else ''}"
                f", with P of {config.left_info_topic} and {config.right_info_topic} (not checked)"
                f"{shifted}"
            )
            return None
        if config.calibration is not None:
            calibration = config.calibration
            source = f"the calibration files ({calibration.left.name}, {calibration.right.name})"
        else:
            held = self._rect_infos
            if held is not None and held[0] is self._left_info and held[1] is self._right_info:
                return self._rectifier
            try:
                calibration = rect.stereo_from_infos(
                    self._left_info,
                    self._right_info,
                    config.left_info_topic,
                    config.right_info_topic,
                )
            except CalibrationError:
                names = (config.left_topic, config.right_topic)
                if config.rectify == "always" or not all(map(is_rectified_name, names)):
                    raise
                # rectified streams whose infos carry no usable raw calibration (size 0, an
                # unknown model): P alone is what they need
                self._say(
                    f"rectify auto: {config.left_topic} and {config.right_topic} are named "
                    f"rectified: used as they are, with P of their camera infos{self._shifted()}"
                )
                self._rect_infos = (self._left_info, self._right_info)
                self._rectifier = self._as_is = None
                return None
            source = f"{config.left_info_topic} and {config.right_info_topic}"
        rectifier: rect.StereoRectifier | None = None
        if config.rectify == "auto" and config.calibration is None:
            named = [t for t in (config.left_topic, config.right_topic) if is_rectified_name(t)]
            if calibration.is_rectified:
                self._say(
                    f"rectify auto: {source} say the images are rectified (D = 0, R = I, "
                    f"K = P): used as they are{self._shifted()}"
                )
            elif len(named) == 2:
                self._say(
                    f"rectify auto: {config.left_topic} and {config.right_topic} are named "
                    "rectified: used as they are, with P of their camera infos (ROS publishes "
                    "image_rect with the raw camera's D and R); --rectify always remaps them"
                    f"{self._shifted()}"
                )
            else:
                rectifier = self._build(calibration)
                self._say(
                    f"rectify auto: remapping the raw images with {source} "
                    f"({calibration.why_raw()}; {calibration.left.model}), as image_proc does: "
                    f"{_size(rectifier.camera)} rectified, fx={rectifier.camera.fx:g}, "
                    f"baseline {rectifier.camera.baseline:.4g} m{rectifier.cx_note}",
                    self._new_maps(rectifier),
                )
        else:
            rectifier = self._build(calibration)
            self._say(
                f"rectify {config.rectify}: remapping the images with {source} "
                f"({calibration.left.model}): {_size(rectifier.camera)} rectified, "
                f"fx={rectifier.camera.fx:g}, baseline {rectifier.camera.baseline:.4g} m"
                f"{rectifier.cx_note}",
                self._new_maps(rectifier),
            )
        if config.calibration is None:
            self._rect_infos = (self._left_info, self._right_info)
        self._rectifier = rectifier
        self._as_is = calibration if rectifier is None else None
        return rectifier

    def _new_maps(self, rectifier: rect.StereoRectifier) -> str:
        """Say maps built anew for a calibration that changed (the line's text may not)."""
        if self._rectifier is None or self._rectifier is rectifier:
            return ""
        return f"; new maps from frame {self._index} on: the calibration changed"

    def _shifted(self) -> str:
        """Set the shift of right images used as they are onto the left's cx; say it."""
        self._right_shift, note = as_is_shift(self._left_info, self._right_info)
        return note

    def as_is(self, image: npt.NDArray[Any], side: str) -> npt.NDArray[Any]:
        """Return an image used as it is (no remap): a right one moved onto the left's cx."""
        return shift_image(image, self._right_shift) if side == "right" else image

    def _build(self, calibration: rect.StereoCalibration) -> rect.StereoRectifier:
        """Return the rectifier of a calibration: the current one when no value changed."""
        current = self._rectifier
        if current is not None and current.calibration.key() == calibration.key():
            return current
        return rect.StereoRectifier(calibration, baseline=self.config.baseline)

    def _baseline_source(self, rectifier: rect.StereoRectifier | None) -> str:
        config = self.config
        if config.baseline is not None:
            return "--baseline"
        if rectifier is not None and config.calibration:
            return "--calibration"
        if rectifier is not None:
            left_tx = float(rectifier.calibration.left.p[0, 3])
        elif self._left_info is not None:
            left_tx = float(rosmsg.projection_matrix(self._left_info)[0, 3])
        else:
            left_tx = 0.0
        topics = config.right_info_topic
        if left_tx:  # a pair calibrated against a third camera: both Tx make the baseline
            topics = f"{config.left_info_topic} and {topics}"
        return f"P of {topics}" if rectifier is None else topics

    def _say(self, line: str, again: str = "") -> None:
        """Echo a rectify line unless it was the last one said; with ``again`` in any case.

        After the first line, :data:`MAX_CAMERA_LINES` changes are said, the last with a note.
        """
        if (line != self._said or again) and self._echo is not None:
            # capped as the camera-change lines are (a calibration that flips every frame)
            changes, self._rectify_changes = self._rectify_changes, self._rectify_changes + 1
            if changes < MAX_CAMERA_LINES:
                self._echo(line + again)
            elif changes == MAX_CAMERA_LINES:
                self._echo(f"{line}{again}; later changes are not said ({changes} said)")
        self._said = line

    def _camera(self, width: int, height: int) -> StereoCamera:
        key = (id(self._left_info), id(self._right_info), width, height)
        camera = self._camera_cache.get(key)
        if camera is None:
            camera = camera_from_infos(
                self._left_info,
                self._right_info,
                width=width,
                height=height,
                left_topic=self.config.left_info_topic,
                right_topic=self.config.right_info_topic,
                baseline=self.config.baseline,
                image_topics=(self.config.left_topic, self.config.right_topic),
            )
            self._camera_cache.clear()  # the infos change rarely; keep one entry
            self._camera_cache[key] = camera
        return camera

    def _undecodable(self, reason: str, problem: str) -> None:
        self.stats.undecodable[reason] = self.stats.undecodable.get(reason, 0) + 1
        self.stats.note(problem)

    # features -------------------------------------------------------------------------
    def _hold_for_features(self, frame: StereoFrame) -> list[StereoFrame]:
        if self.config.features_topic is None:
            return [frame]
        return self._features.hold(frame)

    def _push_features(self, message: Any, log_time_ns: int) -> list[StereoFrame]:
        try:
            features = features_from_pointcloud(message, log_time_ns)
        except (ValueError, AttributeError) as err:
            self._undecodable(_reason(err), f"{self.config.features_topic}: {err}")
            return []
        return self._features.push(features)


def _median(values: Sequence[int]) -> int:
    """Return the median of some integers (the lower middle one), 0 for none."""
    return sorted(values)[(len(values) - 1) // 2] if values else 0


def _nearer(miss_ns: int, gap_ns: int) -> int:
    """Return the nearer of a near miss (-1: none) and a gap, -1 beyond :data:`NEAR_MISS_NS`."""
    if gap_ns > NEAR_MISS_NS:
        return miss_ns
    return gap_ns if miss_ns < 0 else min(miss_ns, gap_ns)


def _size(camera: StereoCamera) -> str:
    return f"{camera.width}x{camera.height}"


def _reason(err: BaseException) -> str:
    """Return the reason of a decoding error, short enough to count by (no sizes, formats)."""
    text = first_clause(str(err))
    return text if len(text) <= 60 else text[:57] + "..."


def iter_stereo_frames(
    reader: LogReader, config: PairingConfig | None = None, *, pairer: StereoPairer | None = None
) -> Iterator[StereoFrame]:
    """Yield the stereo frames of an open log (for callers that want only frames).

    Args:
        reader: an open log reader.
        config: topics and matching; the defaults of :class:`PairingConfig` when None.
        pairer: use this pairer (e.g. to read ``pairer.stats`` afterwards, or
            ``pairer.features_for(frame)``); ``config`` is then ignored.

    Yields:
        Frames in the order they complete.

    Raises:
        TopicNotFoundError: a configured topic is not in the log.
        CalibrationError: a camera info without fx or baseline.
    """
    pairer = pairer or StereoPairer(config)
    reader.require_topics(pairer.config.required_topics())
    pairer.read_ahead(reader)
    for raw in reader.messages(pairer.config.topics):
        yield from pairer.push_raw(raw, reader.decode)
    yield from pairer.flush()
    pairer.finish()
