"""The stereo pair found in a log's topics when no topic is named."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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
