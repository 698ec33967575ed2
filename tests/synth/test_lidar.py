"""The sparse LiDAR-like truth: only with the option, a few % of the pixels, equal to the depth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream import cli
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.records import SynthFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.lidar import LIDAR_DEPTH, LidarConfig, lidar_depth
from pcainterp_stream.synth.log import DEPTH, POSE, frame_messages, write_synthetic_log


@pytest.fixture(scope="module")
def frames() -> dict[float, list[SynthFrame]]:
    return {
        scale: list(generate(SynthConfig(seed=7, frames=2, scale=scale))) for scale in (0.25, 0.5)
    }


def _read(path: Path) -> dict[str, list[np.ndarray]]:
    images: dict[str, list[np.ndarray]] = {}
    with open_log(path) as reader:
        for raw in reader.messages([DEPTH, LIDAR_DEPTH]):
            message = reader.decode(raw)
            assert rosmsg.stamp_ns(message) == raw.log_time_ns
            assert (message.encoding, message.header.frame_id) == ("32FC1", "stereo_left_optical")
            images.setdefault(raw.topic, []).append(rosmsg.image_array(message))
    return images


@pytest.mark.parametrize("scale", [0.25, 0.5])
def test_a_few_percent_of_the_pixels_hold_the_true_depth(
    frames: dict[float, list[SynthFrame]], scale: float
) -> None:
    for frame in frames[scale]:
        sparse = lidar_depth(frame.depth, frame.camera, frame_index=frame.index)
        valid = np.isfinite(sparse)
        # ~3.9 % at every scale: the scan pattern follows the focal length
        assert 0.03 < valid.mean() < 0.05
        np.testing.assert_array_equal(sparse[valid], frame.depth[valid])
        assert not np.isfinite(sparse[np.isnan(frame.depth)]).any()  # no return from the sky
        # scan lines: a 64-beam scanner at full size has ~44 beams inside the image; at
        # scale F it is 64 F beams, a line every few rows, none above +2 deg
        rows = np.flatnonzero(valid.any(axis=1))
        camera = frame.camera
        widest = np.arctan(max(camera.cx + 0.5, camera.width - 0.5 - camera.cx) / camera.fx)
        top_line = camera.cy - camera.fy * np.tan(np.radians(2.0)) / np.cos(widest)
        assert rows.min() >= np.floor(top_line)
        assert 0.25 < rows.size / frame.camera.height < 0.75


def test_returns_beyond_the_range_are_dropped(frames: dict[float, list[SynthFrame]]) -> None:
    frame = frames[0.5][0]
    camera = frame.camera
    sparse = lidar_depth(
        frame.depth, camera, frame_index=0, config=LidarConfig(max_range_m=15.0, dropout=0.0)
    )
    rows, columns = np.nonzero(np.isfinite(sparse))
    ray = np.sqrt(
        ((columns - camera.cx) / camera.fx) ** 2 + ((rows - camera.cy) / camera.fy) ** 2 + 1
    )
    assert rows.size > 0
    assert np.all(sparse[rows, columns] * ray <= 15.0)
    full = lidar_depth(frame.depth, camera, frame_index=0, config=LidarConfig(dropout=0.0))
    assert np.isfinite(full).sum() > rows.size


def test_deterministic_from_the_seed(frames: dict[float, list[SynthFrame]]) -> None:
    frame = frames[0.25][1]
    first = lidar_depth(frame.depth, frame.camera, frame_index=1, config=LidarConfig(seed=3))
    again = lidar_depth(frame.depth, frame.camera, frame_index=1, config=LidarConfig(seed=3))
    other = lidar_depth(frame.depth, frame.camera, frame_index=1, config=LidarConfig(seed=4))
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(np.isfinite(first), np.isfinite(other))


def test_bad_options_and_shapes_are_refused(frames: dict[float, list[SynthFrame]]) -> None:
    with pytest.raises(ValueError, match="dropout must be in"):
        LidarConfig(dropout=1.0)
    with pytest.raises(ValueError, match="beams must be at least 2"):
        LidarConfig(beams=1)
    frame = frames[0.25][0]
    with pytest.raises(ValueError, match=r"Expected `depth` of shape \(94, 310\)"):
        lidar_depth(frame.depth[1:], frame.camera, frame_index=0)


def test_topic_only_with_the_option(frames: dict[float, list[SynthFrame]], tmp_path: Path) -> None:
    frame = frames[0.25][0]
    topics = [topic for topic, _ in frame_messages(frame, lidar=LidarConfig())]
    assert topics[-3:] == [DEPTH, LIDAR_DEPTH, POSE]
    assert LIDAR_DEPTH not in [topic for topic, _ in frame_messages(frame)]
    assert LIDAR_DEPTH not in [
        t for t, _ in frame_messages(frame, ground_truth=False, lidar=LidarConfig())
    ]

    plain = write_synthetic_log(frames[0.25], tmp_path / "plain.mcap")
    assert LIDAR_DEPTH not in plain.topic_counts
    with_lidar = write_synthetic_log(
        frames[0.25], tmp_path / "lidar.mcap", lidar=LidarConfig(seed=7)
    )
    assert with_lidar.topic_counts[LIDAR_DEPTH] == 2
    images = _read(tmp_path / "lidar.mcap")
    for depth, sparse, frame in zip(images[DEPTH], images[LIDAR_DEPTH], frames[0.25], strict=True):
        valid = np.isfinite(sparse)
        np.testing.assert_array_equal(sparse[valid], depth[valid])
        expected = lidar_depth(
            frame.depth, frame.camera, frame_index=frame.index, config=LidarConfig(seed=7)
        )
        np.testing.assert_array_equal(sparse, expected)


def test_cli_synth_lidar_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "drive.mcap"
    assert (
        cli.main(["synth", str(out), "--frames", "2", "--scale", "0.125", "--lidar", "--seed", "2"])
        == 0
    )
    assert "wrote" in capsys.readouterr().out
    images = _read(out)
    assert len(images[LIDAR_DEPTH]) == 2
    for depth, sparse in zip(images[DEPTH], images[LIDAR_DEPTH], strict=True):
        valid = np.isfinite(sparse)
        assert 0.02 < valid.mean() < 0.07
        np.testing.assert_array_equal(sparse[valid], depth[valid])
    assert cli.main(["synth", str(tmp_path / "bad.mcap"), "--frames", "0", "--lidar"]) == 2
    assert "--frames must be at least 1" in capsys.readouterr().err
    plain = tmp_path / "plain.mcap"
    assert cli.main(["synth", str(plain), "--frames", "1", "--scale", "0.125"]) == 0
    assert LIDAR_DEPTH not in _read(plain)
