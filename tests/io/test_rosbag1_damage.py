"""Indexed ROS 1 bags with one bad part: the bad part is skipped and counted, the rest read.

Before (bug hunt 16B F5, F6, F12): one message that did not convert or one damaged chunk
ended the read of the whole bag ("unreadable after message N"), a second read failed with
"I/O operation on closed file", and one topic whose definition did not match its md5sum (as
rosserial records it) made rosbags refuse the whole bag with `rosbag reindex` as advice.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Ros1Writer

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=32, height=24, fx=40.0, fy=40.0, cx=16.0, cy=12.0, baseline=0.5)
LEFT = "/stereo/left/image_rect"
EMPTY_MD5 = "d41d8cd98f00b204e9800998ecf8427e"
INT8_MD5 = "27ffa0c9c4b8fb8492252bcad9e5c57b"  # std_msgs/Int8, ROS 1


def _bag(
    path: Path,
    frames: int = 6,
    *,
    compression: bool = False,
    extra: tuple[str, str, str, str, bytes] | None = None,
    short_first: bool = False,
) -> Path:
    """A ROS 1 bag of ``frames`` images, one chunk per frame.

    ``extra``: (topic, type, definition, md5sum, data) of one more message at the third
    frame's time. ``short_first``: the first image cut to 10 bytes.
    """
    store = rosmsg.TYPESTORE
    rng = np.random.default_rng(5)
    writer = Ros1Writer(path)
    if compression:
        writer.set_compression(Ros1Writer.CompressionFormat.BZ2)
    writer.chunk_threshold = 100  # every message ends its chunk
    with writer:
        msgdef, md5sum = store.generate_msgdef(rosmsg.IMAGE, ros_version=1)
        left = writer.add_connection(LEFT, rosmsg.IMAGE, msgdef=msgdef, md5sum=md5sum)
        other = None
        if extra is not None:
            topic, msgtype, definition, digest, _ = extra
            other = writer.add_connection(topic, msgtype, msgdef=definition, md5sum=digest)
        for i in range(frames):
            stamp = 1_000_000_000 + i * 100_000_000
            image = rng.integers(0, 256, (CAMERA.height, CAMERA.width), dtype=np.uint8)
            message = rosmsg.image_message(image, stamp, "left")
            data = store.cdr_to_ros1(rosmsg.serialize(message), rosmsg.IMAGE)
            writer.write(left, stamp, data[:10] if short_first and i == 0 else data)
            if extra is not None and other is not None and i == 2:
                writer.write(other, stamp + 1, extra[4])
    return path


def _read(path: Path) -> tuple[list[Any], list[str], list[str]]:
    with open_log(path) as reader:
        raws = list(reader.messages())
        raws_again = list(reader.messages())
        assert [r.log_time_ns for r in raws_again] == [r.log_time_ns for r in raws]
        return raws, list(reader.damage), list(reader.warnings)


def test_a_message_that_does_not_convert_is_skipped_and_counted(tmp_path: Path) -> None:
    """Before: 0 of 6 images read after the short first one ("unreadable after message 0")."""
    raws, damage, _ = _read(_bag(tmp_path / "short.bag", short_first=True))
    assert [r.topic for r in raws] == [LEFT] * 5
    assert len(damage) == 1, damage
    assert damage[0].startswith(
        f"short.bag: 1 of the 6 messages on {LEFT} do not convert (SerdeError"
    )
    assert damage[0].endswith("; skipped")


def test_an_empty_definition_with_its_own_md5_skips_its_messages_only(tmp_path: Path) -> None:
    """A driver recording an empty definition (md5 of ""): its message fails, not the bag."""
    extra = ("/weird", "std_msgs/msg/Int8", "", EMPTY_MD5, b"\x05")
    raws, damage, _ = _read(_bag(tmp_path / "weird.bag", extra=extra))
    assert [r.topic for r in raws].count(LEFT) == 6
    assert len(damage) == 1
    assert "1 of the 1 messages on /weird do not convert" in damage[0]


def test_a_rosserial_topic_of_a_noetic_type_is_read_with_noetic_definition(
    tmp_path: Path,
) -> None:
    """Before: the whole bag refused (AnyReaderError: hash mismatch; `rosbag reindex` advice)."""
    extra = ("/weird", "std_msgs/msg/Int8", "", INT8_MD5, b"\x05")
    raws, damage, warnings = _read(_bag(tmp_path / "rosserial.bag", extra=extra))
    assert damage == []
    assert [r.topic for r in raws].count(LEFT) == 6
    weird = [r for r in raws if r.topic == "/weird"]
    assert len(weird) == 1
    assert weird[0].data[4:] == b"\x05"
    assert any("/weird" in w and "ROS 1 Noetic's definition" in w for w in warnings), warnings


def test_a_topic_whose_definition_does_not_match_is_left_out_and_named(tmp_path: Path) -> None:
    """A custom type with an empty definition and its real md5sum: that topic alone left out."""
    extra = ("/battery", "my_msgs/msg/Battery", "", "0123456789abcdef0123456789abcdef", b"\x05")
    bag = _bag(tmp_path / "custom.bag", extra=extra)
    raws, damage, _ = _read(bag)
    assert [r.topic for r in raws] == [LEFT] * 6
    assert len(damage) == 1
    assert damage[0].startswith(
        "custom.bag: /battery (1 messages of my_msgs/msg/Battery) left out: its definition "
        f"has md5sum {EMPTY_MD5}, not the 0123456789abcdef0123456789abcdef recorded (it is "
        "empty, as rosserial records it)"
    )
    with open_log(bag) as reader:  # the topic is still listed, with its count
        assert reader.topics()["/battery"].message_count == 1


def test_a_damaged_chunk_is_skipped_and_the_later_chunks_read(tmp_path: Path) -> None:
    """Before: the read ended at the damaged chunk (3 of 6 images); a second read of the
    same reader added "I/O operation on closed file"."""
    bag = _bag(tmp_path / "chunks.bag", compression=True)
    data = bytearray(bag.read_bytes())
    starts = [i for i in range(len(data)) if data.startswith(b"BZh9", i)]
    assert len(starts) == 6
    third = starts[2]
    data[third + 20 : third + 40] = bytes(b ^ 0x5A for b in data[third + 20 : third + 40])
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    raws, damage, _ = _read(bad)
    assert [r.topic for r in raws] == [LEFT] * 5
    assert len(damage) == 1, damage
    assert "chunk at byte" in damage[0]
    assert "its 1 messages skipped" in damage[0]
    assert "closed file" not in " ".join(damage)
