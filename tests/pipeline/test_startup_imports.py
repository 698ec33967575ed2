"""What the default densify job imports: start-up time is part of its speed.

scipy costs ~0.3 s of start-up (its few compiled modules the job calls load on the
densify thread) and rosbags' bag readers and writers ~65 ms; an MCAP job needs neither on
its main thread. Each case runs in a fresh interpreter (this one has imported everything
already).
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

ROSBAGS_BAGS = ("rosbags.highlevel", "rosbags.rosbag1", "rosbags.rosbag2", "rosbags.convert")


def _modules_after(code: str) -> list[str]:
    """Run ``code`` in a fresh interpreter; return the modules loaded at its end."""
    script = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))\n"
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, cwd=ROOT
    )
    modules: list[str] = json.loads(result.stdout.strip().splitlines()[-1])
    return modules


def _loaded(modules: list[str], prefixes: tuple[str, ...]) -> list[str]:
    return [m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes)]


def test_the_jobs_modules_import_no_scipy_nor_rosbags_bags() -> None:
    modules = _modules_after(
        "import pcainterp_stream.cli.app, pcainterp_stream.cli.densify, "
        "pcainterp_stream.pipeline.densify, pcainterp_stream.pipeline.processor, "
        "pcainterp_stream.estimate.solve"
    )
    assert "pcainterp_stream.pipeline.processor" in modules
    assert _loaded(modules, ("scipy",)) == []
    assert _loaded(modules, ROSBAGS_BAGS) == []


def test_default_densify_of_an_mcap_imports_no_rosbags_bags(tmp_path: Path) -> None:
    """The whole default job on an MCAP: no bag reader or writer, no scipy.interpolate.

    (The fit check's triangulation still imports scipy.spatial, and with it scipy.linalg,
    in the densify thread; the solve's LAPACK does not need it.)
    """
    out = tmp_path / "out.mcap"
    modules = _modules_after(
        "from pcainterp_stream.cli.app import main\n"
        f"code = main(['densify', {str(LOG)!r}, '-o', {str(out)!r}])\n"
        "assert code == 0, code\n"
    )
    assert out.is_file()
    assert _loaded(modules, ROSBAGS_BAGS) == []
    assert _loaded(modules, ("scipy.interpolate", "scipy.optimize")) == []
    # the k-d tree loads without scipy.sparse (its name only holds a placeholder), no bar
    # off a terminal (the job's standard error is a pipe here)
    heavy = ("scipy.sparse._base", "scipy._lib._array_api", "numpy.f2py")
    # scipy 1.18's Qhull module imports scipy's array API layer (and numpy.f2py) itself: what
    # loading it alone brings is not the job's (on scipy <= 1.17 it brings none of these)
    qhull = _modules_after(
        "from pcainterp_stream import compiled\ncompiled.module('spatial._qhull')"
    )
    assert [name for name in _loaded(modules, heavy) if name not in qhull] == []
    assert _loaded(modules, ("tqdm", "multiprocessing")) == []


def test_scipy_loads_off_the_main_thread_with_one_blas_thread(tmp_path: Path) -> None:
    """The main thread starts matching without waiting for scipy (~0.3 s of imports).

    The densify thread (or a stereo worker, for a check frame's held-out pixels) loads
    scipy's LAPACK, Qhull and k-d tree while the first pairs are matched, without the
    ``__init__`` of scipy.linalg and scipy.spatial (the rest of those subpackages: ~0.2 s
    more); scipy's OpenBLAS comes up with one thread (a second, spinning one cost ~5x the
    solve's CPU) and stays so while the job runs; when it returns, the caller gets the
    count a new BLAS has (bug hunt 10A F1), and the process's environment is left as it was.
    """
    out = tmp_path / "out.mcap"
    code = (
        "import importlib.abc, os, sys, threading\n"
        "first = {}\n"
        "class Spy(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'scipy':\n"
        "            first.setdefault('scipy', threading.current_thread().name)\n"
        "        return None\n"
        "sys.meta_path.insert(0, Spy())\n"
        "from pcainterp_stream.cli.app import main\n"
        "from pcainterp_stream.pipeline import blas_threads as job\n"
        "from threadpoolctl import threadpool_info\n"
        "def counts(lib):\n"
        "    return [i['num_threads'] for i in threadpool_info() if lib in i['filepath']]\n"
        "during = []\n"
        "leave = job.BlasThreads.leave\n"
        "def spy():\n"
        "    during.extend(counts('scipy.libs'))\n"
        "    leave()\n"
        "job.BlasThreads.leave = staticmethod(spy)\n"
        f"code = main(['densify', {str(LOG)!r}, '-o', {str(out)!r}])\n"
        "assert code == 0, code\n"
        "import json\n"
        "print(json.dumps([first.get('scipy'), during, counts('scipy.libs'),"
        " counts('numpy.libs'),"
        " os.environ.get('OPENBLAS_NUM_THREADS'),"
        " [m for m in ('scipy.linalg', 'scipy.spatial') if m in sys.modules]]))\n"
    )
    # as a shell starts it: dask.distributed, imported by other tests, sets the variable
    environment = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
        env=environment,
    )
    thread, blas_threads, after, numpy_after, variable, packages = json.loads(
        result.stdout.strip().splitlines()[-1]
    )
    # the densify thread's set-up loads it, or a stereo worker making a check frame's
    # held-out pixels gets there first on a loaded machine: never the main thread
    assert thread.startswith(("densify", "stereo")), thread
    assert blas_threads
    assert set(blas_threads) == {1}  # while the job ran
    assert set(after) == set(numpy_after)  # then the count a new BLAS has
    assert variable is None
    assert packages == []


def test_the_program_freezes_the_imports_for_the_collector_and_main_does_not(
    tmp_path: Path,
) -> None:
    """``pcainterp`` (its own process) freezes the garbage collector's view of the imports;
    :func:`cli.main` run inside a caller's program leaves the caller's collector alone."""
    out = tmp_path / "out.mcap"
    code = (
        "import gc, sys\n"
        "from pcainterp_stream.cli import app\n"
        f"sys.argv = ['pcainterp', 'densify', {str(LOG)!r}, '-o', {str(out)!r}]\n"
        "before = gc.get_freeze_count()\n"
        "assert app.main(sys.argv[1:]) == 0\n"
        "in_process = gc.get_freeze_count()\n"
        f"sys.argv[-1] = {str(tmp_path / 'again.mcap')!r}\n"
        "import atexit\n"  # the program ends in console(), after its exit handlers
        "atexit.register(lambda: print(before, in_process, gc.get_freeze_count()))\n"
        "app.console()\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    before, in_process, program = map(int, result.stdout.split()[-3:])
    # CPython 3.12.1 starts with a frozen collector view already (375 objects): relative
    assert in_process == before
    assert program > before


def test_the_command_imports_nothing_heavy_before_it_handles_signals() -> None:
    """``pcainterp``'s console script imports ``pcainterp_stream.cli`` before it runs: that
    import (and the package's) loads none of NumPy, OpenCV or the jobs, so a Ctrl-C during
    the ~0.4 s they take lands in :func:`cli.console`, which answers it in one line."""
    modules = _modules_after("import pcainterp_stream, pcainterp_stream.cli")
    assert _loaded(modules, ("numpy", "cv2", "scipy", "mcap", "rosbags")) == []
    assert "pcainterp_stream.cli.app" not in modules


def test_a_ctrl_c_while_the_command_starts_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import importlib

    from pcainterp_stream import cli

    def interrupted(name: str) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib, "import_module", interrupted)
    assert cli.console() == 130
    assert capsys.readouterr().err == (
        "pcainterp: interrupted while starting; nothing was read or written\n"
    )


def test_the_packages_names_load_on_first_use() -> None:
    import pcainterp_stream
    from pcainterp_stream import cli
    from pcainterp_stream.cli import app
    from pcainterp_stream.estimate import basis, estimator, prior

    assert pcainterp_stream.Basis is basis.Basis
    assert pcainterp_stream.densify is estimator.densify
    # what densify's local_prior=, temporal= and robust= take, beside densify itself
    assert pcainterp_stream.LocalPrior is prior.LocalPrior
    assert pcainterp_stream.TemporalPrior is prior.TemporalPrior
    assert pcainterp_stream.Robust is prior.Robust
    assert {"LocalPrior", "Robust", "TemporalPrior"} <= set(pcainterp_stream.__all__)
    assert cli.main is app.main
    assert cli.COMMANDS is app.COMMANDS
    assert set(pcainterp_stream.__all__) <= set(dir(pcainterp_stream))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pcainterp_stream.nope  # noqa: B018
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        cli.nope  # noqa: B018
