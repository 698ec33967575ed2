"""A sparse feature stream's points as measurements: pixels and disparities of the left camera.

A stream may be far from sparse: a LiDAR scan or ``stereo_image_proc``'s ``points2`` has
tens of thousands of points in the image, and the estimate's local prior costs memory and
time with the square of the points (92,400 points are a 64 GiB matrix). The points in the
image are thinned as the stereo front end spaces its own measurements (corners, and a
lattice in their gaps): one per pixel, the nearest, and beyond ``max_points`` one per cell
of the coarsest square grid that keeps at most that many (:func:`thin_measurements`).
Points behind the camera, outside the image or nearer than the stereo pair sees
(:func:`too_near`) are dropped first.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from pcainterp_stream import defaults
from pcainterp_stream.records import SparseFeatures, StereoCamera

GRID_STEPS = 10
"""Bisection steps for the thinning grid's cell side, on a log scale from 0.5 px to the image's
side: 10 steps end within 1 % of the finest side that keeps ``max_points`` (up to 8000 px)."""


def features_to_measurements(
    features: SparseFeatures | None,
    camera: StereoCamera,
    max_points: int = defaults.MAX_FEATURES,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], dict[str, int]]:
    """Project sparse 3-D points of the left optical frame to pixels and disparities.

    Args:
        features: the frame's points, or None when the stream has none for this stamp.
        camera: the stereo calibration.
        max_points: most measurements kept (:func:`thin_measurements`), >= 1.

    Returns:
        pixels (k, 2) float32 (x, y) px, disparities (k,) float32 px = f*b / z, and counts:
        ``feature_cloud`` (1 when the frame had a cloud), ``features`` (its points),
        ``features_rejected`` (behind the camera, outside the image or too near),
        ``features_behind`` (of those, behind the camera: z <= 0), ``features_near`` (of
        those, in the image at a disparity over the image's width: nearer than
        ``focal_baseline / width``, where the right camera cannot see them; a
        triangulation failure of the stream's system, :func:`too_near`), ``features_thinned``
        (points in the image left out by the thinning) and ``features_cell`` (the thinning
        grid's cell side, px, rounded up; 0 when the cap was not reached).
    """
    cloud = int(features is not None)
    if features is None or features.points.size == 0:
        empty = np.zeros((0, 2), dtype=np.float32)
        counts = {"feature_cloud": cloud, "features": 0, "features_rejected": 0}
        counts |= {"features_behind": 0, "features_near": 0}
        return (
            empty,
            np.zeros(0, dtype=np.float32),
            counts | {"features_thinned": 0, "features_cell": 0},
        )
    points = features.points.astype(np.float64)
    z = points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * points[:, 0] / z + camera.cx
        v = camera.fy * points[:, 1] / z + camera.cy
        disparity = camera.focal_baseline / z
    seen = (
        np.isfinite(u)
        & np.isfinite(v)
        & (z > 0)
        & (u >= -0.5)
        & (u <= camera.width - 0.5)
        & (v >= -0.5)
        & (v <= camera.height - 0.5)
    )
    near = seen & too_near(disparity, camera.width)
    keep = seen & ~near
    pixels = np.stack([u[keep], v[keep]], axis=1).astype(np.float32)
    disparities = disparity[keep].astype(np.float32)
    kept, cell = thin_measurements(
        pixels, disparities, (camera.width, camera.height), max_points=max_points
    )
    counts = {
        "feature_cloud": cloud,
        "features": int(points.shape[0]),
        "features_rejected": int((~keep).sum()),
        "features_behind": int((~(z > 0)).sum()),
        "features_near": int(near.sum()),
        "features_thinned": int(pixels.shape[0] - kept.size),
        "features_cell": math.ceil(cell),
    }
    return pixels[kept], disparities[kept], counts


def too_near(disparity: npt.NDArray[np.float64], width: int) -> npt.NDArray[np.bool_]:
    """Return which disparities (px) no stereo pair of a camera ``width`` px wide measures.

    A point's match in the right image is its disparity to the left of its pixel; beyond the
    image's width it is outside the right image wherever the point is in the left one. Such
    a point is nearer than f*b / width (0.31 m for KITTI's 0.54 m baseline at 620 px, 2.5 cm
    for a 5 cm one at 1280 px): a triangulation failure of the system that published it (a
    point put at 1 cm on its ray has ~19,000 px). Near objects within the width stay, also
    beyond SGBM's range: a wide-baseline rig's point at 0.5 m (390 px on 620 px) is real, and
    a LiDAR measures it (a wrong one is left to the trimmed robust start,
    :class:`~pcainterp_stream.estimate.prior.RobustStart`).
    """
    result: npt.NDArray[np.bool_] = disparity > width
    return result


def thin_measurements(
    pixels: npt.NDArray[np.float32],
    disparities: npt.NDArray[np.float32],
    image_size: tuple[int, int],
    *,
    max_points: int,
) -> tuple[npt.NDArray[np.intp], float]:
    """Choose the measurements of a cloud to keep: one per pixel, at most ``max_points``.

    Points that fall on one pixel are one measurement: the nearest (largest disparity) is
    kept, as a depth buffer keeps the surface it sees (a LiDAR point behind it is occluded
    for the camera). When more than ``max_points`` remain, the image is cut into square
    cells, the smallest (found by bisection, :data:`GRID_STEPS`) of which at most
    ``max_points`` hold a point, and each cell keeps its point of median disparity
    (the lower median: a real point, robust to a few stray ones), as the stereo front end's
    lattice measures one point per cell in the gaps of its corners.

    Args:
        pixels: (n, 2) float32 (x, y) px, inside the image.
        disparities: (n,) float32 px.
        image_size: (width, height) px.
        max_points: most points kept, >= 1.

    Returns:
        the kept points' indices into ``pixels`` (ascending, intp) and the cell side (px;
        0.0 when no grid was needed).

    Examples:
        >>> pixels = np.array([[1.2, 1.0], [0.8, 1.1], [30.0, 5.0]], np.float32)
        >>> kept, cell = thin_measurements(
        ...     pixels, np.array([4.0, 6.0, 2.0], np.float32), (40, 10), max_points=5
        ... )
        >>> kept.tolist(), cell
        ([1, 2], 0.0)
    """
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    width, height = image_size
    count = pixels.shape[0]
    if count == 0:
        return np.zeros(0, dtype=np.intp), 0.0
    column = np.clip(np.rint(pixels[:, 0]), 0, width - 1).astype(np.int64)
    row = np.clip(np.rint(pixels[:, 1]), 0, height - 1).astype(np.int64)
    order = _sorted_by(row * width + column, -disparities)  # by pixel, nearest first
    pixel = (row * width + column)[order]
    first = np.ones(count, dtype=bool)
    first[1:] = pixel[1:] != pixel[:-1]
    kept = np.sort(order[first])
    if kept.size <= max_points:
        return kept, 0.0
    # from the image's corner (-0.5, -0.5), the far edge itself in the last cell
    x = np.clip(pixels[kept, 0].astype(np.float64) + 0.5, 0.0, np.nextafter(width, 0))
    y = np.clip(pixels[kept, 1].astype(np.float64) + 0.5, 0.0, np.nextafter(height, 0))

    def cells_of(side: float) -> npt.NDArray[np.int64]:
        cell_row = np.floor(y / side).astype(np.int64)
        cells: npt.NDArray[np.int64] = cell_row * math.ceil(width / side) + np.floor(
            x / side
        ).astype(np.int64)
        return cells

    def occupied(side: float) -> int:  # cells holding a point, without sorting
        held = np.zeros(math.ceil(width / side) * math.ceil(height / side), dtype=bool)
        held[cells_of(side)] = True
        return int(np.count_nonzero(held))

    # the finest grid with at most max_points occupied cells, by bisection of the side
    # (log scale): below 1 px every point has its cell, one cell the size of the image holds all
    fine, coarse = 0.5, float(max(width, height) + 1)
    for _ in range(GRID_STEPS):
        side = math.sqrt(fine * coarse)
        if occupied(side) <= max_points:
            coarse = side
        else:
            fine = side
    key = cells_of(coarse)
    cells = np.unique(key)
    order = _sorted_by(key, disparities[kept])  # by cell, then by disparity
    start = np.searchsorted(key[order], cells)
    sizes = np.diff(np.append(start, key.size))
    median = order[start + (sizes - 1) // 2]
    return np.sort(kept[median]), coarse


def _sorted_by(key: npt.NDArray[np.int64], then: npt.NDArray[np.float32]) -> npt.NDArray[np.intp]:
    """Return the order by ``key``, ties by ``then`` (``np.lexsort``'s, ~2x faster)."""
    order = np.argsort(then)  # ties of ``then`` in any order: either point will do
    result: npt.NDArray[np.intp] = order[np.argsort(key[order], kind="stable")]
    return result
