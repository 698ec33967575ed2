"""Turn any decoded ROS message into plain values and numeric arrays, for golden summaries.

:func:`message_content` walks a message generically: strings and numbers become values,
large numeric sequences become arrays, nested messages are flattened into dotted names
(``header.frame_id``, ``p``, ``image.step``). The types whose payload is an encoded array
are decoded first: ``sensor_msgs/Image`` (every REP 118 encoding of
:data:`~pcainterp_stream.io.rosmsg.IMAGE_ENCODINGS`), ``sensor_msgs/CompressedImage`` (png
and jpeg through OpenCV, a Bayer mosaic demosaiced as its Image is, and image_transport's
``compressedDepth`` formats through :func:`decode_compressed_depth`),
``stereo_msgs/DisparityImage`` (its image) and ``sensor_msgs/PointCloud2`` (one array per
point field).

:func:`decode_compressed_depth` is the one place that knows the ``compressedDepth`` wire
format; the rest of the package only calls it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.depth_codec import rvl_decode

__all__ = [
    "MAX_VALUE_LENGTH",
    "MessageContent",
    "decode_compressed_depth",
    "message_content",
    "rvl_decode",
]

MAX_VALUE_LENGTH = 64
"""Numeric sequences up to this length are kept as values (CameraInfo's K, D, R, P); longer
ones are summarised as arrays."""


@dataclasses.dataclass
class MessageContent:
    """What :func:`message_content` found in one message.

    Attributes:
        values: dotted field name -> str, int, float, bool or a short list of numbers.
        arrays: dotted name -> numeric array (an image is (H, W) or (H, W, C); a point field
            is (n,)).
        notes: one-line notes on parts that could not be decoded (kept as values too, so
            that a golden file records them).
    """

    values: dict[str, Any] = dataclasses.field(default_factory=dict)
    arrays: dict[str, npt.NDArray[Any]] = dataclasses.field(default_factory=dict)
    notes: list[str] = dataclasses.field(default_factory=list)


def decode_compressed_depth(image_format: str, data: bytes) -> npt.NDArray[np.generic]:
    """Decode a ``sensor_msgs/CompressedImage`` of image_transport's ``compressedDepth``.

    The data start with a 12-byte ConfigHeader {int32 format, float32 depthQuantA, float32
    depthQuantB}, then a 16-bit PNG, or for ``rvl`` two int32 (columns, rows) and an RVL
    stream; decoded by :func:`pcainterp_stream.io.depth_codec.decode`, as ROS's subscriber
    decodes them.

    Args:
        image_format: the message's ``format``, e.g. ``"32FC1; compressedDepth png"``,
            ``"16UC1; compressedDepth rvl"`` (``"...; compressedDepth"`` alone means png).
        data: the message's ``data`` bytes.

    Returns:
        (H, W) float32 depth (m) for 32FC1, (H, W) uint16 (mm) for 16UC1.

    Raises:
        ValueError: the format is not a compressedDepth one, or the data do not decode.
    """
    return np.asarray(depth_codec.decode(image_format, data))


def _compressed_image(message: Any) -> npt.NDArray[np.generic]:
    image_format = str(message.format)
    if depth_codec.is_compressed_depth(image_format):
        return decode_compressed_depth(image_format, bytes(np.asarray(message.data, np.uint8)))
    data = np.asarray(message.data, dtype=np.uint8)
    if data.size == 0:  # cv2.imdecode asserts on it
        raise ValueError(f"CompressedImage of format {image_format!r} is empty (0 bytes)")
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"CompressedImage of format {image_format!r} does not decode")
    # a Bayer mosaic (``bayer_rggb8; png compressed ``) as the raw Image of its encoding
    return np.asarray(rosmsg.demosaic_compressed(image, image_format))


def _is_message(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def _walk(value: Any, name: str, content: MessageContent, skip: frozenset[str]) -> None:
    if name in skip:
        return
    if _is_message(value):
        if hasattr(value, "sec") and hasattr(value, "nanosec"):  # builtin_interfaces/Time
            content.values[name] = int(value.sec) * 1_000_000_000 + int(value.nanosec)
            return
        for field in dataclasses.fields(value):
            child = f"{name}.{field.name}" if name else field.name
            _walk(getattr(value, field.name), child, content, skip)
    elif isinstance(value, str | bool | int | float | np.generic):
        content.values[name] = value.item() if isinstance(value, np.generic) else value
    elif isinstance(value, np.ndarray):
        if value.size <= MAX_VALUE_LENGTH:
            content.values[name] = [v.item() for v in value.reshape(-1)]
        else:
            content.arrays[name] = value
    elif isinstance(value, list | tuple):
        if len(value) > MAX_VALUE_LENGTH:
            content.values[f"{name}.length"] = len(value)
        elif all(isinstance(v, int | float | bool | str) for v in value):
            content.values[name] = list(value)
        else:
            for i, item in enumerate(value):
                _walk(item, f"{name}[{i}]", content, skip)


def message_content(msgtype: str, message: Any) -> MessageContent:
    """Return the values and arrays of a decoded message (any type).

    Args:
        msgtype: the type in ROS 2 spelling (``sensor_msgs/msg/Image``).
        message: a rosbags typestore message of that type.

    Returns:
        The flattened values and arrays. Images decode to ``image`` (and a
        DisparityImage's to ``image.image``), point clouds to ``points.<field>``; their raw
        ``data`` bytes are not kept. A payload that does not decode leaves a note and its
        byte count (``data.length``) instead of an array.
    """
    content = MessageContent()
    skip = {
        rosmsg.IMAGE: frozenset({"data"}),
        rosmsg.COMPRESSED_IMAGE: frozenset({"data"}),
        rosmsg.DISPARITY_IMAGE: frozenset({"image.data"}),
        rosmsg.POINT_CLOUD2: frozenset({"data"}),
    }.get(msgtype, frozenset())
    try:
        if msgtype == rosmsg.IMAGE:
            content.arrays["image"] = rosmsg.image_array(message)
        elif msgtype == rosmsg.COMPRESSED_IMAGE:
            content.arrays["image"] = _compressed_image(message)
        elif msgtype == rosmsg.DISPARITY_IMAGE:
            content.arrays["image.image"] = rosmsg.image_array(message.image)
        elif msgtype == rosmsg.POINT_CLOUD2:
            for field_name, values in rosmsg.pointcloud2_arrays(message).items():
                content.arrays[f"points.{field_name}"] = values
    except ValueError as err:
        content.notes.append(str(err))
        content.values["decode_error"] = str(err)
        content.arrays.clear()
    _walk(message, "", content, skip)
    if skip and content.notes:  # keep the size of a payload we could not decode
        data = message.image.data if msgtype == rosmsg.DISPARITY_IMAGE else message.data
        content.values["data.length"] = len(data)
    return content
