"""The rosbags-backed reader: ROS 1 bags and rosbag2 folders as the pipeline sees them."""

from __future__ import annotations

import sqlite3
import struct
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.loginfo import describe, format_info
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=32, height=24, fx=40.0, fy=40.0, cx=16.0, cy=12.0, baseline=0.5)
LEFT, LEFT_INFO = "/stereo/left/image_rect", "/stereo/left/camera_info"
STATUS = "my_robot_msgs/msg/Status"


def _frames(n: int) -> list[tuple[str, str, Any, int]]:
    rng = np.random.default_rng(3)
    out: list[tuple[str, str, Any, int]] = []
    for i in range(n):
        stamp = 1_000_000_000 + i * 100_000_000
        image = rng.integers(0, 256, (CAMERA.height, CAMERA.width), dtype=np.uint8)
        out.append((LEFT, rosmsg.IMAGE, rosmsg.image_message(image, stamp, "left"), stamp))
        info = rosmsg.camera_info_message(CAMERA, stamp, "left")
        out.append((LEFT_INFO, rosmsg.CAMERA_INFO, info, stamp))
    return out


def _status_store() -> Typestore:
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg("uint32 level", STATUS))
    return store


def test_a_custom_type_without_a_stored_definition_is_copied_and_the_rest_read(
    tmp_path: Path,
) -> None:
    """Humble's sqlite3 storage keeps no definitions: a custom type is unknown to rosbags.

    Before: the first message of /status ended the read as damage ("unreadable after
    message 1 (TypesysError ...)"), losing every later frame.
    """
    bag = tmp_path / "humble"
    frames = _frames(4)
    status = struct.pack("<4sI", b"\x00\x01\x00\x00", 7)  # CDR header, uint32 level
    with Writer(bag, version=8) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=rosmsg.TYPESTORE)
            for topic, msgtype, _, _ in frames[:2]
        }
        custom = writer.add_connection("/status", STATUS, typestore=_status_store())
        writer.write(custom, 999_000_000, status)
        for topic, _, message, stamp in frames:
            writer.write(connections[topic], stamp, rosmsg.serialize(message))
            if topic == LEFT:
                writer.write(custom, stamp + 1, status)
    with sqlite3.connect(next(bag.glob("*.db3"))) as db:  # as Humble's storage: no definition
        db.execute("DELETE FROM message_definitions WHERE topic_type = ?", (STATUS,))
    with open_log(bag) as reader:
        assert reader.topics()["/status"].schema_encoding == ""
        raws = list(reader.messages())
        assert reader.damage == []
        assert reader.warnings == [
            "humble: /status has type my_robot_msgs/msg/Status, whose definition the bag does "
            "not store; copied without one (an empty schema, as rosbag2 records it)"
        ]
        assert [r.topic for r in raws].count(LEFT) == 4
        copies = [r for r in raws if r.topic == "/status"]
        assert len(copies) == 5
        assert {(r.msgtype, r.schema_name, r.schema_encoding, r.schema_data) for r in copies} == {
            (STATUS, STATUS, "", b"")
        }
        assert copies[0].data == status
        assert copies[0].message_encoding == "cdr"
    text = format_info(describe(bag))
    assert text.splitlines()[-1].split() == ["/status", "5", STATUS, "(no", "definition", "stored)"]


def _ros1_bag(path: Path, *, latched: str) -> Path:
    """A ROS 1 bag of 2 frames; connections of topics ending ``latched`` have latching=1."""
    from rosbags.rosbag1 import Writer as Ros1Writer

    store = rosmsg.TYPESTORE
    with Ros1Writer(path) as writer:
        connections: dict[str, Any] = {}
        for topic, msgtype, message, stamp in _frames(2):
            if topic not in connections:
                msgdef, md5sum = store.generate_msgdef(msgtype, ros_version=1)
                connections[topic] = writer.add_connection(
                    topic,
                    msgtype,
                    msgdef=msgdef,
                    md5sum=md5sum,
                    callerid="/driver",
                    latching=int(topic.endswith(latched)),
                )
            data = store.cdr_to_ros1(rosmsg.serialize(message), msgtype)
            writer.write(connections[topic], stamp, data)
    return path


def test_a_latched_ros1_connection_is_offered_transient_local(tmp_path: Path) -> None:
    """Before: every ROS 1 channel came out with no metadata, a latched one volatile."""
    bag = _ros1_bag(tmp_path / "latched.bag", latched="camera_info")
    unindexed = tmp_path / "unindexed.bag"  # as a killed recorder leaves it: no index
    data = bytearray(bag.read_bytes())
    field = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = struct.unpack_from("<Q", data, field)[0]
    struct.pack_into("<Q", data, field, 0)
    unindexed.write_bytes(bytes(data[:index_pos]))
    for path in (bag, unindexed):
        with open_log(path) as reader:
            metadata = {raw.topic: raw.channel_metadata for raw in reader.messages()}
        assert metadata[LEFT] == {}, path.name
        qos = metadata[LEFT_INFO].get("offered_qos_profiles", "")
        # reliable (1), transient local (1), durations infinite: as rosbags-convert writes it
        assert qos.startswith("- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n")
        assert "    sec: 2147483647\n    nsec: 4294967295" in qos


CUSTOM = "my_msgs/msg/Custom"
MARKER = "visualization_msgs/msg/Marker"


def _ros1_types_bag(path: Path) -> Path:
    """A ROS 1 bag with a Marker (ROS 1 layout) and a custom type with upper-case names."""
    from rosbags.rosbag1 import Writer as Ros1Writer

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("int32 MAX=3\nfloat64 X\nstring Name\nint32 x", CUSTOM))
    types = store.types
    header = types["std_msgs/msg/Header"](
        seq=7, stamp=types["builtin_interfaces/msg/Time"](sec=5, nanosec=6), frame_id="map"
    )
    point = types["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0)
    color = types["std_msgs/msg/ColorRGBA"](r=1.0, g=0.5, b=0.25, a=1.0)
    marker = types[MARKER](
        header=header,
        ns="n",
        id=3,
        type=2,
        action=0,
        pose=types["geometry_msgs/msg/Pose"](
            position=point, orientation=types["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1)
        ),
        scale=types["geometry_msgs/msg/Vector3"](x=1.0, y=1.0, z=1.0),
        color=color,
        lifetime=types["builtin_interfaces/msg/Duration"](sec=1, nanosec=5),
        frame_locked=True,
        points=[point],
        colors=[color],
        text="hi",
        mesh_resource="",
        mesh_use_embedded_materials=False,
    )
    custom = types[CUSTOM](X=1.5, Name="abc", x=4)
    with Ros1Writer(path) as writer:
        for topic, msgtype, message in (("/markers", MARKER, marker), ("/custom", CUSTOM, custom)):
            connection = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connection, 1_000_000_000, store.serialize_ros1(message, msgtype))
    return path


def test_a_ros1_type_of_another_layout_is_migrated_to_the_ros2_one(tmp_path: Path) -> None:
    """Before: /markers kept the ROS 1 Marker layout under the ROS 2 name (no texture...)."""
    with open_log(
        _ros1_types_bag(
            tmp_path / "types.bag",
        )
    ) as reader:
        raw = next(r for r in reader.messages() if r.topic == "/markers")
    assert raw.schema_data == rosmsg.schema_text(MARKER).encode()
    marker = rosmsg.deserialize(raw.data, MARKER)  # the ROS 2 type as installed
    assert (marker.ns, marker.id, marker.text, marker.header.frame_id) == ("n", 3, "hi", "map")
    assert (marker.points[0].z, marker.colors[0].g, marker.lifetime.nanosec) == (3.0, 0.5, 5)
    assert (marker.texture_resource, marker.mesh_file.filename) == ("", "")  # added in ROS 2


def test_a_ros1_custom_type_gets_ros2_legal_names(tmp_path: Path) -> None:
    """Before: ``float64 X`` stayed as it was; mcap_ros2 and Foxglove refuse that schema."""
    with open_log(_ros1_types_bag(tmp_path / "types.bag")) as reader:
        raw = next(r for r in reader.messages() if r.topic == "/custom")
        message = reader.decode(raw)
    assert raw.schema_data.decode().splitlines() == [
        "int32 MAX=3",
        "float64 x_2",  # x is taken
        "string name",
        "int32 x",
    ]
    assert (message.x_2, message.name, message.x) == (1.5, "abc", 4)


OLD_CAMERA_INFO = """Header header
uint32 height
uint32 width
RegionOfInterest roi
float64[5] D
float64[9] K
float64[9] R
float64[12] P
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: sensor_msgs/RegionOfInterest
uint32 x_offset
uint32 y_offset
uint32 height
uint32 width
"""
"""``sensor_msgs/CameraInfo`` before ROS Electric (md5 1b5cf7f984c229b6141ceb3a955aa18f)."""


def _old_definition_bag(
    path: Path, typename: str, msgdef: str, messages: list[dict[str, Any]]
) -> Path:
    """A ROS 1 bag of ``typename`` messages written with an older definition of it."""
    from rosbags.rosbag1 import Writer as Ros1Writer

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(msgdef, typename))
    types = store.types
    with Ros1Writer(path) as writer:
        text, md5sum = store.generate_msgdef(typename)  # the md5 rosbag wrote for it
        connection = writer.add_connection("/old", typename, msgdef=text, md5sum=md5sum)
        for i, fields in enumerate(messages):
            header = types["std_msgs/msg/Header"](
                seq=i,
                stamp=types["builtin_interfaces/msg/Time"](sec=5 + i, nanosec=0),
                frame_id="c",
            )
            message = types[typename](header=header, **fields)
            writer.write(
                connection, 1_000_000_000 * (i + 1), store.serialize_ros1(message, typename)
            )
    return path


def test_a_pre_electric_ros1_camera_info_keeps_its_distortion(tmp_path: Path) -> None:
    """Before: ``float64[5] D`` had no place in ``float64[] d``: d = [], model '' (lens lost)."""
    roi = get_typestore(Stores.ROS1_NOETIC).types["sensor_msgs/msg/RegionOfInterest"]
    d = [-0.12, 0.02, 0.0008, -0.0005, 0.0]
    fields = {
        "height": 24,
        "width": 32,
        "roi": roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        "D": np.array(d),
        "K": np.array([40.0, 0, 16, 0, 40, 12, 0, 0, 1]),
        "R": np.eye(3).ravel(),
        "P": np.array([40.0, 0, 16, 0, 0, 40, 12, 0, 0, 0, 1, 0]),
    }
    store = get_typestore(Stores.EMPTY)  # the old RegionOfInterest has no do_rectify
    store.register(get_types_from_msg(OLD_CAMERA_INFO, "sensor_msgs/msg/CameraInfo"))
    fields["roi"] = store.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0
    )
    bag = _old_definition_bag(
        tmp_path / "old.bag", "sensor_msgs/msg/CameraInfo", OLD_CAMERA_INFO, [fields]
    )
    with open_log(bag) as reader:
        (raw,) = list(reader.messages())
        info = reader.decode(raw)
        assert reader.warnings == []
    assert info.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(info.d, d)
    np.testing.assert_array_equal(info.k, fields["K"])
    assert raw.schema_data == rosmsg.schema_text("sensor_msgs/msg/CameraInfo").encode()


def test_ros1_fields_with_no_ros2_place_are_warned_once_per_topic(tmp_path: Path) -> None:
    """Before: a field of the bag's definition the ROS 2 type lacks was dropped silently."""
    noetic = get_typestore(Stores.ROS1_NOETIC)
    definition = noetic.generate_msgdef("sensor_msgs/msg/Image")[0]
    definition = definition.replace("uint8[] data", "uint8[] data\nfloat64 exposure", 1)
    image = {"height": 1, "width": 2, "encoding": "mono8", "is_bigendian": 0, "step": 2}
    image["data"] = np.array([1, 2], dtype=np.uint8)
    bag = _old_definition_bag(
        tmp_path / "extra.bag",
        "sensor_msgs/msg/Image",
        definition,
        [{**image, "exposure": 0.0}, {**image, "exposure": 0.01}, {**image, "exposure": 0.02}],
    )
    with open_log(bag) as reader:
        images = [reader.decode(raw) for raw in reader.messages()]
        warnings = list(reader.warnings)
    assert [list(i.data) for i in images] == [[1, 2]] * 3
    assert len(warnings) == 1
    assert warnings[0].startswith(
        "/old: the log's ROS 1 definition of sensor_msgs/msg/Image has exposure"
    )
