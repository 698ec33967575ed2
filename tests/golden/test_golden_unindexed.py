"""A complete log without its index is summarised; a cut one is refused (bug hunt 17A F2).

An unindexed ROS 1 bag (``rosbag record`` killed after its last chunk) and an MCAP whose
writer stopped after a whole record (no summary, footer or end magic; no data-end record
either when killed) are read to the end of the file: their golden summary is the indexed
log's. A log cut inside a record is still refused.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer
from rosbags.rosbag1 import Writer as Ros1Writer

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.golden import save_golden
from pcainterp_stream.io import rosmsg

TOPIC = "/chatter"


def _strings(count: int) -> list[tuple[int, bytes]]:
    string = rosmsg.TYPESTORE.types["std_msgs/msg/String"]
    return [
        (
            1_000_000_000 + i * 50_000_000,
            rosmsg.TYPESTORE.serialize_cdr(string(data=f"m{i}"), string.__msgtype__),
        )
        for i in range(count)
    ]


def _mcap(path: Path) -> Path:
    with path.open("wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD, chunk_size=200)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        channel = writer.register_channel(TOPIC, "cdr", schema)
        for time_ns, data in _strings(12):
            writer.add_message(channel, time_ns, data, time_ns)
        writer.finish()
    return path


def _bag(path: Path) -> Path:
    string = rosmsg.TYPESTORE.types["std_msgs/msg/String"]
    writer = Ros1Writer(path)
    writer.chunk_threshold = 200
    with writer:
        connection = writer.add_connection(TOPIC, "std_msgs/msg/String", typestore=rosmsg.TYPESTORE)
        for time_ns, _ in _strings(12):
            data = rosmsg.TYPESTORE.serialize_ros1(string(data=f"m{time_ns}"), string.__msgtype__)
            writer.write(connection, time_ns, data)
    return path


def _unindexed(bag: Path, target: Path, cut: int = 0) -> Path:
    """The bag as a killed recorder leaves it: index_pos and counts 0, no index section."""
    data = bytearray(bag.read_bytes())
    index_pos = 0
    for name, form in ((b"index_pos", "<Q"), (b"conn_count", "<I"), (b"chunk_count", "<I")):
        at = data.index(name + b"=") + len(name) + 1
        index_pos = index_pos or struct.unpack_from(form, data, at)[0]
        struct.pack_into(form, data, at, 0)
    target.write_bytes(bytes(data[: index_pos - cut]))
    return target


def _channels(path: Path) -> object:
    return save_golden(path, path.with_suffix(".golden.json")).channels


def test_an_mcap_missing_only_its_summary_or_footer_is_summarised(tmp_path: Path) -> None:
    whole = _mcap(tmp_path / "whole.mcap")
    data = whole.read_bytes()
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    expected = _channels(whole)
    data_end = summary_start - 13  # a data-end record: opcode, length 4, crc
    assert data[data_end] == 0x0F
    ends = (("no_magic", len(data) - 8), ("no_summary", summary_start), ("killed", data_end))
    for name, end in ends:
        cut = tmp_path / f"{name}.mcap"
        cut.write_bytes(data[:end])
        assert _channels(cut) == expected, name  # refused before: "is damaged: no MCAP magic"
    # cut inside a chunk, or inside a record's header: refused
    for name, end in (("mid_chunk", len(data) // 2), ("mid_header", data_end + 3)):
        cut = tmp_path / f"{name}.mcap"
        cut.write_bytes(data[:end])
        with pytest.raises(LogReadError, match=f"{name}.mcap is damaged: .*truncated"):
            save_golden(cut, tmp_path / f"{name}.golden.json")


def test_an_unindexed_complete_ros1_bag_is_summarised(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "whole.bag")
    expected = _channels(bag)
    assert _channels(_unindexed(bag, tmp_path / "unindexed.bag")) == expected
    cut = _unindexed(bag, tmp_path / "cut.bag", cut=30)  # inside its last chunk
    with pytest.raises(LogReadError, match=r"cut.bag is damaged: unindexed .* up to byte \d+ of"):
        save_golden(cut, tmp_path / "cut.golden.json")
