"""Serve a stream of ROS 2 messages live to Foxglove over its WebSocket protocol.

The server is the maintained ``foxglove-sdk`` (Rust, with Python bindings); nothing of the
protocol is written here. Channels carry the same ``ros2msg`` schema texts and CDR bytes as
the MCAP output (:mod:`.rosmsg`, and the input's own schemas for copied channels), so a
Foxglove layout made on a densified file works on the live stream. Each message is sent
with its log time, and the log time is broadcast as the server's time.

Order and pace: the densified frames come out of the pipeline a few frames after their input
messages were read (stereo matching runs ahead). Input messages are therefore held back
until the frame of the same log time is published (in the file output's
:class:`~pcainterp_stream.io.log_time_hold.LogTimeHold`, at most 256 MiB of them), so a
client sees the stream in log-time order, as a player of the file would. With
``rate > 0`` publishing waits until ``(log time - first log time) / rate`` has passed on
the wall clock; ``rate = 0`` publishes as fast as frames are processed. A gap
in log time longer than :data:`MAX_GAP_S` (or one that would take more than
:data:`MAX_WAIT_S` of wall time at ``rate``) is not waited for: publishing goes on at once
from the next message, and the gap is reported, as ``rosbag play --skip-empty`` does. One
message logged at time 0 (a static transform, a latched message) before camera frames at
epoch times would otherwise hold the stream for decades.

Slow clients never block the caller: ``Channel.log`` only queues. The SDK keeps one bounded
outbox per client (``message_backlog_size`` messages, here :data:`CLIENT_BACKLOG`) and drops
that client's oldest message when it is full; nothing is dropped before the SDK. It exposes
no count of what it dropped (no per-client statistic, no callback): its only sign is a log
record, "outbox for client ADDRESS full", and foxglove-sdk 0.30 writes at most one such
record every 30 s for the whole server (one throttle shared by all clients), however many
messages and clients it dropped from. :class:`FoxgloveLive` therefore keeps only which
clients were named (:attr:`LiveStats.behind`), and :func:`behind_line` says no number:
every client named lost messages at least once, and the others may have too.

Bursts: hundreds of small input messages released with one frame at ``rate = 0`` would
fill that outbox within a millisecond even for a client that keeps up. So while a client is
subscribed to a message's channel, sending is capped at :data:`SEND_RATE` messages/s: a
first burst of half the outbox, then bursts of a quarter of it (nothing waits while nobody
is subscribed). And the server's time goes to a second per-client queue of the same size,
which the SDK does not drop from but disconnects the client for, silently, when full: it is
sent with each frame and at most every :data:`TIME_EVERY_S` between frames, not once per
message.
"""

from __future__ import annotations

import logging
import re
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, NamedTuple, Self, cast

from pcainterp_stream.errors import StreamError
from pcainterp_stream.io.foxglove_drain import SentSizes, queued_bytes
from pcainterp_stream.io.log_time_hold import LogTimeHold

if TYPE_CHECKING:  # imported when used: the command line's parser imports this module
    from pcainterp_stream.records import RawMessage

DEFAULT_HOST = "127.0.0.1"
"""Loopback: the server is reachable from this machine only unless an address is given."""

DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""

SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol foxglove-sdk 0.30 accepts (the same messages as the older
``foxglove.websocket.v1``, which it no longer accepts in the handshake, and cannot be told
to: its handshake takes ``foxglove.sdk.v1`` and ``foxglove.sdk.v1.1`` only)."""

OLD_CLIENT = (
    "most likely a viewer asking for the older subprotocol foxglove.websocket.v1 (an older "
    "Foxglove, Lichtblick 1.21 or older, roslibjs-foxglove), and this server speaks "
    f"{SUBPROTOCOL} only: update the viewer, or write a file with -o and open it (said "
    "once, not per retry)"
)
"""Why a client was refused: the SDK's own line says only "handshake failed"."""

CLIENT_BACKLOG = 256
"""Messages the SDK queues per client before it drops that client's oldest."""

SEND_RATE = 5000.0
"""Messages/s sent at most while a client is subscribed (bursts of half the outbox)."""

TIME_EVERY_S = 0.05
"""Shortest wall time (s) between two broadcasts of the server's time (the log time)."""


DRAIN_MAX_S = 10.0
"""Longest wait (s) at the end for the connected clients to receive what is queued for them
(Linux; elsewhere a fixed second). A client still behind then loses the rest, and is named."""

DRAIN_NOTE_S = 0.5
"""Wait (s) at the end before saying that it waits for a client."""

DRAIN_EMPTY_S = 1.0
"""How long (s) the kernel must hold nothing for any client before the end counts as drained:
the SDK queues in its own memory too, and a sender thread it schedules late (a loaded
machine) leaves the kernel's queue empty for a moment while the stream is not out (two empty
polls 50 ms apart once let a slow client lose the end unnamed; 0.3 s once let one lose 228
of 300 frames on a loaded machine). The fixed wait before the drain existed was 1 s."""

STOP_TIMEOUT_S = 5.0
"""Longest wait (s) for the server to stop on close; past it the process goes on (and ends)."""

INTERRUPTED_STOP_TIMEOUT_S = 0.5
"""The same wait when closing because of Ctrl-C, SIGTERM or an error."""

MIN_RATE = 0.01
"""Slowest ``rate`` (x the log's rate): a 10 Hz camera at one frame per 10 s."""

MAX_RATE = 1000.0
"""Fastest ``rate`` besides 0 (as fast as processed)."""

MAX_GAP_S = 5.0
"""Longest gap in log time (s) the pacing waits for; a longer one is skipped."""

MAX_WAIT_S = 60.0
"""Longest wall-clock wait (s) for one gap at a slow ``rate``; a longer one is skipped."""

MAX_GAP_NOTES = 3
"""Skipped gaps reported one by one; the rest only in :attr:`LiveStats.gaps_skipped`."""

_OVERFLOW = re.compile(r"outbox for client (?P<client>\S+) full")
_REFUSED = re.compile(r"Dropping client (?P<client>\S+): handshake failed")
"""The SDK's line for a refused handshake, with no reason, once per attempt (a viewer
retries every second or so)."""
_DISCONNECT = re.compile(
    r"Error (?:receiving from|sending message to|reading from byte stream for) client "
    r"(?P<client>\S+?): (?P<reason>.*)"
)
"""The SDK's report of a connection that ended without a close handshake: one per message
it could not send or read, so a client that drops mid-stream gave dozens of lines."""


def check_rate(rate: float) -> float:
    """Return ``rate`` if it is 0 or within :data:`MIN_RATE` - :data:`MAX_RATE`.

    Raises:
        StreamError: any other value (negative, nan, inf, 1e-300), in one line.
    """
    if rate == 0 or MIN_RATE <= rate <= MAX_RATE:  # also refuses nan
        return float(rate)
    raise StreamError(
        f"--rate must be 0 (as fast as processed) or between {MIN_RATE:g} and {MAX_RATE:g} "
        f"(x the log's rate; 1 = as recorded), got {rate:g}"
    )


LOG_SUFFIXES = (".mcap", ".bag", ".db3")
"""Names a ``--foxglove`` value never has: a log's (the option takes an optional value)."""


def log_given_as_address(text: str, option: str = "--foxglove") -> str | None:
    """The error for a ``--foxglove`` value that names a log, None for any other value.

    Its value is optional, so ``densify --foxglove drive.mcap`` made the log the address and
    argparse then said only that INPUT was missing. A value names a log if it has a log's
    suffix, is ``-``, or is an existing path that is no address.
    """
    if not _names_a_log(text):
        return None
    return (
        f"{option} took {text!r} as its address (HOST:PORT); put the log first (pcainterp "
        f"densify {text} --foxglove ...) or write the address as --foxglove=HOST:PORT"
    )


def _names_a_log(text: str) -> bool:
    if text == "-" or text.lower().endswith(LOG_SUFFIXES):
        return True
    try:
        ServeAddress.parse(text)
    except StreamError:
        return Path(text).exists()
    return False


class LiveMessage(NamedTuple):
    """One serialized message to publish.

    Attributes:
        topic: channel topic.
        schema_name: ROS 2 type name (``sensor_msgs/msg/Image``).
        data: CDR bytes, as written to the MCAP output.
        metadata: channel metadata (the MCAP output channel's), None for none.
    """

    topic: str
    schema_name: str
    data: bytes
    metadata: dict[str, str] | None = None


@dataclass(frozen=True)
class ServeAddress:
    """Where the server listens.

    Attributes:
        host: an address or host name to bind (loopback by default).
        port: TCP port; 0 picks a free one.
    """

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT

    @classmethod
    def parse(cls, text: str) -> ServeAddress:
        """Parse ``HOST:PORT``, ``[IPV6]:PORT``, ``:PORT`` or ``PORT`` (loopback).

        Raises:
            StreamError: for anything else, or a port outside 0-65535.
        """
        match = re.fullmatch(
            r"(?:(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[^:\[\]\s]*)):)?"
            r"(?P<port>\d{1,5})",
            text.strip(),
        )
        if match is None or int(match["port"]) > 65535:
            raise StreamError(
                f"bad --foxglove address {text!r}; pass HOST:PORT (e.g. 127.0.0.1:8765, "
                "0.0.0.0:8765 for every interface, [::1]:8765) or a port alone (loopback)"
            )
        host = match["v6"] or match["host"] or DEFAULT_HOST
        return cls(host=host, port=int(match["port"]))

    def __str__(self) -> str:
        """``HOST:PORT`` as ``--foxglove`` takes it (``[::]:8765`` for IPv6)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def url(self, port: int | None = None) -> str:
        """Return the ``ws://`` URL a client opens (``port`` overrides, for port 0)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        if self.host in ("0.0.0.0", "::"):
            host = "127.0.0.1" if self.host == "0.0.0.0" else "[::1]"
        return f"ws://{host}:{self.port if port is None else port}"


@dataclass
class LiveStats:
    """What the server published.

    Attributes:
        frames: frames published (:meth:`FoxgloveLive.add_frame` calls).
        messages: messages published, inputs included.
        released_early: input messages published before their frame because the hold was
            full (:data:`~pcainterp_stream.io.log_time_hold.HOLD_BYTES`; their order is then
            not guaranteed).
        clients: distinct clients that subscribed to a channel.
        behind: client addresses the SDK named as having a full outbox (it dropped their
            oldest queued messages), in the order first named; not every such client is
            named (see the module's notes).
        gaps_skipped: gaps in log time the pacing did not wait for.
        gap_s_skipped: their total length (s of log).
        dropped: client addresses whose connection ended without a close handshake.
        cut_off: client address -> messages still queued for it when the server closed (at
            least that many of the last ones: the kernel's queue, as the SDK counts nothing).
        refused: handshakes the SDK refused (said in one line, at the first).
        schemaless: topics of channels with no schema (advertised with none).
        skipped: topics left out of the live stream (the SDK cannot carry them).
    """

    frames: int = 0
    messages: int = 0
    released_early: int = 0
    clients: int = 0
    behind: list[str] = field(default_factory=list)
    gaps_skipped: int = 0
    gap_s_skipped: float = 0.0
    dropped: set[str] = field(default_factory=set)
    cut_off: dict[str, int] = field(default_factory=dict)
    refused: int = 0
    schemaless: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)


def behind_line(stats: LiveStats) -> str | None:
    """Return the summary's line on clients that fell behind, None when the SDK named none.

    No count: the SDK keeps none it exposes, and names at most one client every 30 s.
    """
    if not stats.behind:
        return None
    line = (
        f"foxglove: {len(stats.behind)} client(s) fell behind ({', '.join(stats.behind)}): "
        "the server dropped their oldest queued messages at least once; a slow client sees "
        "gaps"
    )
    others = stats.clients - len(stats.behind)
    if others > 0:
        line += (
            f" (the Foxglove SDK names at most one client every 30 s: the other {others} "
            "may have lost messages too)"
        )
    return line


class _SdkLog(logging.Handler):
    """Notes the clients the SDK's "outbox full" reports name and passes its warnings on.

    A refused handshake (the SDK says only "handshake failed", once per retry of the
    viewer) is said once per server, with its likely cause and the fix (:data:`OLD_CLIENT`).

    A client that drops its connection without a close handshake (a viewer closed, Wi-Fi
    lost) is said in one line per client (the SDK logs an error per message it then cannot
    send); when no server is running (ours is stopping: it closes connections without a
    close frame) such reports are dropped. Every other warning and error is passed on.
    """

    def __init__(self) -> None:
        super().__init__(level=logging.INFO)
        self.sinks: list[FoxgloveLive] = []

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        found = _OVERFLOW.search(text)
        dropped = _DISCONNECT.search(text)
        refused = _REFUSED.search(text)
        if refused is not None and self.sinks:
            for sink in list(self.sinks):
                sink.stats.refused += 1
                if sink.stats.refused == 1:
                    print(
                        f"foxglove: refused a client at {refused['client']} (WebSocket "
                        f"handshake failed): {OLD_CLIENT}",
                        file=sys.stderr,
                        flush=True,
                    )
        elif found is not None:
            for sink in list(self.sinks):
                if found["client"] not in sink.stats.behind:
                    sink.stats.behind.append(found["client"])
        elif dropped is not None:
            client = dropped["client"]
            for sink in list(self.sinks):
                if client not in sink.stats.dropped:
                    sink.stats.dropped.add(client)
                    print(
                        f"foxglove: client {client} disconnected without closing the "
                        f"connection ({dropped['reason']})",
                        file=sys.stderr,
                        flush=True,
                    )
        elif record.levelno >= logging.WARNING:
            print(f"foxglove: {text}", file=sys.stderr, flush=True)


def _stderr(line: str) -> None:
    """Write a line for the user to stderr (a :class:`FoxgloveLive` given no ``note``)."""
    print(line, file=sys.stderr, flush=True)


_SDK_LOG = _SdkLog()
_SDK_LOG_LOCK = threading.Lock()
_sdk_logging_on = False


def _enable_sdk_logging() -> None:
    """Route the SDK's log records (INFO and up) to :data:`_SDK_LOG`, once per process.

    ``foxglove.set_log_level`` calls ``logging.basicConfig`` when the root logger has no
    handler; a placeholder handler during the call keeps the root logger as it was.
    """
    global _sdk_logging_on
    with _SDK_LOG_LOCK:
        if _sdk_logging_on:
            return
        import foxglove

        logger = logging.getLogger("foxglove")
        logger.setLevel(logging.INFO)
        logger.addHandler(_SDK_LOG)
        logger.propagate = False  # its INFO lines would otherwise reach the root handlers
        root = logging.getLogger()
        placeholder = logging.NullHandler()
        root.addHandler(placeholder)
        try:
            foxglove.set_log_level("INFO")
        finally:
            root.removeHandler(placeholder)
        _sdk_logging_on = True


class FoxgloveLive:
    """A Foxglove WebSocket server for one stream; use as a context manager.

    Example::

        with FoxgloveLive(ServeAddress(), rate=1.0) as live:
            print("open", live.url)
            live.advertise("/pcainterp/depth", rosmsg.IMAGE)
            live.add_raw(raw)                                    # an input message
            live.add_frame(log_time_ns, [LiveMessage(topic, schema_name, cdr), ...])
            live.flush()

    Args:
        address: where to listen.
        rate: pace at this multiple of the log's rate; 0 = as fast as frames come, else
            within :data:`MIN_RATE` - :data:`MAX_RATE`.
        wait_for: hold the first message until a client subscribed to one of these topics
            (empty: do not wait).
        name: the server name clients show.
        backlog: messages queued per client before its oldest are dropped.
        send_rate: messages/s sent at most while a client is subscribed to the channel, in
            bursts of ``backlog // 2`` (0: no cap).
        note: called with a line for the user when the pacing skips a gap in log time or a
            topic is left out of the live stream (unset: that line goes to stderr).
        on_start: called once when the server starts accepting clients (the first message).

    Attributes:
        before_start: called once just before the server starts, if set: advertises the
            channels a client must find in its first advertisement whose metadata is known
            late (a densify run's outputs are advertised at its first output, with the
            file's metadata; if input messages start the server before, this does it).
    """

    def __init__(
        self,
        address: ServeAddress | None = None,
        *,
        rate: float = 1.0,
        wait_for: Iterable[str] = (),
        name: str = "pcainterp",
        backlog: int = CLIENT_BACKLOG,
        send_rate: float = SEND_RATE,
        note: Callable[[str], None] | None = None,
        on_start: Callable[[], None] | None = None,
    ) -> None:
        self.address = address or ServeAddress()
        self.rate = check_rate(rate)
        self.note = note
        self.on_start = on_start
        self.before_start: Callable[[], None] | None = None
        self.wait_for = frozenset(wait_for)
        self.name = name
        self.backlog = backlog
        self.send_rate = send_rate
        self._burst = max(1.0, backlog // 2)
        self._tokens = (self._burst, 0.0)  # (messages that may go at once, when counted)
        self.stats = LiveStats()
        self._server: Any = None
        self._port: int | None = None
        self._context: Any = None
        self._channels: dict[
            tuple[str, str, str, str, bytes, tuple[tuple[str, str], ...]], Any
        ] = {}
        self._held = LogTimeHold(self._publish_raw)
        self._subscribed = threading.Event()
        self._clients: set[int] = set()
        self._clock: tuple[int, float] | None = None  # (a log time ns, its wall time)
        self._paced_ns = 0  # the latest log time paced
        self._time_ns = -1  # the latest log time published
        self._time_sent: tuple[int, float] = (-1, 0.0)  # the latest time broadcast, its wall time
        self._sent = SentSizes(4 * backlog)
        self._hosts: tuple[str, ...] = ()  # the addresses the host given resolves to
        self._waited = not self.wait_for

    # lifetime ---------------------------------------------------------------------------
    @property
    def port(self) -> int:
        """The port the server listens on (the chosen one for port 0)."""
        if self._port is None:
            raise StreamError("the Foxglove server is not open; use it in a with block")
        return self._port

    @property
    def url(self) -> str:
        """The ``ws://`` URL to open in Foxglove."""
        return self.address.url(self.port)

    def open(self) -> None:
        """Check the address (bind it once) and prepare the channels' context.

        The server itself starts with the first message (:meth:`start`): foxglove-sdk 0.30
        sometimes refuses a subscription to a channel added while the client is connected
        ("Unknown channel ID"), so the channels known by then (every output and the inputs
        read so far) go out in the first advertisement a client gets. Until then a client
        is refused and retries (as Foxglove does).

        Raises:
            StreamError: the address cannot be bound (in use, unknown host), in one line.
        """
        import foxglove

        _enable_sdk_logging()
        self._context = foxglove.Context()
        self._port = self._check_bind()

    def _check_bind(self) -> int:
        """Bind and release the address; return the port (a free one for port 0).

        With ``SO_REUSEADDR``, as the server's own listener binds (not on Windows, where it
        would let a second listener share the port): a port whose last connection is in
        TIME_WAIT (a run stopped while it sent) binds, one a live server listens on does not.
        """
        try:
            infos = socket.getaddrinfo(
                self.address.host, self.address.port, type=socket.SOCK_STREAM
            )
            family, kind, proto, _, where = infos[0]
            self._hosts = tuple(str(info[4][0]) for info in infos)  # the drain's own clients
            with socket.socket(family, kind, proto) as probe:
                if sys.platform != "win32":
                    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                probe.bind(where)
                return int(probe.getsockname()[1])
        except OSError as err:
            self._raise_bind_error(err.strerror or str(err), err)
        raise AssertionError("unreachable")  # pragma: no cover

    def _raise_bind_error(self, reason: str, err: BaseException) -> None:
        hint = (
            "stop the other server or pass another port (--foxglove HOST:PORT)"
            if "in use" in reason
            else "pass an address of this machine, e.g. 127.0.0.1:8765"
        )
        raise StreamError(f"cannot serve Foxglove on {self.address}: {reason}; {hint}") from err

    def start(self) -> None:
        """Start accepting clients (idempotent; the first message does it).

        Raises:
            StreamError: the port was taken since :meth:`open`.
        """
        if self._server is not None or self._context is None:
            return
        if self.before_start is not None:
            prepare, self.before_start = self.before_start, None
            prepare()
        import foxglove
        from foxglove.websocket import Capability

        try:
            self._server = foxglove.start_server(
                name=self.name,
                host=self.address.host,
                port=self.port,
                capabilities=[Capability.Time],
                # implements the two calls of the ServerListener protocol it needs
                server_listener=cast(Any, _Listener(self)),
                context=self._context,
                message_backlog_size=self.backlog,
            )
        except RuntimeError as err:
            self._raise_bind_error(str(err).removeprefix("FoxgloveError: "), err)
        _SDK_LOG.sinks.append(self)
        if self.on_start is not None:
            self.on_start()

    def close(self, drain_s: float | None = None, stop_timeout_s: float = STOP_TIMEOUT_S) -> None:
        """Stop the server (idempotent); clients see the connection close.

        With subscribers, first wait until what is queued for them has gone out (the SDK
        closes connections without sending what is queued), at most ``drain_s`` (default
        :data:`DRAIN_MAX_S`; 0: no wait), saying so after :data:`DRAIN_NOTE_S`; a client
        still behind then is named, with how many messages it lost
        (:attr:`LiveStats.cut_off`). Where the kernel's queues cannot be read (not Linux)
        the wait is a fixed second. The SDK's stop runs in a thread
        joined for at most ``stop_timeout_s``: it waits for the connections to close, and a
        client that never answers must not keep the process from ending. If it has not
        finished by then the channels and context are left to the process's end: dropping
        them calls into the SDK while it is still stopping.
        """
        stopped = True
        if self._server is not None:
            if self.stats.clients and (drain_s is None or drain_s > 0):
                self._drain(DRAIN_MAX_S if drain_s is None else drain_s)
            server, self._server = self._server, None
            if self in _SDK_LOG.sinks:
                _SDK_LOG.sinks.remove(self)
            stopper = threading.Thread(target=server.stop, name="foxglove-stop", daemon=True)
            stopper.start()
            stopper.join(stop_timeout_s)
            stopped = not stopper.is_alive()
        if stopped:
            self._channels.clear()
            self._context = None

    def _drain(self, limit_s: float, poll_s: float = 0.05) -> None:
        """Wait until nothing is queued for any client for :data:`DRAIN_EMPTY_S`, <= ``limit_s``."""
        started = time.monotonic()
        if queued_bytes(self.port, self._hosts) is None:  # not Linux: the fixed wait of before
            time.sleep(min(1.0, limit_s))
            return
        said, empty, queued = False, 0, {}
        while empty * poll_s < DRAIN_EMPTY_S:
            queued = queued_bytes(self.port, self._hosts) or {}
            empty = 0 if queued else empty + 1
            waited = time.monotonic() - started
            if queued and waited >= limit_s:
                break
            if queued and not said and waited >= DRAIN_NOTE_S:
                said = True
                (self.note or _stderr)(
                    f"foxglove: waiting up to {limit_s:g} s for {len(queued)} client(s) to "
                    f"receive the end of the stream ({sum(queued.values()) / 1e6:.1f} MB "
                    "queued)"
                )
            time.sleep(poll_s)
        for client, size in queued.items():
            missed = self._sent.messages_in(size)
            self.stats.cut_off[client] = missed
            (self.note or _stderr)(
                f"foxglove: client {client} had not received the end of the stream after "
                f"{limit_s:g} s: the last {missed} message(s) or more ({size / 1e6:.1f} MB "
                "queued) were lost when the server closed"
            )

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:  # interrupted or failed: nothing to drain, and the process is about to end
            self.close(drain_s=0.0, stop_timeout_s=INTERRUPTED_STOP_TIMEOUT_S)

    # channels ---------------------------------------------------------------------------
    def advertise(
        self,
        topic: str,
        schema_name: str,
        *,
        schema_encoding: str = "ros2msg",
        schema_data: bytes | None = None,
        message_encoding: str = "cdr",
        metadata: dict[str, str] | None = None,
    ) -> Any:
        """Return the channel of a topic, advertising it to clients on first use.

        Args:
            topic: channel topic.
            schema_name: ROS 2 type name, or the input's schema name.
            schema_encoding: ``ros2msg`` for ROS 2 types.
            schema_data: the schema text; the :mod:`.rosmsg` text of ``schema_name`` if None.
            message_encoding: ``cdr`` for ROS 2 messages.
            metadata: channel metadata (the MCAP channel's).
        """
        import foxglove

        from pcainterp_stream.io import rosmsg

        if schema_data is None:
            schema_data = rosmsg.schema_text(schema_name).encode()
        meta = tuple(sorted((metadata or {}).items()))
        key = (topic, schema_name, schema_encoding, message_encoding, schema_data, meta)
        if key in self._channels:
            return self._channels[key]
        if schema_name or schema_encoding or schema_data:
            schema = foxglove.Schema(name=schema_name, encoding=schema_encoding, data=schema_data)
            channel = foxglove.Channel(
                topic,
                schema=schema,
                message_encoding=message_encoding,
                context=self._context,
                metadata=dict(meta),
            )
        else:
            channel = self._schemaless(topic, message_encoding, dict(meta))
        self._channels[key] = channel
        return channel

    def _schemaless(self, topic: str, message_encoding: str, metadata: dict[str, str]) -> Any:
        """Return a channel with no schema (MCAP schema id 0: cbor, msgpack, raw bytes...).

        The protocol advertises it as such (``schemaName`` "", no ``schemaEncoding``), as
        the file has it. ``foxglove.Channel`` refuses a schema of None for any encoding but
        json (and then makes up a jsonschema name), so the channel is made by the context
        call it wraps. If this SDK has no such call, the topic is left out of the live
        stream with one line (None is returned); the file output is not affected.
        """
        try:
            channel = self._context._create_channel(
                topic, message_encoding=message_encoding, schema=None, metadata=metadata
            )
        except (AttributeError, TypeError, ValueError) as err:
            self.stats.skipped.append(topic)
            (self.note or _stderr)(
                f"foxglove: {topic} is not served live: its channel has no schema (message "
                f"encoding {message_encoding!r}), which this foxglove-sdk cannot advertise "
                f"({err}); a file output (-o) keeps it"
            )
            return None
        self.stats.schemaless.append(topic)
        return channel

    # messages ---------------------------------------------------------------------------
    def add_raw(self, raw: RawMessage) -> None:
        """Queue a message of the input log; it is published before the next frame after it.

        Its channel is advertised now, so clients can subscribe before it is published. At
        most :data:`~pcainterp_stream.io.log_time_hold.HOLD_BYTES` wait; beyond that the
        oldest is published now.
        """
        self._raw_channel(raw)
        self._held.add(raw)
        self.stats.released_early = self._held.released_early

    def add_frame(self, log_time_ns: int, messages: Iterable[LiveMessage]) -> None:
        """Publish one densified frame, after the held input messages up to its log time.

        Paced by ``rate``; with ``wait_for`` the first message waits for a subscriber.
        Returns once the messages are queued for the clients (never waits for a client).
        """
        self._held.release(log_time_ns)
        for message in messages:
            channel = self.advertise(message.topic, message.schema_name, metadata=message.metadata)
            self._log(channel, message.data, log_time_ns, frame=True)
        self.stats.frames += 1

    def flush(self) -> None:
        """Publish every held input message (at the end of the stream)."""
        self._held.release()
        self._broadcast_time(force=True)

    def wait_for_client(self, poll_s: float = 0.2, settle_s: float = 0.2) -> None:
        """Block until a client subscribed to one of ``wait_for`` (Ctrl-C interrupts).

        A client subscribes to the topics of its panels at once: ``settle_s`` more lets its
        other subscriptions land before the first message goes out.
        """
        while not self._subscribed.wait(poll_s):
            pass
        time.sleep(settle_s)
        self._waited = True

    def serve_forever(self, poll_s: float = 0.5) -> None:
        """Keep serving (clients may still connect and look) until Ctrl-C or SIGTERM."""
        self.start()
        if not self.stats.clients and self.stats.frames:
            (self.note or _stderr)(
                "foxglove: no client was connected during the run, and nothing more will be "
                "sent: a viewer that connects now sees the channels but no message; to "
                "watch it, run again with --wait-for-client (or write a file with -o)"
            )
        while self._server is not None:
            time.sleep(poll_s)

    def _publish_raw(self, raw: RawMessage) -> None:
        channel = self._raw_channel(raw)
        if channel is not None:  # None: a channel the SDK cannot carry (said once)
            self._log(channel, bytes(raw.data), int(raw.log_time_ns))

    def _raw_channel(self, raw: RawMessage) -> Any:
        return self.advertise(
            raw.topic,
            raw.schema_name,
            schema_encoding=raw.schema_encoding,
            schema_data=bytes(raw.schema_data),
            message_encoding=raw.message_encoding,
            metadata=raw.channel_metadata,
        )

    def _log(self, channel: Any, data: bytes, log_time_ns: int, *, frame: bool = False) -> None:
        """Publish one message, paced, its log time made the server's time first.

        See :meth:`_broadcast_time`. Capped at :attr:`send_rate` while a client is
        subscribed to its channel.
        """
        self.start()
        if not self._waited:
            self.wait_for_client()
        self._pace(log_time_ns)
        self._time_ns = max(self._time_ns, log_time_ns)
        self._broadcast_time(force=frame)
        if self.send_rate > 0 and channel.has_sinks():
            self._throttle()
        channel.log(data, log_time=log_time_ns)
        self._sent.add(len(data))
        self.stats.messages += 1

    def _broadcast_time(self, *, force: bool) -> None:
        """Tell the clients the latest log time if new (``force``: now, else every 50 ms).

        A frame's messages force it; inputs between frames wait :data:`TIME_EVERY_S`. The SDK
        queues the time on each client's control queue, which holds ``backlog`` messages
        and disconnects the client, silently, when full: a broadcast per message of a burst
        (hundreds of small input messages per frame at ``rate = 0``) disconnected a client
        that was keeping up with the data.
        """
        sent_ns, sent_at = self._time_sent
        if self._server is None or self._time_ns <= sent_ns:
            return
        now = time.monotonic()
        if force or sent_ns < 0 or now - sent_at >= TIME_EVERY_S:
            self._time_sent = (self._time_ns, now)
            self._server.broadcast_time(self._time_ns)

    def _throttle(self) -> None:
        """Take one message of the :attr:`send_rate` budget, sleeping when it is spent.

        A token bucket of ``backlog // 2`` messages: when it is empty, wait until half of
        it is back. A client that reads :attr:`send_rate` messages/s then never has more
        than half its outbox queued, so the SDK drops nothing of a burst.
        """
        tokens, counted = self._tokens
        now = time.monotonic()
        tokens = min(self._burst, tokens + (now - counted) * self.send_rate)
        if tokens < 1:
            wait = (self._burst / 2 - tokens) / self.send_rate
            time.sleep(wait)
            tokens, now = self._burst / 2, now + wait
        self._tokens = (tokens - 1, now)

    def _pace(self, log_time_ns: int) -> None:
        """Sleep until this log time is due at ``rate`` x the log's rate.

        A gap since the latest paced log time longer than :data:`MAX_GAP_S`, or than
        :data:`MAX_WAIT_S` of wall time at ``rate``, is skipped: the clock restarts at this
        message, and the gap is counted and reported.
        """
        if self.rate <= 0:
            return
        now = time.monotonic()
        if self._clock is None:
            self._clock = (log_time_ns, now)
            self._paced_ns = log_time_ns
            return
        gap_s = (log_time_ns - self._paced_ns) / 1e9
        limit_s = min(MAX_GAP_S, MAX_WAIT_S * self.rate)
        if gap_s > limit_s:
            self._skip_gap(gap_s, limit_s)
            self._clock = (log_time_ns, now)
            self._paced_ns = log_time_ns
            return
        self._paced_ns = max(self._paced_ns, log_time_ns)
        first_ns, started = self._clock
        delay = started + (log_time_ns - first_ns) / 1e9 / self.rate - now
        if delay > 0:
            time.sleep(min(delay, MAX_WAIT_S))

    def _skip_gap(self, gap_s: float, limit_s: float) -> None:
        self.stats.gaps_skipped += 1
        self.stats.gap_s_skipped += gap_s
        if self.note is None or self.stats.gaps_skipped > MAX_GAP_NOTES:
            return
        at_rate = f" ({gap_s / self.rate:.0f} s at --rate {self.rate:g})" if self.rate != 1 else ""
        more = (
            "; further gaps are counted in the summary"
            if self.stats.gaps_skipped == MAX_GAP_NOTES
            else ""
        )
        self.note(
            f"foxglove: skipped a {gap_s:.1f} s gap in log time{at_rate}: gaps over "
            f"{limit_s:g} s are not waited for{more}"
        )

    def _on_subscribe(self, client_id: int, topic: str) -> None:
        if client_id not in self._clients:
            self._clients.add(client_id)
            self.stats.clients = len(self._clients)
        if topic in self.wait_for:
            self._subscribed.set()


class _Listener:
    """The SDK's ``ServerListener``: notes subscriptions (called on the SDK's threads)."""

    def __init__(self, live: FoxgloveLive) -> None:
        self._live = live

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self._live._on_subscribe(int(client.id), str(channel.topic))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        return None
