from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from pcainterp_stream.errors import LogReadError, TopicNotFoundError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import LogFormat, decode_image, open_log, sniff_format
from pcainterp_stream.records import StereoCamera

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
CAMERA = StereoCamera(width=32, height=24, fx=40.0, fy=40.0, cx=16.0, cy=12.0, baseline=0.5)
LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"
LEFT_INFO, RIGHT_INFO = "/stereo/left/camera_info", "/stereo/right/camera_info"


def frame_messages(n: int, seed: int = 0) -> list[tuple[str, Any, int]]:
    """(topic, message, log_time_ns) of n stereo frames at 10 Hz."""
    rng = np.random.default_rng(seed)
    out: list[tuple[str, Any, int]] = []
    for i in range(n):
        stamp = 1_000_000_000 + i * 100_000_000
        left = rng.integers(0, 256, (CAMERA.height, CAMERA.width), dtype=np.uint8)
        right = rng.integers(0, 256, (CAMERA.height, CAMERA.width), dtype=np.uint8)
        out.append((LEFT, rosmsg.image_message(left, stamp, "left"), stamp))
        out.append((RIGHT, rosmsg.image_message(right, stamp, "right"), stamp))
        out.append((LEFT_INFO, rosmsg.camera_info_message(CAMERA, stamp, "left"), stamp))
        out.append(
            (RIGHT_INFO, rosmsg.camera_info_message(CAMERA, stamp, "right", right=True), stamp)
        )
    return out


def write_mcap(
    path: Path,
    messages: list[tuple[str, Any, int]],
    *,
    chunk_size: int = 1,
    compression: CompressionType = CompressionType.ZSTD,
    log_times: list[int] | None = None,
    summary: bool = True,
) -> None:
    """Write ROS 2 messages with mcap's Writer (chunk_size=1: one message per chunk).

    ``summary=False`` writes no summary section (no index, no statistics), as a recorder
    that streams does.
    """
    with path.open("wb") as f:
        options: dict[str, Any] = {}
        if not summary:
            options = {
                "index_types": IndexType.NONE,
                "repeat_channels": False,
                "repeat_schemas": False,
                "use_statistics": False,
                "use_summary_offsets": False,
            }
        writer = Writer(f, chunk_size=chunk_size, compression=compression, **options)
        writer.start("ros2", "test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for i, (topic, message, log_time) in enumerate(messages):
            msgtype = message.__msgtype__
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_schema(
                    msgtype, "ros2msg", rosmsg.schema_text(msgtype).encode()
                )
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[msgtype])
            time = log_times[i] if log_times is not None else log_time
            writer.add_message(channels[topic], time, rosmsg.serialize(message), time)
        writer.finish()


@pytest.fixture
def drive(tmp_path: Path) -> tuple[Path, list[tuple[str, Any, int]]]:
    messages = frame_messages(5)
    path = tmp_path / "drive.mcap"
    write_mcap(path, messages)
    return path, messages


def chunk_ends(path: Path) -> list[int]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        return sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)


def chunk_starts(path: Path) -> list[int]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        return sorted(c.chunk_start_offset for c in summary.chunk_indexes)


# --- round trips ----------------------------------------------------------------------------


def test_mcap_round_trip(drive: tuple[Path, list[tuple[str, Any, int]]]) -> None:
    path, messages = drive
    with open_log(path) as reader:
        assert reader.format is LogFormat.MCAP
        topics = reader.topics()
        assert set(topics) == {LEFT, RIGHT, LEFT_INFO, RIGHT_INFO}
        assert topics[LEFT].msgtype == "sensor_msgs/msg/Image"
        assert topics[LEFT].message_count == 5
        raws = list(reader.messages())
        assert [r.topic for r in raws] == [t for t, _, _ in messages]
        assert [r.data for r in raws] == [rosmsg.serialize(m) for _, m, _ in messages]
        assert [r.log_time_ns for r in raws] == [t for _, _, t in messages]
        image = decode_image(reader.decode(raws[0]))
        np.testing.assert_array_equal(image, rosmsg.image_array(messages[0][1]))
        info = reader.decode(raws[3])
        np.testing.assert_allclose(rosmsg.projection_matrix(info), CAMERA.projection_right())
        assert reader.damage == []
        assert reader.warnings == []
        assert reader.message_stats() == (20, 1_000_000_000, 1_400_000_000)


def test_mcap_topic_filter_reads_only_those(drive: tuple[Path, list[tuple[str, Any, int]]]) -> None:
    path, _ = drive
    with open_log(path) as reader:
        raws = list(reader.messages([RIGHT_INFO]))
    assert [r.topic for r in raws] == [RIGHT_INFO] * 5


def _write_with(tmp_path: Path, name: str, log_format: str) -> tuple[Path, list[Any]]:
    from pcainterp_stream.io.logwriter import open_writer

    messages = frame_messages(3)
    path = tmp_path / name
    with open_writer(path, log_format) as writer:
        for topic, message, log_time in messages:
            writer.add_message(topic, message, log_time)
    return path, messages


@pytest.mark.parametrize(
    ("log_format", "suffix"), [("rosbag2", ".mcap"), ("rosbag2-sqlite3", ".db3")]
)
def test_rosbag2_round_trip_folder_and_storage_file(
    tmp_path: Path, log_format: str, suffix: str
) -> None:
    folder, messages = _write_with(tmp_path, "bag", log_format)
    storage = next(folder.glob(f"*{suffix}"))
    for path in (folder, storage):
        with open_log(path) as reader:
            expected = (
                LogFormat.MCAP if suffix == ".mcap" and path == storage else LogFormat.ROSBAG2
            )
            assert reader.format is expected
            assert reader.topics()[LEFT].message_count == 3
            raws = list(reader.messages())
            assert sorted(r.topic for r in raws) == sorted(t for t, _, _ in messages)
            left = [r for r in raws if r.topic == LEFT]
            np.testing.assert_array_equal(
                decode_image(reader.decode(left[1])), rosmsg.image_array(messages[4][1])
            )
            assert reader.damage == []


def test_ros1_round_trip_converts_to_ros2_cdr(tmp_path: Path) -> None:
    path, messages = _write_with(tmp_path, "drive.bag", "ros1")
    with open_log(path) as reader:
        assert reader.format is LogFormat.ROS1
        assert reader.topics()[RIGHT_INFO].msgtype == "sensor_msgs/msg/CameraInfo"
        raws = list(reader.messages())
        assert len(raws) == len(messages)
        by_topic = {r.topic: r for r in raws}
        for topic in (LEFT, RIGHT_INFO):
            raw = by_topic[topic]
            assert raw.message_encoding == "cdr"
            assert raw.schema_encoding == "ros2msg"
            # the ROS 1 type has the Humble layout once Header.seq is dropped
            assert raw.schema_data == rosmsg.schema_text(raw.msgtype).encode()
        info = reader.decode(by_topic[RIGHT_INFO])
        np.testing.assert_allclose(rosmsg.projection_matrix(info), CAMERA.projection_right())
        assert rosmsg.stamp_ns(info) == messages[-1][2]
        image = decode_image(reader.decode(by_topic[LEFT]))
        np.testing.assert_array_equal(image, rosmsg.image_array(messages[-4][1]))


# --- damage ---------------------------------------------------------------------------------


def test_truncated_mcap_yields_everything_before_the_cut(
    drive: tuple[Path, list[tuple[str, Any, int]]], tmp_path: Path
) -> None:
    path, messages = drive
    data = path.read_bytes()
    ends = chunk_ends(path)
    assert len(ends) == len(messages)  # one message per chunk
    full = [rosmsg.serialize(m) for _, m, _ in messages]
    for cut in (20, ends[0] - 5, ends[3], ends[7] + 3, ends[-1] + 2, len(data) - 30, len(data) - 1):
        cut_path = tmp_path / f"cut{cut}.mcap"
        cut_path.write_bytes(data[:cut])
        with open_log(cut_path) as reader:
            got = [r.data for r in reader.messages()]
            complete = sum(end <= cut for end in ends)
            assert got == full[:complete], cut
            assert reader.damage, cut
            assert all(note.startswith(f"cut{cut}.mcap: ") for note in reader.damage)
            topics = reader.topics()  # a scan: must not raise either
            assert sum(t.message_count or 0 for t in topics.values()) == complete


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.NONE])
def test_corrupt_chunk_is_skipped_and_reported(
    tmp_path: Path, compression: CompressionType
) -> None:
    messages = frame_messages(3)
    path = tmp_path / "drive.mcap"
    write_mcap(path, messages, compression=compression)
    data = bytearray(path.read_bytes())
    starts, ends = chunk_starts(path), chunk_ends(path)
    middle = (starts[2] + ends[2]) // 2  # inside chunk 2's (compressed) records
    data[middle - 8 : middle + 8] = bytes(b ^ 0x5A for b in data[middle - 8 : middle + 8])
    path.write_bytes(bytes(data))
    with open_log(path) as reader:
        got = [r.data for r in reader.messages()]
    full = [rosmsg.serialize(m) for _, m, _ in messages]
    assert got == full[:2] + full[3:]
    assert len(reader.damage) == 1
    assert f"at byte {starts[2]}" in reader.damage[0]
    assert "drive.mcap" in reader.damage[0]


def test_garbage_record_length_stops_without_allocating(tmp_path: Path) -> None:
    messages = frame_messages(2)
    path = tmp_path / "drive.mcap"
    write_mcap(path, messages)
    data = bytearray(path.read_bytes())
    start = chunk_starts(path)[4]
    data[start + 1 : start + 9] = (2**62).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    with open_log(path) as reader:
        # the summary's chunk index gives the chunk's real length (before: 4, the walk ended)
        assert len(list(reader.messages())) == 8
    assert any("chunk record of 4611686018427387904 bytes" in note for note in reader.damage)


def test_missing_summary_is_damage_but_all_messages_read(
    drive: tuple[Path, list[tuple[str, Any, int]]], tmp_path: Path
) -> None:
    path, messages = drive
    data = path.read_bytes()
    cut = tmp_path / "nosummary.mcap"
    cut.write_bytes(data[: chunk_ends(path)[-1] + 1 + 8 + 12])  # keep the data-end record
    with open_log(cut) as reader:
        assert len(list(reader.messages())) == len(messages)
        assert reader.message_stats() is None
        assert any("no MCAP magic at the end" in note for note in reader.damage)


def test_non_monotonic_log_times_of_an_indexed_mcap_are_read_in_order(tmp_path: Path) -> None:
    messages = frame_messages(2)
    times = [5, 6, 7, 8, 1, 2, 9, 10]
    path = tmp_path / "jumpy.mcap"
    write_mcap(path, messages, log_times=times)
    with open_log(path) as reader:
        got = [r.log_time_ns for r in reader.messages()]
    assert got == sorted(times)
    assert reader.damage == []
    assert reader.warnings == []


def test_non_monotonic_log_times_without_summary_are_a_warning(tmp_path: Path) -> None:
    messages = frame_messages(2)
    times = [5, 6, 7, 8, 1, 2, 9, 10]
    path = tmp_path / "jumpy.mcap"
    write_mcap(path, messages, log_times=times, summary=False)
    with open_log(path) as reader:
        got = [r.log_time_ns for r in reader.messages()]
        assert reader.message_stats() is None  # no index: read in file order
    assert got == times
    assert reader.damage == []
    assert len(reader.warnings) == 1
    assert reader.warnings[0].startswith("jumpy.mcap: 1 messages have a log time earlier")


# --- log-time order -------------------------------------------------------------------------


def _stored(messages: list[tuple[str, Any, int]], arrangement: str) -> list[tuple[str, Any, int]]:
    """The messages in the order a writer stores them, log times kept."""
    if arrangement == "by-topic":  # a converter writing one topic after another
        return sorted(messages, key=lambda m: m[0])
    # a recorder that receives the right camera 0.7 s (7 frames) late
    return sorted(messages, key=lambda m: m[2] + (700_000_000 if m[0] == RIGHT else 0))


def _log_time_order(messages: list[tuple[str, Any, int]]) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) by log time; equal log times in file order (a stable sort)."""
    ordered = sorted(messages, key=lambda m: m[2])
    return [(topic, log_time, rosmsg.serialize(message)) for topic, message, log_time in ordered]


@pytest.mark.parametrize("arrangement", ["by-topic", "right-late"])
@pytest.mark.parametrize("chunk_size", [1, 2_000, 1 << 20], ids=["1msg", "2kB", "1MB"])
def test_mcap_not_stored_in_time_order_reads_in_log_time_order(
    tmp_path: Path, arrangement: str, chunk_size: int
) -> None:
    stored = _stored(frame_messages(15), arrangement)
    path = tmp_path / "stored.mcap"
    write_mcap(path, stored, chunk_size=chunk_size)
    with open_log(path) as reader:
        got = [(r.topic, r.log_time_ns, r.data) for r in reader.messages()]
        right = [r.log_time_ns for r in reader.messages([RIGHT])]
    assert got == _log_time_order(stored)
    assert right == [log_time for topic, log_time, _ in _log_time_order(stored) if topic == RIGHT]
    assert reader.warnings == []
    assert reader.damage == []
    with path.open("rb") as f:  # as the mcap library (and Foxglove) plays them
        library = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=True)]
    assert [log_time for _, log_time, _ in got] == library


def test_mcap_in_time_order_reads_in_file_order(tmp_path: Path) -> None:
    messages = frame_messages(15)  # four topics per frame, one log time: ties in file order
    path = tmp_path / "ordered.mcap"
    write_mcap(path, messages, chunk_size=2_000)
    with open_log(path) as reader:
        got = [(r.topic, r.log_time_ns, r.data) for r in reader.messages()]
    with path.open("rb") as f:
        library = make_reader(f).iter_messages(log_time_order=False)
        assert got == [(c.topic, m.log_time, m.data) for _, c, m in library]
    assert reader.warnings == []


def test_corrupt_chunk_of_an_mcap_stored_by_topic_is_skipped(tmp_path: Path) -> None:
    stored = _stored(frame_messages(3), "by-topic")
    path = tmp_path / "by_topic.mcap"
    write_mcap(path, stored)  # one message per chunk
    data = bytearray(path.read_bytes())
    starts, ends = chunk_starts(path), chunk_ends(path)
    middle = (starts[4] + ends[4]) // 2  # inside chunk 4's compressed records
    data[middle - 8 : middle + 8] = bytes(b ^ 0x5A for b in data[middle - 8 : middle + 8])
    path.write_bytes(bytes(data))
    with open_log(path) as reader:
        got = [(r.topic, r.log_time_ns, r.data) for r in reader.messages()]
    assert got == _log_time_order(stored[:4] + stored[5:])
    assert len(reader.damage) == 1
    assert "corrupt chunk skipped" in reader.damage[0]
    assert f"at byte {starts[4]}" in reader.damage[0]
    assert stored[4][0] == LEFT
    with open_log(path) as reader:  # the index says which chunks hold a topic: others unread
        right = [r.log_time_ns for r in reader.messages([RIGHT])]
    assert right == [log_time for topic, _, log_time in stored if topic == RIGHT]
    assert reader.damage == []


def test_empty_mcap_has_no_messages_and_no_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    write_mcap(path, [])
    with open_log(path) as reader:
        assert list(reader.messages()) == []
        assert reader.topics() == {}
        assert reader.damage == []
        assert reader.message_stats() == (0, None, None)


# --- errors ---------------------------------------------------------------------------------


def test_missing_topic_names_topics_present_and_option(
    drive: tuple[Path, list[tuple[str, Any, int]]],
) -> None:
    path, _ = drive
    with (
        open_log(path) as reader,
        pytest.raises(
            TopicNotFoundError,
            match=r"^topic /cam/right not found in drive\.mcap; topics present: "
            r"/stereo/left/camera_info, .*; set --right-topic to one of them$",
        ),
    ):
        reader.require_topics({LEFT: "--left-topic", "/cam/right": "--right-topic"})


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(LogReadError, match=r"nope\.mcap does not exist; pass an MCAP file"):
        open_log(tmp_path / "nope.mcap")


def test_not_a_log(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("hello world, not a log at all")
    with pytest.raises(LogReadError, match=r"notes\.txt is not a log \(no MCAP"):
        open_log(path)
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"\x00" * 64)
    with pytest.raises(LogReadError, match=r"named like an MCAP file but does not start"):
        open_log(fake)
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    with pytest.raises(LogReadError, match=r"empty\.bag is empty, not a log"):
        open_log(empty)


def test_folders_that_are_not_bags(tmp_path: Path) -> None:
    kitti = tmp_path / "2011_09_26_drive_0001_sync"
    (kitti / "image_00" / "data").mkdir(parents=True)
    with pytest.raises(
        LogReadError, match=r"KITTI folder: convert it with `pcainterp import-kitti`"
    ):
        sniff_format(kitti)
    (tmp_path / "loose").mkdir()
    (tmp_path / "loose" / "x.db3").write_bytes(b"SQLite format 3\x00")
    with pytest.raises(LogReadError, match=r"pass its storage file .*x\.db3 directly"):
        sniff_format(tmp_path / "loose")


def test_a_folder_of_several_logs_is_not_named_by_one_of_them(tmp_path: Path) -> None:
    """Bug hunt 15E F4: "pass its storage file logs/a.mcap directly" named the first of two
    separate logs as the folder's recording; a split bag without its metadata.yaml (files
    named <folder>_<n>) still gets its storage files named."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("a.mcap", "b.mcap", "c.bag"):
        (logs / name).write_bytes(b"x")
    with pytest.raises(LogReadError) as raised:
        sniff_format(logs)
    message = str(raised.value)
    assert "storage file" not in message
    assert message.endswith(
        "it holds 3 logs (a.mcap, b.mcap, c.bag), not one recording: pass the log files "
        f"themselves (all of them, {logs}/*.bag {logs}/*.mcap, to learn or densify --out-dir "
        "DIR)"
    )
    bag = tmp_path / "run"
    bag.mkdir()
    for name in ("run_0.mcap", "run_1.mcap"):
        (bag / name).write_bytes(b"x")
    with pytest.raises(
        LogReadError, match=r"pass its storage files directly \(.*run/run_\*\.mcap\)$"
    ):
        sniff_format(bag)


def test_a_folder_of_ros1_split_parts_is_named_one_recording(tmp_path: Path) -> None:
    """Review 15e R1: `rosbag record --split` parts in a folder were told "not one recording"
    and sent to --out-dir, which densifies each part as a log of its own."""
    parts = tmp_path / "drive"
    parts.mkdir()
    for index in range(3):
        (parts / f"run_2026-11-28-10-00-00_{index}.bag").write_bytes(b"x")
    with pytest.raises(LogReadError) as raised:
        sniff_format(parts)
    message = str(raised.value)
    assert "not one recording" not in message
    assert message.endswith(
        "it holds 3 ROS 1 bags named as the parts of one split recording "
        "(run_2026-11-28-10-00-00_0.bag, run_2026-11-28-10-00-00_1.bag, "
        "run_2026-11-28-10-00-00_2.bag): pass them together, read as one log (densify "
        f'{parts}/run_2026-11-28-10-00-00_*.bag -o OUTPUT; docs/raw_logs.md, "A recording '
        'split into several bags")'
    )
    (parts / "run_2026-11-28-10-00-00_1.bag").unlink()  # a part missing: not said to be one
    with pytest.raises(LogReadError, match=r"it holds 2 logs .*not one recording"):
        sniff_format(parts)


def test_the_suggested_patterns_work_in_a_shell_for_a_folder_with_a_space(
    tmp_path: Path,
) -> None:
    """Review 15e R5: "logs dir/*.mcap", pasted as it is, is two words for a shell; the
    folder is quoted and the wildcard left for the shell to expand."""
    import subprocess

    for folder, names in (
        (tmp_path / "my logs", ("a.mcap", "b.mcap")),
        (tmp_path / "my run", ("my run_0.mcap", "my run_1.mcap")),  # a split bag's storage
        (tmp_path / "my parts", ("run 1_0.bag", "run 1_1.bag")),  # ROS 1 split parts
    ):
        folder.mkdir()
        for name in names:
            (folder / name).write_bytes(b"x")
        with pytest.raises(LogReadError) as raised:
            sniff_format(folder)
        message = str(raised.value)
        pattern = re.search(r"('[^']+'[\w*.]*)", message)
        assert pattern is not None, message
        listed = subprocess.run(
            ["bash", "-c", f"printf '%s\\n' {pattern.group(1)}"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.splitlines()
        assert sorted(listed) == sorted(str(folder / name) for name in names)


def test_corrupt_ros1_bag_is_a_log_read_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + b"\xff" * 100)
    with pytest.raises(LogReadError, match=r"cannot read ROS 1 bag .*bad\.bag"):
        open_log(path)


def test_closed_reader_refuses(drive: tuple[Path, list[tuple[str, Any, int]]]) -> None:
    path, _ = drive
    reader = open_log(path)
    reader.close()
    with pytest.raises(LogReadError, match="is closed"):
        reader.topics()


# --- images ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "encoding", ["uyvy", "yuyv", "rgb16", "bgr16", "rgba16", "bgra16", "bayer_gbrg16"]
)
def test_the_encodings_of_real_drivers_are_camera_images(encoding: str) -> None:
    """Bug hunt 7A F13: decode_image refused these names (see test_rosmsg.py for values)."""
    dtype, channels = rosmsg.IMAGE_ENCODINGS[encoding]
    shape = (4, 6, channels) if channels > 1 else (4, 6)
    message = rosmsg.image_message(np.zeros(shape, dtype), 0, "f", encoding=encoding)
    decoded = decode_image(message)
    assert decoded.shape == (4, 6, 3)
    assert decoded.dtype == np.dtype(dtype)


def test_decode_image_encodings() -> None:
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (4, 5, 3), dtype=np.uint8)
    bgr_message = rosmsg.image_message(rgb[:, :, ::-1], 0, "f", encoding="bgr8")
    np.testing.assert_array_equal(decode_image(bgr_message), rgb)
    deep = rng.integers(0, 65536, (4, 5), dtype=np.uint16)
    decoded = decode_image(rosmsg.image_message(deep, 0, "f"))
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, deep)


def test_decode_image_unsupported_encoding() -> None:
    message = rosmsg.image_message(np.zeros((2, 2), np.uint8), 0, "f")
    message.encoding = "nv21"
    with pytest.raises(ValueError, match="unsupported image encoding 'nv21'"):
        decode_image(message)
    depth = rosmsg.image_message(np.zeros((2, 2), np.float32), 0, "f")
    assert depth.encoding == "32FC1"
    with pytest.raises(ValueError, match=r"encoding '32FC1'; camera images are mono8,") as err:
        decode_image(depth)
    assert "32FC1" not in str(err.value).split(";")[1]
    tiff = rosmsg.compressed_image_message(b"II*\x00", "tiff", 0, "f")
    with pytest.raises(ValueError, match="unsupported compressed image format 'tiff'"):
        decode_image(tiff)
    broken = rosmsg.compressed_image_message(b"not a png", "png", 0, "f")
    with pytest.raises(ValueError, match=r"^compressed png image does not decode \(9 bytes, "):
        decode_image(broken)
    _, png = cv2.imencode(".png", np.arange(64, dtype=np.uint8).reshape(8, 8))
    cut = rosmsg.compressed_image_message(png.tobytes()[:40], "png", 0, "f")
    with pytest.raises(ValueError, match=r"compressed png image is cut off \(no end marker; 40 b"):
        decode_image(cut)
    damaged = png.tobytes()
    damaged = damaged[:20] + bytes(40) + damaged[60:]  # end marker kept, pixels gone
    padded = rosmsg.compressed_image_message(png.tobytes() + bytes(64), "png", 0, "f")
    assert decode_image(padded).shape == (8, 8)  # a fixed-size buffer's padding after IEND
    bad = rosmsg.compressed_image_message(damaged, "bgr8; png compressed bgr8", 0, "f")
    with pytest.raises(ValueError, match=r"^compressed png image does not decode \(\d+ bytes, "):
        decode_image(bad)


def test_decode_compressed_png_and_jpeg() -> None:
    rng = np.random.default_rng(2)
    grey = rng.integers(0, 256, (6, 7), dtype=np.uint8)
    ok, png = cv2.imencode(".png", grey)
    assert ok
    got = decode_image(rosmsg.compressed_image_message(png.tobytes(), "png", 0, "f"))
    np.testing.assert_array_equal(got, grey)
    red = np.zeros((16, 16, 3), np.uint8)
    red[:, :, 0] = 255  # RGB
    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(red, cv2.COLOR_RGB2BGR))
    assert ok
    got = decode_image(SimpleNamespace(format="rgb8; jpeg compressed bgr8", data=jpeg))
    assert got.shape == (16, 16, 3)
    assert got[8, 8, 0] > 200
    assert got[8, 8, 2] < 50


def _scene(seed: int = 3) -> np.ndarray:
    """A smooth 24x32 RGB scene (demosaicing is exact only where colour varies slowly)."""
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    return np.asarray(cv2.GaussianBlur(noise, (7, 7), 2))


def _mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The one-channel Bayer mosaic of an RGB image (``pattern`` names the first 2x2 cell)."""
    out = np.empty(rgb.shape[:2], np.uint8)
    for k, colour in enumerate(pattern):
        out[k // 2 :: 2, k % 2 :: 2] = rgb[k // 2 :: 2, k % 2 :: 2, "rgb".index(colour)]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_a_compressed_bayer_mosaic_is_demosaiced_as_its_image(pattern: str) -> None:
    """Bug hunt 7A F1: compressed_image_transport compresses a Bayer image as its mosaic,
    format ``bayer_rggb8; png compressed ``; it was taken as a grey image."""
    rgb = _scene()
    mosaic = _mosaic(rgb, pattern)
    raw = decode_image(rosmsg.image_message(mosaic, 0, "f", encoding=f"bayer_{pattern}8"))
    assert raw.shape == rgb.shape
    ok, png = cv2.imencode(".png", mosaic)
    assert ok
    image_format = f"bayer_{pattern}8; png compressed "
    from_png = decode_image(rosmsg.compressed_image_message(png.tobytes(), image_format, 0, "f"))
    np.testing.assert_array_equal(from_png, raw)  # PNG is lossless: the Image's own pixels
    ok, jpeg = cv2.imencode(".jpg", mosaic, [cv2.IMWRITE_JPEG_QUALITY, 98])
    assert ok
    jpeg_format = f"bayer_{pattern}8; jpeg compressed "
    from_jpeg = decode_image(rosmsg.compressed_image_message(jpeg.tobytes(), jpeg_format, 0, "f"))
    assert from_jpeg.shape == rgb.shape
    inner = (slice(3, -3), slice(3, -3))
    assert np.abs(from_jpeg[inner].astype(int) - raw[inner]).mean() < 4


def test_the_formats_compressed_image_transport_writes() -> None:
    """Each prefix and channel order of ``ENCODING; CODEC compressed ORDER`` decodes to the
    array the uncompressed Image of that encoding gives (RGB, or grey of its depth)."""
    rgb = _scene(4)
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])

    def decoded(array: np.ndarray, ext: str, image_format: str) -> np.ndarray:
        ok, data = cv2.imencode(ext, array)
        assert ok
        return decode_image(rosmsg.compressed_image_message(data.tobytes(), image_format, 0, "f"))

    for image_format in ("rgb8; png compressed bgr8", "bgr8; png compressed bgr8", "png"):
        np.testing.assert_array_equal(decoded(bgr, ".png", image_format), rgb)
    # some encoders store RGB bytes and say so: compressed_image_transport's subscriber
    # then does not swap them
    np.testing.assert_array_equal(decoded(rgb, ".png", "bgr8; png compressed rgb8"), rgb)
    alpha = np.full((24, 32, 1), 255, np.uint8)
    bgra = np.concatenate([bgr, alpha], axis=2)
    np.testing.assert_array_equal(decoded(bgra, ".png", "bgra8; png compressed bgra8"), rgb)
    rgba = np.concatenate([rgb, alpha], axis=2)
    np.testing.assert_array_equal(decoded(rgba, ".png", "rgba8; png compressed rgba8"), rgb)
    jpeg = decoded(bgr, ".jpg", "rgb8; jpeg compressed bgr8").astype(int)
    assert np.abs(jpeg - rgb).mean() < 4
    deep = (rgb[:, :, 0].astype(np.uint16) * 257).astype(np.uint16)
    for image_format in ("mono16; png compressed ", "16UC1; png compressed"):
        got = decoded(deep, ".png", image_format)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, deep)
    grey = rgb[:, :, 1].copy()
    np.testing.assert_array_equal(decoded(grey, ".png", "mono8; png compressed "), grey)
    # a 16-bit Bayer mosaic in a 16-bit PNG (bug hunt 7A F13: refused before)
    mosaic16 = np.asarray(_mosaic(rgb, "rggb"), np.uint16) * 257
    raw16 = decode_image(rosmsg.image_message(mosaic16, 0, "f", encoding="bayer_rggb16"))
    got16 = decoded(mosaic16, ".png", "bayer_rggb16; png compressed ")
    assert got16.dtype == np.uint16
    assert got16.shape == rgb.shape
    np.testing.assert_array_equal(got16, raw16)
    with pytest.raises(ValueError, match=r"^a bayer_rggb16 mosaic must decode to uint16, got"):
        decoded(grey, ".png", "bayer_rggb16; png compressed ")


@pytest.mark.parametrize("label", ["png", "bgr8; png compressed bgr8", "jpeg"])
def test_the_payload_not_the_format_word_decides_the_codec(label: str) -> None:
    """Bug hunt 7A F15: JPEG bytes in a CompressedImage whose format says png were refused
    as "cut off" (the PNG end-marker check ran on the format's word), though PNG bytes
    labelled jpeg decoded; a cut PNG is "cut off" whatever its label."""
    rgb = _scene(5)
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    got = decode_image(rosmsg.compressed_image_message(jpeg.tobytes(), label, 0, "f"))
    assert got.shape == rgb.shape
    assert np.abs(got.astype(int) - rgb).mean() < 4  # RGB, as a JPEG labelled jpeg
    ok, png = cv2.imencode(".png", bgr)
    assert ok
    got = decode_image(rosmsg.compressed_image_message(png.tobytes(), label, 0, "f"))
    np.testing.assert_array_equal(got, rgb)
    cut = rosmsg.compressed_image_message(png.tobytes()[:-200], label, 0, "f")
    with pytest.raises(ValueError, match=r"^compressed png image is cut off \(no end marker; "):
        decode_image(cut)


@pytest.mark.parametrize("image_format", ["jpeg", "png", "rgb8; jpeg compressed bgr8"])
def test_an_empty_compressed_payload_is_undecodable(image_format: str) -> None:
    """Bug hunt 7A F2: a 0-byte payload (a bridge's failed frame) reached cv2.imdecode,
    whose assertion was a traceback instead of an undecodable frame."""
    empty = rosmsg.compressed_image_message(b"", image_format, 0, "f")
    codec = "png" if "png" in image_format else "jpeg"
    with pytest.raises(ValueError, match=rf"^compressed {codec} image is empty \(0 bytes, "):
        decode_image(empty)


def test_an_empty_image_is_undecodable() -> None:
    """Bug hunt 7A F3: a 0x0 Image (a driver's failed grab) decoded to an empty array,
    which later failed as a calibration of another size."""
    empty = rosmsg.image_message(np.zeros((0, 0), np.uint8), 0, "f")
    with pytest.raises(ValueError, match=r"^image is empty \(0x0 mono8\)"):
        decode_image(empty)
    no_rows = rosmsg.image_message(np.zeros((0, 8), np.uint8), 0, "f")
    with pytest.raises(ValueError, match=r"^image is empty \(8x0 mono8\)"):
        rosmsg.image_array(no_rows)


def test_decode_non_cdr_is_a_log_read_error(tmp_path: Path) -> None:
    path = tmp_path / "json.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("", "test")
        schema = writer.register_schema("Thing", "jsonschema", b"{}")
        channel = writer.register_channel("/thing", "json", schema)
        writer.add_message(channel, 1, b'{"a": 1}', 1)
        writer.finish()
    with open_log(path) as reader:
        (raw,) = list(reader.messages())
        assert (raw.msgtype, raw.message_encoding) == ("Thing", "json")
        with pytest.raises(LogReadError, match=r"cannot decode message on /thing .* not ROS 2 CDR"):
            reader.decode(raw)


def test_a_placeholder_schema_falls_back_to_the_standard_type(tmp_path: Path) -> None:
    """rosbag2's own test bags store ``uint8 level`` as rcl_interfaces/msg/Log's definition."""
    log = rosmsg.TYPESTORE.types["rcl_interfaces/msg/Log"]
    time = rosmsg.TYPESTORE.types["builtin_interfaces/msg/Time"]
    message = log(time(sec=1, nanosec=2), 20, "node", "hello", "f.cpp", "fn", 38)
    path = tmp_path / "rosout.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("ros2", "test")
        schema = writer.register_schema("rcl_interfaces/msg/Log", "ros2msg", b"uint8 level")
        rosout = writer.register_channel("/rosout", "cdr", schema)
        for stamp in (1, 2):
            writer.add_message(rosout, stamp, rosmsg.serialize(message), stamp)
        bad = writer.register_schema("std_msgs/msg/String", "ros2msg", b"uint8 level")
        chatter = writer.register_channel("/chatter", "cdr", bad)
        writer.add_message(chatter, 3, b"\x00\x01\x00\x00\xff\xff\xff\x7f\x01\x02\x03\x04", 3)
        writer.finish()
    with open_log(path) as reader:
        first, second, broken = list(reader.messages())
        assert reader.decode(first).msg == "hello"
        assert reader.decode(second).line == 38
        (warning,) = reader.warnings
        assert "rcl_interfaces/msg/Log on /rosout does not match" in warning
        with pytest.raises(LogReadError, match="cannot decode message on /chatter"):
            reader.decode(broken)  # neither its schema nor the standard one decodes it


def test_an_empty_schema_is_called_empty(tmp_path: Path) -> None:
    """Bug hunt 16G F5: an empty ros2msg schema was said not to match its messages."""
    log = rosmsg.TYPESTORE.types["rcl_interfaces/msg/Log"]
    time = rosmsg.TYPESTORE.types["builtin_interfaces/msg/Time"]
    message = log(time(sec=1, nanosec=2), 20, "node", "hello", "f.cpp", "fn", 38)
    path = tmp_path / "empty.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("ros2", "test")
        schema = writer.register_schema("rcl_interfaces/msg/Log", "ros2msg", b"")
        rosout = writer.register_channel("/rosout", "cdr", schema)
        writer.add_message(rosout, 1, rosmsg.serialize(message), 1)
        writer.finish()
    with open_log(path) as reader:
        (raw,) = list(reader.messages())
        assert reader.decode(raw).msg == "hello"
        (warning,) = reader.warnings
        assert "rcl_interfaces/msg/Log on /rosout is empty; its messages were decoded" in warning


# --- real data ------------------------------------------------------------------------------

needs_realdata = pytest.mark.skipif(
    not REALDATA.is_dir(), reason=f"real data folder {REALDATA} is absent"
)


@pytest.mark.realdata
@needs_realdata
def test_realdata_rerun_images_decode() -> None:
    path = REALDATA / "mcap_ros2" / "supported_ros2_messages.mcap"
    with open_log(path) as reader:
        images = {
            raw.topic: decode_image(reader.decode(raw))
            for raw in reader.messages(["/image", "/compressed_image"])
        }
    assert images["/image"].shape == (480, 640, 3)
    assert images["/compressed_image"].shape == (480, 640, 3)
    assert images["/image"].dtype == np.uint8


@pytest.mark.realdata
@needs_realdata
def test_realdata_rosbag2_traps() -> None:
    with open_log(REALDATA / "rosbag2" / "sqlite3" / "talker") as reader:
        assert len(list(reader.messages())) == 20
        assert "read talker.db3 directly" in reader.warnings[0]
    # MCAP storage is read through its files, as given directly (bug hunt 6B M7): rosbags'
    # traps (0 messages through metadata.yaml, "Could not parse") no longer apply
    with open_log(REALDATA / "rosbag2" / "mcap" / "talker") as reader:
        assert len(list(reader.messages())) == 20
        assert reader.warnings == []
    with open_log(REALDATA / "rosbag2" / "mcap" / "bag_with_topics_and_service_events") as reader:
        assert len(list(reader.messages())) == 10
        assert reader.damage == []


@pytest.mark.realdata
@needs_realdata
def test_realdata_ros1_messages_decode() -> None:
    with open_log(REALDATA / "ros1" / "example-lz4.bag") as reader:
        raws = list(reader.messages(["/turtle1/cmd_vel"]))
        twist = reader.decode(raws[0])
    assert len(raws) == 357
    assert raws[0].msgtype == "geometry_msgs/msg/Twist"
    assert raws[0].schema_data == rosmsg.schema_text("geometry_msgs/msg/Twist").encode()
    assert np.isfinite(twist.linear.x)


def test_random_damage_never_escapes_as_a_library_exception(tmp_path: Path) -> None:
    messages = frame_messages(2)
    path = tmp_path / "drive.mcap"
    write_mcap(path, messages, chunk_size=600)
    data = path.read_bytes()
    rng = np.random.default_rng(7)
    damaged = tmp_path / "damaged.mcap"
    errors: list[str] = []
    for trial in range(300):
        buffer = bytearray(data)
        if trial % 3 == 0:
            buffer = buffer[: int(rng.integers(0, len(buffer)))]
        else:
            for position in rng.integers(0, len(buffer), int(rng.integers(1, 6))):
                buffer[position] = int(rng.integers(0, 256))
        damaged.write_bytes(bytes(buffer))
        try:
            with open_log(damaged) as reader:
                reader.topics()
                for raw in reader.messages():
                    try:
                        reader.decode(raw)
                    except LogReadError:
                        pass
        except LogReadError as err:
            errors.append(str(err))
    assert all("\n" not in message for message in errors)


def test_mcap_ros1_profile_is_converted_to_cdr(tmp_path: Path) -> None:
    store = rosmsg.TYPESTORE
    message = rosmsg.camera_info_message(CAMERA, 1_500_000_000, "right", right=True)
    msgtype = "sensor_msgs/msg/CameraInfo"
    ros1_text, _ = store.generate_msgdef(msgtype, ros_version=1)
    ros1_data = bytes(store.cdr_to_ros1(rosmsg.serialize(message), msgtype))
    path = tmp_path / "ros1.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("ros1", "test")
        schema = writer.register_schema("sensor_msgs/CameraInfo", "ros1msg", ros1_text.encode())
        channel = writer.register_channel(RIGHT_INFO, "ros1", schema)
        writer.add_message(channel, 5, ros1_data, 5)
        writer.finish()
    with open_log(path) as reader:
        assert reader.topics()[RIGHT_INFO].msgtype == msgtype
        (raw,) = list(reader.messages())
        assert (raw.message_encoding, raw.schema_encoding) == ("cdr", "ros2msg")
        assert raw.data == rosmsg.serialize(message)
        info = reader.decode(raw)
    np.testing.assert_allclose(rosmsg.projection_matrix(info), CAMERA.projection_right())


def test_rosbag2_qos_parsed_by_rosbags_is_written_back_as_rosbag2_stores_it() -> None:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    from pcainterp_stream.io.rosbags_reader import _connection_metadata

    latched = Qos(  # /tf_static's: transient local, as a newer rosbag2 hands it to rosbags
        history=QosHistory.KEEP_LAST,
        depth=1,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL,
        deadline=QosTime(sec=0, nsec=0),
        lifespan=QosTime(sec=10, nsec=0),
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=QosTime(sec=0, nsec=0),
        avoid_ros_namespace_conventions=False,
    )
    connection = SimpleNamespace(ext=SimpleNamespace(offered_qos_profiles=[latched]))
    assert _connection_metadata(connection) == {  # before: {}, replayed volatile
        "offered_qos_profiles": "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
        "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 10\n    nsec: 0\n"
        "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false"
    }
    stored = SimpleNamespace(ext=SimpleNamespace(offered_qos_profiles="- history: 3"))
    assert _connection_metadata(stored) == {"offered_qos_profiles": "- history: 3"}
    assert _connection_metadata(SimpleNamespace(ext=SimpleNamespace())) == {}


@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real data not found at {REALDATA}")
def test_rosbag2_talker_qos_comes_out_as_its_metadata_yaml_holds_it() -> None:
    import yaml
    from rosbags.highlevel import AnyReader

    from pcainterp_stream.io.rosbags_reader import _connection_metadata

    bag = REALDATA / "rosbag2" / "mcap" / "talker"
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    stored = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in info["topics_with_message_count"]
    }
    with AnyReader([bag]) as reader:
        written = {
            c.topic: _connection_metadata(c)["offered_qos_profiles"] for c in reader.connections
        }
    assert written == stored
