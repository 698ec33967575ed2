"""The words of stereo-pair discovery: the line that says which pair was found, the errors.

Kept apart from :mod:`discovery` (which finds the pairs) so that each stays short.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Protocol

from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.frontend.pair_forms import SIDE_BY_SIDE_MATCH, halves_match
from pcainterp_stream.frontend.stream_kinds import first_encoding
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import decode_image
from pcainterp_stream.io.reader_base import LogReader, TopicInfo

_IMAGE_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE)
UNCALIBRATED = "are not calibrated"
"""Said in the reason of two cameras whose camera infos have an all-zero K and P."""


class Stream(Protocol):
    """What these words read of a camera's stream (:class:`discovery.Camera`)."""

    @property
    def topic(self) -> str:
        """The image topic."""

    @property
    def info(self) -> str | None:
        """Its camera info topic (None: none)."""

    @property
    def compressed(self) -> bool:
        """True for a CompressedImage stream."""


class Pair(Protocol):
    """What these words read of a stereo pair found (:class:`discovery.StereoTopics`)."""

    @property
    def left(self) -> Stream:
        """The left stream."""

    @property
    def right(self) -> Stream:
        """The right stream."""

    @property
    def how(self) -> str:
        """How the sides were told apart."""

    @property
    def note(self) -> str:
        """What was passed over ("" when nothing)."""


def no_pair_error(
    reader: LogReader,
    *,
    need_info: bool,
    named: bool,
    rejected: list[str],
    skipped: Sequence[Stream],
) -> TopicNotFoundError:
    """Return the error of a log in which no stereo pair was found.

    Args:
        reader: the log.
        need_info: cameras need a camera info (no calibration files).
        named: an image topic was named on the command line.
        rejected: why cameras numbered alike were not taken for a pair.
        skipped: the depth-named streams left out.
    """
    topics = reader.topics()
    name = str(reader.path)
    images = [t for t, i in sorted(topics.items()) if i.msgtype in _IMAGE_TYPES]
    empty = [t for t in images if topics[t].message_count == 0]
    if rejected and all(UNCALIBRATED in r for r in rejected):
        return TopicNotFoundError(
            f"no stereo pair found in {name}: {'; '.join(dict.fromkeys(rejected))}; "
            "calibrate the pair (ROS camera_calibration) and pass --calibration LEFT.yaml "
            "RIGHT.yaml"
        )
    if rejected:
        return TopicNotFoundError(
            f"no stereo pair found in {name}: {'; '.join(dict.fromkeys(rejected))}; a "
            "stereo pair's right camera info has Tx = -fx * baseline: if they are the "
            "two sides of a stereo pair whose infos lack it, name its topics with "
            "--left-topic and --right-topic and pass --baseline METRES (its images "
            "rectified) or its stereo --calibration (raw images)"
        )
    if images and len(empty) == len(images):
        return TopicNotFoundError(
            f"no stereo pair found in {name}: its image topics have no messages "
            f"({', '.join(empty)}; see pcainterp info)"
        )
    infos = [t for t, i in sorted(topics.items()) if i.msgtype == rosmsg.CAMERA_INFO]
    want = "an image topic with a sibling camera_info" if need_info else "an image topic"
    other_images = [  # cameras in a form pcainterp does not decode (theora, ffmpeg, SDK)
        t
        for t, i in topics.items()
        if i.msgtype not in _IMAGE_TYPES and re.search(r"Image|Packet", i.msgtype or "")
    ]
    foreign = sorted({str(topics[t].msgtype) for t in other_images})
    if not images:
        other = f" (its {', '.join(foreign)} are not read)" if foreign else ""
        return TopicNotFoundError(
            f"no stereo pair found in {name}: it has no camera images{other}; pcainterp "
            "densifies logs with two cameras' sensor_msgs/Image or CompressedImage topics"
        )
    if len(images) == 1 and not other_images and not named:
        return TopicNotFoundError(
            f"no stereo pair found in {name}: it has one camera ({images[0]}; camera infos: "
            f"{', '.join(infos) or 'none'}); pcainterp needs a stereo pair, two cameras side "
            "by side (--left-topic and --right-topic name them)" + side_by_side(reader, images[0])
        )
    listed = ", ".join(f"{t} (no messages)" if t in empty else t for t in images)
    depth = {c.topic for c in skipped}
    return TopicNotFoundError(
        f"no stereo pair found in {name}: it needs two cameras, each {want}, named left/"
        f"right (or cam0/cam1, ...); image topics: {listed or 'none'}; camera "
        f"infos: {', '.join(infos) or 'none'}"
        f"{skipped_as_depth(skipped, first_encoding(reader))}; pass "
        "--left-topic and --right-topic"
        + (" (and --calibration LEFT.yaml RIGHT.yaml without camera infos)" if need_info else "")
        + side_by_side_among(reader, [t for t in images if t not in empty and t not in depth])
    )


SPLIT = (
    "pcainterp reads one camera per image topic, so split each image into a left and a right "
    "half on two topics first (with a camera info each)"
)
"""The advice for a topic whose images hold two views side by side."""


def _halves(reader: LogReader, topic: str) -> tuple[int, int] | None:
    """Return (width, height) when a topic's first image holds two views side by side."""
    try:
        raw = next(iter(reader.messages([topic])), None)
        image = None if raw is None else decode_image(reader.decode(raw))
    except (PcaInterpError, ValueError):
        return None
    if image is None or halves_match(image) < SIDE_BY_SIDE_MATCH:
        return None
    return image.shape[1], image.shape[0]


def no_infos_error(
    topics: dict[str, TopicInfo], name: str, images: tuple[str, str], missing: list[str]
) -> TopicNotFoundError:
    """Return the error of a stereo pair's images without their camera infos in a log.

    Args:
        topics: the log's topics.
        name: the log's name.
        images: the left and right image topics.
        missing: the info topics looked for, not in the log ([] when found by name).
    """
    infos = [t for t, i in sorted(topics.items()) if i.msgtype == rosmsg.CAMERA_INFO]
    live = [t for t in infos if topics[t].message_count != 0]
    looked = f" ({', '.join(missing)} not in it)" if missing else ""
    if live:
        return TopicNotFoundError(
            f"no camera infos for {images[0]} and {images[1]} in {name}{looked}; camera "
            f"infos in it: {', '.join(live)}: pass --left-info-topic and --right-info-topic"
        )
    silent = [t for t in infos if t not in live]
    listed = f" ({', '.join(silent)} without messages)" if silent else ""
    return TopicNotFoundError(
        f"no stereo pair found in {name}: it has no camera infos{listed}; its cameras "
        f"{images[0]} and {images[1]} need them{looked}; a later part of a split recording "
        "(rosbag record --split, ros2 bag record -b) has none when the cameras latched them "
        "in the first part: densify the parts together as one log (pcainterp densify PART_0 "
        "PART_1 ... -o OUT; a rosbag2 bag's folder holds all its parts); else pass "
        "--calibration LEFT.yaml RIGHT.yaml (the cameras' calibration files)"
    )


def side_by_side(reader: LogReader, topic: str) -> str:
    """Return a hint when a lone image topic's first image holds two views side by side."""
    size = _halves(reader, topic)
    if size is None:
        return ""
    return (
        f"; its {size[0]}x{size[1]} images hold two views side by side (their halves show "
        f"one scene): {SPLIT}"
    )


def side_by_side_among(reader: LogReader, images: list[str], most: int = 8) -> str:
    """Return a hint on the first of ``images`` whose images hold two views side by side.

    A ZED's ``stereo/image_rect_color`` beside its depth and confidence streams: the camera
    images among the first ``most`` topics are looked at ("" when none is side by side).
    """
    topics = reader.topics()
    encoding_of = first_encoding(reader)
    for topic in images[:most]:
        compressed = topics[topic].msgtype == rosmsg.COMPRESSED_IMAGE
        encoding = None if compressed else encoding_of(topic)
        if encoding is not None and encoding not in rosmsg.CAMERA_IMAGE_ENCODINGS:
            continue  # depth, disparity, confidence
        size = _halves(reader, topic)
        if size is not None:
            return (
                f"; {topic} holds two views side by side ({size[0]}x{size[1]} images whose "
                f"halves show one scene): {SPLIT}, then pass those as --left-topic and "
                "--right-topic"
            )
    return ""


def named_side_by_side(reader: LogReader, topic: str, side: str) -> str | None:
    """Return the error of a topic named as one side whose images hold both views (None: not)."""
    size = _halves(reader, topic)
    if size is None:
        return None
    other = "right" if side == "left" else "left"
    return (
        f"{topic} (--{side}-topic) holds two views side by side in each image ({size[0]}x"
        f"{size[1]}, its halves show one scene), not one camera's: {SPLIT}, then pass the "
        f"left half's topic as --left-topic and the right half's as --right-topic "
        f"(no --{other}-topic in {reader.path.name} pairs with it)"
    )


def shared_info(topics: dict[str, TopicInfo], info: str, no_baseline: bool) -> str:
    """Return the topics line's words on two images taking one camera info, their namespace's.

    Without ``--baseline`` one info gives none: the words name the options (and the log's
    other camera infos) that give each side its own.
    """
    said = f"both images take {info}, the one camera_info of their namespace"
    if not no_baseline:
        return said
    others = [t for t, i in sorted(topics.items()) if i.msgtype == rosmsg.CAMERA_INFO]
    others = [t for t in others if t != info]
    listed = f"; other camera infos in the log: {', '.join(others[:4])}" if others else ""
    more = f" and {len(others) - 4} more" if len(others) > 4 else ""
    return (
        f"{said}: one camera info gives no baseline, --left-info-topic and "
        f"--right-info-topic name each side's{listed}{more}"
    )


def skipped_as_depth(skipped: Sequence[Stream], encoding_of: Callable[[str], str | None]) -> str:
    """Return the clause of the no-pair error on the streams skipped as depth ("" if none)."""
    if not skipped:
        return ""
    listed = []
    for cam in skipped:
        encoding = None if cam.compressed else encoding_of(cam.topic)
        listed.append(f"{cam.topic} ({encoding})" if encoding else cam.topic)
    return (
        f"; skipped as depth, disparity, segmentation ... streams, their names saying so: "
        f"{', '.join(listed)} (a stereo camera named so is read when its topics are named: "
        f"--left-topic {skipped[0].topic} and its partner's --right-topic)"
    )


def found_line(best: Pair, others: int, *, named_left: bool, named_right: bool) -> str:
    """Return the line that says which pair was found (one side of it may have been named).

    Args:
        best: the pair chosen.
        others: how many other pairs were candidates (with the named side, if one was).
        named_left: the left image topic was named on the command line.
        named_right: the right one was.
    """
    with_infos = f" with {best.left.info} and {best.right.info}" if best.left.info else ""
    pair = f"topics: left {best.left.topic}, right {best.right.topic}{with_infos}"
    note = f"; {best.note}" if best.note else ""
    if named_left and named_right:
        return f"{pair} (both named{note})"
    if named_left or named_right:
        named, found = ("left", "right") if named_left else ("right", "left")
        return (
            f"{pair} (the {found} camera found {best.how} for the {named} one named{note}; "
            f"--{found}-topic chooses another)"
        )
    more = f"; {others} other pair{'s' * (others > 1)} less preferred" if others else ""
    return f"{pair} (found {best.how}{more}{note}; --left-topic/--right-topic choose others)"
