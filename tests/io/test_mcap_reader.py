"""The MCAP reader: what it yields of channels it converts (a ``ros1`` profile's)."""

from __future__ import annotations

from pathlib import Path

from mcap.writer import Writer

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=32, height=24, fx=40.0, fy=40.0, cx=16.0, cy=12.0, baseline=0.5)
INFO = "/stereo/right/camera_info"


def test_a_ros1_channel_converted_to_cdr_drops_md5sum_and_keeps_latching(tmp_path: Path) -> None:
    """Before: the md5sum of the ROS 1 definition stayed on the CDR channel, latching lost."""
    store = rosmsg.TYPESTORE
    msgtype = "sensor_msgs/msg/CameraInfo"
    text, md5sum = store.generate_msgdef(msgtype, ros_version=1)
    message = rosmsg.camera_info_message(CAMERA, 1_500_000_000, "right", right=True)
    data = bytes(store.cdr_to_ros1(rosmsg.serialize(message), msgtype))
    path = tmp_path / "ros1.mcap"
    with path.open("wb") as f:  # as `mcap convert` writes a bag
        writer = Writer(f)
        writer.start("ros1", "test")
        schema = writer.register_schema("sensor_msgs/CameraInfo", "ros1msg", text.encode())
        metadata = {"md5sum": md5sum, "callerid": "/driver", "latching": "1"}
        channel = writer.register_channel(INFO, "ros1", schema, metadata)
        writer.add_message(channel, 5, data, 5)
        writer.finish()
    with open_log(path) as reader:
        (raw,) = list(reader.messages())
        (info,) = reader.extras().channels
    for got in (raw.channel_metadata, info.metadata):
        assert "md5sum" not in got
        assert got["callerid"] == "/driver"
        assert "  durability: 1\n" in got.get("offered_qos_profiles", "")  # transient local
