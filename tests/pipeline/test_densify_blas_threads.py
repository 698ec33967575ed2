"""Bug hunt 10A F1 / review 58a R7: a job in-process left scipy's OpenBLAS at one thread.

``densify`` (10A F1), then ``evaluate`` and ``learn`` (58a R7) through ``cli.main``: each
loads scipy's OpenBLAS inside the job, where the solver holds it at one thread; the caller
gets the count a new BLAS has in its environment back.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LOG = ROOT / "tests" / "data" / "golden_synth.mcap"
BASIS = ROOT / "tests" / "data" / "golden_basis.npz"

SCRIPT = """
import json, sys
from pathlib import Path
from threadpoolctl import threadpool_info
from pcainterp_stream.cli import main

for argv in json.loads(sys.argv[1]):
    if argv[0] == "api-learn":  # pipeline.learn.learn called in-process (review 58c C3)
        from pcainterp_stream.frontend.pairing import PairingConfig
        from pcainterp_stream.pipeline.learn import LearnOptions, learn
        learn([Path(argv[1])], Path(argv[2]), LearnOptions(), PairingConfig())
        continue
    assert main(argv) == 0, argv  # scipy is first loaded inside the first
import scipy.linalg  # a caller's own work afterwards
print(json.dumps({i["filepath"]: i["num_threads"] for i in threadpool_info()
                  if i["user_api"] == "blas"}))
"""


def _counts_after(tmp_path: Path, argvs: list[list[str]]) -> dict[str, int]:
    """Run ``argvs`` through ``cli.main`` in a fresh interpreter; the BLAS counts after."""
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, json.dumps(argvs)],
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    counts: dict[str, int] = json.loads(done.stdout.strip().splitlines()[-1])
    return counts


@pytest.mark.parametrize("command", ["densify", "evaluate", "learn", "api-learn"])
def test_a_command_gives_the_callers_blas_thread_counts_back(tmp_path: Path, command: str) -> None:
    dense = str(tmp_path / "d.mcap")
    if command == "evaluate":  # a log to evaluate, densified by another process
        _counts_after(tmp_path, [["densify", str(LOG), "-o", dense, "--basis", str(BASIS)]])
    argvs = {
        "densify": [["densify", str(LOG), "-o", dense]],
        "evaluate": [
            [
                "evaluate",
                dense,
                "-o",
                str(tmp_path / "rep"),
                "--max-frames",
                "2",
                "--basis",
                str(BASIS),
            ]
        ],
        "learn": [["learn", str(LOG), "-o", str(tmp_path / "b.npz")]],
        "api-learn": [["api-learn", str(LOG), str(tmp_path / "b.npz")]],
    }[command]
    counts = _counts_after(tmp_path, argvs)
    scipy_libs = {path: n for path, n in counts.items() if "scipy.libs" in path}
    numpy_libs = {path: n for path, n in counts.items() if "numpy.libs" in path}
    assert scipy_libs
    # a new library gets the count the caller's environment gives, as numpy's has
    assert set(scipy_libs.values()) == set(numpy_libs.values())


def test_the_learn_and_demo_jobs_give_the_counts_back_when_called_in_process() -> None:
    """Review 58c C3: ``learn`` and ``demo`` called as API run as jobs (the test above)."""
    from pcainterp_stream.pipeline import jobs, learn

    for job in (learn.learn, jobs.demo, jobs.evaluate):
        assert getattr(job, "__wrapped__", None) is not None, job


RACE = """
import json
import scipy.linalg  # both BLAS loaded
from threadpoolctl import threadpool_info
from pcainterp_stream.pipeline.threads import ThreadLimits
from pcainterp_stream.pipeline.blas_threads import blas_threads_given_back

def counts():
    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

seen = {}
with blas_threads_given_back():  # a densify job, its processor inside
    processor = ThreadLimits(None, 1)
    other = ThreadLimits(None, 1)  # another job's processor, opened during this job
    processor.restore()
    seen["job, processor closed"] = counts()
seen["other running"] = counts()  # the densify job returned
other.restore()  # from this thread: OpenBLAS takes a count set from the main thread only
seen["after"] = counts()
print(json.dumps(seen))
"""


def test_a_job_ending_keeps_blas_at_one_thread_while_another_processor_runs() -> None:
    """Review 58c C1: one count for the jobs and the processors' ThreadLimits.

    A densify job returning while another job's processor (its own ThreadLimits) still
    ran gave every BLAS the caller's two threads back under it.
    """
    done = subprocess.run(
        [sys.executable, "-c", RACE],
        env=dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="2"),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen == {"job, processor closed": [1], "other running": [1], "after": [2]}


def test_jobs_entering_and_leaving_in_many_threads_leave_the_count_at_zero() -> None:
    """The one count is taken under a lock: 8 threads x 200 jobs and processors."""
    from pcainterp_stream.pipeline.blas_threads import BlasThreads, blas_threads_given_back
    from pcainterp_stream.pipeline.threads import ThreadLimits

    def work() -> None:
        for _ in range(200):
            with blas_threads_given_back():
                ThreadLimits(None, 1).restore()

    threads = [threading.Thread(target=work) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert BlasThreads.running == 0


class _Library:
    def __init__(self, path: str, threads: int) -> None:
        self.filepath, self.num_threads = path, threads

    def set_num_threads(self, threads: int) -> None:
        self.num_threads = threads


def test_a_blas_loaded_after_the_first_job_entered_is_held_too(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the command line entered before it imported NumPy (lazy imports): the frame processor
    # entering next left numpy's OpenBLAS at 2 threads, the densify job at 1.3x its CPU
    from pcainterp_stream.pipeline import blas_threads
    from pcainterp_stream.pipeline.blas_threads import BlasThreads

    numpy_blas = _Library("numpy.libs/openblas.so", 2)
    loaded: list[_Library] = []
    monkeypatch.setattr(blas_threads, "_blas_libraries", lambda: list(loaded))
    monkeypatch.setattr(BlasThreads, "running", 0)
    BlasThreads.enter()  # the command: nothing loaded yet
    loaded.append(numpy_blas)  # NumPy imported inside the command
    BlasThreads.enter(1)  # the frame processor
    assert numpy_blas.num_threads == 1
    BlasThreads.leave()
    assert numpy_blas.num_threads == 1  # the command still runs
    BlasThreads.leave()
    assert numpy_blas.num_threads == BlasThreads.default  # loaded during the jobs
