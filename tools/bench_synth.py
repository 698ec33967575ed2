"""Benchmark the synthetic renderer: frames/s and peak memory at KITTI and quarter size.

Usage:
    python tools/bench_synth.py [--frames N] [--memory-frames M] [--seed S]

Prints a Markdown table (one row per scale). World creation (texture tiles, once per drive)
is timed separately from the per-frame rate; a frame is left + right image + left depth.
The rate is measured without tracemalloc (its allocation hooks take the GIL and serialise
the left and right render threads); the traced peak comes from a separate run of
``--memory-frames`` frames.
"""

from __future__ import annotations

import resource

import harness

from pcainterp_stream.synth import SynthConfig, World, generate

COLUMNS = ("scale", "size", "world setup (s)", "frames/s (wall)", "CPU s/frame", "peak traced MB")


def _measure(
    scale: float, frames: int, memory_frames: int, seed: int
) -> tuple[float, float, float, float]:
    """Return (world setup s, frames/s wall, CPU s per frame, traced peak MB)."""
    with harness.Stopwatch() as setup:
        World(seed)
    iterator = generate(SynthConfig(seed=seed, frames=frames + 1, scale=scale))
    next(iterator)  # world creation and the first blocks
    with harness.Stopwatch() as rendering:
        count = sum(1 for _ in iterator)
    iterator = generate(SynthConfig(seed=seed, frames=memory_frames + 1, scale=scale))
    next(iterator)
    peak = harness.traced_peak_mb(lambda: sum(1 for _ in iterator))
    return setup.wall, count / rendering.wall, rendering.cpu / count, peak


def main() -> None:
    """Run the benchmark and print the table."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--memory-frames", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(harness.table_header(COLUMNS))
    for scale in (1.0, 0.25):
        camera = SynthConfig(scale=scale).camera
        setup, rate, cpu, peak = _measure(scale, args.frames, args.memory_frames, args.seed)
        cells = [f"{camera.width}x{camera.height}", f"{setup:.2f}", f"{rate:.1f}", f"{cpu:.3f}"]
        print(harness.table_row([scale, *cells, f"{peak:.0f}"]))
    max_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess max RSS: {max_rss:.0f} MB")


if __name__ == "__main__":
    main()
