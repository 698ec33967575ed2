"""What every log reader shares: the base class, topic descriptions, formats, ROS types.

The format readers (:mod:`.mcap_reader`, :mod:`.rosbags_reader`, :mod:`.rosbag1_walk`)
build on it; :mod:`.logreader` opens a path with the right one.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from enum import Enum
from functools import cache, partial
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pcainterp_stream.errors import LogReadError, TopicNotFoundError
from pcainterp_stream.interrupt import raise_if_signalled
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.mcap_extras import McapExtras
from pcainterp_stream.records import RawMessage

ROS2_SCHEMA_ENCODINGS = ("ros2msg", "ros2idl")

MCAP_MAGIC = b"\x89MCAP0\r\n"


SQLITE_MAGIC = b"SQLite format 3\x00"


_LOG_KINDS = "an MCAP file, a ROS 1 .bag or a rosbag2 folder"


_OPTION_TYPES = {
    "--left-topic": ("Image", "CompressedImage"),
    "--right-topic": ("Image", "CompressedImage"),
    "--left-info-topic": ("CameraInfo",),
    "--right-info-topic": ("CameraInfo",),
    "--features-topic": ("PointCloud2", "PointCloud"),
}
"""The message types (last part of the name) a topic option takes: what its hint offers."""


def closest_topic(topic: str, names: Iterable[str]) -> str | None:
    """Return the name of ``names`` closest to a topic not found (a typo's target), or None.

    Examples:
        >>> closest_topic("/stereo/left/image_rec", ["/stereo/left/image_rect", "/tf"])
        '/stereo/left/image_rect'
    """
    close = difflib.get_close_matches(topic, sorted(names), n=1)
    return close[0] if close else None


class LogFormat(Enum):
    """The container format of a log."""

    MCAP = "mcap"
    ROS1 = "ros1"
    ROSBAG2 = "rosbag2"


@dataclass(frozen=True)
class TopicInfo:
    """What a log says about one topic.

    Attributes:
        topic: topic name.
        msgtype: message type in ROS 2 spelling (``sensor_msgs/msg/Image``), or the schema
            name of a non-ROS channel ("" when the channel has no schema).
        message_count: number of messages, or None when the log does not index it.
        message_encoding: encoding of the messages as this reader yields them (``cdr`` for
            every ROS message; the input's encoding for others, e.g. ``json``).
        schema_encoding: ``ros2msg`` for ROS messages, else the input's.
        types: for a topic recorded with more than one message type (a driver restarted
            with ``CompressedImage`` after ``Image``), each type with its count (None when
            not indexed), in log order; ``msgtype`` is then the last of them. Empty for a
            topic of one type.
    """

    topic: str
    msgtype: str
    message_count: int | None
    message_encoding: str
    schema_encoding: str
    types: tuple[tuple[str, int | None], ...] = ()

    def type_counts(self) -> tuple[tuple[str, int | None], ...]:
        """Return every message type of the topic with its count (one pair for most topics)."""
        return self.types or ((self.msgtype, self.message_count),)


def merge_topic(previous: TopicInfo | None, info: TopicInfo) -> TopicInfo:
    """Return a topic's description with another channel (connection, file) of it added.

    The counts are summed (None when either is unknown); a channel of another message type
    is kept in :attr:`TopicInfo.types` with its own count. The other fields are the later
    channel's.

    Examples:
        >>> a = TopicInfo("/cam", "sensor_msgs/msg/Image", 8, "cdr", "ros2msg")
        >>> b = TopicInfo("/cam", "sensor_msgs/msg/CompressedImage", 4, "cdr", "ros2msg")
        >>> merged = merge_topic(a, b)
        >>> merged.message_count, merged.types
        (12, (('sensor_msgs/msg/Image', 8), ('sensor_msgs/msg/CompressedImage', 4)))
        >>> merge_topic(a, a).types
        ()
    """
    if previous is None:
        return info
    counts: dict[str, int | None] = {}
    for msgtype, count in (*previous.type_counts(), *info.type_counts()):
        known = counts.get(msgtype, 0)
        counts[msgtype] = None if known is None or count is None else known + count
    total = (
        None
        if previous.message_count is None or info.message_count is None
        else previous.message_count + info.message_count
    )
    types = tuple(counts.items()) if len(counts) > 1 else ()
    return replace(info, message_count=total, types=types)


def ros2_type_name(name: str) -> str:
    """Return a type name in ROS 2 spelling (``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``)."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


ROS1_TYPE_RENAMES = {"tf/msg/tfMessage": "tf2_msgs/msg/TFMessage"}
"""ROS 1 types ROS 2 has under another name, with the same wire layout: ``rosbags-convert``'s
own table (``STATIC_MSGTYPE_RENAMES`` of ``rosbags.convert.converter``, rosbags 0.11.9),
which renames them whatever the destination typestore."""

_PACKAGE_NAME = re.compile(r"^(?!.*__)(?!.*_$)[a-z][a-z0-9_]*$")
_MESSAGE_NAME = re.compile(r"^[A-Z][A-Za-z0-9]*$")


@cache  # per message by some readers: a handful of names per log
def ros1_type_name(name: str) -> str:
    """Return the ROS 2 name a ROS 1 message type gets when its messages become CDR.

    First ``rosbags-convert``'s renames (:data:`ROS1_TYPE_RENAMES`: old ``tf``'s
    ``tfMessage`` is ``tf2_msgs/msg/TFMessage``); then a name ROS 2 (rosidl, ``mcap_ros2``)
    refuses is made legal, as field names are: the package in lower snake case, the message
    name in upper camel case. ROS 1 allows ``my_pkg/laser_scan_2``, which ROS 2 refuses
    ("invalid message name"); ``mcap_ros2`` then stops reading the whole file. Legal names,
    and the names this returns, are returned unchanged.

    Examples:
        >>> ros1_type_name("tf/tfMessage"), ros1_type_name("sensor_msgs/Image")
        ('tf2_msgs/msg/TFMessage', 'sensor_msgs/msg/Image')
        >>> ros1_type_name("My_Pkg/laser_scan_2")
        'my_pkg/msg/LaserScan2'
    """
    full = ros2_type_name(name)
    if full in ROS1_TYPE_RENAMES:
        return ROS1_TYPE_RENAMES[full]
    parts = full.split("/")
    if len(parts) != 3 or not all(parts):
        return full
    package, kind, message = parts
    if not _PACKAGE_NAME.match(package):
        package = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", package).lower()  # MyPkg: my_pkg
        package = re.sub(r"[^a-z0-9]+", "_", package).strip("_")
        package = package if package[:1].isalpha() else f"pkg_{package}".rstrip("_")
    if not _MESSAGE_NAME.match(message):
        words = re.split(r"[^A-Za-z0-9]+", message)
        message = "".join(word[:1].upper() + word[1:] for word in words)
        message = message if message[:1].isalpha() else f"Msg{message}"
    return f"{package}/{kind}/{message}"


def _ros2_type_names(store: Typestore, typename: str) -> tuple[Typestore, str]:
    """Return ``store`` with ROS 2's type names (:func:`ros1_type_name`), and ``typename``'s.

    Field types follow their type's new name. A name taken by another type of another
    layout gets a number (``Pose2``); one of the same layout (a definition holding both
    ``tf/tfMessage`` and ``tf2_msgs/TFMessage``) is the same type. ``typename`` itself
    always gets :func:`ros1_type_name`'s name, the one the readers give its schema; a type
    of its definition that had that name is numbered instead.
    """
    defs = store.fielddefs
    renames: dict[str, str] = {}
    own = ros1_type_name(typename)
    holder = {  # name: its type; the legal names keep theirs, but typename's is its own
        name: name
        for name in defs
        if ros1_type_name(name) == name and (name == typename or name != own)
    }
    for name in sorted(defs, key=lambda name: name != typename):  # typename first
        new = ros1_type_name(name)
        if holder.get(new) == name:
            continue
        base, number = new, 2
        while new in holder and defs[holder[new]] != defs[name]:
            new, number = f"{base}{number}", number + 1
        holder.setdefault(new, name)
        renames[name] = new
    if not renames:
        return store, typename

    def ref(desc: Any) -> Any:
        kind, detail = desc
        if kind == Nodetype.NAME:
            return (kind, renames.get(detail, detail))
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return (kind, (ref(detail[0]), detail[1]))
        return desc

    types: dict[str, Any] = {}
    for name, (constants, fields) in defs.items():
        types[renames.get(name, name)] = (constants, [(field, ref(d)) for field, d in fields])
    renamed = get_typestore(Stores.EMPTY)
    renamed.register(types)
    return renamed, renames.get(typename, typename)


def _layout(store: Typestore, typename: str) -> Any:
    """Return a hashable wire layout of a type: field kinds in order, names lower-cased.

    Two types with equal layouts serialize to the same bytes, so a message written with one
    can be read with the other (ROS 1's ``CameraInfo.K`` is ROS 2's ``k``).
    """

    def node(desc: Any) -> Any:
        kind, detail = desc
        name = getattr(kind, "name", str(kind))
        if name == "NAME":
            return ("msg", _layout(store, str(detail)))
        if name in ("ARRAY", "SEQUENCE"):
            inner, count = detail
            return (name, node(inner), count)
        return (name, detail)

    fields = store.fielddefs[typename][1]
    return tuple((str(field).lower(), node(desc)) for field, desc in fields)


def _matches_humble(store: Typestore, typename: str) -> bool:
    """Return True when ``typename`` in ``store`` has the wire layout of the Humble type."""
    if typename not in rosmsg.TYPESTORE.fielddefs:
        return False
    try:
        return bool(_layout(store, typename) == _layout(rosmsg.TYPESTORE, typename))
    except KeyError:
        return False


def _store_from_msg(text: str, typename: str, *, ros2_header: bool = False) -> Typestore:
    """Build a typestore from a (concatenated) ``.msg`` definition.

    Args:
        text: message definition with its dependencies (``MSG:`` separated), ROS 1 or 2.
        typename: the top-level type in ROS 2 spelling.
        ros2_header: replace ``std_msgs/msg/Header`` by the ROS 2 one (no ``seq``), which is
            what rosbags' ``ros1_to_cdr`` assumes when it drops ``seq`` on conversion.
    """
    types = dict(get_types_from_msg(text, typename))
    if ros2_header and "std_msgs/msg/Header" in types:
        types["std_msgs/msg/Header"] = rosmsg.TYPESTORE.fielddefs["std_msgs/msg/Header"]
        types.setdefault(
            "builtin_interfaces/msg/Time", rosmsg.TYPESTORE.fielddefs["builtin_interfaces/msg/Time"]
        )
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store


LATCHED_QOS_PROFILES = "\n".join(
    [
        "- history: 3",
        "  depth: 0",
        "  reliability: 1",
        "  durability: 1",
        "  deadline:\n    sec: 2147483647\n    nsec: 4294967295",
        "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295",
        "  liveliness: 1",
        "  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295",
        "  avoid_ros_namespace_conventions: false",
    ]
)
"""rosbag2's ``offered_qos_profiles`` of a latched ROS 1 publisher: reliable, transient local,
durations infinite (``rosbags-convert``'s profile for it), so that a ROS 2 player offers it
latched. Policies as numbers, the form of bag metadata version 8 (as ``rosbags-convert
--dst-version 8`` and :func:`.rosbag2_record.qos_yaml` write it), which every rosbag2 reads
as meant once the file says that version: an MCAP output then ends with a ``rosbag2``
record saying so (:mod:`.rosbag2_record`)."""


def ros1_channel_metadata(metadata: dict[str, str], *, latching: bool) -> dict[str, str]:
    """Return the channel metadata of a ROS 1 connection whose messages become CDR.

    Args:
        metadata: what the input says of the connection (a ``ros1`` MCAP's channel
            metadata: ``callerid``, ``latching``, ``md5sum``), {} for a bag's.
        latching: the connection is latched (a bag's ``latching=1``).

    Returns:
        ``metadata`` without ``md5sum`` (the ROS 1 definition's, which the converted channel
        no longer has) and, for a latched connection, with :data:`LATCHED_QOS_PROFILES`.
    """
    out = {key: value for key, value in metadata.items() if key != "md5sum"}
    latched = latching or metadata.get("latching", "").strip().lower() in ("1", "true")
    if latched and "offered_qos_profiles" not in out:
        out["offered_qos_profiles"] = LATCHED_QOS_PROFILES
    return out


class _Ros1Converter:
    """Convert ROS 1 serialized messages to CDR with a ``ros2msg`` schema, per type.

    Every type has the ROS 2 name :func:`ros1_type_name` gives (``tf/tfMessage`` is
    ``tf2_msgs/msg/TFMessage``, as ``rosbags-convert`` writes it; a name ROS 2 refuses is
    made legal); the readers name the messages' type so. Then three kinds of type, by what a
    ROS 2 consumer of the output expects under its name:

    - the Humble type's layout once ``Header.seq`` is dropped (``sensor_msgs/Image``,
      ``CameraInfo`` whose ``K`` is ROS 2's ``k``): converted byte for byte, Humble's schema;
    - a Humble type of another layout (``visualization_msgs/Marker``, which ROS 2 extended):
      migrated to the Humble layout as ``rosbags-convert --dst-typestore`` does (fields
      matched by name, then by type; fields ROS 2 added get their defaults, fields it dropped
      are left out), Humble's schema, so that a node with the ROS 2 type reads it;
    - a type Humble does not have (a custom one): converted byte for byte, with a schema
      generated from the bag's own definition, its names made legal in ROS 2 (see
      :func:`_ros2_names`; the bytes do not depend on them).

    The migration drops the fields of the bag's definition that have no place in the Humble
    type; each topic on which one held a value is warned of once (through ``warn``). The
    pre-Electric ``sensor_msgs/CameraInfo`` (``float64[5] D``, no ``distortion_model``) is
    migrated as ROS's own rule did: ``D`` into ``d``, ``distortion_model = "plumb_bob"``.

    Args:
        warn: takes a one-line warning (a reader's :attr:`LogReader.warnings`, once each).
    """

    def __init__(self, warn: Callable[[str], None] | None = None) -> None:
        self._cache: dict[tuple[str, str], tuple[Any, bytes, bool]] = {}
        self._migrations: dict[str, object] = {}  # rosbags' cache of migration plans
        self._warn = warn
        self._warned: set[tuple[str, str]] = set()

    def _conversion(self, typename: str, msgdef: str) -> tuple[Any, bytes, bool]:
        """Return (ROS 1 bytes -> CDR bytes, ros2msg schema text, migrated) of a definition.

        A migrated conversion returns (CDR bytes, names of dropped fields that held a value).
        """
        key = (typename, msgdef)
        if key not in self._cache:
            store, target = _ros2_type_names(
                _store_from_msg(msgdef, typename, ros2_header=True), typename
            )
            migrates = False
            if _matches_humble(store, target):
                text = rosmsg.schema_text(target)
                convert: Any = partial(store.ros1_to_cdr, typename=target)
            elif target in rosmsg.TYPESTORE.fielddefs:
                text = rosmsg.schema_text(target)
                source = _ros2_type_names(_store_from_msg(msgdef, typename), typename)[0]
                dropped = dropped_fields(
                    source.fielddefs[target][1], rosmsg.TYPESTORE.fielddefs[target][1]
                )
                convert = partial(self._migrate, source, target, dropped)
                migrates = True
            else:
                text = str(_ros2_names(store).generate_msgdef(target, ros_version=2)[0])
                convert = partial(store.ros1_to_cdr, typename=target)
            self._cache[key] = (convert, text.encode(), migrates)
        return self._cache[key]

    def _migrate(
        self, store: Typestore, typename: str, dropped: list[str], data: bytes | memoryview
    ) -> tuple[bytes, list[str]]:
        """Return ROS 1 bytes of ``typename`` (``store``'s layout) as CDR of the Humble type.

        Also the names of the fields of ``dropped`` that held a value in this message.
        """
        from rosbags.convert.converter import migrate_message  # only for types that differ

        message: Any = store.deserialize_ros1(data, typename)
        migrated: Any = migrate_message(
            store, rosmsg.TYPESTORE, typename, typename, self._migrations, message
        )
        if typename == "sensor_msgs/msg/CameraInfo" and "D" in dropped:
            # pre-Electric CameraInfo: ROS's migration rule made D plumb_bob's coefficients
            d = np.asarray(message.D, dtype=np.float64)
            migrated = replace(migrated, d=d, distortion_model="plumb_bob")
            dropped = [name for name in dropped if name != "D"]
        lost = [name for name in dropped if _holds_value(getattr(message, name, None))]
        return rosmsg.serialize(migrated), lost

    def schema(self, typename: str, msgdef: str) -> bytes:
        """Return the ros2msg schema text its messages get for a ROS 1 type definition.

        Raises:
            rosbags' TypesysError: the definition does not parse.
        """
        return self._conversion(typename, msgdef)[1]

    def convert(
        self, data: bytes | memoryview, typename: str, msgdef: str, topic: str = ""
    ) -> tuple[bytes, bytes]:
        """Return (CDR bytes, ros2msg schema) of one ROS 1 serialized message.

        Args:
            data: the ROS 1 serialized message.
            typename: its type in ROS 2 spelling, as the bag names it or as
                :func:`ros1_type_name` renames it (the schema is that of the renamed type).
            msgdef: the connection's definition (``MSG:`` separated).
            topic: its topic, named in the warning of fields dropped.
        """
        convert, text, migrates = self._conversion(typename, msgdef)
        if not migrates:
            return bytes(convert(data)), text
        cdr, lost = convert(data)
        if lost and (topic, typename) not in self._warned:
            self._warned.add((topic, typename))
            if self._warn is not None:
                self._warn(
                    f"{topic or typename}: the log's ROS 1 definition of {typename} has "
                    f"{', '.join(lost)}, which ROS 2's {typename} has no field for: dropped "
                    "from every message read and copied (`rosbag fix` with the migration "
                    "rules of the type updates an old bag)"
                )
        return bytes(cdr), text


def dropped_fields(source: list[tuple[str, Any]], target: list[tuple[str, Any]]) -> list[str]:
    """Return the fields of ``source`` that a migration to ``target`` leaves out.

    As ``rosbags``' migration plan matches them: by name, then a field ``target`` adds takes
    the first left-over ``source`` field of the same type (``K`` -> ``k``, both
    ``float64[9]``); the ``source`` fields left over are dropped.
    """
    source_types, target_types = dict(source), dict(target)
    removed = [name for name, _ in source if name not in target_types]
    for name, kind in target:
        if name in source_types:
            continue
        match = next((old for old in removed if source_types[old] == kind), None)
        if match is not None:
            removed.remove(match)
    return removed


def _holds_value(value: Any) -> bool:
    """Return True when a message field's value is not its default (0, empty)."""
    if value is None:
        return False
    if isinstance(value, np.ndarray):
        return bool(value.size and np.any(value))
    if isinstance(value, str | bytes | list | tuple):
        return len(value) > 0
    if isinstance(value, bool | int | float):
        return bool(value)
    return True  # a nested message: taken as holding one


_FIELD_NAME = re.compile(r"^(?!.*__)(?!.*_$)[a-z][a-z0-9_]*$")
_CONSTANT_NAME = re.compile(r"^[A-Z]([A-Z0-9_]?[A-Z0-9]+)*$")


def _legal_name(name: str, *, constant: bool) -> str:
    """Return a ROS 1 field (or constant) name as ROS 2's rules allow it.

    ROS 2 (rosidl) wants fields in lower case and constants in upper case, letters, digits
    and single underscores, not ending in one; ROS 1 allows ``float64 X``, which Foxglove
    and ``mcap_ros2`` refuse in a ros2msg schema ("Invalid field name: X").

    Examples:
        >>> _legal_name("X", constant=False), _legal_name("Cov__3_", constant=False)
        ('x', 'cov_3')
        >>> _legal_name("max_speed", constant=True)
        'MAX_SPEED'
    """
    text = name.upper() if constant else name.lower()
    text = re.sub(r"[^A-Za-z0-9]+", "_", text)
    text = re.sub(r"_+", "_", text).strip("_")
    if not text or not text[0].isalpha():
        text = ("C_" if constant else "f_") + text
    return text.rstrip("_")


def _ros2_names(store: Typestore) -> Typestore:
    """Return a copy of ``store`` whose field and constant names follow ROS 2's rules.

    Only the schema text changes: CDR bytes do not hold names. A name made equal to another
    of its type gets a number (``x``, ``x_2``).
    """

    def unique(names: list[str], *, constant: bool, pattern: re.Pattern[str]) -> list[str]:
        out: list[str] = []
        for name in names:
            legal = name if pattern.match(name) else _legal_name(name, constant=constant)
            candidate, number = legal, 2
            while candidate in out or (candidate != name and candidate in names):
                candidate, number = f"{legal}_{number}", number + 1
            out.append(candidate)
        return out

    types: dict[str, Any] = {}
    for typename, (constants, fields) in store.fielddefs.items():
        constant_names = unique([c[0] for c in constants], constant=True, pattern=_CONSTANT_NAME)
        field_names = unique([f[0] for f in fields], constant=False, pattern=_FIELD_NAME)
        types[typename] = (
            [(name, *rest) for name, (_, *rest) in zip(constant_names, constants, strict=True)],
            [(name, desc) for name, (_, desc) in zip(field_names, fields, strict=True)],
        )
    renamed = get_typestore(Stores.EMPTY)
    renamed.register(types)
    return renamed


class LogReader:
    """A log opened for reading; use :func:`open_log` to get one.

    Attributes:
        path: the path given to :func:`open_log`.
        format: the container format.
        damage: one-line descriptions of damage found so far (file and byte offset); grows
            while :meth:`messages` runs.
        warnings: one-line notes that are not damage (non-monotonic log times, a fallback).
        backward_log_times: messages whose log time was earlier than the message yielded
            before them, in the most of a complete :meth:`messages` run (0: in order).
    """

    format: LogFormat

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: list[str] = []
        self.warnings: list[str] = []
        self.backward_log_times = 0
        self._is_open = False
        self._decoders: dict[tuple[str, str, bytes], Typestore] = {}

    def _warn_once(self, note: str) -> None:
        """Add a warning to :attr:`warnings` unless it is there (the list may be replaced)."""
        _add_once(self.warnings, note)

    # context manager -------------------------------------------------------------------
    def open(self) -> None:
        """Open the log (idempotent)."""
        if not self._is_open:
            self._open()
            self._is_open = True

    def close(self) -> None:
        """Close the log and release the file (idempotent)."""
        if self._is_open:
            self._close()
            self._is_open = False

    def __enter__(self) -> LogReader:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if not self._is_open:
            raise LogReadError(f"log {self.path} is closed; use it inside `with open_log(...)`")

    # content ----------------------------------------------------------------------------
    def topics(self) -> dict[str, TopicInfo]:
        """Return topic -> :class:`TopicInfo` for every topic of the log, in log order.

        For an MCAP file without a usable summary this reads the whole file once.
        """
        raise NotImplementedError

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Yield the messages of the log in log-time order, with bounded memory.

        ROS 1 bags, rosbag2 and indexed MCAP files are read in log-time order (equal log
        times in file order), however the file stores them; an MCAP without a chunk index
        (unchunked, or cut short) in file order.

        Args:
            topics: yield only these topics (all when None).

        Yields:
            One :class:`~records.RawMessage` per message. Damage met on the way is appended
            to :attr:`damage` and ends (or, for a corrupt chunk with intact framing, skips
            part of) the stream; it never raises a library exception.
        """
        raise NotImplementedError

    def message_stats(self) -> tuple[int, int | None, int | None] | None:
        """Return (message count, first log time ns, last log time ns) from an index.

        None when the log has no index that says so (then count with :meth:`messages`).
        """
        return None

    def extras(self, *, verify: bool = False) -> McapExtras | None:
        """Return what an MCAP log holds besides messages, None for a log of another kind.

        See :meth:`McapLogReader.extras <pcainterp_stream.io.mcap_reader.McapLogReader.extras>`;
        a rosbag2 folder whose storage files are MCAP has them too. ROS 1 bags and rosbag2
        sqlite3 storage have no attachments or metadata records.
        """
        return None

    def indexed(self) -> bool:
        """Return True when :meth:`messages` of a few topics reads only the part holding them.

        A log with an index (an MCAP summary with chunk and message indexes, a ROS 1 bag)
        finds a topic's first message without reading the rest: a look ahead is cheap. False
        when it would read the log from the start.
        """
        return False

    def require_topics(self, options: dict[str, str]) -> None:
        """Check that topics exist, for a command-line option each.

        Args:
            options: topic -> the option that names it (``{"/stereo/left/image_rect":
                "--left-topic"}``).

        Raises:
            TopicNotFoundError: for the first topic not in the log, naming the topics present,
                the one its name is closest to (a typo) and the option to set.
        """
        present = self.topics()
        for topic, option in options.items():
            if topic not in present:
                listed = ", ".join(sorted(present)) or "none"
                kinds = _OPTION_TYPES.get(option, ())
                candidates = [
                    name
                    for name, info in present.items()
                    if name not in options  # not the topic another option names
                    and (not kinds or info.msgtype.rsplit("/", 1)[-1] in kinds)
                ]
                close = closest_topic(topic, candidates)
                fix = (
                    f"the closest is {close}: set {option} to it"
                    if close
                    else f"set {option} to one of them"
                )
                raise TopicNotFoundError(
                    f"topic {topic} not found in {self.path.name}; topics present: {listed}; " + fix
                )

    def decode(self, raw: RawMessage) -> Any:
        """Deserialize a CDR message into a rosbags typestore message object.

        Schemas that have the wire layout of a ROS 2 Humble type decode with
        :data:`rosmsg.TYPESTORE`; others with a typestore built from the schema text (cached
        per schema).

        Raises:
            LogReadError: for a non-CDR message, a schema that cannot be parsed, or data that
                does not deserialize with its schema.
        """
        raise_if_signalled()  # a signal whose KeyboardInterrupt was lost still stops the job
        where = f"message on {raw.topic} at log time {raw.log_time_ns} ns in {self.path.name}"
        if raw.message_encoding != "cdr" or raw.schema_encoding not in ROS2_SCHEMA_ENCODINGS:
            raise LogReadError(
                f"cannot decode {where}: encoding {raw.message_encoding!r} with schema "
                f"{raw.schema_encoding!r} is not ROS 2 CDR; only CDR with ros2msg is decoded"
            )
        store = self._decoder_store(raw, where)
        try:
            return store.deserialize_cdr(raw.data, raw.msgtype)
        except Exception as err:  # rosbags raises SerdeError, struct.error, IndexError...
            standard = self._standard_fallback(raw, store)
            if standard is not None:
                return standard
            raise LogReadError(
                f"cannot decode {where} as {raw.msgtype}: {_one_line(err)}; the data does not "
                "match its schema (damaged message?)"
            ) from err

    def _standard_fallback(self, raw: RawMessage, store: Typestore) -> Any:
        """Decode with the standard ROS 2 type when the log's own schema of it does not fit.

        Some bags store a placeholder definition (rosbag2's own test bags: ``uint8 level``
        for ``rcl_interfaces/msg/Log``). When the standard definition of the same type name
        decodes the data, it is used for that schema from then on, with a warning; else None.
        """
        if store is rosmsg.TYPESTORE or raw.msgtype not in rosmsg.TYPESTORE.fielddefs:
            return None
        try:
            message = rosmsg.TYPESTORE.deserialize_cdr(raw.data, raw.msgtype)
        except Exception:  # the log's own error is the one reported
            return None
        self._decoders[(raw.msgtype, raw.schema_encoding, raw.schema_data)] = rosmsg.TYPESTORE
        said = "is empty" if not raw.schema_data.strip() else "does not match its messages"
        _add_once(
            self.warnings,
            f"{self.path.name}: the schema stored for {raw.msgtype} on {raw.topic} {said}; "
            "its messages were decoded with the standard ROS 2 definition",
        )
        return message

    def _decoder_store(self, raw: RawMessage, where: str) -> Typestore:
        key = (raw.msgtype, raw.schema_encoding, raw.schema_data)
        store = self._decoders.get(key)
        if store is not None:
            return store
        humble = raw.msgtype in rosmsg.TYPESTORE.fielddefs
        if humble and raw.schema_data == rosmsg.schema_text(raw.msgtype).encode():
            store = rosmsg.TYPESTORE
        elif raw.schema_encoding != "ros2msg":
            if not humble:
                raise LogReadError(
                    f"cannot decode {where}: type {raw.msgtype} has a {raw.schema_encoding} "
                    "schema and is not a ROS 2 Humble type; write the log with ros2msg schemas"
                )
            store = rosmsg.TYPESTORE
        else:
            try:
                own = _store_from_msg(raw.schema_data.decode(), raw.msgtype)
            except Exception as err:  # rosbags TypesysError, UnicodeDecodeError
                raise LogReadError(
                    f"cannot decode {where}: its ros2msg schema {raw.schema_name!r} does not "
                    f"parse ({_one_line(err)})"
                ) from err
            store = rosmsg.TYPESTORE if _matches_humble(own, raw.msgtype) else own
        self._decoders[key] = store
        return store


def _one_line(err: BaseException, said: str | None = None) -> str:
    """Return an exception as one short line: its class and first line of text (or ``said``)."""
    text = (str(err) if said is None else said).strip().splitlines()
    first = text[0] if text else ""
    if len(first) > 160:
        first = first[:157] + "..."
    return f"{type(err).__name__}: {first}" if first else type(err).__name__


def _add_once(notes: list[str], note: str) -> None:
    if note not in notes:
        notes.append(note)


def non_monotonic_warning(name: str, backwards: int) -> str:
    """Return the warning for ``backwards`` messages of log ``name`` that went back in time."""
    return (
        f"{name}: {backwards} messages have a log time earlier than the message before them "
        "(non-monotonic log times)"
    )


class _TimeOrder:
    """Count messages whose log time goes back in time."""

    def __init__(self) -> None:
        self.last_ns: int | None = None
        self.backwards = 0

    def see(self, log_time_ns: int) -> None:
        if self.last_ns is not None and log_time_ns < self.last_ns:
            self.backwards += 1
        self.last_ns = log_time_ns

    def report(self, reader: LogReader) -> None:
        if self.backwards:
            reader.backward_log_times = max(reader.backward_log_times, self.backwards)
            _add_once(reader.warnings, non_monotonic_warning(reader.path.name, self.backwards))
