"""Turn any decoded ROS message into plain values and numeric arrays, for golden summaries.

:func:`message_content` walks a message generically: strings and numbers become values,
large numeric sequences become arrays, nested messages are flattened into dotted names
(``header.frame_id``, ``p``, ``image.step``). The types whose payload is an encoded array
are decoded first: ``sensor_msgs/Image`` (every REP 118 encoding of
:data:`~pcainterp_stream.io.rosmsg.IMAGE_ENCODINGS`), ``sensor_msgs/CompressedImage`` (png
and jpeg through OpenCV, a Bayer mosaic demosaiced as its Image is, and image_transport's
``compressedDepth`` formats through :func:`decode_compressed_depth`),
``stereo_msgs/DisparityImage`` (its image) and ``sensor_msgs/PointCloud2`` (one array per
point field, (n, count) for a field of ``count`` > 1). An Image of any other
``(8|16|32|64)(U|S|F)C(1-4)`` encoding (``16SC1``, ``64FC1``, ``32FC2``) decodes to its dtype;
a payload that still does not decode (``h264``, an unknown encoding) is recorded by its raw
``data`` bytes (a uint8 array), so a change in it is caught. A sequence of more than
:data:`MAX_VALUE_LENGTH` messages (a ``PoseArray``'s poses, a ``MarkerArray``) is recorded per
field over its items (:func:`_sequence`).

``legacy=True`` records a message as golden files of format 2 did (no generic encodings, a
point field's first element only, a long sequence by its length), so that such a file is
still checked as it was written; a note says what it leaves unguarded.

:func:`decode_compressed_depth` is the one place that knows the ``compressedDepth`` wire
format; the rest of the package only calls it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
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


_GENERIC_ENCODING = re.compile(r"(8|16|32|64)([USF])C([1-4])")
_GENERIC_DTYPES = {
    ("8", "U"): "u1",
    ("8", "S"): "i1",
    ("16", "U"): "u2",
    ("16", "S"): "i2",
    ("16", "F"): "f2",
    ("32", "U"): "u4",
    ("32", "S"): "i4",
    ("32", "F"): "f4",
    ("64", "U"): "u8",
    ("64", "S"): "i8",
    ("64", "F"): "f8",
}
_RAW_NOTE = "; its raw data bytes are recorded instead"


def _image(message: Any) -> npt.NDArray[np.generic]:
    """Decode an Image: :func:`rosmsg.image_array`, or any OpenCV-style encoding."""
    encoding = str(message.encoding)
    match = _GENERIC_ENCODING.fullmatch(encoding)
    if encoding in rosmsg.IMAGE_ENCODINGS or match is None:
        return rosmsg.image_array(message)
    code = _GENERIC_DTYPES.get((match[1], match[2]))
    if code is None:
        raise ValueError(f"unsupported image encoding {encoding!r} (no {match[1]}-bit floats)")
    channels = int(match[3])
    dtype = np.dtype(code).newbyteorder(">" if message.is_bigendian else "<")
    height, width, step = int(message.height), int(message.width), int(message.step)
    if height <= 0 or width <= 0:
        raise ValueError(f"image is empty ({width}x{height} {encoding})")
    row_bytes = width * channels * dtype.itemsize
    raw = np.asarray(message.data, dtype=np.uint8)
    if step < row_bytes or raw.size < height * step:
        raise ValueError(
            f"image data has {raw.size} bytes, expected {height} rows of step {step} "
            f">= {row_bytes} for {width}x{height} {encoding}"
        )
    rows = raw[: height * step].reshape(height, step)[:, :row_bytes]
    image = np.ascontiguousarray(rows).view(dtype).astype(dtype.newbyteorder("="), copy=False)
    return image.reshape((height, width, channels) if channels > 1 else (height, width))


def _cloud(message: Any, content: MessageContent) -> None:
    """Record every point field that decodes as ``points.<name>``; note the others.

    A field of ``count`` > 1 (normals, descriptors, echoes) is an (n, count) array; a field
    of an unknown datatype (0, left unset) or outside the point step is noted and left
    out, the other fields still recorded.

    Raises:
        ValueError: the cloud's layout (row step, data size) does not hold its points.
    """
    cloud = rosmsg.CloudLayout.of(message)
    point_step = cloud.point_step
    for field in message.fields:
        name, code, count = str(field.name), int(field.datatype), max(int(field.count), 1)
        if code not in rosmsg.POINT_FIELD_DTYPES:
            content.notes.append(
                f"point field {name!r} has unknown datatype {code}; it is not recorded "
                "(the other fields are)"
            )
            continue
        dtype = np.dtype(cloud.order + rosmsg.POINT_FIELD_DTYPES[code])
        if int(field.offset) + count * dtype.itemsize > point_step:
            content.notes.append(
                f"point field {name!r} ({count} x {dtype.itemsize} bytes at offset "
                f"{int(field.offset)}) lies outside the point step {point_step}; it is not "
                "recorded (the other fields are)"
            )
            continue
        values = cloud.field(int(field.offset), dtype, count)
        content.arrays[f"points.{name}"] = values[:, 0] if count == 1 else values
    if content.notes:
        content.values["decode_error"] = "; ".join(content.notes)


def _digest(values: list[Any]) -> str:
    """Return a short exact fingerprint of a list of JSON values."""
    text = json.dumps(values, sort_keys=True, default=str)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()[:32]


def _float_rows(values: list[Any]) -> bool:
    """Return True for lists of numbers of one length, some of them floats."""
    if not values or not all(isinstance(v, list) and len(v) == len(values[0]) for v in values):
        return False
    items = [x for v in values for x in v]
    return all(isinstance(x, int | float) and not isinstance(x, bool) for x in items) and any(
        isinstance(x, float) for x in items
    )


def _sequence(items: list[Any] | tuple[Any, ...], name: str, content: MessageContent) -> None:
    """Record a sequence longer than :data:`MAX_VALUE_LENGTH` field by field over its items.

    Its length goes to ``<name>.length``; numbers to one array ``<name>[*].<field>`` per field
    (float64, NaN for an item without the field; compared by statistics, element-wise with
    ``--arrays``); strings, integers and booleans, compared exactly, to one value per field:
    the value itself when every item has the same, else a digest of the column. Arrays
    inside the items are concatenated (``<name>[*].<field>``).
    """
    content.values[f"{name}.length"] = len(items)
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in items) and any(
        isinstance(v, float) for v in items
    ):
        content.arrays[name] = np.asarray(items, dtype=np.float64)
        return
    rows: list[MessageContent] = []
    for item in items:
        row = MessageContent()
        _walk(item, "", row, frozenset())
        rows.append(row)
    value_keys: dict[str, None] = {}
    array_keys: dict[str, None] = {}
    for row in rows:
        value_keys.update(dict.fromkeys(row.values))
        array_keys.update(dict.fromkeys(row.arrays))
    for key in value_keys:
        column = [row.values.get(key) for row in rows]
        label = f"{name}[*].{key}" if key else f"{name}[*]"
        present = [v for v in column if v is not None]
        if (
            present
            and all(isinstance(v, float | int) and not isinstance(v, bool) for v in present)
            and any(isinstance(v, float) for v in present)
        ):
            content.arrays[label] = np.array(
                [np.nan if v is None else float(v) for v in column], dtype=np.float64
            )
        elif _float_rows(present):  # a short float list per item (a covariance)
            width = len(present[0])
            content.arrays[label] = np.array(
                [[np.nan] * width if v is None else v for v in column], dtype=np.float64
            )
        elif all(v == column[0] and type(v) is type(column[0]) for v in column):
            content.values[label] = column[0]
        else:
            content.values[label] = _digest(column)
    for key in array_keys:
        parts = [
            np.asarray(row.arrays[key], np.float64).reshape(-1) for row in rows if key in row.arrays
        ]
        content.arrays[f"{name}[*].{key}"] = np.concatenate(parts)


def _is_message(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def _walk(
    value: Any, name: str, content: MessageContent, skip: frozenset[str], legacy: bool = False
) -> None:
    if name in skip:
        return
    if _is_message(value):
        if hasattr(value, "sec") and hasattr(value, "nanosec"):  # builtin_interfaces/Time
            content.values[name] = int(value.sec) * 1_000_000_000 + int(value.nanosec)
            return
        for field in dataclasses.fields(value):
            child = f"{name}.{field.name}" if name else field.name
            _walk(getattr(value, field.name), child, content, skip, legacy)
    elif isinstance(value, str | bool | int | float | np.generic):
        content.values[name] = value.item() if isinstance(value, np.generic) else value
    elif isinstance(value, np.ndarray):
        if value.size <= MAX_VALUE_LENGTH:
            content.values[name] = [v.item() for v in value.reshape(-1)]
        else:
            content.arrays[name] = value
    elif isinstance(value, list | tuple):
        if len(value) > MAX_VALUE_LENGTH and legacy:
            content.values[f"{name}.length"] = len(value)
            content.notes.append(
                f"{name}: a golden file of format 2 records these {len(value)} items by their "
                "count only"
            )
        elif len(value) > MAX_VALUE_LENGTH:
            _sequence(value, name, content)
        elif all(isinstance(v, int | float | bool | str) for v in value):
            content.values[name] = list(value)
        else:
            for i, item in enumerate(value):
                _walk(item, f"{name}[{i}]", content, skip, legacy)


def message_content(msgtype: str, message: Any, *, legacy: bool = False) -> MessageContent:
    """Return the values and arrays of a decoded message (any type).

    Args:
        msgtype: the type in ROS 2 spelling (``sensor_msgs/msg/Image``).
        message: a rosbags typestore message of that type.
        legacy: record it as a golden file of format 2 did (to check such a file).

    Returns:
        The flattened values and arrays. Images decode to ``image`` (and a
        DisparityImage's to ``image.image``), point clouds to ``points.<field>``; their raw
        ``data`` bytes are not kept. A payload that does not decode leaves a note, its
        byte count (``data.length``) and its raw bytes as the uint8 array ``data``
        (``image.data`` of a DisparityImage) instead; a point field that does not decode
        leaves a note and the other fields.
    """
    content = MessageContent()
    skip = {
        rosmsg.IMAGE: frozenset({"data"}),
        rosmsg.COMPRESSED_IMAGE: frozenset({"data"}),
        rosmsg.DISPARITY_IMAGE: frozenset({"image.data"}),
        rosmsg.POINT_CLOUD2: frozenset({"data"}),
    }.get(msgtype, frozenset())
    decode = rosmsg.image_array if legacy else _image
    try:
        if msgtype == rosmsg.IMAGE:
            content.arrays["image"] = decode(message)
        elif msgtype == rosmsg.COMPRESSED_IMAGE:
            content.arrays["image"] = _compressed_image(message)
        elif msgtype == rosmsg.DISPARITY_IMAGE:
            content.arrays["image.image"] = decode(message.image)
        elif msgtype == rosmsg.POINT_CLOUD2 and legacy:
            for field_name, values in rosmsg.pointcloud2_arrays(message).items():
                content.arrays[f"points.{field_name}"] = values
            content.notes += [
                f"point field {field.name!r} has count {field.count}: a golden file of format "
                "2 records its first element only"
                for field in message.fields
                if int(field.count) > 1
            ]
        elif msgtype == rosmsg.POINT_CLOUD2:
            _cloud(message, content)
    except ValueError as err:
        content.notes.append(str(err) if legacy else f"{err}{_RAW_NOTE}")
        content.values["decode_error"] = str(err)
        content.arrays.clear()
        if not legacy:
            data = message.image.data if msgtype == rosmsg.DISPARITY_IMAGE else message.data
            name = "image.data" if msgtype == rosmsg.DISPARITY_IMAGE else "data"
            content.arrays[name] = np.asarray(data, dtype=np.uint8).reshape(-1)
    _walk(message, "", content, skip, legacy)
    if skip and "decode_error" in content.values:  # keep the size of a payload not decoded
        data = message.image.data if msgtype == rosmsg.DISPARITY_IMAGE else message.data
        content.values["data.length"] = len(data)
    return content
