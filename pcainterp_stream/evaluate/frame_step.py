"""The frame interval of a densified log, read from its output camera infos (``evaluate``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.outputs import OutputTopics

__all__ = ["frame_step_ns"]


def frame_step_ns(path: Path, topics: OutputTopics, max_frames: int | None) -> int | None:
    """Return the median step (ns) of a densified log's frame stamps, the frame interval.

    Read from the output camera infos (one per frame, small), in log order: the median of
    the steps forward in time, so that a pause or a clock that goes back does not move it.
    Steps under a quarter of their log-time step are left out while others remain: frames
    densify placed within one frame interval of a clock paused at start (review 16b: 24
    such steps of 3 ms beside 15 of 100 ms took the median, and no real frame paired).
    None when there are fewer than two frames or no step forward.

    Args:
        path: a log written by ``pcainterp densify``.
        topics: its output topics.
        max_frames: read at most this many frames and one more (None: all).
    """
    previous: int | None = None
    previous_log = 0
    steps: list[int] = []
    slow: list[int] = []  # steps under a quarter of their log-time step
    with open_log(path) as reader:
        if topics.camera_info not in reader.topics():
            return None
        for count, raw in enumerate(reader.messages([topics.camera_info])):
            if max_frames is not None and count > max_frames:
                break
            stamp = rosmsg.stamp_ns(reader.decode(raw)) or raw.log_time_ns
            if previous is not None and stamp > previous:
                step = stamp - previous
                (slow if 4 * step < raw.log_time_ns - previous_log else steps).append(step)
            previous, previous_log = stamp, raw.log_time_ns
    steps = steps or slow
    return int(np.median(steps)) if steps else None
