"""densify on a blank right image, a stale right image, and a scene beyond SGBM's range.

Bug hunt 8C: a black right image gave lookups of disparity 0 ("far", depth 5.4x off) and a
stale one (the previous frame's, under a new stamp) wrong depth, both without a warning; a
wall nearer than SGBM's range got the advice to learn a basis, not ``--num-disparities``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.frontend.frame_checks import BeyondRange
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import image_of
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.records import DensifiedFrame

RIGHT = "/stereo/right/image_rect"
FRAMES = 4


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "small.mcap"
    synth(path, frames=FRAMES, seed=3, scale=0.25, fmt="mcap")
    return path


def _rewritten(source: Path, target: Path, black: int, stale: int) -> Path:
    """The log with pair ``black``'s right image all 0, pair ``stale``'s the one before it."""
    rights: list[Any] = []
    with open_log(source) as reader, open_writer(target, "mcap") as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic == RIGHT:
                image = rosmsg.image_array(message)
                if len(rights) == black:
                    image = np.zeros_like(image)
                elif len(rights) == stale:
                    image = rights[-1]
                rights.append(image)
                stamp = rosmsg.stamp_ns(message)
                message = rosmsg.image_message(image, stamp, message.header.frame_id)
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


def _depths(path: Path) -> list[Any]:
    with open_log(path) as reader:
        return [image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])]


def test_a_black_and_a_stale_right_image_are_warned_of_and_not_estimated(
    log: Path, tmp_path: Path
) -> None:
    changed = _rewritten(log, tmp_path / "changed.mcap", black=1, stale=3)
    out = tmp_path / "out.mcap"
    summary = densify(changed, out)
    assert f"1 of {FRAMES} frames had no measurement (blank, dark or textureless images)" in (
        " ".join(summary.warnings)
    )
    stale = [line for line in summary.warnings if "stale right image" in line]
    assert len(stale) == 1, summary.warnings
    assert stale[0].startswith(f"1 of {FRAMES} frames had a stale right image")
    assert "their depth is NaN" in stale[0]
    depths = _depths(out)
    assert [bool(np.isnan(depth).all()) for depth in depths] == [False, True, False, True]
    assert all(np.isfinite(depths[k]).mean() > 0.5 for k in (0, 2))
    # the untouched log: neither warning
    plain = densify(log, tmp_path / "plain.mcap")
    assert not [line for line in plain.warnings if "stale" in line or "no measurement" in line]


def test_dense_mode_writes_a_black_or_stale_right_image_s_frame_all_nan(
    log: Path, tmp_path: Path
) -> None:
    # dense mode wrote such a frame as the prior's mean (22 % depth error), with no warning
    # for the black image and a false "the others only the points carried" for the stale
    # one (review 56b R1)
    changed = _rewritten(log, tmp_path / "changed.mcap", black=1, stale=3)
    out = tmp_path / "dense.mcap"
    summary = densify(changed, out, processor=ProcessorConfig(measurements="dense"))
    assert f"1 of {FRAMES} frames had no measurement (blank, dark or textureless images)" in (
        " ".join(summary.warnings)
    )
    (stale,) = [line for line in summary.warnings if "stale right image" in line]
    assert stale.endswith(
        "such a pair is not matched: those frames have no estimate, their depth is NaN"
    )
    depths = _depths(out)
    assert [bool(np.isnan(depth).all()) for depth in depths] == [False, True, False, True]
    assert all(np.isfinite(depths[k]).mean() > 0.9 for k in (0, 2))


def _near_frame(kept: int, added: int, dropped: int, values: Any) -> DensifiedFrame:
    frame = type("Frame", (), {"left": np.zeros((188, 620), np.uint8)})()
    counts = {"kept": kept, "near_added": added, "near_dropped": dropped}
    disparities = np.asarray(values, np.float32)
    none = np.zeros(0, np.float32)
    return DensifiedFrame(frame, none, disparities, none, none, none, none, "stereo", counts)  # type: ignore[arg-type]


def test_frames_measured_mostly_beyond_the_range_name_a_range_that_covers_them() -> None:
    # wallD150 of bug hunt 8C: 7-26 lookups kept, 153 near points at ~150 px
    beyond = BeyondRange(128.0, 32)
    beyond.result(_near_frame(16, 153, 11, [40.0] * 5 + [150.0] * 150 + [151.0] * 3))
    beyond.result(_near_frame(300, 20, 0, [130.0] * 20 + [20.0] * 300))  # a near truck: fine
    assert beyond.frames == 1
    (line,) = beyond.warnings(2, SgbmConfig(num_disparities=128, downscale=2))
    assert line.startswith("1 of 2 frames were measured mostly beyond SGBM's 128 px")
    assert "--num-disparities 192 " in line  # 151 / 0.875 = 173, up to a multiple of 32
    narrow = BeyondRange(128.0, 32)
    frame = _near_frame(16, 153, 11, [150.0] * 160)
    narrow.result(frame._replace(frame=type("F", (), {"left": np.zeros((94, 150), np.uint8)})()))
    (line,) = narrow.warnings(1, SgbmConfig(num_disparities=128, downscale=2))
    assert "does not fit images 150 px wide" in line
    assert BeyondRange(128.0, 32).warnings(3, SgbmConfig()) == []
