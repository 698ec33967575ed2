"""Synthetic indoor scenes: rooms, corridors and halls with clutter, and other cameras.

The street world (:mod:`.world`) is seen by a forward-looking camera at car height. Indoors
the geometry is another: a closed box of walls, floor and ceiling, all of it near, with
furniture, cabinets, machines and pillars standing on the floor, seen from a hand-held
camera, a drone or a ground robot, each with its own heights and pitches. This module ray
casts such scenes exactly (axis-aligned boxes: the slab method per pixel, vectorised) with
textured surfaces, so that SGBM finds matches as on real walls.

World frame: x along the scene's long side, y to the left, z up (metres); the floor is
z = 0. The camera moves slowly along x (0.3-1.2 m/s at 20 Hz), with a lateral wander and a
yaw that sweeps the room; its height and pitch follow the platform
(:data:`PLATFORMS`). Everything is a function of the seed: the same options give the same
frames on any machine (only + - * / sqrt, comparisons and small tables of sin/cos).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.records import StereoCamera

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

INDOOR_FRAME_PERIOD_NS = 50_000_000
"""20 Hz, as the VI-sensor and most indoor stereo cameras."""


class SceneKind(StrEnum):
    """The kind of indoor scene."""

    ROOM = "room"
    """An office or living room: 4-9 m, 2.5-3.2 m high, much clutter."""
    CORRIDOR = "corridor"
    """A corridor 1.8-2.6 m wide and 25-40 m long, cabinets and doors along its walls."""
    HALL = "hall"
    """A machine hall or warehouse: 20-35 m, 5-9 m high, machines, crates and pillars."""


class Platform(StrEnum):
    """What carries the camera."""

    HANDHELD = "handheld"
    DRONE = "drone"
    ROBOT = "robot"


PLATFORMS: dict[Platform, tuple[tuple[float, float], tuple[float, float]]] = {
    Platform.HANDHELD: ((1.3, 1.7), (-15.0, 5.0)),
    Platform.DRONE: ((0.8, 3.0), (-25.0, 10.0)),
    Platform.ROBOT: ((0.2, 0.45), (-3.0, 10.0)),
}
"""Per platform: camera height range (m) and pitch range (degrees, up positive)."""


@dataclass(frozen=True)
class Boxes:
    """Axis-aligned boxes, (n, 3) lower and upper corners (m), and a grey level each."""

    lower: F64
    upper: F64
    grey: F64


@dataclass(frozen=True)
class IndoorScene:
    """One indoor scene: its shell (the inside of a box) and the solid boxes in it.

    Attributes:
        kind: room, corridor or hall.
        size: (length, width, height) of the shell (m).
        clutter: the solid boxes standing in it.
        shell_grey: grey levels of floor, ceiling and walls (4 walls: -x, +x, -y, +y).
        path_y: the lateral centre of the free lane the camera moves along (m).
    """

    kind: SceneKind
    size: tuple[float, float, float]
    clutter: Boxes
    shell_grey: F64
    path_y: float


def make_scene(seed: int, kind: SceneKind) -> IndoorScene:
    """Build the scene of a seed: shell dimensions and clutter, keeping a lane free.

    The camera's lane (|y - path_y| < 0.9 m, 0.7 m in a corridor) has no clutter, so the
    camera never enters a box.
    """
    rng = np.random.default_rng([seed, 33, list(SceneKind).index(kind)])
    if kind is SceneKind.ROOM:
        size = (rng.uniform(5.0, 9.0), rng.uniform(4.0, 7.0), rng.uniform(2.5, 3.2))
        count, lane = int(rng.integers(8, 15)), 0.9
    elif kind is SceneKind.CORRIDOR:
        size = (rng.uniform(25.0, 40.0), rng.uniform(1.8, 2.6), rng.uniform(2.4, 3.0))
        count, lane = int(rng.integers(4, 10)), 0.45
    else:
        size = (rng.uniform(20.0, 35.0), rng.uniform(15.0, 25.0), rng.uniform(5.0, 9.0))
        count, lane = int(rng.integers(14, 28)), 1.2
    length, width, height = size
    path_y = width / 2.0
    lower: list[list[float]] = []
    upper: list[list[float]] = []
    for _ in range(count * 4):  # tries
        if len(lower) >= count:
            break
        if kind is SceneKind.CORRIDOR:  # cabinets and benches against the walls
            depth = rng.uniform(0.25, width / 2.0 - lane)
            side = rng.integers(0, 2)
            y0 = 0.0 if side == 0 else width - depth
            x0 = rng.uniform(0.0, length - 1.0)
            box_lower = [x0, y0, 0.0]
            box_upper = [x0 + rng.uniform(0.4, 3.0), y0 + depth, rng.uniform(0.4, 2.2)]
        else:
            big = kind is SceneKind.HALL
            dx = rng.uniform(0.8, 5.0) if big else rng.uniform(0.4, 2.0)
            dy = rng.uniform(0.8, 5.0) if big else rng.uniform(0.4, 1.6)
            if big and rng.uniform() < 0.3:  # a pillar up to the roof
                dx = dy = rng.uniform(0.4, 0.9)
                top = height
            else:
                top = rng.uniform(0.5, min(height - 0.3, 4.0 if big else 2.2))
            x0 = rng.uniform(0.0, length - dx)
            y0 = rng.uniform(0.0, width - dy)
            box_lower, box_upper = [x0, y0, 0.0], [x0 + dx, y0 + dy, top]
        if box_lower[1] < path_y + lane and box_upper[1] > path_y - lane:
            continue  # in the camera's lane
        lower.append(box_lower)
        upper.append(box_upper)
    n = len(lower)
    clutter = Boxes(
        lower=np.array(lower, dtype=np.float64).reshape(n, 3),
        upper=np.array(upper, dtype=np.float64).reshape(n, 3),
        grey=rng.uniform(40.0, 210.0, n),
    )
    return IndoorScene(kind, size, clutter, rng.uniform(60.0, 200.0, 6), path_y)


@dataclass(frozen=True)
class Trajectory:
    """The camera's motion through a scene: height, pitch and the speed of its walk."""

    height: float
    pitch_deg: float
    speed: float
    phases: tuple[float, float, float]


def make_trajectory(seed: int, scene: IndoorScene, platform: Platform) -> Trajectory:
    """Draw the platform's height and pitch (within :data:`PLATFORMS`) and a walking speed."""
    rng = np.random.default_rng([seed, 34])
    (low, high), (pitch_low, pitch_high) = PLATFORMS[platform]
    height = min(rng.uniform(low, high), scene.size[2] - 0.3)
    phases = rng.uniform(0.0, 2.0 * math.pi, 3)
    return Trajectory(
        height=float(height),
        pitch_deg=float(rng.uniform(pitch_low, pitch_high)),
        speed=float(rng.uniform(0.3, 1.2)),
        phases=(float(phases[0]), float(phases[1]), float(phases[2])),
    )


def indoor_pose(
    scene: IndoorScene, trajectory: Trajectory, index: int, frames: int
) -> npt.NDArray[np.float64]:
    """Return the left camera's pose (4, 4) at frame ``index`` (optical frame, x right, y down).

    The camera walks along x from 10 % of the length, at the trajectory's speed but slowed
    so that ``frames`` frames end before 90 %; it wanders +-0.25 m laterally (0.1 m in a
    corridor), sweeps its yaw +-30 degrees (+-10 in a corridor), bobs +-3 cm.
    """
    length = scene.size[0]
    time_s = index * INDOOR_FRAME_PERIOD_NS * 1e-9
    duration = max(frames, 1) * INDOOR_FRAME_PERIOD_NS * 1e-9
    speed = min(trajectory.speed, 0.8 * length / duration)
    corridor = scene.kind is SceneKind.CORRIDOR
    p0, p1, p2 = trajectory.phases
    x = 0.1 * length + speed * time_s
    y = scene.path_y + (0.1 if corridor else 0.25) * math.sin(2 * math.pi * time_s / 7.0 + p0)
    z = trajectory.height + 0.03 * math.sin(2 * math.pi * time_s / 1.1 + p1)
    yaw = math.radians(10.0 if corridor else 30.0) * math.sin(2 * math.pi * time_s / 11.0 + p2)
    pitch = math.radians(trajectory.pitch_deg)
    forward = np.array(
        [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
    )
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, (x, y, z)
    quantised: npt.NDArray[np.float64] = np.round(pose * 1e9) / 1e9
    return quantised


_TILE = 256


def texture_tile(seed: int) -> F32:
    """A (256, 256) periodic noise tile, zero mean, unit std, two octaves (FFT-filtered)."""
    rng = np.random.default_rng([seed, 35])
    white = rng.standard_normal((_TILE, _TILE))
    freq = np.fft.fftfreq(_TILE)
    radius = np.sqrt(freq[:, None] ** 2 + freq[None, :] ** 2)
    shaped = np.fft.ifft2(np.fft.fft2(white) / np.maximum(radius, 1.0 / _TILE) ** 0.9).real
    shaped -= shaped.mean()
    tile: F32 = (shaped / shaped.std()).astype(np.float32)
    return tile


def _sample(tile: F32, s: F64, t: F64) -> F32:
    """Bilinear periodic sample of the tile at texel coordinates (s, t)."""
    s0, t0 = np.floor(s), np.floor(t)
    fs, ft = (s - s0).astype(np.float32), (t - t0).astype(np.float32)
    i0 = s0.astype(np.int64) % _TILE
    j0 = t0.astype(np.int64) % _TILE
    i1, j1 = (i0 + 1) % _TILE, (j0 + 1) % _TILE
    top = tile[j0, i0] * (1 - fs) + tile[j0, i1] * fs
    bottom = tile[j1, i0] * (1 - fs) + tile[j1, i1] * fs
    sampled: F32 = (top * (1 - ft) + bottom * ft).astype(np.float32)
    return sampled


def render_indoor(
    scene: IndoorScene, camera: StereoCamera, camera_to_world: F64, tile: F32
) -> tuple[F32, F32]:
    """Ray cast one view: (H, W) float32 grey (0-255, before the sensor) and z-depth (m).

    Every ray hits a surface (the shell is closed): the depth has no NaN.
    """
    rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
    ray_cam = np.stack(
        [
            (cols.ravel() - camera.cx) / camera.fx,
            (rows.ravel() - camera.cy) / camera.fy,
            np.ones(rows.size),
        ]
    )
    rotation, origin = camera_to_world[:3, :3], camera_to_world[:3, 3]
    direction = rotation @ ray_cam  # (3, n); t along it is the z-depth (ray_cam z = 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / direction
    size = np.asarray(scene.size)
    # the shell from inside: the ray leaves through the nearest of the three far planes
    bound = np.where(direction > 0, size[:, None], 0.0)
    exits = (bound - origin[:, None]) * inverse
    exits[~np.isfinite(exits) | (exits <= 0)] = np.inf
    axis = np.argmin(exits, axis=0)
    depth = exits[axis, np.arange(axis.size)]
    positive = direction[axis, np.arange(axis.size)] > 0
    # surface ids: 0 floor, 1 ceiling, 2/3 walls -x/+x, 4/5 walls -y/+y, 6+ clutter boxes
    surface = np.where(axis == 2, np.where(positive, 1, 0), 2 * axis + 2 + positive)
    normal_axis = axis.copy()
    for index in range(scene.clutter.lower.shape[0]):
        low = (scene.clutter.lower[index][:, None] - origin[:, None]) * inverse
        high = (scene.clutter.upper[index][:, None] - origin[:, None]) * inverse
        near = np.minimum(low, high)
        far = np.maximum(low, high)
        near = np.where(np.isnan(near), -np.inf, near)
        far = np.where(np.isnan(far), np.inf, far)
        entry_axis = np.argmax(near, axis=0)
        entry = near[entry_axis, np.arange(entry_axis.size)]
        hit = (entry <= far.min(axis=0)) & (entry > 0) & (entry < depth)
        depth = np.where(hit, entry, depth)
        surface = np.where(hit, 6 + index, surface)
        normal_axis = np.where(hit, entry_axis, normal_axis)
    point = origin[:, None] + direction * depth
    # texture coordinates: the two axes in the surface's plane, 2 cm and 25 cm texels
    first = np.where(normal_axis == 0, point[1], point[0])
    second = np.where(normal_axis == 2, point[1], point[2])
    offset = (surface * 37).astype(np.float64)
    fine = _sample(tile, first / 0.02 + offset, second / 0.02 + 3.0 * offset)
    coarse = _sample(tile, first / 0.25 + 5.0 * offset, second / 0.25 + offset)
    footprint = depth / camera.fx  # metres per pixel
    fine_weight = np.clip(1.0 - footprint / 0.03, 0.0, 1.0).astype(np.float32)
    greys = np.concatenate([scene.shell_grey, scene.clutter.grey])
    base = greys[surface].astype(np.float32)
    # light from above and one side: floors/ceilings, x walls and y walls differ
    shade = np.array([1.0, 0.85, 0.95], dtype=np.float32)[normal_axis]
    grey = base * shade + 14.0 * coarse + 18.0 * fine_weight * fine
    shape = (camera.height, camera.width)
    return (
        np.clip(grey, 0.0, 255.0).astype(np.float32).reshape(shape),
        depth.astype(np.float32).reshape(shape),
    )


CAMERAS: dict[str, dict[str, float]] = {
    "kitti": {
        "width": 1241,
        "height": 376,
        "fx": 718.856,
        "cx": 607.19,
        "cy": 185.22,
        "baseline": 0.5372,
    },
    "752x480": {
        "width": 752,
        "height": 480,
        "fx": 436.0,
        "cx": 364.4,
        "cy": 256.6,
        "baseline": 0.11,
    },
    "640x480": {
        "width": 640,
        "height": 480,
        "fx": 385.0,
        "cx": 319.5,
        "cy": 239.5,
        "baseline": 0.05,
    },
    "1280x720": {
        "width": 1280,
        "height": 720,
        "fx": 700.0,
        "cx": 639.5,
        "cy": 359.5,
        "baseline": 0.12,
    },
    "fisheye-752x480": {
        "width": 752,
        "height": 480,
        "fx": 306.7,
        "cx": 375.5,
        "cy": 239.5,
        "baseline": 0.12,
    },
}
"""Stereo cameras of ``synth --camera``: KITTI's grey pair, a VI-sensor (EuRoC), a
RealSense-like depth camera, a ZED-like wide pair, a rectified fisheye (wide field of view)."""


def camera_options(name: str) -> dict[str, Any]:
    """Return the :class:`~pcainterp_stream.synth.SynthConfig` camera fields of a preset.

    Raises:
        ValueError: an unknown preset (the message lists the known ones).
    """
    if name not in CAMERAS:
        raise ValueError(f"unknown camera {name!r}; one of {', '.join(CAMERAS)}")
    preset: dict[str, Any] = dict(CAMERAS[name])
    preset["fy"] = preset["fx"]
    return preset


def scene_for(scene: str, seed: int) -> SceneKind:
    """Return the indoor scene kind of ``synth --scene`` (``indoor``: by the seed)."""
    if scene == "indoor":
        return list(SceneKind)[seed % len(SceneKind)]
    return SceneKind(scene)


def platform_for(platform: str, seed: int) -> Platform:
    """Return the platform of ``synth --platform`` (``auto``: by the seed)."""
    if platform == "auto":
        return list(Platform)[(seed // len(SceneKind)) % len(Platform)]
    return Platform(platform)
