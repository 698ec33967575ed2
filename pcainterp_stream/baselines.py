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
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import QhullError

from pcainterp_stream.estimator import clean_measurements


@dataclass(frozen=True, eq=False)
class BaselineResult:
    """A baseline's dense estimate.

    Attributes:
        disparity: (H, W) float32 (px); NaN everywhere when there was no measurement.
        pixels: (k, 2) float64, the measurements used, (x, y) in image px.
        disparities: (k,) float64, their disparities (px).
        n_dropped: measurements dropped (non-finite or outside the image).
    """

    disparity: npt.NDArray[np.float32]
    pixels: npt.NDArray[np.float64]
    disparities: npt.NDArray[np.float64]
    n_dropped: int


def nearest(
    pixels: npt.ArrayLike, disparities: npt.ArrayLike, *, image_size: tuple[int, int]
) -> BaselineResult:
    """Nearest-measurement interpolation.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px).
        image_size: (height, width) of the output.

    Returns:
        The :class:`BaselineResult`; each pixel takes the disparity of the measurement
        whose (rounded) pixel is nearest.
    """
    points, values, n_dropped = clean_measurements(pixels, disparities, image_size)
    return BaselineResult(_nearest_map(points, values, image_size), points, values, n_dropped)


def linear(
    pixels: npt.ArrayLike, disparities: npt.ArrayLike, *, image_size: tuple[int, int]
) -> BaselineResult:
    """Piecewise-linear interpolation on the Delaunay triangulation of the measurements.

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        disparities: (k,) float (px).
        image_size: (height, width) of the output.

    Returns:
        The :class:`BaselineResult`; outside the convex hull (or with fewer than three
        non-collinear measurements) the nearest measurement's value.
    """
    points, values, n_dropped = clean_measurements(pixels, disparities, image_size)
    dense = _nearest_map(points, values, image_size)
    if points.shape[0] >= 3:
        height, width = image_size
        try:
            interpolator = LinearNDInterpolator(points, values, fill_value=np.nan)
        except QhullError:
            return BaselineResult(dense, points, values, n_dropped)
        xs, ys = np.meshgrid(np.arange(width), np.arange(height))
        inside = interpolator(xs, ys).astype(np.float32)
        dense = np.where(np.isnan(inside), dense, inside)
    return BaselineResult(dense, points, values, n_dropped)


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
