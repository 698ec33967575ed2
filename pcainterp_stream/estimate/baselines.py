"""Basis-free interpolation baselines with the call shape of :func:`~.estimator.densify`.

Both fill an (H, W) disparity map from k sparse measurements, for comparison with the PCA
estimate: ``nearest`` copies the closest measurement (Voronoi cells, via OpenCV's labelled
distance transform), ``linear`` interpolates on the Delaunay triangulation
(``scipy.interpolate.LinearNDInterpolator``) and falls back to nearest outside the convex
hull. Neither gives an uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from scipy.spatial import Delaunay, QhullError

from pcainterp_stream.estimate.estimator import clean_measurements


@dataclass(frozen=True, eq=False)
class BaselineResult:
    """A baseline's dense estimate.

    Attributes:
        disparity: (H, W) float32 (px); NaN everywhere when there was no measurement.
        pixels: (k, 2) float64, the measurements used, (x, y) in image px.
        disparities: (k,) float64, their disparities (px).
        n_dropped: measurements dropped (non-finite, <= 0 or outside the image).
    """

    disparity: npt.NDArray[np.float32]
    pixels: npt.NDArray[np.float64]
    disparities: npt.NDArray[np.float64]
    n_dropped: int


def nearest(
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    image_size: tuple[int, int],
    zero_is_match: bool = False,
) -> BaselineResult:
    """Nearest-measurement interpolation.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px); <= 0 is no measurement and is dropped, as in
            :func:`~.estimator.densify`.
        image_size: (height, width) of the output.
        zero_is_match: keep disparities of exactly 0 (see :func:`~.estimator.densify`).

    Returns:
        The :class:`BaselineResult`; each pixel takes the disparity of the measurement
        whose (rounded) pixel is nearest.
    """
    points, values, n_dropped = clean_measurements(
        pixels, disparities, image_size, zero_is_match=zero_is_match
    )
    return BaselineResult(_nearest_map(points, values, image_size), points, values, n_dropped)


def linear(
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    *,
    image_size: tuple[int, int],
    zero_is_match: bool = False,
) -> BaselineResult:
    """Piecewise-linear interpolation on the Delaunay triangulation of the measurements.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px); <= 0 is no measurement and is dropped, as in
            :func:`~.estimator.densify`.
        image_size: (height, width) of the output.
        zero_is_match: keep disparities of exactly 0 (see :func:`~.estimator.densify`).

    Returns:
        The :class:`BaselineResult`; outside the convex hull (or with fewer than three
        non-collinear measurements) the nearest measurement's value.
    """
    points, values, n_dropped = clean_measurements(
        pixels, disparities, image_size, zero_is_match=zero_is_match
    )
    dense = _nearest_map(points, values, image_size)
    if points.shape[0] >= 3:
        try:
            triangulation = Delaunay(points)
        except QhullError:
            return BaselineResult(dense, points, values, n_dropped)
        inside = _interpolate_triangles(triangulation, values, image_size)
        dense = np.where(np.isnan(inside), dense, inside)
    return BaselineResult(dense, points, values, n_dropped)


_SHIFT = 8  # fractional bits of the rasterised triangle vertices


def _interpolate_triangles(
    triangulation: Delaunay, values: npt.NDArray[np.float64], image_size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Linear interpolation inside the triangles, NaN outside the convex hull.

    Each triangle is rasterised once with its index (a loop over the few hundred triangles,
    not over pixels), then every covered pixel takes the barycentric combination of its
    triangle's three values. (scipy's LinearNDInterpolator needs ``Delaunay.transform``,
    which took ~5 s per KITTI-size frame here.)
    """
    simplices = triangulation.simplices
    owner = np.full(image_size, -1, dtype=np.int32)
    corners = np.rint(triangulation.points[simplices] * (1 << _SHIFT)).astype(np.int32)
    for index, triangle in enumerate(corners):
        cv2.fillConvexPoly(owner, triangle, index, lineType=cv2.LINE_8, shift=_SHIFT)
    rows, cols = np.nonzero(owner >= 0)
    triangles = owner[rows, cols]
    pixel_points = np.stack([cols, rows], axis=1).astype(np.float64)
    inverse, origin = _barycentric_transforms(triangulation.points[simplices])
    weights = _barycentric(inverse, origin, triangles, pixel_points)
    # Rasterisation rounds edges to the pixel grid, so a pixel near an edge may have been
    # painted by a triangle that does not contain it (with slivers, not even a neighbour
    # of the right one): locate those few pixels among all triangles.
    outside = weights.min(axis=1) < -1e-9
    for side in range(3):  # most belong to the neighbour across the nearest edge
        which = np.flatnonzero(outside)
        neighbour = triangulation.neighbors[triangles[which], side]
        which, neighbour = which[neighbour >= 0], neighbour[neighbour >= 0]
        candidate = _barycentric(inverse, origin, neighbour, pixel_points[which])
        fits = candidate.min(axis=1) >= -1e-9
        triangles[which[fits]] = neighbour[fits]
        weights[which[fits]] = candidate[fits]
        outside[which[fits]] = False
    outside = np.flatnonzero(outside)
    everything = np.arange(simplices.shape[0])
    for start in range(0, outside.size, 1024):
        which = outside[start : start + 1024]
        # (pixels, triangles, 3) barycentric coordinates of every pixel in every triangle
        offset = pixel_points[which, None, :] - origin[None, :, :]
        first_two = np.einsum("tij,ptj->pti", inverse, offset)
        all_weights = np.concatenate(
            [first_two, 1.0 - first_two.sum(axis=2, keepdims=True)], axis=2
        )
        slack = all_weights.min(axis=2)
        best = np.nanargmax(np.where(np.isnan(slack), -np.inf, slack), axis=1)
        triangles[which] = everything[best]
        weights[which] = all_weights[np.arange(which.size), best]
    # pixels left with a negative weight lie within rounding of the hull: clamp them
    weights = np.clip(weights, 0.0, 1.0)
    weights /= weights.sum(axis=1, keepdims=True)
    dense = np.full(image_size, np.nan, dtype=np.float32)
    dense[rows, cols] = np.einsum("ni,ni->n", weights, values[simplices[triangles]])
    return dense


def _barycentric_transforms(
    vertices: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Per triangle, the inverse of [v0 - v2, v1 - v2] (2 x 2) and the origin v2.

    Computed in closed form: scipy's ``Delaunay.transform`` computes the same with a LAPACK
    call per triangle, which took seconds here.
    """
    origin = vertices[:, 2]
    a = vertices[:, 0] - origin
    b = vertices[:, 1] - origin
    determinant = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    determinant = np.where(np.abs(determinant) < 1e-12, np.nan, determinant)
    inverse = np.empty((vertices.shape[0], 2, 2))
    inverse[:, 0, 0] = b[:, 1] / determinant
    inverse[:, 0, 1] = -b[:, 0] / determinant
    inverse[:, 1, 0] = -a[:, 1] / determinant
    inverse[:, 1, 1] = a[:, 0] / determinant
    return inverse, origin


def _barycentric(
    inverse: npt.NDArray[np.float64],
    origin: npt.NDArray[np.float64],
    triangles: npt.NDArray[np.int32],
    points: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """Barycentric coordinates (n, 3) of points (n, 2) in the given triangles (n,)."""
    first_two = np.einsum("nij,nj->ni", inverse[triangles], points - origin[triangles])
    return np.concatenate([first_two, 1.0 - first_two.sum(axis=1, keepdims=True)], axis=1)


def _nearest_map(
    points: npt.NDArray[np.float64], values: npt.NDArray[np.float64], image_size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    height, width = image_size
    if points.shape[0] == 0:
        return np.full(image_size, np.nan, dtype=np.float32)
    cols = np.clip(np.rint(points[:, 0]).astype(np.intp), 0, width - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(np.intp), 0, height - 1)
    source = np.ones(image_size, dtype=np.uint8)
    source[rows, cols] = 0
    _, labels = cv2.distanceTransformWithLabels(
        source, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    # several measurements may round to one pixel: the last one written wins
    by_label = np.zeros(int(labels.max()) + 1, dtype=np.float32)
    by_label[labels[rows, cols]] = values
    return np.asarray(by_label[labels], dtype=np.float32)
