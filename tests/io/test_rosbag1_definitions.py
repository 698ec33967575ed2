"""ROS 1 definitions judged alike by the indexed reader and the walker of unindexed bags (17G).

Before (bug hunt 17G F1): a bag whose index was cut off (a killed recorder) was read by the
walker, which never put ROS 1 Noetic's definition in place of rosserial's empty one: every
message of such a topic was lost as "do not convert (SerdeError ...)", where the indexed bag
read them all. F7: a whole definition that contradicts a recorded md5sum which Noetic's type
of that name has lost every message ("5 of the 5 ... do not convert") though Noetic's
definition decodes them.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.rosbag1_walk import Ros1WalkReader
from pcainterp_stream.io.rosbags_reader import RosbagsLogReader

NOETIC = get_typestore(Stores.ROS1_NOETIC)
IMU, INT8 = "sensor_msgs/msg/Imu", "std_msgs/msg/Int8"
IMU_TEXT, IMU_MD5 = NOETIC.generate_msgdef(IMU)
EMPTY_MD5 = "d41d8cd98f00b204e9800998ecf8427e"
OTHER_MD5 = "0123456789abcdef0123456789abcdef"
SHORT_TEXT = IMU_TEXT.replace("float64[9] linear_acceleration_covariance", "", 1)

# the /imu connection's (definition, md5sum) as each writer records it
KINDS = {
    "good": (IMU_TEXT, IMU_MD5),
    "rosserial": ("", IMU_MD5),  # empty, the right md5sum (F1 when unindexed)
    "short": (SHORT_TEXT, IMU_MD5),  # whole, one field short, Noetic's md5sum (F7)
    "custom": ("", OTHER_MD5),  # empty, an md5sum no known type has: left out
}


def _bag(path: Path, kind: str) -> Path:
    """5 Imu messages on /imu (definition and md5sum of ``kind``) and 5 Int8 on /count."""
    header, time = NOETIC.types["std_msgs/msg/Header"], NOETIC.types["builtin_interfaces/msg/Time"]
    quaternion = NOETIC.types["geometry_msgs/msg/Quaternion"]
    vector = NOETIC.types["geometry_msgs/msg/Vector3"]
    imu_type, int8 = NOETIC.types[IMU], NOETIC.types[INT8]
    writer = Writer(path)
    writer.chunk_threshold = 300
    with writer:
        text, md5 = KINDS[kind]
        if kind == "good":  # as rosbag records it
            imu = writer.add_connection("/imu", IMU, typestore=NOETIC)
        else:
            imu = writer.add_connection("/imu", IMU, msgdef=text, md5sum=md5)
        count = writer.add_connection("/count", INT8, typestore=NOETIC)
        for i in range(5):
            stamp = (100 + i) * 10**9
            message = imu_type(
                header(i, time(100 + i, 0), "imu"),
                quaternion(0.0, 0.0, 0.0, 1.0),
                np.zeros(9),
                vector(1.0 * i, 2.0, 3.0),
                np.zeros(9),
                vector(0.0, 0.0, 9.8),
                np.full(9, 0.5),
            )
            writer.write(imu, stamp, NOETIC.serialize_ros1(message, IMU))
            writer.write(count, stamp + 1, NOETIC.serialize_ros1(int8(i), INT8))
    return path


def _unindexed(bag: Path, target: Path) -> Path:
    """``bag`` as a killed recorder leaves it: index_pos 0, no index section."""
    data = bytearray(bag.read_bytes())
    field = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = struct.unpack_from("<Q", data, field)[0]
    struct.pack_into("<Q", data, field, 0)
    target.write_bytes(bytes(data[:index_pos]))
    return target


def _read(path: Path) -> tuple[list[tuple[str, int, bytes, bytes]], list[str], list[str], type]:
    """(topic, log time, CDR, schema) of every message; damage and warnings, the bag's name
    put as ``BAG``; the reader's class."""
    with open_log(path) as reader:
        messages = [(r.topic, r.log_time_ns, r.data, r.schema_data) for r in reader.messages()]
        again = [(r.topic, r.log_time_ns, r.data, r.schema_data) for r in reader.messages()]
        assert again == messages
        name = path.name
        return (
            messages,
            [line.replace(name, "BAG") for line in reader.damage],
            [line.replace(name, "BAG") for line in reader.warnings],
            type(reader),
        )


@pytest.mark.parametrize("kind", list(KINDS))
def test_the_walker_judges_definitions_as_the_indexed_reader(tmp_path: Path, kind: str) -> None:
    """Before (F1): the unindexed rosserial bag read 0 of its 5 /imu messages."""
    bag = _bag(tmp_path / f"{kind}.bag", kind)
    indexed = _read(bag)
    walked = _read(_unindexed(bag, tmp_path / f"{kind}_cut.bag"))
    assert indexed[3] is RosbagsLogReader
    assert walked[3] is Ros1WalkReader
    assert walked[0] == indexed[0]  # the same messages, converted alike
    assert walked[2] == indexed[2]  # the same warnings
    assert walked[1][0].startswith("BAG: unindexed (recording cut off?): read 10 messages")
    assert walked[1][1:] == indexed[1]  # and the same damage besides
    good = _read(_bag(tmp_path / "good_again.bag", "good"))[0]
    imu = [m for m in indexed[0] if m[0] == "/imu"]
    if kind == "custom":  # no definition decodes it: left out, named, the rest read
        assert imu == []
        assert indexed[1] == [
            f"BAG: /imu (5 messages of {IMU}) left out: its definition has md5sum "
            f"{EMPTY_MD5}, not the {OTHER_MD5} recorded (it is empty, as rosserial records "
            "it), so its messages cannot be decoded; the other topics are read"
        ]
        assert [m for m in indexed[0] if m[0] == "/count"] == [m for m in good if m[0] == "/count"]
    else:
        assert indexed[0] == good
        assert indexed[1] == []


def test_a_whole_definition_contradicting_noetics_md5sum_reads_with_noetics(
    tmp_path: Path,
) -> None:
    """Before (F7): 5 of the 5 messages on /imu skipped (SerdeError: size mismatch)."""
    messages, damage, warnings, _ = _read(_bag(tmp_path / "short.bag", "short"))
    assert len([m for m in messages if m[0] == "/imu"]) == 5
    assert damage == []
    short_md5 = "db86cb684fabdde2dcd80083278de1ec"
    assert warnings == [
        f"BAG: /imu: the bag's definition of {IMU} has md5sum {short_md5}, not the {IMU_MD5} "
        "recorded; read with the bag's definition (a message it does not fit is read with "
        "ROS 1 Noetic's definition, which has that md5sum)",
        f"BAG: /imu: messages the bag's definition of {IMU} does not fit are read with ROS 1 "
        "Noetic's definition, which has the md5sum recorded",
    ]
