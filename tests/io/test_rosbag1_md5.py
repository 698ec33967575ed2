"""ROS 1 connections whose md5sum disagrees with a whole definition; counts per topic (16c).

Before (review 16c R1): a topic whose definition is whole and decodes its messages, but
whose md5sum field is wrong (a writer that computed it wrongly), was left out as "its
messages cannot be decoded"; rosbag reads such a topic with the stored definition. R4: a
topic on two connections said "4 of the 1 messages on /bad do not convert". R5: every
connection's definition was parsed anew at every open.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer

from pcainterp_stream.io import rosbags_reader, rosmsg
from pcainterp_stream.io.logreader import open_log

LEFT = "/stereo/left/image_rect"
WRONG_MD5 = "0123456789abcdef0123456789abcdef"


def _bag(path: Path, *, left_md5: str | None = None, bad: tuple[int, int] = (0, 0)) -> Path:
    """6 images on LEFT (md5sum ``left_md5`` if given); ``bad``: 1-byte Int32 messages on
    /bad from two connections (callerids /a and /b)."""
    store = rosmsg.TYPESTORE
    rng = np.random.default_rng(3)
    writer = Ros1Writer(path)
    writer.chunk_threshold = 100
    with writer:
        msgdef, md5sum = store.generate_msgdef(rosmsg.IMAGE, ros_version=1)
        left = writer.add_connection(LEFT, rosmsg.IMAGE, msgdef=msgdef, md5sum=left_md5 or md5sum)
        int_def, int_md5 = store.generate_msgdef("std_msgs/msg/Int32", ros_version=1)
        senders = [
            writer.add_connection(
                "/bad", "std_msgs/msg/Int32", msgdef=int_def, md5sum=int_md5, callerid=caller
            )
            for caller in ("/a", "/b")
        ]
        queue = [senders[0]] * bad[0] + [senders[1]] * bad[1]
        for i in range(6):
            stamp = 1_000_000_000 + i * 100_000_000
            image = rng.integers(0, 256, (24, 32), dtype=np.uint8)
            data = store.cdr_to_ros1(
                rosmsg.serialize(rosmsg.image_message(image, stamp, "left")), rosmsg.IMAGE
            )
            writer.write(left, stamp, data)
            if i < len(queue):
                writer.write(queue[i], stamp + 1, b"\x01")
    return path


def test_a_whole_definition_with_a_wrong_md5sum_is_read_with_a_warning(tmp_path: Path) -> None:
    """Before: LEFT left out ("cannot be decoded"): 0 images, densify "no stereo pair"."""
    with open_log(_bag(tmp_path / "md5.bag", left_md5=WRONG_MD5)) as reader:
        raws = list(reader.messages())
        assert [r.topic for r in raws] == [LEFT] * 6
        assert reader.damage == []
        (warning,) = reader.warnings
    _, right_md5 = rosmsg.TYPESTORE.generate_msgdef(rosmsg.IMAGE, ros_version=1)
    assert warning == (
        f"md5.bag: {LEFT}: the bag's definition of sensor_msgs/msg/Image has md5sum "
        f"{right_md5}, not the {WRONG_MD5} recorded; read with the bag's definition (a message "
        "it does not fit is counted as damage)"
    )


def test_a_topic_on_two_connections_is_counted_as_one(tmp_path: Path) -> None:
    """Before: "4 of the 1 messages on /bad do not convert" (the last connection's total)."""
    with open_log(_bag(tmp_path / "bad2.bag", bad=(3, 1))) as reader:
        raws = list(reader.messages())
        assert [r.topic for r in raws] == [LEFT] * 6
        (line,) = reader.damage
    assert line.startswith("bad2.bag: 4 of the 4 messages on /bad do not convert (")


def test_each_definition_is_parsed_once_whatever_the_connections_and_opens(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: one parse per connection per open (300 connections: open twice as slow)."""
    bag = _bag(tmp_path / "two.bag", bad=(1, 1))
    rosbags_reader._judge_definition.cache_clear()
    parsed: list[str] = []
    build = rosbags_reader._store_from_msg

    def counting(text: str, typename: str, **kwargs: Any) -> Any:
        parsed.append(typename)
        return build(text, typename, **kwargs)

    monkeypatch.setattr(rosbags_reader, "_store_from_msg", counting)
    for _ in range(3):
        with open_log(bag) as reader:
            assert "/bad" in reader.topics()
    assert sorted(parsed) == ["sensor_msgs/msg/Image", "std_msgs/msg/Int32"]
