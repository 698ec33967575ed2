"""ROS 1 type names as ROS 2 has them: rosbags-convert's renames, names ROS 2 refuses made legal.

A converted ROS 1 channel keeps the bag's type name in ROS 2 spelling; one ROS 2 refuses
(old ``tf``'s ``tf/tfMessage``, ``my_pkg/laser_scan``) made ``mcap_ros2``'s decoder stop
reading the whole output file (``InvalidResourceName``), and no ROS 2 node can have it.
Each test reads a ROS 1 log, copies its messages into an MCAP as ``densify`` does, and
decodes every message of that with ``mcap_ros2``.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.io.reader_base import ROS1_TYPE_RENAMES, ros1_type_name
from pcainterp_stream.io.rosbag1_walk import Ros1WalkReader

SEPARATOR = "=" * 80 + "\n"
Connection = tuple[str, str, str, list[dict[str, Any]]]  # topic, ROS 1 type, msgdef, messages


def _ros1_data(store: Typestore, typename: str, fields: dict[str, Any]) -> bytes:
    def build(name: str, values: dict[str, Any]) -> Any:
        kinds = dict(store.fielddefs[name][1])
        args = {}
        for key, value in values.items():
            _, detail = kinds[key]
            if isinstance(value, dict):  # a nested message
                value = build(detail, value)
            elif isinstance(value, list) and value and isinstance(value[0], dict):
                value = [build(detail[0][1], item) for item in value]
            args[key] = value
        return store.types[name](**args)

    return bytes(store.serialize_ros1(build(typename, fields), typename))


def _bag(path: Path, connections: list[Connection], *, indexed: bool = True) -> Path:
    """A ROS 1 bag of ``connections``; without its index (read by the walker) if not indexed."""
    with Ros1Writer(path) as writer:
        for i, (topic, typename, msgdef, messages) in enumerate(connections):
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(msgdef, typename))
            md5sum = store.generate_msgdef(typename)[1]  # what rosbag writes; rosbags checks it
            connection = writer.add_connection(topic, typename, msgdef=msgdef, md5sum=md5sum)
            for j, fields in enumerate(messages):
                data = _ros1_data(store, typename, fields)
                writer.write(connection, 1_000_000_000 + 1000 * (10 * i + j), data)
    if not indexed:  # as a killed recorder leaves it
        data = bytearray(path.read_bytes())
        field = data.index(b"index_pos=") + len(b"index_pos=")
        index_pos = struct.unpack_from("<Q", data, field)[0]
        struct.pack_into("<Q", data, field, 0)
        path.write_bytes(bytes(data[:index_pos]))
    return path


def _ros1_mcap(path: Path, connections: list[Connection]) -> Path:
    """The same as an MCAP of the ``ros1`` profile (``ros1msg`` schemas, ROS 1 messages)."""
    with path.open("wb") as f:
        writer = McapWriter(f)
        writer.start("ros1", "test")
        for i, (topic, typename, msgdef, messages) in enumerate(connections):
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(msgdef, typename))
            ros1_name = typename.replace("/msg/", "/")
            schema = writer.register_schema(ros1_name, "ros1msg", msgdef.encode())
            channel = writer.register_channel(topic, "ros1", schema)
            for j, fields in enumerate(messages):
                time = 1_000_000_000 + 1000 * (10 * i + j)
                writer.add_message(channel, time, _ros1_data(store, typename, fields), time)
        writer.finish()
    return path


READERS = ["bag", "unindexed bag", "ros1 mcap"]


def _copied(tmp_path: Path, kind: str, connections: list[Connection]) -> dict[str, Any]:
    """Read a ROS 1 log of ``kind``, copy it into an MCAP, decode that with mcap_ros2.

    Returns topic -> (schema name, [decoded messages]).
    """
    if kind == "ros1 mcap":
        log = _ros1_mcap(tmp_path / "in.mcap", connections)
    else:
        log = _bag(tmp_path / "in.bag", connections, indexed=kind == "bag")
    with open_log(log) as reader:
        assert isinstance(reader, Ros1WalkReader) == (kind == "unindexed bag")
        topics = {name: info.msgtype for name, info in reader.topics().items()}
        raws = list(reader.messages())
        assert reader.damage == [] or kind == "unindexed bag"  # that one notes the index lost
    out = tmp_path / "out.mcap"
    with open_writer(out, LogFormat.MCAP) as writer:
        for raw in raws:
            assert raw.msgtype == raw.schema_name == topics[raw.topic]
            writer.add_raw(raw)
    decoded: dict[str, Any] = {}
    with out.open("rb") as f:
        mcap = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _, message in mcap.iter_decoded_messages():
            assert schema is not None
            decoded.setdefault(channel.topic, (schema.name, []))[1].append(message)
    assert sum(len(messages) for _, messages in decoded.values()) == len(raws)
    return decoded


def test_the_ros1_renames_are_rosbags_converts_own() -> None:
    """rosbags-convert renames these whatever the destination; a new one is to be added."""
    from rosbags.convert.converter import STATIC_MSGTYPE_RENAMES

    assert ROS1_TYPE_RENAMES == STATIC_MSGTYPE_RENAMES


TRANSFORM = {
    "header": {"seq": 4, "stamp": {"sec": 5, "nanosec": 6}, "frame_id": "odom"},
    "child_frame_id": "base_link",
    "transform": {
        "translation": {"x": 1.0, "y": 2.0, "z": 3.0},
        "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
    },
}


def _tf_definition() -> str:
    """The ROS 1 definition of old tf's tfMessage (tf2_msgs' TFMessage has the same)."""
    noetic = get_typestore(Stores.ROS1_NOETIC)
    transform = noetic.generate_msgdef("geometry_msgs/msg/TransformStamped")[0]
    return (
        "geometry_msgs/TransformStamped[] transforms\n"
        + SEPARATOR
        + "MSG: geometry_msgs/TransformStamped\n"
        + transform
    )


def _tf_connection() -> Connection:
    """Old tf's /tf: ``tf/tfMessage``."""
    msgdef = _tf_definition()
    messages = [{"transforms": [TRANSFORM]}, {"transforms": [TRANSFORM, TRANSFORM]}]
    return ("/tf", "tf/msg/tfMessage", msgdef, messages)


@pytest.mark.parametrize("kind", READERS)
def test_old_tf_messages_come_out_as_tf2_msgs_tfmessage(tmp_path: Path, kind: str) -> None:
    """Before: schema ``tf/msg/tfMessage``; mcap_ros2 stopped at its first message."""
    decoded = _copied(tmp_path, kind, [_tf_connection()])
    name, messages = decoded["/tf"]
    assert name == "tf2_msgs/msg/TFMessage"
    assert [len(m.transforms) for m in messages] == [1, 2]
    transform = messages[1].transforms[1]
    assert (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_link")
    assert transform.transform.translation.z == 3.0


def test_old_tf_messages_are_the_bytes_rosbags_convert_writes(tmp_path: Path) -> None:
    from rosbags.convert.converter import convert

    bag = _bag(tmp_path / "tf.bag", [_tf_connection()])
    convert(
        [bag], tmp_path / "conv", "mcap", 9, None, "file", None, None, [], [], [], []
    )  # rosbags-convert --src tf.bag --dst conv --dst-storage mcap
    expected: list[tuple[str, bytes]] = []
    with (tmp_path / "conv" / "conv.mcap").open("rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            assert schema is not None
            expected.append((schema.name, bytes(message.data)))
    with open_log(bag) as reader:
        ours = [(raw.schema_name, raw.data) for raw in reader.messages()]
    assert ours == expected


CUSTOM_TYPES = (
    "Inner_part a\n"
    "other_pkg/innerThing[] b\n"
    "uint8 done\n"
    + SEPARATOR
    + "MSG: my_pkg/Inner_part\nint32 v\n"
    + SEPARATOR
    + "MSG: other_pkg/innerThing\nfloat64 w\n"
)


@pytest.mark.parametrize("kind", READERS)
def test_a_message_name_ros2_refuses_is_made_upper_camel_case(tmp_path: Path, kind: str) -> None:
    """Before: ``my_pkg/msg/laser_scan_2`` and its nested types kept their ROS 1 names."""
    messages = [{"a": {"v": 7}, "b": [{"w": 0.5}], "done": 1}]
    decoded = _copied(
        tmp_path, kind, [("/scan", "my_pkg/msg/laser_scan_2", CUSTOM_TYPES, messages)]
    )
    name, (message,) = decoded["/scan"]
    assert name == "my_pkg/msg/LaserScan2"
    assert (message.a.v, message.b[0].w, message.done) == (7, 0.5, 1)
    with (tmp_path / "out.mcap").open("rb") as f:
        (schema,) = make_reader(f).get_summary().schemas.values()  # type: ignore[union-attr]
    assert schema.data.decode().splitlines() == [
        "my_pkg/InnerPart a",
        "other_pkg/InnerThing[] b",
        "uint8 done",
        SEPARATOR.strip(),
        "MSG: my_pkg/InnerPart",
        "int32 v",
        SEPARATOR.strip(),
        "MSG: other_pkg/InnerThing",
        "float64 w",
    ]


@pytest.mark.parametrize("kind", READERS)
def test_a_package_name_ros2_refuses_is_made_lower_snake_case(tmp_path: Path, kind: str) -> None:
    """Before: ``MyRobot_Msgs/msg/Status`` kept its package; mcap_ros2 refused it."""
    decoded = _copied(
        tmp_path, kind, [("/status", "MyRobot_Msgs/msg/Status", "uint8 level", [{"level": 3}])]
    )
    name, (message,) = decoded["/status"]
    assert name == "my_robot_msgs/msg/Status"
    assert message.level == 3


def test_names_made_legal_that_meet_are_numbered_or_one_type(tmp_path: Path) -> None:
    """Two types whose legal names meet: another layout is numbered, the same one is merged."""
    tf_types = _tf_definition().split(SEPARATOR)[1:]
    msgdef = (
        "my_pkg/Pose_A a\nmy_pkg/PoseA b\ntf/tfMessage old\ntf2_msgs/TFMessage new\n"
        + SEPARATOR
        + "MSG: my_pkg/Pose_A\nint32 v\n"
        + SEPARATOR
        + "MSG: my_pkg/PoseA\nfloat64 w\n"
        + SEPARATOR
        + "MSG: tf/tfMessage\ngeometry_msgs/TransformStamped[] transforms\n"
        + SEPARATOR
        + "MSG: tf2_msgs/TFMessage\ngeometry_msgs/TransformStamped[] transforms\n"
        + "".join(SEPARATOR + part for part in tf_types)
    )
    fields = {
        "a": {"v": 2},
        "b": {"w": 0.25},
        "old": {"transforms": [TRANSFORM]},
        "new": {"transforms": []},
    }
    decoded = _copied(tmp_path, "bag", [("/both", "my_pkg/msg/Both", msgdef, [fields])])
    _, (message,) = decoded["/both"]
    assert (message.a.v, message.b.w) == (2, 0.25)
    assert (len(message.old.transforms), len(message.new.transforms)) == (1, 0)
    with (tmp_path / "out.mcap").open("rb") as f:
        (schema,) = make_reader(f).get_summary().schemas.values()  # type: ignore[union-attr]
    lines = schema.data.decode().splitlines()
    assert lines[:4] == [
        "my_pkg/PoseA2 a",  # PoseA is the other layout's
        "my_pkg/PoseA b",
        "tf2_msgs/TFMessage old",
        "tf2_msgs/TFMessage new",
    ]
    assert lines.count("MSG: tf2_msgs/TFMessage") == 1


def test_legal_names_and_ros2_spelling_are_kept() -> None:
    assert ros1_type_name("sensor_msgs/Image") == "sensor_msgs/msg/Image"
    assert ros1_type_name("tf/tfMessage") == ros1_type_name("tf/msg/tfMessage")
    for name in ("sensor_msgs/msg/Image", "tf2_msgs/msg/TFMessage", "a1_b/msg/X9y"):
        assert ros1_type_name(name) == name
    for name in ("my_pkg/laser_scan_2", "My__Pkg_/a__b_", "9pkg/9x", "_/_"):  # idempotent
        legal = ros1_type_name(name)
        assert ros1_type_name(legal) == legal, name
    assert ros1_type_name("9pkg/9x") == "pkg_9pkg/msg/Msg9x"


@pytest.mark.parametrize("kind", READERS)
def test_a_type_whose_legal_name_a_field_type_has_keeps_it(tmp_path: Path, kind: str) -> None:
    """The message's own type keeps its legal name; the other layout is numbered.

    Before: the schema was written for ``my_pkg/msg/PoseA2`` but named ``my_pkg/msg/PoseA``
    (the readers' name), whose text then defined two layouts under one name.
    """
    msgdef = "my_pkg/PoseA inner\nint32 v\n" + SEPARATOR + "MSG: my_pkg/PoseA\nfloat64 w\n"
    messages = [{"inner": {"w": 0.5}, "v": 3}]
    decoded = _copied(tmp_path, kind, [("/pose", "my_pkg/msg/Pose_A", msgdef, messages)])
    name, (message,) = decoded["/pose"]
    assert name == "my_pkg/msg/PoseA"
    assert (message.inner.w, message.v) == (0.5, 3)
    with (tmp_path / "out.mcap").open("rb") as f:
        (schema,) = make_reader(f).get_summary().schemas.values()  # type: ignore[union-attr]
    assert schema.data.decode().splitlines() == [
        "my_pkg/PoseA2 inner",
        "int32 v",
        SEPARATOR.strip(),
        "MSG: my_pkg/PoseA2",
        "float64 w",
    ]
