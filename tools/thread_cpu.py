"""Where a densify job's CPU goes: per thread over time, and per stage of the compute side.

Runs ``pcainterp densify LOG -o OUT`` (the command's own code, any extra arguments after
``--``) in this process and reports:

- **threads over time**: every ``--interval`` seconds the CPU each group of threads used
  (cores: 1.00 is one core busy), read from ``/proc/self/task`` (Linux), grouped by the
  Python thread names (main, stereo workers, densify, estimate pool, encoders, log
  writer): a core left idle, or one thread holding the others up, shows as a row whose
  total is below 2;
- **stages**: thread CPU ms per frame of the front end's stages (SGBM, GFTT, the lattice,
  the lookups, the odometry), of the densify thread (the fit check, the carried points)
  and of the estimate pool (the batches);
- with ``--profile N``: the densify thread's and estimate pool's N most expensive functions
  (one batch at a time while profiled; cProfile on thread CPU time, not wall time, so a
  loaded machine does not inflate them).

Timings on a loaded machine are CPU, not wall: they add up per frame whatever the load.

Example::

    python tools/thread_cpu.py kitti_odometry.mcap --profile 25
    python tools/thread_cpu.py drive.mcap --interval 0.5 -- --precision full
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import pstats
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import harness

from pcainterp_stream.cli import app
from pcainterp_stream.estimate import cells, estimator
from pcainterp_stream.frontend import fill, stereo
from pcainterp_stream.pipeline import processor

GROUPS = ("MainThread", "stereo", "densify", "estimate", "encode", "log-writer")
"""Thread-name prefixes reported as one column each; other threads go to "other"."""


class Sampler(harness.ThreadCpu):
    """The CPU seconds of each group of threads, sampled over time in a thread of its own."""

    def __init__(self, interval: float) -> None:
        super().__init__(interval)
        self.samples: list[tuple[float, dict[str, float]]] = []

    def _sample(self) -> None:
        super()._sample()
        cpu: dict[str, float] = defaultdict(float)
        for native_id, (user, system) in self.seconds.items():  # ended threads included
            if not self.own_thread(native_id):
                cpu[_group(self.names.get(native_id, "other"))] += user + system
        self.samples.append((time.perf_counter(), dict(cpu)))

    def table(self, start: float) -> str:
        """Return the Markdown table of cores used per group and interval."""
        groups = [*GROUPS, "other"]
        lines = [
            "| t (s) | " + " | ".join(groups) + " | total |",
            "| --- " * (len(groups) + 2) + "|",
        ]
        for (before, old), (now, new) in zip(self.samples, self.samples[1:], strict=False):
            span = max(now - before, 1e-9)
            used = [(new.get(g, 0.0) - old.get(g, 0.0)) / span for g in groups]
            cells = " | ".join(f"{value:.2f}" for value in used)
            lines.append(f"| {now - start:.1f} | {cells} | {sum(used):.2f} |")
        last = self.samples[-1][1] if self.samples else {}
        totals = ", ".join(f"{g} {last.get(g, 0.0):.2f}" for g in groups)
        lines += ["", f"CPU seconds by thread: {totals}"]
        return "\n".join(lines)


def _group(name: str) -> str:
    for prefix in GROUPS:
        if name.startswith(prefix):
            return prefix
    return "other"


class StageTimers:
    """Thread-CPU seconds and calls of wrapped functions, by label."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._lock = threading.Lock()

    def wrap(self, label: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """Return ``function`` timed under ``label``."""

        def timed(*args: Any, **kwargs: Any) -> Any:
            started = time.thread_time()
            try:
                return function(*args, **kwargs)
            finally:
                with self._lock:
                    self.cpu[label] += time.thread_time() - started
                    self.calls[label] += 1

        return timed


STAGES: list[tuple[Any, str, str]] = [
    (processor.FrameProcessor, "_measure", "stereo worker, all"),
    (stereo, "_sgbm_weak", "  SGBM (half resolution; dense mode: full)"),
    (stereo, "detect_corners", "  GFTT corners"),
    (fill, "lattice_points", "  lattice points"),
    (fill, "patch_contrast", "  lattice contrast"),
    (fill, "greedy_fill", "  greedy fill (its lookups and contrast too)"),
    (stereo, "_lookup", "  lookups"),
    (processor, "estimate_motion", "  odometry"),
    (cells.Seeding, "along", "  edge-aware seeding (map on the cell grid)"),
    (processor, "_prepare", "densify thread: set-up"),
    (processor.FrameProcessor, "_warm_up", "densify thread: fit check"),
    (processor.FrameProcessor, "_measurements", "densify thread: carried points"),
    (processor.FrameProcessor, "_estimate", "estimate pool: batches"),
    (processor, "densify_batch", "  of which densify_batch"),
    (estimator, "partition_all", "  of which the edge-aware label search"),
    (processor, "fuse_dense", "  of which dense fusion (dense mode)"),
]
"""(owner, attribute, label) of each function timed."""


@contextlib.contextmanager
def instrumented(timers: StageTimers, profile: cProfile.Profile | None) -> Iterator[None]:
    """Wrap the stages' timers (and the densify thread's profiler) around the job."""
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in STAGES]
    batch = processor.FrameProcessor._densify_batch
    estimate = processor.FrameProcessor._estimate
    one_at_a_time = threading.Lock()  # one profiler: the estimate pool runs one batch at once
    try:
        for owner, name, label in STAGES:
            setattr(owner, name, timers.wrap(label, getattr(owner, name)))
        if profile is not None:

            def profiled(function: Any) -> Any:
                def run(self: processor.FrameProcessor, *args: Any) -> Any:
                    with one_at_a_time:
                        profile.enable()
                        try:
                            return function(self, *args)
                        finally:
                            profile.disable()

                return run

            setattr(processor.FrameProcessor, "_densify_batch", profiled(batch))  # noqa: B010
            setattr(  # noqa: B010
                processor.FrameProcessor, "_estimate", profiled(processor.FrameProcessor._estimate)
            )
        yield
    finally:
        setattr(processor.FrameProcessor, "_densify_batch", batch)  # noqa: B010
        setattr(processor.FrameProcessor, "_estimate", estimate)  # noqa: B010
        for owner, name, original in saved:
            setattr(owner, name, original)


def split_arguments(argv: list[str]) -> tuple[list[str], list[str]]:
    """Split the command line at the first ``--``: (this tool's, densify's own arguments).

    argparse alone gives the positional ``log`` its (empty) share of ``extra`` first and
    then rejects every densify option after ``--`` as unknown.
    """
    if "--" not in argv:
        return list(argv), []
    cut = argv.index("--")
    return list(argv[:cut]), list(argv[cut + 1 :])


def main(argv: list[str] | None = None) -> int:
    """Run one densify job with the samplers; print the tables; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", type=Path, help="a stereo log (MCAP or ROS bag)")
    parser.add_argument("-o", "--output", type=Path, default=None, help="default: a temp file")
    parser.add_argument("--interval", type=float, default=0.25, help="seconds per row")
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="top N functions")
    parser.add_argument("extra", nargs="*", help="densify's own arguments (after --)")
    own, densify_args = split_arguments(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(own)
    args.extra = [*args.extra, *densify_args]
    if not args.log.exists():
        print(f"error: {args.log} does not exist", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as scratch:
        output = args.output or Path(scratch) / "out.mcap"
        timers = StageTimers()
        profile = cProfile.Profile(time.thread_time) if args.profile else None
        start = time.perf_counter()
        with instrumented(timers, profile), Sampler(args.interval) as sampler:
            status = app.main(["densify", str(args.log), "-o", str(output), *args.extra])
        wall = time.perf_counter() - start
    frames = max(timers.calls["stereo worker, all"], 1)
    print(f"\n{frames} frames, {wall:.2f} s (after this tool's imports)\n")
    print(sampler.table(start))
    print("\n| stage | CPU ms per frame | calls |\n| --- | --- | --- |")
    for _, _, label in STAGES:
        cpu = 1000 * timers.cpu[label] / frames
        print(f"| {label.strip()} | {cpu:.2f} | {timers.calls[label]} |")
    if profile is not None:
        text = io.StringIO()
        pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(args.profile)
        title = "The densify thread and estimate pool, by function (thread CPU s)"
        print(f"\n{title}:\n" + text.getvalue())
    return status


if __name__ == "__main__":
    sys.exit(main())
