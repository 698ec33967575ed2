"""``pcainterp densify - -o -``: an MCAP stream in on standard input, out on standard output.

The output is written to a pipe that cannot seek; it must read back front to back with
mcap's stream reader (no summary offsets used) and with rosbags, and hold the same messages
as the file output of the same log. Progress and the summary go to standard error.
"""

from __future__ import annotations

import io
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.pipes import McapStreamWriter, spool

FRAMES = 3


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("pipes")
    log, dense = folder / "in.mcap", folder / "file_dense.mcap"
    assert cli.main(["synth", str(log), "--frames", str(FRAMES), "--scale", "0.25"]) == 0
    assert cli.main(["densify", str(log), "-o", str(dense)]) == 0
    return log, dense


def _stream_messages(data: bytes) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message, read front to back by mcap's stream reader."""
    channels: dict[int, str] = {}
    found = []
    for record in StreamReader(io.BytesIO(data), skip_magic=False).records:
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message):
            found.append((channels[record.channel_id], record.log_time, bytes(record.data)))
    return found


def test_a_log_piped_through_cat(logs: tuple[Path, Path], tmp_path: Path) -> None:
    log, file_dense = logs
    out = tmp_path / "out.mcap"
    densify = f"{shlex.quote(sys.executable)} -m pcainterp_stream.cli densify - -o -"
    done = subprocess.run(
        f"cat {shlex.quote(str(log))} | {densify} > {shlex.quote(str(out))}",
        shell=True,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == ""  # everything printed went to standard error
    assert f"densified {FRAMES} frames of stdin" in done.stderr
    assert "wrote <stdout>" in done.stderr
    piped = _stream_messages(out.read_bytes())
    assert piped == _stream_messages(file_dense.read_bytes())
    assert sum(topic == "/pcainterp/depth" for topic, _, _ in piped) == FRAMES
    with AnyReader([out]) as reader:  # rosbags builds the types from the embedded schemas
        depth = [c for c in reader.connections if c.topic == "/pcainterp/depth"]
        images = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(depth)]
    assert len(images) == FRAMES
    assert images[0].format == "32FC1; compressedDepth png"  # the default, compact


def test_the_stream_writer_never_seeks_nor_closes(tmp_path: Path) -> None:
    class Pipe(io.RawIOBase):
        def __init__(self) -> None:
            self.data = bytearray()

        def writable(self) -> bool:
            return True

        def seekable(self) -> bool:
            return False

        def write(self, data: bytes) -> int:  # type: ignore[override]
            self.data += data
            return len(data)

    pipe = Pipe()
    with McapStreamWriter(pipe) as writer:  # type: ignore[arg-type]
        writer.add_message("/pose", rosmsg.pose_stamped_message(np.eye(4), 5, "world"), 5)
    assert not pipe.closed
    assert [(topic, time) for topic, time, _ in _stream_messages(bytes(pipe.data))] == [
        ("/pose", 5)
    ]
    assert writer.summary().message_count == 1


def test_empty_standard_input_is_one_clear_error() -> None:
    with pytest.raises(LogReadError, match="standard input is empty"), spool(io.BytesIO(b"")):
        pass


def test_stdin_is_refused_with_out_dir(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["densify", "-", "--out-dir", "x"]) == 2
    assert "standard input (-) is one log" in capsys.readouterr().err
