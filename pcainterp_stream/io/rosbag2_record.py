"""The ``rosbag2`` metadata record of an MCAP output, and the QoS form it declares.

rosbag2 (``ros2 bag play``) reads the QoS profiles of an MCAP channel (its
``offered_qos_profiles`` metadata, YAML) in the form of the bag metadata version that the
file's ``rosbag2`` metadata record states: policies as numbers (``durability: 1``) up to
version 8, as names (``durability: transient_local``) from version 9 (Jazzy's rosbag2). A
file without that record is read with the reader's own default version, so a latched
``/tf_static`` written in numbers may replay volatile on a newer rosbag2.

So an MCAP output whose channels carry QoS profiles ends with a ``rosbag2`` record, as
rosbags' writer (``rosbags-convert``) writes one, of version 8 (``rosbags-convert
--dst-version 8``): numbers, which every rosbag2 reads as meant. Version 9's names would
not do: the players of Humble and Iron read numbers only and stop on a name (their
``Rosbag2QoS`` decoder takes each policy ``as<int>``), while Jazzy's and later read a file's
version 8 by its record. A profile given in names (a Jazzy bag's) is written in numbers;
one in numbers is copied as it is. An input that brings its own ``rosbag2`` record (an MCAP
``ros2 bag record`` wrote) keeps it and its channels' profiles as they are, which agree
with it, and no second record is added.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from typing import Any

ROSBAG2_RECORD = "rosbag2"
"""The metadata record rosbag2 reads a file's bag metadata from (``serialized_metadata``)."""
RECORD_VERSION = 8
"""The bag metadata version the record declares: QoS policies as numbers."""
QOS_KEY = "offered_qos_profiles"
_POLICIES = ("history", "reliability", "durability", "liveliness")


def numeric_qos(text: str) -> str:
    """Return QoS profiles (rosbag2's YAML) with their policies as numbers.

    Text whose policies are numbers already, and text that is not QoS profiles, is returned
    as it is; names are read with rosbags' own QoS parser and written by :func:`qos_yaml`.
    Without that parser (a rosbags release that moved it) the text is copied as it is.

    Examples:
        >>> latched = "{depth: 0, deadline: {sec: 0, nsec: 0}, lifespan: {sec: 0, nsec: 0}, "
        >>> names = "history: unknown, reliability: reliable, durability: transient_local, "
        >>> rest = "liveliness: automatic, liveliness_lease_duration: {sec: 0, nsec: 0}, "
        >>> numbers = numeric_qos("- " + latched + names + rest + "avoid_ros_namespace_"
        ...     "conventions: false}")
        >>> [line for line in numbers.splitlines() if "ty: " in line or "history" in line]
        ['- history: 3', '  reliability: 1', '  durability: 1']
    """
    import yaml  # here: an MCAP job whose channels have no QoS does not need it

    try:
        profiles = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if not isinstance(profiles, list) or not all(isinstance(p, dict) for p in profiles):
        return text
    if not any(isinstance(p.get(policy), str) for p in profiles for policy in _POLICIES):
        return text
    try:  # rosbags does not export its parser (0.11.9): a release may move it
        from rosbags.rosbag2.metadata import parse_qos
    except (ImportError, AttributeError):
        return text  # names copied as they are, rather than a failed write
    try:
        return "\n".join(qos_yaml(profile) for profile in parse_qos(profiles))
    except (KeyError, TypeError, ValueError, AttributeError):
        return text  # not rosbag2's QoS: copied as it is


def qos_yaml(profile: Any) -> str:
    """Return one rosbag2 QoS profile (a rosbags ``Qos``) as rosbag2's YAML list item.

    Policies as numbers, the form of bag metadata version 8 (:data:`RECORD_VERSION`).
    """

    def number(value: Any) -> int:
        return int(getattr(value, "value", value))

    def duration(name: str) -> str:
        time = getattr(profile, name)
        return f"  {name}:\n    sec: {int(time.sec)}\n    nsec: {int(time.nsec)}"

    return "\n".join(
        [
            f"- history: {number(profile.history)}",
            f"  depth: {int(profile.depth)}",
            f"  reliability: {number(profile.reliability)}",
            f"  durability: {number(profile.durability)}",
            duration("deadline"),
            duration("lifespan"),
            f"  liveliness: {number(profile.liveliness)}",
            duration("liveliness_lease_duration"),
            "  avoid_ros_namespace_conventions: "
            + str(bool(profile.avoid_ros_namespace_conventions)).lower(),
        ]
    )


class Rosbag2Record:
    """What an MCAP writer tells rosbag2; see the module docstring.

    The writer passes every channel's metadata through :meth:`metadata` and
    :meth:`add_channel`, each message to :meth:`count`, the names of the metadata records
    it copies to :meth:`see` (before its channels), and writes :meth:`record` at the end.
    """

    def __init__(self) -> None:
        self.kept = False
        """The output has a ``rosbag2`` record of its own (its input's): QoS left as given."""
        self.schema_names: dict[int, str] = {}
        """Schema id -> name, as the writer registers them."""
        self._channels: dict[int, tuple[str, int, str, str]] = {}
        self._counts: Counter[int] = Counter()
        self._times: list[int] = []  # first and last log time (ns)

    def see(self, names: Iterable[str]) -> None:
        """Note the metadata records the output holds (their names) besides its own."""
        self.kept = self.kept or ROSBAG2_RECORD in names

    def metadata(self, metadata: dict[str, str]) -> dict[str, str]:
        """Return a channel's metadata as it is to be written (QoS in numbers)."""
        text = metadata.get(QOS_KEY)
        if self.kept or not text:
            return metadata
        numeric = numeric_qos(text)
        return metadata if numeric == text else {**metadata, QOS_KEY: numeric}

    def add_channel(
        self, channel_id: int, topic: str, schema_id: int, encoding: str, metadata: dict[str, str]
    ) -> None:
        """Note a channel registered with ``metadata`` (from :meth:`metadata`)."""
        self._channels[channel_id] = (topic, schema_id, encoding, metadata.get(QOS_KEY, ""))

    def count(self, channel_id: int, log_time_ns: int) -> None:
        """Note a message written on a channel."""
        self._counts[channel_id] += 1
        if not self._times:
            self._times = [log_time_ns, log_time_ns]
        elif not self._times[0] <= log_time_ns <= self._times[1]:
            self._times = [min(self._times[0], log_time_ns), max(self._times[1], log_time_ns)]

    def record(self, file_name: str) -> dict[str, str] | None:
        """Return the ``rosbag2`` record to write last, None when none is due.

        Due when a channel carries QoS profiles and the output has no record of its own. It
        holds what rosbags' writer puts in it (``rosbag2_bagfile_information``: every
        channel as a topic, with its QoS and message count); rosbag2 takes the version from
        it and the counts and times from the file's summary.
        """
        if self.kept or not any(qos for *_, qos in self._channels.values()):
            return None
        import yaml

        count = sum(self._counts.values())
        start, end = self._times or [0, 0]

        def times() -> dict[str, Any]:  # new dicts each time: YAML without anchors
            return {
                "duration": {"nanoseconds": end - start},
                "starting_time": {"nanoseconds_since_epoch": start},
            }

        topics: list[dict[str, Any]] = [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": self.schema_names.get(schema_id, ""),
                    "serialization_format": encoding,
                    "offered_qos_profiles": qos,
                    "type_description_hash": "",
                },
                "message_count": self._counts[channel_id],
            }
            for channel_id, (topic, schema_id, encoding, qos) in self._channels.items()
        ]
        info = {
            "version": RECORD_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [file_name],
            **times(),
            "message_count": count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": file_name, **times(), "message_count": count}],
            "custom_data": {},  # a map: rosbag2 (yaml-cpp) cannot read null as one
            "ros_distro": "",
        }
        return {"serialized_metadata": yaml.safe_dump(info, default_flow_style=False).strip()}
