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
