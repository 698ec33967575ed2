"""An MCAP output says to rosbag2 which form its QoS profiles are in (a ``rosbag2`` record).

rosbag2 reads a channel's ``offered_qos_profiles`` by the bag metadata version of the file's
``rosbag2`` record (numbers up to 8, names from 9); the outputs had QoS in numbers and no
record, so a newer rosbag2 could read a latched ``/tf_static`` as volatile. Each test copies
a log as ``densify`` does (extras first, then every message) and reads what rosbag2 would.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Rosbag2Writer
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos
from rosbags.typesys import Stores, get_typestore

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.io.rosbag2_record import numeric_qos

FOREVER = QosTime(2147483647, 4294967295)
LATCHED = Qos(  # /tf_static's: reliable, transient local
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    FOREVER,
    FOREVER,
    QosLiveliness.AUTOMATIC,
    FOREVER,
    avoid_ros_namespace_conventions=False,
)
STATUS = rosmsg.TYPESTORE.types["std_msgs/msg/String"](data="ok")


def _copy(log: Path, out: Path) -> Path:
    """Copy ``log`` into the MCAP ``out`` as densify copies its input."""
    with open_log(log) as reader, open_writer(out, LogFormat.MCAP, threaded=True) as writer:
        if (extras := reader.extras()) is not None:
            writer.add_extras(extras)
        for raw in reader.messages():
            writer.add_raw(raw)
    return out


def _read(path: Path) -> tuple[list[dict[str, str]], dict[str, str]]:
    """Return an MCAP's ``rosbag2`` records and each topic's ``offered_qos_profiles``."""
    with path.open("rb") as f:
        reader = make_reader(f)
        records = [dict(m.metadata) for m in reader.iter_metadata() if m.name == "rosbag2"]
        summary = reader.get_summary()
        assert summary is not None
        qos = {
            c.topic: c.metadata.get("offered_qos_profiles", "") for c in summary.channels.values()
        }
    return records, qos


def _bag_metadata(record: dict[str, str]) -> dict[str, Any]:
    info = yaml.safe_load(record["serialized_metadata"])
    assert isinstance(info, dict)
    return info


def _rosbags_record_keys(tmp_path: Path, version: int) -> tuple[set[str], set[str]]:
    """The keys of rosbags' writer's ``rosbag2`` record, and of a topic in it."""
    with Rosbag2Writer(tmp_path / "ref", version=version, storage_plugin=StoragePlugin.MCAP) as w:
        connection = w.add_connection("/s", "std_msgs/msg/String", typestore=rosmsg.TYPESTORE)
        w.write(connection, 1, rosmsg.serialize(STATUS))
    (record,), _ = _read(tmp_path / "ref" / "ref.mcap")
    info = _bag_metadata(record)
    return set(info), set(info["topics_with_message_count"][0]["topic_metadata"])


def _assert_rosbag2_reads_latched(path: Path, topic: str) -> dict[str, Any]:
    """Check the output as rosbag2 reads it: one version-8 record, ``topic`` latched."""
    records, qos = _read(path)
    assert len(records) == 1  # before: none
    info = _bag_metadata(records[0])
    assert info["version"] == 8  # QoS in numbers: every rosbag2 (Humble's too) reads them
    (profile,) = parse_qos(qos[topic])
    assert (profile.durability, profile.reliability) == (
        QosDurability.TRANSIENT_LOCAL,
        QosReliability.RELIABLE,
    )
    assert "transient_local" not in qos[topic]  # numbers, as the record's version says
    listed = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert parse_qos(listed[topic]["topic_metadata"]["offered_qos_profiles"]) == [profile]
    return info


def test_a_ros1_bags_latched_topic_is_written_with_a_version_8_record(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer as Ros1Writer

    noetic = get_typestore(Stores.ROS1_NOETIC)
    string = noetic.types["std_msgs/msg/String"]
    bag = tmp_path / "latched.bag"
    with Ros1Writer(bag) as writer:
        for topic, latching in (("/map_name", 1), ("/chatter", 0)):
            connection = writer.add_connection(
                topic, "std_msgs/msg/String", typestore=noetic, latching=latching
            )
            data = noetic.serialize_ros1(string(data=topic), "std_msgs/msg/String")
            writer.write(connection, 1_000_000_000 + latching, data)
    info = _assert_rosbag2_reads_latched(_copy(bag, tmp_path / "out.mcap"), "/map_name")
    assert (info["message_count"], info["duration"]["nanoseconds"]) == (2, 1)
    listed = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert listed["/chatter"]["topic_metadata"]["offered_qos_profiles"] == ""
    assert listed["/chatter"]["topic_metadata"]["type"] == "std_msgs/msg/String"
    assert listed["/chatter"]["message_count"] == 1
    keys, topic_keys = _rosbags_record_keys(tmp_path, 8)
    assert set(info) == keys  # every key rosbag2 requires of a version-8 record
    assert info["custom_data"] == {}  # rosbag2 reads a map there (yaml-cpp refuses null)
    assert set(listed["/chatter"]["topic_metadata"]) == topic_keys


def _latched_bag(bag: Path, storage: StoragePlugin) -> Path:
    """A version-9 rosbag2 bag of one latched ``/tf_static`` message."""
    with Rosbag2Writer(bag, version=9, storage_plugin=storage) as writer:
        connection = writer.add_connection(
            "/tf_static",
            "std_msgs/msg/String",
            typestore=rosmsg.TYPESTORE,
            offered_qos_profiles=[LATCHED],
        )
        writer.write(connection, 5, rosmsg.serialize(STATUS))
    return bag


def test_a_sqlite3_bags_qos_is_written_with_a_version_8_record(tmp_path: Path) -> None:
    bag = _latched_bag(tmp_path / "jazzy", StoragePlugin.SQLITE3)  # version 9: QoS in names
    _assert_rosbag2_reads_latched(_copy(bag, tmp_path / "out.mcap"), "/tf_static")


def test_a_rosbag2_mcaps_own_record_and_qos_are_kept_as_they_are(tmp_path: Path) -> None:
    # as Jazzy's rosbag2 writes it: names and a version-9 record
    bag = _latched_bag(tmp_path / "recorded", StoragePlugin.MCAP)
    before = _read(bag / "recorded.mcap")
    assert _bag_metadata(before[0][0])["version"] == 9
    assert _read(_copy(bag, tmp_path / "out.mcap")) == before  # one record, the input's


def test_an_output_without_qos_gets_no_record(tmp_path: Path) -> None:
    out = tmp_path / "plain.mcap"
    with open_writer(out, LogFormat.MCAP) as writer:
        writer.add_message("/status", STATUS, 5)
    assert _read(out) == ([], {"/status": ""})


def _names_mcap(log: Path) -> tuple[Path, str]:
    """An MCAP of one latched ``/tf_static`` message, its QoS in names and no record."""
    names = yaml.safe_dump(dump_qos_v9([LATCHED]), default_flow_style=False)
    with log.open("wb") as f:
        writer = McapWriter(f)
        writer.start("ros2", "test")
        text = rosmsg.schema_text("std_msgs/msg/String").encode()
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", text)
        channel = writer.register_channel(
            "/tf_static", "cdr", schema, {"offered_qos_profiles": names}
        )
        writer.add_message(channel, 5, rosmsg.serialize(STATUS), 5)
        writer.finish()
    return log, names


def test_an_mcap_with_names_and_no_record_is_written_in_numbers(tmp_path: Path) -> None:
    log, _ = _names_mcap(tmp_path / "names.mcap")
    _assert_rosbag2_reads_latched(_copy(log, tmp_path / "out.mcap"), "/tf_static")


def test_without_rosbags_qos_parser_the_names_are_copied_and_the_write_succeeds(
    tmp_path: Path, monkeypatch: Any
) -> None:
    # rosbags does not export parse_qos: a release that moves it failed every such write
    import rosbags.rosbag2.metadata

    monkeypatch.delattr(rosbags.rosbag2.metadata, "parse_qos")
    log, names = _names_mcap(tmp_path / "names.mcap")
    assert numeric_qos(names) == names
    records, qos = _read(_copy(log, tmp_path / "out.mcap"))
    assert qos == {"/tf_static": names}  # copied as it is
    assert len(records) == 1
