"""Every script in ``tools/`` answers ``--help`` and is named in the docs.

The scripts make the figures the docs quote (benchmarks, experiments) or serve the
maintainers (golden files, the built-in basis, fuzzing); a script nobody can ask what it
does, or that no page names, is lost. ``--help`` must print the usage and a description
and exit 0 without doing any work; the modules of helpers the scripts import
(``harness``, ``beyond_data``, ``beyond_eval``) answer it too. And the fuzzer
(``fuzz_readers.py``) gets coverage of the read path: its readers are instrumented.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOLS = sorted((ROOT / "tools").glob("*.py"))
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_there_are_tools() -> None:
    assert len(TOOLS) >= 10, TOOLS


@pytest.mark.parametrize("script", TOOLS, ids=[path.stem for path in TOOLS])
def test_tool_answers_help(script: Path, tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(script), "--help"],
        cwd=tmp_path,  # nothing may be written: the folder stays empty
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: {script.name}"), done.stdout[:200]
    description = done.stdout.split("\n\n")[1]
    assert not description.startswith(("positional arguments", "options")), "no description"
    assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("script", TOOLS, ids=[path.stem for path in TOOLS])
def test_tool_is_named_in_the_docs(script: Path) -> None:
    named = [doc.name for doc in DOCS if script.name in doc.read_text()]
    assert named, f"name tools/{script.name} in the doc that quotes or needs it"


MEASUREMENT_CALLS = {
    "pcainterp_stream": {"densify_batch"},
    "pcainterp_stream.estimate.estimator": {"densify", "densify_batch", "clean_measurements"},
    "pcainterp_stream.estimate.baselines": {"nearest", "linear"},
}
"""The library's functions that drop a disparity of exactly 0 unless ``zero_is_match``."""
NOT_SGBM = {"bench_estimator.py": "times the estimator on noisy samples of a synthetic truth"}
"""Tools whose measurements are no SGBM lookups (an exact 0 is no match there)."""


def _unmatched_zero_calls(source: str) -> list[int]:
    """Lines calling a :data:`MEASUREMENT_CALLS` function without zero_is_match or **options."""
    import ast

    tree = ast.parse(source)
    names = {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
        if alias.name in MEASUREMENT_CALLS.get(node.module or "", set())
    }
    names |= {
        f"baselines.{name}" for name in MEASUREMENT_CALLS["pcainterp_stream.estimate.baselines"]
    }
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        called = ast.unparse(node.func)
        if called == "partial" and node.args:  # partial(nearest, ..., zero_is_match=True)
            called = ast.unparse(node.args[0])
        keywords = {keyword.arg for keyword in node.keywords}
        if called in names and "zero_is_match" not in keywords and None not in keywords:
            lines.append(node.lineno)
    return lines


@pytest.mark.parametrize("script", TOOLS, ids=[path.stem for path in TOOLS])
def test_tools_take_sgbms_zero_as_a_match_as_densify_does(script: Path) -> None:
    """A tool measuring what densify does passes ``zero_is_match=True`` (the CLI's path)."""
    if script.name in NOT_SGBM:
        return
    lines = _unmatched_zero_calls(script.read_text())
    assert not lines, f"tools/{script.name}:{lines}: pass zero_is_match=True, as densify does"


# --- tools/fuzz_readers.py: libFuzzer gets coverage of the read path ----------------------

_FUZZ_WORKER = """
import json, sys
from pathlib import Path

sys.path.insert(0, sys.argv[1])
import atheris
import fuzz_readers

atheris.Setup = lambda *args, **kwargs: None  # the worker up to libFuzzer, without fuzzing
atheris.Fuzz = lambda: None
if sys.argv[4] == "import first":
    import pcainterp_stream.errors
code = fuzz_readers.main(["--format", "mcap", "--address-space-mb", "0", sys.argv[2], "--worker"])
before = set(sys.modules)
if code == 0:
    fuzz_readers.read_everything(Path(sys.argv[3]))
from pcainterp_stream.cli import app
from pcainterp_stream.frontend.pairing import iter_stereo_frames
from pcainterp_stream.io.loginfo import describe
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.mcap_reader import McapLogReader
from pcainterp_stream.pipeline.jobs import info
from rosbags.rosbag1 import Reader

functions = [app.main, iter_stereo_frames, describe, open_log, McapLogReader.messages, info,
             Reader.open]
late = [name for name in set(sys.modules) - before
        if name.partition(".")[0] in ("pcainterp_stream", "rosbags", "mcap")]
print(json.dumps({
    "code": code,
    "blind": [f.__qualname__ for f in functions if "_trace_branch" not in f.__code__.co_names],
    "late": sorted(late),
}))
"""


def _fuzz_worker(tmp_path: Path, mode: str) -> tuple[dict[str, object], str]:
    pytest.importorskip("atheris", reason="atheris not installed: pip install -e '.[fuzz]'")
    import json
    import shutil

    seed = ROOT / "tests" / "data" / "golden_synth.mcap"
    out = tmp_path / "fuzz"
    (out / "corpus").mkdir(parents=True)
    shutil.copyfile(seed, out / "corpus" / "seed.mcap")  # no seed to write with synth
    done = subprocess.run(
        [sys.executable, "-c", _FUZZ_WORKER, str(ROOT / "tools"), str(out), str(seed), mode],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result, done.stderr


@pytest.mark.slow  # ~5 s: atheris instruments ~140 modules
def test_fuzz_readers_instruments_the_read_path(tmp_path: Path) -> None:
    """The fuzz worker imports the read path inside atheris' instrumentation block.

    Only modules first imported inside ``atheris.instrument_imports`` report coverage: from
    406c557 the block was empty and libFuzzer fuzzed blind (no ``cov:``, the corpus never
    grew). Here the worker runs up to libFuzzer's start; then the readers' functions must
    carry atheris' branch tracing, and reading a log must import no module of the read path
    afterwards (it would run uninstrumented).
    """
    result, stderr = _fuzz_worker(tmp_path, "fresh")
    assert result["code"] == 0, stderr[-3000:]
    assert result["blind"] == [], f"uninstrumented {result['blind']}: see instrument_read_path"
    assert result["late"] == [], f"imported after instrumenting {result['late']}"


def test_fuzz_readers_refuses_modules_imported_before_instrumenting(tmp_path: Path) -> None:
    """A read-path module imported before the block would run blind: the worker says so."""
    result, stderr = _fuzz_worker(tmp_path, "import first")
    assert result["code"] == 2
    message = [line for line in stderr.splitlines() if line.startswith("fuzz_readers:")]
    assert message, stderr[-3000:]
    assert "pcainterp_stream.errors" in message[0]
    assert "Traceback" not in stderr


def test_sgbm_alone_pairs_what_densify_pairs(tmp_path: Path) -> None:
    """Bug hunt 9C F7: the SGBM-alone reference read only /stereo/{left,right}/image_rect:
    a raw (``image_raw``) or CompressedImage log was "0 pairs matched", rc 0, in 0.7 s, a
    reference time of nothing. It now finds the pair as densify does, and 0 pairs fail."""
    from pcainterp_stream.pipeline.jobs import synth_raw

    log = tmp_path / "raw.mcap"
    synth_raw(log, frames=3, seed=0, scale=0.25, fmt=None, model="plumb_bob")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tools")])}

    def sgbm_alone(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, str(ROOT / "tools" / "sgbm_alone.py"), *args],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )

    done = sgbm_alone(str(log))
    assert (done.returncode, done.stdout) == (0, "3 pairs matched\n"), done.stderr
    done = sgbm_alone(str(log), "--left-topic", "/camera/right/image_raw")
    assert done.returncode != 0
    assert done.stdout == ""
    assert done.stderr.startswith("error: ")
    assert len(done.stderr.splitlines()) == 1
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import bench_before_after
    finally:
        sys.path.remove(str(ROOT / "tools"))
    assert bench_before_after.frame_count(log) == 3


def test_sparse_sharpness_depth_rmse_is_evaluates() -> None:
    """Bug hunt 15D F6: the tool capped truth beyond 80 m at 80 m and counted it (2.249 m on
    the KITTI LiDAR frames) where evaluate leaves it out (2.240 m, the figure the docs quote
    beside the tool's command)."""
    import numpy as np

    from pcainterp_stream.evaluate.metrics import depth_errors
    from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
    from pcainterp_stream.synth import SynthConfig, generate

    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import sparse_sharpness
    finally:
        sys.path.remove(str(ROOT / "tools"))
    items = []
    for item in generate(SynthConfig(seed=3, frames=2, scale=0.25)):
        fb = item.camera.focal_baseline
        with np.errstate(divide="ignore", invalid="ignore"):
            truth = (fb / item.depth).astype(np.float32)
        truth[: truth.shape[0] // 3] = fb / 200.0  # truth 200 m away: beyond the 80 m cap
        frame = sparse_sharpness._frame(
            item.index, item.stamp_ns, item.left, item.right, item.camera
        )
        items.append((frame, truth))
    figures = sparse_sharpness.score(items, ProcessorConfig())
    with FrameProcessor(None, ProcessorConfig()) as processor:
        results = list(processor.process([frame for frame, _ in items]))
    squares = count = 0.0
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        sums = depth_errors(
            result.disparity, truth, valid, focal_baseline=frame.camera.focal_baseline
        )
        squares, count = squares + sums["sq"], count + sums["n"]
    assert 0 < count
    assert figures["depth_rmse_m"] == float(np.sqrt(squares / count))
    # review 15d R7: the --depth-bins RMSE is depth_errors over each bin's pixels too (the
    # tool kept its own copy of the rule beside the call)
    edges = sparse_sharpness.DEPTH_BINS_M
    for low, high in itertools.pairwise(edges):
        squares = count = 0.0
        for (frame, truth), result in zip(items, results, strict=True):
            valid = np.isfinite(truth) & (truth > 0)
            with np.errstate(divide="ignore"):
                depth = np.minimum(frame.camera.focal_baseline / truth, edges[-1])
            inside = valid & (depth >= low) & ((depth < high) | (high == edges[-1]))
            sums = depth_errors(
                result.disparity, truth, inside, focal_baseline=frame.camera.focal_baseline
            )
            squares, count = squares + sums["sq"], count + sums["n"]
        expected = float(np.sqrt(squares / max(count, 1.0)))
        assert figures[f"depth_rmse_m_{low:g}-{high:g}m"] == pytest.approx(expected, rel=1e-9)
