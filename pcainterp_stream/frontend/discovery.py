"""Find the stereo pair of a log from its topics, when the command line names none.

A camera is an image topic (``sensor_msgs/Image`` or ``CompressedImage``) with a sibling
``camera_info`` (``/ns/left/image_raw`` -> ``/ns/left/camera_info``), or, with calibration
files, any image topic. Two cameras are a stereo pair when their topics differ in one name
that says which is left: ``left``/``right``, ``l``/``r``, or a number (``cam0``/``cam1``,
``infra1``/``infra2``, ``image_2``/``image_3``: the lower one is left); names that say
nothing are ordered by the sign of P[0, 3] (the right camera's is negative). The two sides
are streams of one image (``image_raw``), raw or compressed alike (a compressed left with a
raw right pairs). Of a camera's streams the rectified one is preferred (``image_rect`` over
``image_raw``), then one transport on both sides, then the uncompressed, then the grey one.
A log with several heads (``/front/left`` + ``/front/right`` and ``/rear/left`` +
``/rear/right``) has cross-head candidates too (``/front/left`` + ``/rear/right``, sides from
Tx): a pair whose namespaces differ only in the name that says the side comes first, then
one whose namespaces differ in one name, then the others. Two pairs equally good are an
error that lists them with the options that choose one.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from dataclasses import dataclass

from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.frontend.pairing import PairingConfig, is_rectified_name
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.reader_base import LogReader, TopicInfo

DEFAULT_LEFT_IMAGE = PairingConfig.left_topic
DEFAULT_RIGHT_IMAGE = PairingConfig.right_topic
DEFAULT_LEFT_INFO = PairingConfig.left_info_topic
DEFAULT_RIGHT_INFO = PairingConfig.right_info_topic
_IMAGE_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE)
_COMPRESSED = ("compressed",)


@dataclass(frozen=True)
class Camera:
    """An image stream of one camera: its topic, its namespace and its info topic."""

    topic: str
    namespace: str
    info: str | None

    @property
    def stream(self) -> str:
        """Return the stream's name below the namespace (``image_raw``, ``image/compressed``)."""
        return self.topic[len(self.namespace) :].lstrip("/")

    @property
    def compressed(self) -> bool:
        """Return True for a ``CompressedImage`` stream (``image_raw/compressed``)."""
        return self.topic.rstrip("/").split("/")[-1] in _COMPRESSED

    @property
    def image(self) -> str:
        """Return the stream's image without its transport (``image_raw`` of both forms)."""
        parts = self.stream.rstrip("/").split("/")
        return "/".join(parts[:-1] if self.compressed else parts)


def stream_score(left: Camera, right: Camera) -> tuple[int, int, int, int]:
    """Return how much a pair of streams (of one image) is preferred.

    Rectified first, then both sides of one transport (both raw, or both compressed), then
    the uncompressed sides (both, one, none), then grey.
    """
    colour = any(word in left.stream for word in ("color", "colour", "rgb"))
    return (
        int(is_rectified_name(left.topic)),
        int(left.compressed == right.compressed),
        int(not left.compressed) + int(not right.compressed),
        int(not colour),
    )


BY_NAME = 2
"""Closeness of a pair whose namespaces differ only in a name that says the side."""

SIBLINGS = 1
"""Closeness of a pair whose namespaces differ in one name that does not say the side."""

DISTANT = 0
"""Closeness of a pair whose namespaces differ in more (cameras of two heads, say)."""


@dataclass(frozen=True)
class StereoTopics:
    """A stereo pair found in a log.

    Attributes:
        left: the left camera's stream.
        right: the right camera's stream.
        how: how the sides were told apart (``by name``, ``by the sign of P's Tx``).
        closeness: :data:`BY_NAME`, :data:`SIBLINGS` or :data:`DISTANT`.
    """

    left: Camera
    right: Camera
    how: str
    closeness: int = BY_NAME

    def preference(self) -> tuple[int, int, int, int, int]:
        """Return how much this pair is preferred: closeness, then :func:`stream_score`."""
        return (self.closeness, *stream_score(self.left, self.right))

    def describe(self) -> str:
        """Return the pair as the options that would choose it."""
        text = f"--left-topic {self.left.topic} --right-topic {self.right.topic}"
        if self.left.info is not None and self.right.info is not None:
            text += f" --left-info-topic {self.left.info} --right-info-topic {self.right.info}"
        return text


def namespace(topic: str) -> str:
    """Return a camera's namespace: the image topic without its stream name."""
    parts = topic.rstrip("/").split("/")
    if parts[-1] in _COMPRESSED:
        parts = parts[:-1]
    return "/".join(parts[:-1])


def cameras(topics: dict[str, TopicInfo], *, need_info: bool = True) -> list[Camera]:
    """Return the image streams of a log that can be a stereo camera."""
    found = []
    for topic, info in sorted(topics.items()):
        if info.msgtype not in _IMAGE_TYPES:
            continue
        ns = namespace(topic)
        info_topic = f"{ns}/camera_info"
        has_info = topics.get(info_topic) is not None and (
            topics[info_topic].msgtype == rosmsg.CAMERA_INFO
        )
        if has_info or not need_info:
            found.append(Camera(topic, ns, info_topic if has_info else None))
    return found


def _differing_names(a: str, b: str) -> int:
    """Return in how many ``/`` segments two namespaces differ (a missing one counts)."""
    sa, sb = a.split("/"), b.split("/")
    return sum(x != y for x, y in zip(sa, sb, strict=False)) + abs(len(sa) - len(sb))


def _side_by_name(a: str, b: str) -> int | None:
    """Return -1 when namespace ``a`` is the left camera of ``b``, 1 when right, None if unsure.

    The two namespaces must differ in exactly one ``/`` segment.
    """
    sa, sb = a.split("/"), b.split("/")
    if len(sa) != len(sb):
        return None
    diff = [(x, y) for x, y in zip(sa, sb, strict=True) if x != y]
    if len(diff) != 1:
        return None
    x, y = diff[0][0].lower(), diff[0][1].lower()
    if "left" in x and "right" in y and x.replace("left", "") == y.replace("right", ""):
        return -1
    if "right" in x and "left" in y and x.replace("right", "") == y.replace("left", ""):
        return 1
    tx, ty = re.split(r"[_\-.]", x), re.split(r"[_\-.]", y)
    if len(tx) == len(ty):
        tokens = [(p, q) for p, q in zip(tx, ty, strict=True) if p != q]
        if len(tokens) == 1 and {tokens[0][0], tokens[0][1]} == {"l", "r"}:
            return -1 if tokens[0][0] == "l" else 1
    mx, my = re.fullmatch(r"(.*?)(\d+)(\D*)", x), re.fullmatch(r"(.*?)(\d+)(\D*)", y)
    if mx and my and mx.group(1) == my.group(1) and mx.group(3) == my.group(3):
        nx, ny = int(mx.group(2)), int(my.group(2))
        if nx != ny:
            return -1 if nx < ny else 1
    return None


def find_pairs(
    topics: dict[str, TopicInfo],
    *,
    need_info: bool = True,
    tx_of: Callable[[str], float | None] | None = None,
) -> list[StereoTopics]:
    """Return the stereo pairs of a log, best first (see the module docstring).

    Args:
        topics: the log's topics.
        need_info: cameras need a sibling ``camera_info`` (False with calibration files).
        tx_of: info topic -> its P[0, 3] (read from the log), for names that say nothing.
    """
    streams = cameras(topics, need_info=need_info)
    by_ns: dict[str, list[Camera]] = {}
    for cam in streams:
        by_ns.setdefault(cam.namespace, []).append(cam)
    spaces = sorted(by_ns)
    pairs: list[StereoTopics] = []
    for i, a in enumerate(spaces):
        for b in spaces[i + 1 :]:
            side = _side_by_name(a, b)
            how, closeness = "by name", BY_NAME
            if side is None and tx_of is not None:
                info_a, info_b = by_ns[a][0].info, by_ns[b][0].info
                tx_a = tx_of(info_a) if info_a else None
                tx_b = tx_of(info_b) if info_b else None
                if tx_a is not None and tx_b is not None and (tx_a < 0) != (tx_b < 0):
                    side = 1 if tx_a < 0 else -1
                    how = "by the sign of P's Tx"
                    closeness = SIBLINGS if _differing_names(a, b) == 1 else DISTANT
            if side is None:
                continue
            left_ns, right_ns = (a, b) if side < 0 else (b, a)
            # the two sides of one image; their transports may differ (a compressed left
            # with a raw right), one transport on both sides preferred
            best: tuple[tuple[int, int, int, int], Camera, Camera] | None = None
            for cam in by_ns[left_ns]:
                for partner in by_ns[right_ns]:
                    score = stream_score(cam, partner)
                    if partner.image == cam.image and (best is None or score > best[0]):
                        best = (score, cam, partner)
            if best is not None:
                pairs.append(StereoTopics(best[1], best[2], how, closeness))
    pairs.sort(key=StereoTopics.preference, reverse=True)
    return pairs


def _first_tx(reader: LogReader) -> Callable[[str], float | None]:
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


def resolve_pairing(
    reader: LogReader, config: PairingConfig, echo: Callable[[str], None] | None = None
) -> PairingConfig:
    """Return ``config`` with the topics of the log's stereo pair when none were named.

    With ``config.discover`` set, an image topic of ``config.named_sides`` or other than the
    default one (one side named on the command line) keeps only the pairs with it; an info
    topic other than the default one stays (named). With ``config.discover`` unset, the
    named topics are kept; only info topics left at their defaults become the image topics'
    sibling ``camera_info`` when the log has those and not the defaults.

    Raises:
        TopicNotFoundError: no pair, or two equally good pairs (listing them and the options).
    """
    topics = reader.topics()
    if not config.discover:
        siblings: dict[str, str] = {}
        for field, image, default in (
            ("left_info_topic", config.left_topic, DEFAULT_LEFT_INFO),
            ("right_info_topic", config.right_topic, DEFAULT_RIGHT_INFO),
        ):
            sibling = f"{namespace(image)}/camera_info"
            if getattr(config, field) == default and default not in topics and sibling in topics:
                siblings[field] = sibling
        if not siblings:
            return config
        return dataclasses.replace(
            config,
            left_info_topic=siblings.get("left_info_topic", config.left_info_topic),
            right_info_topic=siblings.get("right_info_topic", config.right_info_topic),
        )
    need_info = config.calibration is None
    named_left = "left" in config.named_sides or config.left_topic != DEFAULT_LEFT_IMAGE
    named_right = "right" in config.named_sides or config.right_topic != DEFAULT_RIGHT_IMAGE
    named = named_left or named_right
    pairs = find_pairs(topics, need_info=need_info, tx_of=_first_tx(reader))
    # a side was named: only the pairs with it
    if named_left:
        pairs = [p for p in pairs if p.left.topic == config.left_topic]
    if named_right:
        pairs = [p for p in pairs if p.right.topic == config.right_topic]
    if named and not pairs:  # the named topic is missing, of another type, or has no partner
        return resolve_pairing(reader, dataclasses.replace(config, discover=False), echo)
    name = str(reader.path)
    if not pairs and (reader.damage or all(info.message_count == 0 for info in topics.values())):
        return dataclasses.replace(config, discover=False)  # the defaults: reported as damaged
    if not pairs:
        images = [t for t, i in sorted(topics.items()) if i.msgtype in _IMAGE_TYPES]
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
            raise TopicNotFoundError(
                f"no stereo pair found in {name}: it has no camera images{other}; pcainterp "
                "densifies logs with two cameras' sensor_msgs/Image or CompressedImage topics"
            )
        if len(images) == 1 and not other_images and not named:
            raise TopicNotFoundError(
                f"no stereo pair found in {name}: it has one camera ({images[0]}; camera infos: "
                f"{', '.join(infos) or 'none'}); pcainterp needs a stereo pair, two cameras side "
                "by side (--left-topic and --right-topic name them)"
            )
        raise TopicNotFoundError(
            f"no stereo pair found in {name}: it needs two cameras, each {want}, named left/"
            f"right (or cam0/cam1, ...); image topics: {', '.join(images) or 'none'}; camera "
            f"infos: {', '.join(infos) or 'none'}; pass "
            "--left-topic and --right-topic"
            + (
                " (and --calibration LEFT.yaml RIGHT.yaml without camera infos)"
                if need_info
                else ""
            )
        )
    best = pairs[0]
    ties = [p for p in pairs if p.preference() == best.preference()]
    if len(ties) > 1:
        listed = "; ".join(p.describe() for p in ties)
        # one side named keeps the pairs with it: the best of those is the tie with it
        alone = len({p.left.topic for p in ties}) == len(ties)
        raise TopicNotFoundError(
            f"{len(ties)} stereo pairs in {name} are equally good: {listed}; pass the options "
            "of the one to read" + (" (its --left-topic alone will do)" if alone else "")
        )
    left_info, right_info = config.left_info_topic, config.right_info_topic
    if best.left.info is not None and best.right.info is not None:
        # an info topic other than the default one was named: it stays
        if left_info == DEFAULT_LEFT_INFO:
            left_info = best.left.info
        if right_info == DEFAULT_RIGHT_INFO:
            right_info = best.right.info
    if echo is not None:
        echo(_found_line(best, len(pairs) - 1, named_left=named_left, named_right=named_right))
    return dataclasses.replace(
        config,
        discover=False,
        left_topic=best.left.topic,
        right_topic=best.right.topic,
        left_info_topic=left_info,
        right_info_topic=right_info,
    )


def _found_line(best: StereoTopics, others: int, *, named_left: bool, named_right: bool) -> str:
    """Return the line that says which pair was found (one side of it may have been named).

    Args:
        best: the pair chosen.
        others: how many other pairs were candidates (with the named side, if one was).
        named_left: the left image topic was named on the command line.
        named_right: the right one was.
    """
    with_infos = f" with {best.left.info} and {best.right.info}" if best.left.info else ""
    pair = f"topics: left {best.left.topic}, right {best.right.topic}{with_infos}"
    if named_left and named_right:
        return f"{pair} (both named)"
    if named_left or named_right:
        named, found = ("left", "right") if named_left else ("right", "left")
        return (
            f"{pair} (the {found} camera found {best.how} for the {named} one named; "
            f"--{found}-topic chooses another)"
        )
    more = f"; {others} other pair{'s' * (others > 1)} less preferred" if others else ""
    return f"{pair} (found {best.how}{more}; --left-topic/--right-topic choose others)"
