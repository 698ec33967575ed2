"""Synthetic indoor scenes and other cameras (synth/indoor.py), densified with no options."""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream.estimate import baselines
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.indoor import (
    CAMERAS,
    PLATFORMS,
    Platform,
    SceneKind,
    camera_options,
    make_scene,
    make_trajectory,
    scene_for,
)


@pytest.mark.parametrize("kind", list(SceneKind))
def test_every_scene_is_closed_and_keeps_the_camera_out_of_its_boxes(kind: SceneKind) -> None:
    config = SynthConfig(
        seed=2, frames=3, scale=0.25, scene=kind.value, **camera_options("752x480")
    )
    frames = list(generate(config))
    assert len(frames) == 3
    scene = make_scene(2, kind)
    for frame in frames:
        assert frame.left.shape == (120, 188)
        assert np.isfinite(frame.depth).all()  # a closed room: every ray hits a surface
        assert frame.depth.min() > 0.1
        position = frame.camera_to_world[:3, 3]
        assert np.all(position > 0)
        assert np.all(position < np.asarray(scene.size))
        inside = np.all(
            (position >= scene.clutter.lower) & (position <= scene.clutter.upper), axis=1
        )
        assert not inside.any()
    assert frames[1].stamp_ns - frames[0].stamp_ns == 50_000_000  # 20 Hz


def test_indoor_frames_are_deterministic_and_platforms_set_height_and_pitch() -> None:
    config = SynthConfig(seed=5, frames=2, scale=0.2, scene="indoor", platform="robot")
    first, second = list(generate(config)), list(generate(config))
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a.left, b.left)
        np.testing.assert_array_equal(a.depth, b.depth)
    scene = make_scene(5, scene_for("indoor", 5))
    (low, high), (pitch_low, pitch_high) = PLATFORMS[Platform.ROBOT]
    trajectory = make_trajectory(5, scene, Platform.ROBOT)
    assert low <= trajectory.height <= high
    assert pitch_low <= trajectory.pitch_deg <= pitch_high
    with pytest.raises(ValueError, match="scene must be one of"):
        SynthConfig(scene="forest")
    with pytest.raises(ValueError, match="unknown camera"):
        camera_options("potato")
    assert camera_options("kitti")["fx"] == SynthConfig().fx  # the street default unchanged
    assert set(CAMERAS) >= {"kitti", "752x480"}


def test_indoor_log_picks_the_indoor_basis_and_beats_linear_against_the_truth() -> None:
    """The built-in street basis does not fit an indoor camera; the fit check picks the
    built-in indoor basis (a basis learned from the log's own maps does not do better
    enough to replace it) and wins.

    Scored against the true disparity right of the stereo matcher's left margin (where no
    method has a measurement and every one extrapolates the same way).
    """
    config = SynthConfig(seed=4, frames=10, scale=0.5, scene="indoor", **camera_options("752x480"))
    synth = list(generate(config))
    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in synth
    ]
    processor = ProcessorConfig()
    margin = processor.sgbm.valid_min_x
    errors: dict[str, list[float]] = {"prior": [], "linear": [], "nearest": []}
    with FrameProcessor(None, processor) as engine:
        for result, truth_frame in zip(engine.process(frames), synth, strict=True):
            camera = truth_frame.camera
            truth = camera.focal_baseline / truth_frame.depth
            size = camera.image_size
            estimates = {
                "prior": result.disparity,
                "linear": baselines.linear(
                    result.pixels, result.disparities, image_size=size
                ).disparity,
                "nearest": baselines.nearest(
                    result.pixels, result.disparities, image_size=size
                ).disparity,
            }
            for name, estimate in estimates.items():
                errors[name].append(float(np.abs(estimate - truth)[:, margin:].mean()))
        assert engine.adaptation.switched is not None
        assert engine.adaptation.switched.basis is Basis.indoor()
        assert engine.basis is Basis.indoor()
        assert not engine.adaptation.adapted  # the log's own basis did no better
    prior, linear = np.mean(errors["prior"]), np.mean(errors["linear"])
    assert prior < linear
    assert prior < np.mean(errors["nearest"])
