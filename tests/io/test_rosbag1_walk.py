"""ROS 1 bags without a usable index (a killed ``rosbag record``) read in file order.

The bags are written with rosbags' own Writer (chunked, lz4 or bz2, camera images and
infos), then cut as a killed recorder leaves them: no index section, a bag header whose
``index_pos`` is 0, or the file cut inside a chunk.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Reader, Writer

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.logreader import LogFormat, decode_image, open_log
from pcainterp_stream.io.rosbag1_walk import VERSION_LINE, Ros1WalkReader, read_bag_header
from pcainterp_stream.io.rosbags_reader import RosbagsLogReader
from pcainterp_stream.pipeline.jobs import synth

LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"
Message = tuple[str, int, bytes]  # topic, log time ns, CDR data


@pytest.fixture(scope="module")
def synth_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 6-frame eighth-size synthetic drive as a ROS 1 bag (images and camera infos)."""
    path = tmp_path_factory.mktemp("walk") / "synth.bag"
    synth(path, frames=6, seed=5, scale=0.125, fmt="ros1")
    return path


def rerecord(source: Path, target: Path, compression: str, chunk_bytes: int = 6000) -> Path:
    """Copy a bag with rosbags' Writer: small chunks, ``compression`` none, lz4 or bz2."""
    writer = Writer(target)
    if compression != "none":
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    writer.chunk_threshold = chunk_bytes
    with Reader(source) as reader, writer:
        connections = {
            c.id: writer.add_connection(
                c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest, callerid="/record"
            )
            for c in reader.connections
        }
        for connection, time_ns, data in reader.messages():
            writer.write(connections[connection.id], time_ns, data)
    return target


def header_field(data: bytes, name: bytes) -> int:
    """Return the offset of a bag header field's value."""
    return data.index(name + b"=") + len(name) + 1


def unindex(bag: Path, target: Path, *, cut: int | None = None) -> Path:
    """Write ``bag`` as a killed recorder leaves it: header index_pos, counts 0, no index.

    ``cut``: keep only the first ``cut`` bytes (default: everything before the index).
    """
    data = bytearray(bag.read_bytes())
    index_pos = struct.unpack_from("<Q", data, header_field(data, b"index_pos"))[0]
    struct.pack_into("<Q", data, header_field(data, b"index_pos"), 0)
    struct.pack_into("<I", data, header_field(data, b"conn_count"), 0)
    struct.pack_into("<I", data, header_field(data, b"chunk_count"), 0)
    target.write_bytes(bytes(data[: index_pos if cut is None else cut]))
    return target


def chunk_spans(bag: Path) -> list[tuple[int, int, int]]:
    """Return (start, end, messages) of every chunk record of an indexed bag."""
    with Reader(bag) as reader:
        return [
            (info.pos, reader.chunks[info.pos].datapos + reader.chunks[info.pos].datasize, n)
            for info in reader.chunk_infos
            for n in [sum(info.connection_counts.values())]
        ]


def read_all(path: Path) -> tuple[list[Message], list[str], type]:
    with open_log(path) as reader:
        messages = [(r.topic, r.log_time_ns, r.data) for r in reader.messages()]
        return messages, list(reader.damage), type(reader)


@pytest.mark.parametrize("compression", ["lz4", "bz2", "none"])
def test_unindexed_bag_reads_every_message_of_its_chunks(
    synth_bag: Path, tmp_path: Path, compression: str
) -> None:
    bag = rerecord(synth_bag, tmp_path / "drive.bag", compression)
    assert len(chunk_spans(bag)) > 5, "expected several chunks"
    intact, damage, kind = read_all(bag)
    assert kind is RosbagsLogReader
    assert damage == []
    active = unindex(bag, tmp_path / "drive.bag.active")
    header = read_bag_header(active)
    assert header is not None
    assert header.index_pos == 0
    messages, damage, kind = read_all(active)
    assert kind is Ros1WalkReader
    # a recorder writes its chunks in time order: file order is the intact bag's order
    assert messages == intact
    size = active.stat().st_size
    assert damage == [
        f"drive.bag.active: unindexed (recording cut off?): read {len(intact)} messages in "
        f"file order up to byte {size} of {size}; rosbag reindex drive.bag.active restores "
        "its index"
    ]
    with open_log(active) as reader:
        assert reader.format is LogFormat.ROS1
        assert not reader.indexed()
        assert reader.message_stats() is None
        topics = reader.topics()
        assert topics[LEFT].message_count == 6
        assert topics[LEFT].msgtype == "sensor_msgs/msg/Image"
        left = next(iter(reader.messages([LEFT])))
        assert decode_image(reader.decode(left)).shape == (47, 155)


@pytest.mark.parametrize("compression", ["lz4", "bz2", "none"])
def test_bag_cut_inside_a_chunk_reads_the_complete_chunks(
    synth_bag: Path, tmp_path: Path, compression: str
) -> None:
    bag = rerecord(synth_bag, tmp_path / "drive.bag", compression)
    intact, _, _ = read_all(bag)
    spans = chunk_spans(bag)
    rng = np.random.default_rng(11)
    for index in (len(spans) // 2, len(spans) - 1):
        start, end, _ = spans[index]
        cut = int(rng.integers(start + 100, end))  # past the chunk's record header
        complete = sum(n for _, chunk_end, n in spans if chunk_end <= cut)
        for damaged in (
            unindex(bag, tmp_path / "cut.bag.active", cut=cut),  # killed recorder
            tmp_path / "copy_cut.bag",  # an indexed bag whose copy broke off
        ):
            if damaged.suffix == ".bag":
                damaged.write_bytes(bag.read_bytes()[:cut])
            messages, damage, kind = read_all(damaged)
            assert kind is Ros1WalkReader
            # every complete chunk, and (uncompressed) the complete records of the cut one
            assert len(messages) >= complete
            assert messages == intact[: len(messages)]
            assert len(damage) == 1
            assert re.search(
                rf"read {len(messages)} messages in file order up to byte {start} of {cut} "
                r"\(then a chunk of \d+ bytes, \d+ left: cut short.*\); rosbag reindex",
                damage[0],
            ), damage[0]
            if damaged.suffix == ".bag":
                assert "index missing (the bag header puts it at byte" in damage[0]


def test_killed_recorders_open_chunk_is_read(synth_bag: Path, tmp_path: Path) -> None:
    """``rosbag record`` writes a chunk's header with sizes 0 and then its records straight
    into the file (uncompressed); killed, the sizes stay 0 and the records follow."""
    bag = rerecord(synth_bag, tmp_path / "drive.bag", "none")
    intact, _, _ = read_all(bag)
    spans = chunk_spans(bag)
    start, end, _ = spans[-1]
    data = bytearray(unindex(bag, tmp_path / "x.bag").read_bytes())
    (header_length,) = struct.unpack_from("<I", data, start)
    header = data[start + 4 : start + 4 + header_length]
    size_at = start + 4 + header.index(b"size=") + len(b"size=")
    struct.pack_into("<I", data, size_at, 0)
    struct.pack_into("<I", data, start + 4 + header_length, 0)  # data_len
    cut = end - 100  # the last message record half written
    active = tmp_path / "killed.bag.active"
    active.write_bytes(bytes(data[:cut]))
    messages, damage, _ = read_all(active)
    assert messages == intact[: len(intact) - 1]
    assert re.search(r"up to byte \d+ of \d+ \(then a record .*cut short\)", damage[0]), damage[0]


def test_corrupt_chunk_is_skipped_and_the_rest_read(synth_bag: Path, tmp_path: Path) -> None:
    bag = rerecord(synth_bag, tmp_path / "drive.bag", "bz2")  # bz2 checks a CRC, lz4 does not
    intact, _, _ = read_all(bag)
    spans = chunk_spans(bag)
    start, end, count = spans[2]
    data = bytearray(unindex(bag, tmp_path / "x.bag").read_bytes())
    data[end - 40 : end - 8] = b"\xff" * 32  # inside the bz2 data; the framing is intact
    damaged = tmp_path / "corrupt.bag"
    damaged.write_bytes(bytes(data))
    messages, damage, _ = read_all(damaged)
    skipped = sum(n for _, _, n in spans[:2])
    assert messages == intact[:skipped] + intact[skipped + count :]
    assert any("corrupt chunk skipped" in note and f"at byte {start}" in note for note in damage), (
        damage
    )


def test_length_fields_do_not_allocate(synth_bag: Path, tmp_path: Path) -> None:
    """A record header length of 2^32 - 1 ends the walk with a note, not an allocation."""
    bag = unindex(rerecord(synth_bag, tmp_path / "drive.bag", "bz2"), tmp_path / "x.bag")
    data = bytearray(bag.read_bytes())
    start = chunk_spans(rerecord(synth_bag, tmp_path / "again.bag", "bz2"))[1][0]
    struct.pack_into("<I", data, start, 0xFFFFFFFF)
    bag.write_bytes(bytes(data))
    messages, damage, _ = read_all(bag)
    assert len(messages) > 0
    assert f"up to byte {start} of" in damage[0]
    assert "record header of 4294967295 bytes: cut short" in damage[0]


def test_an_intact_bag_without_messages_reads_as_before(tmp_path: Path) -> None:
    """Its bag header puts the (empty) index at the end of the file: not a missing index."""
    path = tmp_path / "empty.bag"
    with Writer(path):
        pass
    header = read_bag_header(path)
    assert header is not None
    assert header.index_pos == header.size
    messages, damage, kind = read_all(path)
    assert (messages, damage, kind) == ([], [], RosbagsLogReader)


def test_unreadable_bag_header_is_still_an_error_naming_reindex(tmp_path: Path) -> None:
    path = tmp_path / "bad.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + b"\xff" * 100)
    assert read_bag_header(path) is None
    with pytest.raises(LogReadError, match=r"cannot read ROS 1 bag .*; if it is damaged, `rosbag"):
        open_log(path)


def test_densify_reads_a_killed_recording(
    synth_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    active = unindex(rerecord(synth_bag, tmp_path / "drive.bag", "lz4"), tmp_path / "d.bag.active")
    out = tmp_path / "dense.mcap"
    run: Callable[[list[str]], int] = cli.main
    code = run(["densify", str(active), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "densified 6 frames" in captured.out
    assert re.search(r"damage: d\.bag\.active: unindexed \(recording cut off\?\)", captured.out)
    assert out.is_file()


@pytest.mark.slow
@pytest.mark.parametrize("compression", ["lz4", "bz2", "none"])
def test_random_damage_to_an_unindexed_bag_never_escapes(
    synth_bag: Path, tmp_path: Path, compression: str
) -> None:
    """Flipped bytes and cuts: the walk reads on or stops with damage, no library exception."""
    bag = unindex(rerecord(synth_bag, tmp_path / "drive.bag", compression), tmp_path / "x.bag")
    data = bag.read_bytes()
    rng = np.random.default_rng(3)
    damaged = tmp_path / "damaged.bag.active"
    errors: list[str] = []
    for trial in range(24):
        buffer = bytearray(data)
        if trial % 3 == 0:
            buffer = buffer[: int(rng.integers(len(VERSION_LINE), len(buffer)))]
        else:
            for position in rng.integers(4200, len(buffer), int(rng.integers(1, 6))):
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
                assert reader.damage
        except LogReadError as err:
            errors.append(str(err))
    assert all("\n" not in message for message in errors)


def test_a_connection_without_a_topic_is_damage_not_a_traceback(
    synth_bag: Path, tmp_path: Path
) -> None:
    bag = unindex(rerecord(synth_bag, tmp_path / "drive.bag", "none"), tmp_path / "x.bag")
    data = bytearray(bag.read_bytes())
    start = data.index(b"topic=" + LEFT.encode()) - 4  # the field's 4-byte length first
    size = struct.unpack_from("<I", data, start)[0]
    filler = b"x=" + b"_" * (size - 12)  # as many bytes: "topic=" and a field of filler
    data[start : start + 4 + size] = (
        struct.pack("<I", 6) + b"topic=" + struct.pack("<I", len(filler)) + filler
    )
    damaged = tmp_path / "empty_topic.bag"
    damaged.write_bytes(bytes(data))
    messages, damage, _ = read_all(damaged)  # before: IndexError from an empty topic
    assert any("connection record without topic" in note for note in damage), damage
    assert LEFT not in {topic for topic, _, _ in messages}
