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

import argparse
import resource
import time
import tracemalloc

from pcainterp_stream.synth import SynthConfig, World, generate


def _measure(
    scale: float, frames: int, memory_frames: int, seed: int
) -> tuple[float, float, float, float]:
    """Return (world setup s, frames/s wall, CPU s per frame, traced peak MB)."""
    start = time.perf_counter()
    World(seed)
    setup = time.perf_counter() - start
    iterator = generate(SynthConfig(seed=seed, frames=frames + 1, scale=scale))
    next(iterator)  # world creation and the first blocks
    wall = time.perf_counter()
    cpu = time.process_time()
    count = sum(1 for _ in iterator)
    wall = time.perf_counter() - wall
    cpu = time.process_time() - cpu
    iterator = generate(SynthConfig(seed=seed, frames=memory_frames + 1, scale=scale))
    next(iterator)
    tracemalloc.start()
    sum(1 for _ in iterator)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return setup, count / wall, cpu / count, peak / 1e6


def main() -> None:
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--memory-frames", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print("| scale | size | world setup (s) | frames/s (wall) | CPU s/frame | peak traced MB |")
    print("| --- | --- | --- | --- | --- | --- |")
    for scale in (1.0, 0.25):
        camera = SynthConfig(scale=scale).camera
        setup, rate, cpu, peak = _measure(scale, args.frames, args.memory_frames, args.seed)
        print(
            f"| {scale} | {camera.width}x{camera.height} | {setup:.2f} | {rate:.1f} | "
            f"{cpu:.3f} | {peak:.0f} |"
        )
    max_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess max RSS: {max_rss:.0f} MB")


if __name__ == "__main__":
    main()
