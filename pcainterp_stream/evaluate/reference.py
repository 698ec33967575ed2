"""A ground-truth reference topic of the user's log (``pcainterp evaluate --reference-topic``).

Any depth or disparity image topic can be the reference, dense or sparse (projected LiDAR,
KITTI's annotated depth):

=====================================  ==========  ==========================================
message type and encoding              kind        values
=====================================  ==========  ==========================================
sensor_msgs/msg/Image 32FC1            depth       metres; NaN, 0, < 0: no truth; +inf: far
sensor_msgs/msg/Image 16UC1 / mono16   depth       millimetres (REP 118); 0: no truth
CompressedImage, compressedDepth       depth       as its encoding (32FC1 m or 16UC1 mm)
sensor_msgs/msg/Image 32FC1            disparity   px (``--reference-kind disparity``)
stereo_msgs/msg/DisparityImage         disparity   px, rescaled by the log's f*b / its f*t;
                                                   value + (cx_l - cx_r) < min_disparity,
                                                   > max_disparity (when above min) or
                                                   outside valid_window: no truth
=====================================  ==========  ==========================================

A DisparityImage's bounds are the matcher's: stereo_image_proc shifts its values by
-(cx_l - cx_r) (the two rectified P's cx) and writes min_disparity and max_disparity
unshifted, so its invalid code is min_disparity - 1 - (cx_l - cx_r). The bounds are applied
to value + (cx_l - cx_r) with cx of the input pair's camera infos in the log, the ones
densify read (:meth:`~pcainterp_stream.frontend.images.PairImages.cx_offset`); the message
itself carries no cx. Without those infos (a pair read with calibration files, or none) the
bounds are applied as they are, and a note says so.

This module checks the topic against the log and turns one message into a disparity map of
the densified log's camera, NaN where the reference holds no truth
(:func:`~pcainterp_stream.evaluate.metrics.disparity_from_reference`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError, TopicNotFoundError
from pcainterp_stream.evaluate.metrics import ReferenceKind, disparity_from_reference
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.depth_image import DEPTH_ENCODINGS, depth_metres, first_message
from pcainterp_stream.io.logreader import LogReader
from pcainterp_stream.io.reader_base import TopicInfo, closest_topic

IMAGE_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE, rosmsg.DISPARITY_IMAGE)
"""Message types a reference topic may have."""

SPARSE_BELOW = 0.5
"""A reference with truth at fewer than this share of the pixels is called sparse."""


@dataclass(frozen=True)
class ReferenceTopic:
    """A reference topic checked against a log.

    Attributes:
        topic: the topic name.
        msgtype: ``sensor_msgs/msg/Image`` or ``stereo_msgs/msg/DisparityImage``.
        kind: depth or disparity (never auto).
    """

    topic: str
    msgtype: str
    kind: ReferenceKind


def resolve_reference(
    topic: str,
    kind: ReferenceKind | str,
    present: Mapping[str, TopicInfo],
    log: object,
    *,
    outputs: str | None = None,
    reader: LogReader | None = None,
) -> ReferenceTopic:
    """Check a reference topic against a log's topics and settle its kind.

    Args:
        topic: the ``--reference-topic``.
        kind: the ``--reference-kind``; auto: disparity for a DisparityImage, else depth.
        present: the log's topics (``LogReader.topics()``).
        log: the log, for the messages.
        outputs: the prefix of densify's output topics (``/pcainterp``): none of them is
            truth (the estimate scored against itself), nor offered as one.
        reader: the open log, to offer only image topics whose first message holds depth
            or disparity when the topic is not found (None: every image topic).

    Returns:
        The checked :class:`ReferenceTopic`.

    Raises:
        TopicNotFoundError: the topic is not in the log (the message lists its image topics).
        LogReadError: the topic is not an image, a DisparityImage called depth, or one of
            densify's own outputs.
    """
    kind = ReferenceKind(kind)
    info = present.get(topic)
    own = outputs is not None and topic.startswith(outputs.rstrip("/") + "/")
    if info is not None and own:
        raise LogReadError(
            f"reference topic {topic} is one of densify's own outputs (under {outputs}): "
            "scored against them the estimate would be scored against itself; pass a depth "
            "or disparity topic recorded with the input (`pcainterp info` lists the topics)"
        )
    if info is None:
        images = _candidates(present, outputs, reader)
        close = closest_topic(topic, images)
        raise TopicNotFoundError(
            f"reference topic {topic} not found in {log}; depth and disparity image topics "
            f"present: {', '.join(images) or 'none'}; "
            + (
                f"the closest is {close}: pass it to --reference-topic"
                if close
                else "pass one of them to --reference-topic"
            )
        )
    if info.msgtype not in IMAGE_TYPES:
        raise LogReadError(
            f"reference topic {topic} in {log} is a {info.msgtype or 'non-ROS channel'}, not a "
            f"depth or disparity image ({', '.join(IMAGE_TYPES)}); project it into the left "
            "camera first"
        )
    if info.msgtype == rosmsg.DISPARITY_IMAGE:
        if kind is ReferenceKind.DEPTH:
            raise LogReadError(
                f"reference topic {topic} is a {rosmsg.DISPARITY_IMAGE}, which holds disparity; "
                "drop --reference-kind depth"
            )
        kind = ReferenceKind.DISPARITY
    elif info.msgtype == rosmsg.COMPRESSED_IMAGE and kind is ReferenceKind.DISPARITY:
        raise LogReadError(
            f"reference topic {topic} is a {rosmsg.COMPRESSED_IMAGE}, read as compressedDepth "
            "depth; drop --reference-kind disparity"
        )
    elif kind is ReferenceKind.AUTO:
        kind = ReferenceKind.DEPTH
    return ReferenceTopic(topic=topic, msgtype=info.msgtype, kind=kind)


def _candidates(
    present: Mapping[str, TopicInfo], outputs: str | None, reader: LogReader | None
) -> list[str]:
    """Return the topics a reference could be: image topics, densify's own outputs not.

    With ``reader``, an ``Image`` or ``CompressedImage`` topic only when its first message
    holds depth or disparity (32FC1, 16UC1, mono16, compressedDepth): a camera image would
    be refused.
    """
    own = None if outputs is None else outputs.rstrip("/") + "/"
    found = []
    for name, info in sorted(present.items()):
        if info.msgtype not in IMAGE_TYPES or (own is not None and name.startswith(own)):
            continue
        if reader is not None and info.msgtype != rosmsg.DISPARITY_IMAGE:
            raw = first_message(reader, name)
            try:
                message = None if raw is None else reader.decode(raw)
                if message is None or not _holds_depth(message):
                    continue
            except (ValueError, AttributeError, PcaInterpError):
                continue  # undecodable: not offered
        found.append(name)
    return found


def _holds_depth(message: Any) -> bool:
    """Whether an image message holds depth or disparity (not a camera image)."""
    if str(message.__msgtype__) == rosmsg.COMPRESSED_IMAGE:
        return depth_codec.is_compressed_depth(str(message.format))
    return str(message.encoding) in DEPTH_ENCODINGS


def reference_disparity(
    message: Any,
    reference: ReferenceTopic,
    *,
    focal_baseline: float,
    image_size: tuple[int, int],
    cx_offset: float = 0.0,
) -> npt.NDArray[np.float64]:
    """Decode one reference message into disparity of the densified log's camera.

    Args:
        message: a decoded message of ``reference.topic``.
        reference: the checked topic.
        focal_baseline: f*b (px*m) of the densified log's camera.
        image_size: (height, width) of the estimate (px).
        cx_offset: cx_left - cx_right (px) of the pair a DisparityImage was matched on: its
            bounds apply to value + cx_offset (:func:`disparity_image_valid`).

    Returns:
        (H, W) float64 disparity (px), NaN where the reference holds no truth, 0 where a
        depth reference says +inf (farther than measurable).

    Raises:
        LogReadError: the image is of another size than the estimate, or of an encoding
            that does not hold depth or disparity.
    """
    topic = reference.topic
    if reference.msgtype == rosmsg.COMPRESSED_IMAGE:  # compressedDepth (image_transport)
        try:
            values = depth_metres(message)
        except ValueError as err:
            raise LogReadError(f"reference topic {topic}: {err}") from err
        _check_size(topic, values.shape, image_size)
        return disparity_from_reference(values, kind=reference.kind, focal_baseline=focal_baseline)
    image = message.image if reference.msgtype == rosmsg.DISPARITY_IMAGE else message
    encoding = str(image.encoding)
    if reference.kind is ReferenceKind.DEPTH:
        allowed = DEPTH_ENCODINGS
        what = f"a depth reference must be {', '.join(DEPTH_ENCODINGS)} (REP 118)"
    else:
        allowed = {"32FC1": 1.0}
        what = "a disparity reference must be 32FC1 (px)"
    if encoding not in allowed:
        raise LogReadError(f"reference topic {topic} has {encoding} images; {what}")
    _check_size(topic, (int(image.height), int(image.width)), image_size)
    try:
        if reference.kind is ReferenceKind.DEPTH:
            values = depth_metres(image)  # 0 mm is "no return" (REP 118)
        else:
            values = rosmsg.image_array(image).astype(np.float64)
    except ValueError as err:
        raise LogReadError(f"reference topic {topic}: {err}") from err
    if reference.msgtype == rosmsg.DISPARITY_IMAGE:
        values[~disparity_image_valid(message, values, cx_offset)] = np.nan
        # d = f t / Z: a disparity of another focal length or baseline than the log's
        focal_t = float(message.f) * float(message.t)
        if focal_t > 0 and np.isfinite(focal_t):
            values *= focal_baseline / focal_t
    return disparity_from_reference(values, kind=reference.kind, focal_baseline=focal_baseline)


def disparity_image_valid(
    message: Any, values: npt.NDArray[np.float64], cx_offset: float = 0.0
) -> npt.NDArray[np.bool_]:
    """Return where a ``stereo_msgs/msg/DisparityImage`` says its disparity may be valid.

    As the message defines it (and stereo_image_proc fills it): "any disparity less than
    min_disparity is invalid"; a value above max_disparity is outside the range searched, so
    no match (a bound only when max_disparity > min_disparity: an unset 0 is none); a pixel
    outside ``valid_window`` is invalid (a window of width or height 0 reaches the image's
    edge, so the all-zero RegionOfInterest is the whole image). The bounds are the matcher's:
    stereo_image_proc writes OpenCV's invalid match as min_disparity - 1 and then shifts
    every value by -(cx_l - cx_r), the bounds not, so its invalid code is min_disparity - 1 -
    (cx_l - cx_r): > 0 whenever min_disparity > 1 or cx_r > cx_l. The bounds are applied to
    value + ``cx_offset``, which undoes that shift.

    Args:
        message: the decoded DisparityImage.
        values: (H, W) its image, in its own px (before any rescaling).
        cx_offset: cx_l - cx_r (px) of the pair's rectified P's (0: equal, or unknown).

    Returns:
        (H, W) bool, False where the message says the value is no disparity found.
    """
    lowest, highest = float(message.min_disparity), float(message.max_disparity)
    matched = values + cx_offset  # the matcher's disparity, which the bounds are of
    with np.errstate(invalid="ignore"):
        valid = ~(matched < lowest) if np.isfinite(lowest) else np.ones(values.shape, bool)
        if np.isfinite(highest) and highest > lowest:
            valid &= ~(matched > highest)
    return valid & _inside_window(message, values.shape)


def _inside_window(message: Any, shape: tuple[int, ...]) -> npt.NDArray[np.bool_]:
    """Return where a DisparityImage's ``valid_window`` is (width or height 0: to the edge)."""
    window = message.valid_window
    x, y = int(window.x_offset), int(window.y_offset)
    width = int(window.width) or shape[1] - x
    height = int(window.height) or shape[0] - y
    inside = np.zeros(shape[:2], bool)
    inside[y : max(y + height, y), x : max(x + width, x)] = True
    return inside


def reference_floor(
    message: Any, reference: ReferenceTopic | None, *, focal_baseline: float, cx_offset: float
) -> float:
    """Return the lowest disparity (px of the log) a reference message can hold as truth.

    0 but for a DisparityImage: its min_disparity, less ``cx_offset`` (cx_l - cx_r), rescaled
    as its values are. A reference whose floor is at or above the frame's resolvable minimum
    cannot say "too far" (:class:`~pcainterp_stream.evaluate.results.RangeStats`).
    """
    if reference is None or reference.msgtype != rosmsg.DISPARITY_IMAGE or message is None:
        return 0.0
    lowest = float(message.min_disparity) - cx_offset
    focal_t = float(message.f) * float(message.t)
    scale = focal_baseline / focal_t if focal_t > 0 and np.isfinite(focal_t) else 1.0
    return max(lowest * scale, 0.0) if np.isfinite(lowest) else 0.0


def disparity_image_dropped(message: Any, cx_offset: float) -> str:
    """Say how a DisparityImage's own bounds and window leave its values > 0 no truth.

    "" when it has no finite value > 0 (then every pixel is NaN, 0 or < 0). The counts may
    overlap: a pixel below min_disparity may also be outside valid_window.
    """
    try:
        values = rosmsg.image_array(message.image).astype(np.float64)
    except ValueError:
        return ""
    with np.errstate(invalid="ignore"):
        positive = np.isfinite(values) & (values > 0)
    if not positive.any():
        return ""
    lowest, highest = float(message.min_disparity), float(message.max_disparity)
    matched = values + cx_offset
    shift = f" (value {cx_offset:+g} px: cx_l - cx_r of the pair)" if cx_offset else ""
    with np.errstate(invalid="ignore"):
        below = int(np.count_nonzero(positive & (matched < lowest)))
        above = int(np.count_nonzero(positive & (matched > highest))) if highest > lowest else 0
    outside = int(np.count_nonzero(positive & ~_inside_window(message, values.shape)))
    parts = [
        *([f"{below} below its min_disparity {lowest:g} px{shift}"] if below else []),
        *([f"{above} above its max_disparity {highest:g} px{shift}"] if above else []),
        *([f"{outside} outside its valid_window"] if outside else []),
    ]
    return (
        f"of its {int(np.count_nonzero(positive))} px with a value > 0, "
        f"{', '.join(parts)} (stereo_msgs/DisparityImage: no disparity found there)"
    )


def bounds_notes(reference: ReferenceTopic | None, offsets: set[float | None]) -> list[str]:
    """Say how a DisparityImage's bounds met the pair's cx (none for another reference).

    ``offsets``: cx_l - cx_r of the frames scored (None: the pair's camera infos unknown).
    """
    if reference is None or reference.msgtype != rosmsg.DISPARITY_IMAGE:
        return []
    notes = []
    shifted = sorted(offset for offset in offsets if offset)
    if shifted:
        notes.append(
            f"{reference.topic}'s min_disparity and max_disparity are applied to value + "
            f"(cx_l - cx_r), with cx_l - cx_r {', '.join(f'{o:+g}' for o in shifted)} px "
            "from the P of the input pair's camera infos: stereo_image_proc shifts its values "
            "by -(cx_l - cx_r), its bounds not"
        )
    if None in offsets:
        notes.append(
            f"the input pair's camera infos were not read (calibration files, or none), so "
            f"{reference.topic}'s min_disparity and max_disparity are applied as they are: "
            "right only if the pair's rectified cx are equal (else stereo_image_proc's "
            "invalid code min_disparity - 1 - (cx_l - cx_r) may be scored)"
        )
    return notes


def _check_size(topic: str, size: tuple[int, ...], image_size: tuple[int, int]) -> None:
    if size != image_size:
        raise LogReadError(
            f"reference topic {topic} has {size[1]}x{size[0]} images but the estimate is "
            f"{image_size[1]}x{image_size[0]}; pass a reference at the densified size"
        )
