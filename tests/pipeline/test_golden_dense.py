"""Golden densify: the committed tiny log densified with the committed basis matches."""

from __future__ import annotations

import json
from pathlib import Path

from pcainterp_stream.golden import compare, load_golden
from pcainterp_stream.golden.pytest_plugin import LogGolden
from pcainterp_stream.pipeline.jobs import densify

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"


def test_densified_golden_log_matches_its_golden_file(
    tmp_path: Path, log_golden: LogGolden
) -> None:
    out = tmp_path / "dense.mcap"
    summary = densify(DATA / "golden_synth.mcap", out, DATA / "golden_basis.npz")
    assert summary.frames == 4
    log_golden.check(out, fullpath=DATA / "golden_dense.json")
    topics = set(load_golden(DATA / "golden_dense.json")["channels"])
    assert {"/pcainterp/depth", "/pcainterp/disparity", "/stereo/left/image_rect"} <= topics


def test_golden_comparison_catches_a_changed_depth() -> None:
    golden = load_golden(DATA / "golden_dense.json")
    changed = json.loads(json.dumps(golden))
    changed["channels"]["/pcainterp/depth"]["messages"][1]["arrays"]["image"]["median"] *= 1.05
    differences = compare(golden, changed)
    assert [(d.topic, d.index, d.what) for d in differences] == [
        ("/pcainterp/depth", 1, "image median")
    ]
