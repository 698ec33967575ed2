"""Match a sparse feature stream's clouds to stereo frames by header stamp (no I/O).

A frame takes the cloud nearest to it in stamp within the stamp tolerance, not the first
one there: a stream faster than the camera (a 25 Hz VIO beside a 10 Hz camera, a stream of
another camera) has an older cloud within a widened tolerance as well as the frame's own.
So a frame waits, as an image waits for its partner, until its cloud is known: a cloud of
its very stamp with points came (none can be nearer), a cloud stamped past its stamp plus
the tolerance came (none nearer is to come from an ordered stream), it waited as long as the
pairing's hold allows (by log time, messages and bytes: :mod:`frontend.pairing_window`; a
feature stream logged a second after its images still matches), or the stream ended. Among
clouds equally near (two publishers on one topic, a republished cloud) one with points is
taken before an empty one; a cloud nearer to another frame waiting (a camera faster than
the tolerance is wide) is left to that one. A frame given up without a cloud, or a cloud
given up without a frame, whose partner comes later is counted lost with the lag
(``PairingStats.lost_features``), for the warning naming the lag and ``--hold-s``.

A cloud stamped 0 (its publisher never set the stamp) is placed at no frame with a stamp,
whatever the tolerance: it is counted (``PairingStats.features_unstamped``) and left out of
the nearest miss, for the error to say what is wrong rather than advise a tolerance of the
images' age (41 years). It is not paired by log time either: a cloud is logged after its
image by the time its producer took (a VIO's 30-100 ms, as long as a frame interval or
longer), so the frame logged before it may be the next one, and nothing in the log tells
which. Frames stamped 0 themselves (paired by log time) still take clouds stamped 0.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.frontend.pairing_window import HeldQueue, Hold
from pcainterp_stream.io import rosmsg
from pcainterp_stream.records import SparseFeatures, StereoFrame

__all__ = ["FeatureMatcher", "features_from_pointcloud"]


def features_from_pointcloud(message: Any, log_time_ns: int) -> SparseFeatures:
    """Convert a ``PointCloud2`` with x, y, z fields into :class:`~records.SparseFeatures`.

    Points with a non-finite coordinate are dropped. Only the x, y and z fields are decoded:
    another field (intensity, rgb, a label of an unset datatype 0) is not looked at.

    Raises:
        ValueError: the cloud lacks an x, y or z field, one of an unknown datatype, or its
            data is short.
    """
    fields = rosmsg.pointcloud2_arrays(message, ("x", "y", "z"))
    missing = [name for name in ("x", "y", "z") if name not in fields]
    if missing:
        names = ", ".join(str(field.name) for field in message.fields)
        raise ValueError(f"point cloud has no field {', '.join(missing)} (fields: {names})")
    points = np.stack([fields["x"], fields["y"], fields["z"]], axis=1).astype(np.float32)
    points = points[np.isfinite(points).all(axis=1)]
    return SparseFeatures(
        stamp_ns=rosmsg.stamp_ns(message),
        log_time_ns=int(log_time_ns),
        frame_id=str(message.header.frame_id),
        points=points.reshape(-1, 3),
    )


class FeatureMatcher:
    """Hold frames until their feature cloud is known; see the module docstring.

    Args:
        tolerance_ns: largest difference of header stamps that still matches (ns).
        hold: the pairing's hold: frames wait in one of its queues (the oldest beyond its
            limits is released with the nearest cloud there is, or none), clouds waiting for
            a frame in another (the oldest beyond them is dropped).
        stats: the pairing's statistics: matched, unmatched and lost clouds, the nearest miss.
    """

    def __init__(self, tolerance_ns: int, hold: Hold, stats: PairingStats) -> None:
        self.tolerance_ns = tolerance_ns
        self.stats = stats
        self.matched: dict[int, SparseFeatures] = {}  # frame index -> its cloud
        self._hold = hold
        # waiting for their cloud to be known; clouds waiting for a frame
        self._held: HeldQueue[StereoFrame] = hold.queue(lambda f: f.left.nbytes * 2)
        self._clouds: HeldQueue[SparseFeatures] = hold.queue(lambda c: c.points.nbytes)
        self._latest_ns: int | None = None  # the latest cloud stamp seen

    def hold(self, frame: StereoFrame) -> list[StereoFrame]:
        """Add a frame; return the frames whose cloud is now known, in order."""
        given_up = self._hold.taken("cloud", frame.stamp_ns)
        if given_up is not None:  # its cloud was given up before it came
            self.stats.lost_features.add(given_up.log_time_ns - frame.log_time_ns, given_up)
        self._held.append(frame)
        return self._release()

    def push(self, features: SparseFeatures) -> list[StereoFrame]:
        """Add a cloud; return the frames whose cloud is now known, in order."""
        latest = self._latest_ns
        self._latest_ns = features.stamp_ns if latest is None else max(latest, features.stamp_ns)
        given_up = self._hold.taken("frame", features.stamp_ns)
        if given_up is not None:  # its frame went on without it: cloud log minus frame log
            self.stats.lost_features.add(features.log_time_ns - given_up.log_time_ns, given_up)
        self._clouds.append(features)
        dropped = self._hold.give_up("cloud", self._clouds)
        self.stats.features_unmatched += len(dropped)
        self.stats.features_unstamped += sum(cloud.stamp_ns == 0 for cloud in dropped)
        return self._release()

    def take(self, index: int) -> SparseFeatures | None:
        """Return (once) the cloud matched to the frame of this index, None when none was."""
        return self.matched.pop(index, None)

    def flush(self) -> list[StereoFrame]:
        """Release every frame still held with the nearest cloud left (end of the stream)."""
        frames = self._release(force=True)
        self.stats.features_unmatched += len(self._clouds)
        self.stats.features_unstamped += sum(cloud.stamp_ns == 0 for cloud in self._clouds)
        self._clouds.clear()
        return frames

    def _nearest(self, frame: StereoFrame) -> SparseFeatures | None:
        """Return the cloud nearest a frame's stamp within the tolerance (with points first).

        A cloud nearer to another held frame's stamp is left to that frame; one stamped 0 is
        for a frame stamped 0 only (:func:`_placed`).
        """
        stamp_ns = frame.stamp_ns
        reach = 2 * self.tolerance_ns  # a frame farther cannot be nearer to a cloud in reach
        others = [
            held.stamp_ns
            for held in self._held
            if held is not frame and abs(held.stamp_ns - stamp_ns) <= reach
        ]
        near = [
            c
            for c in self._clouds
            if abs(c.stamp_ns - stamp_ns) <= self.tolerance_ns
            and _placed(c, frame)
            and all(abs(c.stamp_ns - other) >= abs(c.stamp_ns - stamp_ns) for other in others)
        ]
        if not near:
            return None
        # min keeps the first of equals: the one recorded first among clouds with points
        return min(near, key=lambda c: (abs(c.stamp_ns - stamp_ns), c.points.shape[0] == 0))

    def _release(self, *, force: bool = False) -> list[StereoFrame]:
        """Release held frames whose cloud is known, in order (all of them with ``force``)."""
        released: list[StereoFrame] = []
        while self._held:
            frame = self._held[0]
            nearest = self._nearest(frame)
            exact = (
                nearest is not None
                and nearest.stamp_ns == frame.stamp_ns
                and nearest.points.shape[0] > 0
            )
            latest = self._latest_ns
            known = (
                force
                or exact
                or (latest is not None and latest > frame.stamp_ns + self.tolerance_ns)
            )
            limit = None if known else self._hold.beyond(self._held)  # held as long as allowed
            if not known and limit is None:
                break
            if nearest is not None:
                self._clouds.remove(nearest)  # by identity
                self.matched[frame.index] = nearest
                self.stats.features_matched += 1
            else:
                if limit is not None:  # given up without a cloud: one of its stamp is lost
                    self._hold.remember("frame", self._held, limit)
                self.stats.feature_miss(frame.stamp_ns, _stamps(self._clouds, frame))
            released.append(self._held.popleft())
        # clouds older than every frame still to come match nothing
        if self._held:
            horizon = self._held[0].stamp_ns - self.tolerance_ns
            stale = [c for c in self._clouds if c.stamp_ns < horizon]
            self.stats.feature_miss(self._held[0].stamp_ns, _stamps(stale, self._held[0]))
            for cloud in stale:
                self._clouds.remove(cloud)
            self.stats.features_unmatched += len(stale)
            self.stats.features_unstamped += sum(cloud.stamp_ns == 0 for cloud in stale)
        return released


def _placed(cloud: SparseFeatures, frame: StereoFrame) -> bool:
    """Whether a cloud's stamp can place it at a frame: not 0 (unset) beside a frame's stamp."""
    return cloud.stamp_ns != 0 or frame.stamp_ns == 0


def _stamps(clouds: Iterable[SparseFeatures], frame: StereoFrame) -> list[int]:
    """Return the stamps of the clouds that a frame could have taken (:func:`_placed`)."""
    return [cloud.stamp_ns for cloud in clouds if _placed(cloud, frame)]
