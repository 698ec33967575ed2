"""When SGBM runs, in the densify job and in SGBM alone, and how many cores each keeps busy.

Runs ``pcainterp densify LOG -o OUT`` and SGBM alone (``tools/sgbm_alone.py``) in fresh
processes, alternating, and records in each the time (from the process's start, as the
kernel counts it) at which the first SGBM call began and the last one ended, and when the
process ended. Both programs call SGBM through ``frontend.stereo``; a ``sitecustomize``
module put first on ``PYTHONPATH`` wraps that call, so the programs themselves are not
changed. The process's CPU time is read from ``/proc`` every 10 ms meanwhile, which splits
each run in three: the start (process start to the first SGBM call: imports, set-up), the
middle (first call to last) and the tail (the last call to the process's end: for the job,
the last frames' estimate, encoding and writing, closing the output), each with its
length and the cores it kept busy on average. What the job does besides SGBM shows as a
later first call and a longer tail than SGBM alone's; in the middle the job runs its frames
at its own pace (half-resolution SGBM, so faster than SGBM alone).

The job writes a new output in each round, as a first run does: the previous round's is
removed before it starts (``--replace`` keeps it, so that the job replaces it, as a re-run
does; unlinking the old file then adds to the tail).

Example::

    python tools/sgbm_span.py kitti_odometry.mcap --work-dir /tmp/span --rounds 4
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness

import pcainterp_stream

SITECUSTOMIZE = '''
"""Written by tools/sgbm_span.py: times the SGBM calls of this process."""
import atexit, json, os, sys, threading, time


def _process_start():
    with open("/proc/self/stat") as stat:
        ticks = int(stat.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as uptime:
        up = float(uptime.read().split()[0])
    return time.time() - (up - ticks / os.sysconf("SC_CLK_TCK"))


_START = _process_start()
_CALLS = []
_LOCK = threading.Lock()


def _wrap(module):
    compute = module._Checked.compute

    def timed(self, left, right):
        began = time.time() - _START
        try:
            return compute(self, left, right)
        finally:
            with _LOCK:
                _CALLS.append((began, time.time() - _START))

    module._Checked.compute = timed


class _Finder:
    def find_spec(self, name, path=None, target=None):
        if name != "pcainterp_stream.frontend.stereo":
            return None
        sys.meta_path.remove(self)
        import importlib.util

        spec = importlib.util.find_spec(name)
        loader = spec.loader
        run = loader.exec_module

        def exec_module(module):
            run(module)
            _wrap(module)

        loader.exec_module = exec_module
        return spec


sys.meta_path.insert(0, _Finder())


def _report():
    with open(os.environ["SGBM_SPAN_OUT"], "w") as out:
        json.dump({"calls": sorted(_CALLS), "start": _START}, out)


atexit.register(_report)
'''


SAMPLE_S = 0.01
"""How often the running program's CPU time is read (s)."""


def process_cpu(pid: int) -> float | None:
    """Return a process's user + system CPU seconds so far (None once it has ended)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(command: list[str], env: dict[str, str], record: Path) -> dict[str, float]:
    """Run one program; return its phases' ends (s from its start) and their cores.

    Raises:
        SystemExit: the program failed or made no SGBM call.
    """
    record.unlink(missing_ok=True)
    samples: list[tuple[float, float]] = []  # (epoch s, CPU s)
    # its messages to a file: a pipe read only at the end could fill up and block it
    with tempfile.TemporaryFile() as errors:
        with subprocess.Popen(
            command,
            env={**env, "SGBM_SPAN_OUT": str(record)},
            stdout=subprocess.DEVNULL,
            stderr=errors,
        ) as child:
            while child.poll() is None:
                cpu = process_cpu(child.pid)
                if cpu is not None:
                    samples.append((time.time(), cpu))
                time.sleep(SAMPLE_S)
        ended = time.time()  # after the interpreter's teardown too, where a program has one
        if child.returncode != 0:
            errors.seek(0)
            raise SystemExit(f"{' '.join(command)} failed: {errors.read().decode()[-2000:]}")
    data = json.loads(record.read_text())
    calls = data["calls"]
    if not calls or not samples:
        raise SystemExit(f"{' '.join(command)} made no SGBM call")
    start = float(data["start"])
    first = float(calls[0][0])
    last = max(float(end) for _, end in calls)

    def cpu_at(moment: float) -> float:
        """CPU seconds at the last sample before ``moment`` (s from the start)."""
        return max((cpu for at, cpu in samples if at - start <= moment), default=0.0)

    at_first, at_last, total = cpu_at(first), cpu_at(last), samples[-1][1]
    tail = ended - start - last
    return {
        "first": first,
        "last": last,
        "exit": ended - start,
        "start cores": at_first / first,
        "middle cores": (at_last - at_first) / (last - first),
        # the CPU of the last ~10 ms is not seen: the tail's cores are a lower bound
        "tail cores": (total - at_last) / tail if tail > 0 else 0.0,
        "calls": len(calls),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the rounds; print a Markdown table and the medians."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("log", type=Path, help="the input log")
    harness.add_work_dir(parser, description="folder of the output and the timing hook")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument(
        "--replace", action="store_true", help="the job replaces the previous round's output"
    )
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir).resolve()
    hook = work / "hook"
    hook.mkdir(exist_ok=True)
    (hook / "sitecustomize.py").write_text(SITECUSTOMIZE)
    package = Path(pcainterp_stream.__file__).resolve().parent
    harness.compile_bytecode(package)
    path = [str(hook), str(package.parent), os.environ.get("PYTHONPATH", "")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p)}
    log = str(args.log.resolve())
    programs = {
        "SGBM alone": [sys.executable, str(Path(__file__).with_name("sgbm_alone.py")), log],
        "densify": [
            *(sys.executable, "-m", "pcainterp_stream.cli", "densify", log),
            *("-o", str(work / "span.mcap")),
        ],
    }
    print(
        harness.table_header(
            [
                "round",
                "program",
                "first SGBM call s (cores before)",
                "first to last s (cores)",
                "tail s (cores)",
                "exit s",
            ]
        )
    )
    spans: dict[str, list[dict[str, float]]] = {name: [] for name in programs}
    for round_index in range(args.rounds):
        names = list(programs) if round_index % 2 == 0 else list(programs)[::-1]
        for name in names:
            if name == "densify" and not args.replace:
                (work / "span.mcap").unlink(missing_ok=True)
            span = run(programs[name], env, work / "span.json")
            spans[name].append(span)
            print(
                harness.table_row(
                    [
                        round_index + 1,
                        name,
                        f"{span['first']:.3f} ({span['start cores']:.2f})",
                        f"{span['last'] - span['first']:.3f} ({span['middle cores']:.2f})",
                        f"{span['exit'] - span['last']:.3f} ({span['tail cores']:.2f})",
                        f"{span['exit']:.3f}",
                    ]
                ),
                flush=True,
            )
    print()
    for name, runs in spans.items():

        def median(key: str, runs: list[dict[str, float]] = runs) -> float:
            return statistics.median(s[key] for s in runs)

        middle = statistics.median(s["last"] - s["first"] for s in runs)
        tail = statistics.median(s["exit"] - s["last"] for s in runs)
        print(
            f"{name}: medians over {len(runs)} rounds: first SGBM call at {median('first'):.3f}"
            f" s ({median('start cores'):.2f} cores before), first to last {middle:.3f} s "
            f"({median('middle cores'):.2f} cores), tail {tail:.3f} s "
            f"({median('tail cores'):.2f} cores), exit {median('exit'):.3f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
