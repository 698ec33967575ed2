"""What a stereo pairing did: counts, and the notes and warnings the command line prints.

:class:`PairingStats` is the accumulator :class:`frontend.pairing.StereoPairer` fills as it
pairs a log; its methods word the lines a run prints about it (a tolerance too tight, camera
infos recorded late, header stamps that do not tell the pairs apart).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from pcainterp_stream.frontend.pairing_window import HoldLimits, Lost
from pcainterp_stream.io.camera_model import MIN_FOCAL_BASELINE as MIN_FOCAL_BASELINE
from pcainterp_stream.records import StereoCamera

MAX_PROBLEMS = 20
"""How many one-line problem descriptions :class:`PairingStats` keeps (counts are exact)."""

NEAR_MISS_LIMIT_NS = 1_000_000_000
"""Sides whose nearest stamps are farther apart than this (ns) are on different clocks."""

MAX_FRAME_OFFSETS = 4096
"""How many unpaired images' offsets to their own frame's other image are kept."""

MS_NS = 1_000_000

MAX_CAMERA_LINES = 5
"""Camera changes said as they happen (each with a line); the summary counts them all."""

MAX_BASELINE_M = 3.0
"""Beyond this baseline (m) a calibration is taken for wrong (a rig of trucks' width is ~1.5 m;
a millimetre P[0, 3] gives a thousand times the real one)."""


def _plausible(camera: StereoCamera) -> bool:
    """Whether a camera's baseline and f*b are a stereo rig's (see :data:`MIN_FOCAL_BASELINE`)."""
    return camera.baseline <= MAX_BASELINE_M and camera.focal_baseline >= MIN_FOCAL_BASELINE


@dataclass
class PairingStats:
    """Counts of what the pairer did (a mutable accumulator).

    Attributes:
        camera: the camera of the first pair, or the first with a baseline beyond
            :data:`MAX_BASELINE_M` or an f*b below :data:`MIN_FOCAL_BASELINE`; None before
            any pair.
        camera_source: where that camera's baseline came from.
        nearest_gap_ns: the smallest stamp gap (right minus left, ns) seen between an image
            that found no partner and the other side's waiting images; None: none seen.
        first_stamps_ns: the header stamp of each side's first image (``left``, ``right``).
        pairs: stereo frames emitted.
        unpaired_left: left images dropped without a right partner.
        unpaired_right: right images dropped without a left partner.
        undecodable: images (or feature clouds) that could not be decoded, by reason.
        size_mismatches: pairs skipped because left and right sizes differ.
        encoding_mismatches: pairs skipped because left and right are of one size but
            differ in channels (grey, colour) or bit depth.
        no_camera_info: pairs dropped because a side never had a camera info in time.
        missing_info_topics: the camera info topics that had no message yet when a pair
            was dropped (or made with one read ahead).
        info_late_ns: log time (ns) from the first pair dropped for want of a camera info (or
            made with one read ahead) to the first camera info on both sides; -1 when none
            was dropped or none came.
        pairs_before_info: pairs made before the stream's first camera info of a side, with
            the one read ahead (:meth:`StereoPairer.look_ahead`).
        changed_info_topics: camera info topics whose calibration later differs from the
            one read ahead.
        features_matched: frames that got a feature cloud (the nearest within the tolerance).
        features_unmatched: feature clouds that matched no frame.
        features_unstamped: of those, clouds whose header stamp is 0 (not set by their
            publisher); beside frames with stamps such a cloud is placed at none, whatever
            the tolerance (the feature check says so when the frames have stamps).
        features_nearest_miss_ns: the smallest gap (ns) between the stamps of a frame and a
            feature cloud that were not paired, one of them for want of the other (beyond
            the tolerance, or they would have been); -1 when there was none.
        non_monotonic_stamps: images whose stamp is earlier than the previous one on the
            same side.
        frame_offsets_ns: (log time apart, right minus left stamp) (ns) of an image that
            found no partner and the waiting other-side image nearest it by log time (its own
            frame's when they were logged together), the first :data:`MAX_FRAME_OFFSETS`.
        near_misses_ns: the gap (ns) of each image dropped unpaired to the nearest other-side
            image that was waiting unpaired too (recorded before or after it), if beyond the
            tolerance but within :data:`NEAR_MISS_NS`.
        repeated_stamp_topic: the image topic whose header stamps did not tell its images
            apart (the side's previous stamp again), from which on images were paired
            by log time; None when the stamps paired every image.
        repeated_stamp_ns: that stamp (ns).
        pairs_by_stamp: pairs made by header stamp before the switch to log time.
        log_lag_ns: by log time, the right images' log time after their left ones' (ns), the
            median on the pairs made by other stamps before the switch, subtracted.
        log_period_ns: by log time, the frame interval (ns) the tolerance is a quarter of.
        stamp_period_ns: the frame interval (ns) the header stamps give: the median of
            each side's last stamp intervals, known at :meth:`StereoPairer.finish`; 0 when
            not known.
        log_gap_ns: by log time, the smallest gap (right minus left log time, less the lag,
            ns) between an image that found no partner and the other side's waiting images.
        duplicate_images: images dropped as the same message as their side's last one again
            (same header stamp, size, encoding and bytes: a bag merge's, a driver's re-send).
        duplicate_topics: image topic -> how many of its images were so dropped, in the order
            of their first duplicate.
        duplicate_stamp_ns: the first duplicate's header stamp (ns).
        duplicate_log_ns: the first duplicate's log time (ns): what places it when its
            stamp is 0.
        unsure_pairs: (left log time, log time between the sides) (ns) of the pairs made by
            stamp before the stamps repeated that have the repeated stamp but whose images
            were recorded beyond the tolerance apart.
        tolerance_ns: the pairing's tolerance (ns).
        log_tolerance_ns: the tolerance once paired by log time (ns): at least a quarter of
            a frame interval.
        log_stamped: frames whose left image's header stamp did not place it (0, or the
            stamp of the image before it), stamped with its log time instead (no left image
            before it had a stamp of its own: see :mod:`frontend.image_clock`).
        clock_stamped: such frames stamped on the left images' header clock instead: the
            last stamp of their own plus the log time since that image.
        window: the pairing's window (pairs held waiting for camera infos).
        hold: the limits of what the pairing holds waiting for its partner (log-time span,
            messages, bytes); None: not known.
        lost_pairs: pairs lost because one image had been given up by those limits when the
            other side's image of its stamp came (lags: right minus left log time).
        lost_features: frames that lost the cloud of their stamp so (lags: cloud minus frame
            log time).
        problems: the first :data:`MAX_PROBLEMS` one-line problem descriptions.
        row_check_undecided: why the check that the pair is rectified and not swapped gave
            no verdict (too few matched corners); None when it gave one or was off.
        remapped: pairs remapped from their calibration (``--rectify``), of ``pairs``.
        camera_frames: every camera the pairs had (size, intrinsics, baseline), in the order
            of its first pair, with its pair count and the baseline's source.
        camera_changes: pairs whose camera differs from the pair before's (a driver
            restarted at another resolution, a recalibration, another rig).
        last_camera: the camera of the last pair; None before any pair.
        first_log_ns: the first pair's log time (ns), what a change's time counts from;
            None before any pair.
        matching: the SGBM resolution ``densify`` chose for the camera (``--stereo-downscale
            auto``), said in :meth:`camera_note`; None when given or not matched.
        matched_alone: the later cameras that ``--stereo-downscale auto`` would match at
            another resolution than the first camera's, which they were matched at: what it
            would choose for each alone ("full resolution (f*b 24 < 90 px*m)").
    """

    camera: StereoCamera | None = None
    camera_source: str = ""
    camera_frames: dict[StereoCamera, tuple[int, str]] = field(default_factory=dict)
    camera_changes: int = 0
    last_camera: StereoCamera | None = None
    first_log_ns: int | None = None
    matching: str | None = None
    matched_alone: dict[StereoCamera, str] = field(default_factory=dict)
    nearest_gap_ns: int | None = None
    first_stamps_ns: dict[str, int] = field(default_factory=dict)
    pairs: int = 0
    unpaired_left: int = 0
    unpaired_right: int = 0
    undecodable: dict[str, int] = field(default_factory=dict)
    size_mismatches: int = 0
    encoding_mismatches: int = 0
    no_camera_info: int = 0
    missing_info_topics: list[str] = field(default_factory=list)
    info_late_ns: int = -1
    pairs_before_info: int = 0
    changed_info_topics: list[str] = field(default_factory=list)
    features_matched: int = 0
    features_unmatched: int = 0
    features_unstamped: int = 0
    features_nearest_miss_ns: int = -1
    non_monotonic_stamps: int = 0
    near_misses_ns: list[int] = field(default_factory=list)
    frame_offsets_ns: list[tuple[int, int]] = field(default_factory=list)
    repeated_stamp_topic: str | None = None
    repeated_stamp_ns: int = 0
    pairs_by_stamp: int = 0
    log_lag_ns: int = 0
    log_period_ns: int = 0
    log_gap_ns: int | None = None
    stamp_period_ns: int = 0
    duplicate_images: int = 0
    duplicate_topics: dict[str, int] = field(default_factory=dict)
    duplicate_stamp_ns: int = 0
    duplicate_log_ns: int = 0
    unsure_pairs: list[tuple[int, int]] = field(default_factory=list)
    tolerance_ns: int = 0
    log_tolerance_ns: int = 0
    log_stamped: int = 0
    clock_stamped: int = 0
    window: int = 0
    hold: HoldLimits | None = None
    lost_pairs: Lost = field(default_factory=Lost)
    lost_features: Lost = field(default_factory=Lost)
    problems: list[str] = field(default_factory=list)
    row_check_undecided: str | None = None
    remapped: int = 0

    def row_check_hint(self) -> str | None:
        """A warning when the rectified-and-not-swapped check could not decide, else None."""
        return self.row_check_undecided if self.pairs else None

    def tolerance_hint(self) -> str | None:
        """A warning when unpaired images had a partner just beyond the tolerance, else None."""
        misses = self.near_misses_ns
        if not misses:
            return None
        widest = max(misses) / 1e6
        by_log = self.repeated_stamp_topic is not None
        when = " of log time" if by_log else ""
        tolerance = self.log_tolerance_ns if by_log else self.tolerance_ns
        dropped = self.unpaired_left + self.unpaired_right
        some = f"{len(misses)} of the {dropped}" if len(misses) < dropped else f"all {dropped}"
        return (
            f"{some} images dropped unpaired had an unpaired other-side image "
            f"{min(misses) / 1e6:.2f}-{widest:.2f} ms{when} away, beyond the "
            f"{tolerance / 1e6:g} ms tolerance; {self._tolerance_advice(widest)}"
        )

    def _tolerance_advice(self, widest_ms: float) -> str:
        """The tolerance that pairs the near misses, never half a frame or more.

        A tolerance of half a frame or more reaches the neighbouring frame's image: near
        misses that far apart are images of different frames (a dropped image on each
        side), not a stamp offset, and no tolerance is advised for them. By log time an
        image 40 ms after its partner cannot be told from one 60 ms before the next frame's
        (at 10 Hz): the advice names which.
        """
        if self.repeated_stamp_topic is None:
            return self._stamp_advice()
        advice = f"pass --stamp-tolerance-ms {math.ceil(widest_ms)} to pair them"
        period, gap = self.log_period_ns / 1e6, self.log_gap_ns
        if not period or gap is None:
            return advice
        if 2 * widest_ms >= period:
            return (
                f"that is half the {period:g} ms frame interval or more: by log time they "
                "cannot be told from the neighbouring frames' images; give the images "
                "distinct header stamps"
            )
        lag, other = abs(gap) / 1e6, period - abs(gap) / 1e6
        after, before = ("after", "before") if gap > 0 else ("before", "after")
        return (
            f"{advice} if each right image is logged {lag:.0f} ms {after} its left one (if "
            f"{other:.0f} ms {before} it, a tolerance pairs each image with the neighbouring "
            "frame's: give the images distinct header stamps)"
        )

    def saw_frame_offset(self, log_apart_ns: int, right_minus_left_ns: int) -> None:
        """Keep an unpaired image's stamp offset to the other side's image logged nearest it."""
        if len(self.frame_offsets_ns) < MAX_FRAME_OFFSETS:
            self.frame_offsets_ns.append((log_apart_ns, right_minus_left_ns))

    def stamp_offset_ns(self) -> int | None:
        """The right stamps' steady offset (ns) from their own frame's left ones, else None.

        Own frame: the images logged less than half a frame interval apart. It is steady
        when such images outnumber the pairs and nine in ten of them are within a twentieth
        of a frame of their median offset: the cameras' stamps are offset, nothing dropped.
        """
        period = self.stamp_period_ns
        offsets = sorted(
            off for apart, off in self.frame_offsets_ns if period and 2 * apart < period
        )
        if not offsets or len(offsets) <= self.pairs:
            return None
        median = offsets[(len(offsets) - 1) // 2]
        near = sum(abs(off - median) <= max(MS_NS, period // 20) for off in offsets)
        return median if 10 * near >= 9 * len(offsets) else None

    def _offset_advice(self) -> str | None:
        """Why no tolerance pairs a steady stamp offset of half a frame or more, else None."""
        offset_ns = self.stamp_offset_ns()
        period = self.stamp_period_ns / 1e6
        if offset_ns is None or 2 * math.ceil(abs(offset_ns) / 1e6) < period:
            return None
        offset, how = abs(offset_ns) / 1e6, "after" if offset_ns > 0 else "before"
        return (
            f"the right images are stamped {offset:.0f} ms {how} the left image logged with "
            f"them on most frames: the two cameras' stamps are offset by {offset:.0f} ms, half "
            f"the {period:g} ms frame interval or more: no tolerance pairs each left image with "
            "its own frame's right one (it would pair it with the neighbouring frame's); "
            "densify has no option to shift one side's stamps: re-stamp one side, or "
            "synchronise the cameras"
        )

    def _stamp_advice(self) -> str:
        """By stamp: the tolerance that pairs the near misses under half the frame interval."""
        offset = self._offset_advice()
        if offset is not None:
            return offset
        period = self.stamp_period_ns

        def advised(miss_ns: int) -> int:
            return math.ceil(miss_ns / 1e6)

        near = [
            miss for miss in self.near_misses_ns if not period or 2 * advised(miss) * 1e6 < period
        ]
        far = len(self.near_misses_ns) - len(near)
        frames = (
            f"half the {period / 1e6:g} ms frame interval or more apart: images of "
            "neighbouring frames whose partners are missing (dropped, or stored out of "
            "order), not a stamp offset (a tolerance would pair each with the other frame's "
            "image)"
        )
        if not near:
            return f"they are {frames}"
        advice = f"pass --stamp-tolerance-ms {advised(max(near))} to pair them"
        if not far:
            return advice
        return f"{advice}; {far} of them are {frames}"

    def hold_hint(self) -> str | None:
        """A warning when pairs were lost for a side logged later than the pairing held."""
        lost, hold = self.lost_pairs, self.hold
        if not lost.count or hold is None:
            return None
        lag = lost.lag_s()
        late, early = ("right", "left") if lag >= 0 else ("left", "right")
        return (
            f"{lost.count} stereo pairs lost: the {late} images were logged ~{abs(lag):.3g} s "
            f"after the {early} ones with the same stamps, "
            f"{lost.beyond(hold, 'an image for its partner')}"
        )

    def stamp_note(self) -> str | None:
        """A note on duplicated images and on pairing by log time, else None.

        By log time: the images' header stamps repeat (:meth:`StereoPairer._stamps_repeat`). It
        also says when outputs carry their left image's log time as their stamp.
        """
        notes = [self._duplicate_note(), self._log_time_note()]
        return "; ".join(note for note in notes if note) or None

    def saw_duplicate(self, topic: str, stamp_ns: int, log_time_ns: int = 0) -> None:
        """Count an image of ``topic`` that is a copy of its side's last one (a bag merge's)."""
        if not self.duplicate_images:
            self.duplicate_stamp_ns, self.duplicate_log_ns = stamp_ns, log_time_ns
        self.duplicate_images += 1
        self.duplicate_topics[topic] = self.duplicate_topics.get(topic, 0) + 1

    def _duplicate_note(self) -> str | None:
        count = self.duplicate_images
        if not count or not self.duplicate_topics:
            return None
        # each topic with its own count: "6 images of /left and 6 of /right"
        of = [
            f"{n} image{'s' * (n != 1)} of {topic}" if not k else f"{n} of {topic}"
            for k, (topic, n) in enumerate(self.duplicate_topics.items())
        ]
        how = "made by header stamp" if self.repeated_stamp_topic is None else "made as below"
        stamp = self.duplicate_stamp_ns
        log_time = f"log time {_seconds(self.duplicate_log_ns)} s, stamp 0"
        first = f"stamp {_seconds(stamp)} s" if stamp else log_time
        return (
            f"duplicates: {' and '.join(of)} {'was' if count == 1 else 'were'} logged again "
            f"(the same message, first at {first}): the "
            f"{'copy was' if count == 1 else 'copies were'} dropped, the pairs are {how}"
        )

    def restamped(self, *, by_log_time: bool) -> None:
        """Count a frame whose left header stamp did not place it: by log time or on its clock."""
        if by_log_time:
            self.log_stamped += 1
        else:
            self.clock_stamped += 1

    def _restamped_note(self) -> str:
        """Say where the outputs of the frames whose left header stamp did not place them are."""
        by_log, on_clock = self.log_stamped, self.clock_stamped
        stamped = by_log + on_clock
        clock = "on the images' clock (the last stamp of their own plus the log time since it)"
        log = "with the left image's log time"
        if by_log and on_clock:
            how = f": {on_clock} {clock}, {by_log} {log} (no left image before had a stamp)"
        else:
            how = f" {clock if on_clock else log}"
        return (
            f"the outputs of the {stamped} frame{'' if stamped == 1 else 's'} whose left header "
            f"stamp was 0 or its previous image's are stamped{how}"
        )

    def _log_time_note(self) -> str | None:
        topic = self.repeated_stamp_topic
        stamped = self.log_stamped + self.clock_stamped
        outputs = self._restamped_note()
        if topic is None:
            return f"stamps: {outputs}" if stamped else None
        stamp = self.repeated_stamp_ns
        why = "repeat 0 (not set)" if stamp == 0 else f"repeat ({_seconds(stamp)} s twice)"
        after = f" after the first {self.pairs_by_stamp}" if self.pairs_by_stamp else ""
        lag = self.log_lag_ns
        lagged = (
            f" (the right images logged {abs(lag) / 1e6:g} ms {'after' if lag > 0 else 'before'}"
            " their left ones, as in the pairs by stamp)"
            if lag
            else ""
        )
        return (
            f"stamps: the header stamps of {topic} {why}, so they do not tell its images "
            f"apart: the images were paired by log time{after}{lagged}, within "
            f"{self.log_tolerance_ns / 1e6:g} ms (a quarter frame, or --stamp-tolerance-ms "
            "when wider)" + (f"; {outputs}" if stamped else "")
        )

    def stamp_hint(self) -> str | None:
        """A warning when pairs made by stamp before the stamps repeated may be wrong, else None."""
        unsure = self.unsure_pairs
        if not unsure:
            return None
        times = ", ".join(f"{t / 1e9:.3f}" for t, _ in unsure[:3])
        more = ", ..." if len(unsure) > 3 else ""
        gaps = [gap / 1e6 for _, gap in unsure]
        said = (
            f"{len(unsure)} stereo pair(s) made by header stamp before the stamps of "
            f"{self.repeated_stamp_topic} repeated had their images recorded "
            f"{min(gaps):.2f}-{max(gaps):.2f} ms apart, beyond the "
            f"{self.log_tolerance_ns / 1e6:g} ms tolerance: they may be mispaired (left "
            f"images at log time {times}{more} s)"
        )
        period = self.log_period_ns / 1e6
        if period and 2 * max(gaps) >= period:  # a tolerance would reach the next frame's
            return (
                f"{said}; that is half the {period:g} ms frame interval or more, where no "
                "tolerance tells them from the neighbouring frames' images: give the images "
                "distinct header stamps"
            )
        return (
            f"{said}; pass --stamp-tolerance-ms {math.ceil(max(gaps))} if the two sides are "
            "only received that far apart"
        )

    def camera_info_hint(self) -> str | None:
        """A warning when pairs were dropped before the first camera info came, else None.

        Also when pairs were made with a camera info read ahead that changed later in the
        log. A log without a single pair gets no hint: its error says why.
        """
        topics = " and ".join(self.missing_info_topics) or "the camera info topics"
        late = self.info_late_ns / 1e9
        # pairs within the window would have waited for the first info: no difference
        ahead = self.pairs_before_info > self.window
        if ahead and self.changed_info_topics:
            return (
                f"the first {self.pairs_before_info} stereo pairs came before the first camera "
                f"info on {topics} (recorded {late:.1f} s of log later) and were densified with "
                f"it, but {' and '.join(self.changed_info_topics)} changed later in the log: "
                "their depth may be off; pass --calibration LEFT.yaml RIGHT.yaml (the cameras' "
                "camera_info_manager files) to densify them with their own"
            )
        if not (self.no_camera_info and self.pairs):
            return None
        when = f" (it came {late:.1f} s of log after the first dropped pair)" if late >= 0 else ""
        return (
            f"{self.no_camera_info} of {self.no_camera_info + self.pairs} stereo pairs were "
            f"dropped because no camera info had arrived yet on {topics}{when}; pass "
            "--calibration LEFT.yaml RIGHT.yaml (the cameras' camera_info_manager files) to "
            "densify every pair"
        )

    def camera_info_note(self) -> str | None:
        """A note when pairs were made with a camera info read ahead that never changed.

        Only when they are more than the window: pairs within it would have waited for that
        first camera info anyway (a log that writes each image before its camera info).
        """
        if self.pairs_before_info <= self.window or self.changed_info_topics:
            return None
        return (
            f"camera info: the first {self.pairs_before_info} stereo pairs came before the first "
            f"camera info on {' and '.join(self.missing_info_topics)} (recorded "
            f"{self.info_late_ns / 1e9:.1f} s of log later): densified with it, read ahead "
            "(the log's camera infos do not change)"
        )

    def saw_gap(self, right_minus_left_ns: int, by_log: bool = False) -> None:
        """Keep the smallest stamp gap between an unpaired image and the other side's."""
        if by_log and (self.log_gap_ns is None or abs(right_minus_left_ns) < abs(self.log_gap_ns)):
            self.log_gap_ns = right_minus_left_ns
        if self.nearest_gap_ns is None or abs(right_minus_left_ns) < abs(self.nearest_gap_ns):
            self.nearest_gap_ns = right_minus_left_ns

    def clock_hint(self) -> str | None:
        """Why no image paired when the two sides' stamps are far apart, else None."""
        gap = self.nearest_gap_ns
        if self.pairs or gap is None or abs(gap) <= NEAR_MISS_LIMIT_NS:
            return None
        side = "after" if gap > 0 else "before"
        first = self.first_stamps_ns
        offset = ""
        if "left" in first and "right" in first:  # what re-stamping has to move
            shift = (first["right"] - first["left"]) / 1e9
            offset = f" (the first right image {shift:+.6g} s from the first left one)"
        return (
            f"the right images are stamped at least {abs(gap) / 1e9:.6g} s {side} the nearest "
            f"left ones{offset}: the two cameras stamp with different clocks (or one is not "
            "synchronised); re-stamp one side, or record the pair with one clock"
        )

    def saw_camera(self, camera: StereoCamera, source: str, log_time_ns: int = 0) -> str | None:
        """Count a pair's camera; return the line that says it changed, else None.

        Keeps the first camera, or the first whose baseline is implausible (see below), as
        :attr:`camera`; the line is returned for the first :data:`MAX_CAMERA_LINES` changes
        (the summary lists every camera).
        """
        if self.camera is None or (_plausible(self.camera) and not _plausible(camera)):
            self.camera, self.camera_source = camera, source
        if self.first_log_ns is None:
            self.first_log_ns = log_time_ns
        previous, self.last_camera = self.last_camera, camera
        count, _ = self.camera_frames.get(camera, (0, source))
        self.camera_frames[camera] = (count + 1, source)
        if previous is None or previous == camera:
            return None
        self.camera_changes += 1
        if self.camera_changes > MAX_CAMERA_LINES:
            return None
        at = (log_time_ns - self.first_log_ns) / 1e9
        more = (
            f"; later changes are counted in the summary only ({MAX_CAMERA_LINES} said)"
            if self.camera_changes == MAX_CAMERA_LINES
            else ""
        )
        return (
            f"camera changed at {at:.3g} s of log (frame {self.pairs}): "
            f"{_camera_text(camera)} (was {_camera_text(previous)}); each pair is densified "
            f"with its own camera{more}"
        )

    def camera_note(self) -> str | None:
        """The camera(s) the depths were computed with, else None (no pair).

        One line for a log of one camera; for a log whose camera changed, a line that says
        so and one per camera with its pair count.
        """
        camera = self.camera
        if camera is None:
            return None
        if len(self.camera_frames) <= 1:
            return (
                f"camera: {_camera_text(camera, baseline=False)}, baseline "
                f"{camera.baseline:.4g} m (from {self.camera_source}), f*b "
                f"{camera.focal_baseline:.5g} px*m"
                + (f"; {self.matching}" if self.matching else "")
            )
        times = "once" if self.camera_changes == 1 else f"{self.camera_changes} times"
        lines = [
            f"cameras: {len(self.camera_frames)} (the camera changed {times} in the log; "
            "each pair densified with its own"
            # the resolution is chosen once, on the first camera: said as such
            + (f"; {self.matching}, chosen on the first camera for all" if self.matching else "")
            + "):"
        ]
        listed = list(self.camera_frames.items())
        for seen, (count, source) in listed[:MAX_CAMERA_LINES]:
            alone = self.matched_alone.get(seen)
            lines.append(
                f"  {_camera_text(seen, baseline=False)}, baseline {seen.baseline:.4g} m (from "
                f"{source}), f*b {seen.focal_baseline:.5g} px*m: {count} pair"
                + ("" if count == 1 else "s")
                + (
                    f"; matched at the first camera's resolution, where on its own "
                    f"--stereo-downscale auto would choose {alone}"
                    if alone
                    else ""
                )
            )
        rest = listed[MAX_CAMERA_LINES:]
        if rest:
            pairs = sum(count for _, (count, _) in rest)
            lines.append(f"  and {len(rest)} more cameras ({pairs} pairs)")
        return "\n".join(lines)

    def baseline_hint(self) -> str | None:
        """A warning when the baseline is beyond any stereo rig's, or f*b below any's, else None."""
        camera = self.camera
        if camera is None or _plausible(camera):
            return None
        if camera.baseline <= MAX_BASELINE_M:  # f*b too small: Tx in metres?
            fb = camera.focal_baseline
            fix = (
                "check --baseline (metres)"
                if self.camera_source == "--baseline"
                else "fix the calibration (P[0, 3] = -fx * baseline, in metres); if P[0, 3] is "
                f"the baseline in metres, pass --baseline {fb:.4g}"
            )
            return (
                f"the baseline from {self.camera_source} is {camera.baseline:.4g} m at fx "
                f"{camera.fx:g} px, f*b {fb:.4g} px*m (1 px of disparity at {fb:.3g} m), below "
                f"any stereo rig's (>= {MIN_FOCAL_BASELINE:g} px*m), and every depth scales "
                f"with it: {fix}"
            )
        guess = f"; if it is in millimetres, pass --baseline {camera.baseline / 1000:.4g}"
        return (
            f"the baseline from {self.camera_source} is {camera.baseline:.4g} m, beyond any "
            f"stereo rig's (< {MAX_BASELINE_M:g} m), and every depth scales with it: fix the "
            f"calibration (P[0, 3] = -fx * baseline, in metres){guess}"
        )

    def feature_miss(self, stamp_ns: int, cloud_stamps_ns: Iterable[int]) -> None:
        """Keep the gap from a frame to the nearest of feature clouds it was not paired with."""
        gaps = [abs(cloud - stamp_ns) for cloud in cloud_stamps_ns]
        if gaps:
            nearest = self.features_nearest_miss_ns
            self.features_nearest_miss_ns = min(gaps) if nearest < 0 else min(nearest, *gaps)

    def note(self, problem: str) -> None:
        """Keep a one-line problem description (only the first few are kept)."""
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(problem)

    def summary(self) -> str:
        """Return the counts as one line."""
        parts = [
            f"{self.pairs} pairs",
            f"{self.unpaired_left} unpaired left",
            f"{self.unpaired_right} unpaired right",
        ]
        if self.size_mismatches:
            parts.append(f"{self.size_mismatches} size mismatches")
        if self.encoding_mismatches:
            parts.append(f"{self.encoding_mismatches} encoding mismatches")
        if self.no_camera_info:
            parts.append(f"{self.no_camera_info} without camera info")
        if self.non_monotonic_stamps:
            parts.append(f"{self.non_monotonic_stamps} non-monotonic stamps")
        if self.duplicate_images:
            many = "s" if self.duplicate_images > 1 else ""
            parts.append(f"{self.duplicate_images} duplicate image{many} dropped")
        for reason, count in self.undecodable.items():
            parts.append(f"{count} undecodable ({reason})")
        if self.features_matched or self.features_unmatched:
            parts.append(
                f"{self.features_matched} frames with features, "
                f"{self.features_unmatched} unmatched feature clouds"
            )
        return ", ".join(parts)

    def undecodable_fix(self) -> str:
        """Return the fix of images that did not decode (for a log without a usable pair).

        A wrong ``step`` field is the publisher's to fix, not the encoding; other reasons
        (an encoding not read) are told to convert the images.
        """
        if self.undecodable and all(r.startswith("image step ") for r in self.undecodable):
            return (
                "the images' step field is shorter than their rows: fix the publisher (step = "
                "width * bytes per pixel) and re-record"
            )
        return "convert the images to mono8, rgb8 or bgr8 (or png/jpeg CompressedImage)"


def _seconds(stamp_ns: int) -> str:
    """Return a stamp (ns) as seconds with all nine decimals."""
    return f"{stamp_ns // 1_000_000_000}.{stamp_ns % 1_000_000_000:09d}"


def _camera_text(camera: StereoCamera, *, baseline: bool = True) -> str:
    """Return "620x188 px, fx 359.428 px" (with ", f*b 193.08 px*m" when ``baseline``)."""
    text = f"{camera.width}x{camera.height} px, fx {camera.fx:.6g} px"
    return text + (f", f*b {camera.focal_baseline:.5g} px*m" if baseline else "")


def first_clause(text: str) -> str:
    """Return ``text`` up to its first ``;`` or `` (`` outside a quoted value.

    A quote opens after a space, ``(``, ``=``, ``:`` or at the start, and closes before a
    character that is not a letter or digit, so an apostrophe (``densify's``) opens none.

    >>> first_clause("unsupported compressed image format 'rgb8; compressedDepth'; use png")
    "unsupported compressed image format 'rgb8; compressedDepth'"
    >>> first_clause("compressed png image does not decode (3 bytes)")
    'compressed png image does not decode'
    """
    quote = ""
    for index, char in enumerate(text):
        if quote:
            after = text[index + 1 : index + 2]
            if char == quote and not after.isalnum():
                quote = ""
        elif char in "'\"" and (index == 0 or text[index - 1] in " (=:"):
            quote = char
        elif char == ";" or text.startswith(" (", index):
            return text[:index]
    return text
