"""Find the stereo pair of a log from its topics, when the command line names none.

A camera is an image topic (``sensor_msgs/Image`` or ``CompressedImage``) with a
``camera_info`` of its own below it (``/ns/left/Scene/camera_info``: AirSim, MultiSense) or a
sibling one (``/ns/left/image_raw`` -> ``/ns/left/camera_info``), or, with calibration files,
any image topic. A depth, disparity, segmentation, normals or confidence stream (``depth``,
``DepthPlanar``, ``disparity``, ``Segmentation``: a simulator's or a depth camera's, beside
its camera images; not ``depth_left``, a camera's name) is no camera, unless no pair is found
without it and its first image is a camera image; nor, when the camera has another stream, one
whose first image is not a camera image (``32FC1``). Two cameras are a stereo pair when their
topics differ in one name that says which is left: ``left``/``right``, ``l``/``r``, or a
number (``cam0``/``cam1``, ``infra1``/``infra2``, ``image_2``/``image_3``: the lower one is
left); names that say nothing are ordered by the sign of P[0, 3] (the right camera's is
negative). The two sides are streams of one image (``image_raw``), raw or compressed alike (a
compressed left with a raw right pairs). Of a camera's streams the rectified one is preferred
(``image_rect`` over ``image_raw``), then one transport on both sides, then the uncompressed,
then the grey one; but a stream pair with clearly fewer images than another gives way to it
(said in the line). An image topic the log counts no message on is no camera. A number does
not make a pair when a name both namespaces share says the side (``/robot1/stereo/left`` and
``/robot2/stereo/left``), nor, without calibration files or ``--baseline``, when both infos
have P[0, 3] = 0 (two monocular ``/camera1`` and ``/camera2``).
A log with several heads (``/front/left`` + ``/front/right`` and ``/rear/left`` +
``/rear/right``) has cross-head candidates too (``/front/left`` + ``/rear/right``, sides from
Tx): a pair whose namespaces differ only in the name that says the side comes first, then
one whose namespaces differ in one name, then the others. Two pairs equally good are an
error that lists them with the options that choose one; the stream preference chooses among
one camera's streams only (:func:`head`), so two cameras tie whatever their streams.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from dataclasses import dataclass

from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.frontend.camchain_topics import (
    calibration_file,
    camchain_order,
    one_topic_both_sides,
)
from pcainterp_stream.frontend.discovery_words import (
    UNCALIBRATED,
    found_line,
    named_side_by_side,
    no_infos_error,
    no_pair_error,
    shared_info,
)
from pcainterp_stream.frontend.pair_forms import is_rectified_name
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stream_kinds import (
    camera_images,
    depth_named,
    first_encoding,
    first_tx,
    first_uncalibrated,
)
from pcainterp_stream.frontend.tf_baseline import tf_baseline_line
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
    count: int | None = dataclasses.field(default=None, compare=False)
    """How many images the log has on the topic (None: not counted)."""

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

    @property
    def not_camera(self) -> bool:
        """Return True for a depth, disparity, segmentation ... stream (its name says so).

        A name of the stream below the namespace (``/isaac/left/depth``,
        ``/airsim_node/drone_1/front_left/DepthPlanar``) or the namespace's last name
        (``/camera/depth/image_rect_raw``, ``/zed/zed_node/disparity/disparity_image``)
        says it, one that says no side (``/robot/depth_left/image_raw`` is a camera's):
        :func:`stream_kinds.depth_named`.
        """
        return depth_named(self.namespace, self.image)


def stream_score(left: Camera, right: Camera) -> tuple[int, int, int, int]:
    """Return how much a pair of streams (of one image) is preferred.

    Rectified first, then both sides of one transport (both raw, or both compressed), then
    the uncompressed sides (both, one, none), then grey. The names below the one that says
    the side say it too (``/zed/zed_node/left/gray/rect/image``, the ZED wrapper 5.x's).
    """
    parts, others = left.topic.split("/"), right.topic.split("/")
    side = next((i for i, (a, b) in enumerate(zip(parts, others, strict=False)) if a != b), 0)
    below = "/".join([left.stream, *parts[side + 1 :]]).lower()
    colour = any(word in below for word in ("color", "colour", "rgb"))
    return (
        int(is_rectified_name(left.topic, right.topic)),
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
        note: what was passed over for these streams (a rectified stream with fewer
            images), "" when nothing.
    """

    left: Camera
    right: Camera
    how: str
    closeness: int = BY_NAME
    note: str = dataclasses.field(default="", compare=False)

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
    """Return the image streams of a log that can be a stereo camera.

    An image topic the log counts no message on (an advertised topic that never published,
    as ``ros2 bag record`` leaves it) is no camera. Its camera info is the one below it
    (``IMAGE/camera_info``) if the log has that, else its sibling (:func:`info_topic_of`).
    """
    found = []
    for topic, info in sorted(topics.items()):
        if info.msgtype not in _IMAGE_TYPES or info.message_count == 0:
            continue
        info_topic = info_topic_of(topic, topics)
        if info_topic is not None or not need_info:
            found.append(Camera(topic, namespace(topic), info_topic, info.message_count))
    return found


def info_topic_of(image: str, topics: dict[str, TopicInfo]) -> str | None:
    """Return the camera info topic of an image topic in a log, None if it has none.

    The one below the image (``/airsim_node/drone_1/front_left/Scene/camera_info``, the
    MultiSense driver's ``/multisense/left/image_rect/camera_info``) first, then the
    sibling (``/stereo/left/image_raw`` -> ``/stereo/left/camera_info``); a compressed
    stream's are its image's (``.../Scene/compressed`` -> ``.../Scene/camera_info``).
    """
    parts = image.rstrip("/").split("/")
    if parts[-1] in _COMPRESSED:
        parts = parts[:-1]
    for candidate in ("/".join([*parts, "camera_info"]), f"{namespace(image)}/camera_info"):
        found = topics.get(candidate)
        if found is not None and found.msgtype == rosmsg.CAMERA_INFO:
            return candidate
    return None


def _differing_names(a: str, b: str) -> int:
    """Return in how many ``/`` segments two namespaces differ (a missing one counts)."""
    sa, sb = a.split("/"), b.split("/")
    return sum(x != y for x, y in zip(sa, sb, strict=False)) + abs(len(sa) - len(sb))


def _the_differing_name(a: str, b: str) -> tuple[str, str] | None:
    """Return the one ``/`` segment two namespaces differ in (lower case), None if not one."""
    sa, sb = a.split("/"), b.split("/")
    if len(sa) != len(sb):
        return None
    diff = [(x, y) for x, y in zip(sa, sb, strict=True) if x != y]
    if len(diff) != 1:
        return None
    return diff[0][0].lower(), diff[0][1].lower()


def _side_by_name(a: str, b: str) -> int | None:
    """Return -1 when namespace ``a`` is the left camera of ``b``, 1 when right, None if unsure.

    The two namespaces must differ in exactly one ``/`` segment.
    """
    names = _the_differing_name(a, b)
    if names is None:
        return None
    x, y = names
    if "left" in x and "right" in y and x.replace("left", "") == y.replace("right", ""):
        return -1
    if "right" in x and "left" in y and x.replace("right", "") == y.replace("left", ""):
        return 1
    tx, ty = re.split(r"[_\-.]", x), re.split(r"[_\-.]", y)
    if len(tx) == len(ty):
        tokens = [(p, q) for p, q in zip(tx, ty, strict=True) if p != q]
        if len(tokens) == 1 and {tokens[0][0], tokens[0][1]} == {"l", "r"}:
            return -1 if tokens[0][0] == "l" else 1
    return None


def _side_by_number(a: str, b: str) -> int | None:
    """Return -1 when namespace ``a`` is the lower-numbered of ``b`` (left), 1 when higher.

    The two namespaces must differ in exactly one ``/`` segment, by one number
    (``cam0``/``cam1``, ``infra1``/``infra2``); None otherwise.
    """
    names = _the_differing_name(a, b)
    if names is None:
        return None
    x, y = names
    mx, my = re.fullmatch(r"(.*?)(\d+)(\D*)", x), re.fullmatch(r"(.*?)(\d+)(\D*)", y)
    if mx and my and mx.group(1) == my.group(1) and mx.group(3) == my.group(3):
        nx, ny = int(mx.group(2)), int(my.group(2))
        if nx != ny:
            return -1 if nx < ny else 1
    return None


def _not_numbered_sides(
    a: list[Camera],
    b: list[Camera],
    tx_of: Callable[[str], float | None] | None,
    uncalibrated: Callable[[str], bool] | None = None,
) -> str | None:
    """Return why two cameras numbered alike are not the sides of one pair, None if they may be.

    ``/robot1/stereo/left`` and ``/robot2/stereo/left`` are the left cameras of two heads (a
    name they share says the side); ``/camera1`` and ``/camera2`` whose infos both have
    Tx = P[0, 3] = 0 have no baseline: two monocular cameras (a stereo pair's right info has
    Tx = -fx * baseline).

    Args:
        a: the streams of one namespace.
        b: the streams of the other.
        tx_of: info topic -> its P[0, 3] (None: the infos are not looked at).
        uncalibrated: info topic -> its K and P are all zero (a driver without a
            calibration): said first, the fix being a calibration, not ``--baseline``.
    """
    ns_a, ns_b = a[0].namespace, b[0].namespace
    for x, y in zip(ns_a.split("/"), ns_b.split("/"), strict=True):
        # a word of its own: "camera_left", "leftcam", not "bright"
        word = re.search(r"(?:^|[^a-z])(left|right)", x.lower())
        if x == y and word is not None:
            return f"{ns_a} and {ns_b} are the {word.group(1)} cameras of two heads"
    if tx_of is None or a[0].info is None or b[0].info is None:
        return None
    tx_a, tx_b = tx_of(a[0].info), tx_of(b[0].info)
    if tx_a == 0 and tx_b == 0 and uncalibrated is not None:
        if uncalibrated(a[0].info) and uncalibrated(b[0].info):
            return (
                f"{ns_a} and {ns_b} {UNCALIBRATED} (all-zero K and P on both camera infos, "
                "as a driver without a calibration publishes them)"
            )
    if tx_a == 0 and tx_b == 0:
        return (
            f"{ns_a} and {ns_b} have no baseline (Tx = P[0, 3] = 0 on both camera infos, as "
            "two monocular cameras have)"
        )
    return None


def _pair_count(left: Camera, right: Camera) -> int | None:
    """Return how many pairs two streams can make at most (None: a count is not known)."""
    if left.count is None or right.count is None:
        return None
    return min(left.count, right.count)


def _best_streams(
    left: list[Camera],
    right: list[Camera],
    encoding_of: Callable[[str], str | None] | None = None,
) -> tuple[Camera, Camera, str] | None:
    """Return the preferred streams of two cameras (of one image), and a note on those passed.

    :func:`stream_score` decides, but a stream pair that holds clearly fewer images than
    another (a ``stereo_image_proc`` started late: 3 rectified pairs of 12 raw ones) comes
    after it; the note says so ("" when nothing of the kind was passed over). With
    ``encoding_of`` (image topic -> its first image's encoding) and more than one stream
    pair, a stream whose images are no camera images (``32FC1`` depth) comes last.
    """
    candidates = [(c, p) for c in left for p in right if p.image == c.image]
    if not candidates:
        return None
    if encoding_of is not None and len(candidates) > 1:
        cameras_ = [(c, p) for c, p in candidates if _camera_images(c, p, encoding_of)]
        candidates = cameras_ or candidates
    counts = [_pair_count(c, p) for c, p in candidates]
    most = max((n for n in counts if n is not None), default=None)

    def full(n: int | None) -> bool:
        return n is None or most is None or n >= most - max(2, most // 10)

    best: tuple[tuple[int, ...], Camera, Camera, int | None] | None = None
    for (cam, partner), n in zip(candidates, counts, strict=True):
        score = (int(full(n)), *stream_score(cam, partner))
        if best is None or score > best[0]:
            best = (score, cam, partner, n)
    assert best is not None
    _, cam, partner, n = best
    passed = [
        (c, p, m)
        for (c, p), m in zip(candidates, counts, strict=True)
        if not full(m) and stream_score(c, p) > stream_score(cam, partner)
    ]
    note = ""
    if passed:
        c, p, m = passed[0]
        note = (
            f"{c.topic} and {p.topic} hold {m} image pair{'s' * (m != 1)} at most, these "
            f"{n}: --left-topic {c.topic} reads those"
        )
    return cam, partner, note


def _camera_images(left: Camera, right: Camera, encoding_of: Callable[[str], str | None]) -> bool:
    """Return False when a stream pair's first raw images have an encoding no camera has."""
    for cam in (left, right):
        encoding = None if cam.compressed else encoding_of(cam.topic)
        if encoding is not None and encoding not in rosmsg.CAMERA_IMAGE_ENCODINGS:
            return False
    return True


def find_pairs(
    topics: dict[str, TopicInfo],
    *,
    need_info: bool = True,
    tx_of: Callable[[str], float | None] | None = None,
    encoding_of: Callable[[str], str | None] | None = None,
    uncalibrated: Callable[[str], bool] | None = None,
    baseline_given: bool = False,
    rejected: list[str] | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
    camera_kind: Callable[[str, bool], str | None] | None = None,
    skipped: list[Camera] | None = None,
) -> list[StereoTopics]:
    """Return the stereo pairs of a log, best first (see the module docstring).

    A stream whose name says depth (:attr:`Camera.not_camera`) is no camera, unless a side
    names it, or no pair is found without such streams and its first image is a camera
    image (``camera_kind``: a camera of the log named ``/robot/depth_cam0``): the pair then
    says so in its note.

    Two cameras numbered alike (``cam0``/``cam1``) are not a pair when a name they share
    says their side (``/robot1/stereo/left`` and ``/robot2/stereo/left``) or, without
    calibration files and ``--baseline``, when both infos have Tx = 0 (two monocular
    ``/camera1`` and ``/camera2``).

    Args:
        topics: the log's topics.
        need_info: cameras need a sibling ``camera_info`` (False with calibration files).
        tx_of: info topic -> its P[0, 3] (read from the log), for names that say nothing.
        encoding_of: image topic -> its first image's encoding (read from the log): of a
            camera's streams, those of no camera image (``32FC1``) come last.
        uncalibrated: info topic -> its K and P are all zero (said in ``rejected``).
        baseline_given: ``--baseline`` was given (two infos with Tx = 0 may be a pair).
        rejected: given, it takes why cameras numbered alike were not taken for a pair.
        left_topic: only the pairs whose left stream is this one (a side named).
        right_topic: only the pairs whose right stream is this one.
        camera_kind: (image topic, compressed) -> its first image's encoding or format
            when a camera image (None: depth, or not known), from
            :func:`stream_kinds.camera_images`; None: depth-named streams never come back.
        skipped: given, it takes the depth-named streams left out when no pair is found.
    """
    streams = cameras(topics, need_info=need_info)
    sides = (left_topic, right_topic)
    # depth, disparity, ... streams are no camera, unless one is named (its partner is one)
    if any(c.not_camera and c.topic in sides for c in streams):
        return _pairs_of(
            streams, need_info, tx_of, encoding_of, uncalibrated, baseline_given, rejected, sides
        )
    depth = [c for c in streams if c.not_camera]
    cams = [c for c in streams if not c.not_camera]
    reasons: list[str] = []
    pairs = _pairs_of(
        cams, need_info, tx_of, encoding_of, uncalibrated, baseline_given, reasons, sides
    )
    back: dict[Camera, str | None] = {}
    if not pairs and camera_kind is not None:  # read only then: the first image of each
        back = {c: camera_kind(c.topic, c.compressed) for c in depth}
    if any(back.values()):  # the only pair: cameras named depth_cam0, ... (not depth images)
        pairs = _pairs_of(
            cams + [c for c in depth if back[c]],
            need_info,
            tx_of,
            encoding_of,
            uncalibrated,
            baseline_given,
            reasons,
            sides,
        )
        pairs = [_say_depth_named(p, back) for p in pairs]
    if rejected is not None:
        rejected.extend(reasons)
    if not pairs and skipped is not None:
        skipped.extend(depth)
    return pairs


def _say_depth_named(pair: StereoTopics, kinds: dict[Camera, str | None]) -> StereoTopics:
    """Return ``pair`` with a note on its streams whose name says depth (taken: no other)."""
    named = [c for c in (pair.left, pair.right) if c in kinds]
    if not named:
        return pair
    said = ", ".join(f"{c.topic} ({kinds[c]})" for c in named)
    note = f"{said} taken though named like depth: their images are camera images, no other pair"
    return dataclasses.replace(pair, note="; ".join(n for n in (pair.note, note) if n))


def _pairs_of(
    streams: list[Camera],
    need_info: bool,
    tx_of: Callable[[str], float | None] | None,
    encoding_of: Callable[[str], str | None] | None,
    uncalibrated: Callable[[str], bool] | None,
    baseline_given: bool,
    rejected: list[str] | None,
    sides: tuple[str | None, str | None],
) -> list[StereoTopics]:
    """Return the stereo pairs of ``streams``, best first (the arguments of :func:`find_pairs`)."""
    left_topic, right_topic = sides
    by_ns: dict[str, list[Camera]] = {}
    for cam in streams:
        by_ns.setdefault(cam.namespace, []).append(cam)
    spaces = sorted(by_ns)
    pairs: list[StereoTopics] = []
    for i, a in enumerate(spaces):
        for b in spaces[i + 1 :]:
            side = _side_by_name(a, b)
            how, closeness = "by name", BY_NAME
            if side is None and (side := _side_by_number(a, b)) is not None:
                check_tx = tx_of if need_info and not baseline_given else None
                reason = _not_numbered_sides(by_ns[a], by_ns[b], check_tx, uncalibrated)
                if reason is not None:
                    side = None
                    if rejected is not None:
                        rejected.append(reason)
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
            lefts = [c for c in by_ns[left_ns] if left_topic in (None, c.topic)]
            rights = [c for c in by_ns[right_ns] if right_topic in (None, c.topic)]
            best = _best_streams(lefts, rights, encoding_of)
            if best is not None:
                pairs.append(StereoTopics(best[0], best[1], how, closeness, best[2]))
    pairs.sort(key=StereoTopics.preference, reverse=True)
    return _without_crossed_kinds(pairs)


def _without_crossed_kinds(pairs: list[StereoTopics]) -> list[StereoTopics]:
    """Return ``pairs`` without the ones of two kinds of stream of one head.

    ``/zed/zed_node/left/color/rect`` and ``/zed/zed_node/right/gray/raw`` (the ZED wrapper
    5.x's streams) pair by Tx, but each camera has its partner of its own kind by name: a
    pair by Tx whose namespaces first differ in a name that says the side, both of whose
    cameras pair by name, is dropped (two heads, ``/front/left`` + ``/rear/right``, stay).
    """
    by_name = {c.namespace for p in pairs if p.how == "by name" for c in (p.left, p.right)}

    def crossed(pair: StereoTopics) -> bool:
        a, b = pair.left.namespace.split("/"), pair.right.namespace.split("/")
        if pair.how == "by name" or not {pair.left.namespace, pair.right.namespace} <= by_name:
            return False
        k = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), 0)
        return _side_by_name("/".join(a[: k + 1]), "/".join(b[: k + 1])) is not None

    return [p for p in pairs if not crossed(p)]


def head(pair: StereoTopics) -> str:
    """Return the namespace of a pair's stereo camera: the names its two sides share first.

    ``/zed/zed_node`` of ``/zed/zed_node/left`` + ``/zed/zed_node/right`` and of
    ``/zed/zed_node/left_raw`` + ``/zed/zed_node/right_raw`` (two streams of one camera);
    ``/front`` and ``/rear`` of a robot's two heads.
    """
    a, b = pair.left.namespace.split("/"), pair.right.namespace.split("/")
    k = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))
    return "/".join(a[:k])


def _ties(pairs: list[StereoTopics]) -> list[StereoTopics]:
    """Return the pairs (best first) that are equally good: the best of each stereo camera.

    The stream preference (rectified, one transport, uncompressed, grey: :func:`stream_score`)
    chooses among the streams of one camera (:func:`head`), never between two cameras: the
    best pairs of two heads of equal closeness tie whatever their streams (a ZED's colour
    ``image_rect_color`` and a RealSense's grey ``infra1/image_rect_raw``; a front head with
    ``image_raw`` only and a rear one with ``image_rect``); two pairs of one camera tie
    when their streams are alike too.
    """
    best: dict[str, StereoTopics] = {}  # pairs come best first
    ties = []
    for pair in pairs:
        if pair.closeness != pairs[0].closeness:
            continue
        first = best.setdefault(head(pair), pair)
        if pair.preference() == first.preference():
            ties.append(pair)  # two pairs of one camera alike tie too
    return ties


def resolve_pairing(
    reader: LogReader, config: PairingConfig, echo: Callable[[str], None] | None = None
) -> PairingConfig:
    """Return ``config`` with the topics of the log's stereo pair when none were named.

    With ``config.discover`` set, an image topic of ``config.named_sides`` or other than the
    default one (one side named on the command line) keeps only the pairs with it; an info
    topic of ``config.named_infos`` or other than the default one stays (named). With
    ``config.discover`` unset, the named topics are kept, each image with its own camera
    info unless its info topic was named (:func:`_named_infos`).

    A Kalibr camchain whose cam1 is the left camera (Kalibr numbers the cameras in its
    ``--topics`` order) is said in a line of its own before the topics line; a right camera
    info without Tx, the baseline in ``/tf_static``, in one after it (:mod:`tf_baseline`).

    Raises:
        TopicNotFoundError: no pair, or two equally good pairs (listing them and the options).
    """
    order = camchain_order(config)
    if order and echo is not None:
        echo(order)
    resolved = _resolve(reader, config, echo)
    _refuse_no_camera_images(reader, resolved)
    if echo is not None and (line := tf_baseline_line(reader, resolved)):
        echo(line)  # the right info has no Tx: the baseline /tf_static gives, quoted
    return resolved


def _refuse_no_camera_images(reader: LogReader, config: PairingConfig) -> None:
    """Raise when a side's first image is no camera image and its camera has other streams.

    ``--left-topic /isaac/left/depth`` (``32FC1``) beside ``/isaac/left/rgb``: the error
    names the camera's other streams (the images would be refused later, with no word on
    them).

    Raises:
        TopicNotFoundError: a side's first image has an encoding no camera image has, and
            its namespace has other image streams (named in the message).
    """
    topics = reader.topics()
    encoding_of = first_encoding(reader)
    images = [c for c in cameras(topics, need_info=False) if not c.compressed]
    for side, topic in (("left", config.left_topic), ("right", config.right_topic)):
        encoding = encoding_of(topic) if topic in topics else None
        if encoding is None or encoding in rosmsg.CAMERA_IMAGE_ENCODINGS:
            continue
        ns = namespace(topic)
        others = [
            c.topic
            for c in images
            if c.namespace == ns and c.topic != topic and not c.not_camera
            if encoding_of(c.topic) in rosmsg.CAMERA_IMAGE_ENCODINGS
        ]
        if not others:
            continue
        raise TopicNotFoundError(
            f"the {side} images ({topic}) are {encoding}, no camera images (a depth or "
            f"disparity stream?); the camera's image stream{'s' * (len(others) > 1)}: "
            f"{', '.join(others)}: pass --{side}-topic {others[0]} (and its partner)"
        )


def _resolve(
    reader: LogReader, config: PairingConfig, echo: Callable[[str], None] | None
) -> PairingConfig:
    """Return ``config`` with the topics of the log's stereo pair (:func:`resolve_pairing`)."""
    topics = reader.topics()
    if not config.discover:
        return _named_infos(topics, config, echo, str(reader.path))
    named_left = "left" in config.named_sides or config.left_topic != DEFAULT_LEFT_IMAGE
    named_right = "right" in config.named_sides or config.right_topic != DEFAULT_RIGHT_IMAGE
    name = str(reader.path)
    absent = ""  # the calibration file's topics the log has not
    if config.calibration_topics is not None:
        cal_left, cal_right = config.calibration_topics
        left = config.left_topic if named_left else cal_left
        right = config.right_topic if named_right else cal_right
        source = calibration_file(config)
        if left == right:
            raise PcaInterpError(one_topic_both_sides(left, named_left, named_right, config))
        images = {t for t, i in topics.items() if i.msgtype in _IMAGE_TYPES}
        if left in images and right in images:
            if echo is not None:
                echo(f"topics: left {left}, right {right} (the rostopics of {source})")
            return dataclasses.replace(config, discover=False, left_topic=left, right_topic=right)
        missing = [t for t in (cal_left, cal_right) if t not in images]
        absent = (
            f"the rostopic{'s' * (len(missing) > 1)} of {source} ({', '.join(missing)}) "
            f"{'are' if len(missing) > 1 else 'is'} not in {name}"
        )
    try:
        return _discover(
            reader, config, echo, named_left=named_left, named_right=named_right, note=absent
        )
    except TopicNotFoundError as err:
        if not absent:
            raise
        raise TopicNotFoundError(f"{absent}; {err}") from None


def _named_infos(
    topics: dict[str, TopicInfo],
    config: PairingConfig,
    echo: Callable[[str], None] | None,
    name: str = "the log",
) -> PairingConfig:
    """Return ``config`` (image topics named) with each image's own camera info.

    An info topic not named becomes the image's own (:func:`info_topic_of`: below the image,
    else its sibling) whenever the log has one, the default ``/stereo/...`` ones too (a
    second head named beside a ``/stereo`` one); the default stays only for an image without
    one. An info topic named (``config.named_infos``, the default name included: the row
    check's advice for swapped images names the recorded infos) or other than the default
    is kept. With image topics named on the command line (``config.named_sides``), both in
    the log, and no calibration files, a line says which infos were taken and why (and when
    both images took their namespace's one ``camera_info``, that it gives no baseline).
    """
    infos: dict[str, str] = {}
    why: dict[str, str] = {}
    for side, image, info, default in (
        ("left", config.left_topic, config.left_info_topic, DEFAULT_LEFT_INFO),
        ("right", config.right_topic, config.right_info_topic, DEFAULT_RIGHT_INFO),
    ):
        own = info_topic_of(image, topics)
        if side in config.named_infos or info != default:
            infos[side], why[side] = info, f"--{side}-info-topic"
        elif own is not None:
            infos[side], why[side] = own, "own"
        else:
            infos[side], why[side] = info, f"the default, {image} has no camera_info of its own"
    resolved = dataclasses.replace(
        config, left_info_topic=infos["left"], right_info_topic=infos["right"]
    )
    images = (config.left_topic, config.right_topic)
    missing = [
        infos[side]
        for side in ("left", "right")
        if why[side] != f"--{side}-info-topic" and topics.get(infos[side]) is None
    ]
    if config.calibration is None and missing and all(image in topics for image in images):
        raise no_infos_error(topics, name, images, missing)
    if echo is None or not config.named_sides or config.calibration is not None:
        return resolved
    if not all(image in topics for image in images):
        return resolved  # refused as missing, with the options
    named = "both named" if len(config.named_sides) > 1 else f"{config.named_sides[0]} named"
    if set(why.values()) == {"own"} and infos["left"] == infos["right"]:
        said = shared_info(topics, infos["left"], config.baseline is None)
    elif set(why.values()) == {"own"}:
        said = "each image with its own camera_info"
    else:
        said = "; ".join(
            f"{side}: {'its own camera_info' if how == 'own' else how}" for side, how in why.items()
        )
    echo(
        f"topics: left {images[0]}, right {images[1]} with {infos['left']} and "
        f"{infos['right']} ({named}; {said})"
    )
    return resolved


def _discover(
    reader: LogReader,
    config: PairingConfig,
    echo: Callable[[str], None] | None,
    *,
    named_left: bool,
    named_right: bool,
    note: str = "",
) -> PairingConfig:
    """Return ``config`` with the pair found in the log (:func:`resolve_pairing`).

    Args:
        reader: the log.
        config: the pairing asked for (``discover``).
        echo: given the line that says which pair was found.
        named_left: the left image topic was named.
        named_right: the right one was.
        note: said in that line too (the calibration file's topics the log has not).
    """
    topics = reader.topics()
    name = str(reader.path)
    need_info = config.calibration is None
    named = named_left or named_right
    rejected: list[str] = []
    skipped: list[Camera] = []
    # a side was named: only the pairs with it
    pairs = find_pairs(
        topics,
        need_info=need_info,
        tx_of=first_tx(reader),
        encoding_of=first_encoding(reader),
        uncalibrated=first_uncalibrated(reader),
        baseline_given=config.baseline is not None,
        rejected=rejected,
        left_topic=config.left_topic if named_left else None,
        right_topic=config.right_topic if named_right else None,
        camera_kind=camera_images(reader),
        skipped=skipped,
    )
    if not pairs and need_info and not reader.damage:  # cameras by name, but no infos?
        bare = find_pairs(
            topics,
            need_info=False,
            left_topic=config.left_topic if named_left else None,
            right_topic=config.right_topic if named_right else None,
        )
        live = [t for t, i in topics.items() if i.msgtype == rosmsg.CAMERA_INFO and i.message_count]
        if bare and not live:
            images = (bare[0].left.topic, bare[0].right.topic)
            raise no_infos_error(topics, name, images, [])
    if named and not pairs and not (named_left and named_right):
        side, topic = ("left", config.left_topic) if named_left else ("right", config.right_topic)
        if topic in topics and topics[topic].msgtype in _IMAGE_TYPES:
            said = named_side_by_side(reader, topic, side)
            if said is not None:  # its other side is a default never named
                raise TopicNotFoundError(said)
    if named and not pairs:  # the named topic is missing, of another type, or has no partner
        if config.calibration_topics is not None:
            side = "left" if named_left else "right"
            topic = config.left_topic if named_left else config.right_topic
            raise TopicNotFoundError(
                f"{topic} (--{side}-topic) has no partner camera in {name}: pass "
                "--left-topic and --right-topic both"
            )
        return _resolve(reader, dataclasses.replace(config, discover=False), echo)
    if not pairs and (reader.damage or all(info.message_count == 0 for info in topics.values())):
        return dataclasses.replace(config, discover=False)  # the defaults: reported as damaged
    if not pairs:
        raise no_pair_error(
            reader, need_info=need_info, named=named, rejected=rejected, skipped=skipped
        )
    best = pairs[0]
    ties = _ties(pairs)
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
        # an info topic named (the default name too) or other than the default one stays
        if left_info == DEFAULT_LEFT_INFO and "left" not in config.named_infos:
            left_info = best.left.info
        if right_info == DEFAULT_RIGHT_INFO and "right" not in config.named_infos:
            right_info = best.right.info
    if echo is not None:  # the line names the infos read
        best = dataclasses.replace(
            best,
            left=dataclasses.replace(best.left, info=left_info if best.left.info else None),
            right=dataclasses.replace(best.right, info=right_info if best.right.info else None),
            note="; ".join(n for n in (note, best.note) if n),
        )
        echo(found_line(best, len(pairs) - 1, named_left=named_left, named_right=named_right))
    return dataclasses.replace(
        config,
        discover=False,
        left_topic=best.left.topic,
        right_topic=best.right.topic,
        left_info_topic=left_info,
        right_info_topic=right_info,
    )
