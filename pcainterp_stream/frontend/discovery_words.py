"""The words of stereo-pair discovery: the line that says which pair was found, the errors.

Kept apart from :mod:`discovery` (which finds the pairs) so that each stays short.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.frontend.pair_forms import SIDE_BY_SIDE_MATCH, halves_match
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import decode_image
from pcainterp_stream.io.reader_base import LogReader, TopicInfo

if TYPE_CHECKING:
    from pcainterp_stream.frontend.discovery import Camera, StereoTopics


def side_by_side(reader: LogReader, topic: str) -> str:
    """Return a hint when a lone image topic's first image holds two views side by side."""
    try:
        raw = next(iter(reader.messages([topic])), None)
        image = None if raw is None else decode_image(reader.decode(raw))
    except (PcaInterpError, ValueError):
        return ""
    if image is None or halves_match(image) < SIDE_BY_SIDE_MATCH:
        return ""
    return (
        f"; its {image.shape[1]}x{image.shape[0]} images hold two views side by side (their "
        "halves show one scene): pcainterp reads one camera per image topic, so split each "
        "image into a left and a right half on two topics first (with a camera info each)"
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


def skipped_as_depth(skipped: list[Camera], encoding_of: Callable[[str], str | None]) -> str:
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


def found_line(best: StereoTopics, others: int, *, named_left: bool, named_right: bool) -> str:
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
