"""Dense mode against real ground truth: ``tools/dense_truth.py`` on KITTI's annotated frames."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
ANNOTATED = ROOT.parent / "shared" / "realdata" / "kitti_depth_annotated_07"


def _tool() -> ModuleType:
    import sys

    sys.path.insert(0, str(ROOT / "tools"))  # the tool imports its harness as tools/ does
    spec = importlib.util.spec_from_file_location("dense_truth", ROOT / "tools" / "dense_truth.py")
    assert spec is not None
    assert spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    sys.modules["dense_truth"] = tool  # its dataclasses look their module up
    spec.loader.exec_module(tool)
    return tool


def test_scores_split_at_the_holes() -> None:
    scores = _tool().Scores()
    truth = np.array([[1.0, 2.0, np.nan, 4.0]])
    estimate = np.array([[1.5, 2.0, 9.0, 8.0]], np.float32)
    std = np.array([[0.5, 0.1, 1.0, 1.0]], np.float32)
    valid = np.array([[True, True, True, False]])
    scores.add(estimate, std, truth, valid)
    assert scores.pixels == {"valid": 2.0, "holes": 1.0}
    assert scores.mean("valid") == pytest.approx(0.25)
    assert scores.mean("holes") == pytest.approx(4.0)
    assert scores.mean() == pytest.approx(4.5 / 3)
    assert scores.coverage("valid") == 1.0
    assert scores.coverage("holes") == 0.0
    assert scores.share_over3("holes") == 1.0


def test_a_folder_without_calibration_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"calib\.txt not found"):
        _tool().read_annotated(tmp_path)


@pytest.mark.skipif(
    not ANNOTATED.is_dir(), reason="../shared/realdata/kitti_depth_annotated_07 is absent"
)
def test_dense_mode_fills_sgbms_holes_on_real_truth(tmp_path: Path) -> None:
    """The three annotated frames: dense mode beats SGBM with nearest-filled holes."""
    tool = _tool()
    frames = tool.read_annotated(ANNOTATED)
    log = tmp_path / "annotated.mcap"
    tool.write_log(frames, log)
    results = tool.score(frames, {"dense": tool.run_job(log, tool.dense_config(), tmp_path)})
    dense, nearest, sgbm = results["dense"], results["sgbm_nn"], results["sgbm"]
    assert dense.mean("holes") <= 1.5  # 0.97 px measured (3.8 px nearest-filled)
    assert dense.mean("valid") <= sgbm.mean("valid") + 0.01
    assert dense.mean() <= 0.75 * nearest.mean()
    assert 0.9 <= dense.coverage("valid") <= 0.99
    assert dense.coverage("holes") >= 0.9
