"""The calibration CameraInfo messages carry, for the pairer (no stream state here).

:func:`camera_from_infos` builds the :class:`~records.StereoCamera` of a rectified pair from
its two camera infos; :func:`first_infos` reads each side's first camera info ahead of the
stream, from a log with an index (a log that recorded its camera infos after its first
images); :func:`calibration_values` says whether two infos carry the same calibration.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pcainterp_stream.errors import CalibrationError, LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.camera_model import (
    image_projection,
    stacked_vertically,
    uncalibrated,
)
from pcainterp_stream.io.reader_base import LogReader
from pcainterp_stream.records import StereoCamera

__all__ = ["calibration_values", "camera_from_infos", "first_infos"]


def camera_from_infos(
    left_info: Any,
    right_info: Any,
    *,
    width: int,
    height: int,
    left_topic: str = "left camera_info",
    right_topic: str = "right camera_info",
    baseline: float | None = None,
    image_topics: tuple[str, str] | None = None,
) -> StereoCamera:
    """Build the stereo calibration from the two rectified ``CameraInfo`` messages.

    P is read as ``image_geometry`` reads it: the full-resolution camera's, moved by the
    ROI and divided by the binning the images were taken with (:func:`image_projection`),
    so the camera describes the images as they are. The baseline is
    (P_left[0, 3] - P_right[0, 3]) / fx: ROS writes Tx = 0 on the left, but a pair
    calibrated against a third camera (KITTI's colour cameras through kitti2bag) has a
    left Tx too.

    Args:
        left_info: left ``CameraInfo`` (ROS 1 ``P`` or ROS 2 ``p``).
        right_info: right ``CameraInfo``; its P[0, 3] = -fx * baseline (+ the left's).
        width: the images' width (px); an info for another size is refused.
        height: their height (px).
        left_topic: topic name used in error messages.
        right_topic: topic name used in error messages.
        baseline: override (m); when given the P[0, 3] are not used.
        image_topics: the (left, right) image topics, named in the advice for a negative
            baseline (the sides swapped).

    Raises:
        CalibrationError: an info for another image size, an uncalibrated (all-zero) P, a
            pair stacked vertically (the right P's Ty), fx or fy not positive, or no positive
            baseline from the P and no override.
    """
    for info, topic in ((left_info, left_topic), (right_info, right_topic)):
        size = rosmsg.imaged_size(info)
        if size is not None and size != (width, height):
            raise CalibrationError(
                f"camera info on {topic} is for {size[0]}x{size[1]} px images but they are "
                f"{width}x{height}: its K and P would be off by the scale; record the images "
                "with their own camera info (or its roi / binning)"
            )
    p_left = image_projection(left_info)
    p_right = image_projection(right_info)
    used = [(left_info, p_left, left_topic)]
    if baseline is None:
        used.append((right_info, p_right, right_topic))
    for info, p, topic in used:  # all zeros: ROS's "not calibrated"
        if np.isfinite(p).all() and not np.any(p[:, :3]):
            k = getattr(info, "k", getattr(info, "K", None))
            zeros = "K and P" if k is not None and not np.any(k) else "P"
            raise CalibrationError(uncalibrated(f"camera info on {topic}", zeros))
    vertical = stacked_vertically(
        p_left, p_right, f"camera info on {right_topic}", baseline=baseline
    )
    if vertical is not None:
        raise CalibrationError(vertical)
    fx, fy, cx, cy = p_left[0, 0], p_left[1, 1], p_left[0, 2], p_left[1, 2]
    if not (np.isfinite(p_left).all() and fx > 0 and fy > 0):
        raise CalibrationError(
            f"camera info on {left_topic} has P with fx={fx}, fy={fy}; a rectified camera "
            "needs positive focal lengths: fix the calibration"
        )
    if baseline is None:
        if not (np.isfinite(p_right).all() and p_right[0, 0] > 0):
            raise CalibrationError(
                f"camera info on {right_topic} has P with fx={p_right[0, 0]}; fix the "
                "calibration or pass --baseline"
            )
        with np.errstate(over="ignore"):  # a damaged tiny fx overflows: caught below
            baseline = float((p_left[0, 3] - p_right[0, 3]) / p_right[0, 0])
        if not (baseline > 0 and np.isfinite(baseline)):
            left_tx = f", left P[0,3] = {p_left[0, 3]}" if p_left[0, 3] else ""
            fix = "pass --baseline METRES"
            if left_topic == right_topic:  # one info read for both sides: Tx - Tx = 0
                fix = (
                    f"{left_topic} was read for both sides: pass --left-info-topic and "
                    "--right-info-topic (each camera's own), or --baseline METRES"
                )
            if baseline < 0:  # a sign problem --baseline cannot fix
                swap = (
                    f"pass --left-topic {image_topics[1]} --right-topic {image_topics[0]}"
                    if image_topics is not None
                    else "exchange --left-topic and --right-topic"
                )
                fix = (
                    f"the sides look swapped ({right_topic}'s camera lies left of "
                    f"{left_topic}'s): if the images are swapped too, {swap} (each with its "
                    f"own camera info); if only the infos are crossed, pass --left-info-topic "
                    f"{right_topic} --right-info-topic {left_topic}"
                )
            raise CalibrationError(
                f"camera info on {right_topic} gives no baseline (P[0,3] = {p_right[0, 3]}, "
                f"fx = {p_right[0, 0]}{left_tx}; expected P_left[0,3] - P_right[0,3] = fx * "
                f"baseline > 0, finite); {fix}"
            )
    return StereoCamera(
        width=int(width),
        height=int(height),
        fx=float(fx),
        fy=float(fy),
        cx=float(cx),
        cy=float(cy),
        baseline=float(baseline),
    )


def calibration_values(info: Any) -> tuple[Any, ...]:
    """Return what a CameraInfo says of its camera (ROS 2 or ROS 1 names), to compare two."""
    values: list[Any] = []
    for name in ("width", "height", "distortion_model", "binning_x", "binning_y"):
        values.append(getattr(info, name, None))
    for name in ("k", "d", "r", "p"):
        array = getattr(info, name, getattr(info, name.upper(), None))
        values.append(None if array is None else tuple(np.asarray(array, float).ravel()))
    roi = getattr(info, "roi", None)
    if roi is not None:
        values.extend(getattr(roi, name, None) for name in ("x_offset", "y_offset", "width"))
        values.extend(getattr(roi, name, None) for name in ("height", "do_rectify"))
    return tuple(values)


def first_infos(reader: LogReader, topics: Sequence[str]) -> list[tuple[str, int, Any]]:
    """Return (topic, log time ns, message) of the first camera info of each topic.

    Only from a log with an index (:meth:`LogReader.indexed`): there the look ahead reads
    the chunks of the info topics alone, up to their first message; elsewhere it would read
    the log twice, and nothing is returned. A topic without a decodable info is left out.
    """
    if not reader.indexed():
        return []
    found = []
    for topic in dict.fromkeys(topics):
        stream = reader.messages([topic])
        raw = next(stream, None)
        close = getattr(stream, "close", None)  # a generator: release its file position
        if close is not None:
            close()
        if raw is None:
            continue
        try:
            found.append((topic, raw.log_time_ns, reader.decode(raw)))
        except LogReadError:
            continue  # the stream's own reading counts it as undecodable
    return found
