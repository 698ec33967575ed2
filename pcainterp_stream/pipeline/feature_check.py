"""What a sparse feature stream gave ``densify``: its counts, warnings and the error of none.

With ``--features-topic`` the measurements are the points of another system's clouds, not
the images' corners: a frame without a measurement is the stream's doing (no cloud of its
stamp, an empty cloud, points behind the camera or outside the image), not the images'.
:class:`FeatureStreamCheck` accumulates, frame by frame, what the stream gave and words it:
a summary line, warnings that name the cause, and the one-line error of a run in which no
frame got a single usable point. It refuses a stream whose points all lie at z = 1
(:data:`FLAT_SPREAD`, :data:`NORMALIZED_DEPTH`: normalized image coordinates, not 3-D points;
clouds of a few points are judged together, :data:`FLAT_MIN_POINTS`; a cloud at one other
depth is a flat surface facing the camera, used) or whose clouds are in a world frame
(:data:`WORLD_FRAMES`), warns, once, of clouds in another frame than the left image's and
of coordinates that look like millimetres, counts points nearer than the stereo pair sees
(:func:`~pcainterp_stream.frontend.features.too_near`), says how a dense cloud was thinned
(:func:`~pcainterp_stream.frontend.features.thin_measurements`) and how far from their
images' stamps the clouds matched were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pcainterp_stream.frontend.pairing import NEAR_MISS_NS
from pcainterp_stream.frontend.pairing_stats import NEAR_MISS_LIMIT_NS, PairingStats
from pcainterp_stream.records import DensifiedFrame, SparseFeatures, StereoFrame

MILLIMETRE_DEPTH_M = 500.0
"""Median point depth (m) beyond which a feature stream's coordinates look like millimetres.

A street scene's features have a median depth of 10-20 m (the KITTI features of the bug
hunt's log: 16 m, with single points out to 2 km), a room's 1-5 m; in millimetres those read
10,000-20,000 and 1,000-5,000. A stereo camera resolves no depth at 500 m (KITTI's 0.54 m
baseline: 0.8 px of disparity), so a median beyond it is no real scene. A scene closer than
0.5 m recorded in millimetres is not caught."""


FLAT_SPREAD = 1e-6
"""Spread of a cloud's depths (max - min, relative to their median) at or below which its
points all lie at one depth; at depth 1 they are normalized image coordinates, refused.

Measured depths vary, if only by noise: a wall facing the camera at 5 m has centimetres of
stereo, VIO or LiDAR noise (a relative spread of 1e-3 or more), a depth camera's millimetre
steps 1e-3 at 1 m. 1e-6 is a few float32 steps (2**-23 = 1.2e-7) of one value: a cloud that
holds a single depth in every point. VINS feature_tracker's normalized image coordinates
(x/z, y/z, 1) are such a cloud at z = 1, and are refused (:data:`NORMALIZED_DEPTH`). A
simulator's noiseless depth sensor facing a wall (Gazebo, Isaac, CARLA without a noise model)
gives one at the wall's depth too, with x and y spread over metres: those are 3-D points of a
flat surface and are densified."""

NORMALIZED_DEPTH = 1.0
"""The depth (m) of a flat cloud that is refused as normalized image coordinates (x/z, y/z,
1). A cloud at one other depth is a flat surface facing the camera, used as it is; a real
wall at exactly 1 m with no noise cannot be told from normalized coordinates and is refused
with them (the refusal names them)."""

WORLD_FRAMES = ("map", "odom", "world", "earth")
"""Frame ids of a world frame (REP 105's map, odom and earth, and the common world): a cloud
in one is a SLAM map's points, never in a camera's optical frame, and is refused. Other
names are warned of only (``camera_link`` may be a renamed optical frame)."""

FLAT_MIN_POINTS = 10
"""Points (in front of the camera) at z = 1 that refuse a stream (:data:`FLAT_SPREAD`).

A few measured depths may coincide by chance (a depth camera's millimetre steps, stereo's
integer disparities of far points), ten in one cloud do not. Clouds of fewer points are
judged together: the points of the stream's clouds of 2 to 9 points, while every one of
them lies at one and the same depth (VINS feature_tracker's z = 1 in every cloud), count
towards the ten; a cloud with depths that differ, or one at another depth than the clouds
before it, ends that (a single point has no depth to compare and is not judged). Clouds
pooled at another depth than 1 are a flat surface: neither refused nor warned of."""

FLAT_SUSPECT_POINTS = 3
"""Points at z = 1, fewer than :data:`FLAT_MIN_POINTS`, that a run warns of when its
stream gave no cloud with points at different depths."""


@dataclass
class FeatureStreamCheck:
    """What a feature stream gave the frames of one ``densify`` run (a mutable accumulator).

    Attributes:
        topic: the feature stream's topic.
        frames: frames densified.
        without_cloud: frames that had no cloud within the stamp tolerance.
        empty_clouds: frames whose cloud had no point (with finite x, y, z).
        all_dropped: frames whose cloud had points, all behind the camera, outside the image
            or too near.
        all_dropped_behind: the points of those frames behind the camera.
        all_dropped_outside: the points of those frames outside the image.
        all_dropped_near: the points of those frames too near.
        usable_frames: frames with at least one point in front of the camera, in the image.
        unmeasured: frames without a single measurement, own or carried (no estimate: NaN).
        points: points of the frames' clouds.
        behind: points behind the camera (z <= 0).
        outside: points in front of the camera but outside the image.
        near: points in the image at a disparity over its width (nearer than ``near_depth``:
            no stereo pair of the camera sees them; :func:`~.features.too_near`).
        near_depth: f*b / width of the camera (m).
        image_size: the left image's ``WxH`` (px).
        frame_ids: the first (cloud, left image) frame_ids that differ, None while they agree.
        median_depths: each cloud's median depth of its points in front of the camera (m).
        max_points: the most points measured per frame (0: not known).
        thinned: points in the image left out by the thinning.
        grid_frames: frames whose cloud had more than ``max_points`` in the image.
        grid_points: the points in the image of those frames.
        grid_kept: the points kept of those.
        cell: the largest thinning grid cell side (px).
        offsets_ns: of frames given a cloud of another stamp, the gap between the stamps (ns).
        spread_seen: a cloud with points at different depths came.
        small_flat_clouds: clouds of 2 to :data:`FLAT_MIN_POINTS` - 1 points at one depth,
            all at the same depth, before any with spread (-1: one came at another depth).
        small_flat_points: the points of those clouds in front of the camera.
        small_flat_depth: their depth (m).
        small_flat_stamps_ns: the stamps of the first and the last of them (ns).
        flat_clouds: clouds of :data:`FLAT_MIN_POINTS` points or more whose points all lay
            at one depth, after such a cloud.
        flat_depth: the depth of the first of those (m).
        frame_stamps_ns: the first and the last frame's stamp (ns), for the frame interval.
        carried_frames: frames without a point of their own estimated from carried points.
        predicted_frames: frames without a point of their own or carried, estimated by the
            temporal prior's prediction from the previous frame.
    """

    topic: str
    frames: int = 0
    without_cloud: int = 0
    empty_clouds: int = 0
    all_dropped: int = 0
    all_dropped_behind: int = 0
    all_dropped_outside: int = 0
    all_dropped_near: int = 0
    usable_frames: int = 0
    unmeasured: int = 0
    points: int = 0
    behind: int = 0
    outside: int = 0
    near: int = 0
    near_depth: float = 0.0
    image_size: str = ""
    frame_ids: tuple[str, str] | None = None
    median_depths: list[float] = field(default_factory=list)
    max_points: int = 0
    thinned: int = 0
    grid_frames: int = 0
    grid_points: int = 0
    grid_kept: int = 0
    cell: int = 0
    offsets_ns: list[int] = field(default_factory=list)
    spread_seen: bool = False
    small_flat_clouds: int = 0
    small_flat_points: int = 0
    small_flat_depth: float = 0.0
    small_flat_stamps_ns: tuple[int, int] = (0, 0)
    flat_clouds: int = 0
    flat_depth: float = 0.0
    frame_stamps_ns: tuple[int, int] | None = None
    carried_frames: int = 0
    predicted_frames: int = 0

    def cloud(self, frame: StereoFrame, features: SparseFeatures | None) -> str | None:
        """Look at the cloud handed to a frame (None: none): its stamp, frame_id and depths.

        Returns:
            why the stream is refused: its cloud is in a world frame (:data:`WORLD_FRAMES`),
            or, before any cloud with points at different depths, a cloud of
            :data:`FLAT_MIN_POINTS` points or more has every point at z = 1 (normalized
            image coordinates), or smaller clouds together hold that many points, all at
            z = 1; None to go on (a cloud at one other depth is a flat surface).
        """
        stamps = self.frame_stamps_ns
        self.frame_stamps_ns = (frame.stamp_ns if stamps is None else stamps[0], frame.stamp_ns)
        if features is None:
            return None
        if features.stamp_ns != frame.stamp_ns:
            self.offsets_ns.append(abs(features.stamp_ns - frame.stamp_ns))
        cloud_id, image_id = features.frame_id.lstrip("/"), frame.frame_id.lstrip("/")
        if cloud_id.lower() in WORLD_FRAMES:
            return (
                f"the clouds of --features-topic {self.topic} are in frame "
                f"'{features.frame_id}', a world frame (REP 105): a map's points, not the "
                f"left camera's; transform them into the left optical frame "
                f"'{frame.frame_id}' (with the camera's pose at each stamp) before densifying"
            )
        if self.frame_ids is None and cloud_id and image_id and cloud_id != image_id:
            self.frame_ids = (features.frame_id, frame.frame_id)
        depth = features.points[:, 2]
        ahead = depth[depth > 0]
        if ahead.size:
            self.median_depths.append(float(np.median(ahead)))
        if ahead.size < 2:  # a single point has no spread
            return None
        median = float(np.median(ahead))
        if float(np.ptp(ahead)) > FLAT_SPREAD * median:
            self.spread_seen = True
            return None
        normalized = _same_depth(median, NORMALIZED_DEPTH)  # else a flat surface: 3-D points
        if self.spread_seen:  # a stream of 3-D clouds with a normalized one: warned of
            if ahead.size >= FLAT_MIN_POINTS and normalized:
                self.flat_clouds += 1
                self.flat_depth = self.flat_depth or median
            return None
        if ahead.size >= FLAT_MIN_POINTS:
            if not normalized:  # a noiseless simulator's wall facing the camera
                return None
            return (
                f"every point of the cloud of --features-topic {self.topic} at stamp "
                f"{_seconds(features.stamp_ns)} s ({ahead.size} points) has z = {median:.6g}: "
                f"{_not_3d(median)}"
            )
        return self._small_flat(features.stamp_ns, ahead.size, median)

    def _small_flat(self, stamp_ns: int, points: int, depth: float) -> str | None:
        """Pool a cloud of fewer than :data:`FLAT_MIN_POINTS` points, all at ``depth`` (m)."""
        if self.small_flat_clouds < 0:
            return None
        if self.small_flat_clouds and not _same_depth(depth, self.small_flat_depth):
            self.small_flat_clouds = -1  # each at a depth of its own: coincidences
            return None
        if not self.small_flat_clouds:
            self.small_flat_depth = depth
            self.small_flat_stamps_ns = (stamp_ns, stamp_ns)
        self.small_flat_clouds += 1
        self.small_flat_points += points
        self.small_flat_stamps_ns = (self.small_flat_stamps_ns[0], stamp_ns)
        if self.small_flat_points < FLAT_MIN_POINTS or not self._small_flat_normalized():
            return None
        return f"{self._small_flat_clause()}: {_not_3d(self.small_flat_depth)}"

    def _small_flat_normalized(self) -> bool:
        """Whether the pooled small clouds are at z = 1 (not a flat surface at its depth)."""
        return _same_depth(self.small_flat_depth, NORMALIZED_DEPTH)

    def _small_flat_clause(self) -> str:
        """Return "every point of the 4 clouds ... has z = 1" for the pooled small clouds."""
        first, last = (_seconds(stamp) for stamp in self.small_flat_stamps_ns)
        clouds, when = f"{self.small_flat_clouds} clouds", f"from stamp {first} s to {last}"
        if self.small_flat_clouds == 1:
            clouds, when = "cloud", f"at stamp {first}"
        return (
            f"every point of the {clouds} of --features-topic {self.topic} {when} s "
            f"({self.small_flat_points} points, fewer than {FLAT_MIN_POINTS} a cloud) has "
            f"z = {self.small_flat_depth:.6g}"
        )

    def result(self, result: DensifiedFrame) -> None:
        """Count one densified frame's feature counts (``features_to_measurements``)."""
        counts = result.counts
        points = counts.get("features", 0)
        rejected = counts.get("features_rejected", 0)
        behind = counts.get("features_behind", 0)
        near = counts.get("features_near", 0)
        camera = result.frame.camera
        self.frames += 1
        self.image_size = f"{camera.width}x{camera.height}"
        self.near_depth = camera.focal_baseline / camera.width
        self.points += points
        self.behind += behind
        self.near += near
        self.outside += rejected - behind - near
        thinned = counts.get("features_thinned", 0)
        self.thinned += thinned
        if counts.get("features_cell", 0):
            self.grid_frames += 1
            self.grid_points += points - rejected
            self.grid_kept += points - rejected - thinned
            self.cell = max(self.cell, counts["features_cell"])
        self.unmeasured += not result.estimated
        if result.estimated and points - rejected == 0:  # none of its own: carried, or predicted
            if counts.get("carried", 0):
                self.carried_frames += 1
            else:
                self.predicted_frames += 1
        if not counts.get("feature_cloud", 0):
            self.without_cloud += 1
        elif points == 0:
            self.empty_clouds += 1
        elif rejected == points:
            self.all_dropped += 1
            self.all_dropped_behind += behind
            self.all_dropped_outside += rejected - behind - near
            self.all_dropped_near += near
        else:
            self.usable_frames += 1

    def summary(self) -> str:
        """Return one line: the points the stream gave and those dropped, by reason."""
        used = self.points - self.behind - self.outside - self.near - self.thinned
        line = (
            f"features: {self.points} points of {self.topic} in {self.frames - self.without_cloud}"
            f" of {self.frames} frames, {used} used; {self.behind} behind the camera, "
            f"{self.outside} outside the {self.image_size} image"
        )
        if self.near:
            line += f", {self.near} {self._near_clause()}"
        shared = self.thinned - (self.grid_points - self.grid_kept)
        if self.grid_frames:
            cap = f", --max-features {self.max_points}" if self.max_points else ""
            line += (
                f"; {self.grid_points / self.grid_frames:.0f} points per frame in the image"
                f"{'' if self.grid_frames == self.frames else f' ({self.grid_frames} frames)'}, "
                f"thinned to {self.grid_kept / self.grid_frames:.0f} (one per cell of "
                f"{self.cell} px{cap})"
            )
        if shared > 0:
            line += f"; {shared} left out on a pixel already holding a nearer point"
        if self.offsets_ns:
            # clouds of another stamp than their image's (the nearest within the tolerance)
            low, high = (f"{min(self.offsets_ns) / 1e6:.3g}", f"{max(self.offsets_ns) / 1e6:.3g}")
            median = f"{float(np.median(self.offsets_ns)) / 1e6:.3g}"
            line += (
                f"; {len(self.offsets_ns)} of the {self.frames - self.without_cloud} clouds "
                "matched an image "
                + (high if low == high else f"{low}-{high}")
                + " ms from their stamp"
                + ("" if low == high else f" (median {median} ms)")
            )
        return line

    def error(self, stats: PairingStats) -> str | None:
        """Return why no frame got a usable point from the stream, or None when one did."""
        if self.usable_frames or not self.frames:
            return None
        return (
            f"--features-topic {self.topic} gave no usable point in any of the {self.frames} "
            f"frames: {'; '.join(self._causes(stats, error=True))}"
        )

    def warnings(self, stats: PairingStats) -> list[str]:
        """Return the run's warnings on the stream (none when every frame got points)."""
        lines: list[str] = []
        missed = self.frames - self.usable_frames
        if missed:
            kinds = [
                (self.unmeasured, "no estimate (depth NaN)"),
                (
                    self.carried_frames,
                    "only the points carried from earlier frames (do not trust them)",
                ),
                (
                    self.predicted_frames,
                    "the temporal prior's prediction from the previous frame (wider std)",
                ),
            ]
            had = [(count, what) for count, what in kinds if count]
            if len(had) == 1:
                alone = f"they have {had[0][1]}"
            else:
                alone = ", ".join(f"{count} have {what}" for count, what in had)
            lines.append(
                f"{missed} of {self.frames} frames got no point from --features-topic "
                f"{self.topic}, so {alone}: {'; '.join(self._causes(stats, error=False))}"
            )
        dropped = self.behind + self.outside + self.near
        # frames that lost every point have their warning above; this one is for the others
        if dropped and not self.all_dropped and dropped * 2 > self.points:
            near = f", {self.near} {self._near_clause()}" if self.near else ""
            lines.append(
                f"{dropped} of the {self.points} points of {self.topic} were dropped "
                f"({self.behind} behind the camera, {self.outside} outside the "
                f"{self.image_size} image{near}): {self._frame_hint()}"
            )
        if self.frame_ids is not None:
            cloud_id, image_id = self.frame_ids
            lines.append(
                f"the clouds of {self.topic} are in frame '{cloud_id}', the left image in "
                f"'{image_id}': their points were used as if in the left optical frame "
                "(transform them there before densifying)"
            )
        far = [offset for offset in self.offsets_ns if offset > NEAR_MISS_LIMIT_NS]
        if far:
            lines.append(
                f"{len(far)} of the {self.frames - self.without_cloud} clouds of {self.topic} "
                f"matched an image more than {NEAR_MISS_LIMIT_NS / 1e9:g} s from their stamp "
                f"(up to {_duration(max(far))}): not of the image's instant, their points are "
                f"likely another frame's (a clock other than the images'?); {_RESTAMP}"
            )
        if self.flat_clouds:
            lines.append(
                f"{self.flat_clouds} clouds of {self.topic} had every point at one depth (the "
                f"first z = {self.flat_depth:.6g}): not 3-D points, their frames' depths are a "
                "flat wall (densify needs x y z in metres in the left optical frame)"
            )
        if (
            self.small_flat_clouds > 0
            and self.small_flat_points >= FLAT_SUSPECT_POINTS
            and not self.spread_seen
            and self._small_flat_normalized()
        ):
            # refused at FLAT_MIN_POINTS: fewer are a warning, as real depths may coincide
            lines.append(
                f"{self._small_flat_clause()}, and no cloud had points at different depths: "
                f"{_not_3d(self.small_flat_depth)} (too few points to refuse the run)"
            )
        depth = self.median_depth()
        if depth is not None and depth > MILLIMETRE_DEPTH_M:
            lines.append(
                f"the points of {self.topic} have a median depth of {depth:,.0f} m "
                f"({depth / 1000:.2f} m if the coordinates are millimetres): ROS point clouds "
                "are in metres (REP 103); fix the publisher's units: the depths and the fit "
                "check's figures of this run are wrong"
            )
        return lines

    def median_depth(self) -> float | None:
        """Return the median of the clouds' median depths (m), None without a point ahead."""
        return float(np.median(self.median_depths)) if self.median_depths else None

    def _causes(self, stats: PairingStats, *, error: bool) -> list[str]:
        """Return why frames got no point, one clause per cause with its fix."""
        causes: list[str] = []
        if self.without_cloud:
            causes.append(self._no_cloud(stats, error=error))
        if self.empty_clouds:
            causes.append(f"{self.empty_clouds} had an empty cloud (no point with finite x, y, z)")
        if self.all_dropped:
            behind, outside = self.all_dropped_behind, self.all_dropped_outside
            near = self.all_dropped_near
            where = [
                f"behind the camera (z <= 0, {behind} points)" if behind else "",
                f"outside the {self.image_size} image ({outside} points)" if outside else "",
                f"{self._near_clause()} ({near} points)" if near else "",
            ]
            causes.append(
                f"{self.all_dropped} had every point of their cloud "
                f"{' or '.join(w for w in where if w)}: {self._frame_hint()}"
            )
        return causes

    def _no_cloud(self, stats: PairingStats, *, error: bool) -> str:
        """Return the clause for frames without a cloud of their stamp."""
        tolerance = stats.tolerance_ns / 1e6
        clause = f"{self.without_cloud} had no cloud within the {tolerance:g} ms stamp tolerance"
        clouds = stats.features_matched + stats.features_unmatched
        undecodable = [p for p in stats.problems if p.startswith(f"{self.topic}: ")]
        nearest = stats.features_nearest_miss_ns
        stamps = self.frame_stamps_ns
        unstamped = stats.features_unstamped if stamps is not None and stamps[1] else 0
        lost = stats.lost_features
        if lost.count and stats.hold is not None:  # logged farther apart than the pairing held
            lag = lost.lag_s()
            order, held = ("after", "a frame for its cloud")
            if lag < 0:
                order, held = ("before", "a cloud for its frame")
            which = f" ({lost.count} of them)" if lost.count < self.without_cloud else ""
            return (
                f"{self.without_cloud} had no cloud{which}: the clouds of {self.topic} were "
                f"logged ~{abs(lag):.3g} s {order} their images with the same stamps, "
                f"{lost.beyond(stats.hold, held)}"
            )
        if clouds == 0 and undecodable:
            return f"{self.without_cloud} had no cloud: none could be read ({undecodable[0]})"
        if clouds == 0:
            return f"{self.without_cloud} had no cloud: the log has none on {self.topic}"
        if unstamped:
            of = "" if unstamped == clouds else f" of the {clouds}"
            clause = (
                f"{self.without_cloud} had no cloud: {unstamped}{of} clouds of {self.topic} "
                "have header stamp 0 (not set by their publisher), which places them at no "
                f"image, whatever the tolerance; {_RESTAMP}"
            )
            if nearest < 0:
                return clause
            clause += "; of the other clouds, none was within the stamp tolerance"
        elif 0 <= nearest <= stats.tolerance_ns:  # within it, but nearer another frame
            return (
                f"{self.without_cloud} had no cloud of their own: those within the "
                f"{tolerance:g} ms stamp tolerance were nearer other frames' stamps"
                + self._far(nearest, stats, error=error)
            )
        far = self._far(nearest, stats, error=error) if nearest >= 0 else ""
        if far:  # never a tolerance that reaches the neighbouring frames' clouds
            return clause + far
        interval = self._frame_interval_ns(stats)
        within_half = not interval or 2 * nearest < interval  # never reaches another frame
        if nearest >= 0 and within_half and (error or nearest <= NEAR_MISS_NS):
            return (
                f"{clause} (the nearest cloud was {nearest / 1e6:.3g} ms from an image's "
                f"stamp; pass --stamp-tolerance-ms {math.ceil(nearest / 1e6)} if they are of "
                "the same instant)"
            )
        return clause

    def _far(self, nearest_ns: int, stats: PairingStats, *, error: bool = True) -> str:
        """Return why clouds this far (ns) from the images' stamps pair with no tolerance.

        Empty for a gap under half a frame interval (a tolerance may pair those; without a
        known interval, under :data:`NEAR_MISS_LIMIT_NS`); for a warning (``error`` False),
        also for one up to that limit: a frame without a cloud of its own has other frames'
        clouds farther than half a frame, which says nothing of their clock.
        """
        interval = self._frame_interval_ns(stats)
        other_clock = nearest_ns > NEAR_MISS_LIMIT_NS
        if not other_clock and (not error or not interval or 2 * nearest_ns < interval):
            return ""
        frames = ""
        if interval and not other_clock:
            frames = f", {nearest_ns / interval:.3g} frame intervals of {interval / 1e6:.3g} ms"
        why = "half a frame interval or more"
        if other_clock:
            why = "the clouds are stamped on another clock than the images, or another log's"
        return (
            f" (the nearest cloud was {_duration(nearest_ns)} from an image's stamp{frames}: "
            f"{why}; a tolerance that wide pairs frames with other frames' clouds; "
            f"{_RESTAMP})"
        )

    def _frame_interval_ns(self, stats: PairingStats) -> int:
        """Return the frames' mean stamp interval (ns; by log time if so paired), 0: unknown."""
        if stats.repeated_stamp_topic is not None:
            return stats.log_period_ns
        stamps = self.frame_stamps_ns
        if stamps is None or self.frames < 2 or stamps[1] <= stamps[0]:
            return 0
        return (stamps[1] - stamps[0]) // (self.frames - 1)

    def _near_clause(self) -> str:
        """Return what the points too near are (after their count)."""
        width = self.image_size.split("x")[0]
        return (
            f"nearer than the stereo pair sees (disparity over the {width} px width: "
            f"z < {self.near_depth:.3g} m; triangulation failures?)"
        )

    def _frame_hint(self) -> str:
        """Return what points behind the camera or outside the image suggest."""
        hint = "are the clouds in the left camera's optical frame (x right, y down, z forward)?"
        if self.frame_ids is not None:
            hint += f" (their frame_id is '{self.frame_ids[0]}', the image's '{self.frame_ids[1]}')"
        return hint


_RESTAMP = "stamp each cloud with the header stamp of the image it was computed from"
"""The fix of clouds whose stamps place them at no image (0, or another clock's)."""


def _duration(ns: int) -> str:
    """Return a gap (ns) in the unit that reads best: ms, s, hours, days or years."""
    seconds = ns / 1e9
    if seconds < 1:
        return f"{ns / 1e6:.3g} ms"
    for unit, length in (("years", 365.25 * 86400), ("days", 86400), ("hours", 3600)):
        if seconds >= length:
            return f"{seconds:.3g} s ({seconds / length:.3g} {unit})"
    return f"{seconds:.3g} s"


def _seconds(stamp_ns: int) -> str:
    """Return a stamp (ns) as seconds with all nine digits, exactly."""
    return f"{stamp_ns // 10**9}.{stamp_ns % 10**9:09d}"


def _same_depth(depth: float, other: float) -> bool:
    """Return whether two depths (m) are one within :data:`FLAT_SPREAD`."""
    return abs(depth - other) <= FLAT_SPREAD * max(depth, other)


def _not_3d(depth: float) -> str:
    """Return why points all at ``depth`` (m) are refused, and what densify needs."""
    guess = (
        "normalized image coordinates (x/z, y/z, 1: VINS feature_tracker's points)? "
        if _same_depth(depth, 1.0)
        else ""
    )
    return (
        f"not 3-D points, whose depths differ if only by noise; {guess}densify needs x y z in "
        "metres in the left optical frame"
    )
