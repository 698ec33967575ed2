"""The baseline a log's ``/tf_static`` gives between its two cameras, when their infos give none.

A driver whose right ``CameraInfo`` has no Tx (P[0, 3] = 0) may still publish the stereo
extrinsics as static transforms (``camera_left_optical -> camera_right_optical``). The
distance between the two images' ``header.frame_id`` origins, composed along the
``/tf_static`` tree, is the baseline ``--baseline`` asks for: :func:`tf_baseline_line` says it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stream_kinds import first_tx
from pcainterp_stream.io.reader_base import LogReader

TF_STATIC = "/tf_static"
_Pose = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]  # rotation, translation


def _rotation(q: Any) -> npt.NDArray[np.float64]:
    """Return the rotation matrix of a ``geometry_msgs/Quaternion``."""
    x, y, z, w = (float(q.x), float(q.y), float(q.z), float(q.w))
    n = x * x + y * y + z * z + w * w
    if n == 0:
        return np.eye(3)
    s = 2 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )


def _static_edges(reader: LogReader, most: int = 50) -> dict[str, list[tuple[str, _Pose]]]:
    """Return frame -> [(neighbour frame, pose of the neighbour in it)] of ``/tf_static``."""
    edges: dict[str, list[tuple[str, _Pose]]] = {}
    for i, raw in enumerate(reader.messages([TF_STATIC])):
        if i >= most:
            break
        try:
            transforms = reader.decode(raw).transforms
        except (PcaInterpError, AttributeError, TypeError, ValueError):
            continue
        for t in transforms:
            parent = str(t.header.frame_id).lstrip("/")
            child = str(t.child_frame_id).lstrip("/")
            v = t.transform.translation
            rot = _rotation(t.transform.rotation)
            trans = np.array([float(v.x), float(v.y), float(v.z)])
            edges.setdefault(parent, []).append((child, (rot, trans)))
            edges.setdefault(child, []).append((parent, (rot.T, -rot.T @ trans)))
    return edges


def static_distance(reader: LogReader, left: str, right: str) -> float | None:
    """Return the distance between two frames' origins along ``/tf_static`` (None: no path)."""
    left, right = left.lstrip("/"), right.lstrip("/")
    if not left or not right or left == right:
        return None
    edges = _static_edges(reader)
    poses: dict[str, _Pose] = {left: (np.eye(3), np.zeros(3))}
    todo = [left]
    while todo:
        frame = todo.pop()
        rot, trans = poses[frame]
        for other, (r, t) in edges.get(frame, []):
            if other not in poses:
                poses[other] = (rot @ r, rot @ t + trans)
                todo.append(other)
    if right not in poses:
        return None
    distance = float(np.linalg.norm(poses[right][1]))
    return distance if np.isfinite(distance) and distance > 0 else None


def _frame_id(reader: LogReader, topic: str) -> str:
    """Return the ``header.frame_id`` of a topic's first message ("" when none)."""
    for raw in reader.messages([topic]):
        try:
            return str(reader.decode(raw).header.frame_id)
        except (PcaInterpError, AttributeError, TypeError, ValueError):
            return ""
    return ""


def tf_baseline_line(
    reader: LogReader, config: PairingConfig, tx_of: Callable[[str], float | None] | None = None
) -> str:
    """Return a line quoting the ``/tf_static`` baseline when the infos give none ("" else).

    Only for a pair read with its camera infos (no calibration files, no ``--baseline``, two
    info topics) whose right info has P[0, 3] = 0, in a log with ``/tf_static``.
    """
    topics = reader.topics()
    if (
        TF_STATIC not in topics
        or config.calibration is not None
        or config.baseline is not None
        or config.left_info_topic == config.right_info_topic
        or config.right_info_topic not in topics
    ):
        return ""
    tx = (tx_of or first_tx(reader))(config.right_info_topic)
    if tx is None or tx != 0:
        return ""
    frames = [_frame_id(reader, t) for t in (config.left_topic, config.right_topic)]
    distance = static_distance(reader, frames[0], frames[1])
    if distance is None:
        return ""
    return (
        f"baseline: {config.right_info_topic} has no Tx (P[0,3] = 0); pass --baseline "
        f"{distance:.4f} (the {TF_STATIC} transform from {frames[0]} to {frames[1]})"
    )
