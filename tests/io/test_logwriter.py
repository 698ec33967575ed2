from __future__ import annotations

import errno
import gc
import shutil
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path
from time import sleep
from typing import Any

import mcap.writer
import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io import logwriter, rosmsg
from pcainterp_stream.io.logwriter import (
    MCAP_ZSTD_LEVEL,
    LogFormat,
    McapLogWriter,
    Rosbag2LogWriter,
    format_from_path,
    open_writer,
)
from pcainterp_stream.records import RawMessage, StereoCamera

CAMERA = StereoCamera(width=8, height=6, fx=50.0, fy=50.0, cx=4.0, cy=3.0, baseline=0.5)
T0 = 1_700_000_000_000_000_000
DT = 100_000_000

OUTPUT_NAMES = {
    LogFormat.MCAP: "out.mcap",
    LogFormat.ROSBAG2: "out_bag",
    LogFormat.ROSBAG2_SQLITE3: "out_db3",
    LogFormat.ROS1: "out.bag",
}


def _messages(n: int = 3) -> list[tuple[str, Any, int]]:
    """(topic, message, log_time_ns) of a few frames of every type the project writes."""
    rng = np.random.default_rng(0)
    out: list[tuple[str, Any, int]] = []
    for i in range(n):
        stamp = T0 + i * DT
        grey = rng.integers(0, 256, size=(6, 8), dtype=np.uint8)
        depth = rng.uniform(1, 50, size=(6, 8)).astype(np.float32)
        depth[0, :] = np.nan
        pose = np.eye(4)
        pose[:3, 3] = [i, 0.5 * i, 2.0]
        out += [
            ("/stereo/left/image_rect", rosmsg.image_message(grey, stamp, "left"), stamp),
            ("/stereo/left/camera_info", rosmsg.camera_info_message(CAMERA, stamp, "left"), stamp),
            ("/ground_truth/depth", rosmsg.image_message(depth, stamp, "left"), stamp),
            ("/ground_truth/pose", rosmsg.pose_stamped_message(pose, stamp, "world"), stamp),
            (
                "/pcainterp/features",
                rosmsg.pointcloud2_message(
                    {"x": rng.random(5, dtype=np.float32), "u": rng.random(5, dtype=np.float32)},
                    stamp,
                    "left",
                ),
                stamp,
            ),
            (
                "/pcainterp/disparity",
                rosmsg.disparity_image_message(
                    depth,
                    stamp,
                    "left",
                    focal=50.0,
                    baseline=0.5,
                    min_disparity=0,
                    max_disparity=64,
                ),
                stamp,
            ),
        ]
    return out


def _read_anyreader(path: Path) -> list[tuple[str, str, int, Any]]:
    with AnyReader([path], default_typestore=rosmsg.TYPESTORE) as reader:
        return [
            (conn.topic, conn.msgtype, log_time, reader.deserialize(data, conn.msgtype))
            for conn, log_time, data in reader.messages()
        ]


def _check_same(expected: Any, actual: Any) -> None:
    """Compare two messages field by field (ROS 1 adds header.seq, spells K/P upper case)."""
    for name in expected.__dataclass_fields__:
        if name == "__msgtype__":
            continue
        want = getattr(expected, name)
        have = getattr(actual, name, None)
        if have is None:
            have = getattr(actual, name.upper())
        if hasattr(want, "__dataclass_fields__"):
            _check_same(want, have)
        elif isinstance(want, np.ndarray):
            np.testing.assert_array_equal(np.asarray(have), want)
        elif isinstance(want, list):
            assert len(want) == len(have)
            for w, h in zip(want, have, strict=True):
                _check_same(w, h)
        else:
            assert want == have, name


@pytest.mark.parametrize("fmt", list(LogFormat))
def test_round_trip_anyreader(tmp_path: Path, fmt: LogFormat) -> None:
    messages = _messages()
    target = tmp_path / OUTPUT_NAMES[fmt]
    with open_writer(target, fmt) as writer:
        for topic, message, log_time in messages:
            writer.add_message(topic, message, log_time)
    summary = writer.summary()
    assert summary.message_count == len(messages)
    assert summary.topic_counts["/ground_truth/depth"] == 3
    assert (summary.start_ns, summary.end_ns) == (T0, T0 + 2 * DT)
    assert [p.name for p in tmp_path.iterdir()] == [target.name]  # no partial left over

    read = _read_anyreader(target)
    assert len(read) == len(messages)
    by_topic: dict[str, list[tuple[str, int, Any]]] = {}
    for topic, msgtype, log_time, message in read:
        by_topic.setdefault(topic, []).append((msgtype, log_time, message))
    for topic, message, log_time in messages:
        msgtype, read_time, read_message = by_topic[topic].pop(0)
        assert msgtype == message.__msgtype__
        assert read_time == log_time
        assert rosmsg.stamp_ns(read_message) == log_time
        _check_same(message, read_message)
    depth = next(m for t, _, _, m in read if t == "/ground_truth/depth")
    np.testing.assert_array_equal(rosmsg.image_array(depth), rosmsg.image_array(messages[2][1]))


def test_ros1_uses_noetic_definitions(tmp_path: Path) -> None:
    target = tmp_path / "out.bag"
    with open_writer(target) as writer:
        for topic, message, log_time in _messages(1):
            writer.add_message(topic, message, log_time)
    with AnyReader([target]) as reader:
        digests = {c.msgtype: c.digest for c in reader.connections}
        info = next(
            reader.deserialize(d, c.msgtype)
            for c, _, d in reader.messages()
            if c.msgtype == rosmsg.CAMERA_INFO
        )
    # the MD5 sums of ROS 1 Noetic, so ROS 1 tools accept the bag
    assert digests[rosmsg.CAMERA_INFO] == "c9a58c1b0b154e0e6da7578cb991d214"
    assert digests[rosmsg.IMAGE] == "060021388200f6f0f447d0fcd9c64743"
    assert info.header.seq == 0
    np.testing.assert_array_equal(info.P, CAMERA.projection_left().reshape(-1))


def test_mcap_profile_summary_and_decoding(tmp_path: Path) -> None:
    messages = _messages()
    target = tmp_path / "out.mcap"
    with open_writer(target) as writer:
        for topic, message, log_time in messages:
            writer.add_message(topic, message, log_time, publish_time_ns=log_time + 7)
    with target.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        decoded = list(reader.iter_decoded_messages(log_time_order=False))
    assert header.profile == "ros2"
    assert summary is not None
    assert summary.statistics.message_count == len(messages)
    assert summary.statistics.channel_count == 6
    assert len(summary.schemas) == 5  # the two Image topics share one schema
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert summary.chunk_indexes
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert len(decoded) == len(messages)
    for (topic, message, log_time), item in zip(messages, decoded, strict=True):
        assert item.channel.topic == topic
        assert item.schema.name == message.__msgtype__
        assert item.message.log_time == log_time
        assert item.message.publish_time == log_time + 7
    image = decoded[0].decoded_message
    np.testing.assert_array_equal(
        np.frombuffer(bytes(image.data), dtype=np.uint8), np.asarray(messages[0][1].data)
    )


def _raw(topic: str, data: bytes, log_time: int, **changes: Any) -> RawMessage:
    fields: dict[str, Any] = {
        "topic": topic,
        "msgtype": "example/Text",
        "schema_name": "example/Text",
        "schema_encoding": "jsonschema",
        "schema_data": b'{"type": "object"}',
        "message_encoding": "json",
        "channel_metadata": {"qos": "reliable"},
        "data": data,
        "log_time_ns": log_time,
        "publish_time_ns": log_time - 5,
        "sequence": 3,
    }
    fields.update(changes)
    return RawMessage(**fields)


def test_mcap_add_raw_copies_unchanged_and_deduplicates(tmp_path: Path) -> None:
    image = rosmsg.image_message(np.arange(48, dtype=np.uint8).reshape(6, 8), T0, "left")
    ros_raw = RawMessage(
        topic="/stereo/left/image_rect",
        msgtype=rosmsg.IMAGE,
        schema_name=rosmsg.IMAGE,
        schema_encoding="ros2msg",
        schema_data=rosmsg.schema_text(rosmsg.IMAGE).encode(),
        message_encoding="cdr",
        channel_metadata={"offered_qos_profiles": "- history: 3"},
        data=rosmsg.serialize(image),
        log_time_ns=T0,
        publish_time_ns=T0 - 1,
        sequence=0,
    )
    raws = [_raw("/text", b'{"a": %d}' % i, T0 + i) for i in range(3)]
    raws.append(_raw("/other", b"{}", T0 + 9, channel_metadata={}))
    target = tmp_path / "copy.mcap"
    with open_writer(target, LogFormat.MCAP) as writer:
        writer.add_raw(ros_raw)
        for raw in raws:
            writer.add_raw(raw)
        writer.add_message("/pcainterp/depth", image, T0)  # shares the Image schema
    with target.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        records = list(reader.iter_messages(log_time_order=False))
    assert summary is not None
    assert len(summary.schemas) == 2
    assert len(summary.channels) == 4
    assert [r[2].data for r in records] == [ros_raw.data, *[r.data for r in raws], ros_raw.data]
    schema, channel, message = records[1]
    assert (schema.name, schema.encoding, schema.data) == (
        "example/Text",
        "jsonschema",
        b'{"type": "object"}',
    )
    assert channel.metadata == {"qos": "reliable"}
    assert channel.message_encoding == "json"
    assert (message.log_time, message.publish_time, message.sequence) == (T0, T0 - 5, 3)
    assert records[0][1].metadata == {"offered_qos_profiles": "- history: 3"}


@pytest.mark.parametrize("fmt", [LogFormat.ROSBAG2, LogFormat.ROS1])
def test_bag_add_raw_takes_cdr_and_refuses_json(tmp_path: Path, fmt: LogFormat) -> None:
    image = rosmsg.image_message(np.arange(48, dtype=np.uint8).reshape(6, 8), T0, "left")
    ros_raw = _raw(
        "/img",
        rosmsg.serialize(image),
        T0,
        msgtype=rosmsg.IMAGE,
        schema_name=rosmsg.IMAGE,
        schema_encoding="ros2msg",
        schema_data=rosmsg.schema_text(rosmsg.IMAGE).encode(),
        message_encoding="cdr",
    )
    target = tmp_path / OUTPUT_NAMES[fmt]
    with open_writer(target, fmt) as writer:
        writer.add_raw(ros_raw)
    (_, msgtype, log_time, message), *_ = _read_anyreader(target)
    assert (msgtype, log_time) == (rosmsg.IMAGE, T0)
    np.testing.assert_array_equal(rosmsg.image_array(message), rosmsg.image_array(image))
    with (
        pytest.raises(LogWriteError, match=r"topic /text has 'json' messages.*write an \.mcap"),
        open_writer(tmp_path / ("b_" + target.name), fmt) as writer,
    ):
        writer.add_raw(_raw("/text", b"{}", T0))
    assert not (tmp_path / ("b_" + target.name)).exists()


def _write_then_fail(target: Path, fmt: LogFormat, error: type[BaseException]) -> None:
    with open_writer(target, fmt) as writer:
        topic, message, log_time = _messages(1)[0]
        writer.add_message(topic, message, log_time + 1)
        assert writer.partial_path.exists()
        assert writer.partial_path.parent.name.startswith(f".{target.name}.partial-")
        raise error


@pytest.mark.parametrize("fmt", list(LogFormat))
@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_failure_leaves_no_target_and_no_partial(
    tmp_path: Path, fmt: LogFormat, error: type[BaseException]
) -> None:
    target = tmp_path / OUTPUT_NAMES[fmt]
    with pytest.raises(error):
        _write_then_fail(target, fmt, error)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("fmt", list(LogFormat))
def test_existing_target_survives_failure_and_is_replaced_on_success(
    tmp_path: Path, fmt: LogFormat
) -> None:
    target = tmp_path / OUTPUT_NAMES[fmt]
    topic, message, log_time = _messages(1)[0]
    with open_writer(target, fmt) as writer:
        writer.add_message(topic, message, log_time)
    before = sorted((p.relative_to(tmp_path), p.read_bytes()) for p in _files(tmp_path))
    with pytest.raises(RuntimeError):
        _write_then_fail(target, fmt, RuntimeError)
    after = sorted((p.relative_to(tmp_path), p.read_bytes()) for p in _files(tmp_path))
    assert after == before
    with open_writer(target, fmt) as writer:
        writer.add_message(topic, message, log_time + 1)
        writer.add_message(topic, message, log_time + 2)
    assert [t for _, _, t, _ in _read_anyreader(target)] == [log_time + 1, log_time + 2]
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()]


def test_refuses_to_write_onto_input(tmp_path: Path) -> None:
    source = tmp_path / "in.mcap"
    with open_writer(source) as writer:
        writer.add_message(*_messages(1)[0])
    with pytest.raises(
        LogWriteError, match=r"refusing to write the output onto the input .*in\.mcap"
    ):
        open_writer(tmp_path / "." / "in.mcap", inputs=[source])
    link = tmp_path / "link.mcap"
    link.symlink_to(source)
    with pytest.raises(LogWriteError, match="refusing to write the output onto the input"):
        open_writer(link, inputs=[source])
    bag = tmp_path / "bag"
    with open_writer(bag, LogFormat.ROSBAG2) as writer:
        writer.add_message(*_messages(1)[0])
    storage = bag / "bag.mcap"
    with pytest.raises(LogWriteError, match="refusing to write the output onto the input"):
        open_writer(bag, LogFormat.ROSBAG2, inputs=[storage])
    open_writer(tmp_path / "out.mcap", inputs=[source])  # a different path is fine


def test_errors_on_bad_paths(tmp_path: Path) -> None:
    with pytest.raises(LogWriteError, match=r"folder .*missing does not exist; create it first"):
        open_writer(tmp_path / "missing" / "out.mcap").__enter__()
    with pytest.raises(LogWriteError, match=r"unknown log format 'zip'.*choose one of mcap"):
        open_writer(tmp_path / "out.mcap", "zip")
    folder = tmp_path / "stuff"
    folder.mkdir()
    (folder / "keep.txt").write_text("precious")
    with pytest.raises(LogWriteError, match=r"not a rosbag2 bag.*remove it or choose another"):
        open_writer(folder, LogFormat.ROSBAG2)
    with pytest.raises(LogWriteError, match="is a folder but format mcap writes a file"):
        open_writer(folder, LogFormat.MCAP)
    assert (folder / "keep.txt").read_text() == "precious"


def test_error_on_unwritable_folder(tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        folder = locked
        if _can_write(locked):  # root ignores permissions; /proc refuses new entries
            if not Path("/proc/self").is_dir():
                pytest.skip("running as root without /proc: no unwritable folder to try")
            folder = Path("/proc")
        with pytest.raises(LogWriteError, match=r"cannot write .*out\.mcap: .*writable folder"):
            open_writer(folder / "out.mcap").__enter__()
    finally:
        locked.chmod(0o700)


def _can_write(folder: Path) -> bool:
    try:
        (folder / "probe").write_bytes(b"")
    except OSError:
        return False
    (folder / "probe").unlink()
    return True


def test_format_from_path(tmp_path: Path) -> None:
    assert format_from_path("a/b.mcap") == LogFormat.MCAP
    assert format_from_path("b.MCAP") == LogFormat.MCAP
    assert format_from_path("b.bag") == LogFormat.ROS1
    assert format_from_path("drive_bag") == LogFormat.ROSBAG2
    assert format_from_path(tmp_path) == LogFormat.ROSBAG2
    with pytest.raises(LogWriteError, match=r"cannot tell the log format of x\.zip"):
        format_from_path("x.zip")


REAL_ROS2_MCAP = (
    Path(__file__).resolve().parents[3]
    / "shared"
    / "realdata"
    / "mcap_ros2"
    / "supported_ros2_messages.mcap"
)


def _real_raws() -> list[RawMessage]:
    with REAL_ROS2_MCAP.open("rb") as stream:
        return [
            RawMessage(
                topic=channel.topic,
                msgtype=schema.name,
                schema_name=schema.name,
                schema_encoding=schema.encoding,
                schema_data=schema.data,
                message_encoding=channel.message_encoding,
                channel_metadata=dict(channel.metadata),
                data=message.data,
                log_time_ns=message.log_time,
                publish_time_ns=message.publish_time,
                sequence=message.sequence,
            )
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False)
        ]


@pytest.mark.realdata
@pytest.mark.skipif(not REAL_ROS2_MCAP.is_file(), reason=f"{REAL_ROS2_MCAP} not found")
@pytest.mark.parametrize("fmt", list(LogFormat))
def test_copy_real_ros2_recording(tmp_path: Path, fmt: LogFormat) -> None:
    raws = _real_raws()
    assert len(raws) > 100
    target = tmp_path / OUTPUT_NAMES[fmt]
    with open_writer(target, fmt, inputs=[REAL_ROS2_MCAP]) as writer:
        for raw in raws:
            writer.add_raw(raw)
    read = _read_anyreader(target)
    assert [(t, m, lt) for t, m, lt, _ in read] == [
        (r.topic, r.msgtype, r.log_time_ns) for r in raws
    ]
    if fmt == LogFormat.MCAP:
        with target.open("rb") as stream:
            copied = list(make_reader(stream).iter_messages(log_time_order=False))
        for raw, (schema, channel, message) in zip(raws, copied, strict=True):
            assert (schema.name, schema.encoding, schema.data) == (
                raw.schema_name,
                raw.schema_encoding,
                raw.schema_data,
            )
            assert (channel.message_encoding, channel.metadata) == (
                raw.message_encoding,
                raw.channel_metadata,
            )
            assert (message.data, message.publish_time, message.sequence) == (
                raw.data,
                raw.publish_time_ns,
                raw.sequence,
            )


# ----------------------------------------------------------------------------- threaded writing


@pytest.mark.parametrize("fmt", list(LogFormat))
def test_threaded_writer_writes_what_the_plain_one_does(tmp_path: Path, fmt: LogFormat) -> None:
    messages = _messages()
    written = {}
    for threaded in (False, True):
        target = tmp_path / str(threaded) / OUTPUT_NAMES[fmt]
        target.parent.mkdir()
        with open_writer(target, fmt, threaded=threaded) as writer:
            for topic, message, log_time in messages:
                writer.add_message(topic, message, log_time)
        assert writer.summary().message_count == len(messages)
        assert [p.name for p in target.parent.iterdir()] == [target.name]
        written[threaded] = _read_anyreader(target)
    assert len(written[True]) == len(messages)
    for (topic, msgtype, time, plain), (topic2, msgtype2, time2, threaded_message) in zip(
        written[False], written[True], strict=True
    ):
        assert (topic, msgtype, time) == (topic2, msgtype2, time2)
        _check_same(plain, threaded_message)


@pytest.mark.parametrize("fail_at", [1, 7, 18])
def test_threaded_writer_error_is_raised_and_nothing_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail_at: int
) -> None:
    """A failure in the writer thread surfaces in the caller; the old target survives."""
    calls = 0
    original = McapLogWriter._add_message

    def failing(self: McapLogWriter, *args: Any) -> None:
        nonlocal calls
        calls += 1
        if calls == fail_at:
            raise OSError(28, "No space left on device")
        original(self, *args)

    monkeypatch.setattr(McapLogWriter, "_add_message", failing)
    target = tmp_path / "out.mcap"
    target.write_bytes(b"the old output")
    messages = _messages(3)  # 18 messages: the last one fails at close at the latest
    match = r"writing .*out\.mcap failed: OSError: .*No space left on device; nothing was written"

    def write() -> None:
        with open_writer(target, LogFormat.MCAP, threaded=True) as writer:
            for topic, message, log_time in messages:
                writer.add_message(topic, message, log_time)

    with pytest.raises(LogWriteError, match=match):
        write()
    assert target.read_bytes() == b"the old output"
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]  # no partial folder left
    assert calls <= len(messages)  # work queued after the failure is not run


FULL_DISK = (
    r"writing .*{name} failed: {error}.*; nothing was written there; "
    "free some space, or write it elsewhere$"
)


def _big_frames(count: int) -> list[tuple[str, Any, int]]:
    """Depth images of ~1.9 MB each: every format writes a chunk before the last one."""
    rng = np.random.default_rng(1)
    depth = rng.uniform(1, 50, size=(600, 800)).astype(np.float32)
    return [
        ("/ground_truth/depth", rosmsg.image_message(depth, T0 + i * DT, "left"), T0 + i * DT)
        for i in range(count)
    ]


@pytest.mark.parametrize("fmt", [LogFormat.MCAP, LogFormat.ROSBAG2, LogFormat.ROS1])
@pytest.mark.parametrize("threaded", [False, True], ids=["plain", "threaded"])
@pytest.mark.parametrize("where", ["at-open", "mid-stream", "at-close"])
def test_a_full_disk_is_one_error_and_writes_nothing(
    tmp_path: Path, full_disk: Callable[[int], None], fmt: LogFormat, threaded: bool, where: str
) -> None:
    """ENOSPC at the header, mid-way or at the close (summary, index, metadata.yaml): a
    LogWriteError naming the output, never the OSError itself; no target, no partial."""
    messages = _big_frames(4) if where == "mid-stream" else _messages(2)

    def write(target: Path) -> None:
        with open_writer(target, fmt, threaded=threaded) as writer:
            for topic, message, log_time in messages:
                writer.add_message(topic, message, log_time)

    whole = tmp_path / "whole"
    whole.mkdir()
    write(whole / OUTPUT_NAMES[fmt])
    size = sum(path.stat().st_size for path in whole.rglob("*") if path.is_file())
    shutil.rmtree(whole)
    full_disk({"at-open": 0, "mid-stream": size // 2, "at-close": size - 1}[where])
    target = tmp_path / OUTPUT_NAMES[fmt]
    match = FULL_DISK.format(name=target.name, error=r"OSError: \[Errno 28\] No space left")
    with warnings.catch_warnings():
        if fmt is LogFormat.ROSBAG2 and where == "at-open":
            # rosbags' MCAP storage writes its header in its constructor: failing there, it
            # leaves its open file to the garbage collector (a ResourceWarning)
            warnings.simplefilter("ignore", ResourceWarning)
        with pytest.raises(LogWriteError, match=match) as raised:
            write(target)
        assert isinstance(raised.value.__cause__, OSError)
        del raised
        gc.collect()
    assert list(tmp_path.iterdir()) == []  # no target, no partial folder


def test_a_full_sqlite_database_is_one_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SQLite says "database or disk is full" in its own exception, not an OSError."""
    import sqlite3

    def full(*args: Any) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(Rosbag2LogWriter, "_add_message", full)
    target = tmp_path / OUTPUT_NAMES[LogFormat.ROSBAG2_SQLITE3]
    match = FULL_DISK.format(name=target.name, error="OperationalError: database or disk is full")
    with (
        pytest.raises(LogWriteError, match=match),
        open_writer(target, LogFormat.ROSBAG2_SQLITE3) as writer,
    ):
        writer.add_message(*_messages(1)[0])
    assert list(tmp_path.iterdir()) == []


def test_threaded_writer_drops_queued_work_on_caller_error(tmp_path: Path) -> None:
    target = tmp_path / "out.mcap"

    def interrupted() -> None:
        with open_writer(target, threaded=True) as writer:
            for topic, message, log_time in _messages(3):
                writer.add_message(topic, message, log_time)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        interrupted()
    assert list(tmp_path.iterdir()) == []


def test_mcap_chunks_are_zstd_at_the_writer_level(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    levels: list[int] = []
    real = zstandard.ZstdCompressor

    def recording(level: int) -> zstandard.ZstdCompressor:
        levels.append(level)
        return real(level=level)

    monkeypatch.setattr(zstandard, "ZstdCompressor", recording)
    target = tmp_path / "out.mcap"
    with open_writer(target, threaded=True) as writer:  # a fresh thread: no cached compressor
        for topic, message, log_time in _messages(2):
            writer.add_message(topic, message, log_time)
    assert levels == [MCAP_ZSTD_LEVEL]
    with target.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    assert {index.compression for index in summary.chunk_indexes} == {"zstd"}
    # other users of mcap's writer in the process keep zstd's default level
    data = bytes(range(256)) * 64
    assert mcap.writer.zstandard.compress(data) == zstandard.compress(data, 3)


def test_mcap_chunk_crcs_check_out_with_zlib(tmp_path: Path) -> None:
    # the writer checksums with zlib-ng; mcap's reader validates with the standard zlib
    target = tmp_path / "out.mcap"
    messages = _messages(40)
    with open_writer(target, threaded=True) as writer:
        for topic, message, log_time in messages:
            writer.add_message(topic, message, log_time)
    with target.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        assert all(index.compression == "zstd" for index in summary.chunk_indexes)
        assert sum(1 for _ in reader.iter_messages()) == len(messages)
    with target.open("rb") as stream:  # the chunks' CRCs, recomputed here
        records = list(StreamReader(stream, skip_magic=False, emit_chunks=True).records)
    chunks = [record for record in records if isinstance(record, Chunk)]
    assert chunks
    for chunk in chunks:
        data = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        assert chunk.uncompressed_crc == zlib.crc32(data) != 0


def test_mcap_chunks_built_from_parts_hold_what_was_written_even_if_changed_later(
    tmp_path: Path,
) -> None:
    # mcap's writer is patched for the whole process: a buffer its owner reuses is copied
    # when written, bytes and views of bytes are kept by reference, and every record reads
    # back as written, with chunk offsets the reader's index finds
    target = tmp_path / "out.mcap"
    reused = bytearray(b"first")
    chunk_of_input = bytes(range(256)) * 4
    with target.open("wb") as stream:
        writer = mcap.writer.Writer(stream, chunk_size=1 << 10)
        writer.start()
        channel = writer.register_channel("/t", "raw", 0)
        writer.add_message(channel, 1, reused, 1)
        reused[:] = b"later"  # changed before the chunk ends
        writer.add_message(channel, 2, memoryview(chunk_of_input)[10:700], 2)
        writer.add_message(channel, 3, np.arange(6, dtype=np.uint8).data, 3)
        for time in range(4, 40):
            writer.add_message(channel, time, bytes([time]) * time, time)
        writer.finish()
    with target.open("rb") as stream:
        read = [(m.log_time, bytes(m.data)) for _, _, m in make_reader(stream).iter_messages()]
    assert read[:3] == [(1, b"first"), (2, chunk_of_input[10:700]), (3, bytes(range(6)))]
    assert read[3:] == [(time, bytes([time]) * time) for time in range(4, 40)]


def _remove_under_a_writer(folder: Path) -> None:
    """``rm -r folder`` while a writer thread may still add a file to it (sqlite3's journal):
    removed again until it is gone, as a user's second ``rm -r`` would."""
    for _ in range(100):
        try:
            shutil.rmtree(folder)
        except OSError:  # "Directory not empty": the thread wrote into it meanwhile
            sleep(0.01)
        if not folder.exists():
            return
    raise AssertionError(f"{folder} could not be removed")


@pytest.mark.parametrize("fmt", list(LogFormat))
@pytest.mark.parametrize("threaded", [False, True], ids=["plain", "threaded"])
def test_an_output_folder_removed_before_the_commit_says_so(
    tmp_path: Path, fmt: LogFormat, threaded: bool
) -> None:
    """Bug hunt 7B F11a: "cannot move the finished output onto X: No such file or
    directory; check the folder's permissions" for a folder removed under the job."""
    folder = tmp_path / "gone"
    folder.mkdir()
    target = folder / OUTPUT_NAMES[fmt]

    def write() -> None:
        with open_writer(target, fmt, threaded=threaded) as writer:
            for topic, message, log_time in _messages(1):
                writer.add_message(topic, message, log_time)
            _remove_under_a_writer(folder)  # the close, then the rename, find no folder

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResourceWarning)  # a bag library's file left open
        with pytest.raises(LogWriteError) as raised:
            write()
        gc.collect()
    assert str(raised.value) == (
        f"cannot write {target}: folder {folder} no longer exists (removed while the output "
        "was being written); nothing was written"
    )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("removed", ["folder", "partial"])
def test_a_removed_output_folder_stops_the_writing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, removed: str
) -> None:
    """The writer notices within PARTIAL_CHECK_S that its partial output is gone: the job
    stops there, not after writing the rest of the log into an unlinked file."""
    monkeypatch.setattr(logwriter, "PARTIAL_CHECK_S", 0.0)  # check at every message
    folder = tmp_path / "gone"
    folder.mkdir()
    target = folder / "out.mcap"
    written = 0
    partial = folder  # the writer's partial folder, once it is made

    def write() -> None:
        nonlocal written, partial
        with open_writer(target, LogFormat.MCAP, threaded=True) as writer:
            for topic, message, log_time in _messages(2):
                writer.add_message(topic, message, log_time)
                written += 1
                if written == 3:
                    (partial,) = folder.iterdir()
                    shutil.rmtree(folder if removed == "folder" else partial)

    with pytest.raises(LogWriteError) as raised:
        write()
    assert written == 3  # the next message was refused
    reason = (
        f"folder {folder} no longer exists (removed while the output was being written)"
        if removed == "folder"
        else f"its partial output {partial} was removed while the output was being written"
    )
    assert str(raised.value) == f"cannot write {target}: {reason}; nothing was written"
    assert list(tmp_path.iterdir()) == ([] if removed == "folder" else [folder])
    if removed == "partial":
        assert list(folder.iterdir()) == []


def test_a_full_disk_in_an_out_dir_names_the_output_not_its_staging_folder(
    tmp_path: Path,
) -> None:
    """Bug hunt 9C F6: `densify --out-dir` said "writing DIR/.a_dense.mcap.partial-OWNER-XXXX/
    a_dense.mcap failed: ...; nothing was written there", a hidden folder already removed,
    and no fix."""
    from pcainterp_stream.io.logwriter import write_failed
    from pcainterp_stream.io.output_paths import partial_prefix

    out = tmp_path / "dd" / "a_dense.mcap"
    staged = out.parent / (partial_prefix(out, out.parent) + "dq0rdd3r") / out.name
    full = OSError(errno.ENOSPC, "No space left on device")
    assert str(write_failed(staged, full)) == (
        f"writing {out} failed: OSError: [Errno 28] No space left on device; nothing was "
        "written there; free some space, or write it elsewhere"
    )
    other = tmp_path / "dd" / ".a_dense.mcap.mine" / "a_dense.mcap"  # not a staging folder
    assert str(write_failed(other, ValueError("x"))) == (
        f"writing {other} failed: ValueError: x; nothing was written there"
    )
