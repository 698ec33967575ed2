"""``pcainterp densify - -o -``: an MCAP stream in on standard input, out on standard output.

The output is written to a pipe that cannot seek; it must read back front to back with
mcap's stream reader (no summary offsets used) and with rosbags, and hold the same messages
as the file output of the same log. Progress and the summary go to standard error.
"""

from __future__ import annotations

import errno
import io
import os
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError, LogWriteError
from pcainterp_stream.interrupt import InterruptedStreamOutput
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


class _Pipe(io.RawIOBase):
    """A pipe that takes at most ``most`` bytes a write, then fails with ``error`` after
    ``room`` bytes."""

    def __init__(self, *, most: int = 1 << 30, room: int = 1 << 30, error: int = 0) -> None:
        self.data = bytearray()
        self.most, self.room, self.error = most, room, error

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        taken = bytes(data)[: min(self.most, self.room - len(self.data))]
        if not taken:
            raise OSError(self.error, os.strerror(self.error))
        self.data += taken
        return len(taken)


def _write_frames(writer: McapStreamWriter, frames: int) -> None:
    rng = np.random.default_rng(0)
    for index in range(frames):
        depth = rng.uniform(1, 50, size=(600, 800)).astype(np.float32)  # 1.9 MB
        writer.add_message("/depth", rosmsg.image_message(depth, index, "left"), index)


def test_an_unbuffered_stream_that_takes_part_of_a_write_gets_the_rest() -> None:
    """``PYTHONUNBUFFERED=1`` makes standard output a raw file, whose write may take part
    of the bytes (a pipe interrupted by a signal, a disk filling up): the rest was lost."""
    pipe = _Pipe(most=65536)
    with McapStreamWriter(pipe) as writer:  # type: ignore[arg-type]
        _write_frames(writer, 3)
    assert [time for _, time, _ in _stream_messages(bytes(pipe.data))] == [0, 1, 2]
    assert writer.written == len(pipe.data)


def test_a_full_disk_under_standard_output_is_one_error_naming_the_bytes_sent() -> None:
    """``densify -o - > FILE`` on a full disk: the bytes sent stay there, and the error says
    so (it was a traceback once the stream was running)."""
    pipe = _Pipe(most=65536, room=3_000_000, error=errno.ENOSPC)
    message = (
        r"writing <stdout> failed: OSError: \[Errno 28\] No space left on device; the MCAP "
        r"written to standard output is incomplete \(3000000 bytes\); discard it$"
    )
    with (
        pytest.raises(LogWriteError, match=message),
        McapStreamWriter(pipe) as writer,  # type: ignore[arg-type]
    ):
        _write_frames(writer, 3)
    assert len(pipe.data) == 3_000_000


def test_a_reader_that_goes_away_is_a_broken_pipe_still() -> None:
    """``densify -o - | head -c 100``: the program ends quietly, as on any broken pipe."""
    pipe = _Pipe(room=100, error=errno.EPIPE)
    with pytest.raises(BrokenPipeError), McapStreamWriter(pipe) as writer:  # type: ignore[arg-type]
        _write_frames(writer, 3)


@pytest.mark.parametrize("when", ["while writing", "after the end"])
def test_an_interruption_says_what_standard_output_holds(when: str) -> None:
    """Ctrl-C of ``densify -o - > out.mcap``: the bytes sent cannot be taken back; the
    interruption says how many there are and whether they are the whole MCAP."""
    pipe = _Pipe()

    def interrupted() -> None:
        with McapStreamWriter(pipe) as writer:  # type: ignore[arg-type]
            _write_frames(writer, 3)
            if when == "after the end":
                writer.close()
            raise KeyboardInterrupt

    with pytest.raises(InterruptedStreamOutput) as raised:
        interrupted()
    size = len(pipe.data)
    assert raised.value.written == size > 3_000_000
    state = "complete" if when == "after the end" else "incomplete"
    assert str(raised.value).startswith(
        f"the MCAP written to standard output is {state} ({size} bytes)"
    )
    assert str(raised.value).endswith("discard it") == (state == "incomplete")


def test_a_killed_runs_copy_of_standard_input_is_removed_by_the_next(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bug hunt 9C F5: a SIGKILL of `cat LOG | pcainterp densify - ...` left the whole log's
    copy in $TMPDIR/pcainterp-stdin-XXXX (114 MB; RAM on a tmpfs), kept by every later run."""
    import tempfile

    from pcainterp_stream.io.output_paths import temporary_prefix

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    prefix = temporary_prefix("pcainterp-stdin")
    killed = tmp_path / (prefix.replace(f"-{os.getpid()}@", f"-{process.pid}@") + "t1x6e3v1")
    killed.mkdir()
    (killed / "stdin").write_bytes(bytes(1000))
    live = tmp_path / (prefix.replace(f"-{os.getpid()}@", f"-{os.getppid()}@") + "abcdefgh")
    live.mkdir()  # a run still going
    with spool(io.BytesIO(b"some log bytes")) as path:
        assert path.parent.name.startswith(prefix)
        assert not killed.exists()
        assert live.is_dir()
    assert sorted(os.listdir(tmp_path)) == [live.name]
