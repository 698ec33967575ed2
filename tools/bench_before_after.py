"""The default densify job before and after a change, against SGBM alone, in the same rounds.

Each round runs, in fresh processes: full-resolution SGBM alone
(``tools/sgbm_alone.py``), ``pcainterp densify LOG -o OUT`` from a checkout of the code
before the change (``--before``: a folder holding its ``pcainterp_stream`` package, put
first on ``PYTHONPATH``), and the same command with the code installed here. Per round it
prints the wall time and the CPU (user + system, start-up included) of each, CPU per frame,
the job's wall time and CPU against SGBM alone's, the output's MB per frame and each
process's peak RSS; then the
medians. "before" and "after" swap places every round. Both
packages are compiled to bytecode first, as an installed copy is
(:func:`harness.compile_bytecode`).

On a shared machine the wall times are the load's; the CPU figures, paired within a round,
are the measure. ``--after-args`` adds densify options to the "after" run only: with
``--before`` a copy of the same code, it times an option against the default.

Example (a checkout of the parent commit, without touching the work tree)::

    git archive HEAD~1 | tar -x -C /tmp/before
    python tools/bench_before_after.py kitti_odometry.mcap --before /tmp/before \
        --work-dir /tmp/before_after --rounds 4
    python tools/bench_before_after.py kitti_odometry.mcap --before /tmp/same \
        --work-dir /tmp/option --rounds 4 --after-args=--fill-spacing=36
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import harness

import pcainterp_stream
from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.logreader import open_log


def run(
    command: list[str], cwd: Path, env: dict[str, str] | None = None
) -> tuple[float, float, float]:
    """Run a command to its end in ``cwd``; return its wall and CPU seconds and peak RSS (MB).

    Raises:
        SystemExit: the command failed (its last error lines).
    """
    started = time.perf_counter()
    child = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=cwd, env=env
    )
    assert child.stderr is not None
    errors = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(command)} failed: {errors.decode()[-2000:]}")
    wall = time.perf_counter() - started
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024  # KiB on Linux


def frame_count(log: Path) -> int:
    """Return the number of left images of a log (the frames densify makes).

    The left camera is the one densify finds (compressed images, ``image_raw``, a camera's
    own names), not only ``/stereo/left/image_rect``.
    """
    with open_log(log) as reader:
        try:
            left = resolve_pairing(reader, PairingConfig(discover=True)).left_topic
        except PcaInterpError as err:
            raise SystemExit(f"{log}: {err}") from None
        info = reader.topics().get(left)
    if info is None or not info.message_count:
        raise SystemExit(f"{log} has no {left} messages to densify")
    return int(info.message_count)


def main(argv: list[str] | None = None) -> int:
    """Run the rounds; print a Markdown table."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("log", type=Path, help="the input log")
    parser.add_argument(
        "--before", type=Path, required=True, help="folder holding the old pcainterp_stream"
    )
    harness.add_work_dir(parser, description="folder of the outputs (overwritten)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--after-args",
        nargs="+",
        default=[],
        metavar="ARG",
        help="densify options of the 'after' run only (write --after-args=--opt=value)",
    )
    args = parser.parse_args(argv)
    if not (args.before / "pcainterp_stream").is_dir():
        parser.error(f"--before {args.before} holds no pcainterp_stream package")
    # every command runs in the work folder: ``python -m`` puts the current folder first on
    # sys.path, so a run from a checkout would import that checkout's code for "before" too
    work = harness.work_dir(args.work_dir).resolve()
    log = args.log.resolve()
    frames = frame_count(log)
    sgbm = [sys.executable, str(Path(__file__).resolve().with_name("sgbm_alone.py")), str(log)]
    output = work / "before_after.mcap"
    densify = [sys.executable, "-m", "pcainterp_stream.cli", "densify", str(log)]
    densify += ["-o", str(output)]
    old_env = {**os.environ, "PYTHONPATH": str(args.before.resolve())}
    harness.compile_bytecode(
        args.before.resolve() / "pcainterp_stream", Path(pcainterp_stream.__file__).parent
    )
    print(f"{args.log}: {frames} frames\n")
    print(
        harness.table_header(
            [
                "round",
                "SGBM alone s (CPU ms/frame)",
                "before s (CPU ms/frame)",
                "after s (CPU ms/frame)",
                "wall before / SGBM",
                "wall after / SGBM",
                "CPU before / SGBM",
                "CPU after / SGBM",
                "MB/frame before",
                "after",
                "peak RSS MB before",
                "after",
            ]
        )
    )
    walls: dict[str, list[float]] = {"before": [], "after": []}
    cpus: dict[str, list[float]] = {"before": [], "after": []}
    peaks: dict[str, list[float]] = {"before": [], "after": []}
    for round_index in range(args.rounds):
        alone = run(sgbm, work)
        # the order alternates from round to round, so neither gains from going second
        timed: dict[str, tuple[float, float, float]] = {}
        sizes: dict[str, float] = {}
        for name in ("before", "after") if round_index % 2 == 0 else ("after", "before"):
            output.unlink(missing_ok=True)  # a fresh output each run, as a first run writes
            if name == "before":
                timed[name] = run(densify, work, old_env)
            else:
                timed[name] = run(densify + args.after_args, work)
            sizes[name] = output.stat().st_size / 1e6 / frames
            walls[name].append(timed[name][0] / alone[0])
            cpus[name].append(timed[name][1] / alone[1])
            peaks[name].append(timed[name][2])
        cells: list[object] = [round_index + 1]
        cells += [
            f"{wall:.2f} ({1000 * cpu / frames:.0f})"
            for wall, cpu, _ in (alone, timed["before"], timed["after"])
        ]
        cells += [f"{walls[name][-1]:.3f}" for name in ("before", "after")]
        cells += [f"{cpus[name][-1]:.2f}" for name in ("before", "after")]
        cells += [f"{sizes['before']:.3f}", f"{sizes['after']:.3f}"]
        cells += [f"{peaks[name][-1]:.0f}" for name in ("before", "after")]
        print(harness.table_row(cells), flush=True)
    print(
        f"\nagainst SGBM alone over {args.rounds} rounds, median wall: before "
        f"{statistics.median(walls['before']):.3f}, after {statistics.median(walls['after']):.3f}"
        f"; median CPU: before {statistics.median(cpus['before']):.2f}, after "
        f"{statistics.median(cpus['after']):.2f}; peak RSS: before "
        f"{min(peaks['before']):.0f}-{max(peaks['before']):.0f} MB, after "
        f"{min(peaks['after']):.0f}-{max(peaks['after']):.0f} MB"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
