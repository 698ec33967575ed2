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
from typing import Any, TypeVar

import numpy as np

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.camera_model import vertical_ty
from pcainterp_stream.io.reader_base import LogReader

_T = TypeVar("_T")

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


def name_words(name: str) -> list[str]:
    """Return the words of a name, lower case (``DepthPlanar`` -> ``depth``, ``planar``)."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    return [w for w in re.split(r"[^A-Za-z0-9]+", spaced.lower()) if w]


def depth_name(name: str) -> bool:
    """Return True when one name says depth, disparity, ... and not a side.

    ``depth``, ``DepthPlanar``, ``aligned_depth_to_infra1``, ``disparity_image``,
    ``optical_flow``: True; ``depth_left``, ``stereo_depth_r``, ``image_raw``: False.
    """
    words = name_words(name)
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


def _first(reader: LogReader, read: Callable[[Any], _T], unknown: _T) -> Callable[[str], _T]:
    """Return topic -> ``read`` of its first message, read once per topic.

    ``unknown`` for a topic with no message, or one that does not decode or lacks the field.
    """
    cache: dict[str, _T] = {}

    def first(topic: str) -> _T:
        if topic not in cache:
            cache[topic] = unknown
            for raw in reader.messages([topic]):
                try:
                    cache[topic] = read(reader.decode(raw))
                except (PcaInterpError, AttributeError, TypeError, ValueError):
                    cache[topic] = unknown
                break
        return cache[topic]

    return first


def first_encoding(reader: LogReader) -> Callable[[str], str | None]:
    """Return image topic -> its first ``Image``'s encoding (None: not known, compressed)."""
    return _first(reader, lambda image: str(image.encoding), None)


def first_format(reader: LogReader) -> Callable[[str], str | None]:
    """Return image topic -> its first ``CompressedImage``'s format (None: not known)."""
    return _first(reader, lambda image: str(image.format), None)


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
    """Return camera info topic -> its first message's P[0, 3] (None: not known).

    P[1, 3] when P[0, 3] is 0 and it is a rig's Ty (:func:`io.camera_model.vertical_ty`, f*b
    >= 1 px*m): a vertical pair's second camera has its translation there, and is no monocular
    camera (the pairer refuses the pair as stacked vertically); a smaller Ty is noise.
    """

    def tx(info: Any) -> float:
        p = rosmsg.projection_matrix(info)
        return float(p[0, 3] or vertical_ty(p))

    return _first(reader, tx, None)


def first_uncalibrated(reader: LogReader) -> Callable[[str], bool]:
    """Return camera info topic -> its first message has an all-zero K and P."""

    def uncalibrated(info: Any) -> bool:
        k = getattr(info, "k", None)
        k = np.asarray(info.K if k is None else k, dtype=float)
        return not k.any() and not rosmsg.projection_matrix(info).any()

    return _first(reader, uncalibrated, False)
