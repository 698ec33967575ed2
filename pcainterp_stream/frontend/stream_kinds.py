"""What a camera namespace's image streams hold, told by their names and first images.

Stereo discovery (:mod:`pcainterp_stream.frontend.discovery`) passes over the depth,
disparity, segmentation, normals, confidence and optical-flow streams a simulator or a
depth camera publishes beside its camera images. A name says so when one of its names
(the stream's, or its namespace's last one) has a word that starts with one of
:data:`DEPTH_WORDS` and no word that says a side: ``depth``, ``DepthPlanar``,
``depth_registered``, ``aligned_depth_to_color``, ``disparity_image``, ``Segmentation``,
but not ``depth_left`` or ``stereo_depth_r``, which name a camera of a stereo pair. The
first image of a stream tells the rest: ``32FC1`` and (beside such a name) ``16UC1`` are
depth, ``compressedDepth`` too.

The log probes read the first message of a topic, once (cached).
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.reader_base import LogReader

DEPTH_WORDS = (
    "depth",
    "disparit",
    "segment",
    "semantic",
    "normals",
    "confidence",
    "opticalflow",
    "optical_flow",
)
"""Beginnings of the words of a name that says its stream holds no camera image."""

SIDE_WORDS = frozenset({"left", "right", "l", "r"})
"""Words of a name that say a camera's side: such a name is a camera's, not a stream's."""

DEPTH_ENCODINGS = frozenset({"16UC1", "32FC1"})
"""Encodings of a depth image (millimetres as ``16UC1``, metres as ``32FC1``)."""


def _words(name: str) -> list[str]:
    """Return the words of a name, lower case (``DepthPlanar`` -> ``depth``, ``planar``)."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    return [w for w in re.split(r"[^A-Za-z0-9]+", spaced.lower()) if w]


def depth_name(name: str) -> bool:
    """Return True when one name says depth, disparity, ... and not a side.

    ``depth``, ``DepthPlanar``, ``aligned_depth_to_infra1``, ``disparity_image``,
    ``optical_flow``: True; ``depth_left``, ``stereo_depth_r``, ``image_raw``: False.
    """
    words = _words(name)
    if SIDE_WORDS.intersection(words):
        return False
    joined = "_".join(words)
    return any(w.startswith(DEPTH_WORDS) for w in words) or "optical_flow" in joined


def depth_named(namespace: str, image: str) -> bool:
    """Return True when a stream's name or its namespace's last name says depth (etc.).

    Args:
        namespace: the camera's namespace (``/camera/depth``, ``/robot/depth_left``).
        image: the stream's image below it (``image_rect_raw``, ``DepthPlanar``).
    """
    last = namespace.rstrip("/").split("/")[-1]
    return any(depth_name(name) for name in (last, *image.split("/")))


def first_encoding(reader: LogReader) -> Callable[[str], str | None]:
    """Return image topic -> its first ``Image``'s encoding (None: not known, compressed)."""
    cache: dict[str, str | None] = {}

    def encoding_of(topic: str) -> str | None:
        if topic not in cache:
            cache[topic] = None
            for raw in reader.messages([topic]):
                try:
                    cache[topic] = str(reader.decode(raw).encoding)
                except (PcaInterpError, AttributeError, ValueError):  # not known: no ranking
                    cache[topic] = None
                break
        return cache[topic]

    return encoding_of


def first_format(reader: LogReader) -> Callable[[str], str | None]:
    """Return image topic -> its first ``CompressedImage``'s format (None: not known)."""
    cache: dict[str, str | None] = {}

    def format_of(topic: str) -> str | None:
        if topic not in cache:
            cache[topic] = None
            for raw in reader.messages([topic]):
                try:
                    cache[topic] = str(reader.decode(raw).format)
                except (PcaInterpError, AttributeError, ValueError):
                    cache[topic] = None
                break
        return cache[topic]

    return format_of


def camera_images(reader: LogReader) -> Callable[[str, bool], str | None]:
    """Return (image topic, compressed) -> its first image's kind when a camera's, else None.

    The kind is the encoding (``mono8``) or the compressed format (``jpeg``); None when the
    first image is a depth image (``32FC1``, ``16UC1``, ``compressedDepth``) or not known.
    For streams whose name says depth: only a known camera image brings one back.
    """
    encoding_of, format_of = first_encoding(reader), first_format(reader)

    def kind(topic: str, compressed: bool) -> str | None:
        if compressed:
            fmt = format_of(topic)
            if fmt is None or "compresseddepth" in fmt.lower():
                return None
            return None if any(e in fmt for e in DEPTH_ENCODINGS) else fmt
        encoding = encoding_of(topic)
        if encoding not in rosmsg.CAMERA_IMAGE_ENCODINGS or encoding in DEPTH_ENCODINGS:
            return None
        return encoding

    return kind


def first_tx(reader: LogReader) -> Callable[[str], float | None]:
    """Return camera info topic -> its first message's P[0, 3] (None: not known)."""
    cache: dict[str, float | None] = {}

    def tx_of(topic: str) -> float | None:
        if topic not in cache:
            cache[topic] = None
            for raw in reader.messages([topic]):
                try:
                    cache[topic] = float(rosmsg.projection_matrix(reader.decode(raw))[0, 3])
                except (PcaInterpError, AttributeError, ValueError):  # a damaged info: no side
                    cache[topic] = None
                break
        return cache[topic]

    return tx_of


def first_uncalibrated(reader: LogReader) -> Callable[[str], bool]:
    """Return camera info topic -> its first message has an all-zero K and P."""
    cache: dict[str, bool] = {}

    def uncalibrated(topic: str) -> bool:
        if topic not in cache:
            cache[topic] = False
            for raw in reader.messages([topic]):
                try:
                    info = reader.decode(raw)
                    k = getattr(info, "k", None)
                    k = np.asarray(info.K if k is None else k, dtype=float)
                    cache[topic] = not k.any() and not rosmsg.projection_matrix(info).any()
                except (PcaInterpError, AttributeError, TypeError, ValueError):
                    cache[topic] = False
                break
        return cache[topic]

    return uncalibrated
