"""Bug hunt 10A F1: a densify job in-process left scipy's OpenBLAS at one thread for good."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

SCRIPT = """
import json, sys
from threadpoolctl import threadpool_info
from pcainterp_stream.cli import main

log, out = sys.argv[1], sys.argv[2]
assert main(["densify", log, "-o", out]) == 0  # scipy is first loaded inside
import scipy.linalg  # a caller's own work afterwards
print(json.dumps({i["filepath"]: i["num_threads"] for i in threadpool_info()
                  if i["user_api"] == "blas"}))
"""


def test_densify_gives_the_callers_blas_thread_counts_back(tmp_path: Path) -> None:
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root))
    log = root / "tests" / "data" / "golden_synth.mcap"
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(log), str(tmp_path / "b.mcap")],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    counts = json.loads(done.stdout.strip().splitlines()[-1])
    scipy_libs = {path: n for path, n in counts.items() if "scipy.libs" in path}
    numpy_libs = {path: n for path, n in counts.items() if "numpy.libs" in path}
    assert scipy_libs  # loaded by the job's solver
    # a new library gets the count the caller's environment gives, as numpy's has
    assert set(scipy_libs.values()) == set(numpy_libs.values())
