"""Every script in ``tools/`` answers ``--help`` and is named in the docs.

The scripts make the figures the docs quote (benchmarks, experiments) or serve the
maintainers (golden files, the built-in basis, fuzzing); a script nobody can ask what it
does, or that no page names, is lost. ``--help`` must print the usage and a description
and exit 0 without doing any work; the modules of helpers the scripts import
(``harness``, ``beyond_data``, ``beyond_eval``) answer it too.
"""

from __future__ import annotations

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
