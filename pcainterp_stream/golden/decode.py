"""Turn any decoded ROS message into plain values and numeric arrays, for golden summaries.

:func:`message_content` walks a message generically: strings and numbers become values,
large numeric sequences become arrays, nested messages are flattened into dotted names
(``header.frame_id``, ``p``, ``image.step``). The types whose payload is an encoded array
are decoded first: ``sensor_msgs/Image`` (every REP 118 encoding of
:data:`~pcainterp_stream.io.rosmsg.IMAGE_ENCODINGS`), ``sensor_msgs/CompressedImage`` (png
and jpeg through OpenCV, and image_transport's ``compressedDepth`` formats through
:func:`decode_compressed_depth`), ``stereo_msgs/DisparityImage`` (its image) and
``sensor_msgs/PointCloud2`` (one array per point field).

:func:`decode_compressed_depth` is the one place that knows the ``compressedDepth`` wire
format; the rest of the package only calls it.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.io import rosmsg

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

_CONFIG_HEADER = struct.Struct("<iff")  # compressedDepth ConfigHeader: format, quant A, quant B


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


def rvl_decode(data: bytes, n_pixels: int) -> npt.NDArray[np.uint16]:
    """Decode an RVL stream (Wilson 2017, "Fast lossless depth image compression").

    RVL codes runs of zeros and runs of non-zero values; each non-zero value is the
    zig-zag coded difference to the previous one. Every number is a variable-length code of
    3-bit groups, least significant first, one group per 4-bit nibble whose high bit says
    that another group follows; nibbles fill little-endian 32-bit words from the top.

    Args:
        data: the RVL bytes (a whole number of 32-bit words; shorter input is zero-padded).
        n_pixels: number of values to decode.

    Returns:
        (n_pixels,) uint16 values in stream order.

    Raises:
        ValueError: the stream ends before ``n_pixels`` values or codes more than that.
    """
    padded = bytes(data) + b"\x00" * (-len(data) % 4)
    words = np.frombuffer(padded, dtype="<u4")
    shifts = np.arange(28, -1, -4, dtype=np.uint32)
    nibbles = ((words[:, None] >> shifts[None, :]) & 0xF).reshape(-1).astype(np.int64)
    ends = np.flatnonzero((nibbles & 0x8) == 0)
    starts = np.concatenate(([0], ends[:-1] + 1))
    # the value of each code: sum of its 3-bit groups, group k shifted by 3k
    group = np.repeat(np.arange(ends.size), ends - starts + 1)
    position = np.arange(group.size) - starts[group]
    codes = np.zeros(ends.size, dtype=np.int64)
    np.add.at(codes, group, (nibbles[: group.size] & 0x7) << (3 * position))
    out = np.zeros(n_pixels, dtype=np.int64)
    filled, cursor, previous = 0, 0, 0
    while filled < n_pixels:
        if cursor + 2 > codes.size:
            raise ValueError(f"RVL stream ends after {filled} of {n_pixels} pixels")
        zeros, nonzeros = int(codes[cursor]), int(codes[cursor + 1])
        cursor += 2
        if filled + zeros + nonzeros > n_pixels or cursor + nonzeros > codes.size:
            raise ValueError(f"RVL stream codes more than {n_pixels} pixels or ends early")
        filled += zeros
        positive = codes[cursor : cursor + nonzeros]
        deltas = (positive >> 1) ^ -(positive & 1)  # zig-zag decoding
        out[filled : filled + nonzeros] = previous + np.cumsum(deltas)
        if nonzeros:
            previous = int(out[filled + nonzeros - 1])
        filled += nonzeros
        cursor += nonzeros
    return (out & 0xFFFF).astype(np.uint16)


def decode_compressed_depth(image_format: str, data: bytes) -> npt.NDArray[np.generic]:
    """Decode a ``sensor_msgs/CompressedImage`` of image_transport's ``compressedDepth``.

    The data start with a 12-byte ConfigHeader {int32 format, float32 depthQuantA, float32
    depthQuantB}. For ``32FC1`` the image is quantised inverse depth v (uint16) and
    ``depth = depthQuantA / (v - depthQuantB)`` where v != 0, NaN where v == 0; for
    ``16UC1`` it is the depth itself (mm). After the header comes a 16-bit PNG, or for
    ``rvl`` two int32 (columns, rows) and an RVL stream (:func:`rvl_decode`).

    Args:
        image_format: the message's ``format``, e.g. ``"32FC1; compressedDepth png"``,
            ``"16UC1; compressedDepth rvl"`` (``"...; compressedDepth"`` alone means png).
        data: the message's ``data`` bytes.

    Returns:
        (H, W) float32 depth (m) for 32FC1, (H, W) uint16 (mm) for 16UC1.

    Raises:
        ValueError: the format is not a compressedDepth one, or the data do not decode.
    """
    words = image_format.replace(";", " ").split()
    lowered = [word.lower() for word in words]
    if "compresseddepth" not in lowered or not words or words[0] not in ("32FC1", "16UC1"):
        raise ValueError(
            f"not a compressedDepth format: {image_format!r}; expected e.g. "
            "'32FC1; compressedDepth png' or '16UC1; compressedDepth rvl'"
        )
    encoding = words[0]
    codec = "rvl" if "rvl" in lowered else "png"
    raw = bytes(data)
    if len(raw) < _CONFIG_HEADER.size:
        raise ValueError(f"compressedDepth data of {len(raw)} bytes has no 12-byte header")
    _, quant_a, quant_b = _CONFIG_HEADER.unpack_from(raw)
    payload = raw[_CONFIG_HEADER.size :]
    if codec == "png":
        image = cv2.imdecode(np.frombuffer(payload, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            raise ValueError(f"{image_format}: the payload is not a one-channel 16-bit PNG")
        values = np.asarray(image, dtype=np.uint16)
    else:
        if len(payload) < 8:
            raise ValueError(f"{image_format}: the payload has no image size")
        cols, rows = struct.unpack_from("<ii", payload)
        if cols < 0 or rows < 0 or cols * rows > 1 << 28:
            raise ValueError(f"{image_format}: implausible image size {cols}x{rows}")
        values = rvl_decode(payload[8:], cols * rows).reshape(rows, cols)
    if encoding == "16UC1":
        return values
    depth = np.full(values.shape, np.nan, dtype=np.float32)
    valid = values != 0
    depth[valid] = np.float32(quant_a) / (values[valid].astype(np.float32) - np.float32(quant_b))
    return depth


def _compressed_image(message: Any) -> npt.NDArray[np.generic]:
    image_format = str(message.format)
    if "compresseddepth" in image_format.lower():
        return decode_compressed_depth(image_format, bytes(np.asarray(message.data, np.uint8)))
    image = cv2.imdecode(np.asarray(message.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"CompressedImage of format {image_format!r} does not decode")
    return np.asarray(image)


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
