"""An input's empty ros2msg schema is written as the standard definition (bug hunt 16G F5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.records import RawMessage, StereoCamera

CAMERA = StereoCamera(width=8, height=6, fx=50.0, fy=51.0, cx=4.0, cy=3.0, baseline=0.25)


def _raw(topic: str, message: object, msgtype: str, schema: bytes = b"") -> RawMessage:
    return RawMessage(
        topic=topic,
        msgtype=msgtype,
        schema_name=msgtype,
        schema_encoding="ros2msg",
        schema_data=schema,
        message_encoding="cdr",
        channel_metadata={},
        data=rosmsg.serialize(message),
        log_time_ns=1,
        publish_time_ns=1,
        sequence=0,
    )


def test_an_empty_standard_schema_is_copied_as_the_standard_definition(tmp_path: Path) -> None:
    """Bug hunt 16G F5: the copy kept 0-byte Image and CameraInfo schemas, so mcap_ros2
    decoded the copied camera topics as empty messages (``CameraInfo()``)."""
    info = rosmsg.camera_info_message(CAMERA, 1, "left")
    image = rosmsg.image_message(np.zeros((6, 8), np.uint8), 1, "left")
    target = tmp_path / "copy.mcap"
    with open_writer(target, LogFormat.MCAP) as writer:
        writer.add_raw(_raw("/cam/left/camera_info", info, rosmsg.CAMERA_INFO))
        writer.add_raw(_raw("/cam/left/image_raw", image, rosmsg.IMAGE))
        writer.add_raw(_raw("/custom", image, "my_msgs/msg/Unknown"))  # not known: kept
        writer.add_message("/pcainterp/depth", image, 1)  # shares the filled Image schema
    with target.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        decoded = {
            c.topic: m
            for _, c, _, m in reader.iter_decoded_messages(topics=["/cam/left/camera_info"])
        }
    assert summary is not None
    schemas = {s.name: s.data for s in summary.schemas.values()}
    assert len(summary.schemas) == 3
    assert schemas[rosmsg.CAMERA_INFO] == rosmsg.schema_text(rosmsg.CAMERA_INFO).encode()
    assert schemas[rosmsg.IMAGE] == rosmsg.schema_text(rosmsg.IMAGE).encode()
    assert schemas["my_msgs/msg/Unknown"] == b""
    assert decoded["/cam/left/camera_info"].width == 8
