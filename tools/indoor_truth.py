"""Synthetic indoor logs against their truth: the default, the built-in bases, linear, nearest.

For each seed, renders an indoor log (``SynthConfig(scene="indoor")``: a room, corridor or
hall by the seed), densifies it with the frame processor by default (``adapt="auto"``),
with the built-in bases as they are (``adapt="check"``: the street or the indoor one,
whichever the check picks), with each built-in basis forced, and with only the log's own
basis as the alternative (``--own-only``: the default before the indoor basis existed), and
scores them and linear and nearest-neighbour interpolation of the same points against the
true disparity, right of the stereo matcher's left margin (where no method has a
measurement). Prints a Markdown table and which basis the default used per seed::

    python tools/indoor_truth.py --seeds 0 1 2 3 4 5 --frames 12 --scale 0.5 --camera 752x480
"""

from __future__ import annotations

import sys

import harness
import numpy as np

VARIANTS = {
    "default": {"adapt": "auto"},
    "own-only": {"adapt": "auto", "builtin": "street"},
    "builtin": {"adapt": "check"},
    "street": {"adapt": "check", "builtin": "street"},
    "indoor": {"adapt": "check", "builtin": "indoor"},
}
"""The densify variants scored: ProcessorConfig fields (``own-only``: the street basis or
the log's own, never the indoor one, as densify chose before there was an indoor basis)."""


def score(seed: int, frames: int, scale: float, camera: str) -> tuple[dict[str, float], str]:
    """Return the mean |d - truth| (px) of each method over the frames of one log.

    Also returns the default's basis choice (its summary line).
    """
    from pcainterp_stream.estimate import baselines
    from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
    from pcainterp_stream.records import StereoFrame
    from pcainterp_stream.synth import SynthConfig, generate
    from pcainterp_stream.synth.indoor import camera_options

    config = SynthConfig(
        seed=seed, frames=frames, scale=scale, scene="indoor", **camera_options(camera)
    )
    synth = list(generate(config))
    stereo = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in synth
    ]
    errors: dict[str, list[float]] = {}
    chosen = ""
    for name, fields in VARIANTS.items():
        processor = ProcessorConfig(**fields)  # type: ignore[arg-type]
        margin = processor.sgbm.valid_min_x
        with FrameProcessor(None, processor) as engine:
            for result, truth_frame in zip(engine.process(stereo), synth, strict=True):
                size = truth_frame.camera.image_size
                truth = truth_frame.camera.focal_baseline / truth_frame.depth
                estimates = {name: result.disparity}
                if name == "default":
                    pixels, values = result.pixels, result.disparities
                    estimates["linear"] = baselines.linear(
                        pixels, values, image_size=size, zero_is_match=True
                    ).disparity
                    estimates["nearest"] = baselines.nearest(
                        pixels, values, image_size=size, zero_is_match=True
                    ).disparity
                for method, estimate in estimates.items():
                    error = float(np.abs(estimate - truth)[:, margin:].mean())
                    errors.setdefault(method, []).append(error)
            if name == "default":
                lines = engine.adaptation.lines
                chosen = next((line for line in lines if " chosen" in line), "")
                chosen = chosen or next((line for line in lines if "adapted:" in line), "kept")
    return {method: float(np.mean(values)) for method, values in errors.items()}, chosen


def main(argv: list[str] | None = None) -> int:
    """Score every seed and print the table with the mean row."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--camera", default="752x480")
    args = parser.parse_args(argv)
    methods = [*VARIANTS, "linear", "nearest"]
    print(harness.table_header(["seed", *methods]))
    rows, choices = [], []
    for seed in args.seeds:
        scores, chosen = score(seed, args.frames, args.scale, args.camera)
        rows.append([scores[method] for method in methods])
        choices.append(f"seed {seed}: {chosen[:100]}")
        print(harness.table_row([seed, *(f"{value:.3f}" for value in rows[-1])]), flush=True)
    means = np.mean(rows, axis=0)
    print(harness.table_row(["mean", *(f"{value:.3f}" for value in means)]))
    print("\n".join(choices))
    return 0


if __name__ == "__main__":
    sys.exit(main())
