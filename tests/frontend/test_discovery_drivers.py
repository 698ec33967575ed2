"""The stereo pair found in the topic layouts of simulators and drivers (bug hunt 10C)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.errors import TopicNotFoundError
from pcainterp_stream.frontend.discovery import find_pairs, resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.reader_base import TopicInfo


def _topics(*names: str) -> dict[str, TopicInfo]:
    out = {}
    for name in names:
        kind = rosmsg.CAMERA_INFO if name.endswith("camera_info") else rosmsg.IMAGE
        if name.endswith("/compressed"):
            kind = rosmsg.COMPRESSED_IMAGE
        out[name] = TopicInfo(name, kind, 10, "cdr", "ros2msg")
    return out


class _Reader:
    """A log whose images have the encodings of ``encodings`` (topic -> encoding)."""

    def __init__(self, topics: dict[str, TopicInfo], encodings: dict[str, str]) -> None:
        self._topics = topics
        self._encodings = encodings
        self.path = Path("sim.mcap")
        self.damage: list[str] = []

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def messages(self, topics: Any = None) -> Any:
        return iter([SimpleNamespace(topic=t) for t in topics or () if t in self._encodings])

    def decode(self, raw: Any) -> Any:
        return SimpleNamespace(encoding=self._encodings[raw.topic])


def _isaac() -> dict[str, TopicInfo]:
    """Isaac Sim's camera helper: ``rgb``, ``depth`` and ``camera_info`` in one namespace."""
    ns = "/front_stereo_camera"
    return _topics(
        *(f"{ns}/{side}/{s}" for side in ("left", "right") for s in ("rgb", "depth", "camera_info"))
    )


def _airsim(below: bool) -> dict[str, TopicInfo]:
    """AirSim's ROS wrapper: ``Scene``, ``DepthPlanar``, ... with one camera info per camera.

    ``below``: the info under the image (``Scene/camera_info``, airsim_ros_pkgs 1.3-1.8),
    else beside it (``front_left_custom/camera_info``, after its PR #4511).
    """
    names = []
    for side in ("left", "right"):
        ns = f"/airsim_node/drone_1/front_{side}_custom"
        streams = ("DepthPerspective", "DepthPlanar", "DepthVis", "Scene", "Segmentation")
        names += [f"{ns}/{s}" for s in streams]
        names.append(f"{ns}/Scene/camera_info" if below else f"{ns}/camera_info")
    return _topics(*names)


@pytest.mark.parametrize(
    ("topics", "stream"),
    [(_isaac(), "rgb"), (_airsim(False), "Scene"), (_airsim(True), "Scene")],
    ids=["isaac", "airsim", "airsim_info_below"],
)
def test_a_simulators_depth_stream_is_no_stereo_image(
    topics: dict[str, TopicInfo], stream: str
) -> None:
    # bug hunt 10C F1: `depth` (16UC1) won over `rgb` on "grey" and was densified as grey
    # images; `DepthPlanar` (32FC1) won over `Scene` by sorting first and was refused
    (pair,) = find_pairs(topics)
    assert pair.left.topic.endswith(f"left/{stream}") or pair.left.topic.endswith(
        f"left_custom/{stream}"
    )
    assert pair.right.topic == pair.left.topic.replace("left", "right")
    assert pair.left.info is not None
    assert pair.left.info.endswith("camera_info")


def test_a_depth_stream_named_is_read() -> None:
    # naming a depth stream is the user's choice: its partner is found
    topics = _isaac()
    (pair,) = find_pairs(topics, left_topic="/front_stereo_camera/left/depth")
    assert pair.right.topic == "/front_stereo_camera/right/depth"


def test_a_stream_of_depth_encoding_comes_after_the_camera_images() -> None:
    # a depth stream whose name does not say so: its first image's encoding does
    names = [f"/sim/{side}/{s}" for side in ("left", "right") for s in ("a", "b", "camera_info")]
    topics = _topics(*names)
    encodings = {"/sim/left/a": "32FC1", "/sim/right/a": "32FC1"}
    encodings |= {"/sim/left/b": "rgb8", "/sim/right/b": "rgb8"}
    config = resolve_pairing(_Reader(topics, encodings), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == ("/sim/left/b", "/sim/right/b")
    # without the encodings, `a` sorts first
    assert find_pairs(topics)[0].left.topic == "/sim/left/a"


@pytest.mark.parametrize(
    "streams",
    [("image_mono", "image_rect"), ("image_rect", "image_rect/compressed")],
)
def test_camera_infos_below_their_image_topic_are_found(streams: tuple[str, ...]) -> None:
    # bug hunt 10C F3: the MultiSense driver's `left/image_rect/camera_info`; no pair found
    names = ["/multisense/left/disparity", "/multisense/left/disparity/camera_info"]
    for side in ("left", "right"):
        for s in streams:
            names.append(f"/multisense/{side}/{s}")
            names.append(f"/multisense/{side}/{s.removesuffix('/compressed')}/camera_info")
    (pair,) = find_pairs(_topics(*names))
    assert pair.left.topic == "/multisense/left/image_rect"
    assert pair.left.info == "/multisense/left/image_rect/camera_info"
    assert pair.right.info == "/multisense/right/image_rect/camera_info"


def test_named_image_topics_take_the_camera_info_below_them() -> None:
    # bug hunt 10C F3: naming the image topics blamed /stereo/left/camera_info, a default
    topics = _airsim(True)
    ns = "/airsim_node/drone_1/front_{}_custom"
    named = PairingConfig(
        left_topic=f"{ns.format('left')}/Scene", right_topic=f"{ns.format('right')}/Scene"
    )
    config = resolve_pairing(_Reader(topics, {}), named)  # type: ignore[arg-type]
    assert config.left_info_topic == f"{ns.format('left')}/Scene/camera_info"
    assert config.right_info_topic == f"{ns.format('right')}/Scene/camera_info"


def test_only_depth_streams_are_no_pair() -> None:
    topics = _topics(
        *(f"/cam/{side}/{s}" for side in ("left", "right") for s in ("depth", "camera_info"))
    )
    with pytest.raises(TopicNotFoundError, match=r"no stereo pair found in sim\.mcap"):
        resolve_pairing(_Reader(topics, {}), PairingConfig(discover=True))  # type: ignore[arg-type]


def test_a_named_depth_stream_is_refused_naming_the_camera_streams() -> None:
    # bug hunt 10C F1: "4 undecodable ('32FC1') ...; convert the images to mono8": the `rgb`
    # streams that densify were not named
    ns = "/front_stereo_camera"
    encodings = {f"{ns}/{side}/depth": "32FC1" for side in ("left", "right")}
    encodings |= {f"{ns}/{side}/rgb": "rgba8" for side in ("left", "right")}
    named = PairingConfig(left_topic=f"{ns}/left/depth", right_topic=f"{ns}/right/depth")
    with pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(_Reader(_isaac(), encodings), named)  # type: ignore[arg-type]
    assert str(caught.value) == (
        f"the left images ({ns}/left/depth) are 32FC1, no camera images (a depth or disparity "
        f"stream?); the camera's image stream: {ns}/left/rgb: pass --left-topic "
        f"{ns}/left/rgb (and its partner)"
    )
    # a camera with no other stream: left to the pipeline's own refusal
    alone = {t: i for t, i in _isaac().items() if not t.endswith("/rgb")}
    config = resolve_pairing(_Reader(alone, encodings), named)  # type: ignore[arg-type]
    assert config.left_topic == f"{ns}/left/depth"


class _InfoReader(_Reader):
    """A log whose camera infos have the K and P of ``infos`` (topic -> (k, p))."""

    def __init__(self, topics: dict[str, TopicInfo], infos: dict[str, Any]) -> None:
        super().__init__(topics, {})
        self._infos = infos

    def messages(self, topics: Any = None) -> Any:
        return iter([SimpleNamespace(topic=t) for t in topics or () if t in self._infos])

    def decode(self, raw: Any) -> Any:
        k, p = self._infos[raw.topic]
        return SimpleNamespace(k=np.asarray(k, float), p=np.asarray(p, float))


def test_uncalibrated_infos_are_said_first_with_calibration_as_the_fix() -> None:
    # bug hunt 10C F4: all-zero K, R, P (camera_info_manager without a calibration) were
    # "two monocular cameras ... pass --baseline", a dead end: the real fix is --calibration
    names = [f"/camera/infra{i}/{s}" for i in (1, 2) for s in ("image_rect_raw", "camera_info")]
    zero = {f"/camera/infra{i}/camera_info": ([0.0] * 9, [0.0] * 12) for i in (1, 2)}
    with pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(_InfoReader(_topics(*names), zero), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert str(caught.value) == (
        "no stereo pair found in sim.mcap: /camera/infra1 and /camera/infra2 are not "
        "calibrated (all-zero K and P on both camera infos, as a driver without a calibration "
        "publishes them); calibrate the pair (ROS camera_calibration) and pass --calibration "
        "LEFT.yaml RIGHT.yaml"
    )
    # calibrated monocular infos with Tx = 0 keep the "no baseline" reason
    k = [500.0, 0, 300, 0, 500, 200, 0, 0, 1]
    mono = {t: (k, [500.0, 0, 300, 0, 0, 500, 200, 0, 0, 0, 1, 0]) for t in zero}
    with pytest.raises(TopicNotFoundError, match="have no baseline"):
        resolve_pairing(_InfoReader(_topics(*names), mono), PairingConfig(discover=True))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("left", "right"),
    [
        ("depth_left", "depth_right"),
        ("front_depth_left", "front_depth_right"),
        ("stereo_depth_l", "stereo_depth_r"),
        ("DepthLeft", "DepthRight"),
    ],
)
def test_a_stereo_camera_whose_name_has_depth_in_it_is_found(left: str, right: str) -> None:
    # review 58a R3: /robot/depth_left/image_raw + /robot/depth_right/... (each with its
    # camera_info) were skipped as depth streams: "no stereo pair found"
    names = [f"/robot/{ns}/{s}" for ns in (left, right) for s in ("image_raw", "camera_info")]
    (pair,) = find_pairs(_topics(*names, "/robot/depth/image_raw", "/robot/depth/camera_info"))
    assert pair.left.topic == f"/robot/{left}/image_raw"
    assert pair.right.topic == f"/robot/{right}/image_raw"


def _numbered_depth_cams(encoding: str) -> tuple[dict[str, TopicInfo], dict[str, str]]:
    names = [f"/robot/depth_cam{i}/{s}" for i in (0, 1) for s in ("image_raw", "camera_info")]
    return _topics(*names), {f"/robot/depth_cam{i}/image_raw": encoding for i in (0, 1)}


class _TxReader(_Reader):
    """A log of images of ``encodings`` whose camera infos have the P[0, 3] of ``txs``."""

    def __init__(
        self, topics: dict[str, TopicInfo], encodings: dict[str, str], txs: dict[str, float]
    ) -> None:
        super().__init__(topics, encodings)
        self._txs = txs

    def messages(self, topics: Any = None) -> Any:
        known = self._encodings.keys() | self._txs.keys()
        return iter([SimpleNamespace(topic=t) for t in topics or () if t in known])

    def decode(self, raw: Any) -> Any:
        if raw.topic in self._txs:
            p = [500.0, 0, 300, self._txs[raw.topic], 0, 500, 200, 0, 0, 0, 1, 0]
            return SimpleNamespace(k=np.ones(9), p=np.asarray(p))
        return super().decode(raw)


def test_the_only_pair_named_like_depth_is_read_when_its_images_are_camera_images() -> None:
    # review 58a R3: a name that says depth and no side (`depth_cam0`/`depth_cam1`) is
    # still the log's stereo camera when its images are mono8 and no other pair is there
    topics, encodings = _numbered_depth_cams("mono8")
    txs = {"/robot/depth_cam0/camera_info": 0.0, "/robot/depth_cam1/camera_info": -50.0}
    lines: list[str] = []
    config = resolve_pairing(
        _TxReader(topics, encodings, txs),  # type: ignore[arg-type]
        PairingConfig(discover=True),
        lines.append,
    )
    assert (config.left_topic, config.right_topic) == (
        "/robot/depth_cam0/image_raw",
        "/robot/depth_cam1/image_raw",
    )
    assert "taken though named like depth: their images are camera images" in lines[-1]


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_depth_streams_skipped_are_said_in_the_no_pair_error(encoding: str) -> None:
    # review 58a R3: the error listed the skipped streams as image topics and said nothing
    # of why they were not taken
    topics, encodings = _numbered_depth_cams(encoding)
    txs = {"/robot/depth_cam0/camera_info": 0.0, "/robot/depth_cam1/camera_info": -50.0}
    with pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(_TxReader(topics, encodings, txs), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (
        "; skipped as depth, disparity, segmentation ... streams, their names saying so: "
        f"/robot/depth_cam0/image_raw ({encoding}), /robot/depth_cam1/image_raw ({encoding}) "
        "(a stereo camera named so is read when its topics are named: --left-topic "
        "/robot/depth_cam0/image_raw and its partner's --right-topic); pass --left-topic"
    ) in str(caught.value)


@pytest.mark.parametrize(
    ("name", "depth"),
    [
        ("depth", True),
        ("DepthPlanar", True),
        ("depth_registered", True),
        ("aligned_depth_to_infra1", True),
        ("disparity_image", True),
        ("Segmentation", True),
        ("OpticalFlow", True),
        ("depth_left", False),
        ("stereo_depth_r", False),
        ("DepthRight", False),
        ("image_raw", False),
        ("rgb", False),
    ],
)
def test_a_name_says_depth_only_as_a_word_and_without_a_side(name: str, depth: bool) -> None:
    from pcainterp_stream.frontend.stream_kinds import depth_name

    assert depth_name(name) is depth
