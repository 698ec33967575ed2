"""Long-log benchmark: ``pcainterp densify`` on a 1,000-frame full-size log (memory, speed).

Checks the two long-log promises of ``densify``: memory does not grow with the length of
the log, and the frame rate does not fall over time. Each run is the real command line
(``pcainterp densify LOG -o OUT --basis BASIS``, parsed by ``cli.main``) in a fresh Python
process; the product code is not changed. The child process only wraps ``densify`` to
pass an ``on_frame`` callback that records when each frame was written (CLOCK_MONOTONIC),
and reports its peak RSS (``VmHWM`` of ``/proc/self/status``) at the end. Meanwhile this
process samples the child's ``VmRSS``, its CPU time and the 1-minute load average twice a
second: on a shared machine CPU ms per frame is the steadier measure of "no slowdown".

Logs (``pcainterp synth --scale 1``, 1241x376, seed 1) and the basis (``pcainterp learn``
on a separate seed-2 log, l = 200, prior fitted as ``learn`` does by default) are cached
in ``--work-dir``; densified outputs are deleted after each run (a 1,000-frame output is
~7 GB).

Example::

    python tools/bench_longlog.py --work-dir /tmp/pcll --frames 100 1000 --segment 100
"""

from __future__ import annotations

import argparse
import functools
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import harness

SAMPLE_SECONDS = 0.5
"""How often this process samples the child's RSS and the load average."""
SUMMARY_COLUMNS = (
    "log frames",
    "s",
    "frames/s",
    "CPU ms/frame",
    "peak RSS MB (VmHWM)",
    "output MB",
    "load avg 1 min",
)
SEGMENT_COLUMNS = (
    "frames",
    "s",
    "frames/s",
    "CPU ms/frame",
    "max RSS MB (sampled)",
    "load avg 1 min at end",
)


@dataclass
class Sample:
    """One sample of the child taken by this process.

    Attributes:
        monotonic_s: CLOCK_MONOTONIC time (s), the clock of the child's frame times.
        rss_mb: the child's resident set size (MB).
        load_1min: the machine's 1-minute load average.
        cpu_s: CPU time (user + system, s) the child has used so far.
    """

    monotonic_s: float
    rss_mb: float
    load_1min: float
    cpu_s: float


@dataclass
class Run:
    """One densify run.

    Attributes:
        frames: frames of the input log.
        exit_code: the command's exit code.
        started_s: CLOCK_MONOTONIC time (s) when the child entered ``cli.main``.
        frame_times_s: CLOCK_MONOTONIC time (s) at which each frame's outputs were written.
        ended_s: CLOCK_MONOTONIC time (s) when ``cli.main`` returned (output renamed).
        cpu_s: CPU time (user + system, all threads, s) of the child inside ``cli.main``.
        peak_rss_mb: the child's ``VmHWM`` (MB) at the end.
        output_mb: size of the densified log (MB).
        samples: RSS and load samples over the run.
        stdout: what the command printed.
    """

    frames: int
    exit_code: int
    started_s: float
    frame_times_s: list[float]
    ended_s: float
    cpu_s: float
    peak_rss_mb: float
    output_mb: float
    samples: list[Sample] = field(default_factory=list)
    stdout: str = ""


# ----------------------------------------------------------------------------- child


def _cpu_seconds(pid: int) -> float | None:
    """Return user + system CPU time (s) of process ``pid`` and its threads, None once gone."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            # fields after the parenthesised command name; utime and stime are 14 and 15
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def child(report: Path, argv: list[str]) -> int:
    """Run ``pcainterp ARGV`` here, recording when each densified frame was written.

    Writes a JSON report: entry and exit times, frame times (CLOCK_MONOTONIC, s), CPU time
    inside ``cli.main`` (s), exit code and ``VmHWM`` (kB).
    """
    from pcainterp_stream import cli
    from pcainterp_stream.pipeline import densify
    from pcainterp_stream.records import DensifiedFrame

    frame_times: list[float] = []

    def on_frame(result: DensifiedFrame) -> None:
        frame_times.append(time.monotonic())

    # cli.main imports ``densify`` from pipeline/densify.py when the command runs
    densify.densify = functools.partial(densify.densify, on_frame=on_frame)
    started, cpu_started = time.monotonic(), time.process_time()
    code = cli.main(argv)
    ended, cpu_ended = time.monotonic(), time.process_time()
    result = {
        "exit_code": code,
        "started_s": started,
        "ended_s": ended,
        "cpu_s": cpu_ended - cpu_started,
        "frame_times_s": frame_times,
        "peak_rss_kib": harness.proc_status_kib("VmHWM"),
    }
    harness.write_json(report, result, indent=None)
    return code


# ----------------------------------------------------------------------------- parent


def densify_run(log: Path, basis: Path, out: Path, frames: int, work_dir: Path) -> Run:
    """Run ``pcainterp densify`` on ``log`` in a child process and sample it."""
    report = work_dir / "child_report.json"
    report.unlink(missing_ok=True)
    stdout_path = work_dir / "child_stdout.txt"
    args = ["densify", str(log), "-o", str(out), "--basis", str(basis)]
    print("$ pcainterp " + " ".join(args), file=sys.stderr, flush=True)
    command = [sys.executable, os.path.abspath(__file__), "--child", str(report), "--", *args]
    samples: list[Sample] = []
    with stdout_path.open("w") as stdout:
        process = subprocess.Popen(command, stdout=stdout, stderr=subprocess.STDOUT)
        while process.poll() is None:
            rss = harness.proc_status_kib("VmRSS", process.pid)
            cpu = _cpu_seconds(process.pid)
            if rss is not None and cpu is not None:
                samples.append(Sample(time.monotonic(), rss / 1024.0, os.getloadavg()[0], cpu))
            time.sleep(SAMPLE_SECONDS)
    text = stdout_path.read_text()
    if process.returncode != 0 or not report.exists():
        raise RuntimeError(f"densify of {log} failed (exit {process.returncode}): {text[-2000:]}")
    result: dict[str, Any] = harness.read_json(report)
    return Run(
        frames=frames,
        exit_code=int(result["exit_code"]),
        started_s=float(result["started_s"]),
        frame_times_s=[float(t) for t in result["frame_times_s"]],
        ended_s=float(result["ended_s"]),
        cpu_s=float(result["cpu_s"]),
        peak_rss_mb=float(result["peak_rss_kib"]) / 1024.0,
        output_mb=out.stat().st_size / 1e6,
        samples=samples,
        stdout=text,
    )


def segment_table(run: Run, segment: int) -> str:
    """Return a Markdown table of throughput, CPU, RSS and load per ``segment`` frames.

    CPU per frame is the child's CPU time between the samples nearest the segment's ends:
    unlike wall time it hardly depends on what else the machine runs.
    """
    lines = [harness.table_header(SEGMENT_COLUMNS)]
    times = run.frame_times_s
    for first in range(0, len(times), segment):
        last = min(first + segment, len(times)) - 1
        # the first segment starts at cli.main (basis load, opening, filling the pipeline)
        begin = run.started_s if first == 0 else times[first - 1]
        end = times[last]
        inside = [s for s in run.samples if begin <= s.monotonic_s <= end]
        rss = max((s.rss_mb for s in inside), default=float("nan"))
        load = inside[-1].load_1min if inside else float("nan")
        count = last + 1 - first
        cpu_ms = float("nan")
        if run.samples:
            at_begin = min(run.samples, key=lambda s: abs(s.monotonic_s - begin))
            at_end = min(run.samples, key=lambda s: abs(s.monotonic_s - end))
            cpu_ms = 1000 * (at_end.cpu_s - at_begin.cpu_s) / count
        numbers = [f"{end - begin:.1f}", f"{count / (end - begin):.1f}", f"{cpu_ms:.0f}"]
        lines.append(
            harness.table_row([f"{first + 1}-{last + 1}", *numbers, f"{rss:.0f}", f"{load:.2f}"])
        )
    return "\n".join(lines)


def summary_row(run: Run) -> str:
    """Return one Markdown row: frames, wall time, frames/s, peak RSS, output, load."""
    seconds = run.ended_s - run.started_s
    loads = [s.load_1min for s in run.samples]
    load = f"{min(loads):.1f}-{max(loads):.1f}" if loads else "n/a"
    frames = len(run.frame_times_s)
    cpu = f"{1000 * run.cpu_s / frames:.0f}" if frames else "n/a"
    rate = f"{frames / seconds:.1f}"
    sizes = [f"{run.peak_rss_mb:.0f}", f"{run.output_mb:.0f}"]
    return harness.table_row([run.frames, f"{seconds:.1f}", rate, cpu, *sizes, load])


def main(argv: list[str] | None = None) -> int:
    """Run the long-log benchmark and print Markdown tables."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/pcainterp_longlog"))
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--segment", type=int, default=100, help="frames per throughput row")
    harness.add_basis_arguments(parser)
    parser.add_argument("--keep-output", action="store_true", help="keep the densified logs")
    parser.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument("command", nargs="*", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        return child(args.child, list(args.command))

    work = harness.work_dir(args.work_dir)
    basis = harness.synth_basis(work, args.components, args.train_frames, fit_prior=args.fit_prior)
    logs = {frames: harness.synth_log(work, frames, seed=1) for frames in args.frames}
    runs: list[Run] = []
    load_before = os.getloadavg()
    for frames, log in logs.items():
        out = work / f"dense_{frames}.mcap"
        free_gb = shutil.disk_usage(work).free / 1e9
        needed_gb = 8e-3 * frames  # ~7.3 MB of output per full-size frame, with margin
        if free_gb < needed_gb + 2:
            raise SystemExit(
                f"{work} has {free_gb:.1f} GB free; {frames} frames need ~{needed_gb:.0f} GB"
            )
        try:
            runs.append(densify_run(log, basis, out, frames, work))
        finally:
            if not args.keep_output:
                out.unlink(missing_ok=True)
        print(runs[-1].stdout.strip(), file=sys.stderr)

    print(f"basis {basis}; logs {', '.join(str(p) for p in logs.values())}")
    print(
        f"machine: {os.cpu_count()} CPUs; load average (1, 5, 15 min) before the first run: "
        + ", ".join(f"{value:.2f}" for value in load_before)
        + f"; after the last: {', '.join(f'{value:.2f}' for value in os.getloadavg())}"
    )
    print("\n" + harness.table_header(SUMMARY_COLUMNS))
    for run in runs:
        print(summary_row(run))
    for run in runs:
        if len(run.frame_times_s) > args.segment:
            print(f"\n{run.frames}-frame log, per {args.segment} frames:\n")
            print(segment_table(run, args.segment))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
