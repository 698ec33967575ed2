"""The stereo pair found in a log's topics when no topic is named."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.frontend.discovery import (
    BY_NAME,
    DISTANT,
    SIBLINGS,
    find_pairs,
    resolve_pairing,
)
from pcainterp_stream.frontend.pair_forms import is_rectified_name
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


def _camera(ns: str, *streams: str) -> list[str]:
    return [f"{ns}/{s}" for s in streams] + [f"{ns}/camera_info"]


@pytest.mark.parametrize(
    ("left", "right"),
    [
        ("/stereo/left", "/stereo/right"),
        ("/zed/zed_node/left", "/zed/zed_node/right"),
        ("/kitti/camera_gray_left", "/kitti/camera_gray_right"),
        ("/cam0", "/cam1"),
        ("/camera/infra1", "/camera/infra2"),
        ("/kitti/image_2", "/kitti/image_3"),
        ("/stereo_l", "/stereo_r"),
        ("/multisense/left", "/multisense/right"),
    ],
)
def test_pairs_by_name(left: str, right: str) -> None:
    # given in the order right, left: the names decide
    topics = _topics(*_camera(right, "image_raw"), *_camera(left, "image_raw"), "/imu")
    (pair,) = find_pairs(topics)
    assert pair.left.topic == f"{left}/image_raw"
    assert pair.right.topic == f"{right}/image_raw"
    assert pair.left.info == f"{left}/camera_info"


def test_rectified_stream_preferred_over_raw_and_compressed() -> None:
    streams = ("image_raw", "image_rect", "image_rect/compressed", "image_raw/compressed")
    topics = _topics(*_camera("/s/left", *streams), *_camera("/s/right", *streams))
    pair = find_pairs(topics)[0]
    assert pair.left.topic == "/s/left/image_rect"
    assert pair.right.topic == "/s/right/image_rect"


@pytest.mark.parametrize(
    ("left", "right"),
    [
        ("image_raw/compressed", "image_raw"),
        ("image_rect", "image_rect/compressed"),
        ("image/compressed", "image"),
    ],
)
def test_one_side_compressed_the_other_raw_is_a_pair(left: str, right: str) -> None:
    topics = _topics(*_camera("/cam/left", left), *_camera("/cam/right", right))
    (pair,) = find_pairs(topics)
    assert (pair.left.topic, pair.right.topic) == (f"/cam/left/{left}", f"/cam/right/{right}")


def test_one_transport_on_both_sides_preferred_over_a_mixed_pair() -> None:
    # the left camera has both transports, the right one only the compressed one
    topics = _topics(
        *_camera("/cam/left", "image_raw", "image_raw/compressed"),
        *_camera("/cam/right", "image_raw/compressed"),
    )
    (pair,) = find_pairs(topics)
    assert (pair.left.topic, pair.right.topic) == (
        "/cam/left/image_raw/compressed",
        "/cam/right/image_raw/compressed",
    )
    # both with both: the raw pair, as before
    topics = _topics(*(f"/cam/{side}/image_raw/compressed" for side in ("left", "right")))
    topics |= _topics(*_camera("/cam/left", "image_raw"), *_camera("/cam/right", "image_raw"))
    (pair,) = find_pairs(topics)
    assert (pair.left.topic, pair.right.topic) == ("/cam/left/image_raw", "/cam/right/image_raw")


def test_streams_of_two_images_are_no_pair() -> None:
    # a rectified left and a raw right are two images, whatever their transports
    topics = _topics(
        *_camera("/cam/left", "image_rect/compressed"), *_camera("/cam/right", "image_raw")
    )
    assert find_pairs(topics) == []


def test_image_without_camera_info_is_no_camera_unless_calibrated() -> None:
    topics = _topics("/cam0/image_raw", "/cam1/image_raw")
    assert find_pairs(topics) == []
    (pair,) = find_pairs(topics, need_info=False)
    assert (pair.left.topic, pair.right.topic) == ("/cam0/image_raw", "/cam1/image_raw")


def test_sides_by_the_sign_of_tx() -> None:
    topics = _topics(*_camera("/front/a", "image_raw"), *_camera("/front/b", "image_raw"))
    assert find_pairs(topics) == []
    tx = {"/front/a/camera_info": -80.0, "/front/b/camera_info": 0.0}
    (pair,) = find_pairs(topics, tx_of=tx.get)
    assert pair.left.topic == "/front/b/image_raw"
    assert pair.how == "by the sign of P's Tx"


class _Reader:
    def __init__(self, topics: dict[str, TopicInfo]) -> None:
        self._topics = topics
        self.path = Path("robot.bag")
        self.damage: list[str] = []

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def messages(self, topics: Any = None) -> Any:
        return iter(())


def test_two_equally_good_pairs_are_one_line_listing_them() -> None:
    topics = _topics(
        *_camera("/front/left", "image_raw"),
        *_camera("/front/right", "image_raw"),
        *_camera("/rear/left", "image_raw"),
        *_camera("/rear/right", "image_raw"),
    )
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_Reader(topics), PairingConfig(discover=True))  # type: ignore[arg-type]
    line = str(err.value)
    assert "\n" not in line
    assert "2 stereo pairs in robot.bag are equally good" in line
    assert "--left-topic /front/left/image_raw --right-topic /front/right/image_raw" in line
    assert "--left-topic /rear/left/image_raw" in line


def test_resolve_prints_one_line_and_named_topics_win() -> None:
    topics = _topics(*_camera("/cam/left", "image_raw"), *_camera("/cam/right", "image_raw"))
    said: list[str] = []
    config = resolve_pairing(_Reader(topics), PairingConfig(discover=True), said.append)  # type: ignore[arg-type]
    assert (config.left_topic, config.right_info_topic) == (
        "/cam/left/image_raw",
        "/cam/right/camera_info",
    )
    assert len(said) == 1
    assert said[0].startswith("topics: left /cam/left/image_raw, right /cam/right/image_raw")
    named = PairingConfig(left_topic="/cam/left/image_raw", right_topic="/cam/right/image_raw")
    config = resolve_pairing(_Reader(topics), named)  # type: ignore[arg-type]
    assert config.left_info_topic == "/cam/left/camera_info"  # the sibling, not the default


def test_one_named_side_takes_the_other_from_its_pair() -> None:
    topics = _topics(
        *_camera("/front/left", "image_raw"),
        *_camera("/front/right", "image_raw"),
        *_camera("/rear/left", "image_raw"),
        *_camera("/rear/right", "image_raw"),
    )
    config = PairingConfig(discover=True, left_topic="/rear/left/image_raw")
    config = resolve_pairing(_Reader(topics), config)  # type: ignore[arg-type]
    assert (config.right_topic, config.left_info_topic) == (
        "/rear/right/image_raw",
        "/rear/left/camera_info",
    )


class _TxReader(_Reader):
    """A reader whose camera infos have P[0, 3] = ``tx[topic]`` (the right camera's < 0)."""

    def __init__(self, topics: dict[str, TopicInfo], tx: dict[str, float]) -> None:
        super().__init__(topics)
        self._tx = tx

    def messages(self, topics: Any = None) -> Any:
        return iter([SimpleNamespace(topic=topic) for topic in topics or () if topic in self._tx])

    def decode(self, raw: Any) -> Any:
        p = [500.0, 0.0, 300.0, self._tx[raw.topic], 0.0, 500.0, 200.0, 0.0, 0, 0, 1, 0]
        return SimpleNamespace(p=p)


def _two_heads(first: str = "/front", second: str = "/stereo") -> _TxReader:
    names = [f"{head}/{side}" for head in (first, second) for side in ("left", "right")]
    topics = _topics(*(topic for ns in names for topic in _camera(ns, "image_rect")))
    tx = {f"{ns}/camera_info": -50.0 if ns.endswith("right") else 0.0 for ns in names}
    return _TxReader(topics, tx)


def test_cross_head_pairs_rank_below_the_heads() -> None:
    reader = _two_heads()
    pairs = find_pairs(reader.topics(), tx_of=lambda topic: reader._tx.get(topic))
    heads = [(p.left.topic, p.right.topic) for p in pairs[:2]]
    assert heads == [
        ("/front/left/image_rect", "/front/right/image_rect"),
        ("/stereo/left/image_rect", "/stereo/right/image_rect"),
    ]
    assert [p.closeness for p in pairs] == [BY_NAME, BY_NAME, DISTANT, DISTANT]
    assert {p.how for p in pairs[2:]} == {"by the sign of P's Tx"}


def test_two_heads_are_one_line_listing_only_the_heads() -> None:
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_two_heads(), PairingConfig(discover=True))  # type: ignore[arg-type]
    line = str(err.value)
    assert "2 stereo pairs in robot.bag are equally good" in line
    assert "--left-topic /front/left/image_rect --right-topic /front/right/image_rect" in line
    assert "--left-topic /stereo/left/image_rect --right-topic /stereo/right/image_rect" in line
    assert "--right-topic /stereo/right/image_rect --left-info-topic /front" not in line
    # learn and evaluate discover the pair too: "the one to densify" was densify's word
    assert line.endswith("pass the options of the one to read (its --left-topic alone will do)")


@pytest.mark.parametrize(
    ("named", "expected"),
    [
        ({"left_topic": "/front/left/image_rect"}, "/front/right/image_rect"),
        ({"left_topic": "/stereo/left/image_rect"}, "/stereo/right/image_rect"),
        ({"right_topic": "/front/right/image_rect"}, "/front/left/image_rect"),
        ({"right_topic": "/stereo/right/image_rect"}, "/stereo/left/image_rect"),
    ],
)
def test_one_named_side_takes_its_sibling_not_another_heads_camera(
    named: dict[str, str], expected: str
) -> None:
    said: list[str] = []
    # the command line says which side it named: /stereo/left/image_rect is the default topic
    sides = tuple(field.split("_")[0] for field in named)
    config = PairingConfig(discover=True, named_sides=sides, **named)  # type: ignore[arg-type]
    config = resolve_pairing(_two_heads(), config, said.append)  # type: ignore[arg-type]
    other = config.right_topic if "left_topic" in named else config.left_topic
    assert other == expected
    assert config.left_info_topic == config.left_topic.replace("image_rect", "camera_info")
    assert config.right_info_topic == config.right_topic.replace("image_rect", "camera_info")
    # the other candidate was a cross-head pair with the named side, never asked for
    named_side, found = ("left", "right") if "left_topic" in named else ("right", "left")
    assert said[0].endswith(
        f" (the {found} camera found by name for the {named_side} one named; "
        f"--{found}-topic chooses another)"
    )
    assert "less preferred" not in said[0]


def test_the_line_counts_the_other_pairs_found() -> None:
    # one camera's two stream pairs (the ZED wrapper 4.x's left/right and left_raw/right_raw)
    topics = _topics(
        *_camera("/a/left", "image_rect"),
        *_camera("/a/right", "image_rect"),
        *_camera("/a/left_raw", "image_raw"),
        *_camera("/a/right_raw", "image_raw"),
    )
    said: list[str] = []
    resolve_pairing(_Reader(topics), PairingConfig(discover=True), said.append)  # type: ignore[arg-type]
    assert said == [
        "topics: left /a/left/image_rect, right /a/right/image_rect with /a/left/camera_info "
        "and /a/right/camera_info (found by name; 1 other pair less preferred; "
        "--left-topic/--right-topic choose others)"
    ]  # before: "(found by name (1 other pair(s) less preferred); ..."


@pytest.mark.parametrize(
    ("first", "second"),
    [
        (
            _camera("/a/left", "image_rect") + _camera("/a/right", "image_rect"),
            _camera("/b/left", "image_raw") + _camera("/b/right", "image_raw"),
        ),
        # a ZED's colour stream beside a RealSense's grey one (bug hunt 16G F1)
        (
            _camera("/zed/zed_node/left", "image_rect_color")
            + _camera("/zed/zed_node/right", "image_rect_color"),
            _camera("/camera/infra1", "image_rect_raw")
            + _camera("/camera/infra2", "image_rect_raw"),
        ),
    ],
)
def test_two_cameras_whose_streams_differ_in_kind_are_equally_good(
    first: list[str], second: list[str]
) -> None:
    """Bug hunt 16G F1: the preference among one camera's streams (rectified, grey) chose
    between two cameras silently ("1 other pair less preferred", unnamed)."""
    topics = _topics(*first, *second)
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_Reader(topics), PairingConfig(discover=True))  # type: ignore[arg-type]
    line = str(err.value)
    assert "2 stereo pairs in robot.bag are equally good" in line
    assert f"--left-topic {first[0]} " in line
    assert f"--left-topic {second[0]} " in line
    # either is taken when named
    for named in (first[0], second[0]):
        config = PairingConfig(discover=True, left_topic=named, named_sides=("left",))
        assert resolve_pairing(_Reader(topics), config).left_topic == named  # type: ignore[arg-type]


def test_heads_named_alike_keep_the_pairs_with_a_side_in_one_name() -> None:
    # a RealSense's infra1/infra2 beside a ZED's left/right: two heads, no cross pairs
    names = ["/camera/infra1", "/camera/infra2", "/zed/left", "/zed/right"]
    topics = _topics(*(topic for ns in names for topic in _camera(ns, "image_rect_raw")))
    tx = {f"{ns}/camera_info": -50.0 if ns[-1] in "t2" else 0.0 for ns in names}
    pairs = find_pairs(topics, tx_of=tx.get)
    assert [(p.left.topic, p.closeness) for p in pairs[:2]] == [
        ("/camera/infra1/image_rect_raw", BY_NAME),
        ("/zed/left/image_rect_raw", BY_NAME),
    ]
    assert all(p.closeness == DISTANT for p in pairs[2:])


def test_sides_by_tx_in_one_parent_rank_above_sides_by_tx_across_heads() -> None:
    names = ["/front/a", "/front/b", "/rear/c"]
    topics = _topics(*(topic for ns in names for topic in _camera(ns, "image_raw")))
    tx = {"/front/a/camera_info": 0.0, "/front/b/camera_info": -50.0, "/rear/c/camera_info": -5.0}
    pairs = find_pairs(topics, tx_of=tx.get)
    assert [(p.left.topic, p.right.topic, p.closeness) for p in pairs] == [
        ("/front/a/image_raw", "/front/b/image_raw", SIBLINGS),
        ("/front/a/image_raw", "/rear/c/image_raw", DISTANT),
    ]
    config = resolve_pairing(_TxReader(topics, tx), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == ("/front/a/image_raw", "/front/b/image_raw")


def test_one_head_named_by_number_still_pairs_with_tx() -> None:
    # EuRoC-style names: cam0 is left; with its infos' Tx as well, nothing else competes
    topics = _topics(*_camera("/cam0", "image_raw"), *_camera("/cam1", "image_raw"))
    tx = {"/cam0/camera_info": 0.0, "/cam1/camera_info": -50.0}
    config = resolve_pairing(_TxReader(topics, tx), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == ("/cam0/image_raw", "/cam1/image_raw")
    assert config.right_info_topic == "/cam1/camera_info"


def test_a_camera_in_a_transport_not_decoded_is_not_called_a_one_camera_log() -> None:
    from types import SimpleNamespace

    from pcainterp_stream.errors import TopicNotFoundError
    from pcainterp_stream.frontend.discovery import resolve_pairing
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.io.reader_base import TopicInfo

    kinds = {
        "/cam/left/image_raw": "sensor_msgs/msg/Image",
        "/cam/left/camera_info": "sensor_msgs/msg/CameraInfo",
        "/cam/right/image_raw/ffmpeg": "ffmpeg_image_transport_msgs/msg/FFMPEGPacket",
        "/cam/right/camera_info": "sensor_msgs/msg/CameraInfo",
    }
    topics = {t: TopicInfo(t, kind, 10, "cdr", "ros2msg") for t, kind in kinds.items()}
    reader = SimpleNamespace(
        path="x.mcap", damage=[], topics=lambda: topics, messages=lambda topics=None: iter(())
    )  # no images read: the side-by-side check of the no-pair error finds none
    with pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(reader, PairingConfig(discover=True))  # type: ignore[arg-type]
    assert "one camera" not in str(caught.value)  # the right camera is there, as ffmpeg
    assert str(caught.value).endswith(
        "pass --left-topic and --right-topic (and --calibration LEFT.yaml RIGHT.yaml without "
        "camera infos)"
    )


def _counted(topics: dict[str, TopicInfo], counts: dict[str, int | None]) -> dict[str, TopicInfo]:
    """Return ``topics`` with the message counts of ``counts`` (the others' kept)."""
    return {
        t: TopicInfo(t, i.msgtype, counts.get(t, i.message_count), "cdr", "ros2msg")
        for t, i in topics.items()
    }


def _robots() -> _TxReader:
    names = [f"/robot{n}/stereo/{side}" for n in (1, 2) for side in ("left", "right")]
    topics = _topics(*(topic for ns in names for topic in _camera(ns, "image_raw")))
    tx = {f"{ns}/camera_info": -50.0 if ns.endswith("right") else 0.0 for ns in names}
    return _TxReader(topics, tx)


def test_two_heads_numbered_alike_never_pair_their_left_cameras() -> None:
    # bug hunt 7A F4: /robot1 and /robot2 were read as sides said by a number: the two left
    # cameras were a pair as good as each robot's own
    reader = _robots()
    rejected: list[str] = []
    pairs = find_pairs(reader.topics(), tx_of=reader._tx.get, rejected=rejected)
    by_name = [(p.left.topic, p.right.topic) for p in pairs if p.closeness == BY_NAME]
    assert by_name == [
        ("/robot1/stereo/left/image_raw", "/robot1/stereo/right/image_raw"),
        ("/robot2/stereo/left/image_raw", "/robot2/stereo/right/image_raw"),
    ]
    assert "/robot1/stereo/left and /robot2/stereo/left are the left cameras of two heads" in (
        rejected
    )
    said: list[str] = []
    config = PairingConfig(
        discover=True, left_topic="/robot1/stereo/left/image_raw", named_sides=("left",)
    )
    config = resolve_pairing(reader, config, said.append)  # type: ignore[arg-type]
    assert config.right_topic == "/robot1/stereo/right/image_raw"
    assert config.right_info_topic == "/robot1/stereo/right/camera_info"


def _monos(tx: float = 0.0) -> _TxReader:
    topics = _topics(*_camera("/camera1", "image_raw"), *_camera("/camera2", "image_raw"))
    return _TxReader(topics, {"/camera1/camera_info": 0.0, "/camera2/camera_info": tx})


def test_two_monocular_cameras_numbered_alike_are_no_stereo_pair() -> None:
    # bug hunt 7A F4: /camera1 + /camera2 with Tx = 0 on both were a pair "found by name",
    # then an error advising --baseline: densifying two unrelated cameras
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_monos(), PairingConfig(discover=True))  # type: ignore[arg-type]
    line = str(err.value)
    assert line.startswith(
        "no stereo pair found in robot.bag: /camera1 and /camera2 have no baseline (Tx = "
        "P[0, 3] = 0 on both camera infos, as two monocular cameras have)"
    )
    # review55a F4: the sides of a rectified pair whose infos lack Tx are told --baseline,
    # as an "if" (never advised for two cameras that are no pair)
    assert line.endswith(
        "if they are the two sides of a stereo pair whose infos lack it, name its topics with "
        "--left-topic and --right-topic and pass --baseline METRES (its images rectified) or "
        "its stereo --calibration (raw images)"
    )
    named = PairingConfig(
        left_topic="/camera1/image_raw", right_topic="/camera2/image_raw", baseline=0.5
    )
    assert resolve_pairing(_monos(), named).right_info_topic == "/camera2/camera_info"  # type: ignore[arg-type]
    # a baseline or calibration files given say they are a pair; so does a Tx < 0
    given = PairingConfig(discover=True, baseline=0.5)
    assert resolve_pairing(_monos(), given).left_topic == "/camera1/image_raw"  # type: ignore[arg-type]
    assert find_pairs(_monos().topics(), need_info=False, tx_of=_monos()._tx.get)
    config = resolve_pairing(_monos(-40.0), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == ("/camera1/image_raw", "/camera2/image_raw")


@pytest.mark.parametrize(
    ("left", "right"),
    [("/cam0", "/cam1"), ("/camera/infra1", "/camera/infra2"), ("/bright/cam0", "/bright/cam1")],
)
def test_numbered_pairs_with_a_baseline_still_pair(left: str, right: str) -> None:
    topics = _topics(*_camera(left, "image_rect_raw"), *_camera(right, "image_rect_raw"))
    tx = {f"{left}/camera_info": 0.0, f"{right}/camera_info": -30.0}
    config = resolve_pairing(_TxReader(topics, tx), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == (
        f"{left}/image_rect_raw",
        f"{right}/image_rect_raw",
    )


def test_image_topics_without_messages_are_no_cameras() -> None:
    # bug hunt 7A F10: image_rect channels advertised, never published (count 0), won over
    # the raw pair with every image
    streams = ("image_raw", "image_rect")
    topics = _topics(*_camera("/camera/left", *streams), *_camera("/camera/right", *streams))
    empty = {"/camera/left/image_rect": 0, "/camera/right/image_rect": 0}
    (pair,) = find_pairs(_counted(topics, empty))
    assert (pair.left.topic, pair.right.topic) == (
        "/camera/left/image_raw",
        "/camera/right/image_raw",
    )
    # a count not known (None) is no reason to pass a stream over
    unknown = {t: None for t in topics}
    assert find_pairs(_counted(topics, unknown))[0].left.topic == "/camera/left/image_rect"
    # no image topic with messages: said so
    nothing = _counted(_topics(*_camera("/cam/left", "image_raw")), {"/cam/left/image_raw": 0})
    nothing.update({"/imu": TopicInfo("/imu", "sensor_msgs/msg/Imu", 5, "cdr", "ros2msg")})
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_Reader(nothing), PairingConfig(discover=True))  # type: ignore[arg-type]
    assert "its image topics have no messages (/cam/left/image_raw; see pcainterp info)" in str(
        err.value
    )


@pytest.mark.parametrize(("rect", "chosen"), [(3, "image_raw"), (11, "image_rect")])
def test_a_rectified_stream_with_clearly_fewer_images_gives_way(rect: int, chosen: str) -> None:
    # bug hunt 7A F10: a stereo_image_proc started late (3 rectified pairs of 12) won silently
    streams = ("image_raw", "image_rect")
    topics = _topics(*_camera("/camera/left", *streams), *_camera("/camera/right", *streams))
    counts = {t: rect if "image_rect" in t else 12 for t in topics if "image" in t}
    said: list[str] = []
    config = resolve_pairing(
        _Reader(_counted(topics, counts)),  # type: ignore[arg-type]
        PairingConfig(discover=True),
        said.append,
    )
    assert config.left_topic == f"/camera/left/{chosen}"
    note = (
        "/camera/left/image_rect and /camera/right/image_rect hold 3 image pairs at most, these "
        "12: --left-topic /camera/left/image_rect reads those"
    )
    assert (note in said[0]) == (chosen == "image_raw")
    # naming the rectified side reads it, whatever its count
    named = PairingConfig(
        discover=True, left_topic="/camera/left/image_rect", named_sides=("left",)
    )
    config = resolve_pairing(_Reader(_counted(topics, counts)), named)  # type: ignore[arg-type]
    assert config.right_topic == "/camera/right/image_rect"


def _camchain(topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw")) -> PairingConfig:
    calibration = SimpleNamespace(left=SimpleNamespace(name="/calib/camchain.yaml:cam0"))
    return PairingConfig(discover=True, calibration=calibration, calibration_topics=topics)  # type: ignore[arg-type]


def test_a_camchains_rostopics_are_the_pair_and_said() -> None:
    # bug hunt 7A F8: the pair taken from a Kalibr camchain was never printed
    topics = _topics("/cam0/image_raw", "/cam1/image_raw", "/imu")
    said: list[str] = []
    config = resolve_pairing(_Reader(topics), _camchain(), said.append)  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic, config.discover) == (
        "/cam0/image_raw",
        "/cam1/image_raw",
        False,
    )
    assert said == [
        "topics: left /cam0/image_raw, right /cam1/image_raw (the rostopics of camchain.yaml)"
    ]


def test_a_camchains_rostopics_not_in_the_log_fall_back_to_the_pair_found() -> None:
    # bug hunt 7A F8: "topic /cam0/image_raw not found ...: set --left-topic", then the same
    # for the right one: topics the user never named, one side at a time
    topics = _topics("/camera/left/image_raw", "/camera/right/image_raw")
    said: list[str] = []
    config = resolve_pairing(_Reader(topics), _camchain(), said.append)  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == (
        "/camera/left/image_raw",
        "/camera/right/image_raw",
    )
    assert (
        "(found by name; the rostopics of camchain.yaml (/cam0/image_raw, /cam1/image_raw) are "
        "not in robot.bag; --left-topic/--right-topic choose others)"
    ) in said[0]
    with pytest.raises(TopicNotFoundError) as err:
        resolve_pairing(_Reader(_topics("/a/image_raw", "/b/image_raw")), _camchain())  # type: ignore[arg-type]
    line = str(err.value)
    assert line.startswith(
        "the rostopics of camchain.yaml (/cam0/image_raw, /cam1/image_raw) are not in robot.bag; "
        "no stereo pair found in robot.bag"
    )
    assert "pass --left-topic and --right-topic" in line


def test_the_zed_wrapper_5_layout_takes_its_rectified_grey_pair() -> None:
    # bug hunt 7A F12: rect/raw and gray/color are names below the side one
    # (/zed/zed_node/left/gray/rect/image): "4 stereo pairs equally good"
    z = "/zed/zed_node"
    kinds = ("color/rect", "gray/rect", "color/raw", "gray/raw")
    names = [f"{z}/{side}/{kind}" for side in ("left", "right") for kind in kinds]
    topics = _topics(*(topic for ns in names for topic in _camera(ns, "image")))
    tx = {f"{ns}/camera_info": (-190.0 if "/right/" in ns else 0.0) for ns in names}
    said: list[str] = []
    reader = _TxReader(topics, tx)
    config = resolve_pairing(reader, PairingConfig(discover=True), said.append)  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == (
        f"{z}/left/gray/rect/image",
        f"{z}/right/gray/rect/image",
    )
    assert "(found by name; 3 other pairs less preferred;" in said[0]
    order = [p.left.topic for p in find_pairs(topics, tx_of=tx.get)]
    ranked = ("gray/rect", "color/rect", "gray/raw", "color/raw")
    assert order == [f"{z}/left/{kind}/image" for kind in ranked]


def test_rect_above_the_side_name_says_nothing() -> None:
    # the names below the side one say rectified; above it (a node's name) they do not
    assert is_rectified_name("/zed/zed_node/left/gray/rect/image")
    assert is_rectified_name("/cam0/rect/image", "/cam1/rect/image")
    assert not is_rectified_name("/rectifier/left/image_raw")
    assert not is_rectified_name("/zed/zed_node/left/gray/raw/image")
    assert not is_rectified_name("/cam0/rect/image")  # no side said, no partner given
    assert not is_rectified_name("/stereo/left/direct/image")


@pytest.mark.parametrize(
    ("topic", "rectified"),
    [
        ("/camera/left/image_rect", True),
        ("/camera/left/image_rect_color", True),
        ("/camera/infra1/image_rect_raw", True),
        ("/stereo/left/rect", True),
        ("/stereo/left/image_rectified", True),
        ("/stereo/left/imageRect", True),
        ("/camera/left/image_rect/compressed", True),
        # bug hunt 15A F3: a substring test took these as rectified (used without a remap)
        ("/camera/left/image_corrected", False),
        ("/camera/left/image_color_corrected", False),
        ("/camera/left/directional", False),
        ("/camera/left/image_raw", False),
        # review 15a R5: words split as stream_kinds splits them (any separator)
        ("/camera/left/image.rect", True),
        ("/camera/left/IMAGE_RECT", True),
    ],
)
def test_the_last_name_says_rectified_by_a_word_not_a_substring(
    topic: str, rectified: bool
) -> None:
    assert is_rectified_name(topic) is rectified


def test_a_camchain_read_with_cam1_left_says_so_in_a_line() -> None:
    # bug hunt 7A F14: a camchain whose cam0 is the right camera (Kalibr numbers the cameras
    # in --topics order) is read with cam1 left (io.calibration names the cameras so)
    left = SimpleNamespace(name="/calib/camchain.yaml:cam1", baseline=lambda right: 0.5372)
    calibration = SimpleNamespace(
        left=left, right=SimpleNamespace(name="/calib/camchain.yaml:cam0")
    )
    topics = ("/cam1/image_raw", "/cam0/image_raw")
    config = PairingConfig(discover=True, calibration=calibration, calibration_topics=topics)  # type: ignore[arg-type]
    said: list[str] = []
    config = resolve_pairing(_Reader(_topics(*topics)), config, said.append)  # type: ignore[arg-type]
    assert (config.left_topic, config.right_topic) == topics
    assert said == [
        "camchain.yaml: cam1 is the left camera (cam0 lies 0.537 m to its right; Kalibr numbers "
        "cameras in --topics order)",
        "topics: left /cam1/image_raw, right /cam0/image_raw (the rostopics of camchain.yaml)",
    ]
    # both sides named: the line still says how the camchain is read
    named = dataclasses.replace(
        config, discover=False, calibration_topics=None, left_topic=topics[0], right_topic=topics[1]
    )
    said.clear()
    resolve_pairing(_Reader(_topics(*topics)), named, said.append)  # type: ignore[arg-type]
    assert len(said) == 1
    assert said[0].startswith("camchain.yaml: cam1 is the left camera")
    said.clear()
    resolve_pairing(_Reader(_topics(*topics[::-1])), _camchain(), said.append)  # type: ignore[arg-type]
    assert len(said) == 1  # cam0 left: nothing more than the topics line


@pytest.mark.parametrize("side", ["left", "right"])
def test_one_side_named_as_the_camchains_other_camera_is_refused(side: str) -> None:
    # review55a F1: --left-topic /cam1/image_raw with a camchain of /cam0, /cam1 paired
    # /cam1/image_raw with itself (then "no stereo pair found ... header stamps")
    other = "/cam1/image_raw" if side == "left" else "/cam0/image_raw"
    config = dataclasses.replace(_camchain(), named_sides=(side,), **{f"{side}_topic": other})
    reader = _Reader(_topics("/cam0/image_raw", "/cam1/image_raw"))
    with pytest.raises(PcaInterpError) as err:
        resolve_pairing(reader, config)  # type: ignore[arg-type]
    named, found = (side, "right" if side == "left" else "left")
    assert str(err.value) == (
        f"--{named}-topic and --{found}-topic are both {other} (--{named}-topic as given, "
        f"--{found}-topic the rostopic of camchain.yaml's {found} camera); a stereo pair "
        f"needs the images of two cameras: pass the {found} camera's topic as --{found}-topic, "
        "or no topic option to read the pair camchain.yaml names (left /cam0/image_raw, "
        "right /cam1/image_raw)"
    )
    # naming the side as the camchain has it is fine; a camchain naming one topic twice is not
    same = dataclasses.replace(_camchain(), named_sides=("left",), left_topic="/cam0/image_raw")
    assert resolve_pairing(reader, same).right_topic == "/cam1/image_raw"  # type: ignore[arg-type]
    twice = _camchain(("/cam0/image_raw", "/cam0/image_raw"))
    with pytest.raises(PcaInterpError, match=r"the rostopics of camchain\.yaml are both /cam0/"):
        resolve_pairing(reader, twice)  # type: ignore[arg-type]


@pytest.mark.parametrize("side_by_side", [True, False])
def test_a_lone_side_by_side_topic_is_told_to_be_split(tmp_path: Path, side_by_side: bool) -> None:
    """Bug hunt 7A: one topic of side-by-side stereo frames (a UVC stereo camera, a ZED
    without its SDK) gets a hint to split it; one wide camera's images do not."""
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.logwriter import open_writer

    rng = np.random.default_rng(5)
    scene = rng.integers(0, 256, (60, 170), np.uint8)
    left, right = scene[:, 4:164], scene[:, 8:168]  # the right view: the scene 4 px on
    if not side_by_side:  # two unrelated halves: a wide scene of one camera
        right = rng.integers(0, 256, (60, 160), np.uint8)
    frame = np.ascontiguousarray(np.hstack([left, right]))  # 320x60
    log = tmp_path / "sbs.mcap"
    with open_writer(log, "mcap") as writer:
        writer.add_message("/usb_cam/image_raw", rosmsg.image_message(frame, 1, "cam"), 1)
    with open_log(log) as reader, pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(reader, PairingConfig(discover=True))
    message = str(caught.value)
    assert "it has one camera (/usb_cam/image_raw; camera infos: none)" in message
    hint = (
        "; its 320x60 images hold two views side by side (their halves show one scene): "
        "pcainterp reads one camera per image topic, so split each image into a left and a "
        "right half on two topics first (with a camera info each)"
    )
    assert message.endswith(hint) == side_by_side
    assert ("side by side (their" in message) == side_by_side
