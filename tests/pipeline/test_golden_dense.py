"""Golden densify: the committed tiny log densified with the committed basis matches the JSON."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path
from types import ModuleType

from pcainterp_stream.pipeline.jobs import densify

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"


def _load_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_golden", ROOT / "tools" / "make_golden.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


tool = _load_tool()


def test_densified_golden_log_matches_expected_summary(tmp_path: Path) -> None:
    expected = json.loads((DATA / "golden_dense.json").read_text())
    out = tmp_path / "dense.mcap"
    summary = densify(DATA / "golden_synth.mcap", out, DATA / "golden_basis.npz")
    assert summary.frames == 4
    actual = tool.summarize_log(out)
    assert tool.compare_summary(expected, actual) == []
    topics = {channel["topic"] for channel in actual["channels"]}
    assert {"/pcainterp/depth", "/pcainterp/disparity_std", "/stereo/left/image_rect"} <= topics


def test_golden_comparison_catches_a_changed_depth() -> None:
    expected = json.loads((DATA / "golden_dense.json").read_text())
    changed = copy.deepcopy(expected)
    index = next(
        i for i, m in enumerate(changed["messages"]) if m["topic"] == "/pcainterp/depth"
    )
    changed["messages"][index]["image"]["mean"] *= 1.05
    problems = tool.compare_summary(expected, changed)
    assert problems
    assert "/pcainterp/depth" in problems[0]
