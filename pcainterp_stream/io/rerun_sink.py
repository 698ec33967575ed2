"""Rerun sink: log densified frames to a viewer or an ``.rrd`` recording.

Entity layout (one time line, ``stamp``, the left image's header stamp):

- ``camera``: the left camera's ``Pinhole`` (image plane, focal length, principal point);
- ``camera/image``: the left image;
- ``camera/features``: the sparse measurements, coloured by disparity;
- ``camera/depth``: the dense depth (``DepthImage``, metres, turbo colour map over the fixed
  range 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH`; ``+inf`` = too far);
- ``depth_std``: the posterior depth std (m) as a second depth image, so it gets its own view
  (viridis, 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH_STD`).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from pcainterp_stream.defaults import DISPLAY_MAX_DEPTH, DISPLAY_MAX_DEPTH_STD
from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.interrupt import signalled, track_partial, untrack_partial
from pcainterp_stream.records import DensifiedFrame

if TYPE_CHECKING:
    import rerun as rr

TIMELINE = "stamp"

VIEWER_FLUSH_S = 10.0
"""How long the end of a job waits for a spawned viewer to take the last frames."""

FILE_FLUSH_S = 300.0
"""How long it waits for the recording's last bytes to reach its file."""

PUMP_CHUNK = 1 << 20
"""Bytes the recording's pump moves from Rerun's pipe to the file at a time."""


NO_DISPLAY = (
    "--rerun starts a Rerun viewer, which needs a display (neither DISPLAY nor "
    "WAYLAND_DISPLAY is set)"
)
"""The start of the error for a viewer on a machine without one; the caller adds the fix."""


def has_display() -> bool:
    """Whether a spawned viewer can open a window: not on Linux without X11 or Wayland."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class _Pump:
    """Move the bytes Rerun's file sink writes into a pipe on to the recording's file.

    Rerun's own file sink never returns from its shutdown once a write has failed (a full
    disk), so it is given a named pipe and this thread writes the file: a failed write is
    remembered, the partial file removed, and the pipe drained to its end, so Rerun always
    finishes. Where there are no named pipes (Windows) Rerun writes the file itself.
    """

    def __init__(self, target: Path, name: Path) -> None:
        self.target = target
        self.name = name  # the file the user named (``target`` is its partial)
        self.error: str | None = None
        self._folder = Path(tempfile.mkdtemp(prefix="pcainterp-rrd-"))
        self.pipe = self._folder / "recording.rrd"
        os.mkfifo(self.pipe)
        self._thread = threading.Thread(target=self._run, name="rrd-pump", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            with self.pipe.open("rb") as source:
                out = None
                try:
                    out = self._open_target()
                except OSError as error:
                    self._fail(error)
                while chunk := source.read(PUMP_CHUNK):
                    if out is None:
                        continue  # given up: drained, so that Rerun can finish
                    try:
                        out.write(chunk)
                    except OSError as error:
                        self._fail(error)
                        self._close(out)
                        out = None
                if out is not None:
                    self._close(out)
        except OSError as error:  # the pipe itself
            self._fail(error)

    def _open_target(self) -> BinaryIO:
        return self.target.open("wb")

    def _close(self, out: BinaryIO) -> None:
        try:
            out.close()
        except OSError as error:  # the last buffered bytes
            self._fail(error)
        if self.error is not None:
            self.target.unlink(missing_ok=True)

    def _fail(self, error: OSError) -> None:
        if self.error is None:
            self.error = f"cannot write {self.name}: {error.strerror or error}"
        self.target.unlink(missing_ok=True)  # free what it took of the disk at once

    def finish(self, timeout: float) -> None:
        """Wait for the pipe's end (Rerun closed it), then remove the pipe."""
        if self._thread.is_alive():
            try:  # Rerun never opened it: a writer that closes at once ends the read
                os.close(os.open(self.pipe, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass  # opened and being written: the read ends when Rerun closes it
        self._thread.join(timeout)
        if self._thread.is_alive() and self.error is None:
            self.error = f"cannot write {self.name}: its bytes did not arrive in {timeout:g} s"
        shutil.rmtree(self._folder, ignore_errors=True)


class RerunSink:
    """Log :class:`DensifiedFrame` records to Rerun, as a context manager.

    Args:
        rrd_path: write a recording to this file (written to a temporary beside it and
            renamed when the sink closes without error).
        spawn: start a viewer and stream to it.
        application_id: Rerun application id.
    """

    def __init__(
        self,
        *,
        rrd_path: str | Path | None = None,
        spawn: bool = False,
        application_id: str = "pcainterp",
    ) -> None:
        if rrd_path is None and not spawn:
            raise ValueError("RerunSink needs rrd_path or spawn=True")
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        self.spawn = spawn
        self.application_id = application_id
        self._partial: Path | None = None
        self._pump: _Pump | None = None
        self.written = False
        """Whether the recording file was written whole (set when the sink closes)."""
        self._recording: rr.RecordingStream | None = None
        self._camera_logged: tuple[int, int, float, float, float, float] | None = None

    def __enter__(self) -> RerunSink:
        import rerun as rr  # imported when used: ~0.3 s of every densify start-up otherwise

        if self.spawn and not has_display():
            raise LogWriteError(
                f"{NO_DISPLAY}; record with --rrd FILE instead and open it with `rerun FILE` "
                "where there is one"
            )
        recording = rr.RecordingStream(self.application_id)
        if self.rrd_path is not None:
            if not self.rrd_path.parent.is_dir():
                raise LogWriteError(
                    f"cannot write {self.rrd_path}: folder {self.rrd_path.parent} does not exist"
                )
            self._partial = self.rrd_path.with_name(f".{self.rrd_path.name}.partial")
            track_partial(self._partial)  # removed even if a signal forces the end
            if hasattr(os, "mkfifo"):
                self._pump = _Pump(self._partial, self.rrd_path)
                recording.save(self._pump.pipe)
            else:
                recording.save(self._partial)
        if self.spawn:
            recording.spawn(connect=self.rrd_path is None)
        self._recording = recording
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        recording = self._recording
        self._recording = None
        if recording is None:
            return
        # the recording's failure never costs the job's other outputs: it is a warning
        failed = None
        try:
            recording.flush(timeout_sec=FILE_FLUSH_S if self.rrd_path else VIEWER_FLUSH_S)
        except RuntimeError as error:  # the viewer gone, or the file's bytes stuck
            failed = str(error).splitlines()[0] if str(error) else type(error).__name__
        recording.disconnect()
        if self._pump is not None:
            self._pump.finish(FILE_FLUSH_S)
            failed = failed or self._pump.error
        if self._partial is not None and self.rrd_path is not None:
            if exc_type is None and failed is None and not signalled():  # never after a signal
                self._partial.replace(self.rrd_path)
                self.written = True
            else:
                self._partial.unlink(missing_ok=True)
            untrack_partial(self._partial)
        if self._pump is not None and self._pump.error is not None:
            print(
                f"warning: {self._pump.error}; no recording was written there, the other "
                "outputs are whole",
                file=sys.stderr,
            )
        elif failed is not None:
            target = f"the recording {self.rrd_path}" if self.rrd_path else "the Rerun viewer"
            print(
                f"warning: {target} did not take the last frames ({failed}); "
                + ("nothing was written there" if self.rrd_path else "the other outputs are whole"),
                file=sys.stderr,
            )

    def log(self, result: DensifiedFrame) -> None:
        """Log one densified frame at its left-image stamp."""
        import rerun as rr

        recording = self._recording
        if recording is None:
            raise RuntimeError("RerunSink.log called outside its with-block")
        frame = result.frame
        camera = frame.camera
        recording.set_time(TIMELINE, timestamp=np.datetime64(frame.stamp_ns, "ns"))
        key = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        if key != self._camera_logged:
            recording.log(
                "camera",
                rr.Pinhole(
                    focal_length=[camera.fx, camera.fy],
                    principal_point=[camera.cx, camera.cy],
                    resolution=[camera.width, camera.height],
                ),
            )
            self._camera_logged = key
        recording.log("camera/image", rr.Image(frame.left))
        recording.log(
            "camera/depth",
            rr.DepthImage(
                result.depth, meter=1.0, colormap="turbo", depth_range=(0.0, DISPLAY_MAX_DEPTH)
            ),
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
        recording.log("camera/features", rr.Points2D(result.pixels, radii=2.0, colors=colors))
        recording.log(
            "depth_std",
            rr.DepthImage(
                result.depth_std,
                meter=1.0,
                colormap="viridis",
                depth_range=(0.0, DISPLAY_MAX_DEPTH_STD),
            ),
        )
