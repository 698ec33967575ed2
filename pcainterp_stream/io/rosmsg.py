"""ROS 2 message construction and array conversion, shared by every log reader and writer.

Messages are rosbags typestore objects (``sensor_msgs/msg/Image`` and friends) of the ROS 2
Humble store; ROS 1 bags use the same types (rosbags converts the wire format). This module
knows message layouts only: nothing here opens a file.
"""

from __future__ import annotations

from functools import cache
from typing import Any, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt
from rosbags.typesys import Stores, get_typestore

from pcainterp_stream.records import StereoCamera

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
DISPARITY_IMAGE = "stereo_msgs/msg/DisparityImage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"

_T = TYPESTORE.types

# encoding -> (numpy dtype, channels)
IMAGE_ENCODINGS: dict[str, tuple[str, int]] = {
    "mono8": ("u1", 1),
    "8UC1": ("u1", 1),
    "rgb8": ("u1", 3),
    "bgr8": ("u1", 3),
    "8UC3": ("u1", 3),
    "bgra8": ("u1", 4),
    "rgba8": ("u1", 4),
    "8UC4": ("u1", 4),  # cv_bridge's BGRA
    "bayer_rggb8": ("u1", 1),
    "bayer_bggr8": ("u1", 1),
    "bayer_gbrg8": ("u1", 1),
    "bayer_grbg8": ("u1", 1),
    "yuv422": ("u1", 2),
    "yuv422_yuy2": ("u1", 2),
    "uyvy": ("u1", 2),  # sensor_msgs' current name of yuv422 (the same bytes)
    "yuyv": ("u1", 2),  # ... and of yuv422_yuy2
    "mono16": ("u2", 1),
    "16UC1": ("u2", 1),
    "rgb16": ("u2", 3),  # 12-bit colour of FLIR Spinnaker, Basler pylon drivers
    "bgr16": ("u2", 3),
    "rgba16": ("u2", 4),
    "bgra16": ("u2", 4),
    "bayer_rggb16": ("u2", 1),  # their 12-bit Bayer formats
    "bayer_bggr16": ("u2", 1),
    "bayer_gbrg16": ("u2", 1),
    "bayer_grbg16": ("u2", 1),
    "32FC1": ("f4", 1),
}

TO_RGB: dict[str, int] = {
    "bgr8": cv2.COLOR_BGR2RGB,
    "8UC3": cv2.COLOR_BGR2RGB,  # cv_bridge's order for three 8-bit channels
    "bgra8": cv2.COLOR_BGRA2RGB,  # the ZED wrappers' image_rect_color
    "8UC4": cv2.COLOR_BGRA2RGB,  # cv_bridge's order for four 8-bit channels
    "rgba8": cv2.COLOR_RGBA2RGB,
    # ROS names the first 2x2 cell, OpenCV the second row's: as cv_bridge maps them
    "bayer_rggb8": cv2.COLOR_BayerBG2RGB,
    "bayer_bggr8": cv2.COLOR_BayerRG2RGB,
    "bayer_gbrg8": cv2.COLOR_BayerGR2RGB,
    "bayer_grbg8": cv2.COLOR_BayerGB2RGB,
    "yuv422": cv2.COLOR_YUV2RGB_UYVY,  # usb_cam, UVC stereo cameras
    "yuv422_yuy2": cv2.COLOR_YUV2RGB_YUY2,
    "uyvy": cv2.COLOR_YUV2RGB_UYVY,
    "yuyv": cv2.COLOR_YUV2RGB_YUY2,
    # 16 bits per channel: the same conversions (OpenCV's take uint16), the result uint16
    "bgr16": cv2.COLOR_BGR2RGB,
    "bgra16": cv2.COLOR_BGRA2RGB,
    "rgba16": cv2.COLOR_RGBA2RGB,
    "bayer_rggb16": cv2.COLOR_BayerBG2RGB,
    "bayer_bggr16": cv2.COLOR_BayerRG2RGB,
    "bayer_gbrg16": cv2.COLOR_BayerGR2RGB,
    "bayer_grbg16": cv2.COLOR_BayerGB2RGB,
}
"""Encodings :func:`image_array` converts to RGB (demosaicing Bayer images, as image_proc)."""

YUV422_ENCODINGS = frozenset({"yuv422", "yuv422_yuy2", "uyvy", "yuyv"})
"""The packed YUV 4:2:2 encodings (two pixels share a U and a V: the width must be even)."""

CAMERA_IMAGE_ENCODINGS: tuple[str, ...] = tuple(
    name for name, (dtype, _) in IMAGE_ENCODINGS.items() if dtype != "f4"
)
"""The encodings of :data:`IMAGE_ENCODINGS` a camera (stereo) image may have: 8- and 16-bit
grey or RGB. ``32FC1`` is a depth or disparity image, which the stereo front end does not match."""

# PointField datatype code -> numpy dtype
POINT_FIELD_DTYPES: dict[int, str] = {
    1: "i1",
    2: "u1",
    3: "i2",
    4: "u2",
    5: "i4",
    6: "u4",
    7: "f4",
    8: "f8",
}


@cache
def schema_text(typename: str) -> str:
    """Return the ``ros2msg`` schema text of a message type (with its dependencies)."""
    return str(TYPESTORE.generate_msgdef(typename, ros_version=2)[0])


def serialize(message: Any) -> bytes:
    """Serialize a typestore message to CDR bytes (little endian)."""
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))


def deserialize(data: bytes | memoryview, typename: str) -> Any:
    """Deserialize CDR bytes into a typestore message of ``typename``."""
    return TYPESTORE.deserialize_cdr(data, typename)


def header(stamp_ns: int, frame_id: str) -> Any:
    """Return a ``std_msgs/msg/Header`` for a stamp in ns."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _T["std_msgs/msg/Header"](
        stamp=_T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def stamp_ns(message: Any) -> int:
    """Return the header stamp of a message in ns (ROS 1 and ROS 2 field names)."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def image_message(
    array: npt.NDArray[np.generic], stamp_ns: int, frame_id: str, *, encoding: str | None = None
) -> Any:
    """Build a ``sensor_msgs/msg/Image`` from an array.

    Args:
        array: (H, W) uint8 / uint16 / float32 or (H, W, 3) uint8 image.
        stamp_ns: header stamp (ns).
        frame_id: header frame id.
        encoding: ROS encoding; inferred when None (mono8, rgb8, mono16, 32FC1).

    Returns:
        The message, little endian, rows packed (step = W * bytes per pixel).
    """
    if encoding is None:
        kind = (array.dtype.str[1:], 1 if array.ndim == 2 else array.shape[2])
        encoding = {
            ("u1", 1): "mono8",
            ("u1", 3): "rgb8",
            ("u2", 1): "mono16",
            ("f4", 1): "32FC1",
        }.get(kind, "")
        if not encoding:
            raise ValueError(
                f"cannot infer an image encoding for dtype {array.dtype} and shape {array.shape}"
            )
    dtype, channels = IMAGE_ENCODINGS[encoding]
    data = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    height, width = data.shape[:2]
    return _T[IMAGE](
        header=header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels * data.dtype.itemsize,
        data=data.reshape(-1).view(np.uint8),
    )


def image_array(message: Any) -> npt.NDArray[np.generic]:
    """Decode a ``sensor_msgs/Image`` into an array, honouring step and endianness.

    Returns:
        (H, W) or (H, W, 3) array of the encoding's dtype (uint16 for the 16-bit colour
        and Bayer encodings); the encodings of :data:`TO_RGB` (BGR, with alpha, Bayer, YUV
        4:2:2) are returned as RGB.

    Raises:
        ValueError: for an encoding outside :data:`IMAGE_ENCODINGS`, an empty image (a
            height or width of 0, what a driver's failed grab publishes) or a data size that
            does not match height * step.
    """
    encoding = str(message.encoding)
    if encoding not in IMAGE_ENCODINGS:
        raise ValueError(
            f"unsupported image encoding {encoding!r}; supported: {', '.join(IMAGE_ENCODINGS)}"
        )
    dtype_code, channels = IMAGE_ENCODINGS[encoding]
    dtype = np.dtype(dtype_code).newbyteorder(">" if message.is_bigendian else "<")
    height, width, step = int(message.height), int(message.width), int(message.step)
    if height <= 0 or width <= 0:
        raise ValueError(f"image is empty ({width}x{height} {encoding})")
    row_bytes = width * channels * dtype.itemsize
    raw = np.asarray(message.data, dtype=np.uint8)
    if step < row_bytes:  # the step field is wrong, not the encoding
        raise ValueError(
            f"image step {step} is shorter than a row of {width} px {encoding} ({row_bytes} "
            f"bytes; data {raw.size} bytes for {height} rows): the publisher's step field is "
            "wrong (step = width * bytes per pixel)"
        )
    if raw.size < height * step:
        raise ValueError(
            f"image data has {raw.size} bytes, expected {height} rows of step {step} "
            f">= {row_bytes} for {width}x{height} {encoding}"
        )
    rows = raw[: height * step].reshape(height, step)[:, :row_bytes]
    image = np.ascontiguousarray(rows).view(dtype).astype(dtype.newbyteorder("="), copy=False)
    image = image.reshape((height, width, channels) if channels > 1 else (height, width))
    if encoding in TO_RGB:
        if encoding in YUV422_ENCODINGS and width % 2:
            raise ValueError(f"a {encoding} image needs an even width, got {width}")
        image = cv2.cvtColor(np.ascontiguousarray(image), TO_RGB[encoding])
    return image


def compressed_format_encoding(image_format: str) -> tuple[str, str]:
    """Return the (encoding, stored colour order) a ``CompressedImage`` format names.

    compressed_image_transport writes ``"ENCODING; CODEC compressed ORDER"``: the encoding
    of the image it compressed, and for a colour image the channel order of the encoded
    bytes (``bgr8``; ``rgb8`` in some encoders). ``"bayer_rggb8; png compressed "`` ->
    ``("bayer_rggb8", "")``; ``"rgb8; jpeg compressed bgr8"`` -> ``("rgb8", "bgr8")``; a
    bare ``"jpeg"`` -> ``("", "")``.
    """
    if ";" not in image_format:
        return "", ""
    encoding, rest = image_format.split(";", 1)
    words = rest.split()
    order = words[words.index("compressed") + 1] if "compressed" in words[:-1] else ""
    return encoding.strip(), order


def demosaic_compressed(
    image: npt.NDArray[np.generic], image_format: str
) -> npt.NDArray[np.generic]:
    """Demosaic a decoded ``CompressedImage`` whose format names a Bayer encoding.

    compressed_image_transport compresses a Bayer image as its one-channel mosaic (no
    colour conversion) and restores the encoding from the format's prefix, so that
    image_proc demosaics it; this does the same, as :func:`image_array` does for the raw
    ``Image`` (``bayer_*8`` from an 8-bit, ``bayer_*16`` from a 16-bit PNG). Any other image
    is returned unchanged.

    Raises:
        ValueError: a Bayer encoding this package does not know, or a mosaic whose bit depth
            is not the encoding's.
    """
    encoding, _ = compressed_format_encoding(image_format)
    if not encoding.startswith("bayer_") or image.ndim != 2:
        return image
    if encoding not in TO_RGB:
        supported = ", ".join(name for name in TO_RGB if name.startswith("bayer_"))
        raise ValueError(
            f"unsupported image encoding {encoding!r} ({image.dtype} mosaic); Bayer images "
            f"are {supported}"
        )
    expected = np.dtype(IMAGE_ENCODINGS[encoding][0])
    if image.dtype != expected:
        raise ValueError(
            f"a {encoding} mosaic must decode to {expected}, got {image.dtype} "
            f"(format {image_format!r})"
        )
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(image), TO_RGB[encoding]))


def compressed_image_message(data: bytes, image_format: str, stamp_ns: int, frame_id: str) -> Any:
    """Build a ``sensor_msgs/msg/CompressedImage`` (``image_format``: "png" or "jpeg")."""
    return _T[COMPRESSED_IMAGE](
        header=header(stamp_ns, frame_id),
        format=image_format,
        data=np.frombuffer(data, dtype=np.uint8),
    )


def camera_info_message(
    camera: StereoCamera, stamp_ns: int, frame_id: str, *, right: bool = False
) -> Any:
    """Build the ``sensor_msgs/msg/CameraInfo`` of the left (or right) rectified camera."""
    p = camera.projection_right() if right else camera.projection_left()
    k = p[:, :3].copy()
    return _T[CAMERA_INFO](
        header=header(stamp_ns, frame_id),
        height=camera.height,
        width=camera.width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=k.reshape(-1),
        r=np.eye(3).reshape(-1),
        p=p.reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=_T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def projection_matrix(message: Any) -> npt.NDArray[np.float64]:
    """Return the 3x4 P of a CameraInfo (ROS 2 field ``p`` or ROS 1 field ``P``)."""
    p = getattr(message, "p", None)
    if p is None:
        p = message.P
    return np.asarray(p, dtype=np.float64).reshape(3, 4)


def imaged_size(message: Any) -> tuple[int, int] | None:
    """Return the (width, height) of the images a CameraInfo describes, None when it says none.

    ``width`` x ``height`` is the size the camera was calibrated at; a region of interest
    (``roi`` with a width and height) crops it and binning divides it, as ``image_proc``
    reads them. A CameraInfo with a zero width or height (some drivers) says nothing.
    """
    width, height = int(getattr(message, "width", 0)), int(getattr(message, "height", 0))
    if width <= 0 or height <= 0:
        return None
    roi = getattr(message, "roi", None)
    if roi is not None and int(roi.width) > 0 and int(roi.height) > 0:
        width, height = int(roi.width), int(roi.height)
    binning = int(getattr(message, "binning_x", 0)), int(getattr(message, "binning_y", 0))
    return width // max(binning[0], 1), height // max(binning[1], 1)


def pointcloud2_message(
    fields: dict[str, npt.NDArray[np.float32]], stamp_ns: int, frame_id: str
) -> Any:
    """Build an unorganised ``sensor_msgs/msg/PointCloud2`` of float32 fields.

    Args:
        fields: name -> (n,) float32 values, all of the same length, in the order given.
        stamp_ns: header stamp (ns).
        frame_id: header frame id.

    Returns:
        The message, little endian; ``is_dense`` only when every value is finite (readers
        such as PCL skip their NaN checks on a dense cloud).
    """
    names = list(fields)
    n = len(next(iter(fields.values()))) if fields else 0
    record = np.zeros(n, dtype=[(name, "<f4") for name in names])
    for name in names:
        record[name] = fields[name]
    point_field = _T["sensor_msgs/msg/PointField"]
    return _T[POINT_CLOUD2](
        header=header(stamp_ns, frame_id),
        height=1,
        width=n,
        fields=[
            point_field(name=name, offset=4 * i, datatype=7, count=1)
            for i, name in enumerate(names)
        ],
        is_bigendian=False,
        point_step=4 * len(names),
        row_step=4 * len(names) * n,
        data=record.view(np.uint8).reshape(-1),
        is_dense=all(bool(np.isfinite(values).all()) for values in fields.values()),
    )


def pointcloud2_arrays(
    message: Any, names: tuple[str, ...] | None = None
) -> dict[str, npt.NDArray[np.float64]]:
    """Decode the scalar fields of a ``PointCloud2`` into float64 arrays of length n.

    An organized cloud (``height`` > 1) is read row by row at ``row_step`` bytes, which may
    exceed ``width * point_step`` (rows padded, as PointCloud2 allows).

    Args:
        message: the cloud.
        names: the fields to decode (those of them the cloud has); None: every field. Other
            fields are not looked at: one of a type code outside 1..8 (0, left unset by a
            publisher that fills only the fields it uses) does not make the cloud unreadable.

    Raises:
        ValueError: for a decoded field's type code outside 1..8, a ``row_step`` shorter
            than a row's points or data shorter than the points need.
    """
    cloud = CloudLayout.of(message)
    out: dict[str, npt.NDArray[np.float64]] = {}
    for field in message.fields:
        if names is not None and str(field.name) not in names:
            continue
        code = int(field.datatype)
        if code not in POINT_FIELD_DTYPES:
            raise ValueError(f"point field {field.name!r} has unknown datatype {code}")
        dtype = np.dtype(cloud.order + POINT_FIELD_DTYPES[code])
        if int(field.offset) + dtype.itemsize > cloud.point_step:
            raise ValueError(
                f"point field {field.name!r} lies outside the point step {cloud.point_step}"
            )
        out[str(field.name)] = cloud.field(int(field.offset), dtype, 1)[:, 0]
    return out


class CloudLayout(NamedTuple):
    """Where a ``PointCloud2``'s points lie in its data (rows may be padded)."""

    height: int
    width: int
    point_step: int
    row_step: int
    order: str
    """``>`` or ``<``: the byte order of its fields."""
    buffer: bytes
    """The data its points need, rows padded as in the message."""

    @classmethod
    def of(cls, message: Any) -> CloudLayout:
        """Return the layout of ``message``.

        Raises:
            ValueError: a ``row_step`` shorter than a row's points or data shorter than the
                points need.
        """
        height, width = int(message.height), int(message.width)
        point_step = int(message.point_step)
        row_step = int(message.row_step) if height > 1 else width * point_step
        if height > 1 and row_step < width * point_step:
            raise ValueError(
                f"point cloud row_step {row_step} is shorter than its {width} points of "
                f"{point_step} bytes ({width * point_step})"
            )
        raw = np.asarray(message.data, dtype=np.uint8)
        n = height * width
        need = (height - 1) * row_step + width * point_step if n else 0
        if raw.size < need:
            raise ValueError(f"point cloud data has {raw.size} bytes, {n} points need {need}")
        order = ">" if message.is_bigendian else "<"
        return cls(height, width, point_step, row_step, order, raw[:need].tobytes())

    def field(self, offset: int, dtype: np.dtype[Any], count: int) -> npt.NDArray[np.float64]:
        """Return the (n, count) values of the field at ``offset`` as float64."""
        n = self.height * self.width
        if not n:
            return np.zeros((0, count), np.float64)
        view: npt.NDArray[Any] = np.ndarray(
            shape=(self.height, self.width, count),
            dtype=dtype,
            buffer=self.buffer,
            offset=offset,
            strides=(self.row_step, self.point_step, dtype.itemsize),
        )
        return view.reshape(n, count).astype(np.float64)


def disparity_image_message(
    disparity: npt.NDArray[np.float32],
    stamp_ns: int,
    frame_id: str,
    *,
    focal: float,
    baseline: float,
    min_disparity: float,
    max_disparity: float,
) -> Any:
    """Build a ``stereo_msgs/msg/DisparityImage`` (32FC1 px, f in px, t = baseline in m)."""
    height, width = disparity.shape
    return _T[DISPARITY_IMAGE](
        header=header(stamp_ns, frame_id),
        image=image_message(disparity.astype(np.float32, copy=False), stamp_ns, frame_id),
        f=float(focal),
        t=float(baseline),
        valid_window=_T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=height, width=width, do_rectify=False
        ),
        min_disparity=float(min_disparity),
        max_disparity=float(max_disparity),
        delta_d=0.0,
    )


def pose_stamped_message(
    camera_to_world: npt.NDArray[np.float64], stamp_ns: int, frame_id: str
) -> Any:
    """Build a ``geometry_msgs/msg/PoseStamped`` from a 4x4 (or 3x4) camera-to-world matrix."""
    from scipy.spatial.transform import Rotation  # imported when used: ~0.3 s of start-up

    rotation = np.asarray(camera_to_world, dtype=np.float64)[:3, :3]
    translation = np.asarray(camera_to_world, dtype=np.float64)[:3, 3]
    qx, qy, qz, qw = Rotation.from_matrix(rotation).as_quat()
    return _T[POSE_STAMPED](
        header=header(stamp_ns, frame_id),
        pose=_T["geometry_msgs/msg/Pose"](
            position=_T["geometry_msgs/msg/Point"](
                x=float(translation[0]), y=float(translation[1]), z=float(translation[2])
            ),
            orientation=_T["geometry_msgs/msg/Quaternion"](
                x=float(qx), y=float(qy), z=float(qz), w=float(qw)
            ),
        ),
    )


def pose_matrix(message: Any) -> npt.NDArray[np.float64]:
    """Return the 4x4 matrix of a ``PoseStamped`` (or ``Pose``) message."""
    from scipy.spatial.transform import Rotation

    pose = getattr(message, "pose", message)
    q = pose.orientation
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    matrix[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return matrix
