"""An MCAP input's attachments, metadata records and channels without messages, copied."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import McapLogReader, open_log
from pcainterp_stream.io.logwriter import McapLogWriter, open_writer
from pcainterp_stream.io.mcap_extras import size_text

IMAGE = "sensor_msgs/msg/Image"
URDF = b'<robot name="r2d2"><link name="base"/></robot>'
BIG = np.random.default_rng(0).integers(0, 256, 3 << 20, dtype=np.uint8).tobytes()  # 3 MiB
ATTACHMENTS = [
    ("robot.urdf", "application/xml", 5, 7, URDF),
    ("calibration.bin", "", 9, 0, BIG),  # larger than a read block, no media type
]
QOS = {"offered_qos_profiles": "- history: 1\n  depth: 1\n"}
CHANNELS = [
    ("/cam", "cdr", IMAGE, QOS),
    ("/empty", "cdr", IMAGE, QOS),
    ("/json_empty", "json", "foxglove.Log", {}),
    ("/raw_empty", "application/octet-stream", "", {}),
]
METADATA = [
    ("rosbag2", {"serialized_metadata": "rosbag2_bagfile_information: {}", "ros_distro": "humble"}),
    ("robot", {}),
]


def write_input(path: Path, attachments: list[Any] = ATTACHMENTS, **options: Any) -> None:
    """Write an MCAP with messages, channels without messages, attachments and metadata."""
    with path.open("wb") as f:
        writer = Writer(f, **options)
        writer.start("ros2", "test")
        image = writer.register_schema(IMAGE, "ros2msg", rosmsg.schema_text(IMAGE).encode())
        camera = writer.register_channel("/cam", "cdr", image, QOS)
        writer.register_channel("/empty", "cdr", image, QOS)
        log = writer.register_schema("foxglove.Log", "jsonschema", json.dumps({}).encode())
        writer.register_channel("/json_empty", "json", log)
        writer.register_channel("/raw_empty", "application/octet-stream", 0)
        writer.add_metadata(*METADATA[0])
        for i in range(3):
            stamp = 1_000_000_000 + i
            message = rosmsg.image_message(np.zeros((2, 3), np.uint8), stamp, "c")
            writer.add_message(camera, stamp, rosmsg.serialize(message), stamp)
            if i == 1:
                for name, media_type, log_time, create_time, data in attachments:
                    writer.add_attachment(create_time, log_time, name, media_type, data)
        writer.add_metadata(*METADATA[1])
        writer.finish()


def contents(path: Path) -> tuple[list[Any], list[Any], list[Any]]:
    """Return (channels, attachments, metadata) of an MCAP as mcap's own reader reads them."""
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = [
            (
                channel.topic,
                channel.message_encoding,
                summary.schemas[channel.schema_id].name if channel.schema_id else "",
                dict(channel.metadata),
            )
            for channel in sorted(summary.channels.values(), key=lambda c: c.id)
        ]
        attachments = [
            (a.name, a.media_type, a.log_time, a.create_time, a.data)
            for a in reader.iter_attachments()
        ]
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    return channels, attachments, metadata


def copy(source: Path, target: Path, *, threaded: bool = False) -> list[str]:
    """Copy a log as densify does (extras first, then every message); return its damage."""
    with open_log(source) as reader, open_writer(target, "mcap", threaded=threaded) as writer:
        assert isinstance(reader, McapLogReader)
        assert isinstance(writer, McapLogWriter)
        writer.add_extras(reader.extras(verify=True))
        for raw in reader.messages():
            writer.add_raw(raw)
        return list(reader.damage)


INPUTS = {
    "indexed": {},
    "no summary indexes": {"index_types": IndexType.NONE},
    "no summary": {
        "index_types": IndexType.NONE,
        "repeat_channels": False,
        "repeat_schemas": False,
        "use_statistics": False,
        "use_summary_offsets": False,
    },
    "unchunked": {"use_chunking": False},
}


@pytest.mark.parametrize("options", INPUTS.values(), ids=INPUTS.keys())
@pytest.mark.parametrize("threaded", [False, True])
def test_copy_keeps_attachments_metadata_and_channels_without_messages(
    tmp_path: Path, options: dict[str, Any], threaded: bool
) -> None:
    source, target = tmp_path / "in.mcap", tmp_path / "out.mcap"
    write_input(source, **options)
    assert copy(source, target, threaded=threaded) == []
    channels, attachments, metadata = contents(target)
    assert channels == CHANNELS  # each once, in the input's order; before: /cam only
    assert [item[:4] for item in attachments] == [item[:4] for item in ATTACHMENTS]
    assert attachments[0][4] == URDF  # before: no attachment
    assert attachments[1][4] == BIG
    assert metadata == METADATA  # before: none


def test_extras_of_a_log_without_any(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    with open_writer(path, "mcap") as writer:
        writer.add_message("/cam", rosmsg.image_message(np.zeros((2, 3), np.uint8), 5, "c"), 5)
    with open_log(path) as reader:
        assert isinstance(reader, McapLogReader)
        extras = reader.extras(verify=True)
    assert (extras.attachments, extras.metadata) == ([], [])
    assert [channel.topic for channel in extras.channels] == ["/cam"]


def test_a_damaged_attachment_is_left_out_and_named(tmp_path: Path) -> None:
    source, target = tmp_path / "in.mcap", tmp_path / "out.mcap"
    write_input(source)
    data = bytearray(source.read_bytes())
    at = data.find(URDF)
    data[at + 3] ^= 0xFF
    source.write_bytes(bytes(data))
    damage = copy(source, target)
    assert len(damage) == 1
    assert "in.mcap: corrupt attachment left out (CRC mismatch) at byte " in damage[0]
    _, attachments, metadata = contents(target)
    assert [item[0] for item in attachments] == ["calibration.bin"]
    assert metadata == METADATA
    with open_log(source) as reader:  # not verified: listed as the file states it
        assert isinstance(reader, McapLogReader)
        assert [item.name for item in reader.extras().attachments] == [
            "robot.urdf",
            "calibration.bin",
        ]


def test_an_index_pointing_elsewhere_is_damage_not_an_exception(tmp_path: Path) -> None:
    path = tmp_path / "in.mcap"
    write_input(path)
    with open_log(path) as reader:
        assert isinstance(reader, McapLogReader)
        reader._attachment_offsets[0] = 8  # the first record after the magic: a header
        reader._metadata_offsets[0] = path.stat().st_size + 10
        extras = reader.extras()
        assert [item.name for item in extras.attachments] == ["calibration.bin"]
        assert [record.name for record in extras.metadata] == ["robot"]
        assert len(reader.damage) == 2
        assert (
            "corrupt attachment left out (the index points to an opcode 0x01 record)"
            in (reader.damage[0])
        )
        assert "corrupt metadata record left out (it lies outside the file)" in reader.damage[1]


@pytest.mark.parametrize("options", INPUTS.values(), ids=INPUTS.keys())
def test_random_damage_never_escapes(tmp_path: Path, options: dict[str, Any]) -> None:
    source, damaged, target = tmp_path / "in.mcap", tmp_path / "damaged.mcap", tmp_path / "o.mcap"
    write_input(source, [ATTACHMENTS[0], ("b", "x", 1, 1, b"data" * 50)], **options)
    data = source.read_bytes()
    rng = np.random.default_rng(11)
    kept = 0
    for trial in range(150):
        buffer = bytearray(data)
        if trial % 3 == 0:
            buffer = buffer[: int(rng.integers(0, len(buffer)))]
        else:
            for position in rng.integers(0, len(buffer), int(rng.integers(1, 6))):
                buffer[position] = int(rng.integers(0, 256))
        damaged.write_bytes(bytes(buffer))
        try:
            reader = open_log(damaged)
        except LogReadError:
            continue
        with reader, open_writer(target, "mcap") as writer:
            assert isinstance(reader, McapLogReader)
            assert isinstance(writer, McapLogWriter)
            extras = reader.extras(verify=True)  # damage is noted, never raised
            writer.add_extras(extras)
            kept += len(extras.attachments)
    assert kept > 0


def test_a_ros1_channel_without_messages_is_copied_as_cdr(tmp_path: Path) -> None:
    store = rosmsg.TYPESTORE
    msgtype = "sensor_msgs/msg/CameraInfo"
    ros1_text, _ = store.generate_msgdef(msgtype, ros_version=1)
    source, target = tmp_path / "ros1.mcap", tmp_path / "out.mcap"
    camera = rosmsg.camera_info_message(_camera(), 5, "left")
    with source.open("wb") as f:
        writer = Writer(f)
        writer.start("ros1", "test")
        schema = writer.register_schema("sensor_msgs/CameraInfo", "ros1msg", ros1_text.encode())
        info = writer.register_channel("/left/camera_info", "ros1", schema)
        writer.register_channel("/right/camera_info", "ros1", schema)
        data = bytes(store.cdr_to_ros1(rosmsg.serialize(camera), msgtype))
        writer.add_message(info, 5, data, 5)
        writer.finish()
    assert copy(source, target) == []
    channels, _, _ = contents(target)
    assert channels == [
        ("/left/camera_info", "cdr", msgtype, {}),
        ("/right/camera_info", "cdr", msgtype, {}),
    ]


def _camera() -> Any:
    from pcainterp_stream.records import StereoCamera

    return StereoCamera(width=8, height=6, fx=50.0, fy=50.0, cx=4.0, cy=3.0, baseline=0.5)


def test_size_text() -> None:
    assert [size_text(n) for n in (0, 1023, 1024, 3 << 20, 5 << 30)] == [
        "0 bytes",
        "1023 bytes",
        "1.0 KiB",
        "3.0 MiB",
        "5.0 GiB",
    ]


REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"


@pytest.mark.realdata
@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real data folder {REALDATA} is absent")
@pytest.mark.parametrize(
    "path",
    sorted(REALDATA.glob("mcap_conformance/One[AM]*/*.mcap")) if REALDATA.is_dir() else [],
    ids=lambda p: p.name,
)
def test_conformance_files_are_copied_whole(path: Path, tmp_path: Path) -> None:
    records = json.loads(path.with_suffix(".json").read_text())["records"]
    fields = [dict(r["fields"]) for r in records if r["type"] in ("Attachment", "Metadata")]
    target = tmp_path / "copy.mcap"
    assert copy(path, target) == []  # with and without summary, indexes, CRCs, padding
    _, attachments, metadata = contents(target)
    assert attachments == [
        (
            f["name"],
            f["media_type"],
            int(f["log_time"]),
            int(f["create_time"]),
            bytes(int(b) for b in f["data"]),
        )
        for f in fields
        if "data" in f
    ]
    assert metadata == [(f["name"], f["metadata"]) for f in fields if "metadata" in f]
