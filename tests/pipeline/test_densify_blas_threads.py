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
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LOG = ROOT / "tests" / "data" / "golden_synth.mcap"
BASIS = ROOT / "tests" / "data" / "golden_basis.npz"

SCRIPT = """
import json, sys
from threadpoolctl import threadpool_info
from pcainterp_stream.cli import main

for argv in json.loads(sys.argv[1]):
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


@pytest.mark.parametrize("command", ["densify", "evaluate", "learn"])
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
    }[command]
    counts = _counts_after(tmp_path, argvs)
    scipy_libs = {path: n for path, n in counts.items() if "scipy.libs" in path}
    numpy_libs = {path: n for path, n in counts.items() if "numpy.libs" in path}
    assert scipy_libs
    # a new library gets the count the caller's environment gives, as numpy's has
    assert set(scipy_libs.values()) == set(numpy_libs.values())
