"""Synthetic KITTI-like stereo driving logs with ground truth.

A procedural street world (:mod:`.world`) is ray-cast (:mod:`.render`) from a stereo camera
driving through it at 10 Hz. Each frame is a :class:`~pcainterp_stream.records.SynthFrame`:
rectified grey left and right images, the left camera's ground-truth z-depth (NaN for sky) and
its pose. Frames are produced one at a time; memory does not grow with the number of frames.

Example:
    >>> from pcainterp_stream.synth import SynthConfig, generate
    >>> for frame in generate(SynthConfig(seed=0, frames=2, scale=0.25)):
    ...     print(frame.left.shape, frame.depth.dtype)
    (94, 310) float32
    (94, 310) float32
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.allocator import keep_freed_memory
from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth.lidar import LIDAR_DEPTH, LidarConfig, lidar_depth
from pcainterp_stream.synth.render import View, render_view
from pcainterp_stream.synth.world import World

__all__ = [
    "CAMERA_HEIGHT",
    "FRAME_PERIOD_NS",
    "LIDAR_DEPTH",
    "LidarConfig",
    "SynthConfig",
    "View",
    "World",
    "camera_pose",
    "generate",
    "lidar_depth",
    "non_occluded",
    "render_view",
    "right_pose",
]

#: Height of the camera's optical centre above the road (m), as on KITTI's car.
CAMERA_HEIGHT = 1.65
#: 10 Hz.
FRAME_PERIOD_NS = 100_000_000
#: Sensor noise standard deviation (grey levels) and the 3-tap optical blur weights.
_NOISE_STD = 1.6
_BLUR = (0.2, 0.6, 0.2)


@dataclass(frozen=True)
class SynthConfig:
    """Options of a synthetic drive.

    At scale F the image is round(W*F) x round(H*F) px and the intrinsics follow the
    pixel-centre convention: f' = f*F, c' = (c + 0.5)*F - 0.5.

    Attributes:
        seed: world and noise seed; the same options give identical frames on any machine.
        frames: number of frames.
        scale: image size factor (0.25 gives a quarter-size log, 310x94).
        width: full-scale image width (px), KITTI's grey cameras by default.
        height: full-scale image height (px).
        fx: full-scale focal length x (px).
        fy: full-scale focal length y (px).
        cx: full-scale principal point x (px).
        cy: full-scale principal point y (px).
        baseline: stereo baseline (m); the right camera sits +baseline along camera x.
        start_time_ns: stamp of frame 0 (ns).
        speed: mean driving speed (m/s).
        noise: sensor noise on (True) or off.
        scene: ``"street"`` (the street world), ``"indoor"`` (a room, corridor or hall chosen
            by the seed) or one of ``"room"``, ``"corridor"``, ``"hall"`` (:mod:`.indoor`;
            20 Hz, the camera carried by ``platform``).
        platform: indoor only: ``"handheld"``, ``"drone"``, ``"robot"`` or ``"auto"`` (by
            the seed).
    """

    seed: int = 0
    frames: int = 20
    scale: float = 1.0
    width: int = 1241
    height: int = 376
    fx: float = 718.856
    fy: float = 718.856
    cx: float = 607.19
    cy: float = 185.22
    baseline: float = 0.5372
    start_time_ns: int = 1_317_046_453_000_000_000
    speed: float = 10.0
    noise: bool = True
    scene: str = "street"
    platform: str = "auto"

    def __post_init__(self) -> None:
        scenes = ("street", "indoor", "room", "corridor", "hall")
        if self.scene not in scenes:
            raise ValueError(f"scene must be one of {', '.join(scenes)}, got {self.scene!r}")
        platforms = ("auto", "handheld", "drone", "robot")
        if self.platform not in platforms:
            raise ValueError(
                f"platform must be one of {', '.join(platforms)}, got {self.platform!r}"
            )
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.frames < 0:
            raise ValueError(f"frames must be >= 0, got {self.frames}")
        if not 0.05 <= self.scale <= 4.0:
            raise ValueError(f"scale must be in [0.05, 4], got {self.scale}")
        if not 0.0 < self.speed <= 40.0:
            raise ValueError(f"speed must be in (0, 40] m/s, got {self.speed}")
        if self.baseline <= 0.0:
            raise ValueError(f"baseline must be > 0 m, got {self.baseline}")
        self._check_intrinsics()

    def _check_intrinsics(self) -> None:
        """Refuse an image size or intrinsics the renderer cannot cast rays for."""
        for name, size in (("width", self.width), ("height", self.height)):
            if not size >= 1:  # also refuses nan
                raise ValueError(f"{name} must be >= 1 px, got {size}")
            if round(size * self.scale) < 1:
                raise ValueError(
                    f"{name} {size} px at scale {self.scale} is less than 1 px; "
                    "give a larger image or scale"
                )
        for name, focal in (("fx", self.fx), ("fy", self.fy)):
            if not (math.isfinite(focal) and focal > 0.0):
                raise ValueError(f"{name} must be finite and > 0 px, got {focal}")
        for name, centre, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            # pixel centres at 0 .. size - 1: the image spans [-0.5, size - 0.5]
            if not (math.isfinite(centre) and -0.5 <= centre <= size - 0.5):
                raise ValueError(
                    f"{name} must be inside the image, in [-0.5, {size - 0.5}] px, got {centre}"
                )

    @property
    def camera(self) -> StereoCamera:
        """Return the scaled stereo calibration."""
        factor = self.scale
        return StereoCamera(
            width=round(self.width * factor),
            height=round(self.height * factor),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            baseline=self.baseline,
        )


def _lateral(seed_phase: tuple[float, float], time_s: float) -> float:
    """Lateral offset of the car in its lane (m, left positive): lane centre plus wander."""
    return (
        -1.75
        + 0.15 * math.sin(2 * math.pi * time_s / 9.0 + seed_phase[0])
        + 0.05 * math.sin(2 * math.pi * time_s / 3.7 + seed_phase[1])
    )


def camera_pose(world: World, config: SynthConfig, index: int) -> npt.NDArray[np.float64]:
    """Return the left camera's pose at frame ``index``.

    The car drives along the road at ``config.speed`` (+-5 %), in the right-hand lane with a
    small lateral wander, its heading along its path; the camera is level, 1.65 m above
    the road.

    Args:
        world: the world.
        config: the drive's options.
        index: frame number (0-based).

    Returns:
        (4, 4) float64 camera-to-world transform of the left optical frame (x right, y down,
        z forward) in the world frame (z up); quantised to 1e-9.
    """
    phases = np.random.default_rng([config.seed, 5]).uniform(0, 2 * math.pi, 3)
    phase = (float(phases[0]), float(phases[1]))

    def u_at(time_s: float) -> float:
        wobble = 0.05 * config.speed * 13.0 / (2 * math.pi)
        angle = 2 * math.pi * time_s / 13.0 + float(phases[2])
        return 5.0 + config.speed * time_s + wobble * math.sin(angle)

    time_s = index * FRAME_PERIOD_NS * 1e-9
    look_ahead = 0.2
    u_now, u_next = u_at(time_s), u_at(time_s + look_ahead)
    table = world.road_table(u_now - 20.0, u_next + 20.0)
    blocks = world.block_table(u_now - 20.0, u_next + 20.0)
    x, y = world.road_point(
        table,
        np.array([u_now, u_next]),
        np.array([_lateral(phase, time_s), _lateral(phase, time_s + look_ahead)]),
    )
    ground, _ = world.ground(table, blocks, x[:1], y[:1])
    heading_x, heading_y = x[1] - x[0], y[1] - y[0]
    norm = math.hypot(heading_x, heading_y)
    fx, fy = heading_x / norm, heading_y / norm
    pose = np.array(
        [
            [fy, 0.0, fx, x[0]],
            [-fx, 0.0, fy, y[0]],
            [0.0, -1.0, 0.0, ground[0] + CAMERA_HEIGHT],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    quantised: npt.NDArray[np.float64] = np.round(pose * 1e9) / 1e9
    return quantised


def right_pose(
    camera_to_world: npt.NDArray[np.float64], baseline: float
) -> npt.NDArray[np.float64]:
    """Return the right camera's pose: the left one moved +baseline along its own x axis.

    Args:
        camera_to_world: (4, 4) float64 left pose.
        baseline: metres.

    Returns:
        (4, 4) float64 right pose.
    """
    pose = camera_to_world.copy()
    pose[:3, 3] += baseline * camera_to_world[:3, 0]
    return pose


def _blur(image: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Separable 3-tap optical blur with replicated borders (exact, thread-independent)."""
    low, mid, _ = (np.float32(w) for w in _BLUR)
    padded = np.pad(image, 1, mode="edge")
    rows = low * (padded[:, :-2] + padded[:, 2:]) + mid * padded[:, 1:-1]
    return (low * (rows[:-2] + rows[2:]) + mid * rows[1:-1]).astype(np.float32)


def _sensor(
    image: npt.NDArray[np.float32], noise: npt.NDArray[np.float32] | None
) -> npt.NDArray[np.uint8]:
    """Blur, add noise, round and clip to 8-bit grey."""
    blurred = _blur(image)
    if noise is not None:
        blurred += noise
    return np.clip(np.rint(blurred), 0, 255).astype(np.uint8)


class _NoiseSource:
    """Gaussian sensor noise from one precomputed buffer, read at a random offset per image."""

    def __init__(self, seed: int, size: int) -> None:
        rng = np.random.default_rng([seed, 6])
        self._rng = np.random.default_rng([seed, 7])
        self._size = size
        self._buffer = (rng.standard_normal(size * 3) * _NOISE_STD).astype(np.float32)

    def next(self, shape: tuple[int, int]) -> npt.NDArray[np.float32]:
        start = int(self._rng.integers(0, 2 * self._size))
        return self._buffer[start : start + self._size].reshape(shape)


def _render_image(
    world: World,
    camera: StereoCamera,
    camera_to_world: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float32] | None,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32]]:
    """Render one view and pass it through the sensor model.

    Returns:
        (H, W) uint8 image and (H, W) float32 z-depth (m, NaN for sky).
    """
    view = render_view(world, camera, camera_to_world)
    return _sensor(view.image, noise), view.depth


def generate(config: SynthConfig) -> Iterator[SynthFrame]:
    """Render a synthetic stereo drive frame by frame.

    Tunes glibc's malloc on first use (:func:`~pcainterp_stream.allocator.keep_freed_memory`): freed
    temporaries are kept for reuse instead of being page-faulted in again for every view.

    Args:
        config: the drive's options.

    Yields:
        One :class:`SynthFrame` per 100 ms: left/right (H, W) uint8, depth (H, W) float32 m
        (NaN for sky), camera_to_world (4, 4) float64, and the scaled camera.
    """
    keep_freed_memory()
    if config.scene != "street":
        yield from _generate_indoor(config)
        return
    world = World(config.seed)
    camera = config.camera
    noise = _NoiseSource(config.seed, camera.width * camera.height) if config.noise else None
    shape = (camera.height, camera.width)
    # The right view (render and sensor) runs in a second thread while this one renders the
    # left (numpy releases the GIL); both are pure functions of the world, the pose and the
    # noise drawn here in a fixed order, so the result does not depend on the scheduling.
    with ThreadPoolExecutor(max_workers=1) as pool:
        for index in range(config.frames):
            pose = camera_pose(world, config, index)
            left_noise = noise.next(shape) if noise else None
            right_noise = noise.next(shape) if noise else None
            right_job = pool.submit(
                _render_image, world, camera, right_pose(pose, camera.baseline), right_noise
            )
            left, depth = _render_image(world, camera, pose, left_noise)
            right, _ = right_job.result()
            yield SynthFrame(
                index=index,
                stamp_ns=config.start_time_ns + index * FRAME_PERIOD_NS,
                left=left,
                right=right,
                depth=depth,
                camera_to_world=pose,
                camera=camera,
            )


def _generate_indoor(config: SynthConfig) -> Iterator[SynthFrame]:
    """Render an indoor log (:mod:`.indoor`) frame by frame, 20 Hz, same sensor model."""
    from pcainterp_stream.synth import indoor

    scene = indoor.make_scene(config.seed, indoor.scene_for(config.scene, config.seed))
    trajectory = indoor.make_trajectory(
        config.seed, scene, indoor.platform_for(config.platform, config.seed)
    )
    tile = indoor.texture_tile(config.seed)
    camera = config.camera
    noise = _NoiseSource(config.seed, camera.width * camera.height) if config.noise else None
    shape = (camera.height, camera.width)
    for index in range(config.frames):
        pose = indoor.indoor_pose(scene, trajectory, index, config.frames)
        left_noise = noise.next(shape) if noise else None
        right_noise = noise.next(shape) if noise else None
        left, depth = indoor.render_indoor(scene, camera, pose, tile)
        right, _ = indoor.render_indoor(scene, camera, right_pose(pose, camera.baseline), tile)
        yield SynthFrame(
            index=index,
            stamp_ns=config.start_time_ns + index * indoor.INDOOR_FRAME_PERIOD_NS,
            left=_sensor(left, left_noise),
            right=_sensor(right, right_noise),
            depth=depth,
            camera_to_world=pose,
            camera=camera,
        )


def non_occluded(
    depth_left: npt.NDArray[np.float32],
    depth_right: npt.NDArray[np.float32],
    focal_baseline: float,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float32]]:
    """Return the left pixels whose surface point the right camera also sees.

    A left pixel with true disparity d lands on column x - d of the right image; it is
    visible there when the right view's depth at that pixel matches (within 3 % + 5 cm),
    i.e. no nearer surface hides it.

    Args:
        depth_left: (H, W) float32 left ground-truth depth (m), NaN for sky.
        depth_right: (H, W) float32 right ground-truth depth (m), rendered from the right
            camera (``render_view`` with ``right_pose``).
        focal_baseline: f*b (px*m).

    Returns:
        (H, W) bool visibility mask and (H, W) float32 true disparity (px).
    """
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
