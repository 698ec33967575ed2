"""The live server's channels and flow (bug hunt 8B: F3, F4, F5), against a real client.

Cheap: no densify run but one, a few thousand tiny messages, a server on port 0.
"""

from __future__ import annotations

import asyncio
import struct
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from test_foxglove import FRAMES, Received, _collect, _raw, synthetic_log  # noqa: F401

from pcainterp_stream import cli
from pcainterp_stream.io import foxglove, log_time_hold, rosmsg
from pcainterp_stream.io.foxglove import FoxgloveLive, LiveMessage, ServeAddress
from pcainterp_stream.records import RawMessage

websockets = pytest.importorskip("websockets")

STEP = 1_000_000  # 1 ms of log between input messages


def _schemaless(topic: str, log_time_ns: int, encoding: str = "cbor") -> RawMessage:
    """A message of a channel with no schema (MCAP schema id 0)."""
    return RawMessage(
        topic=topic,
        msgtype="",
        schema_name="",
        schema_encoding="",
        schema_data=b"",
        message_encoding=encoding,
        channel_metadata={},
        data=bytes([0xA1, 0x01, log_time_ns % 256]),
        log_time_ns=log_time_ns,
        publish_time_ns=log_time_ns,
        sequence=0,
    )


def _serve_in_thread(
    live: FoxgloveLive, until: dict[str, int]
) -> tuple[threading.Thread, list[Received]]:
    """A client subscribing to every channel, in a thread, until ``until`` counts."""
    result: list[Received] = []
    thread = threading.Thread(target=lambda: result.append(_collect(live.url, None, until)))
    thread.start()
    return thread, result


# ------------------------------------------------------------------- F3: no schema


def test_a_channel_without_schema_is_served_as_the_protocol_has_it() -> None:
    """It raised foxglove-sdk's TypeError "Invalid schema type: NoneType" (bug hunt 8B, F3)."""
    with FoxgloveLive(ServeAddress(port=0), rate=0.0, wait_for={"/out"}) as live:
        live.advertise("/out", rosmsg.IMAGE)
        live.add_raw(_schemaless("/raw_bytes", 0))
        live.add_raw(_schemaless("/status", 0, encoding="json"))
        thread, result = _serve_in_thread(live, {"/raw_bytes": 2, "/status": 1, "/out": 1})
        live.add_raw(_schemaless("/raw_bytes", STEP))
        live.add_frame(STEP, [LiveMessage("/out", rosmsg.IMAGE, b"frame")])
        live.flush()
        thread.join(timeout=60)
    got = result[0]
    for topic, encoding in (("/raw_bytes", "cbor"), ("/status", "json")):
        channel = got.channels[topic]
        # the protocol's schemaless channel: no schema name, no schema encoding (not a
        # made-up jsonschema name for json)
        assert (channel["encoding"], channel["schemaName"], channel["schema"]) == (
            encoding,
            "",
            "",
        )
        assert "schemaEncoding" not in channel
    assert got.messages["/raw_bytes"] == [(0, bytes([0xA1, 1, 0])), (STEP, bytes([0xA1, 1, 64]))]
    assert live.stats.schemaless == ["/raw_bytes", "/status"]


def test_a_channel_the_sdk_cannot_advertise_is_left_out_in_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An SDK without the schemaless call: the topic is skipped, said once, the rest goes on."""
    with FoxgloveLive(ServeAddress(port=0), rate=0.0) as live:
        context, live._context = live._context, object()  # no _create_channel
        try:
            for index in range(3):
                live.add_raw(_schemaless("/raw_bytes", index))
        finally:
            live._context = context
        live.add_frame(5, [LiveMessage("/out", rosmsg.IMAGE, b"frame")])
        live.flush()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("foxglove: /raw_bytes is not served live: its channel has no")
    assert lines[0].endswith("; a file output (-o) keeps it")
    assert live.stats.skipped == ["/raw_bytes"]
    assert live.stats.messages == 1  # the frame


def test_the_line_of_a_channel_left_out_goes_to_the_note_when_given(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The CLI passes its ``echo`` as ``note``: the line goes there, not straight to stderr."""
    notes: list[str] = []
    with FoxgloveLive(ServeAddress(port=0), rate=0.0, note=notes.append) as live:
        context, live._context = live._context, object()  # no _create_channel
        try:
            live.add_raw(_schemaless("/raw_bytes", 0))
        finally:
            live._context = context
        live.flush()
    assert len(notes) == 1
    assert notes[0].startswith("foxglove: /raw_bytes is not served live")
    assert capsys.readouterr().err == ""


def _with_schemaless_channel(source: Path, target: Path) -> None:
    """Copy an MCAP adding /raw_bytes: message encoding cbor, schema id 0."""
    with source.open("rb") as stream, target.open("wb") as out:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="test")
        schemas = {
            key: writer.register_schema(schema.name, schema.encoding, schema.data)
            for key, schema in summary.schemas.items()
        }
        channels = {
            key: writer.register_channel(
                channel.topic, channel.message_encoding, schemas[channel.schema_id]
            )
            for key, channel in summary.channels.items()
        }
        extra = writer.register_channel("/raw_bytes", "cbor", 0)
        for index, (_, channel, message) in enumerate(reader.iter_messages()):
            if index % 10 == 0:
                writer.add_message(extra, message.log_time, b"\xa0", message.log_time)
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.finish()


def test_densify_foxglove_with_a_schemaless_input_channel_writes_its_output(
    synthetic_log: Path,  # noqa: F811
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The bug: a traceback, and the -o file lost."""
    log = tmp_path / "cbor.mcap"
    _with_schemaless_channel(synthetic_log, log)
    output = tmp_path / "dense.mcap"
    args = ["densify", str(log), "-o", str(output), "--foxglove", "127.0.0.1:0"]
    assert cli.main([*args, "--exit-when-done"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert f"foxglove: published {FRAMES} frames" in out
    with output.open("rb") as stream:
        topics = {channel.topic for _, channel, _ in make_reader(stream).iter_messages()}
    assert {"/raw_bytes", "/pcainterp/depth"} <= topics


# ----------------------------------------------------- F4: an older subprotocol


async def _refused_attempts(url: str, attempts: int) -> int:
    refused = 0
    for _ in range(attempts):
        try:
            ws = await websockets.connect(url, subprotocols=["foxglove.websocket.v1"])
        except websockets.InvalidStatus:
            refused += 1
        else:
            await ws.close()
    return refused


def test_a_client_of_the_older_subprotocol_is_said_once_with_the_fix(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """It was "foxglove: Dropping client ...: handshake failed" per retry (bug hunt 8B, F4)."""
    with FoxgloveLive(ServeAddress(port=0), rate=0.0) as live:
        live.start()
        assert asyncio.run(_refused_attempts(live.url, 4)) == 4
        deadline = time.monotonic() + 10
        while live.stats.refused < 4 and time.monotonic() < deadline:
            time.sleep(0.01)  # the SDK's records come from its own threads
    assert live.stats.refused == 4
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("foxglove: refused a client at 127.0.0.1:")
    assert "foxglove.websocket.v1" in lines[0]
    assert "Lichtblick" in lines[0]
    assert "update the viewer, or write a file with -o and open it" in lines[0]


# ---------------------------------------------------------------- F5: bursts, order


def test_a_burst_of_inputs_reaches_a_subscribed_client_whole_and_in_order() -> None:
    """2000 input messages of rising log times, then one frame, at rate 0.

    Before: a time broadcast per message filled the client's control queue (256) and the
    SDK disconnected the client; the data outbox (256) dropped most of the burst; more than
    1024 held inputs went out before the frame of their time.
    """
    count = 2000
    with FoxgloveLive(ServeAddress(port=0), rate=0.0, wait_for={"/out"}) as live:
        live.advertise("/out", rosmsg.IMAGE)
        live.add_raw(_raw("/in", 0))
        thread, result = _serve_in_thread(live, {"/in": count, "/out": 2})
        live.add_frame(0, [LiveMessage("/out", rosmsg.IMAGE, b"frame0")])
        for index in range(1, count):
            live.add_raw(_raw("/in", index * STEP))
        live.add_frame(count * STEP, [LiveMessage("/out", rosmsg.IMAGE, b"frame1")])
        live.flush()
        thread.join(timeout=60)
    got = result[0]
    assert [t for t, _ in got.messages["/in"]] == [index * STEP for index in range(count)]
    assert [data for _, data in got.messages["/out"]] == [b"frame0", b"frame1"]
    assert live.stats.behind == []
    assert live.stats.released_early == 0
    # each frame's time is the server's time; the inputs between add a few, not one each.
    # The SDK sends times on another queue than messages, so the last frame's time may come
    # after its message, when the client has stopped: only the first frame's is certain.
    assert 0 in got.times
    assert got.times == sorted(got.times)
    assert max(got.times) <= count * STEP
    assert len(got.times) < count // 10


def test_held_inputs_are_bounded_in_bytes_not_in_count(monkeypatch: pytest.MonkeyPatch) -> None:
    """1500 small inputs ahead of the first frame wait for it (1024 did, then went early)."""
    published: list[tuple[bytes, int]] = []
    monkeypatch.setattr(
        FoxgloveLive, "_log", lambda self, channel, data, t, **_: published.append((data, t))
    )
    with FoxgloveLive(ServeAddress(port=0), rate=0.0) as live:
        for index in range(1500):
            live.add_raw(_raw("/in", index))
        assert published == []
        live.add_frame(0, [LiveMessage("/out", rosmsg.IMAGE, b"frame0")])
        assert [t for _, t in published] == [0, 0]  # input 0, then the frame
        monkeypatch.setattr(log_time_hold, "HOLD_BYTES", 100 * (log_time_hold.HOLD_OVERHEAD + 8))
        live.add_raw(_raw("/in", 1500))
    assert live.stats.released_early == 1500 - 100
    assert [t for _, t in published[2:]] == list(range(1, 1401))


def test_sending_is_capped_in_bursts_of_half_the_outbox(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        now[0] += seconds

    monkeypatch.setattr(foxglove.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(foxglove.time, "sleep", sleep)
    live = FoxgloveLive(ServeAddress(port=0), backlog=256, send_rate=1000.0)
    for _ in range(128 + 64 * 10):
        live._throttle()
    # a full bucket of 128 at once, then 64 per sleep of 64 ms: 1000 messages/s
    assert slept == pytest.approx([0.064] * 10)


def test_nothing_waits_while_no_client_is_subscribed(monkeypatch: pytest.MonkeyPatch) -> None:
    """A slow or absent client never slows densify: the cap holds only for a subscriber."""
    slept: list[float] = []
    monkeypatch.setattr(foxglove.time, "sleep", slept.append)
    with FoxgloveLive(ServeAddress(port=0), rate=0.0, send_rate=1000.0) as live:
        for index in range(3000):
            live.add_frame(index, [LiveMessage("/out", rosmsg.IMAGE, struct.pack("<I", index))])
    assert slept == []
    assert live.stats.messages == 3000
