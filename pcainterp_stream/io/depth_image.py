"""Depth images of a log read as metres, whatever their REP 118 encoding.

=====================================================  ======================================
message type and encoding                              values
=====================================================  ======================================
``sensor_msgs/msg/Image`` 32FC1                        metres; NaN: no value; +inf: far
``sensor_msgs/msg/Image`` 16UC1 / mono16               millimetres; 0: no value
``sensor_msgs/msg/CompressedImage`` compressedDepth    as its encoding (32FC1 or 16UC1)
=====================================================  ======================================

pcainterp's own outputs are of these forms: the compact ``depth`` is a ``32FC1;
compressedDepth`` image and ``depth_mm`` a 16UC1 one, whose largest value (60 m,
:data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH`) also stands for anything farther. A
camera image (mono8, rgb8, png or jpeg) is not depth: :func:`depth_metres` refuses it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logreader import LogReader
from pcainterp_stream.records import RawMessage

__all__ = ["DEPTH_ENCODINGS", "DEPTH_TYPES", "depth_metres", "depth_topics"]

DEPTH_ENCODINGS = {"32FC1": 1.0, "16UC1": 1e-3, "mono16": 1e-3}
"""Image encodings a depth image may have, with their unit in metres (REP 118)."""

DEPTH_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE)
"""Message types a depth topic may have (a CompressedImage only in a compressedDepth format)."""


def depth_metres(message: Any) -> npt.NDArray[np.float64]:
    """Decode a depth image into metres.

    Args:
        message: a decoded ``sensor_msgs/Image`` (32FC1, 16UC1, mono16) or
            ``sensor_msgs/CompressedImage`` of a ``compressedDepth`` format.

    Returns:
        (H, W) float64 depth (m): NaN where the image holds no value (a 16-bit 0), +inf
        where a 32FC1 image says "farther than measurable".

    Raises:
        ValueError: a camera image (says which encoding or format), or data that do not decode.
    """
    if str(message.__msgtype__) == rosmsg.COMPRESSED_IMAGE:
        image_format = str(message.format)
        parsed = depth_codec.parse_format(image_format)
        if parsed is None:
            raise ValueError(f"{image_format!r} is a compressed camera image, not depth")
        raw = depth_codec.decode(image_format, np.asarray(message.data, dtype=np.uint8))
        unit = DEPTH_ENCODINGS[parsed[0]]
    else:
        encoding = str(message.encoding)
        if encoding not in DEPTH_ENCODINGS:
            what = "a camera image" if encoding in rosmsg.CAMERA_IMAGE_ENCODINGS else "an image"
            raise ValueError(
                f"{encoding} is {what}, not depth (depth is "
                f"{', '.join(DEPTH_ENCODINGS)} or compressedDepth)"
            )
        raw = rosmsg.image_array(message)
        unit = DEPTH_ENCODINGS[encoding]
    values = raw.astype(np.float64) * unit
    if np.issubdtype(raw.dtype, np.integer):  # 0 mm is "no value" (REP 118)
        values[raw == 0] = np.nan
    return values


def _is_depth(message: Any) -> bool:
    if str(message.__msgtype__) == rosmsg.COMPRESSED_IMAGE:
        return depth_codec.is_compressed_depth(str(message.format))
    return str(message.encoding) in DEPTH_ENCODINGS


def first_message(reader: LogReader, topic: str) -> RawMessage | None:
    """Return a topic's first message (None when it has none), leaving the log unread after."""
    stream = reader.messages([topic])
    raw = next(stream, None)
    close = getattr(stream, "close", None)  # a generator: release its file position
    if close is not None:
        close()
    return raw


def depth_topics(reader: LogReader) -> list[str]:
    """Return the image topics of a log whose first message is a depth image.

    Topics named for a disparity or a standard deviation (``disparity_std``) are left out.

    Reads the first message of each ``Image`` and ``CompressedImage`` topic (for an error
    message's suggestions: on a log without an index that reads up to it).
    """
    found = []
    for topic, info in reader.topics().items():
        name = topic.rsplit("/", 1)[-1]
        if info.msgtype not in DEPTH_TYPES or "disparity" in name or name.endswith("std"):
            continue  # a 32FC1 disparity or standard deviation is no depth
        raw = first_message(reader, topic)
        try:
            if raw is not None and _is_depth(reader.decode(raw)):
                found.append(topic)
        except (ValueError, AttributeError, PcaInterpError):
            continue  # undecodable: not offered
    return found
