"""Ego-motion between stereo frames and measurements carried over from earlier frames.

A frame's ~360 corners leave most of the image far from any measurement: on the synthetic
test log two thirds of the mean error lies more than 40 px from the nearest point, on
large textureless surfaces (docs/options.md). The frames before saw other parts of the
scene. This module carries their measurements into the current frame:

* :func:`estimate_motion` -- stereo visual odometry from one frame to the next: the frame's
  measured corners (3-D from their disparities) are tracked back into the previous left
  image with pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK`` on half-size images,
  forward-backward checked) and the rigid motion is ``cv2.solvePnPRansac`` on those 3-D/2-D
  pairs, refined on the inliers (``cv2.solvePnPRefineLM``). It needs only the frame's own
  measurements and the previous image, so the stream processor runs it in the stereo
  worker threads, beside SGBM;
* :class:`CarriedPoints` -- the measurements of the last N frames as 3-D points, moved by
  the estimated motions into the current camera and projected; a carried point closer than
  ``gap`` px to a point already used is dropped (it adds little but costs a row of the k x k
  system). Each carried measurement gets an extra noise std ``age_std * age`` (px), passed to
  the estimate as ``noise_std`` (``estimator.densify``): the posterior stays exact for that
  noise model (independent Gaussian errors per measurement, growing linearly with age);
  what it does not model is correlated error of one frame's points through a wrong motion.

A failed motion (too few tracks or inliers) empties the history: the next frames start over.
Pure maths over arrays; nothing here knows about logs.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream import compiled
from pcainterp_stream.records import StereoCamera

__all__ = ["CarriedPoints", "CarryConfig", "Motion", "estimate_motion", "view_shift"]

FloatArray = npt.NDArray[np.float64]

TRACK_WINDOW = 11
"""Lucas-Kanade window (px of the half-size image)."""
TRACK_LEVELS = 3
"""Pyramid levels above half size: 16x, enough for ~1 m steps of a car at 10 Hz."""
MIN_DEPTH_M = 0.5
"""Carried points nearer than this (m) to the current camera are dropped."""


@dataclass(frozen=True)
class CarryConfig:
    """Options of carrying measurements over from earlier frames.

    Attributes:
        frames: earlier frames whose measurements are carried (0: off).
        gap: a carried point within this distance (px) of a point already used is dropped.
        age_std: extra noise std per frame of age (px of disparity).
        min_inliers: a motion with fewer PnP inliers counts as failed (history emptied).
        track_error: forward-backward Lucas-Kanade error (px) above which a track is dropped.
        reprojection_error: RANSAC inlier threshold of the PnP (px).
    """

    frames: int = 4
    gap: float = 30.0
    age_std: float = 1.0
    min_inliers: int = 20
    track_error: float = 1.0
    reprojection_error: float = 1.0

    def __post_init__(self) -> None:
        if self.frames < 0:
            raise ValueError(f"Expected carried `frames` >= 0, got {self.frames}")
        for name in ("gap", "age_std", "track_error", "reprojection_error"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"Expected `{name}` >= 0, got {value}")
        if self.min_inliers < 4:
            raise ValueError(f"Expected `min_inliers` >= 4 (PnP), got {self.min_inliers}")


class Motion(NamedTuple):
    """Rigid motion from one camera to the next.

    Attributes:
        transform: (4, 4) float64, maps a point of the previous left camera (m) to the
            current one: X_cur = R X_prev + t.
        inliers: PnP inliers it was estimated from.
        tracked: corners tracked into the new image (forward-backward checked).
    """

    transform: FloatArray
    inliers: int
    tracked: int


def back_project(
    pixels: npt.ArrayLike, disparities: npt.ArrayLike, camera: StereoCamera
) -> FloatArray:
    """Return the (k, 3) float64 points (m) of the left camera seen at pixels, disparities.

    Args:
        pixels: (k, 2) float, (x, y) in px.
        disparities: (k,) float, > 0 (px).
        camera: the rectified stereo camera.
    """
    pixel_array = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    depth = camera.focal_baseline / np.asarray(disparities, dtype=np.float64)
    return np.stack(
        [
            (pixel_array[:, 0] - camera.cx) * depth / camera.fx,
            (pixel_array[:, 1] - camera.cy) * depth / camera.fy,
            depth,
        ],
        axis=1,
    )


def project(
    points: FloatArray, camera: StereoCamera
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """Project (k, 3) points (m) of the left camera: pixels (k, 2), disparities (k,), in view.

    In view: in front of the camera by at least :data:`MIN_DEPTH_M` and inside the image.
    """
    depth = points[:, 2]
    visible = np.isfinite(depth) & (depth > MIN_DEPTH_M)
    safe = np.where(visible, depth, 1.0)
    x = camera.fx * points[:, 0] / safe + camera.cx
    y = camera.fy * points[:, 1] / safe + camera.cy
    visible &= (x >= -0.5) & (x <= camera.width - 0.5) & (y >= -0.5) & (y <= camera.height - 0.5)
    return np.stack([x, y], axis=1), camera.focal_baseline / safe, visible


def view_shift(
    transform: FloatArray, pixels: npt.ArrayLike, disparities: npt.ArrayLike, camera: StereoCamera
) -> float:
    """Return how far a motion moves a frame's measurements in the image (px; inf if unknown).

    Each measurement is moved back by the motion into the earlier camera and projected
    there; the figure is the median of its image displacement and disparity change
    (``hypot(dx, dy, dd)``). A camera standing still measures ~0.1 px (the motion's own
    noise); 1 cm and 0.5 degree at 10 m is a few px.

    Args:
        transform: (4, 4) float64, the earlier camera -> this one (X = R X_earlier + t).
        pixels: (k, 2) float, (x, y) px of this frame's measurements.
        disparities: (k,) float (px).
        camera: the rectified stereo camera of both frames.
    """
    pixel_array = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    disparity_array = np.asarray(disparities, dtype=np.float64).reshape(-1)
    usable = np.isfinite(disparity_array) & (disparity_array > 0)
    if not usable.any():
        return math.inf
    points = back_project(pixel_array[usable], disparity_array[usable], camera)
    rotation, translation = transform[:3, :3], transform[:3, 3]
    earlier = (points - translation) @ rotation  # R^T (X - t), row by row
    depth = earlier[:, 2]
    if not np.all(np.isfinite(depth) & (depth > 0)):
        return math.inf
    x = camera.fx * earlier[:, 0] / depth + camera.cx
    y = camera.fy * earlier[:, 1] / depth + camera.cy
    moved = np.stack(
        [x - pixel_array[usable, 0], y - pixel_array[usable, 1], camera.focal_baseline / depth]
    )
    moved[2] -= disparity_array[usable]
    return float(np.median(np.sqrt((moved**2).sum(axis=0))))


def _intrinsics(camera: StereoCamera) -> FloatArray:
    return np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])


def estimate_motion(
    previous_image: npt.NDArray[np.uint8],
    image: npt.NDArray[np.uint8],
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    camera: StereoCamera,
    *,
    config: CarryConfig | None = None,
) -> Motion | None:
    """Estimate the left camera's motion from the previous frame to this one.

    Args:
        previous_image: (H, W) uint8, the previous left image.
        image: (H, W) uint8, this frame's left image.
        pixels: (k, 2) float, (x, y) px of this frame's measurements.
        disparities: (k,) float, their disparities (px).
        camera: the rectified stereo camera (both frames).
        config: thresholds (:class:`CarryConfig`).

    Returns:
        The :class:`Motion`, or None when too few corners track or agree on one motion.
    """
    options = config or CarryConfig()
    pixel_array = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    disparity_array = np.asarray(disparities, dtype=np.float64).reshape(-1)
    usable = np.isfinite(disparity_array) & (disparity_array > 0)
    if np.count_nonzero(usable) < options.min_inliers or previous_image.shape != image.shape:
        return None
    pixel_array, disparity_array = pixel_array[usable], disparity_array[usable]
    # tracked on the half-size images: 4x fewer pixels per window, ~0.1 px accuracy;
    # cv2.pyrDown centres half-size pixel i on full-size pixel 2 i
    half, previous_half = cv2.pyrDown(image), cv2.pyrDown(previous_image)
    start = (pixel_array / 2.0).astype(np.float32).reshape(-1, 1, 2)
    window = (TRACK_WINDOW, TRACK_WINDOW)
    behind, status, _ = cv2.calcOpticalFlowPyrLK(
        half, previous_half, start, start.copy(), winSize=window, maxLevel=TRACK_LEVELS
    )
    tracked = status.ravel() == 1
    if options.track_error > 0:
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(
            previous_half, half, behind, behind.copy(), winSize=window, maxLevel=TRACK_LEVELS
        )
        round_trip = 2.0 * np.linalg.norm((back - start).reshape(-1, 2), axis=1)
        tracked &= (status_back.ravel() == 1) & (round_trip < options.track_error)
    if np.count_nonzero(tracked) < options.min_inliers:
        return None
    object_points = back_project(pixel_array[tracked], disparity_array[tracked], camera)
    image_points = behind.reshape(-1, 2)[tracked].astype(np.float64) * 2.0
    intrinsics = _intrinsics(camera)
    # PnP: this camera's points seen in the previous image give X_prev = R X + t
    found, rotation, translation, inliers = cv2.solvePnPRansac(
        object_points,
        image_points,
        intrinsics,
        None,
        reprojectionError=options.reprojection_error,
        iterationsCount=100,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not found or inliers is None or len(inliers) < options.min_inliers:
        return None
    chosen = inliers.ravel()
    rotation, translation = cv2.solvePnPRefineLM(
        object_points[chosen], image_points[chosen], intrinsics, None, rotation, translation
    )
    to_previous = np.eye(4)
    to_previous[:3, :3] = cv2.Rodrigues(rotation)[0]
    to_previous[:3, 3] = translation.ravel()
    if not np.all(np.isfinite(to_previous)):
        return None
    # previous -> this camera: X = R^T (X_prev - t)
    transform = np.eye(4)
    transform[:3, :3] = to_previous[:3, :3].T
    transform[:3, 3] = -to_previous[:3, :3].T @ to_previous[:3, 3]
    return Motion(transform, int(chosen.size), int(np.count_nonzero(tracked)))


@dataclass
class _Past:
    points: FloatArray  # (k, 3) m, in the camera of the frame they were measured in
    to_current: FloatArray  # (4, 4) that camera -> the current camera


@dataclass
class CarriedPoints:
    """Measurements of the last frames of a stream, carried into the current frame.

    An accumulator: call :meth:`carry` once per frame in stream order.

    Attributes:
        config: the options.
        resets: times a failed motion emptied the history.
    """

    config: CarryConfig = field(default_factory=CarryConfig)
    resets: int = 0
    _history: deque[_Past] = field(default_factory=deque, repr=False)
    _previous: tuple[npt.NDArray[np.uint8] | None, StereoCamera] | None = field(
        default=None, repr=False
    )

    def reset(self) -> None:
        """Forget every earlier frame."""
        self._history.clear()
        self._previous = None

    def carry(
        self,
        image: npt.NDArray[np.uint8] | None,
        pixels: npt.ArrayLike,
        disparities: npt.ArrayLike,
        camera: StereoCamera,
        *,
        motion: Motion | str | None = "estimate",
    ) -> tuple[FloatArray, FloatArray, FloatArray, int]:
        """Add this frame and return its measurements with the carried ones appended.

        Args:
            image: (H, W) uint8, this frame's left image (for the motion); None when
                ``motion`` is given.
            pixels: (k, 2) float, (x, y) px of this frame's measurements.
            disparities: (k,) float (px).
            camera: the frame's camera; a different camera than the last frame's restarts.
            motion: the motion from the previous frame, None when unknown (restart), or
                ``"estimate"``: :func:`estimate_motion` from the previous frame's image.

        Returns:
            pixels (m, 2), disparities (m,), noise_std (m,) (0 for this frame's own, then
            ``age_std * age``) in float64, and the number m - k of carried measurements.
        """
        own_pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        own_disparities = np.asarray(disparities, dtype=np.float64).reshape(-1)
        options = self.config
        previous, self._previous = self._previous, (image, camera)
        if isinstance(motion, str):
            motion = None
            if (
                previous is not None
                and previous[0] is not None
                and image is not None
                and previous[1] == camera
                and options.frames
            ):
                motion = estimate_motion(
                    previous[0], image, own_pixels, own_disparities, camera, config=options
                )
        if previous is not None:
            if motion is None or previous[1] != camera:
                if self._history:
                    self.resets += 1
                self._history.clear()
            else:
                for past in self._history:
                    past.to_current = motion.transform @ past.to_current
        all_pixels = [own_pixels]
        all_disparities = [own_disparities]
        noise = [np.zeros(own_disparities.shape)]
        used = own_pixels[np.isfinite(own_disparities)]
        for age, past in enumerate(reversed(self._history), start=1):
            moved = past.points @ past.to_current[:3, :3].T + past.to_current[:3, 3]
            carried_pixels, carried_disparities, visible = project(moved, camera)
            carried_pixels, carried_disparities = (
                carried_pixels[visible],
                carried_disparities[visible],
            )
            if used.shape[0] and carried_pixels.shape[0] and options.gap > 0:
                # scipy's k-d tree alone, loaded when first needed (scipy.spatial: ~0.3 s)
                tree = compiled.module("spatial._ckdtree").cKDTree(used)
                distance, _ = tree.query(carried_pixels)
                far = distance > options.gap
                carried_pixels, carried_disparities = carried_pixels[far], carried_disparities[far]
            all_pixels.append(carried_pixels)
            all_disparities.append(carried_disparities)
            noise.append(np.full(carried_disparities.shape, options.age_std * age))
            used = np.concatenate([used, carried_pixels])
        valid = np.isfinite(own_disparities) & (own_disparities > 0)
        self._history.append(
            _Past(back_project(own_pixels[valid], own_disparities[valid], camera), np.eye(4))
        )
        while len(self._history) > options.frames:
            self._history.popleft()
        joined_disparities = np.concatenate(all_disparities)
        return (
            np.concatenate(all_pixels),
            joined_disparities,
            np.concatenate(noise),
            int(joined_disparities.size - own_disparities.size),
        )
