"""The golden synthetic log: the committed file and a fresh render match the expected JSON."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth.log import write_synthetic_log

ROOT = Path(__file__).resolve().parents[2]
GOLDEN_LOG = ROOT / "tests" / "data" / "golden_synth.mcap"
GOLDEN_JSON = ROOT / "tests" / "data" / "golden_synth.json"


def _load_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_golden", ROOT / "tools" / "make_golden.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


tool = _load_tool()


def _renderer_available() -> bool:
    try:
        from pcainterp_stream.synth import SynthConfig, generate  # noqa: F401
    except ImportError:
        return False
    return True


needs_golden = pytest.mark.skipif(
    not GOLDEN_JSON.is_file() or not GOLDEN_LOG.is_file(),
    reason="tests/data/golden_synth.* missing; run python tools/make_golden.py",
)


@needs_golden
def test_committed_log_matches_json() -> None:
    expected = json.loads(GOLDEN_JSON.read_text())
    assert expected["format"] == "pcainterp-golden/1"
    assert GOLDEN_LOG.stat().st_size < 1_000_000
    actual = tool.summarize_log(GOLDEN_LOG)
    assert tool.compare_summary(expected, actual) == []
    frames = expected["generator"]["frames"]
    assert {c["message_count"] for c in expected["channels"]} == {frames}
    assert len(expected["channels"]) == 6


@needs_golden
@pytest.mark.skipif(not _renderer_available(), reason="pcainterp_stream.synth not available")
def test_fresh_render_matches_json(tmp_path: Path) -> None:
    expected = json.loads(GOLDEN_JSON.read_text())
    actual = tool.render_golden(tmp_path / "golden.mcap", **expected["generator"])
    assert tool.compare_summary(expected, actual) == []


# --- the comparison itself, on a fabricated log (independent of the renderer) -----------

CAMERA = StereoCamera(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5, baseline=0.5)


def _frames() -> list[SynthFrame]:
    rng = np.random.default_rng(0)
    frames = []
    for i in range(2):
        depth = rng.uniform(3.0, 60.0, size=CAMERA.image_size).astype(np.float32)
        depth[:5] = np.nan
        frames.append(
            SynthFrame(
                index=i,
                stamp_ns=10**9 + i * 10**8,
                left=rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8),
                right=rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8),
                depth=depth,
                camera_to_world=np.eye(4),
                camera=CAMERA,
            )
        )
    return frames


def _summary(path: Path, frames: list[SynthFrame]) -> dict[str, Any]:
    write_synthetic_log(frames, path)
    return {"tolerance": tool.TOLERANCE, **tool.summarize_log(path)}


def test_summary_records_times_stamps_and_statistics(tmp_path: Path) -> None:
    frames = _frames()
    summary = _summary(tmp_path / "a.mcap", frames)
    assert summary["profile"] == "ros2"
    assert [c["topic"] for c in summary["channels"]][:2] == [
        "/stereo/left/image_rect",
        "/stereo/right/image_rect",
    ]
    depth = summary["messages"][4]
    assert depth["topic"] == "/ground_truth/depth"
    assert depth["log_time_ns"] == depth["stamp_ns"] == 10**9
    assert depth["image"]["nan_count"] == 5 * 40
    assert depth["image"]["mean"] == pytest.approx(float(np.nanmean(frames[0].depth)), rel=1e-9)
    json.dumps(summary)  # serialisable


def test_compare_accepts_tiny_and_rejects_real_differences(tmp_path: Path) -> None:
    frames = _frames()
    expected = _summary(tmp_path / "a.mcap", frames)
    assert tool.compare_summary(expected, expected) == []

    nudged = list(frames)
    left = frames[0].left.copy()
    left[0, :3] = np.clip(left[0, :3].astype(int) + 1, 0, 255)  # 3 pixels one grey level up
    depth = frames[0].depth * np.float32(1 + 1e-6)  # float noise
    nudged[0] = frames[0]._replace(left=left, depth=depth)
    assert tool.compare_summary(expected, _summary(tmp_path / "b.mcap", nudged)) == []

    changed = list(frames)
    changed[1] = frames[1]._replace(depth=frames[1].depth * np.float32(1.05))
    problems = tool.compare_summary(expected, _summary(tmp_path / "c.mcap", changed))
    assert problems
    assert all("message 10 (/ground_truth/depth)" in p for p in problems)

    late = [f._replace(stamp_ns=f.stamp_ns + 1) for f in frames]
    problems = tool.compare_summary(expected, _summary(tmp_path / "d.mcap", late))
    assert any("log_time_ns" in p for p in problems)

    fewer = copy.deepcopy(expected)
    fewer["messages"].pop()
    assert tool.compare_summary(fewer, expected) == ["12 messages, expected 11"]
