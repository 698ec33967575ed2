"""``tools/sgbm_span.py`` sees every SGBM call of a program it runs, and when it ended."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]

PROGRAM = """
import numpy as np
from pcainterp_stream.frontend import stereo
rng = np.random.default_rng(0)
left = rng.integers(0, 255, (48, 200), dtype=np.uint8)
right = np.roll(left, -5, axis=1)
matcher = stereo._Checked(stereo.SgbmConfig())
for _ in range(3):
    matcher.compute(left, right)
"""


def _tool(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "tools"))  # it imports its harness as tools/ does
    spec = importlib.util.spec_from_file_location("sgbm_span", ROOT / "tools" / "sgbm_span.py")
    assert spec is not None
    assert spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_the_hook_times_every_sgbm_call(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    tool = _tool(monkeypatch)
    (tmp_path / "sitecustomize.py").write_text(tool.SITECUSTOMIZE)
    path = [str(tmp_path), str(ROOT), os.environ.get("PYTHONPATH", "")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p)}
    span = tool.run([sys.executable, "-c", PROGRAM], env, tmp_path / "span.json")
    assert span["calls"] == 3
    assert 0 < span["first"] < span["last"] < span["exit"]
    assert span["middle cores"] >= 0


def test_a_program_without_sgbm_is_an_error(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    tool = _tool(monkeypatch)
    (tmp_path / "sitecustomize.py").write_text(tool.SITECUSTOMIZE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    with pytest.raises(SystemExit, match="made no SGBM call"):
        tool.run([sys.executable, "-c", "import pcainterp_stream"], env, tmp_path / "s.json")
