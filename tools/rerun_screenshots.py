"""Take the Rerun screenshots of docs/viewing.md from a real headless Rerun viewer.

Usage::

    python tools/rerun_screenshots.py                  # writes docs/img/viewing_rerun_*.png
    python tools/rerun_screenshots.py --work-dir /tmp/shots --out docs/img

Steps:

1. Build a small synthetic case in ``--work-dir`` with the project's own commands
   (``pcainterp synth`` 40 training and 4 test frames at half KITTI size, ``learn`` 30
   components from the true depth, ``densify --depth-mm --rrd``; about 25 s on 2 cores).
2. Open the ``.rrd`` recording in ``rerun --headless`` with a blueprint (``.rbl``) of four
   views, move the time cursor to the last frame and save the whole viewer through
   ``rerun.experimental.ViewerClient.take_screenshot`` (``viewing_rerun.png``).
3. Convert the densified ``.mcap`` with ``rerun mcap convert`` (Rerun's own MCAP importer,
   restricted to a few of our topics) and screenshot that the same way: what Rerun makes of
   the ROS 2 messages alone (``viewing_rerun_mcap.png``).

The headless viewer renders with wgpu and needs a Vulkan driver: a GPU's, or Mesa's CPU
renderer lavapipe (Debian package ``mesa-vulkan-drivers``). Without one it stops with
"Failed to get render context" and this script exits 1.

The depth of a PCA map runs to millions of metres where the estimated disparity nears 0,
so the views pin the colour maps with blueprint overrides (``depth_range``); the
recording itself is not changed.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import IO

import harness
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.experimental import ViewerClient

APPLICATION_ID = "pcainterp"
MCAP_APPLICATION_ID = "pcainterp_mcap"
TIMELINE = "stamp"
MCAP_TIMELINE = "ros2_timestamp"
WINDOW_SIZE = "1600x900"
SCREENSHOT_MAX_SIZE = 1280  # px, longest side of the PNGs
DEPTH_RANGE_M = (0.0, 60.0)
DEPTH_STD_RANGE_M = (0.0, 5.0)
MCAP_TOPICS = r"^/(pcainterp/(depth|features|camera_info)|stereo/left/image_rect)$"
START_TIMEOUT_S = 60.0


def build_case(folder: Path) -> tuple[Path, Path]:
    """Densify a small synthetic drive; return (the densified .mcap, its .rrd recording)."""
    train, test = folder / "train.mcap", folder / "test.mcap"
    basis, dense, rrd = folder / "basis.npz", folder / "dense.mcap", folder / "dense.rrd"
    commands: list[list[str]] = [
        ["synth", str(train), "--frames", "40", "--scale", "0.5", "--seed", "1"],
        ["synth", str(test), "--frames", "4", "--scale", "0.5", "--seed", "2"],
        [
            "learn",
            str(train),
            "-o",
            str(basis),
            "--components",
            "30",
            "--depth-topic",
            "/ground_truth/depth",
        ],
        [
            "densify",
            str(test),
            "-o",
            str(dense),
            "--basis",
            str(basis),
            "--depth-mm",
            "--rrd",
            str(rrd),
        ],
    ]
    for command in commands:
        harness.run_cli(*command)
    return dense, rrd


def _eye_controls() -> rrb.EyeControls3D:
    """The 3-D views' camera: behind, left of and above the car, looking ahead."""
    return rrb.EyeControls3D(
        position=(-25.0, -15.0, -12.0), look_target=(0.0, 0.0, 20.0), eye_up=(0, -1, 0)
    )


def recording_blueprint() -> rrb.Blueprint:
    """Four views of a ``pcainterp densify --rrd`` recording (see rerun_sink.py's layout)."""
    depth = rr.DepthImage.from_fields(depth_range=DEPTH_RANGE_M)
    return rrb.Blueprint(
        rrb.Grid(
            rrb.Spatial2DView(
                name="left image + features",
                origin="/camera",
                contents=["/camera/image", "/camera/features"],
            ),
            rrb.Spatial2DView(
                name="dense depth (m)",
                origin="/camera",
                contents=["/camera/depth", "/camera/features"],
                overrides={"/camera/depth": depth},
            ),
            rrb.Spatial2DView(
                name="depth std (m)",
                origin="/depth_std",
                overrides={"/depth_std": rr.DepthImage.from_fields(depth_range=DEPTH_STD_RANGE_M)},
            ),
            rrb.Spatial3DView(
                name="3-D",
                origin="/",
                contents=["/camera/**", "- /camera/image"],
                overrides={"/camera/depth": depth},
                eye_controls=_eye_controls(),
            ),
        ),
        collapse_panels=True,
    )


def mcap_blueprint() -> rrb.Blueprint:
    """Views of the densified .mcap as Rerun's MCAP importer reads it."""
    depth = rr.DepthImage.from_fields(depth_range=DEPTH_RANGE_M)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="/stereo/left/image_rect", origin="/stereo/left/image_rect"),
                rrb.Spatial2DView(
                    name="/pcainterp/depth",
                    origin="/pcainterp/depth",
                    overrides={"/pcainterp/depth": depth},
                ),
            ),
            rrb.Spatial3DView(
                name="/pcainterp/features, camera_info, depth",
                origin="/",
                contents=["/pcainterp/**"],
                overrides={"/pcainterp/depth": depth},
                eye_controls=_eye_controls(),
            ),
        ),
        collapse_panels=True,
    )


def free_port() -> int:
    """Return a TCP port that was free a moment ago (the viewer binds it)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def screenshot_viewer(paths: list[Path], timeline: str, out: Path, stem: str, log: IO[str]) -> Path:
    """Open ``paths`` in a headless viewer, go to the last frame, save the screenshots.

    Returns:
        The PNG written, ``out/{stem}.png`` (the whole viewer).
    """
    port = free_port()
    command = [shutil.which("rerun") or "rerun", *map(str, paths), "--headless"]
    command += ["--port", str(port), "--bind", "127.0.0.1", "--window-size", WINDOW_SIZE]
    command += ["--hide-welcome-screen"]
    # `rerun` is a Python wrapper that runs the viewer binary as its child: start both in a
    # session of their own and signal that process group, or the viewer outlives the wrapper
    viewer_process = subprocess.Popen(command, stdout=log, stderr=log, start_new_session=True)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if viewer_process.poll() is not None:
                raise RuntimeError(f"rerun exited with {viewer_process.returncode}; see {log.name}")
            try:
                viewer = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                state = viewer.get_state()
                if state.recordings and state.views and not state.loading:
                    break
            except ConnectionError:
                pass  # the viewer is still starting
            if time.monotonic() > deadline:
                raise RuntimeError(f"no recording in the viewer after {START_TIMEOUT_S} s")
            time.sleep(0.5)
        recording = state.recordings[0]
        end = next(line.end for line in recording.timelines if line.name == timeline)
        viewer.set_time(timeline, timestamp=np.datetime64(end, "ns"), play_state="paused")
        time.sleep(12.0)  # let the notifications fade and the software renderer settle
        for view in viewer.get_state().views:
            for report in view.reports:
                print(f"  view {view.name!r}: {report.severity}: {report.summary}")
        path = out / f"{stem}.png"
        path.write_bytes(viewer.take_screenshot(max_size=SCREENSHOT_MAX_SIZE))
    finally:
        stop_process_group(viewer_process)
    return path


def stop_process_group(process: subprocess.Popen[bytes]) -> None:
    """Terminate the process group led by ``process``, kill it after 10 s, reap the leader."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        process.poll()  # reap the leader, or its zombie keeps the group alive
        try:
            os.killpg(process.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
    process.wait()


def main(argv: list[str] | None = None) -> int:
    """Build the case, take the screenshots, print what was written."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/pcainterp_screenshots"))
    parser.add_argument("--out", type=Path, default=harness.REPO / "docs" / "img")
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    out = harness.work_dir(args.out)
    if shutil.which("rerun") is None:
        print("rerun_screenshots: the rerun CLI (rerun-sdk) is not on PATH", file=sys.stderr)
        return 1

    dense, rrd = build_case(work)
    layout = work / "layout.rbl"
    recording_blueprint().save(APPLICATION_ID, layout)

    converted = work / "dense_from_mcap.rrd"
    mcap_layout = work / "mcap_layout.rbl"
    convert = ["rerun", "mcap", "convert", str(dense), "-o", str(converted)]
    convert += ["--application-id", MCAP_APPLICATION_ID, "-y", MCAP_TOPICS]
    subprocess.run(convert, check=True, capture_output=True)
    mcap_blueprint().save(MCAP_APPLICATION_ID, mcap_layout)

    written: list[Path] = []
    with (work / "viewer.log").open("w") as log:
        try:
            written.append(screenshot_viewer([rrd, layout], TIMELINE, out, "viewing_rerun", log))
            written.append(
                screenshot_viewer(
                    [converted, mcap_layout], MCAP_TIMELINE, out, "viewing_rerun_mcap", log
                )
            )
        except RuntimeError as err:
            print(f"rerun_screenshots: {err}", file=sys.stderr)
            return 1
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
