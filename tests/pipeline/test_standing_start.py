"""``tools/standing_start.py``: a camera that stands, then drives; densify scored on the truth."""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from pcainterp_stream import synth

ROOT = Path(__file__).resolve().parents[2]


def _tool(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "tools"))  # it imports its harness as tools/ does
    return importlib.import_module("standing_start")


def test_the_camera_stands_then_drives_on(monkeypatch: pytest.MonkeyPatch) -> None:
    tool = _tool(monkeypatch)
    config = synth.SynthConfig(seed=tool.SEED, frames=6, scale=tool.SCALE)
    world = synth.World(tool.SEED)
    pose = tool.standing_pose(3)
    standing = [pose(world, config, index) for index in range(3)]
    assert all(np.array_equal(standing[0], other) for other in standing[1:])
    for index in (3, 4):  # the drive from its frame 1 on
        assert np.array_equal(
            pose(world, config, index), synth.camera_pose(world, config, index - 2)
        )


def test_a_densified_standing_log_is_scored_on_every_frame(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    tool = _tool(monkeypatch)
    log = tmp_path / "standing.mcap"
    tool.build_log(log, 2, 1)
    cells, lines = tool.densify(log, tmp_path / "out.mcap", ("--basis", "builtin-street"))
    frames, rmse, mean, inside = cells
    assert frames == "3"
    assert 0.0 < float(mean) <= float(rmse)
    assert 0.0 < float(inside.removesuffix(" %")) <= 100.0
    assert lines[0].startswith("prior: the built-in street basis")
