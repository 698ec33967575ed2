"""What every log reader shares: the base class, topic descriptions, formats, ROS types.

The format readers (:mod:`.mcap_reader`, :mod:`.rosbags_reader`, :mod:`.rosbag1_walk`)
build on it; :mod:`.logreader` opens a path with the right one.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pcainterp_stream.errors import LogReadError, TopicNotFoundError
from pcainterp_stream.interrupt import raise_if_signalled
from pcainterp_stream.io import rosmsg
from pcainterp_stream.records import RawMessage

ROS2_SCHEMA_ENCODINGS = ("ros2msg", "ros2idl")

MCAP_MAGIC = b"\x89MCAP0\r\n"


SQLITE_MAGIC = b"SQLite format 3\x00"


_LOG_KINDS = "an MCAP file, a ROS 1 .bag or a rosbag2 folder"


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
    """

    topic: str
    msgtype: str
    message_count: int | None
    message_encoding: str
    schema_encoding: str


def ros2_type_name(name: str) -> str:
    """Return a type name in ROS 2 spelling (``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``)."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


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


class _Ros1Converter:
    """Convert ROS 1 serialized messages to CDR with a ``ros2msg`` schema, per type."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, str], tuple[Typestore, bytes]] = {}

    def schema(self, typename: str, msgdef: str) -> tuple[Typestore, bytes]:
        """Return (conversion typestore, ros2msg schema text) for a ROS 1 type definition.

        Types whose layout equals the ROS 2 Humble type (after dropping ``Header.seq``) get
        Humble's schema text, so that they read as the ROS 2 type downstream; others get a
        schema generated from the bag's own definition.
        """
        key = (typename, msgdef)
        if key not in self._cache:
            store = _store_from_msg(msgdef, typename, ros2_header=True)
            if _matches_humble(store, typename):
                text = rosmsg.schema_text(typename)
            else:
                text = str(store.generate_msgdef(typename, ros_version=2)[0])
            self._cache[key] = (store, text.encode())
        return self._cache[key]

    def convert(self, data: bytes | memoryview, typename: str, msgdef: str) -> tuple[bytes, bytes]:
        """Return (CDR bytes, ros2msg schema) of one ROS 1 serialized message."""
        store, text = self.schema(typename, msgdef)
        return bytes(store.ros1_to_cdr(data, typename)), text


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
                close = difflib.get_close_matches(topic, sorted(present), n=1)
                fix = (
                    f"the closest is {close[0]}: set {option} to it"
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
        _add_once(
            self.warnings,
            f"{self.path.name}: the schema stored for {raw.msgtype} on {raw.topic} does not "
            "match its messages; they were decoded with the standard ROS 2 definition",
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


def _one_line(err: BaseException) -> str:
    """Return an exception as one short line: its class and first line of text."""
    text = str(err).strip().splitlines()
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
