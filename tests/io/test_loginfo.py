from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.loginfo import LogInfo, describe, format_info, seconds_text
from pcainterp_stream.io.logreader import LogFormat

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"


def write_small(path: Path, n: int = 3) -> None:
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=1)
        writer.start("ros2", "test")
        schema = writer.register_schema(
            "sensor_msgs/msg/Image", "ros2msg", rosmsg.schema_text("sensor_msgs/msg/Image").encode()
        )
        channel = writer.register_channel("/cam", "cdr", schema)
        for i in range(n):
            stamp = 1_000_000_000 + i * 500_000_000
            message = rosmsg.image_message(np.zeros((2, 3), np.uint8), stamp, "c")
            writer.add_message(channel, stamp, rosmsg.serialize(message), stamp)
        writer.finish()


def test_describe_and_format(tmp_path: Path) -> None:
    path = tmp_path / "small.mcap"
    write_small(path)
    info = describe(path)
    assert info.format is LogFormat.MCAP
    assert info.message_count == 3
    assert (info.start_ns, info.end_ns, info.duration_ns) == (1_000_000_000, 2_000_000_000, 10**9)
    assert info.topics["/cam"].message_count == 3
    assert info.counted is False
    assert info.damage == []
    text = format_info(info)
    assert "small.mcap: mcap log" in text
    assert "messages: 3 (from the index)" in text
    assert "duration: 1.000 s" in text
    assert "/cam         3  sensor_msgs/msg/Image" in text
    assert describe(path, count=True).counted is True


def test_describe_damaged_counts_what_is_readable(tmp_path: Path) -> None:
    path = tmp_path / "small.mcap"
    write_small(path, n=4)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 4])
    info = describe(cut)
    assert info.counted is True
    assert 0 < info.message_count < 4
    assert info.topics["/cam"].message_count == info.message_count
    assert info.damage
    assert f"DAMAGE ({len(info.damage)}):" in format_info(info)
    assert len(info.damage) == 2  # no footer, and a chunk cut short


def test_format_prints_epoch_times_exactly(tmp_path: Path) -> None:
    # through a float64 1600000000300000000 ns printed as 1600000000.299999952 s
    info = LogInfo(
        path=tmp_path / "x.mcap",
        format=LogFormat.MCAP,
        topics={},
        message_count=2,
        start_ns=1_585_866_235_112_411_371,
        end_ns=1_600_000_000_300_000_000,
        counted=False,
    )
    text = format_info(info)
    assert "start: 1585866235.112411371 s   end: 1600000000.300000000 s" in text
    assert seconds_text(0) == "0.000000000"
    assert seconds_text(-1_500_000_000) == "-1.500000000"


def test_describe_empty_log(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    write_small(path, n=0)
    info = describe(path)
    assert (info.message_count, info.start_ns, info.duration_ns) == (0, None, 0)
    assert "messages: 0" in format_info(info)


def test_describe_kitti_folder_suggests_import(tmp_path: Path) -> None:
    drive = tmp_path / "2011_09_26_drive_0001_sync"
    (drive / "image_00" / "data").mkdir(parents=True)
    with pytest.raises(
        LogReadError, match=r"is a KITTI folder, not a log; .*pcainterp import-kitti"
    ):
        describe(drive)


def _realdata_paths() -> list[Path]:
    if not REALDATA.is_dir():
        return []
    paths = sorted(REALDATA.glob("mcap_conformance/*/*.mcap"))
    paths += [REALDATA / "mcap_ros2" / "supported_ros2_messages.mcap"]
    paths += sorted(REALDATA.glob("ros1/*.bag"))
    paths += sorted(p.parent for p in REALDATA.glob("rosbag2/*/*/metadata.yaml"))
    paths += sorted(REALDATA.glob("rosbag2/**/*.mcap")) + sorted(REALDATA.glob("rosbag2/**/*.db3"))
    paths += [REALDATA / "rosbag2" / "standalone", REALDATA / "kitti_raw" / "2011_09_26"]
    paths += [REALDATA / "kitti_odometry_clip", REALDATA / "stereo_aloe" / "aloe-L.png"]
    return paths


def _expected_messages(path: Path) -> int | None:
    expected = path.with_suffix(".json")
    if path.suffix != ".mcap" or not expected.is_file():
        return None
    records = json.loads(expected.read_text())["records"]
    return sum(1 for record in records if record["type"] == "Message")


@pytest.mark.realdata
@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real data folder {REALDATA} is absent")
@pytest.mark.parametrize("path", _realdata_paths(), ids=lambda p: str(p.relative_to(REALDATA)))
def test_every_realdata_file_describes_or_fails_in_one_line(path: Path) -> None:
    try:
        info = describe(path)
    except LogReadError as err:
        message = str(err)
        assert "\n" not in message
        assert str(path) in message
        return
    assert format_info(info).startswith(f"{path}: ")
    assert info.damage == []
    expected = _expected_messages(path)
    if expected is not None:  # the conformance suite says how many messages there are
        assert info.message_count == expected
        assert sum(t.message_count or 0 for t in info.topics.values()) == expected


def test_describe_lists_attachments_and_metadata_records(tmp_path: Path) -> None:
    path = tmp_path / "extras.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("ros2", "test")
        writer.add_attachment(2, 1, "robot.urdf", "application/xml", b"<robot/>")
        writer.add_attachment(0, 1, "calibration.bin", "", bytes(3000))
        writer.add_metadata("rosbag2", {"serialized_metadata": "x", "ros_distro": "humble"})
        writer.add_metadata("origin", {"site": "lab"})
        writer.finish()
    info = describe(path)
    assert [(a.name, a.media_type, a.size) for a in info.attachments] == [
        ("robot.urdf", "application/xml", 8),
        ("calibration.bin", "", 3000),
    ]
    assert [(m.name, dict(m.metadata)) for m in info.metadata] == [
        ("rosbag2", {"serialized_metadata": "x", "ros_distro": "humble"}),
        ("origin", {"site": "lab"}),
    ]
    text = format_info(info)  # before: neither was mentioned
    assert "  attachments: 2\n" in text
    assert "    robot.urdf          8 bytes  application/xml\n" in text
    assert "    calibration.bin     2.9 KiB  (no media type)\n" in text
    assert "  metadata records: 2\n    rosbag2  2 keys\n    origin   1 key" in text
    plain = tmp_path / "plain.mcap"
    write_small(plain)
    assert "attachments" not in format_info(describe(plain))
    assert "metadata" not in format_info(describe(plain))


@pytest.mark.realdata
@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real data folder {REALDATA} is absent")
@pytest.mark.parametrize(
    "path",
    sorted(REALDATA.glob("mcap_conformance/One[AM]*/*.mcap")) if REALDATA.is_dir() else [],
    ids=lambda p: p.name,
)
def test_conformance_attachments_and_metadata_are_found(path: Path) -> None:
    records = json.loads(path.with_suffix(".json").read_text())["records"]
    fields = [dict(r["fields"]) for r in records if r["type"] in ("Attachment", "Metadata")]
    info = describe(path)  # with and without summary, indexes, statistics, padding
    assert info.damage == []
    assert [
        (a.name, a.media_type, a.log_time_ns, a.create_time_ns, a.size) for a in info.attachments
    ] == [
        (f["name"], f["media_type"], int(f["log_time"]), int(f["create_time"]), len(f["data"]))
        for f in fields
        if "data" in f
    ]
    assert [(m.name, dict(m.metadata)) for m in info.metadata] == [
        (f["name"], f["metadata"]) for f in fields if "metadata" in f
    ]


def write_two_types(path: Path, images: int = 3, compressed: int = 2) -> None:
    """/cam as sensor_msgs/Image, then (a driver restarted) as CompressedImage: two channels."""
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=1)
        writer.start("ros2", "test")
        channels = {}
        for name in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"):
            schema = writer.register_schema(name, "ros2msg", rosmsg.schema_text(name).encode())
            channels[name] = writer.register_channel("/cam", "cdr", schema)
        for i in range(images + compressed):
            stamp = 1_000_000_000 + i * 100_000_000
            if i < images:
                message = rosmsg.image_message(np.zeros((2, 3), np.uint8), stamp, "c")
                channel = channels["sensor_msgs/msg/Image"]
            else:
                kind = rosmsg.TYPESTORE.types["sensor_msgs/msg/CompressedImage"]
                header = rosmsg.image_message(np.zeros((2, 3), np.uint8), stamp, "c").header
                message = kind(header=header, format="png", data=np.zeros(4, np.uint8))
                channel = channels["sensor_msgs/msg/CompressedImage"]
            writer.add_message(channel, stamp, rosmsg.serialize(message), stamp)
        writer.finish()


@pytest.mark.parametrize("count", [False, True])
def test_topic_recorded_with_two_types_lists_both(tmp_path: Path, count: bool) -> None:
    # a topic whose driver was restarted with compression: info named only the last type
    path = tmp_path / "two.mcap"
    write_two_types(path)
    info = describe(path, count=count)
    topic = info.topics["/cam"]
    assert topic.message_count == 5
    assert topic.types == (("sensor_msgs/msg/Image", 3), ("sensor_msgs/msg/CompressedImage", 2))
    assert "/cam         5  3 sensor_msgs/msg/Image + 2 sensor_msgs/msg/CompressedImage" in (
        format_info(info)
    )


def test_ros1_topic_recorded_with_two_types_lists_both(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "two.bag"
    with Ros1Writer(path) as writer:
        for name, n in (("sensor_msgs/msg/Image", 3), ("sensor_msgs/msg/CompressedImage", 2)):
            connection = writer.add_connection("/cam", name, typestore=store)
            kind = store.types[name]
            header = store.types["std_msgs/msg/Header"](
                seq=0, stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0),
                frame_id="c",
            )
            for i in range(n):
                if name.endswith("/Image"):
                    message = kind(header, 1, 1, "mono8", 0, 1, np.zeros(1, np.uint8))
                else:
                    message = kind(header, "png", np.zeros(1, np.uint8))
                data = store.serialize_ros1(message, name)
                writer.write(connection, 10**9 + i, data)
    info = describe(path)
    assert info.topics["/cam"].types == (
        ("sensor_msgs/msg/Image", 3),
        ("sensor_msgs/msg/CompressedImage", 2),
    )
