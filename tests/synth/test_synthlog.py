from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logwriter import LogFormat
from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth.log import (
    DEPTH,
    LEFT_IMAGE,
    LEFT_INFO,
    POSE,
    RIGHT_IMAGE,
    RIGHT_INFO,
    frame_messages,
    write_synthetic_log,
)

CAMERA = StereoCamera(width=16, height=10, fx=20.0, fy=21.0, cx=7.5, cy=4.5, baseline=0.54)
T0 = 1_000_000_000


def _frames(n: int, seed: int = 0) -> list[SynthFrame]:
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        depth = rng.uniform(2.0, 80.0, size=CAMERA.image_size).astype(np.float32)
        depth[:3] = np.nan  # sky
        pose = np.eye(4)
        pose[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        pose[:3, 3] = [0.1 * i, 0.0, 1.5 * i]
        frames.append(
            SynthFrame(
                index=i,
                stamp_ns=T0 + i * 100_000_000,
                left=rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8),
                right=rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8),
                depth=depth,
                camera_to_world=pose,
                camera=CAMERA,
            )
        )
    return frames


TOPICS = [LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO, DEPTH, POSE]


@pytest.mark.parametrize("fmt", [LogFormat.MCAP, LogFormat.ROSBAG2, LogFormat.ROS1])
def test_written_log_reads_back(tmp_path: Path, fmt: LogFormat) -> None:
    frames = _frames(3)
    calls: list[tuple[int, int | None]] = []
    target = (
        tmp_path / {LogFormat.MCAP: "s.mcap", LogFormat.ROSBAG2: "s", LogFormat.ROS1: "s.bag"}[fmt]
    )
    summary = write_synthetic_log(
        iter(frames), target, format=fmt, progress=lambda d, t: calls.append((d, t)), total=3
    )
    assert calls == [(1, 3), (2, 3), (3, 3)]
    assert summary.message_count == 18
    assert summary.topic_counts == dict.fromkeys(TOPICS, 3)
    with AnyReader([target], default_typestore=rosmsg.TYPESTORE) as reader:
        read = [
            (c.topic, c.msgtype, t, reader.deserialize(d, c.msgtype))
            for c, t, d in reader.messages()
        ]
    assert len(read) == 18
    for topic, msgtype, log_time, message in read:
        frame = frames[(log_time - T0) // 100_000_000]
        assert rosmsg.stamp_ns(message) == log_time == frame.stamp_ns
        if topic == LEFT_IMAGE:
            assert (msgtype, message.encoding, message.header.frame_id) == (
                rosmsg.IMAGE,
                "mono8",
                "stereo_left_optical",
            )
            np.testing.assert_array_equal(rosmsg.image_array(message), frame.left)
        elif topic == RIGHT_IMAGE:
            assert message.header.frame_id == "stereo_right_optical"
            np.testing.assert_array_equal(rosmsg.image_array(message), frame.right)
        elif topic in (LEFT_INFO, RIGHT_INFO):
            p = rosmsg.projection_matrix(message)
            assert (p[0, 0], p[1, 1], p[0, 2], p[1, 2]) == (20.0, 21.0, 7.5, 4.5)
            expected_tx = -20.0 * 0.54 if topic == RIGHT_INFO else 0.0
            assert p[0, 3] == pytest.approx(expected_tx)
            assert (message.width, message.height) == (16, 10)
        elif topic == DEPTH:
            assert message.encoding == "32FC1"
            # the sky, NaN in the frame, is written +inf (REP 118: too far; NaN is no value)
            expected = np.where(np.isnan(frame.depth), np.inf, frame.depth)
            np.testing.assert_array_equal(rosmsg.image_array(message), expected)
        else:
            assert (topic, msgtype, message.header.frame_id) == (POSE, rosmsg.POSE_STAMPED, "world")
            np.testing.assert_allclose(
                rosmsg.pose_matrix(message), frame.camera_to_world, atol=1e-12
            )


def test_mcap_topics_in_frame_order_and_decodable(tmp_path: Path) -> None:
    target = tmp_path / "s.mcap"
    write_synthetic_log(_frames(2), target)
    with target.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        items = list(reader.iter_decoded_messages(log_time_order=False))
    assert [i.channel.topic for i in items] == TOPICS * 2
    assert {i.schema.name for i in items} == {rosmsg.IMAGE, rosmsg.CAMERA_INFO, rosmsg.POSE_STAMPED}
    depth = items[4].decoded_message
    values = np.frombuffer(bytes(depth.data), dtype="<f4").reshape(10, 16)
    assert np.isposinf(values[:3]).all()  # the sky: too far (REP 118)
    assert np.isfinite(values[3:]).all()


def test_frame_messages_without_ground_truth() -> None:
    topics = [t for t, _ in frame_messages(_frames(1)[0], ground_truth=False)]
    assert topics == TOPICS[:4]


def test_shape_mismatch_is_refused_and_nothing_written(tmp_path: Path) -> None:
    frame = _frames(1)[0]
    bad = frame._replace(left=frame.left[:, :-1])
    with pytest.raises(ValueError, match=r"Expected `left` to be uint8 of shape \(10, 16\)"):
        write_synthetic_log([frame, bad], tmp_path / "s.mcap")
    bad_depth = frame._replace(depth=frame.depth[:-1])
    with pytest.raises(ValueError, match=r"Expected `depth` of frame 0 to have shape \(10, 16\)"):
        write_synthetic_log([bad_depth], tmp_path / "s.mcap")
    assert list(tmp_path.iterdir()) == []


def test_renderer_frames_write_and_read_back(tmp_path: Path) -> None:
    synth = pytest.importorskip("pcainterp_stream.synth", reason="synthetic renderer missing")
    config = synth.SynthConfig(seed=1, frames=2, scale=0.125)
    frames = list(synth.generate(config))
    target = tmp_path / "render.bag"
    summary = write_synthetic_log(iter(frames), target)
    assert summary.topic_counts == dict.fromkeys(TOPICS, 2)
    with AnyReader([target]) as reader:
        depths = [
            rosmsg.image_array(reader.deserialize(d, c.msgtype))
            for c, _, d in reader.messages()
            if c.topic == DEPTH
        ]
    np.testing.assert_array_equal(
        depths[1], np.where(np.isnan(frames[1].depth), np.inf, frames[1].depth)
    )
