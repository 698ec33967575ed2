"""The forms of a stereo pair's images and topics, as :mod:`frontend.pairing` reads them.

A rig of two cameras of one model gives two images of one encoding; a rig of a colour and a
mono camera (``bgr8`` + ``mono8``), or of an 8-bit and a 16-bit one (``mono8`` + ``mono16``),
gives two encodings of one size. The stereo matcher takes 8-bit grey anyway
(:func:`frontend.stereo.to_grey8_pair`), so :func:`grey_alike` turns such a pair into grey of
one bit depth, each side on its own. :func:`is_rectified_name` reads a topic name;
:func:`is_copy` tells an image logged again (a merged bag's copy) from a frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.stereo import to_grey8
from pcainterp_stream.frontend.stream_kinds import name_words

if TYPE_CHECKING:
    from pcainterp_stream.frontend.pairing_window import PendingImage

__all__ = [
    "SIDE_BY_SIDE_MATCH",
    "describe",
    "grey_alike",
    "halves_match",
    "is_copy",
    "is_rectified_name",
]

SIDE_BY_SIDE_MATCH = 0.6
"""A :func:`halves_match` at or above this says an image holds two views side by side: a
side-by-side stereo frame scores 0.86-0.94 (KITTI pairs put side by side, either order), a
single wide camera image 0.21 at most (KITTI raw and odometry, a street drive)."""


def grey_alike(
    left: npt.NDArray[Any], right: npt.NDArray[Any]
) -> tuple[npt.NDArray[Any], npt.NDArray[Any], str]:
    """Return a pair of images of one size in one form, and what was done ('' for nothing).

    A pair of one shape and dtype is returned as it is (a mono16 pair keeps its 16 bits: the
    matcher scales both sides by one factor). A pair of one size in two encodings is turned
    into grey, each side on its own: colour (RGB) with ``cv2.COLOR_RGB2GRAY``, and when one
    side has 8 bits and the other 16, the 16-bit side is scaled to 8 bits as
    :func:`frontend.stereo.to_grey8` scales one image (its 99.9th percentile to 255); the
    8-bit side keeps its grey levels (a dark one too: the matcher's
    :func:`frontend.stereo.to_grey8_pair` then maps the right side's levels onto the left's
    and stretches the pair with one mapping for both views). Two 16-bit sides (``rgb16`` +
    ``mono16``) stay 16-bit, so they still share one scale. Images of two sizes, or of a
    layout not described here, are returned as they are (the caller refuses them).
    """
    if (left.shape == right.shape and left.dtype == right.dtype) or (
        left.shape[:2] != right.shape[:2]
    ):
        return left, right, ""
    grey_left, grey_right = _grey(left), _grey(right)
    if grey_left is None or grey_right is None:
        return left, right, ""
    if grey_left.dtype == grey_right.dtype:
        return grey_left, grey_right, "both converted to grey"
    said = "both converted to 8-bit grey, the 16-bit side scaled on its own"
    return _eight(grey_left), _eight(grey_right), said


def _eight(grey: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """An 8-bit grey image as it is; a 16-bit one scaled as :func:`.grey.to_grey8` does.

    Not the 8-bit side through ``to_grey8`` too: that would stretch a dark one on its own;
    the pair-level steps (:mod:`.levels`) act on the pair in :func:`.grey.to_grey8_pair`.
    """
    return grey if grey.dtype == np.uint8 else to_grey8(grey)


def halves_match(image: npt.NDArray[Any]) -> float:
    """Return how alike the left and right halves of an image are (-1 to 1; -1: not judged).

    The best normalised cross-correlation of the halves (160 px wide, each row's mean
    removed, so sky above and road below do not count) over horizontal shifts of up to a
    quarter of a half: high for the two views of a side-by-side stereo frame (a ZED or a UVC
    stereo camera without its SDK), low for one camera's wide image. Images less than twice
    as wide as tall, or without texture, are not judged.
    """
    grey = _grey(image)
    height, width = image.shape[:2]
    if grey is None or width < 2 * height or height < 8:
        return -1.0
    half = width // 2
    scale = min(1.0, 160 / half)
    views = []
    for view in (grey[:, :half], grey[:, half : 2 * half]):
        small = cv2.resize(
            view.astype(np.float32), None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA
        )
        views.append(small - small.mean(axis=1, keepdims=True))
    left, right = views
    best = -1.0
    for shift in range(left.shape[1] // 4):
        a, b = left[:, shift:], right[:, : right.shape[1] - shift]
        norm = float(np.sqrt(float((a * a).sum()) * float((b * b).sum())))
        if norm > 0:
            best = max(best, float((a * b).sum()) / norm)
    return best


def _grey(image: npt.NDArray[Any]) -> npt.NDArray[Any] | None:
    """Return an image as (H, W) grey of its own depth, None for a layout not known here."""
    if image.dtype not in (np.uint8, np.uint16):
        return None
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 1:
        return np.ascontiguousarray(image[:, :, 0])
    if image.ndim == 3 and image.shape[2] == 3:
        return np.asarray(cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY))
    return None


def describe(image: Any) -> str:
    """Return an image's size, channels and dtype as messages name them (``620x186x3 uint8``)."""
    shape = image.shape
    size = f"{shape[1]}x{shape[0]}"
    return f"{size}x{shape[2]} {image.dtype}" if len(shape) == 3 else f"{size} {image.dtype}"


def is_rectified_name(topic: str, partner: str | None = None) -> bool:
    """Return True for an image topic named as rectified (``image_rect``, ``image_rect_color``).

    The stream's name says it (``image_rect``), or a name below the one that says the side
    does (``/zed/zed_node/left/gray/rect/image``, as the ZED wrapper 5.x names its streams):
    that side name is where ``topic`` and ``partner`` (the other side's topic) first differ,
    else the last name with ``left``/``right`` as a word of its own; names above it
    (``/rectifier/left/image_raw``) say nothing.
    """
    transports = ("compressed", "compressedDepth")
    names = [p for p in topic.split("/") if p and p not in transports]
    if not names:
        return False
    if _says_rect(names[-1]):  # not "image_corrected" (bug hunt 15A F3), "directional"
        return True
    parts = [p.lower() for p in names]
    if partner is not None:
        others = [p.lower() for p in partner.split("/") if p and p not in transports]
        sides = [i for i, (a, b) in enumerate(zip(parts, others, strict=False)) if a != b][:1]
    else:  # "left", "camera_left", "left_raw", not "bright"
        starts = [(i, p.find(word)) for i, p in enumerate(parts) for word in ("left", "right")]
        sides = [i for i, k in starts if k == 0 or (k > 0 and not parts[i][k - 1].isalpha())]
    if not sides:
        return False
    return any(_says_rect(p) for p in names[sides[-1] + 1 :])


def _says_rect(name: str) -> bool:
    """Whether a name of a topic has a word starting with ``rect``.

    Words as :func:`frontend.stream_kinds.name_words` splits them (at any character that is
    no letter or digit, and a lower-to-upper case change): ``rect``, ``image_rect_color``,
    ``image_rect_raw``, ``rectified``, ``imageRect``, ``image.rect`` do; ``image_corrected``,
    ``direct``, ``color_corrected`` do not.
    """
    return any(word.startswith("rect") for word in name_words(name))


def is_copy(new: PendingImage, last: PendingImage | None) -> bool:
    """Whether an image is its side's last one logged again: a merged bag's copy, a re-send.

    The same header stamp, size, encoding and bytes (:func:`same_image_message`). Without a
    stamp (0: a driver that sets none) the same log time too: two overlapping bags merged
    give the copy its original's log time, while a static scene renders identical frames at
    other log times, and those are frames.
    """
    if last is None or new.stamp_ns != last.stamp_ns:
        return False
    if not new.stamp_ns and new.log_time_ns != last.log_time_ns:
        return False
    return same_image_message(new.message, last.message)


def same_image_message(new: Any, old: Any) -> bool:
    """Whether two image messages are one image: size, step, encoding or format, and bytes.

    The duplicate rule of densify's pairer and evaluate (a re-sent message, a merged bag):
    the callers compare the header stamps first.
    """
    if new is old:
        return True
    for name in ("height", "width", "step", "encoding", "format"):
        if getattr(new, name, None) != getattr(old, name, None):
            return False
    return bool(np.array_equal(np.asarray(new.data), np.asarray(old.data)))
