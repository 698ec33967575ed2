"""The golden synthetic log: the committed file and a fresh render match its golden file."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from pcainterp_stream.golden import check_log, format_differences, load_golden, save_golden
from pcainterp_stream.golden.pytest_plugin import LogGolden
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

needs_golden = pytest.mark.skipif(
    not GOLDEN_JSON.is_file() or not GOLDEN_LOG.is_file(),
    reason="tests/data/golden_synth.* missing; run python tools/make_golden.py",
)


@needs_golden
def test_committed_log_matches_its_golden_file(log_golden: LogGolden) -> None:
    log_golden.check(GOLDEN_LOG, fullpath=GOLDEN_JSON)
    golden = load_golden(GOLDEN_JSON)
    assert GOLDEN_LOG.stat().st_size < 1_000_000
    assert {c["message_count"] for c in golden["channels"].values()} == {4}
    assert len(golden["channels"]) == 6


@needs_golden
def test_fresh_render_matches_the_golden_file(tmp_path: Path) -> None:
    fresh = tmp_path / "golden.mcap"
    tool.render_log(fresh)
    result = check_log(fresh, GOLDEN_JSON)
    assert result.passed, format_differences(result.differences)


# --- tolerances on a fabricated log (independent of the renderer) -----------------------

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


def _check(tmp_path: Path, golden: Path, frames: list[SynthFrame], name: str) -> list[str]:
    path = tmp_path / name
    write_synthetic_log(frames, path)
    return [str(d) for d in check_log(path, golden).differences]


def test_tolerances_accept_tiny_and_reject_real_differences(tmp_path: Path) -> None:
    frames = _frames()
    write_synthetic_log(frames, tmp_path / "a.mcap")
    golden = tmp_path / "a.golden.json"
    summary = save_golden(tmp_path / "a.mcap", golden)
    depth = summary.channels["/ground_truth/depth"]["messages"][0]
    assert depth["log_time_ns"] == depth["stamp_ns"] == 10**9
    assert depth["arrays"]["image"]["posinf"] == 5 * 40  # the sky, written +inf
    assert depth["arrays"]["image"]["mean"] == pytest.approx(float(np.nanmean(frames[0].depth)))

    nudged = list(frames)
    left = frames[0].left.copy()
    left[0, :3] = np.clip(left[0, :3].astype(int) + 1, 0, 255)  # 3 pixels one grey level up
    nudged[0] = frames[0]._replace(left=left, depth=frames[0].depth * np.float32(1 + 1e-6))
    assert _check(tmp_path, golden, nudged, "b.mcap") == []

    changed = list(frames)
    changed[1] = frames[1]._replace(depth=frames[1].depth * np.float32(1.05))
    problems = _check(tmp_path, golden, changed, "c.mcap")
    assert problems
    assert all(
        p.startswith("/ground_truth/depth #1 (stamp 1.100000000 s): image") for p in problems
    )

    late = [f._replace(stamp_ns=f.stamp_ns + 1) for f in frames]
    problems = _check(tmp_path, golden, late, "d.mcap")
    assert any("message missing from the log" in p for p in problems)
    assert any("with stamp 1.000000001 s not in the golden file" in p for p in problems)
