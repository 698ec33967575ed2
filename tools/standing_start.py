"""A standing start on synthetic street logs: what ``pcainterp densify`` makes of it (truth).

Two logs of the synthetic street world (seed 7, half size, 10 Hz), rendered by the
package's renderer with fresh sensor noise in every frame:

- ``standing``: 30 frames of a camera that stands where the slow drive (0.01 m/s) starts,
  facing a facade;
- ``standing+drive``: 10 such frames, then frames 1-30 of the ordinary 10 m/s drive.

Each log is densified by ``pcainterp densify LOG -o OUT`` (run in this process, with no
flags and with each ``--basis`` variant below), and the output log is scored against the
renderer's depth (disparity = f*b / depth, every pixel with a surface): the RMSE and mean
|disparity error| (px) and the share of pixels within +-2 posterior std. Prints a Markdown
table, then the lines densify printed about its choice of basis::

    python tools/standing_start.py

The logs are rendered again on every run (~4 s each); the table is the same on every run of
the same code (~30 s on a loaded 2-core machine), and so is each densified output, byte
for byte.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from unittest import mock

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream import synth
from pcainterp_stream.evaluate.log_frames import read_frames
from pcainterp_stream.evaluate.metrics import calibration_sums
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.synth.log import write_synthetic_log

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

SEED = 7
"""The street world's seed: its slow drive's first pose faces a facade."""
SCALE = 0.5
"""Half-size images (620x188): a log renders in ~4 s."""
LOGS = {"standing": (30, 0), "standing+drive": (10, 30)}
"""Log name: (standing frames, driving frames after them)."""
VARIANTS = {
    "standing": [(), ("--basis", "builtin-street")],
    "standing+drive": [(), ("--basis", "builtin-indoor"), ("--basis", "builtin-street")],
}
"""The densify flags each log is run with (``()``: none, the default)."""

Pose = Callable[[synth.World, synth.SynthConfig, int], F64]


def standing_pose(stand_frames: int) -> Pose:
    """Return a pose function standing for ``stand_frames`` frames, then driving on.

    Frames before ``stand_frames`` take the first pose of the slow drive (0.01 m/s);
    frame ``stand_frames + k`` takes frame ``k + 1`` of the drive being rendered.
    """
    driving = synth.camera_pose
    slow = synth.SynthConfig(seed=SEED, frames=1, scale=SCALE, speed=0.01)

    def pose(world: synth.World, config: synth.SynthConfig, index: int) -> F64:
        if index < stand_frames:
            return driving(world, slow, 0)
        return driving(world, config, index - stand_frames + 1)

    return pose


def build_log(path: Path, stand_frames: int, drive_frames: int) -> None:
    """Render the standing (then driving) log and write it with its ground truth.

    ``generate`` takes its poses from ``synth.camera_pose`` and draws the sensor noise per
    frame in a fixed order, so replacing that one function for the render gives a camera
    that stands, with the renderer's own images, noise and depth.
    """
    config = synth.SynthConfig(seed=SEED, frames=stand_frames + drive_frames, scale=SCALE)
    with mock.patch.object(synth, "camera_pose", standing_pose(stand_frames)):
        write_synthetic_log(synth.generate(config), path)


def frames_of(densified: Path) -> Iterator[tuple[F32, F32, F64]]:
    """Yield (disparity, disparity std, true disparity) per frame of a densified log (px)."""
    for frame in read_frames(densified, OutputTopics(), None):
        assert frame.depth is not None, f"{densified} has no /ground_truth/depth"
        depth = frame.depth.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            surface = np.isfinite(depth) & (depth > 0)  # not the sky (+inf, too far)
            truth = np.where(surface, frame.camera.focal_baseline / depth, np.nan)
        yield frame.estimate, frame.std, truth


def score(densified: Path) -> list[str]:
    """Return the table cells of a densified log: frames, RMSE, mean |error|, +-2 sigma."""
    errors: list[F64] = []
    inside = with_std = 0.0
    for estimate, std, truth in frames_of(densified):
        counted = np.isfinite(truth) & np.isfinite(estimate)
        errors.append(estimate[counted] - truth[counted])
        sums = calibration_sums(estimate, std, truth, counted)  # pixels with a std
        inside, with_std = inside + sums["inside_2"], with_std + sums["n"]
    error = np.concatenate(errors)
    return [
        str(len(errors)),
        f"{np.sqrt(np.mean(np.square(error))):.2f}",
        f"{np.mean(np.abs(error)):.2f}",
        f"{100.0 * inside / with_std:.1f} %",
    ]


def densify(log: Path, out: Path, flags: tuple[str, ...]) -> tuple[list[str], list[str]]:
    """Run ``pcainterp densify LOG -o OUT FLAGS``; return its score cells and basis lines."""
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        harness.run_cli("densify", log, "-o", out, *flags)
    lines = [
        line for line in said.getvalue().splitlines() if line.startswith(("prior:", "adapted"))
    ]
    return score(out), lines


def main(argv: list[str] | None = None) -> int:
    """Render the logs, densify each one per variant, print the table and densify's lines."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument(
        "--work-dir", type=Path, default=None, help="keep the logs here (default: a temporary one)"
    )
    args = parser.parse_args(argv)
    notes: list[str] = []
    with tempfile.TemporaryDirectory() as temporary:
        work = harness.work_dir(args.work_dir or Path(temporary))
        print(harness.table_header(["log", "densify", "frames", "RMSE px", "mean px", "+-2 sigma"]))
        for name, (stand, drive) in LOGS.items():
            log = work / f"{name}.mcap"
            build_log(log, stand, drive)
            for number, flags in enumerate(VARIANTS[name]):
                cells, lines = densify(log, work / f"{name}_{number}.mcap", flags)
                label = " ".join(flags) or "(no flags)"
                print(harness.table_row([name, label, *cells]), flush=True)
                notes += [f"{name}, {label}:", *(f"  {line}" for line in lines)]
    print("\n" + "\n".join(notes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
