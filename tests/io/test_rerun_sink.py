"""The Rerun sink's failures: never a traceback, never the job's other outputs lost."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fake_port import loopback_port

from pcainterp_stream import interrupt
from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io import rerun_sink
from pcainterp_stream.io.rerun_sink import RerunSink
from pcainterp_stream.records import DensifiedFrame, StereoCamera, StereoFrame


class _StuckRecording:
    """A recording whose last bytes never arrive: flush times out, as on a full disk."""

    def __init__(self) -> None:
        self.disconnected = False

    def flush(self, *, timeout_sec: float) -> None:
        raise RuntimeError("Flush timed out - not all log messages were sent")

    def disconnect(self) -> None:
        self.disconnected = True


def test_a_viewer_without_a_display_is_refused_before_any_work(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert not rerun_sink.has_display()
    with pytest.raises(LogWriteError, match=r"needs a display.*--rrd"):
        RerunSink(spawn=True).__enter__()
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(rerun_sink, "_x_server_answers", lambda display: True)
    assert rerun_sink.has_display()


def test_a_recording_that_cannot_finish_is_a_warning_and_leaves_no_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "run.rrd"
    sink = RerunSink(rrd_path=target)
    sink.__enter__()
    assert sink._partial is not None
    assert sink._partial.exists()
    stuck = _StuckRecording()
    sink._recording = stuck  # type: ignore[assignment]
    sink.__exit__(None, None, None)  # no exception: the MCAP beside it is committed
    assert stuck.disconnected
    assert not target.exists()
    assert not sink._partial.exists()
    err = capsys.readouterr().err
    assert f"warning: the recording {target} did not take the last frames" in err
    assert "Flush timed out" in err
    assert "nothing was written there" in err


def test_a_viewer_that_went_away_is_a_warning(capsys: pytest.CaptureFixture[str]) -> None:
    sink = RerunSink(spawn=True)
    sink._recording = _StuckRecording()  # type: ignore[assignment]
    sink.__exit__(None, None, None)
    assert "warning: the Rerun viewer did not take the last frames" in capsys.readouterr().err


@pytest.fixture
def temporary_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A TMPDIR of the test's own, to see what the sink leaves there."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def _frame(
    index: int, *, stamp_ns: int | None = None, log_time_ns: int | None = None
) -> DensifiedFrame:
    camera = StereoCamera(width=8, height=6, fx=7.0, fy=7.0, cx=4.0, cy=3.0, baseline=0.5)
    image = np.full((6, 8), 10 * index, np.uint8)
    stamp_ns = index * 100_000_000 if stamp_ns is None else stamp_ns
    log_time_ns = index * 100_000_000 if log_time_ns is None else log_time_ns
    stereo = StereoFrame(index, stamp_ns, log_time_ns, "left", image, image, camera)
    maps = np.full((6, 8), 2.0, np.float32)
    pixels = np.array([[1.0, 2.0], [3.0, 4.0]], np.float32)
    disparities = np.array([1.0, 3.0], np.float32)
    return DensifiedFrame(stereo, pixels, disparities, maps, maps, maps, maps, "stereo", {})


def _entity_rows(rrd: Path) -> dict[str, int]:
    import rerun.chunk

    rows: dict[str, int] = {}
    with warnings.catch_warnings():  # the stand-in's file has no footer (read whole instead)
        warnings.filterwarnings("ignore", "RRD file has no footer")
        chunks = rerun.chunk.RrdReader(rrd).stream().to_chunks()
    for chunk in chunks:
        if not chunk.is_static:
            rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    return rows


def test_a_folder_that_cannot_be_written_is_refused_before_any_frame(
    tmp_path: Path, temporary_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A read-only folder (EROFS, or EACCES for a user): one error, no thread, nothing left."""

    def read_only(self: object) -> None:
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(rerun_sink._Pump, "_open_target", read_only)
    target = tmp_path / "run.rrd"
    with (
        pytest.raises(
            LogWriteError,
            match=r"cannot write .*run\.rrd: Read-only file system; choose a writable folder",
        ),
        RerunSink(rrd_path=target),
    ):
        pass
    assert not list(tmp_path.glob("*.rrd*"))
    assert not list(tmp_path.glob(".run.rrd*"))
    assert not list(temporary_folder.iterdir())  # no pipe folder
    assert not [t for t in threading.enumerate() if t.name == "rrd-pump"]


@pytest.mark.skipif(
    hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into a read-only folder"
)
def test_a_folder_without_write_permission_is_refused(
    tmp_path: Path, temporary_folder: Path
) -> None:
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with (
            pytest.raises(LogWriteError, match=r"Permission denied; choose a writable folder"),
            RerunSink(rrd_path=folder / "run.rrd"),
        ):
            pass
    finally:
        folder.chmod(0o755)
    assert not list(folder.iterdir())
    assert not list(temporary_folder.iterdir())


class _FullDisk:
    def write(self, data: bytes) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    def close(self) -> None:
        pass


def test_the_pump_drains_the_pipe_when_the_partial_cannot_even_be_removed(
    tmp_path: Path, temporary_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A write fails and so does the unlink of the partial: the pipe is still drained.

    Rerun writes into the pipe; had the pump's thread died, its writes would block for ever
    once the pipe is full (the run hung) or fail with a broken pipe (a traceback).
    """
    monkeypatch.setattr(rerun_sink._Pump, "_open_target", lambda self: _FullDisk())
    blocker = tmp_path / "a_file"
    blocker.write_bytes(b"")
    # unlinking a path below a regular file fails with ENOTDIR, not "missing"
    pump = rerun_sink._Pump(blocker / ".run.rrd.partial", tmp_path / "run.rrd")
    written = threading.Event()

    def rerun_writes() -> None:
        with pump.pipe.open("wb") as pipe:
            for _ in range(16):
                pipe.write(bytes(1 << 20))
        written.set()

    writer = threading.Thread(target=rerun_writes, daemon=True)
    writer.start()
    writer.join(20)
    # had the pump's thread died, the writer is blocked on the full pipe or broke it
    assert written.is_set(), "the pump stopped draining Rerun's pipe"
    pump.finish(5)
    assert pump.error is not None
    assert pump.error.endswith("No space left on device")
    assert not list(temporary_folder.iterdir())


def test_the_pipe_folder_is_removed_however_the_command_ends(
    tmp_path: Path, temporary_folder: Path
) -> None:
    """A forced end (second Ctrl-C, the watchdog) removes the tracked partials: the folder too."""
    sink = RerunSink(rrd_path=tmp_path / "run.rrd")
    sink.__enter__()
    try:
        (folder,) = temporary_folder.iterdir()
        assert folder.name.startswith("pcainterp-rrd-")
        interrupt.remove_partials()  # what the second signal's handler does before it exits
        assert not folder.exists()
        assert not list(tmp_path.glob(".run.rrd*"))
    finally:
        sink.__exit__(KeyboardInterrupt, KeyboardInterrupt(), None)
    assert not list(temporary_folder.iterdir())
    assert not (tmp_path / "run.rrd").exists()
    # and a clean end leaves nothing in the temporary folder either
    with RerunSink(rrd_path=tmp_path / "whole.rrd") as whole:
        whole.log(_frame(0))
    assert whole.written
    assert not list(temporary_folder.iterdir())


class _SlowRecording:
    """A recording whose flush takes long (a slow disk, a viewer that stopped reading)."""

    def __init__(self) -> None:
        self.flushed = False
        self.threads: list[threading.Thread] = []

    def flush(self, *, timeout_sec: float) -> None:
        self.threads.append(threading.current_thread())
        self.flushed = True
        time.sleep(min(timeout_sec, 30.0))

    def disconnect(self) -> None:
        self.threads.append(threading.current_thread())


def test_after_a_signal_the_end_waits_for_nothing_kept_and_never_blocks_the_main_thread(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A signal's clean-up does not flush what is thrown away; Rerun is closed off the main thread.

    Rerun's flush is a native call: made in the main thread it held off the second Ctrl-C's
    handler until the watchdog killed the command (exit 137, "did not end in time").
    """
    sink = RerunSink(spawn=True)
    slow = _SlowRecording()
    sink._recording = slow  # type: ignore[assignment]
    started = time.monotonic()
    sink.__exit__(KeyboardInterrupt, KeyboardInterrupt(), None)
    assert time.monotonic() - started < 2.0
    assert not slow.flushed
    assert slow.threads
    assert threading.main_thread() not in slow.threads
    assert capsys.readouterr().err == ""


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


@pytest.fixture
def stand_in_viewer(tmp_path: Path) -> Iterator[tuple[int, Path]]:
    """A Rerun gRPC server on a free loopback port, saving what it receives (a viewer's place)."""
    rerun = Path(sys.executable).with_name("rerun")
    if not rerun.is_file():
        rerun_on_path = shutil.which("rerun")
        if rerun_on_path is None:
            pytest.skip("no rerun executable to stand in for a viewer")
        rerun = Path(rerun_on_path)
    port, received = _free_port(), tmp_path / "received.rrd"
    server = subprocess.Popen(
        [rerun, "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port), "--save", received],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # `rerun` is a launcher: signal its group, the server with it
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                if time.monotonic() > deadline or server.poll() is not None:
                    pytest.fail("the stand-in viewer did not start")
                time.sleep(0.1)
        yield port, received
    finally:
        os.killpg(server.pid, signal.SIGINT)  # it finishes its file on Ctrl-C
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


def test_viewer_and_recording_both_get_every_frame(
    tmp_path: Path,
    temporary_folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    stand_in_viewer: tuple[int, Path],
) -> None:
    """--rerun with --rrd: streamed to the viewer (bound to loopback) and written to the file."""
    import rerun_bindings

    port, received = stand_in_viewer
    monkeypatch.setattr(rerun_sink, "has_display", lambda: True)
    spawned: list[dict[str, Any]] = []
    real_spawn = rerun_bindings.spawn

    def spawn(**kwargs: Any) -> int | None:
        spawned.append(kwargs)
        return real_spawn(**kwargs)  # the port is taken: it starts nothing, as with a viewer open

    monkeypatch.setattr(rerun_bindings, "spawn", spawn)
    target = tmp_path / "run.rrd"
    with RerunSink(rrd_path=target, spawn=True, viewer_port=port) as sink:
        for index in range(3):
            sink.log(_frame(index))
    assert sink.written
    assert not list(temporary_folder.iterdir())
    ((options,),) = [tuple(spawned)]
    assert options["port"] == port
    extra = list(options.get("extra_args", []))
    assert extra[extra.index("--bind") + 1] == "127.0.0.1"  # this machine only
    rows = _entity_rows(target)
    for entity in ("/camera/image", "/camera/depth", "/camera/features", "/depth_std"):
        assert rows[entity] == 3, rows
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not received.is_file():
        time.sleep(0.1)
    # the stand-in saves as it receives; give it the recording's last chunks
    for _ in range(50):
        try:
            if _entity_rows(received).get("/camera/depth") == 3:
                break
        except Exception:  # the stand-in is still writing its last chunk
            pass
        time.sleep(0.2)
    assert _entity_rows(received).get("/camera/depth") == 3


def _time_columns(rrd: Path, entity: str) -> dict[str, list[Any]]:
    """Time line name -> values (in row order) of ``entity`` in a recording."""
    import pyarrow as pa
    import rerun.chunk

    columns: dict[str, list[Any]] = {}
    for chunk in rerun.chunk.RrdReader(rrd).stream().to_chunks():
        if chunk.is_static or str(chunk.entity_path) != entity:
            continue
        batch = chunk.to_record_batch()
        for name in ("stamp", "message_log_time", "log_time", "log_tick"):
            if name in batch.schema.names:
                column = batch.column(batch.schema.names.index(name))
                kind = "timestamp" if pa.types.is_timestamp(column.type) else "duration"
                values = column.cast(pa.int64()).to_pylist()
                columns.setdefault(name, []).extend((kind, value) for value in values)
    return columns


def test_frames_with_one_stamp_are_told_apart_by_their_log_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A driver's zero stamps: the log time line, named as Rerun's MCAP importer names it."""
    target = tmp_path / "run.rrd"
    with RerunSink(rrd_path=target) as sink:
        for index in range(3):
            sink.log(_frame(index, stamp_ns=0))
    columns = _time_columns(target, "/camera/depth")
    assert columns["stamp"] == [("timestamp", 0)] * 3
    # small log times are durations since the log's zero, as Rerun's importer takes them
    log_times = [("duration", index * 100_000_000) for index in range(3)]
    assert columns["message_log_time"] == log_times
    assert "log_time" not in columns  # the run's wall clock is not a time line of the log
    assert "log_tick" not in columns
    err = capsys.readouterr().err
    assert (
        "warning: the left images' header stamps do not advance (3 frames, all at 0 ns): on "
        "the recording's `stamp` time line they are one instant; choose the "
        "`message_log_time` time line in the viewer"
    ) in err


def test_epoch_log_times_are_timestamps_and_advancing_stamps_give_no_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "run.rrd"
    epoch_ns = 1_317_042_000_000_000_000  # 2011
    with RerunSink(rrd_path=target) as sink:
        for index in range(3):
            sink.log(_frame(index, log_time_ns=epoch_ns + index * 100_000_000))
    columns = _time_columns(target, "/camera/depth")
    assert columns["stamp"] == [("timestamp", index * 100_000_000) for index in range(3)]
    assert columns["message_log_time"] == [
        ("timestamp", epoch_ns + index * 100_000_000) for index in range(3)
    ]
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("first", [0, 1])
def test_two_sinks_on_one_recording_path_never_share_a_partial(
    tmp_path: Path, temporary_folder: Path, first: int, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two runs writing one --rrd (closed in either order): each file whole, no exception.

    With one fixed partial name the first to close renamed the other's partial (which
    went on being written into the final file) and the second's rename failed with a
    traceback, which cost that run's MCAP.
    """
    target = tmp_path / "same.rrd"
    sinks = [RerunSink(rrd_path=target), RerunSink(rrd_path=target)]
    for sink in sinks:
        sink.__enter__()
    assert sinks[0]._partial != sinks[1]._partial
    for index, sink in enumerate(sinks):
        for frame in range(3 + 2 * index):
            sink.log(_frame(frame))
    order = [sinks[first], sinks[1 - first]]
    order[0].__exit__(None, None, None)
    assert _entity_rows(target)["/camera/image"] == (3 if first == 0 else 5)
    order[1].__exit__(None, None, None)
    assert all(sink.written for sink in sinks)
    assert _entity_rows(target)["/camera/image"] == (5 if first == 0 else 3)
    assert [p.name for p in tmp_path.iterdir() if p.name != "tmp"] == ["same.rrd"]
    assert "warning" not in capsys.readouterr().err


def test_a_recording_that_cannot_be_moved_onto_its_target_is_a_warning(
    tmp_path: Path, temporary_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The final rename fails (here: a folder is in the way): a warning, the job goes on."""
    target = tmp_path / "run.rrd"
    sink = RerunSink(rrd_path=target)
    sink.__enter__()
    sink.log(_frame(0))
    target.mkdir()
    (target / "keep").write_bytes(b"")  # a non-empty folder: the rename is refused
    sink.__exit__(None, None, None)  # no exception: the MCAP beside it is committed
    assert not sink.written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd", "tmp"]
    err = capsys.readouterr().err
    assert f"warning: cannot move the finished recording onto {target}" in err
    assert err.rstrip().endswith(": Is a directory; no recording was written there")
    assert "whole" not in err  # the MCAP is committed after this warning (bug hunt 7B F11b)


def test_a_killed_runs_partial_recording_is_removed_and_a_live_ones_kept(
    tmp_path: Path, temporary_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A partial named after a dead process goes (one line, its size); a live one stays.

    So does a killed run's pipe folder in the temporary folder (silently: it holds a FIFO)."""
    from pcainterp_stream.io.output_paths import partial_prefix, temporary_prefix

    target = tmp_path / "run.rrd"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    own = partial_prefix(target)
    stale = tmp_path / own.replace(f"-{os.getpid()}@", f"-{dead.pid}@").__add__("abc123")
    stale.write_bytes(bytes(2_500_000))
    live = tmp_path / own.replace(f"-{os.getpid()}@", f"-{os.getppid()}@").__add__("xyz789")
    live.write_bytes(b"x")
    pipes = temporary_prefix("pcainterp-rrd")
    stale_pipe = temporary_folder / (pipes.replace(f"-{os.getpid()}@", f"-{dead.pid}@") + "a1")
    stale_pipe.mkdir()
    os.mkfifo(stale_pipe / "recording.rrd")
    live_pipe = temporary_folder / (pipes.replace(f"-{os.getpid()}@", f"-{os.getppid()}@") + "b2")
    live_pipe.mkdir()
    with RerunSink(rrd_path=target) as sink:
        sink.log(_frame(0))
    assert not stale.exists()
    assert live.exists()
    assert [p.name for p in temporary_folder.iterdir()] == [live_pipe.name]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run.rrd", "tmp", live.name])
    err = capsys.readouterr().err
    assert err.count("note: removed") == 1
    assert f"note: removed {target}'s partial output left by an earlier run that was " in err
    assert "killed (2.5 MB)" in err


def test_a_recording_that_fails_on_a_full_disk_claims_nothing_of_the_other_outputs(
    tmp_path: Path,
    temporary_folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Bug hunt 7B F11b: "...; no recording was written there, the other outputs are whole"
    came just before the MCAP on the same full disk failed too."""
    monkeypatch.setattr(rerun_sink._Pump, "_open_target", lambda self: _FullDisk())
    target = tmp_path / "run.rrd"
    sink = RerunSink(rrd_path=target)
    sink.__enter__()
    sink.log(_frame(0))
    sink.__exit__(None, None, None)
    assert not sink.written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp"]
    err = capsys.readouterr().err
    assert err == (
        f"warning: cannot write {target}: No space left on device; no recording was written there\n"
    )


def test_a_recording_whose_folder_was_removed_says_so(
    tmp_path: Path, temporary_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Bug hunt 7B F11a, for --rrd: not "cannot move ...: No such file or directory"."""
    folder = tmp_path / "gone"
    folder.mkdir()
    target = folder / "run.rrd"
    sink = RerunSink(rrd_path=target)
    sink.__enter__()
    sink.log(_frame(0))
    shutil.rmtree(folder)
    sink.__exit__(None, None, None)  # a warning, no exception
    assert not sink.written
    assert not list(temporary_folder.iterdir())
    assert capsys.readouterr().err == (
        f"warning: cannot write {target}: folder {folder} no longer exists (removed while the "
        "recording was being written); no recording was written there\n"
    )


class _Recorded:
    """A file handle that says whether it was closed."""

    def __init__(self) -> None:
        self.closed = False

    def write(self, data: bytes) -> int:
        return len(data)

    def close(self) -> None:
        self.closed = True


def test_a_temporary_folder_without_named_pipes_is_named_and_leaves_nothing(
    tmp_path: Path, temporary_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 55b R55b-6: a failed mkfifo left the pipe folder in TMPDIR and the partial's
    handle open, and said "choose a writable folder" of the recording's (fine) folder."""
    handles: list[_Recorded] = []

    def opened(self: Any) -> _Recorded:
        handles.append(_Recorded())
        self.target.write_bytes(b"")  # as open("wb") would
        return handles[-1]

    def refused(path: Any) -> None:
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(rerun_sink._Pump, "_open_target", opened)
    monkeypatch.setattr(rerun_sink.os, "mkfifo", refused)
    target = tmp_path / "run.rrd"
    with pytest.raises(LogWriteError) as caught, RerunSink(rrd_path=target):
        pass
    assert str(caught.value) == (
        f"cannot write {target}: no named pipe can be made in the temporary folder "
        f"{temporary_folder} (Operation not permitted); set TMPDIR to a local writable folder"
    )
    assert [h.closed for h in handles] == [True]
    assert list(temporary_folder.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp"]
    assert not any(str(p).startswith(str(tmp_path)) for p in interrupt._partials)


@pytest.mark.usefixtures("umask_027_unchanged")
def test_the_recording_mode_is_set_without_changing_the_umask(
    tmp_path: Path, temporary_folder: Path
) -> None:
    """Review 55b R55b-5: the umask was set to 0 for a moment while other threads run."""
    target = tmp_path / "run.rrd"
    with RerunSink(rrd_path=target) as sink:
        sink.log(_frame(0))
    assert target.stat().st_mode & 0o777 == 0o640


def test_a_pipe_folder_of_another_pid_namespace_is_kept(
    tmp_path: Path, temporary_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 55b R55b-1 for TMPDIR: another container's live run's pipe folder is kept."""
    from pcainterp_stream.io import output_paths

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        monkeypatch.setattr(output_paths, "_pid_namespace", lambda: "111", raising=False)
        output_paths._scope.cache_clear()
        theirs = output_paths.temporary_prefix("pcainterp-rrd")
        theirs = theirs.replace(f"-{os.getpid()}@", f"-{dead.pid}@") + "a1"
        (temporary_folder / theirs).mkdir()
        monkeypatch.setattr(output_paths, "_pid_namespace", lambda: "222", raising=False)
        output_paths._scope.cache_clear()
        with RerunSink(rrd_path=tmp_path / "run.rrd") as sink:
            sink.log(_frame(0))
    finally:
        monkeypatch.undo()
        output_paths._scope.cache_clear()
    assert [p.name for p in temporary_folder.iterdir()] == [theirs]


def _no_spawn(**kwargs: Any) -> int | None:
    raise AssertionError("a viewer was spawned")


def _free_x_display() -> str:
    """A display number where no X server answers (no socket, nothing on TCP 6000+N)."""
    for number in range(97, 200):
        if not Path(f"/tmp/.X11-unix/X{number}").exists() and not rerun_sink._connects(
            socket.AF_INET, ("127.0.0.1", 6000 + number)
        ):
            if not rerun_sink._connects(socket.AF_UNIX, f"\0/tmp/.X11-unix/X{number}"):
                return f":{number}"
    pytest.skip("no free X display number")


def test_a_display_where_no_x_server_answers_is_refused_before_spawning(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Bug hunt 9C F1: with a stale DISPLAY (tmux outliving its X login, ssh -X gone) the
    viewer died at once, and densify waited ~6 s for it, streamed into nothing, printed 8 of
    Rerun's raw log lines and "did not take the last frames": 21 s for a 2 s job, rc 0."""
    import rerun_bindings

    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    display = _free_x_display()
    monkeypatch.setenv("DISPLAY", display)
    monkeypatch.setattr(rerun_bindings, "spawn", _no_spawn)
    port = _free_port()
    started = time.monotonic()
    with pytest.raises(LogWriteError) as caught:
        RerunSink(spawn=True, viewer_port=port).__enter__()
    assert time.monotonic() - started < 5
    message = str(caught.value)
    assert "\n" not in message
    assert f"none answers at DISPLAY={display}" in message
    assert "record with --rrd FILE instead" in message
    assert not rerun_sink.has_display()


def test_an_x_server_that_answers_is_a_display(monkeypatch: pytest.MonkeyPatch) -> None:
    """``HOST:N`` is TCP port 6000+N of HOST (ssh -X's ``localhost:10``)."""
    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        number = server.getsockname()[1] - 6000
        assert rerun_sink._x_server_answers(f"127.0.0.1:{number}.0") is True
        monkeypatch.setenv("DISPLAY", f"localhost:{number}")
        assert rerun_sink.display_problem() is None
    assert rerun_sink._x_server_answers(f"127.0.0.1:{number}") is False
    assert rerun_sink._x_server_answers("host::0") is None  # DECnet: not looked at
    assert rerun_sink._x_server_answers("garbage") is None


def test_a_viewer_that_exits_at_once_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """A viewer that dies for another reason: said at once, not streamed into."""
    import rerun_bindings

    child = subprocess.Popen([sys.executable, "-c", "raise SystemExit(1)"])
    pid = child.pid
    child.returncode = 0  # let spawn_viewer, not Popen, reap it
    monkeypatch.setattr(rerun_bindings, "spawn", lambda **kwargs: pid)
    time.sleep(0.5)
    with pytest.raises(LogWriteError, match=r"the Rerun viewer exited at once \(status 1\)"):
        rerun_sink.spawn_viewer(_free_port())


def test_a_viewer_listening_gets_the_stream_without_a_display(
    monkeypatch: pytest.MonkeyPatch, stand_in_viewer: tuple[int, Path]
) -> None:
    """Bug hunt 9C F2: docs/viewing.md says a viewer already listening on the port gets the
    stream; on a machine without DISPLAY (a headless `rerun --serve-grpc`, a laptop's viewer
    reached by `ssh -R 9876:...`) --rerun was refused "needs a display"."""
    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    port, received = stand_in_viewer
    with RerunSink(spawn=True, viewer_port=port) as sink:
        for index in range(2):
            sink.log(_frame(index))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not received.is_file():
        time.sleep(0.1)
    with pytest.raises(LogWriteError, match="or start a viewer yourself"):
        RerunSink(spawn=True, viewer_port=_free_port()).__enter__()


@pytest.fixture
def fake_viewer(request: pytest.FixtureRequest) -> Iterator[int]:
    """A loopback port that accepts connections and then closes them ("close": an `ssh -R`
    with no viewer behind it, a viewer closed) or never answers ("hold": a suspended viewer)."""
    with loopback_port(request.param) as port:
        yield port


@pytest.mark.parametrize("fake_viewer", ["close", "hold"], indirect=True)
def test_a_viewer_that_fails_or_never_answers_costs_not_the_recording_file(
    tmp_path: Path,
    temporary_folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    fake_viewer: int,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """--rerun --rrd: the file is written whole whatever the viewer does, and the end waits
    at most VIEWER_FLUSH_S for it (bug hunt 12A F3: the viewer's failure discarded the file;
    F4: a viewer that accepted and never answered held the end for ever)."""
    monkeypatch.setattr(rerun_sink, "spawn_viewer", lambda port: None)
    monkeypatch.setattr(rerun_sink, "has_display", lambda: True)
    monkeypatch.setattr(rerun_sink, "VIEWER_FLUSH_S", 1.0)
    target = tmp_path / "run.rrd"
    outcome: list[bool] = []

    def run() -> None:
        with RerunSink(rrd_path=target, spawn=True, viewer_port=fake_viewer) as sink:
            for index in range(3):
                sink.log(_frame(index))
        outcome.append(sink.written)

    started = time.monotonic()
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(15)
    assert not worker.is_alive(), "the end waited on a viewer that does not answer"
    assert time.monotonic() - started < 8
    assert outcome == [True]
    for entity in ("/camera/image", "/camera/depth", "/camera/features", "/depth_std"):
        assert _entity_rows(target)[entity] == 3
    assert not list(temporary_folder.iterdir())
    warning = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(warning) == 1, warning
    assert warning[0].startswith("warning: the Rerun viewer did not take the last frames")
    assert warning[0].endswith(f"; {target} is complete")


@pytest.mark.parametrize("fake_viewer", ["hold"], indirect=True)
def test_a_viewer_that_never_answers_holds_the_end_at_most_its_deadline(
    monkeypatch: pytest.MonkeyPatch, fake_viewer: int, capsys: pytest.CaptureFixture[str]
) -> None:
    """--rerun alone to a suspended viewer: the end gives up after VIEWER_FLUSH_S (12A F4)."""
    monkeypatch.setattr(rerun_sink, "spawn_viewer", lambda port: None)
    monkeypatch.setattr(rerun_sink, "has_display", lambda: True)
    monkeypatch.setattr(rerun_sink, "VIEWER_FLUSH_S", 1.0)

    def run() -> None:
        with RerunSink(spawn=True, viewer_port=fake_viewer) as sink:
            for index in range(3):
                sink.log(_frame(index))

    started = time.monotonic()
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(15)
    assert not worker.is_alive(), "the end waited on a viewer that does not answer"
    assert time.monotonic() - started < 8
    err = capsys.readouterr().err
    assert "warning: the Rerun viewer did not take the last frames (no answer in 1 s)" in err
