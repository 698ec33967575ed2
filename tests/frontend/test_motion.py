"""Ego-motion and carried measurements (motion.py)."""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream.frontend.motion import (
    CarriedPoints,
    CarryConfig,
    Motion,
    back_project,
    estimate_motion,
    project,
)
from pcainterp_stream.frontend.stereo import StereoFrontEnd
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth import SynthConfig, generate

CAMERA = StereoCamera(width=200, height=100, fx=150.0, fy=150.0, cx=99.5, cy=49.5, baseline=0.5)


def _forward(metres: float) -> Motion:
    """The camera moves forward: points come nearer by ``metres``."""
    transform = np.eye(4)
    transform[2, 3] = -metres
    return Motion(transform, 100, 100)


def test_back_project_and_project_are_inverse() -> None:
    pixels = np.array([[10.0, 20.0], [150.5, 80.25], [99.5, 49.5]])
    disparities = np.array([5.0, 12.5, 40.0])
    points = back_project(pixels, disparities, CAMERA)
    projected, projected_disparities, visible = project(points, CAMERA)
    assert visible.all()
    np.testing.assert_allclose(projected, pixels)
    np.testing.assert_allclose(projected_disparities, disparities)


def test_motion_of_a_synthetic_drive_matches_its_poses() -> None:
    frames = list(generate(SynthConfig(seed=3, frames=2, scale=0.5)))
    camera = frames[0].camera
    measured = StereoFrontEnd().measure(frames[1].left, frames[1].right)
    motion = estimate_motion(
        frames[0].left, frames[1].left, measured.pixels, measured.disparities, camera
    )
    assert motion is not None
    truth = np.linalg.inv(frames[1].camera_to_world) @ frames[0].camera_to_world
    step = np.linalg.norm(truth[:3, 3])
    assert step > 0.5  # the car moved ~1 m
    assert np.linalg.norm(motion.transform[:3, 3] - truth[:3, 3]) < 0.05 * step
    cosine = (np.trace(motion.transform[:3, :3].T @ truth[:3, :3]) - 1) / 2
    angle = np.arccos(np.clip(cosine, -1, 1))
    assert np.degrees(angle) < 0.2
    assert motion.inliers >= CarryConfig().min_inliers


def test_motion_fails_cleanly_on_unrelated_images() -> None:
    rng = np.random.default_rng(0)
    first = rng.integers(0, 255, (100, 200), dtype=np.uint8)
    second = rng.integers(0, 255, (100, 200), dtype=np.uint8)
    pixels = rng.uniform([10, 10], [190, 90], (60, 2))
    assert estimate_motion(first, second, pixels, np.full(60, 10.0), CAMERA) is None
    assert estimate_motion(first, first, pixels[:3], np.full(3, 10.0), CAMERA) is None


def test_carried_points_follow_the_motion_and_age() -> None:
    carrier = CarriedPoints(CarryConfig(frames=2, gap=0.0, age_std=1.5))
    first = np.array([[50.0, 30.0], [150.0, 70.0]])
    carrier.carry(None, first, np.array([5.0, 7.5]), CAMERA, motion=None)
    own = np.array([[100.0, 50.0]])
    pixels, disparities, noise, carried = carrier.carry(
        None, own, np.array([5.0]), CAMERA, motion=_forward(1.0)
    )
    assert carried == 2
    np.testing.assert_array_equal(pixels[:1], own)
    np.testing.assert_array_equal(noise, [0.0, 1.5, 1.5])
    # depth 15 m -> 14 m and 10 m -> 9 m: disparity = f b / depth, pixels move outwards
    expected_points = back_project(first, [5.0, 7.5], CAMERA) - [0.0, 0.0, 1.0]
    expected_pixels, expected_disparities, _ = project(expected_points, CAMERA)
    np.testing.assert_allclose(pixels[1:], expected_pixels)
    np.testing.assert_allclose(disparities[1:], expected_disparities)
    # the next frame carries both earlier frames, the older ones with twice the noise
    _, _, noise, carried = carrier.carry(
        None, own, np.array([5.0]), CAMERA, motion=_forward(1.0)
    )
    assert carried == 3
    np.testing.assert_array_equal(np.sort(noise), [0.0, 1.5, 3.0, 3.0])


def test_carried_points_near_a_measurement_or_out_of_view_are_dropped() -> None:
    carrier = CarriedPoints(CarryConfig(frames=1, gap=10.0))
    carrier.carry(None, np.array([[100.0, 50.0], [20.0, 50.0]]), [10.0, 10.0], CAMERA)
    _, _, _, carried = carrier.carry(
        None, np.array([[101.0, 50.0]]), [10.0], CAMERA, motion=_forward(0.0)
    )
    assert carried == 1  # (100, 50) lies 1 px from this frame's point
    # moving 20 m forward puts the 15 m deep points behind the camera
    _, _, _, carried = carrier.carry(None, np.zeros((0, 2)), [], CAMERA, motion=_forward(20.0))
    assert carried == 0


def test_a_lost_motion_or_a_new_camera_starts_over() -> None:
    carrier = CarriedPoints(CarryConfig(frames=3))
    carrier.carry(None, np.array([[100.0, 50.0]]), [10.0], CAMERA)
    _, _, _, carried = carrier.carry(None, np.array([[10.0, 10.0]]), [10.0], CAMERA, motion=None)
    assert (carried, carrier.resets) == (0, 1)
    other = StereoCamera(200, 100, 150.0, 150.0, 99.5, 49.5, 0.3)
    _, _, _, carried = carrier.carry(
        None, np.array([[10.0, 10.0]]), [10.0], other, motion=_forward(0.0)
    )
    assert (carried, carrier.resets) == (0, 2)


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"frames": -1}, "frames"),
        ({"gap": float("nan")}, "gap"),
        ({"age_std": -1.0}, "age_std"),
        ({"min_inliers": 3}, "min_inliers"),
    ],
)
def test_carry_config_validates(options: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CarryConfig(**options)  # type: ignore[arg-type]
