"""A sparse LiDAR-like ground truth: a rotating multi-beam scanner projected into the left camera.

Real logs rarely have dense depth truth; what they have is projected LiDAR (KITTI's
annotated depth and its raw Velodyne scans are a few percent of the pixels, in scan lines).
This module makes the same kind of truth from a synthetic frame's dense z-depth, so that
``pcainterp evaluate --reference-topic`` can be tested on sparse truth with known values.

The scanner is a 64-beam one like KITTI's Velodyne HDL-64E: beam elevations from +2 deg to
-24.8 deg (32 beams 1/3 deg apart above -8.33 deg, 32 about 1/2 deg apart below), and a
return every :attr:`LidarConfig.azimuth_step_deg` of rotation. It sits at the left camera's
optical centre (the camera is level in the synthetic world), so a beam at elevation phi and
azimuth theta (right of the optical axis) lands on

    u = cx + fx tan(theta),    v = cy - fy tan(phi) / cos(theta),

curved scan lines as in real projected scans, and its return is the true depth at that pixel
(no parallax between scanner and camera, so no occlusion artefacts: the values are truth).
A beam into the sky, beyond :attr:`LidarConfig.max_range_m` (range along the ray, not
z-depth), or dropped at random (dark or specular surfaces, :attr:`LidarConfig.dropout`)
returns nothing.

Scale: the angular pattern is defined at KITTI's focal length (:data:`KITTI_FOCAL`); for a
camera of focal length f both angular spacings are multiplied by KITTI_FOCAL / f, so a
quarter-size log gets a 16-beam scanner with 4x the azimuth step. The pattern on the image
(scan lines a few pixels apart, a few percent of the pixels) is then the same at every
``--scale``, as the rest of the synthetic image is.

Determinism: the only randomness, the scan's azimuth phase and the dropouts of a frame, is
drawn from ``numpy.random.default_rng((seed, 11, frame_index))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.io.stereo_log import LIDAR_DEPTH as LIDAR_DEPTH
from pcainterp_stream.records import StereoCamera

KITTI_FOCAL = 718.856
"""Focal length (px) at which the scanner is the HDL-64E (full-size synthetic logs)."""

_HDL64_ELEVATIONS_DEG = np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)])
"""The HDL-64E's 64 beam elevations (deg): an upper and a lower block of 32 lasers."""


@dataclass(frozen=True)
class LidarConfig:
    """Options of the LiDAR-like truth.

    Attributes:
        seed: seed of the azimuth phase and the dropouts (the drive's seed).
        beams: beams at :data:`KITTI_FOCAL`; their elevations follow the HDL-64E's profile.
        azimuth_step_deg: rotation between two returns of a beam at :data:`KITTI_FOCAL`
            (deg); KITTI's scans have ~2000 returns per beam and turn, ~0.18 deg.
        max_range_m: farthest return (m, along the ray).
        dropout: share of the returns dropped at random.
    """

    seed: int = 0
    beams: int = 64
    azimuth_step_deg: float = 0.18
    max_range_m: float = 120.0
    dropout: float = 0.02

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.beams < 2:
            raise ValueError(f"beams must be at least 2, got {self.beams}")
        if not 0.0 < self.azimuth_step_deg <= 5.0:
            raise ValueError(f"azimuth_step_deg must be in (0, 5], got {self.azimuth_step_deg}")
        if not self.max_range_m > 0.0:
            raise ValueError(f"max_range_m must be > 0, got {self.max_range_m}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")

    def elevations_deg(self, camera: StereoCamera) -> npt.NDArray[np.float64]:
        """Return the beam elevations (deg, descending) for a camera, scaled to its focal length."""
        count = max(2, round(self.beams * camera.fy / KITTI_FOCAL))
        index = np.linspace(0.0, 1.0, count) * (len(_HDL64_ELEVATIONS_DEG) - 1)
        elevations: npt.NDArray[np.float64] = np.interp(
            index, np.arange(len(_HDL64_ELEVATIONS_DEG)), _HDL64_ELEVATIONS_DEG
        )
        return elevations

    def azimuth_step_rad(self, camera: StereoCamera) -> float:
        """Return the azimuth step (rad) for a camera, scaled to its focal length."""
        return float(np.radians(self.azimuth_step_deg) * KITTI_FOCAL / camera.fx)


def lidar_depth(
    depth: npt.ArrayLike,
    camera: StereoCamera,
    *,
    frame_index: int,
    config: LidarConfig | None = None,
) -> npt.NDArray[np.float32]:
    """Return the sparse LiDAR-like depth image of one frame.

    Args:
        depth: (H, W) float, the left camera's true z-depth (m), NaN for sky.
        camera: the left camera (``camera.image_size`` == ``depth.shape``).
        frame_index: the frame's number (seeds its scan phase and dropouts).
        config: scanner options (default :class:`LidarConfig`).

    Returns:
        (H, W) float32 z-depth (m) at the pixels a return lands on, equal to ``depth``
        there; NaN elsewhere.

    Raises:
        ValueError: ``depth`` is not of the camera's image size.
    """
    config = config or LidarConfig()
    truth = np.asarray(depth, dtype=np.float32)
    if truth.shape != camera.image_size:
        raise ValueError(f"Expected `depth` of shape {camera.image_size}, got {truth.shape}")
    rng = np.random.default_rng((config.seed, 11, frame_index))
    step = config.azimuth_step_rad(camera)
    # the azimuths whose rays stay inside the image columns, from a random scan phase
    left = np.arctan((-0.5 - camera.cx) / camera.fx)
    right = np.arctan((camera.width - 0.5 - camera.cx) / camera.fx)
    start = left + rng.uniform(0.0, step)
    azimuth = start + step * np.arange(max(int(np.floor((right - start) / step)) + 1, 0))
    elevation = np.radians(config.elevations_deg(camera))
    # eq. in the module docstring: pinhole projection of the beam direction
    u = camera.cx + camera.fx * np.tan(azimuth)[None, :]
    v = camera.cy - camera.fy * np.tan(elevation)[:, None] / np.cos(azimuth)[None, :]
    columns = np.rint(np.broadcast_to(u, v.shape)).astype(np.int64).ravel()
    rows = np.rint(v).astype(np.int64).ravel()
    inside = (rows >= 0) & (rows < camera.height) & (columns >= 0) & (columns < camera.width)
    kept = rng.random(rows.size) >= config.dropout
    rows, columns = rows[inside & kept], columns[inside & kept]
    z = truth[rows, columns]
    ray = np.sqrt(
        ((columns - camera.cx) / camera.fx) ** 2 + ((rows - camera.cy) / camera.fy) ** 2 + 1.0
    )
    with np.errstate(invalid="ignore"):
        hit = np.isfinite(z) & (z > 0) & (z * ray <= config.max_range_m)
    out = np.full(camera.image_size, np.nan, dtype=np.float32)
    out[rows[hit], columns[hit]] = z[hit]
    return out
