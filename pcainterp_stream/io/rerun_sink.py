"""Rerun sink: log densified frames to a viewer or an ``.rrd`` recording.

Time lines: ``stamp``, the left image's header stamp, and ``message_log_time``, its log time
(the name Rerun's own MCAP importer gives the log time, so the recording and the densified
MCAP opened in one viewer share it; a timestamp from 1990 to 2100, a duration otherwise, as
that importer guesses). Rerun's automatic ``log_time``, the wall clock of the run, is off.

Entity layout:

- ``camera``: the left camera's ``Pinhole`` (image plane, focal length, principal point);
- ``camera/image``: the left image;
- ``camera/features``: the sparse measurements, coloured by disparity;
- ``camera/depth``: the dense depth (``DepthImage``, metres, turbo colour map over the fixed
  range 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH`; ``+inf`` = too far);
- ``depth_std``: the posterior depth std (m) as a second depth image, so it gets its own view
  (viridis, 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH_STD`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

from pcainterp_stream.defaults import DISPLAY_MAX_DEPTH, DISPLAY_MAX_DEPTH_STD
from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.interrupt import signalled, track_partial, untrack_partial
from pcainterp_stream.io.output_paths import (
    partial_prefix,
    process_umask,
    remove_stale_partials,
    remove_stale_temporaries,
    removed_meanwhile,
    temporary_prefix,
    write_advice,
)
from pcainterp_stream.records import DensifiedFrame

if TYPE_CHECKING:
    import rerun as rr

TIMELINE = "stamp"
"""The time line of the left image's header stamp."""

LOG_TIME_TIMELINE = "message_log_time"
"""The time line of the left image's log time, named as Rerun's MCAP importer names it."""

_EPOCH_SPAN_NS = (631_148_400_000_000_000, 4_102_444_800_000_000_000)
"""Log times Rerun's MCAP importer takes for Unix timestamps (1990 to 2100); others are
durations since the log's own zero."""

VIEWER_FLUSH_S = 10.0
"""How long the end of a job waits for the viewer to take the last frames (a viewer that
does not answer, suspended or frozen, is then left: Rerun's own flush would wait for ever)."""

FILE_FLUSH_S = 300.0
"""How long it waits for the recording's last bytes to reach its file."""

PUMP_CHUNK = 1 << 20
"""Bytes the recording's pump moves from Rerun's pipe to the file at a time."""

VIEWER_NOTE_S = 0.5
"""After this long waiting for the viewer the end says it waits (as Foxglove's end does)."""

CLOSE_AFTER_SIGNAL_S = 1.0
"""After a signal, how long the end waits for Rerun to close its sinks (nothing is kept)."""

VIEWER_HOST = "127.0.0.1"
"""The address a spawned viewer listens on: this machine only."""

VIEWER_PORT = 9876
"""The port of the spawned viewer (Rerun's default)."""


NO_DISPLAY = (
    "--rerun starts a Rerun viewer, which needs a display (neither DISPLAY nor "
    "WAYLAND_DISPLAY is set)"
)
"""The start of the error for a viewer on a machine without one; the caller adds the fix."""

DISPLAY_WAIT_S = 1.0
"""How long a look at the display, or at a viewer listening on the port, may take."""

START_YOURSELF = (
    f"or start a viewer yourself (`rerun --bind {VIEWER_HOST}`) where there is a display and "
    f"forward its port {VIEWER_PORT} to this machine (`ssh -R {VIEWER_PORT}:127.0.0.1:"
    f"{VIEWER_PORT} THIS_MACHINE`)"
)
"""The other fix for a viewer that cannot open a window here: one listening elsewhere."""


def has_display() -> bool:
    """Whether a spawned viewer can open a window: not on Linux without X11 or Wayland."""
    return display_problem() is None


def display_problem() -> str | None:
    """Say why a spawned viewer could not open a window here (None: it can, or unknown).

    On Linux a DISPLAY that is set but where no X server answers (a tmux or screen session
    that outlived its X login, ``ssh -X`` whose forwarding is gone, a container that copied
    the host's DISPLAY) is as good as none: the viewer dies at once ("Failed to open
    connection to X server"). A Wayland socket that is there is taken as a display.
    """
    if not sys.platform.startswith("linux"):
        return None
    wayland, display = os.environ.get("WAYLAND_DISPLAY"), os.environ.get("DISPLAY")
    if not wayland and not display:
        return NO_DISPLAY
    if wayland and _wayland_socket_exists(wayland):
        return None
    if display and _x_server_answers(display) is not False:
        return None
    shown = f"DISPLAY={display}" if display else f"WAYLAND_DISPLAY={wayland}"
    return (
        f"--rerun starts a Rerun viewer, which needs a display, and none answers at {shown} "
        "(a session that outlived its X login, or ssh -X forwarding that is gone?)"
    )


def _wayland_socket_exists(name: str) -> bool:
    folder = os.environ.get("XDG_RUNTIME_DIR")
    if not os.path.isabs(name) and not folder:
        return True  # unknown: taken as there
    return os.path.exists(name if os.path.isabs(name) else os.path.join(folder or "", name))


def _connects(family: int, address: str | tuple[Any, ...]) -> bool:
    try:
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.settimeout(DISPLAY_WAIT_S)
            sock.connect(address)
    except OSError:
        return False
    return True


def _x_server_answers(display: str) -> bool | None:
    """Whether an X server accepts connections at ``display`` (None: a form not understood).

    ``[PROTOCOL/][HOST]:N[.SCREEN]``: a local display's socket (Linux's abstract one, then
    ``/tmp/.X11-unix/XN``, then TCP 6000+N on this machine, as libxcb tries them), else TCP
    port 6000+N of HOST (``localhost:10`` of ``ssh -X``).
    """
    if display.startswith("/"):  # a socket path (XQuartz's launchd form)
        return _connects(socket.AF_UNIX, display.rsplit(":", 1)[0]) or _connects(
            socket.AF_UNIX, display
        )
    host, colon, rest = display.rpartition(":")
    number = rest.split(".", 1)[0]
    if not colon or not number.isdigit() or host.endswith(":"):  # DECnet's HOST::N
        return None
    protocol, _, host = host.rpartition("/")
    port = 6000 + int(number)
    if host in ("", "unix") or protocol == "unix":
        path = f"/tmp/.X11-unix/X{number}"
        if _connects(socket.AF_UNIX, "\0" + path) or _connects(socket.AF_UNIX, path):
            return True
        if protocol == "unix" or host == "unix":
            return False
        host = "localhost"
    host = host.strip("[]")
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError:
        return False
    return any(_connects(family, address) for family, _, _, _, address in addresses)


def viewer_listening(port: int) -> bool:
    """Whether something accepts connections on loopback ``port`` (a viewer started by hand)."""
    return _connects(socket.AF_INET, (VIEWER_HOST, port))


class _Pump:
    """Move the bytes Rerun's file sink writes into a pipe on to the recording's file.

    Rerun's own file sink never returns from its shutdown once a write has failed (a full
    disk), so it is given a named pipe and this thread writes the file: a failed write is
    remembered, the partial file removed, and the pipe drained to its end whatever happens,
    so Rerun always finishes. Where there are no named pipes (Windows) Rerun writes the file
    itself.

    The file is opened here, in the caller's thread, so a target that cannot be written at
    all raises ``OSError`` before any frame; the pipe's temporary folder is a tracked partial
    output, removed however the command ends.
    """

    def __init__(self, target: Path, name: Path) -> None:
        self.target = target
        self.name = name  # the file the user named (``target`` is its partial)
        self.error: str | None = None
        out = self._open_target()  # OSError: the caller refuses the path
        try:
            remove_stale_temporaries(Path(tempfile.gettempdir()), "pcainterp-rrd")
            self._folder = Path(tempfile.mkdtemp(prefix=temporary_prefix("pcainterp-rrd")))
        except OSError as err:
            self._close(out)
            self.target.unlink(missing_ok=True)
            raise LogWriteError(
                f"cannot write {name}: no temporary folder for its pipe ({err.strerror or err}); "
                "set TMPDIR to a writable folder"
            ) from err
        track_partial(self._folder)  # removed even if a signal forces the end
        self.pipe = self._folder / "recording.rrd"
        try:
            os.mkfifo(self.pipe)
        except OSError as err:  # a temporary folder without named pipes (some FUSE/SMB mounts)
            self._close(out)
            self.target.unlink(missing_ok=True)
            self.remove_folder()
            raise LogWriteError(
                f"cannot write {name}: no named pipe can be made in the temporary folder "
                f"{self._folder.parent} ({err.strerror or err}); set TMPDIR to a local "
                "writable folder"
            ) from err
        self._thread = threading.Thread(target=self._run, args=(out,), name="rrd-pump", daemon=True)
        self._thread.start()

    def _run(self, out: BinaryIO | None) -> None:
        try:
            with self.pipe.open("rb") as source:
                while chunk := source.read(PUMP_CHUNK):
                    if out is None:
                        continue  # given up: drained, so that Rerun can finish
                    try:
                        out.write(chunk)
                    except OSError as error:
                        self._fail(error)
                        self._close(out)
                        out = None
        except OSError as error:  # the pipe itself
            self._fail(error)
        finally:
            if out is not None:
                self._close(out)

    def _open_target(self) -> BinaryIO:
        return self.target.open("wb")

    def _close(self, out: BinaryIO) -> None:
        try:
            out.close()
        except OSError as error:  # the last buffered bytes
            self._fail(error)
        if self.error is not None:
            self._remove_target()

    def _fail(self, error: OSError) -> None:
        if self.error is None:
            self.error = f"cannot write {self.name}: {error.strerror or error}"
        self._remove_target()  # free what it took of the disk at once

    def _remove_target(self) -> None:
        with contextlib.suppress(OSError):  # the folder may refuse even that
            self.target.unlink(missing_ok=True)

    def finish(self, timeout: float) -> None:
        """Wait for the pipe's end (Rerun closed it), then remove the pipe."""
        deadline = time.monotonic() + timeout
        while self._thread.is_alive() and time.monotonic() < deadline:
            try:  # Rerun never opened it: a writer that closes at once ends the read
                os.close(os.open(self.pipe, os.O_WRONLY | os.O_NONBLOCK))
                break  # opened and being written: the read ends when Rerun closes it
            except OSError:  # no reader yet: the thread has not reached its open
                self._thread.join(0.05)
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive() and self.error is None:
            self.error = f"cannot write {self.name}: its bytes did not arrive in {timeout:g} s"
        self.remove_folder()

    def remove_folder(self) -> None:
        """Remove the pipe's temporary folder (the thread, if still reading, ends with us)."""
        shutil.rmtree(self._folder, ignore_errors=True)
        untrack_partial(self._folder)


def spawn_viewer(port: int) -> None:
    """Start a Rerun viewer listening on loopback ``port``, or use the one listening there.

    ``rr.spawn`` starts it on every interface (Rerun's default bind, 0.0.0.0); this binds it
    to 127.0.0.1, as densify's Foxglove server is by default, so that only this machine can
    connect to the stream. Waits until the viewer accepts connections.
    """
    import rerun_bindings

    if os.environ.get("_RERUN_TEST_FORCE_SAVE") is not None:
        return  # Rerun's own test switch: every stream goes to disk, no viewer (as rr.spawn)
    pid = rerun_bindings.spawn(  # None: one listens there already; else waits ~5 s for it
        port=port,
        extra_args=["--bind", VIEWER_HOST],
        extra_env=[
            ("RERUN_APP_ONLY", "true"),  # as rr.spawn: no analytics opt-in prompt
            ("RUST_LOG", os.environ.get("RUST_LOG", "warn")),  # not its INFO lines
        ],
    )
    status = _exit_status(pid)
    if status is not None:  # it died (its own "Error: ..." line above says why)
        raise LogWriteError(
            f"--rerun: the Rerun viewer exited at once (status {status}) without listening on "
            f"{VIEWER_HOST}:{port}; record with --rrd FILE instead and open it with `rerun FILE`"
        )


def _exit_status(pid: int | None) -> int | None:
    """The exit status of the spawned viewer ``pid`` if it has ended (None: running, or none)."""
    if not isinstance(pid, int) or pid <= 0 or not hasattr(os, "waitpid"):
        return None
    try:
        done, status = os.waitpid(pid, os.WNOHANG)
    except OSError:  # not our child (a Rerun that detaches it): not looked at
        return None
    return os.waitstatus_to_exitcode(status) if done else None


class RerunSink:
    """Log :class:`DensifiedFrame` records to Rerun, as a context manager.

    With both ``rrd_path`` and ``spawn`` the recording goes to both, the viewer and the file,
    as two Rerun recording streams of one recording id: the file is flushed on its own, so
    a viewer that went away or does not answer never costs the file (Rerun flushes every
    sink of a stream at once, and one failed sink failed the flush), and the end waits at
    most :data:`VIEWER_FLUSH_S` for the viewer.

    Args:
        rrd_path: write a recording to this file (written to a temporary beside it and
            renamed when the sink closes without error).
        spawn: start a viewer (or use the one listening on ``viewer_port``) and stream to it.
        application_id: Rerun application id.
        viewer_port: the loopback port of the viewer.
        defer_viewer_wait: on a clean exit, leave the wait for the viewer to
            :meth:`wait_for_viewer` (called once the job's other outputs are committed, so
            that a Ctrl-C in that wait costs none of them).
    """

    def __init__(
        self,
        *,
        rrd_path: str | Path | None = None,
        spawn: bool = False,
        application_id: str = "pcainterp",
        viewer_port: int = VIEWER_PORT,
        defer_viewer_wait: bool = False,
    ) -> None:
        if rrd_path is None and not spawn:
            raise ValueError("RerunSink needs rrd_path or spawn=True")
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        self.spawn = spawn
        self.application_id = application_id
        self.viewer_port = viewer_port
        self._defer_viewer_wait = defer_viewer_wait
        self._closing: _Closer | None = None  # the viewer's close, deferred (defer_viewer_wait)
        self._partial: Path | None = None
        self._pump: _Pump | None = None
        self.written = False
        """Whether the recording file was written whole (set when the sink closes)."""
        self._recording: rr.RecordingStream | None = None  # the file's, else the viewer's
        self._viewer: rr.RecordingStream | None = None  # the viewer's, beside a file's
        self._camera_logged: tuple[int, int, float, float, float, float] | None = None
        self._log_time_is_epoch: bool | None = None  # decided at the first frame
        self._stamps: tuple[int, int, bool] | None = None  # frames, first stamp ns, any other

    def __enter__(self) -> RerunSink:
        import rerun as rr  # imported when used: ~0.3 s of every densify start-up otherwise

        if self.spawn and not viewer_listening(self.viewer_port):  # else it gets the stream
            problem = display_problem()
            if problem is not None:
                raise LogWriteError(
                    f"{problem}; record with --rrd FILE instead and open it with `rerun FILE` "
                    f"where there is one, {START_YOURSELF}"
                )
        recordings: list[rr.RecordingStream] = []
        recording_id = str(uuid.uuid4())  # one recording, in the file and in the viewer
        try:
            sinks: list[rr.GrpcSink | rr.FileSink] = []
            if self.rrd_path is not None:  # before the viewer: a path refused starts none
                sinks.append(rr.FileSink(self._open_recording_file(self.rrd_path)))
            if self.spawn:
                spawn_viewer(self.viewer_port)
                sinks.append(rr.GrpcSink(f"rerun+http://{VIEWER_HOST}:{self.viewer_port}/proxy"))
            for sink in sinks:  # a stream per sink: each is flushed (and fails) on its own
                recording = rr.RecordingStream(self.application_id, recording_id=recording_id)
                recording.set_log_time_enabled(False)  # the run's wall clock: not the log's time
                recording.set_sinks(sink)
                recordings.append(recording)
        except BaseException:
            self._discard()
            raise
        recording = recordings[0]
        self._viewer = recordings[1] if len(recordings) > 1 else None
        self._recording = recording
        return self

    def _open_recording_file(self, rrd_path: Path) -> Path:
        """Create the partial beside ``rrd_path``; return the file Rerun is to write.

        Raises:
            LogWriteError: the folder is missing or cannot be written (before any frame).
        """
        if not rrd_path.parent.is_dir():
            raise LogWriteError(f"cannot write {rrd_path}: folder {rrd_path.parent} does not exist")
        remove_stale_partials(rrd_path)  # a killed earlier run's (never a live one's)
        try:
            # unique: two runs writing one --rrd never share (nor remove) each other's
            handle, name = tempfile.mkstemp(prefix=partial_prefix(rrd_path), dir=rrd_path.parent)
            os.close(handle)
            self._partial = Path(name)
            track_partial(self._partial)  # removed even if a signal forces the end
            os.chmod(self._partial, 0o666 & ~process_umask())  # mkstemp's 0600: as a new file's
            if hasattr(os, "mkfifo"):
                self._pump = _Pump(self._partial, rrd_path)
                return self._pump.pipe
            self._partial.open("wb").close()  # Rerun writes it: only whether it can be
            return self._partial
        except OSError as err:
            raise LogWriteError(
                f"cannot write {rrd_path}: {err.strerror or err}; {write_advice(err)}"
            ) from err

    def _discard(self) -> None:
        """Remove the partial recording and the pipe's folder (an error or a signal)."""
        if self._pump is not None:
            self._pump.remove_folder()
        if self._partial is not None:
            with contextlib.suppress(OSError):
                self._partial.unlink(missing_ok=True)
            untrack_partial(self._partial)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        recording, viewer = self._recording, self._viewer
        self._recording = self._viewer = None
        if recording is None:
            return
        if self.rrd_path is None:  # the viewer's stream alone
            recording, viewer = None, recording
        interrupted = signalled() or (
            exc_type is not None and issubclass(exc_type, KeyboardInterrupt)
        )
        # the recording's failure never costs the job's other outputs: it is a warning
        closing = (
            None if viewer is None else _Closer(viewer, None if interrupted else VIEWER_FLUSH_S)
        )
        failed: str | None = None
        defer = self._defer_viewer_wait and exc_type is None and not interrupted
        try:
            if recording is not None:  # the file: never waits on the viewer
                failed = _Closer(recording, None if interrupted else FILE_FLUSH_S).wait()
            if self._pump is not None:
                self._pump.finish(CLOSE_AFTER_SIGNAL_S if interrupted else FILE_FLUSH_S)
                failed = failed or self._pump.error
            if defer:
                self._closing, closing = closing, None
            note = None if interrupted else self._waiting_line(False)
            viewer_failed = None if closing is None else closing.wait(note)
        except BaseException:  # a signal while Rerun finishes
            self._discard()
            raise
        if self._partial is not None and self.rrd_path is not None:
            if exc_type is None and failed is None and not signalled():  # never after a signal
                try:
                    self._partial.replace(self.rrd_path)
                except OSError as err:  # the recording is lost, never the other outputs
                    during = "the recording was being written"
                    gone = removed_meanwhile(self._partial, self.rrd_path.parent, during)
                    self._discard()
                    # the MCAP is committed after this: the warning makes no claim about it
                    reason = (
                        f"cannot write {self.rrd_path}: {gone}"
                        if gone
                        else f"cannot move the finished recording onto {self.rrd_path}: "
                        f"{err.strerror or err}"
                    )
                    print(f"warning: {reason}; no recording was written there", file=sys.stderr)
                else:
                    self.written = True
                    untrack_partial(self._partial)
            else:
                self._discard()
        if interrupted:
            return  # the command says it was stopped; the recording is simply not there
        if exc_type is None and (line := self.constant_stamps_line()) is not None:
            print(f"warning: {line}", file=sys.stderr)
        if self._pump is not None and self._pump.error is not None:
            print(f"warning: {self._pump.error}; no recording was written there", file=sys.stderr)
        elif failed is not None:
            print(
                f"warning: the recording {self.rrd_path} did not take the last frames ({failed}); "
                "nothing was written there",
                file=sys.stderr,
            )
        self._say_viewer_failed(viewer_failed)

    def wait_for_viewer(self) -> None:
        """Wait for the viewer to take the last frames, once the outputs are committed.

        The deferred end of :meth:`__exit__` (``defer_viewer_wait``): at most
        :data:`VIEWER_FLUSH_S`, saying so after :data:`VIEWER_NOTE_S`; a viewer that did not
        take them is warned of. After a signal the viewer is left at once. A Ctrl-C during
        the wait leaves the viewer and raises: what was written stays written.
        """
        closing, self._closing = self._closing, None
        if closing is None:
            return
        if signalled():  # the process is ending: no time for the viewer
            _leave_to_exit()
            return
        try:
            failed = closing.wait(self._waiting_line(True))
        except BaseException:
            _leave_to_exit()  # its thread may still be in Rerun's flush
            raise
        self._say_viewer_failed(failed)

    def _waiting_line(self, committed: bool) -> str:
        """The line said when the wait for the viewer lasts (``committed``: outputs written)."""
        done = (
            "; the outputs are written, Ctrl-C stops the wait and keeps them" if committed else ""
        )
        return (
            f"rerun: waiting up to {VIEWER_FLUSH_S:g} s for the viewer to take the last "
            f"frames{done}"
        )

    def _say_viewer_failed(self, failed: str | None) -> None:
        if failed is not None:
            kept = f"; {self.rrd_path} is complete" if self.written else ""
            print(
                f"warning: the Rerun viewer did not take the last frames ({failed}){kept}",
                file=sys.stderr,
            )

    def constant_stamps_line(self) -> str | None:
        """Say that the header stamps never advanced (None if they did, or one frame).

        A driver that leaves ``header.stamp`` at zero (or at one value) puts every frame at
        one instant of the ``stamp`` time line; ``message_log_time`` still tells them apart.
        """
        if self._stamps is None or self._stamps[0] < 2 or self._stamps[2]:
            return None
        frames, stamp_ns, _ = self._stamps
        return (
            f"the left images' header stamps do not advance ({frames} frames, all at "
            f"{stamp_ns} ns): on the recording's `{TIMELINE}` time line they are one instant; "
            f"choose the `{LOG_TIME_TIMELINE}` time line in the viewer"
        )

    def log(self, result: DensifiedFrame) -> None:
        """Log one densified frame at its left-image stamp and its log time."""
        import rerun as rr

        recording = self._recording
        if recording is None:
            raise RuntimeError("RerunSink.log called outside its with-block")
        frame = result.frame
        camera = frame.camera
        stamp = np.datetime64(frame.stamp_ns, "ns")
        if self._log_time_is_epoch is None:  # one type for the whole time line
            low, high = _EPOCH_SPAN_NS
            self._log_time_is_epoch = low <= frame.log_time_ns <= high
        frames, first, other = self._stamps or (0, frame.stamp_ns, False)
        self._stamps = (frames + 1, first, other or frame.stamp_ns != first)
        entities: list[tuple[str, Any]] = []
        key = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        if key != self._camera_logged:
            entities.append(
                (
                    "camera",
                    rr.Pinhole(
                        focal_length=[camera.fx, camera.fy],
                        principal_point=[camera.cx, camera.cy],
                        resolution=[camera.width, camera.height],
                    ),
                )
            )
            self._camera_logged = key
        entities.append(("camera/image", rr.Image(frame.left)))
        entities.append(
            (
                "camera/depth",
                rr.DepthImage(
                    result.depth, meter=1.0, colormap="turbo", depth_range=(0.0, DISPLAY_MAX_DEPTH)
                ),
            )
        )
        disparities = result.disparities
        if disparities.size:
            span = float(np.ptp(disparities)) or 1.0
            level = (disparities - disparities.min()) / span
            colors = np.stack(
                [255 * level, 64 * np.ones_like(level), 255 * (1 - level)], axis=1
            ).astype(np.uint8)
        else:
            colors = np.zeros((0, 3), dtype=np.uint8)
        entities.append(("camera/features", rr.Points2D(result.pixels, radii=2.0, colors=colors)))
        entities.append(
            (
                "depth_std",
                rr.DepthImage(
                    result.depth_std,
                    meter=1.0,
                    colormap="viridis",
                    depth_range=(0.0, DISPLAY_MAX_DEPTH_STD),
                ),
            )
        )
        for stream in (recording, self._viewer):  # the archetypes are built once for both
            if stream is None:
                continue
            stream.set_time(TIMELINE, timestamp=stamp)
            if self._log_time_is_epoch:
                log_time = np.datetime64(frame.log_time_ns, "ns")
                stream.set_time(LOG_TIME_TIMELINE, timestamp=log_time)
            else:
                log_time_d = np.timedelta64(frame.log_time_ns, "ns")
                stream.set_time(LOG_TIME_TIMELINE, duration=log_time_d)
            for entity, archetype in entities:
                stream.log(entity, archetype)


class _Closer:
    """Flush (unless ``flush_s`` is None) and disconnect a recording stream, in a thread.

    Rerun's flush and disconnect are native calls that can wait for seconds (a viewer that
    went away, a slow disk) or for ever (a viewer that accepted the connection and does not
    answer: Rerun's gRPC flush then ignores its timeout, "will keep waiting"). Made from the
    main thread, they would also hold off a second Ctrl-C's handler (Python runs it only
    between the main thread's bytecodes) until the signal watchdog killed the process; so
    they run in a daemon thread of their own, which :meth:`wait` joins in short,
    interruptible waits, for at most ``flush_s`` and a second more. A stream not closed by
    then is left to the process's end (Rerun's exit handler, which would flush it again,
    is then removed). Without a flush (after a signal) the wait is
    :data:`CLOSE_AFTER_SIGNAL_S`: nothing is kept then, and the process is ending.
    """

    def __init__(self, recording: rr.RecordingStream, flush_s: float | None) -> None:
        self.failed: list[str] = []
        self.flush_s = flush_s
        self._deadline = time.monotonic() + (
            CLOSE_AFTER_SIGNAL_S if flush_s is None else flush_s + 1.0
        )
        self._thread = threading.Thread(
            target=self._close, args=(recording,), name="rerun-close", daemon=True
        )
        self._thread.start()

    def _close(self, recording: rr.RecordingStream) -> None:
        if self.flush_s is not None:
            try:
                recording.flush(timeout_sec=self.flush_s)
            except RuntimeError as error:  # the viewer gone, or the file's bytes stuck
                text = str(error).splitlines()[0] if str(error) else type(error).__name__
                self.failed.append(text)
        recording.disconnect()

    def wait(self, note: str | None = None) -> str | None:
        """Wait for the close (at most until its deadline); return its failure, if any.

        ``note`` is printed (standard output) once the wait has lasted :data:`VIEWER_NOTE_S`.
        """
        started = time.monotonic()
        while self._thread.is_alive() and time.monotonic() < self._deadline:
            self._thread.join(0.1)
            if note is not None and self._thread.is_alive():
                if time.monotonic() - started >= VIEWER_NOTE_S:
                    print(note, flush=True)
                    note = None
        if self._thread.is_alive():
            _leave_to_exit()
            if self.flush_s is not None and not self.failed:
                return f"no answer in {self.flush_s:g} s"
        return self.failed[0] if self.failed else None


def _leave_to_exit() -> None:
    """Keep Rerun's exit handler from flushing a stream that did not close (it would hang)."""
    import rerun as rr

    rr.unregister_shutdown()
