"""Tests of the synthetic KITTI-like stereo world (issue 3), at quarter size for speed."""

from __future__ import annotations

import itertools
import platform
import sys

import cv2
import numpy as np
import pytest

from pcainterp_stream.records import SynthFrame
from pcainterp_stream.synth import (
    CAMERA_HEIGHT,
    SynthConfig,
    World,
    camera_pose,
    generate,
    non_occluded,
    render,
    render_view,
    right_pose,
    textures,
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


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"fx": 0.0}, r"fx must be finite and > 0 px, got 0\.0"),
        ({"fy": -700.0}, r"fy must be finite and > 0 px, got -700\.0"),
        ({"fx": float("inf")}, r"fx must be finite and > 0 px, got inf"),
        ({"width": 0}, r"width must be >= 1 px, got 0"),
        ({"height": float("nan")}, r"height must be >= 1 px, got nan"),
        ({"width": 4, "scale": 0.1}, r"width 4 px at scale 0\.1 is less than 1 px"),
        ({"cx": -10.0}, r"cx must be inside the image, in \[-0\.5, 1240\.5\] px, got -10\.0"),
        ({"cy": float("nan")}, r"cy must be inside the image, in \[-0\.5, 375\.5\] px, got nan"),
    ],
)
def test_camera_options_are_checked(options: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SynthConfig(**{"frames": 1, "scale": 0.25, **options})  # type: ignore[arg-type]


def test_a_one_pixel_camera_renders() -> None:
    frame = next(iter(generate(SynthConfig(frames=1, width=1, height=1, cx=0.0, cy=0.0))))
    assert frame.left.shape == frame.depth.shape == (1, 1)


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


def test_left_right_depth_consistent() -> None:
    world = World(QUARTER.seed)
    camera = QUARTER.camera
    pose = camera_pose(world, QUARTER, 2)
    left = render_view(world, camera, pose)
    right = render_view(world, camera, right_pose(pose, camera.baseline))
    visible, _ = non_occluded(left.depth, right.depth, camera.focal_baseline)
    valid = np.isfinite(left.depth)
    assert visible.sum() / valid.sum() > 0.9


def test_sgbm_recovers_disparity() -> None:
    world = World(QUARTER.seed)
    camera = QUARTER.camera
    frame = next(iter(generate(QUARTER)))
    right = render_view(world, camera, right_pose(frame.camera_to_world, camera.baseline))
    visible, truth = non_occluded(frame.depth, right.depth, camera.focal_baseline)
    block = 5
    sgbm = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
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


def test_mip_level_rounds_log2_at_sqrt2() -> None:
    footprint = np.geomspace(1e-4, 40.0, 20_000).astype(np.float32)
    level = render._mip_level(footprint)
    exact = np.log2(footprint.astype(np.float64) / render.TEXEL) + render._MIP_BIAS
    expected = np.clip(np.floor(exact + 0.5), 0, textures.TILE_LOG2)
    # Away from the rounding boundaries the bit arithmetic equals the float64 reference.
    clear = np.abs(exact + 0.5 - np.round(exact + 0.5)) > 1e-5
    np.testing.assert_array_equal(level[clear], expected[clear])
    assert level.dtype == np.int32
    assert set(np.unique(level)) == set(range(10))


def test_texture_lookup_matches_pyramid_levels() -> None:
    bank = textures.make_texture_bank(np.random.default_rng(11))
    rng = np.random.default_rng(12)
    s = rng.uniform(-3000.0, 3000.0, 5000).astype(np.float32)
    t = rng.uniform(-3000.0, 3000.0, 5000).astype(np.float32)
    level = rng.integers(0, textures.TILE_LOG2 + 1, 5000).astype(np.int32)
    tile = rng.integers(0, bank.n_tiles, 5000)
    values = bank.sample(textures.tile_offset(tile), s, t, level)
    planes = bank.texels.reshape(bank.n_tiles, 2 * textures.TILE_SIZE, textures.TILE_SIZE)
    size = textures.TILE_SIZE >> level
    row = 2 * textures.TILE_SIZE - (2 * textures.TILE_SIZE >> level)
    # Coordinates are floored after the float32 shift by 512 * 1024 texels (1/16 texel).
    shift = np.float32(textures.TILE_SIZE * 1024)
    texel_s = np.floor((s + shift).astype(np.float64) / 2.0**level).astype(int) % size
    texel_t = np.floor((t + shift).astype(np.float64) / 2.0**level).astype(int) % size
    np.testing.assert_array_equal(values, planes[tile, row + texel_t, texel_s])
    # Level 1 is the (blurred) 2x2 mean of level 0: same mean, less variance.
    top = planes[0, :512, :512]
    second = planes[0, 512:768, :256]
    assert abs(float(top.mean()) - float(second.mean())) < 0.01
    assert float(second.std()) < float(top.std())


@pytest.mark.parametrize("index", [0, 37])
def test_column_spans_keep_every_nearest_hit(index: int) -> None:
    """The sparse (column, object) pairs find the same nearest hit as testing all pairs."""
    world = World(1)
    camera = QUARTER.camera
    pose = camera_pose(world, QUARTER, index)
    centre, right, forward = pose[:3, 3], pose[:3, 0], pose[:3, 2]
    slope = (np.arange(camera.width) - camera.cx) / camera.fx
    ray_x = forward[0] + slope * right[0]
    ray_y = forward[1] + slope * right[1]
    layers = render._object_layers(world, camera, centre, right, forward, ray_x, ray_y, 8)
    assert layers is not None
    # Brute force: every column against every footprint.
    objects = world.objects(float(centre[0]) - 30.0, float(centre[0]) + render.OBJECT_RANGE)
    rx, ry = ray_x[:, None], ray_y[:, None]
    start = objects.seg_start - centre[:2]
    edge = objects.seg_end - objects.seg_start
    with np.errstate(divide="ignore", invalid="ignore"):
        det = ry * edge[:, 0] - rx * edge[:, 1]
        depth = (start[:, 1] * edge[:, 0] - start[:, 0] * edge[:, 1]) / det
        along = (rx * start[:, 1] - ry * start[:, 0]) / det
    depth[~((along >= 0) & (along <= 1) & (depth > 0.3))] = np.inf
    offset = objects.cyl_centre - centre[:2]
    norm_sq = rx * rx + ry * ry
    along_c = rx * offset[:, 0] + ry * offset[:, 1]
    disc = along_c**2 - norm_sq * ((offset**2).sum(axis=1) - objects.cyl_radius**2)
    cyl = (along_c - np.sqrt(np.maximum(disc, 0.0))) / norm_sq
    cyl[~((disc > 0) & (cyl > 0.3))] = np.inf
    nearest = np.minimum(depth.min(axis=1), cyl.min(axis=1))
    assert np.isfinite(nearest).mean() > 0.5
    np.testing.assert_allclose(layers.depth[:, 0], nearest, rtol=1e-12)


def test_allocator_tuning_is_idempotent() -> None:
    from pcainterp_stream.allocator import keep_freed_memory

    first = keep_freed_memory()
    assert keep_freed_memory() == first
    if sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc":
        assert first


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
    reason="glibc's allocator and /proc",
)
def test_released_memory_leaves_the_resident_set() -> None:
    from pcainterp_stream.allocator import keep_freed_memory, release_free_memory, resident_bytes

    def resident_mb() -> float:
        resident = resident_bytes()
        assert resident is not None
        return resident / 2**20

    assert keep_freed_memory()  # freed memory is kept resident from here on
    blocks = [np.ones(2**19) for _ in range(64)]  # 64 x 4 MiB from the heap, touched
    del blocks
    kept = resident_mb()
    assert release_free_memory()
    assert resident_mb() < kept - 128  # most of the 256 MiB left the resident set


def test_free_memory_goes_back_early_when_the_resident_size_is_high(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Read every RESIDENT_CHECK_EVERY frames: above RELEASE_ABOVE_MB the free pages go back
    # at once; the next early release waits until the size grew RELEASE_GROWTH_MB more.
    from pcainterp_stream import allocator

    mib = 1 << 20
    sizes = iter([300 * mib, 400 * mib, 380 * mib, 390 * mib, 420 * mib, 100 * mib])
    released: list[int] = []
    monkeypatch.setattr(allocator, "resident_bytes", lambda: next(sizes))
    monkeypatch.setattr(allocator, "release_free_memory", lambda: released.append(1) or True)
    monkeypatch.setattr(allocator, "RESIDENT_CHECK_EVERY", 1)
    releases = allocator.Releases()
    for count in range(1, 5):
        releases.frame(count)
    # 1: 300 (below 350); 2: 400 -> release, 380 after -> next above 412; 3: 390;
    # 4: 420 -> release, 100 after -> next above 350 again
    assert len(released) == 2
    assert releases.floor == allocator.RELEASE_ABOVE_MB * mib
    releases.frame(allocator.RELEASE_EVERY)  # the periodic release, whatever the size
    assert len(released) == 3
