"""Tests of the synthetic KITTI-like stereo world (issue 3), at quarter size for speed."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.records import SynthFrame
from pcainterp_stream.synth import (
    CAMERA_HEIGHT,
    SynthConfig,
    World,
    camera_pose,
    generate,
    render_view,
    right_pose,
)

QUARTER = SynthConfig(seed=3, frames=3, scale=0.25)


@pytest.fixture(scope="module")
def frames() -> list[SynthFrame]:
    return list(generate(QUARTER))


def test_shapes_dtypes_and_sky(frames: list[SynthFrame]) -> None:
    camera = QUARTER.camera
    assert (camera.width, camera.height) == (310, 94)
    assert camera.fx == pytest.approx(718.856 * 0.25)
    assert camera.cx == pytest.approx((607.19 + 0.5) * 0.25 - 0.5)
    for frame in frames:
        assert frame.left.shape == frame.right.shape == frame.depth.shape == (94, 310)
        assert frame.left.dtype == frame.right.dtype == np.uint8
        assert frame.depth.dtype == np.float32
        assert frame.camera_to_world.shape == (4, 4)
        assert frame.camera == camera
        sky = np.isnan(frame.depth)
        assert 0.0 < sky.mean() < 0.5
        assert sky[0].mean() > sky[-1].mean()  # sky at the top, none at the bottom
        assert not sky[-1].any()
        assert np.nanmin(frame.depth) > 0.3
        # Sky is bright and featureless; the scene carries texture for matching.
        assert frame.left[~sky].std() > 15.0


def test_deterministic_and_seed_dependent(frames: list[SynthFrame]) -> None:
    again = list(generate(QUARTER))
    for first, second in zip(frames, again, strict=True):
        np.testing.assert_array_equal(first.left, second.left)
        np.testing.assert_array_equal(first.right, second.right)
        np.testing.assert_array_equal(first.depth, second.depth)
        np.testing.assert_array_equal(first.camera_to_world, second.camera_to_world)
    other = next(iter(generate(SynthConfig(seed=4, frames=1, scale=0.25))))
    assert not np.array_equal(other.left, frames[0].left)


def test_streaming_is_lazy() -> None:
    iterator = generate(SynthConfig(seed=0, frames=10**6, scale=0.1))
    first = next(iterator)
    second = next(iterator)
    assert (first.index, second.index) == (0, 1)
    assert second.stamp_ns - first.stamp_ns == 100_000_000


def test_pose_smooth_at_speed(frames: list[SynthFrame]) -> None:
    positions = np.array([frame.camera_to_world[:3, 3] for frame in frames])
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    # 10 Hz at 10 m/s +- 5 %.
    assert np.all(np.abs(steps - QUARTER.speed * 0.1) < 0.07 * QUARTER.speed * 0.1)
    for frame in frames:
        rotation = frame.camera_to_world[:3, :3]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-8)
        np.testing.assert_allclose(rotation[:, 1], [0.0, 0.0, -1.0])  # level camera
    world = World(QUARTER.seed)
    heading = [camera_pose(world, QUARTER, i)[:2, 2] for i in range(0, 30, 3)]
    cosines = [a @ b for a, b in itertools.pairwise(heading)]
    turn = np.degrees(np.arccos(np.clip(cosines, -1, 1)))
    assert np.all(turn < 3.0)  # no jumps in heading over 0.3 s


def test_camera_height_above_road(frames: list[SynthFrame]) -> None:
    frame = frames[0]
    camera = frame.camera
    # The pixel straight below the principal point at the bottom rows sees the road.
    bottom_row = camera.height - 1
    depth = float(frame.depth[bottom_row, round(camera.cx)])
    height = depth * (bottom_row - camera.cy) / camera.fy
    # The road ahead may climb or fall (grades up to ~5 % over these ~6 m).
    assert height == pytest.approx(CAMERA_HEIGHT, abs=0.3)


def _non_occluded(
    depth_left: npt.NDArray[np.float32], depth_right: npt.NDArray[np.float32], focal_baseline: float
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float32]]:
    """Left pixels whose surface point is visible in the right view, and true disparity."""
    height, width = depth_left.shape
    disparity = (focal_baseline / depth_left).astype(np.float32)
    columns = np.arange(width)[None, :] - disparity
    target = np.rint(np.nan_to_num(columns, nan=-1)).astype(int)
    inside = (target >= 0) & (target < width) & np.isfinite(depth_left)
    rows = np.broadcast_to(np.arange(height)[:, None], depth_left.shape)
    seen = np.full(depth_left.shape, np.nan, dtype=np.float32)
    seen[inside] = depth_right[rows[inside], target[inside]]
    with np.errstate(invalid="ignore"):
        visible = inside & (np.abs(seen - depth_left) < 0.03 * depth_left + 0.05)
    return visible, disparity


def test_left_right_depth_consistent() -> None:
    world = World(QUARTER.seed)
    camera = QUARTER.camera
    pose = camera_pose(world, QUARTER, 2)
    left = render_view(world, camera, pose)
    right = render_view(world, camera, right_pose(pose, camera.baseline))
    visible, _ = _non_occluded(left.depth, right.depth, camera.focal_baseline)
    valid = np.isfinite(left.depth)
    assert visible.sum() / valid.sum() > 0.9


def test_sgbm_recovers_disparity() -> None:
    world = World(QUARTER.seed)
    camera = QUARTER.camera
    frame = next(iter(generate(QUARTER)))
    right = render_view(world, camera, right_pose(frame.camera_to_world, camera.baseline))
    visible, truth = _non_occluded(frame.depth, right.depth, camera.focal_baseline)
    block = 5
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=32,
        blockSize=block,
        P1=8 * block**2,
        P2=32 * block**2,
        uniquenessRatio=10,
        speckleWindowSize=50,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    estimate = sgbm.compute(frame.left, frame.right).astype(np.float32) / 16.0
    valid = visible & (estimate >= 0) & (np.arange(camera.width)[None, :] >= 32)
    assert valid.sum() > 0.4 * visible.sum()
    share = float((np.abs(estimate[valid] - truth[valid]) <= 1.0).mean())
    assert share > 0.8, share
