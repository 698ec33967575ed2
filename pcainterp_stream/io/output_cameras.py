"""The cameras a densified log's outputs were made with: the ``pcainterp.cameras`` record.

A compact log stores depth, whose disparity is f*b / depth: a reader needs each frame's f*b,
and the smallest resolvable disparity (below it: "too far") that a full log's
``DisparityImage`` carries per frame. The output channels' metadata holds both of the first
outputs (:data:`~.outputs.FOCAL_BASELINE_KEY`, :data:`~.outputs.MIN_DISPARITY_KEY`): a
channel's metadata is fixed when its first message is written. When either changes in the
log (densify densifies each pair with its own camera; the min disparity is the noise std of
the basis in force, so it changes with the basis, and may change every frame with ``--sigma
evidence``, which fits it per frame), the MCAP metadata record :data:`CAMERAS_RECORD`,
written at the end as ``pcainterp.basis`` is, lists the (camera, min disparity) in force
from the first frame of each change, with the same per-entry keys: ``count``,
``output_prefix`` and, per entry ``N`` (0, 1, ...), ``N.focal_baseline`` (px*m),
``N.min_disparity`` (px), ``N.first_frame``, ``N.first_stamp_ns`` and
``N.first_log_time_ns``. A frame's values are those of the last entry whose
``first_log_time_ns`` is at or before its outputs' log time (:meth:`FrameCameras.metadata`).
A log without the record (neither changed, or densified before it was written) has one f*b
and min disparity for every frame: the channels'. Logs densified before the min disparity's
changes were recorded list camera changes only: their frames after a basis change read the
min disparity of their camera's first frame.

A copy of a log that kept its channels and messages but dropped its MCAP metadata records
(``mcap filter`` without ``--include-metadata``) lost the record of a camera change. Each
feature point holds z = f*b / disparity, so a frame's features state its own f*b
(:func:`features_focal_baseline`): :meth:`FrameCameras.metadata` given the features message
decodes a frame whose features state another f*b than the channel's with theirs, and counts
it (:attr:`FrameCameras.unrecorded`) for a reader to say so.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.densify_record import OUTPUT_PREFIX_KEY
from pcainterp_stream.io.outputs import (
    CAMERAS_RECORD,
    FOCAL_BASELINE_KEY,
    MIN_DISPARITY_KEY,
    _records,
    record_of_prefix,
)
from pcainterp_stream.records import DensifiedFrame, StereoCamera

__all__ = [
    "CAMERAS_RECORD",
    "CameraInForce",
    "CamerasInForce",
    "FrameCameras",
    "cameras_record",
    "features_focal_baseline",
    "recorded_cameras_of",
]


class CameraInForce(NamedTuple):
    """The camera and min disparity a densified log's outputs were made with, from a frame on.

    Attributes:
        focal_baseline: the camera's f*b (px*m): a compact frame's disparity is f*b / depth.
        min_disparity: the smallest resolvable disparity (px) from that frame on.
        first_frame: 0-based index of the first stereo pair densified with both.
        first_stamp_ns: that pair's header stamp (ns).
        first_log_time_ns: its log time (ns), the log time of its outputs.
    """

    focal_baseline: float
    min_disparity: float
    first_frame: int
    first_stamp_ns: int
    first_log_time_ns: int


class CamerasInForce:
    """The cameras and min disparities of a densify run's outputs (:meth:`see` each frame)."""

    def __init__(self) -> None:
        self.entries: list[CameraInForce] = []
        self._camera: StereoCamera | None = None

    def see(self, result: DensifiedFrame) -> None:
        """Count a densified frame: a new entry at the first frame and at each change.

        A change of the camera or of the min disparity (the basis in force, or ``--sigma
        evidence``'s fit); one entry per frame at most. A frame without an estimate (a black
        frame: its maps are NaN, its min disparity a fallback's) adds none for its min
        disparity alone.
        """
        camera, frame = result.frame.camera, result.frame
        min_disparity = float(result.min_disparity)
        if (
            self.entries
            and camera == self._camera
            and (min_disparity == self.entries[-1].min_disparity or not result.estimated)
        ):
            return
        self._camera = camera
        self.entries.append(
            CameraInForce(
                float(camera.focal_baseline),
                min_disparity,
                frame.index,
                frame.stamp_ns,
                frame.log_time_ns,
            )
        )

    def record(self, prefix: str | None = None) -> dict[str, str] | None:
        """Return the :data:`CAMERAS_RECORD` record, or None for one entry (the channels')."""
        return cameras_record(self.entries, prefix) if len(self.entries) > 1 else None


def cameras_record(cameras: Iterable[CameraInForce], prefix: str | None = None) -> dict[str, str]:
    """Return the :data:`CAMERAS_RECORD` metadata record of the entries in force, in order.

    ``prefix``: the output topics' prefix, recorded under ``output_prefix`` (None: not
    recorded). Floats are written as ``repr`` (read back exactly).

    Examples:
        >>> entry = CameraInForce(96.5, 0.25, 6, 5, 7)
        >>> record = cameras_record([entry], "/pcainterp")
        >>> record["count"], record["0.focal_baseline"], record["0.first_frame"]
        ('1', '96.5', '6')
        >>> recorded_cameras_of(record) == [entry]
        True
    """
    entries = list(cameras)
    record = {"count": str(len(entries))}
    if prefix is not None:
        record[OUTPUT_PREFIX_KEY] = prefix
    for number, entry in enumerate(entries):
        record.update(
            {
                f"{number}.{name}": repr(value) if isinstance(value, float) else str(value)
                for name, value in entry._asdict().items()
            }
        )
    return record


def recorded_cameras_of(record: dict[str, str]) -> list[CameraInForce]:
    """Return the entries a :data:`CAMERAS_RECORD` record lists (:func:`cameras_record`'s inverse).

    Raises:
        ValueError: the record is not one :func:`cameras_record` wrote.
    """
    try:
        return [
            CameraInForce(
                float(record[f"{number}.focal_baseline"]),
                float(record[f"{number}.min_disparity"]),
                int(record[f"{number}.first_frame"]),
                int(record[f"{number}.first_stamp_ns"]),
                int(record[f"{number}.first_log_time_ns"]),
            )
            for number in range(int(record["count"]))
        ]
    except (KeyError, ValueError) as err:
        raise ValueError(
            f"not a {CAMERAS_RECORD} metadata record: {err!r} missing or invalid"
        ) from err


UNRECORDED_TOLERANCE = 1e-3
"""A frame's features state another camera when their f*b is this share off the channel's."""


def features_focal_baseline(features: Any) -> float | None:
    """Return the f*b (px*m) a frame's features message states (None: no point with a disparity).

    Each point holds z = f*b / disparity: the median of z * disparity.
    """
    arrays = rosmsg.pointcloud2_arrays(features)
    if "z" not in arrays or "disparity" not in arrays:
        return None
    z = np.asarray(arrays["z"], dtype=np.float64)
    disparity = np.asarray(arrays["disparity"], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(z) & np.isfinite(disparity) & (z > 0) & (disparity > 0)
    return float(np.median(z[usable] * disparity[usable])) if usable.any() else None


class FrameCameras:
    """Each frame's f*b and min disparity in a densified log (the channels' without a record).

    Attributes:
        unrecorded: without the record, the f*b of each frame whose features stated another
            camera's than the channel's (:meth:`metadata` given ``features``).
    """

    def __init__(self, cameras: Iterable[CameraInForce] = ()) -> None:
        self.cameras = sorted(cameras, key=lambda entry: entry.first_log_time_ns)
        self._starts = [entry.first_log_time_ns for entry in self.cameras]
        self.unrecorded: list[float] = []
        self._stated: float | None = None  # the f*b the last frame's features stated

    @classmethod
    def of_log(cls, path: Path, prefix: str | None = None) -> FrameCameras:
        """Return the cameras an MCAP log records for the outputs of ``prefix`` (none: empty).

        Raises:
            ValueError: the log's record is not one densify wrote (the message names ``path``).
        """
        record, _ = record_of_prefix(_records(path, CAMERAS_RECORD), prefix)
        if record is None:
            return cls()
        try:
            return cls(recorded_cameras_of(record))
        except ValueError as err:
            raise ValueError(f"{path}: {err}; densify the log again") from None

    def __len__(self) -> int:
        return len(self.cameras)

    def metadata(
        self, channel: dict[str, str], log_time_ns: int, features: Any = None
    ) -> dict[str, str]:
        """Return a channel's metadata with the f*b and min disparity in force at a frame.

        ``log_time_ns``: the log time of the frame's outputs. The channel's own metadata when
        the log records no change (no :data:`CAMERAS_RECORD`), unless the frame's
        ``features`` message (given for a compact log) states another f*b than the channel's
        (the record lost): then that f*b (a frame whose features hold no disparity: the frame
        before's), counted in :attr:`unrecorded`; the min disparity stays the channel's.

        Examples:
            >>> first, second = CameraInForce(2.0, 0.5, 0, 0, 0), CameraInForce(1.0, 0.25, 6, 6, 60)
            >>> cameras = FrameCameras([first, second])
            >>> cameras.metadata({}, 59)["pcainterp.focal_baseline"]
            '2.0'
            >>> cameras.metadata({}, 60)["pcainterp.focal_baseline"]
            '1.0'
        """
        if not self.cameras:
            return channel if features is None else self._stated_by(channel, features)
        entry = self.cameras[max(bisect_right(self._starts, log_time_ns) - 1, 0)]
        return {
            **channel,
            FOCAL_BASELINE_KEY: repr(entry.focal_baseline),
            MIN_DISPARITY_KEY: repr(entry.min_disparity),
        }

    def _stated_by(self, channel: dict[str, str], features: Any) -> dict[str, str]:
        """Return the channel's metadata, or with the f*b a frame's features state if other."""
        try:
            recorded = float(channel[FOCAL_BASELINE_KEY])
        except (KeyError, ValueError):
            return channel
        stated = features_focal_baseline(features)
        self._stated = stated = self._stated if stated is None else stated
        if stated is None or abs(stated - recorded) <= UNRECORDED_TOLERANCE * abs(recorded):
            return channel
        self.unrecorded.append(stated)
        return {**channel, FOCAL_BASELINE_KEY: repr(stated)}

    @property
    def unrecorded_note(self) -> str:
        """Return the sentence on the frames decoded with their features' f*b ("": none)."""
        if not self.unrecorded:
            return ""
        low, high = f"{min(self.unrecorded):.6g}", f"{max(self.unrecorded):.6g}"
        stated = low if low == high else f"{low}-{high}"
        return (
            f"{len(self.unrecorded)} frames were decoded with the f*b their features "
            f"state ({stated} px*m, z * disparity), not the depth channel's: the camera changed "
            f"and the log has no {CAMERAS_RECORD} record (a copy that dropped the MCAP metadata "
            "records, e.g. `mcap filter` without --include-metadata); their smallest "
            "resolvable disparity is the first frame's; evaluate the log densify wrote to have it"
        )
