"""``pcainterp densify --foxglove``: a real WebSocket client against the live server (issue 19).

The client is the ``websockets`` library speaking the Foxglove WebSocket protocol by its
spec (JSON ``serverInfo`` / ``advertise`` / ``subscribe``, binary ``messageData`` frames:
opcode 1, subscription id u32, log time u64, payload). It receives every /pcainterp/*
message of a small synthetic log and must match the MCAP output of the same run byte for
byte (so pixel for pixel). The server runs in a subprocess, as a user runs it.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from pcainterp_stream import cli
from pcainterp_stream.errors import StreamError
from pcainterp_stream.interrupt import STALL_DUMP_VARIABLE
from pcainterp_stream.io import foxglove, log_time_hold, rosmsg
from pcainterp_stream.io.foxglove import SUBPROTOCOL, FoxgloveLive, LiveMessage, ServeAddress
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import BASIS_KEY, FOCAL_BASELINE_KEY, OutputTopics, image_of
from pcainterp_stream.pipeline.densify import densify, output_types
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.records import RawMessage

websockets = pytest.importorskip("websockets")

FRAMES = 4
LONG_FRAMES = 40  # 3.9 s of log: at --rate 1 it streams that long
EXIT_S = 10
INTERRUPTED = "pcainterp: interrupted; no partial output was left at the target"
"""Bound on the exit after a signal: the promise is 2 s; generous for a loaded machine."""
URL = re.compile(r"serving on (ws://\S+)")
OUTPUTS = ("/pcainterp/depth_mm", "/pcainterp/features")


@dataclass
class Received:
    """What a client saw: channels by topic, and (log time, payload) per topic."""

    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=lambda: defaultdict(list))
    times: list[int] = field(default_factory=list)


async def _client(url: str, topics: set[str] | None, until: dict[str, int]) -> Received:
    """Subscribe to ``topics`` (every channel when None) until ``until`` counts are reached."""
    got = Received()
    by_subscription: dict[int, str] = {}
    async with await _connect(url) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        while any(len(got.messages[topic]) < count for topic, count in until.items()) or (
            topics is not None and not topics <= set(got.channels)
        ):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=60)
            except websockets.ConnectionClosed as closed:
                counts = {topic: len(items) for topic, items in got.messages.items()}
                raise AssertionError(f"closed with {counts} of {until}") from closed
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] != "advertise":
                    continue
                subscriptions = []
                for channel in op["channels"]:
                    got.channels[channel["topic"]] = channel
                    if topics is None or channel["topic"] in topics:
                        subscription = len(by_subscription) + 1
                        by_subscription[subscription] = channel["topic"]
                        subscriptions.append({"id": subscription, "channelId": channel["id"]})
                if subscriptions:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
            elif frame[0] == 1:  # messageData
                subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                got.messages[by_subscription[subscription]].append((log_time, bytes(frame[13:])))
            elif frame[0] == 2:  # time
                got.times.append(struct.unpack_from("<Q", frame, 1)[0])
    return got


async def _connect(url: str, timeout_s: float = 60.0) -> Any:
    """Connect, retrying while refused: the server accepts clients from its first message."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.05)


def _mcap_messages(path: Path) -> dict[str, list[tuple[int, bytes, str, str]]]:
    """topic -> (log time, CDR bytes, schema name, schema text) in file order."""
    found: dict[str, list[tuple[int, bytes, str, str]]] = defaultdict(list)
    with path.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            assert schema is not None
            found[channel.topic].append(
                (message.log_time, bytes(message.data), schema.name, schema.data.decode())
            )
    return found


def _mcap_channel_metadata(path: Path) -> dict[str, dict[str, str]]:
    """topic -> channel metadata of an MCAP file."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return {channel.topic: dict(channel.metadata) for channel in summary.channels.values()}


@pytest.fixture(scope="module")
def synthetic_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("foxglove") / "x.mcap"
    assert cli.main(["synth", str(log), "--frames", str(FRAMES), "--scale", "0.25"]) == 0
    return log


@contextlib.contextmanager
def serving(*args: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """Run ``pcainterp densify ARGS`` in a subprocess; yield it and the URL it prints."""
    command = [sys.executable, "-m", "pcainterp_stream.cli", "densify", *args]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        preexec_fn=_default_sigint,
    )
    try:
        assert process.stdout is not None
        lines = []  # the URL comes when the server starts: with the first message
        while (found := URL.search(line := _line(process))) is None and line:
            lines.append(line)
        if found is None:
            process.kill()
            _, err = process.communicate()
            pytest.fail(f"no URL printed: {lines!r}\n{err}")
        yield process, found[1]
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


def _default_sigint() -> None:
    """Give the child the default SIGINT disposition (runs in the child before exec).

    A shell that starts the test run in the background leaves SIGINT ignored, Python keeps
    an inherited SIG_IGN, and the child would never see the signal.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stopped(process: subprocess.Popen[str], sig: signal.Signals) -> tuple[str, str]:
    """Send ``sig``; return (stdout, stderr) once the process ended, within EXIT_S."""
    process.send_signal(sig)
    try:
        return process.communicate(timeout=EXIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
        pytest.fail(f"still running {EXIT_S} s after {sig.name}\n{out}\n{err}")


def _line(process: subprocess.Popen[str]) -> str:
    """Read one line of standard output from the pipe itself ("" at its end).

    Not through ``process.stdout``: its buffer reads ahead, and what it took is lost to
    ``communicate``, which reads the pipe's descriptor (a summary printed right after the
    URL went missing that way on a loaded machine).
    """
    assert process.stdout is not None
    data = bytearray()
    while not data.endswith(b"\n") and (byte := os.read(process.stdout.fileno(), 1)):
        data += byte
    return data.decode()


def _read_until(process: subprocess.Popen[str], text: str) -> list[str]:
    """Read standard output until a line holding ``text``; return the lines read."""
    assert process.stdout is not None
    lines = []
    while text not in (line := _line(process)):
        assert line, f"the server stopped before {text!r}: {lines}"
        lines.append(line)
    return lines


def _collect(url: str, topics: set[str] | None, until: dict[str, int]) -> Received:
    return asyncio.run(_client(url, topics, until))


# ----------------------------------------------------------------------------- the bar


def test_a_client_receives_every_frame_equal_to_the_mcap_output(
    synthetic_log: Path, tmp_path: Path
) -> None:
    output = tmp_path / "dense.mcap"
    args = [str(synthetic_log), "-o", str(output), "--foxglove", "127.0.0.1:0", "--depth-mm"]
    with serving(*args, "--wait-for-client") as (process, url):
        assert url.startswith("ws://127.0.0.1:")
        counts = {topic: len(items) for topic, items in _mcap_messages(synthetic_log).items()}
        # the default (compact) channels
        outputs = [f"/pcainterp/{name}" for name in ("depth", "disparity_std")]
        outputs += [f"/pcainterp/{name}" for name in ("features", "camera_info")]
        counts.update(dict.fromkeys([*outputs, "/pcainterp/depth_mm"], FRAMES))
        received = _collect(url, None, counts)
        out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert "foxglove: published 4 frames" in out
    written = _mcap_messages(output)
    assert len(written["/pcainterp/depth"]) == FRAMES
    metadata = _mcap_channel_metadata(output)
    assert "pcainterp.focal_baseline" in metadata["/pcainterp/depth"]
    for topic, messages in written.items():
        channel = received.channels[topic]
        _, _, schema_name, schema_text = messages[0]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg"), topic
        assert (channel["schemaName"], channel["schema"]) == (schema_name, schema_text), topic
        assert channel.get("metadata", {}) == metadata[topic], topic  # f*b, basis, encoding
        # every message, inputs included, the same bytes at the same log time
        assert received.messages[topic] == [(t, data) for t, data, _, _ in messages], topic
    depth_times = [t for t, _ in received.messages["/pcainterp/depth"]]
    # the log's time is the server's time (the SDK sends times on another queue than
    # messages: the last frame's may come after the client stopped)
    assert set(depth_times[:-1]) <= set(received.times)
    assert received.times == sorted(received.times)


def test_the_depth_decodes_to_the_image_of_the_file(synthetic_log: Path, tmp_path: Path) -> None:
    output = tmp_path / "dense.mcap"
    args = [str(synthetic_log), "-o", str(output), "--foxglove", "0", "--wait-for-client"]
    with serving(*args) as (process, url):
        received = _collect(url, {"/pcainterp/depth"}, {"/pcainterp/depth": FRAMES})
        process.communicate(timeout=120)
    written = _mcap_messages(output)["/pcainterp/depth"]
    for (_, live), (_, data, _, _) in zip(
        received.messages["/pcainterp/depth"], written, strict=True
    ):
        live_image = image_of(rosmsg.deserialize(live, rosmsg.COMPRESSED_IMAGE))
        file_image = image_of(rosmsg.deserialize(data, rosmsg.COMPRESSED_IMAGE))
        assert live_image.dtype == file_image.dtype == "float32"
        assert live_image.tobytes() == file_image.tobytes()  # pixel for pixel, NaN included


@pytest.fixture(scope="module")
def long_synthetic_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("foxglove") / "long.mcap"
    assert cli.main(["synth", str(log), "--frames", str(LONG_FRAMES), "--scale", "0.25"]) == 0
    return log


def test_without_output_it_serves_until_interrupted(synthetic_log: Path) -> None:
    args = [str(synthetic_log), "--foxglove", "127.0.0.1:0", "--wait-for-client"]
    with serving(*args) as (process, url):
        received = _collect(url, set(OUTPUTS), {topic: FRAMES for topic in OUTPUTS})
        _read_until(process, "still serving")
        assert process.poll() is None  # after the last frame, still serving
        again = _collect(url, set(OUTPUTS), {})  # a late client connects and sees channels
        assert set(OUTPUTS) <= set(again.channels)
        out, err = _stopped(process, signal.SIGINT)
    assert process.returncode == 0, err
    assert "foxglove: stopped" in out
    assert "Traceback" not in err
    # it ended by itself: the stall-dump file armed for the watchdog is gone too
    assert not (Path(os.environ[STALL_DUMP_VARIABLE]) / f"stall-{process.pid}.txt").exists()
    assert {topic: len(received.messages[topic]) for topic in OUTPUTS} == dict.fromkeys(
        OUTPUTS, FRAMES
    )


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_before_the_first_client_stops_it(
    synthetic_log: Path, sig: signal.Signals
) -> None:
    args = [str(synthetic_log), "--foxglove", "127.0.0.1:0", "--wait-for-client"]
    with serving(*args) as (process, _):
        _read_until(process, "waiting for a client")
        _, err = _stopped(process, sig)
    assert process.returncode == 130, err
    assert err.splitlines()[-1] == "pcainterp: interrupted; nothing was written"  # no file


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_streaming_stops_it(
    long_synthetic_log: Path, tmp_path: Path, sig: signal.Signals
) -> None:
    output = tmp_path / "dense.mcap"
    args = [str(long_synthetic_log), "-o", str(output), "--foxglove", "127.0.0.1:0"]
    with serving(*args, "--rate", "1", "--wait-for-client") as (process, url):
        # one frame received: at rate 1 the rest of the log takes 3.8 s more
        _collect(url, {"/pcainterp/depth"}, {"/pcainterp/depth": 1})
        assert process.poll() is None
        out, err = _stopped(process, sig)
    assert process.returncode == 130, err
    assert "Traceback" not in err
    assert "published" not in out  # stopped mid-stream
    assert list(tmp_path.iterdir()) == []  # what -o was writing is removed


def test_two_signals_in_a_row_stop_it_cleanly(synthetic_log: Path) -> None:
    args = [str(synthetic_log), "--foxglove", "127.0.0.1:0", "--wait-for-client"]
    with serving(*args) as (process, url):
        _collect(url, set(OUTPUTS), {topic: FRAMES for topic in OUTPUTS})
        _read_until(process, "still serving")
        process.send_signal(signal.SIGINT)
        _, err = _stopped(process, signal.SIGINT)
    assert process.returncode in (0, 130), err  # 0 when the first had already ended it
    assert "Traceback" not in err


def test_exit_when_done_with_no_client(synthetic_log: Path) -> None:
    args = [str(synthetic_log), "--foxglove", "127.0.0.1:0", "--exit-when-done", "--rate", "0"]
    with serving(*args) as (process, _):
        out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert "published 4 frames" in out
    assert "to 0 client(s)" in out


def test_a_signal_after_the_output_is_complete_says_it_is_kept(
    synthetic_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C while the server stops (after `wrote X`): the complete output is kept and the
    line says so (it said "no partial output was left at the target")."""
    close = FoxgloveLive.close

    def interrupted_close(self: FoxgloveLive, *args: Any, **kwargs: Any) -> None:
        close(self, drain_s=0.0)
        raise KeyboardInterrupt  # as a Ctrl-C in the drain after the last frame

    monkeypatch.setattr(FoxgloveLive, "close", interrupted_close)
    output = tmp_path / "dense.mcap"
    args = [str(synthetic_log), "-o", str(output), "--foxglove", "127.0.0.1:0", "--rate", "0"]
    assert cli.main(["densify", *args]) == 130
    out, err = capsys.readouterr()
    assert f"wrote {output}: " in out
    assert err.splitlines()[-1] == f"pcainterp: interrupted; {output} was complete and is kept"
    with output.open("rb") as stream:
        assert sum(1 for _ in make_reader(stream).iter_messages()) > 0


# ----------------------------------------------------------------------------- TypeScript


@pytest.fixture(scope="session")
def js_live_client(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """tests/js/live_client.mjs beside its installed node_modules (as test_interop does)."""
    from test_interop import JS_DIR, _install_js

    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are needed for @foxglove/ws-protocol; install Node.js")
    cache = getattr(request.config, "cache", None)  # None with -p no:cacheprovider
    folder = cache.mkdir("pcainterp-js") if cache is not None else tmp_path_factory.mktemp("js")
    _install_js(Path(folder))
    script = Path(folder) / "live_client.mjs"
    shutil.copyfile(JS_DIR / "live_client.mjs", script)
    return script


@pytest.mark.slow  # npm ci on the first run, then node
def test_the_reference_client_receives_every_frame(
    js_live_client: Path, synthetic_log: Path, tmp_path: Path
) -> None:
    output = tmp_path / "dense.mcap"
    args = [str(synthetic_log), "-o", str(output), "--foxglove", "127.0.0.1:0"]
    with serving(*args, "--wait-for-client") as (process, url):
        done = subprocess.run(
            ["node", js_live_client.name, url, ",".join(OUTPUTS), str(FRAMES)],
            cwd=js_live_client.parent,
            capture_output=True,
            text=True,
            timeout=180,
            check=False,
        )
        assert done.returncode == 0, f"live_client.mjs failed:\n{done.stderr}"
        process.communicate(timeout=120)
    assert process.returncode == 0
    received = json.loads(done.stdout)
    written = _mcap_messages(output)
    for topic in OUTPUTS:
        channel = received[topic]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
        assert channel["schemaName"] == written[topic][0][2]
        assert len(channel["messages"]) == FRAMES == len(written[topic])
        for live, (log_time, data, schema_name, _) in zip(
            channel["messages"], written[topic], strict=True
        ):
            message = rosmsg.deserialize(data, schema_name)
            assert int(live["timestamp"]) == log_time, topic
            assert live["sha256"] == hashlib.sha256(data).hexdigest(), topic
            # decoded by rosmsg2-serialization: the image's / cloud's bytes, so every pixel
            assert live["data_sha256"] == hashlib.sha256(bytes(message.data)).hexdigest()
            assert (live["width"], live["height"]) == (message.width, message.height)
            assert live["header"]["frame_id"] == message.header.frame_id
    assert received["/pcainterp/depth_mm"]["messages"][0]["encoding"] == "16UC1"
    assert received["/pcainterp/features"]["messages"][0]["fields"] == [
        "x",
        "y",
        "z",
        "u",
        "v",
        "disparity",
    ]


# ----------------------------------------------------------------------------- the server


def _raw(topic: str, log_time_ns: int) -> RawMessage:
    text = rosmsg.schema_text(rosmsg.POSE_STAMPED)
    return RawMessage(
        topic=topic,
        msgtype=rosmsg.POSE_STAMPED,
        schema_name=rosmsg.POSE_STAMPED,
        schema_encoding="ros2msg",
        schema_data=text.encode(),
        message_encoding="cdr",
        channel_metadata={"origin": "input"},
        data=struct.pack("<Q", log_time_ns),
        log_time_ns=log_time_ns,
        publish_time_ns=log_time_ns,
        sequence=0,
    )


def test_inputs_are_held_until_their_frame_and_paced(tmp_path: Path) -> None:
    step = 100_000_000  # 0.1 s of log between frames
    with FoxgloveLive(ServeAddress(port=0), rate=1.0, wait_for={"/out"}) as live:
        live.advertise("/out", rosmsg.IMAGE)
        live.add_raw(_raw("/in", 0))  # advertised now, published with frame 0
        result: list[Received] = []
        thread = threading.Thread(
            target=lambda: result.append(_collect(live.url, None, {"/in": 3, "/out": 3}))
        )
        thread.start()
        started = time.monotonic()
        for index in range(3):
            if index:
                live.add_raw(_raw("/in", index * step))
            live.add_frame(index * step, [LiveMessage("/out", rosmsg.IMAGE, b"frame%d" % index)])
        live.flush()
        thread.join(timeout=30)
        elapsed = time.monotonic() - started
    assert elapsed >= 2 * step / 1e9 - 0.01  # rate 1: 0.2 s of log took 0.2 s or more
    got = result[0]
    assert [t for t, _ in got.messages["/in"]] == [0, step, 2 * step]
    assert [data for _, data in got.messages["/out"]] == [b"frame0", b"frame1", b"frame2"]
    assert got.channels["/in"]["schemaName"] == rosmsg.POSE_STAMPED
    assert live.stats.frames == 3
    assert live.stats.messages == 6
    assert live.stats.clients == 1


EPOCH_NS = 1_600_000_000_000_000_000  # camera frames at epoch times


@pytest.mark.parametrize("rate", [1.0, 0.1, 0.01])
def test_a_gap_in_log_time_is_skipped_with_a_note(
    monkeypatch: pytest.MonkeyPatch, rate: float
) -> None:
    """A message at log time 0 before frames at epoch times: no wait of decades, no crash."""
    slept: list[float] = []
    monkeypatch.setattr(foxglove.time, "sleep", slept.append)  # records, never waits
    notes: list[str] = []
    step = 10_000_000  # 0.01 s of log between frames
    with FoxgloveLive(ServeAddress(port=0), rate=rate, note=notes.append) as live:
        live.add_raw(_raw("/static", 0))
        for index in range(3):
            live.add_frame(EPOCH_NS + index * step, [LiveMessage("/out", rosmsg.IMAGE, b"f")])
        live.flush()
    assert slept, "the frames after the gap are paced"
    # the sleeps do not pass: the last frame is due 2 steps after the first
    assert max(slept) <= 2 * step / 1e9 / rate + 0.01
    assert live.stats.gaps_skipped == 1
    assert live.stats.gap_s_skipped == pytest.approx(EPOCH_NS / 1e9)
    assert len(notes) == 1
    assert notes[0].startswith("foxglove: skipped a 1600000000.0 s gap in log time")
    assert "\n" not in notes[0]


def test_gaps_up_to_the_limit_are_waited_for_and_longer_ones_skipped(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    slept: list[float] = []
    monkeypatch.setattr(foxglove.time, "sleep", slept.append)
    notes: list[str] = []
    second = 1_000_000_000
    times = [0, 3 * second, 3 * second + 3600 * second]  # a 3 s gap, then an hour
    times += [times[-1] + 7200 * second * k for k in (1, 2, 3, 4)]  # four gaps of 2 h
    with FoxgloveLive(ServeAddress(port=0), rate=1.0, note=notes.append) as live:
        for log_time_ns in times:
            live.add_frame(log_time_ns, [LiveMessage("/out", rosmsg.IMAGE, b"f")])
    assert len(slept) == 1  # the 3 s gap (minus the time the first frame took)
    assert 0 < slept[0] <= 3.0
    assert live.stats.gaps_skipped == 5
    assert len(notes) == foxglove.MAX_GAP_NOTES  # then only counted
    assert notes[0].startswith("foxglove: skipped a 3600.0 s gap in log time: gaps over 5 s")
    assert notes[-1].endswith("further gaps are counted in the summary")


@pytest.mark.parametrize("rate", ["1e-300", "5e-324", "0.001", "-1", "nan", "inf", "1e6"])
def test_a_rate_out_of_range_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], rate: str
) -> None:
    missing = tmp_path / "missing.mcap"  # the rate is checked before the input is opened
    code = cli.main(["densify", str(missing), "--foxglove", "127.0.0.1:0", "--rate", rate])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1
    assert "--rate must be 0 (as fast as processed) or between 0.01 and 1000" in err


def test_a_message_at_log_time_0_does_not_hold_the_stream(
    synthetic_log: Path, tmp_path: Path
) -> None:
    """The bug: a static transform logged at time 0 held the first frame for 1.6e9 s."""
    log = tmp_path / "t0.mcap"
    with open_log(synthetic_log) as reader, open_writer(log) as writer:
        pose = rosmsg.pose_stamped_message(np.eye(4), 0, "map")
        writer.add_message("/static_pose", pose, 0)
        for raw in reader.messages():
            writer.add_message(raw.topic, reader.decode(raw), raw.log_time_ns)
    output = tmp_path / "dense.mcap"
    command = [sys.executable, "-m", "pcainterp_stream.cli", "densify", str(log)]
    command += ["-o", str(output), "--foxglove", "127.0.0.1:0", "--rate", "0.5"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=300)
    except subprocess.TimeoutExpired as err:
        pytest.fail(f"still waiting for the gap after 300 s: {err.stdout!r}")
    assert done.returncode == 0, done.stderr
    assert "foxglove: skipped a " in done.stdout
    assert "gap in log time (" in done.stdout
    assert "; skipped 1 gap(s) in log time" in done.stdout
    assert output.exists()


def test_a_client_that_drops_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """The SDK logs an error per message it cannot send to a dropped client: one line each."""
    sdk = logging.getLogger("foxglove.websocket.connected_client")  # where the SDK logs
    reset = "WebSocket protocol error: Connection reset without closing handshake"
    with FoxgloveLive(ServeAddress(port=0), rate=0.0) as live:
        live.start()
        for client in ("127.0.0.1:40001", "[::1]:40002"):
            sdk.error("Error receiving from client %s: %s", client, reset)
            for _ in range(5):
                sdk.error(
                    "Error sending message to client %s: IO error: Broken pipe (os error 32)",
                    client,
                )
        sdk.error("Error advertising channel to client: something else")  # not hidden
    sdk.error("Error receiving from client 127.0.0.1:40003: %s", reset)  # our own stop
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        f"foxglove: client 127.0.0.1:40001 disconnected without closing the connection ({reset})",
        f"foxglove: client [::1]:40002 disconnected without closing the connection ({reset})",
        "foxglove: Error advertising channel to client: something else",
    ]
    assert live.stats.dropped == {"127.0.0.1:40001", "[::1]:40002"}


SDK_SEND = "foxglove.websocket.connected_client.send_lossy"
"""A logger under the SDK's (its records of a full outbox; ours handles all of "foxglove")."""


def test_clients_that_fell_behind_are_named_with_no_count(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The SDK logs "outbox full" at most once per 30 s for all its clients: no count."""
    sdk = logging.getLogger(SDK_SEND)
    with FoxgloveLive(ServeAddress(port=0), rate=0.0) as live:
        live.start()
        for client in ("127.0.0.1:40001", "127.0.0.1:40001", "[::1]:40002", "127.0.0.1:40001"):
            sdk.info("outbox for client %s full", client)
    assert live.stats.behind == ["127.0.0.1:40001", "[::1]:40002"]
    assert capsys.readouterr().err == ""  # INFO records: said in the summary only
    live.stats.clients = 2
    behind = (
        "foxglove: 2 client(s) fell behind (127.0.0.1:40001, [::1]:40002): the server "
        "dropped their oldest queued messages at least once; a slow client sees gaps"
    )
    assert foxglove.behind_line(live.stats) == behind
    live.stats.clients = 3  # a client the SDK did not name (its reports are throttled)
    assert foxglove.behind_line(live.stats) == (
        f"{behind} (the Foxglove SDK names at most one client every 30 s: the other 1 may "
        "have lost messages too)"
    )
    live.stats.behind.clear()
    assert foxglove.behind_line(live.stats) is None


def test_the_summary_names_clients_behind_once_each_with_no_count(
    synthetic_log: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two clients, the SDK's reports naming one of them twice (bug hunt 5B, M2)."""
    start = FoxgloveLive.start

    def start_and_overflow(live: FoxgloveLive) -> None:
        start(live)
        live.stats.clients = 2  # as two subscribed
        for _ in range(2):
            logging.getLogger(SDK_SEND).info("outbox for client 127.0.0.1:39744 full")

    monkeypatch.setattr(FoxgloveLive, "start", start_and_overflow)
    args = [str(synthetic_log), "--foxglove", "127.0.0.1:0", "--exit-when-done", "--rate", "0"]
    assert cli.main(["densify", *args]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line for line in out if "behind" in line or "overflow" in line] == [
        "foxglove: 1 client(s) fell behind (127.0.0.1:39744): the server dropped their oldest "
        "queued messages at least once; a slow client sees gaps (the Foxglove SDK names at "
        "most one client every 30 s: the other 1 may have lost messages too)"
    ]


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [
        ("127.0.0.1:8765", "127.0.0.1", 8765),
        ("0.0.0.0:9000", "0.0.0.0", 9000),
        ("[::1]:8765", "::1", 8765),
        (":9001", "127.0.0.1", 9001),
        ("9002", "127.0.0.1", 9002),
        ("localhost:0", "localhost", 0),
    ],
)
def test_addresses(text: str, host: str, port: int) -> None:
    assert ServeAddress.parse(text) == ServeAddress(host, port)


@pytest.mark.parametrize("text", ["", "host:", "host:port", "1.2.3.4:70000", "a:b:1", "[::1]"])
def test_bad_addresses(text: str) -> None:
    with pytest.raises(StreamError, match="bad --foxglove address"):
        ServeAddress.parse(text)


def test_urls_name_a_reachable_host() -> None:
    assert ServeAddress("0.0.0.0", 8765).url() == "ws://127.0.0.1:8765"
    assert ServeAddress("::1", 1).url() == "ws://[::1]:1"


def test_a_port_in_use_is_one_line(synthetic_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = cli.main(["densify", str(synthetic_log), "--foxglove", f"127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1
    assert f"cannot serve Foxglove on 127.0.0.1:{port}" in err
    assert "Address already in use" in err


def test_a_busy_ipv6_port_is_named_in_brackets(capsys: pytest.CaptureFixture[str]) -> None:
    assert str(ServeAddress("::", 8765)) == "[::]:8765"
    assert str(ServeAddress("127.0.0.1", 8765)) == "127.0.0.1:8765"
    try:
        taken = socket.socket(socket.AF_INET6)
        taken.bind(("::1", 0))
    except OSError:
        pytest.skip("no IPv6 loopback here")
    with taken:
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(StreamError, match=re.escape(f"cannot serve Foxglove on [::1]:{port}:")):
            FoxgloveLive(ServeAddress("::1", port)).open()


def test_the_address_is_printed_once_the_input_is_open(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An input that cannot be read must not look served."""
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a log at all")
    code = cli.main(["densify", str(broken), "--foxglove", "127.0.0.1:0"])
    captured = capsys.readouterr()
    assert code == 2
    assert "serving on" not in captured.out
    assert captured.err.count("\n") == 1
    assert str(broken) in captured.err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--foxglove", "127.0.0.1:99999"], "bad --foxglove address '127.0.0.1:99999'"),
        (["--foxglove", "--rate", "-1"], "--rate must be 0 (as fast as processed) or between"),
        (["--rate", "2", "-o", "x.mcap"], "--rate needs --foxglove"),
        ([], "densify needs an output"),
    ],
)
def test_option_errors(
    synthetic_log: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code = cli.main(["densify", str(synthetic_log), *args])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert err.count("\n") == 1


# ----------------------------------------------------------------------- live metadata


class _SeenAtStart(FoxgloveLive):
    """A live server that notes the channels a first client would be advertised."""

    def __init__(self) -> None:
        super().__init__(ServeAddress(port=0), rate=0)
        self.at_start: dict[str, list[dict[str, str]]] | None = None
        self.published: dict[str, set[tuple[tuple[str, str], ...]]] = defaultdict(set)

    def start(self) -> None:
        super().start()
        if self.at_start is None and self._server is not None:
            self.at_start = defaultdict(list)
            for topic, *_, metadata in self._channels:
                self.at_start[topic].append(dict(metadata))

    def add_frame(self, log_time_ns: int, messages: Any) -> None:
        messages = list(messages)
        for message in messages:
            self.published[message.topic].add(tuple(sorted((message.metadata or {}).items())))
        super().add_frame(log_time_ns, messages)


@pytest.fixture(scope="module")
def room_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A room the street basis does not fit: densify adapts (learns the log's own basis)."""
    log = tmp_path_factory.mktemp("foxglove") / "room.mcap"
    synth(log, frames=8, seed=1, scale=0.25, fmt=None, scene="indoor", camera="752x480")
    return log


def test_the_live_outputs_are_advertised_with_the_file_metadata(
    room_log: Path, tmp_path: Path
) -> None:
    """f*b, min disparity, tolerance, encoding, and the basis the run adapted, not the given."""
    out = tmp_path / "room_dense.mcap"
    with _SeenAtStart() as live:
        summary = densify(room_log, out, processor=ProcessorConfig(builtin="street"), live=live)
    assert any(line.startswith("adapted:") for line in summary.prior_lines)
    written = _mcap_channel_metadata(out)
    assert written["/pcainterp/depth"][BASIS_KEY] == "room_dense.basis.npz"
    assert live.at_start is not None
    for topic in output_types(OutputTopics().compact()):
        # one channel per output topic, advertised before the server started
        assert live.at_start[topic] == [written.get(topic, {})], topic
    for topic in written:
        if topic.startswith("/pcainterp/"):
            assert live.published[topic] == {tuple(sorted(written[topic].items()))}, topic


def test_inputs_that_start_the_server_early_advertise_the_outputs_then(
    synthetic_log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Past HOLD_BYTES of input before the first output: the metadata known then."""
    monkeypatch.setattr(log_time_hold, "HOLD_BYTES", 1)
    out = tmp_path / "dense.mcap"
    with _SeenAtStart() as live:
        densify(synthetic_log, out, live=live)
    assert live.at_start is not None
    depth = live.at_start["/pcainterp/depth"]
    assert len(depth) == 1
    assert depth[0][BASIS_KEY] == "built-in"
    assert FOCAL_BASELINE_KEY not in depth[0]  # not known before the first frame
    assert "pcainterp.stamp_tolerance_ns" in depth[0]
    # the frames go out on the channels advertised (no second channel per topic)
    assert live.published["/pcainterp/depth"] == {tuple(sorted(depth[0].items()))}
    assert live.stats.frames == FRAMES
