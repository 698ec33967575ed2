"""The frames after a log's own basis stops fitting, against the synthetic truth.

Renders synthetic logs whose fit check adopts the log's own basis and whose scene then
changes (the package's renderer, 310x94 px, 10 Hz): a room, then another room of the same
camera (``room2+room0``: 16 frames of room seed 2, then 16 of room seed 0); one room walked
for 48 frames (``room3x48``); a room, then the street (``room3+street7``: 12 frames, then
12). Each is densified as ``pcainterp densify`` does (the frame processor, default options)
and scored against the renderer's depth on the 8 frames after the frame where the own
basis stopped fitting (those densified while the choice is made again, docs/bases.md "The
log's own basis stops fitting"), right of SGBM's unmatched band: the mean |disparity error|
(px), the median |depth error| / depth, and the share of pixels within +-2 posterior std.
Prints a Markdown table::

    python tools/refit_truth.py [--logs room2+room0 room3+street7 ...]

Run it with ``PYTHONPATH`` at another tree to compare (the script uses only the frame
processor and the renderer). The table is the same on every run of the same code.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from pcainterp_stream.estimate.basis import builtin_kind
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoFrame
from pcainterp_stream.synth import SynthConfig, generate

FIRST_ROOMS = (2, 3, 9, 10, 11, 13)
"""Room seeds whose 8-frame warm-up check adopts the log's own basis (310x94 px, scale 0.25)."""
SECOND_ROOMS = (0, 4, 5, 6)
"""Room seeds walked after them."""
STEP_NS = 100_000_000


def _logs() -> dict[str, list[SynthConfig]]:
    def room(seed: int, frames: int) -> SynthConfig:
        return SynthConfig(seed=seed, frames=frames, scale=0.25, scene="indoor")

    logs = {
        f"room{first}+room{second}": [room(first, 16), room(second, 16)]
        for first in FIRST_ROOMS
        for second in SECOND_ROOMS
    }
    logs.update({f"room{seed}x48": [room(seed, 48)] for seed in FIRST_ROOMS})
    logs["room3+street7"] = [room(3, 12), SynthConfig(seed=7, frames=12, scale=0.25)]
    return logs


def score(configs: list[SynthConfig]) -> tuple[str, str]:
    """Return the table cells of one log: where its own basis stopped, and the figures."""
    frames: list[StereoFrame] = []
    depths: list[tuple[float, np.ndarray]] = []
    for config in configs:
        for rendered in generate(config):
            index = len(frames)
            stamp = (index + 1) * STEP_NS
            frames.append(
                StereoFrame(
                    index, stamp, stamp, "left", rendered.left, rendered.right, rendered.camera
                )
            )
            depths.append((rendered.camera.focal_baseline, rendered.depth))
    processor = ProcessorConfig()
    margin = processor.sgbm.valid_min_x
    figures = []
    with FrameProcessor(None, processor) as engine:
        for result in engine.process(frames):
            focal_baseline, depth = depths[result.frame.index]
            error = np.abs(result.disparity - focal_baseline / depth)[:, margin:]
            relative = (np.abs(result.depth - depth) / depth)[:, margin:]
            within = (error <= 2 * result.disparity_std[:, margin:])[np.isfinite(error)]
            figures.append(
                (
                    float(np.nanmean(error)),
                    float(np.nanmedian(relative)),
                    float(np.mean(within)),
                )
            )
        lines, in_force = engine.adaptation.lines, engine.adaptation.in_force
    stop = next((line for line in lines if "stopped fitting at frame" in line), None)
    if stop is None:
        return "no stop", ""
    at = int(stop.split("stopped fitting at frame ")[1].split(":")[0])
    after = figures[at + 1 : at + 9]
    if not after:
        return f"frame {at}, the last", ""
    used = [s for s in in_force if s.frame.index <= at + 1][-1]
    kind = builtin_kind(used.basis) or "own"
    tuned = " (tuned)" if used.tuning else ""
    mean, median, covered = (float(np.mean(values)) for values in zip(*after, strict=True))
    return (
        f"frame {at}: {kind}{tuned} on {at + 1}-{at + len(after)}",
        f"{mean:.3f} px, {100 * median:.1f} %, {100 * covered:.1f} %",
    )


def main(argv: list[str] | None = None) -> int:
    """Print the table of the logs chosen (all by default)."""
    logs = _logs()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", nargs="+", choices=sorted(logs), help="default: all of them")
    args = parser.parse_args(argv)
    print(
        "| log | own basis stopped at; basis on the next 8 frames | mean abs disparity "
        "error, median depth error, +-2 std |"
    )
    print("|---|---|---|")
    for name in args.logs or list(logs):
        where, figures = score(logs[name])
        print(f"| {name} | {where} | {figures} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
