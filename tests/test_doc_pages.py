"""Doc pages: their scripts and commands run as a user would run them, their references resolve."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_logreader_benchmark_script_runs_as_saved(tmp_path: Path) -> None:
    """docs/logreader_benchmarks.md's script, saved and run on a few frames.

    Its right image was the left one rolled 7 px the wrong way: the pair check refuses such
    a pair as swapped cameras, and the script stopped with a ``CalibrationError``.
    """
    page = (ROOT / "docs" / "logreader_benchmarks.md").read_text()
    script = page.split("\n## Script\n", 1)[1]
    match = re.search(r"```python\n(.*?)```", script, re.DOTALL)
    assert match, "docs/logreader_benchmarks.md has no script"
    saved = tmp_path / "bench_reader.py"
    saved.write_text(match.group(1))
    log = tmp_path / "bench.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for args in ([], ["read"]):  # write, then read; read only in a fresh process
        done = subprocess.run(
            [sys.executable, str(saved), "3", str(log), *args],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        assert "iter_stereo_frames: 3 frames" in done.stdout, done.stdout


def test_doc_commands_do_not_run_the_authors_checkout() -> None:
    """``PYTHONPATH=.`` from the checkout, never the authors' own one (``/work/main``)."""
    found = [
        f"{doc.name}: {hit}"
        for doc in DOCS
        for hit in re.findall(r"PYTHONPATH=[^\s`]+", doc.read_text())
        if hit.startswith("PYTHONPATH=/work/")
    ]
    assert not found, found


SECTION_REF = re.compile(r"(docs/([a-z_0-9]+)\.md|README)[,:]? (?:section )?\"([^\"]{3,80})\"")
"""A quoted section reference: ``docs/dense.md, "Today's answer"`` or ``README, "Python API"``."""
CHECKED_PAGES = ["README.md", *sorted(f"docs/{page.name}" for page in (ROOT / "docs").glob("*.md"))]
"""The README and every page of docs/."""


def _labels(page: Path) -> list[str]:
    """The headings and bold paragraph labels of a page, lower case (code blocks left out)."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    labels = re.findall(r"^#+\s+(.*)$", text, flags=re.MULTILINE)
    return [label.lower() for label in labels + re.findall(r"\*\*(.+?)\*\*", text)]


@pytest.mark.parametrize("name", CHECKED_PAGES)
def test_section_references_name_a_section(name: str) -> None:
    """``docs/X.md, "Section"`` names a heading (or a bold label) of X, as written."""
    text = re.sub(r"\s+", " ", (ROOT / name).read_text())
    missing = []
    for match in SECTION_REF.finditer(text):
        target = ROOT / (f"docs/{match.group(2)}.md" if match.group(2) else "README.md")
        wanted = match.group(3).lower()
        if not target.is_file() or not any(wanted in label for label in _labels(target)):
            missing.append(match.group(0))
    assert not missing, f"{name}: no such section: {missing}"
