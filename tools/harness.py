"""The shared harness of the scripts in ``tools/``: command line, work folder, timing, output.

The scripts run as ``python tools/NAME.py ...``, so Python puts ``tools/`` first on
``sys.path`` and they ``import harness`` (mypy, given ``tools``, resolves it the same way).
Only the standard library is imported here at the top; the builders of cached inputs import
the package when they run.

- command line: :func:`argument_parser`, :func:`add_work_dir`, :func:`add_realdata`,
  :func:`add_basis_arguments`, :func:`add_batch_timing`;
- work folder: :func:`work_dir`; :func:`cached` builds a file once and reuses it, with the
  builders :func:`build_synth`, :func:`build_basis` and :func:`build_kitti`; the benchmark
  inputs :func:`synth_log` and :func:`synth_basis` (options :func:`add_basis_arguments`);
  :func:`run_cli` runs a ``pcainterp`` command in this process;
- timing: :class:`Stopwatch` (one block), :func:`timed` (repeated calls, a
  :class:`Timing`), :func:`traced_peak_mb`, :func:`log` (time-stamped progress lines);
  memory of a process: :func:`proc_status_kib`, :func:`peak_rss_mb`;
- output: :func:`table_header` and :func:`table_row` (the Markdown tables the docs quote),
  :func:`read_json`, :func:`write_json`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import os
import statistics
import sys
import threading
import time
import tracemalloc
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

REPO = Path(__file__).resolve().parents[1]
"""The repository's root folder."""
REALDATA = REPO.parent / "shared" / "realdata"
"""The shared real data beside the repository (KITTI clips, sample bags)."""
KITTI_RAW_0001 = Path("kitti_raw", "2011_09_26", "2011_09_26_drive_0001_sync")
"""The raw KITTI drive 0001, relative to :data:`REALDATA` (or a ``--realdata`` folder)."""
KITTI_ODOMETRY_CLIP = Path("kitti_odometry_clip", "sequences", "a")
"""The KITTI odometry clip, relative to :data:`REALDATA`."""

Builder = Callable[[Path], object]
"""Writes the file (or folder) it is given: what :func:`cached` calls when it is missing."""


# ----------------------------------------------------------------------------- command line


def argument_parser(doc: str | None, **kwargs: Any) -> argparse.ArgumentParser:
    """Return a parser described by the first line of a script's docstring.

    Args:
        doc: the script's ``__doc__``.
        **kwargs: more ``argparse.ArgumentParser`` arguments (``formatter_class``, ...).
    """
    description = doc.strip().splitlines()[0] if doc else None
    return argparse.ArgumentParser(description=description, **kwargs)


def add_work_dir(
    parser: argparse.ArgumentParser,
    default: Path | None = None,
    *,
    flag: str = "--work-dir",
    description: str | None = None,
) -> None:
    """Add the option naming the work folder (caches, outputs); required without a default."""
    parser.add_argument(
        flag, type=Path, default=default, required=default is None, help=description
    )


def add_realdata(parser: argparse.ArgumentParser) -> None:
    """Add ``--realdata``, the folder of the real KITTI data (default :data:`REALDATA`)."""
    parser.add_argument(
        "--realdata",
        type=Path,
        default=REALDATA,
        help=f"folder holding {KITTI_RAW_0001.as_posix()}",
    )


def add_dense_points(parser: argparse.ArgumentParser) -> None:
    """Add ``--corners`` and ``--fill-spacing``: the points of dense mode's sparse estimate."""
    from pcainterp_stream.frontend.matchers import DENSE_GFTT

    parser.add_argument(
        "--corners",
        type=int,
        default=None,
        help=f"GFTT corners of dense mode's sparse estimate (densify --corners; default: "
        f"densify --measurements dense's, {DENSE_GFTT.max_corners} at full resolution)",
    )
    parser.add_argument(
        "--fill-spacing",
        type=float,
        default=None,
        help=f"its lattice's side, px (densify --fill-spacing; default: densify's, "
        f"{DENSE_GFTT.fill_spacing:g} at full resolution)",
    )


def dense_points(args: argparse.Namespace) -> Any:
    """The ``GfttConfig`` of :func:`add_dense_points`' options; None: densify's own."""
    from pcainterp_stream.frontend.matchers import DENSE_GFTT

    if args.corners is None and args.fill_spacing is None:
        return None
    changes = {"max_corners": args.corners, "fill_spacing": args.fill_spacing}
    given = {name: value for name, value in changes.items() if value is not None}
    return dataclasses.replace(DENSE_GFTT, **given)


def add_basis_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--train-frames``, ``--components``, ``--fit-prior`` (see :func:`synth_basis`)."""
    parser.add_argument(
        "--train-frames", type=int, default=250, help="frames of the basis's training log"
    )
    parser.add_argument("--components", type=int, default=200, help="basis components (l)")
    parser.add_argument(
        "--fit-prior",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="learn the basis fitting the prior, as `learn` does by default (densify then "
        "uses the hybrid prior; default: %(default)s)",
    )


def add_batch_timing(
    parser: argparse.ArgumentParser, *, repeat: int, repeat_help: str = "best of N rounds"
) -> None:
    """Add ``--repeat``, ``--batch`` and ``--blas-threads``.

    For timing ``densify_batch`` as the stream processor calls it: batches of 4 frames, BLAS
    on one thread.
    """
    parser.add_argument("--repeat", type=int, default=repeat, help=repeat_help)
    parser.add_argument("--batch", type=int, default=4, help="frames per densify_batch")
    parser.add_argument("--blas-threads", type=int, default=1, help="1: as in the stream processor")


# ----------------------------------------------------------------------------- work folder


def compile_bytecode(*packages: Path) -> None:
    """Compile each package's modules to bytecode, as ``pip install`` does, before timing.

    A job's start-up is part of its speed. An installed copy (``pip install .``) comes
    with compiled modules; an editable checkout, or a shell with
    ``PYTHONDONTWRITEBYTECODE`` set, compiles every module again in every process (~0.1 s
    of the densify job's start-up, measured). The timed commands then start as a user's
    installed tool does.
    """
    import compileall

    for package in packages:
        compileall.compile_dir(str(package), quiet=1)


def work_dir(path: Path) -> Path:
    """Create the folder ``path`` (and its parents) when missing; return it."""
    path.mkdir(parents=True, exist_ok=True)
    return path


def cached(
    path: Path,
    build: Builder,
    note: str | None = None,
    *,
    echo: Callable[[str], object] | None = None,
) -> Path:
    """Return ``path``, calling ``build(path)`` first when it does not exist.

    What a script generates or learns once into its work folder and reuses on the next run.
    The package's log and basis writers write to a temporary name and rename, so an
    interrupted build leaves no partial file behind.

    Args:
        path: the file or folder.
        build: writes it, e.g. :func:`build_synth`.
        note: shown before a build.
        echo: how the note is shown (default: a line on stderr, so that stdout keeps the
            script's tables).
    """
    if not path.exists():
        if note is not None:
            (echo or _to_stderr)(note)
        build(path)
    return path


def _to_stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def build_synth(*, frames: int, seed: int, scale: float = 1.0) -> Builder:
    """Return a builder of a synthetic log (``pcainterp synth``; format from the name)."""

    def build(path: Path) -> None:
        from pcainterp_stream.pipeline import jobs

        with contextlib.redirect_stdout(sys.stderr):
            jobs.synth(path, frames=frames, seed=seed, scale=scale, fmt=None)

    return build


def build_basis(logs: Sequence[Path], *, components: int, fit_prior: bool = False) -> Builder:
    """Return a builder of a basis learned from the SGBM maps of ``logs`` (``pcainterp learn``).

    Args:
        logs: the training logs.
        components: ``--components``.
        fit_prior: ``--fit-prior`` (the hybrid prior, fitted on the logs' last 20 %).
    """

    def build(path: Path) -> None:
        from pcainterp_stream.frontend.pairing import PairingConfig
        from pcainterp_stream.pipeline import jobs

        options = jobs.LearnOptions(n_components=components, fit_prior=fit_prior)
        with contextlib.redirect_stdout(sys.stderr):
            jobs.learn(list(logs), path, options, PairingConfig())

    return build


def build_kitti(folder: Path, *, max_frames: int | None = None) -> Builder:
    """Return a builder of an MCAP log of a KITTI folder (``pcainterp import-kitti``)."""

    def build(path: Path) -> None:
        from pcainterp_stream.pipeline import jobs

        with contextlib.redirect_stdout(sys.stderr):
            jobs.import_kitti(folder, path, max_frames=max_frames)

    return build


def synth_log(work: Path, frames: int, seed: int) -> Path:
    """Return the full-size synthetic log ``WORK/synth_{frames}_s{seed}.mcap``, made once."""
    path = work / f"synth_{frames}_s{seed}.mcap"
    return cached(path, build_synth(frames=frames, seed=seed), f"generating {path} ...")


def synth_basis(work: Path, components: int, train_frames: int, *, fit_prior: bool = False) -> Path:
    """Return a basis learned once from the SGBM maps of a full-size synthetic log (seed 2).

    ``WORK/basis_l{components}_n{train_frames}.npz`` (``..._prior.npz`` with ``fit_prior``,
    as ``learn --fit-prior`` learns it: ``densify`` then uses the hybrid prior by default).
    """
    suffix = "_prior" if fit_prior else ""
    path = work / f"basis_l{components}_n{train_frames}{suffix}.npz"
    if path.exists():
        return path
    train = synth_log(work, train_frames, seed=2)
    build = build_basis([train], components=components, fit_prior=fit_prior)
    return cached(path, build, f"learning {path} from {train} ...")


def run_cli(*args: str | float | Path, quiet: bool = False) -> None:
    """Run ``pcainterp ARGS`` in this process.

    Args:
        *args: the command line after ``pcainterp``.
        quiet: drop what the command prints.

    Raises:
        RuntimeError: the command exited other than 0.
    """
    from pcainterp_stream import cli

    argv = [str(arg) for arg in args]
    with contextlib.ExitStack() as stack:
        if quiet:
            stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
            stack.enter_context(contextlib.redirect_stderr(io.StringIO()))
        code = cli.main(argv)
    if code != 0:
        raise RuntimeError(f"pcainterp {' '.join(argv)} exited {code}")


# ----------------------------------------------------------------------------- timing


class Stopwatch:
    """Wall and CPU seconds of a ``with`` block.

    Args:
        cpu_clock: ``time.process_time`` (all threads of the process, the default) or
            ``time.thread_time`` (the calling thread).

    Attributes:
        wall: wall seconds (``time.perf_counter``) of the last block.
        cpu: CPU seconds of the last block.
    """

    def __init__(self, cpu_clock: Callable[[], float] = time.process_time) -> None:
        self.cpu_clock = cpu_clock
        self.wall = 0.0
        self.cpu = 0.0
        self._started = (0.0, 0.0)

    def __enter__(self) -> Stopwatch:
        self._started = (time.perf_counter(), self.cpu_clock())
        return self

    def __exit__(self, *exc_info: object) -> None:
        wall, cpu = self._started
        self.wall = time.perf_counter() - wall
        self.cpu = self.cpu_clock() - cpu


@dataclass(frozen=True)
class Timing:
    """Seconds of repeated runs (the shared machine makes the best the steadier figure).

    Attributes:
        wall: wall seconds of each run.
        cpu: CPU seconds of each run (empty when not measured).
    """

    wall: tuple[float, ...]
    cpu: tuple[float, ...] = ()

    @property
    def best(self) -> float:
        """The fastest run's wall seconds."""
        return min(self.wall)

    @property
    def median(self) -> float:
        """The median wall seconds."""
        return statistics.median(self.wall)

    @property
    def best_cpu(self) -> float:
        """The least CPU seconds of a run."""
        return min(self.cpu)


def timed(
    run: Callable[[], object],
    repeat: int = 1,
    *,
    warmup: bool = True,
    cpu_clock: Callable[[], float] = time.process_time,
) -> Timing:
    """Time ``repeat`` calls of ``run``, after one untimed warm-up call unless ``warmup``."""
    if warmup:
        run()
    watches = []
    for _ in range(repeat):
        with Stopwatch(cpu_clock) as watch:
            run()
        watches.append(watch)
    return Timing(tuple(w.wall for w in watches), tuple(w.cpu for w in watches))


def traced_peak_mb(run: Callable[[], object]) -> float:
    """Return the peak of the memory ``tracemalloc`` traces during one call of ``run`` (MB)."""
    tracemalloc.start()
    try:
        run()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1e6


def log(text: str) -> None:
    """Print a progress line ``[HH:MM:SS] text`` (flushed)."""
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def proc_status_kib(field: str, pid: int | str = "self") -> float | None:
    """Return a ``kB`` field of ``/proc/PID/status`` (``VmRSS``, ``VmHWM``, ``VmSize``).

    None where there is no such field or process (the process ended, not Linux).
    """
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith(field + ":"):
                    return float(line.split()[1])
    except OSError:
        return None
    return None


def peak_rss_mb() -> float:
    """Peak resident set size of this process (``VmHWM``, MB; NaN where /proc does not say).

    Not ``getrusage``: on Linux its ``ru_maxrss`` survives exec, so a spawned worker would
    report its parent's peak if that were higher.
    """
    kib = proc_status_kib("VmHWM")
    return float("nan") if kib is None else kib / 1024.0


# ----------------------------------------------------------------------------- output


class ThreadCpu:
    """Samples each thread's CPU seconds (user, system) in this process while a block runs.

    Read from ``/proc/self/task`` (Linux) every ``period`` seconds and once at the end, with
    the Python name of each thread (``names``; native threads have none). A thread that ends
    between two samples keeps its last sample. Subclasses extend :meth:`_sample` to record
    the samples over time.
    """

    def __init__(self, period: float = 0.1) -> None:
        self.period = period
        self.seconds: dict[int, tuple[float, float]] = {}
        self.names: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cpu-sampler", daemon=True)
        self._tick = os.sysconf("SC_CLK_TCK")

    def own_thread(self, native_id: int) -> bool:
        """Whether ``native_id`` is the sampler's own thread (left out of reports)."""
        return native_id == self._thread.native_id

    def _sample(self) -> None:
        for thread in threading.enumerate():
            if thread.native_id is not None:
                self.names.setdefault(thread.native_id, thread.name)
        for tid in os.listdir("/proc/self/task"):
            try:
                stat = Path(f"/proc/self/task/{tid}/stat").read_text()
            except OSError:  # the thread ended meanwhile: its last sample stands
                continue
            fields = stat.rsplit(")", 1)[1].split()
            self.seconds[int(tid)] = (int(fields[11]) / self._tick, int(fields[12]) / self._tick)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self._sample()

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()


def table_row(cells: Iterable[object]) -> str:
    """Return one Markdown table row, ``| a | b |``."""
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def table_header(headers: Sequence[str], align: str = "") -> str:
    """Return a Markdown table's header row and the rule under it (two lines).

    Args:
        headers: the column titles.
        align: a letter per column, ``l`` (``---``, the default for missing letters) or
            ``r`` (right-aligned, ``---:``).
    """
    rule = ["---:" if align[i : i + 1] == "r" else "---" for i in range(len(headers))]
    return table_row(headers) + "\n" + table_row(rule)


def read_json(path: Path, default: Any = None) -> Any:
    """Return the JSON in ``path``, or ``default`` when it is given and the file is missing."""
    if default is not None and not path.is_file():
        return default
    return json.loads(path.read_text())


def write_json(path: Path, data: object, indent: int | None = 1) -> None:
    """Write ``data`` to ``path`` as JSON with a final newline."""
    path.write_text(json.dumps(data, indent=indent) + "\n")


def module_main(doc: str | None, used_by: str) -> None:
    """Answer ``--help`` for a module of helpers that other tools import; refuse to run.

    Args:
        doc: the module's docstring, shown as the description.
        used_by: the scripts that import it, named in the help and the error.
    """
    parser = argparse.ArgumentParser(
        description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"imported by {used_by}; it has nothing to run on its own",
    )
    parser.parse_args()
    parser.error(f"nothing to run: this module is imported by {used_by}; run one of those")


if __name__ == "__main__":
    module_main(__doc__, "every script in tools/")
