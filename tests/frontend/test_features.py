"""A feature stream's points as measurements: projection and the thinning of dense clouds."""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream import defaults
from pcainterp_stream.frontend.features import features_to_measurements, thin_measurements
from pcainterp_stream.records import SparseFeatures, StereoCamera

CAMERA = StereoCamera(width=160, height=60, fx=100.0, fy=100.0, cx=80.0, cy=30.0, baseline=0.5)


def _cloud(u: np.ndarray, v: np.ndarray, z: np.ndarray) -> SparseFeatures:
    """Points of the left optical frame that project to pixels (u, v) at depth z (m)."""
    x = (u - CAMERA.cx) * z / CAMERA.fx
    y = (v - CAMERA.cy) * z / CAMERA.fy
    points = np.stack([x, y, z], axis=1).astype(np.float32)
    return SparseFeatures(stamp_ns=1, log_time_ns=1, frame_id="left", points=points)


def test_a_dense_cloud_is_thinned_to_one_point_per_cell_across_the_image() -> None:
    # stereo_image_proc's points2: a point at every pixel (9,600), depth varying
    v, u = (a.reshape(-1).astype(np.float64) for a in np.mgrid[0:60, 0:160])
    z = 5.0 + u / 40.0
    pixels, disparities, counts = features_to_measurements(_cloud(u, v, z), CAMERA, max_points=100)
    assert 80 <= pixels.shape[0] <= 100  # the finest grid that keeps at most 100
    assert counts["features"] == 9600
    assert counts["features_thinned"] == 9600 - pixels.shape[0]
    assert counts["features_cell"] >= 9
    # spread over the image as a lattice is: every 40x30 px block keeps points
    # (a pixel of row 0 comes back at y = -1e-6 or so through the float32 cloud: round first)
    blocks = {(round(x) // 40, round(y) // 30) for x, y in pixels}
    assert len(blocks) == 8
    # each kept point is one of the cloud's, not an average
    np.testing.assert_allclose(disparities, CAMERA.focal_baseline / (5.0 + pixels[:, 0] / 40.0))


def test_the_default_cap_holds_for_a_cloud_far_beyond_it() -> None:
    rng = np.random.default_rng(0)
    n = 20 * defaults.MAX_FEATURES
    u, v = rng.uniform(0, 159, n), rng.uniform(0, 59, n)
    pixels, _, counts = features_to_measurements(_cloud(u, v, rng.uniform(2, 50, n)), CAMERA)
    assert pixels.shape[0] <= defaults.MAX_FEATURES
    assert counts["features_thinned"] == n - pixels.shape[0]


def test_points_on_one_pixel_keep_the_nearest() -> None:
    # a LiDAR point behind a nearer one on the same pixel is occluded for the camera
    u = np.array([40.2, 39.9, 100.0])
    v = np.array([20.1, 19.8, 50.0])
    z = np.array([20.0, 5.0, 10.0])
    pixels, disparities, counts = features_to_measurements(_cloud(u, v, z), CAMERA)
    np.testing.assert_allclose(pixels, [[39.9, 19.8], [100.0, 50.0]], atol=1e-4)
    np.testing.assert_allclose(disparities, CAMERA.focal_baseline / np.array([5.0, 10.0]))
    assert counts["features_thinned"] == 1
    assert counts["features_cell"] == 0  # under the cap: no grid


def test_a_cell_keeps_its_median_disparity_point() -> None:
    pixels = np.array([[1, 1], [2, 2], [3, 1], [1, 3], [30, 30]], np.float32)
    disparities = np.array([9.0, 1.0, 5.0, 100.0, 7.0], np.float32)  # 100: a stray point
    kept, cell = thin_measurements(pixels, disparities, (40, 40), max_points=2)
    assert cell > 3
    assert kept.tolist() == [2, 4]  # the median of 1, 5, 9, 100 (the lower one) and the lone one


def test_a_sparse_cloud_is_kept_whole() -> None:
    pixels = np.array([[1, 1], [20, 5], [35, 30]], np.float32)
    kept, cell = thin_measurements(pixels, np.ones(3, np.float32), (40, 40), max_points=3)
    assert kept.tolist() == [0, 1, 2]
    assert cell == 0.0
    with pytest.raises(ValueError, match="max_points must be >= 1"):
        thin_measurements(pixels, np.ones(3, np.float32), (40, 40), max_points=0)


def test_points_nearer_than_the_pair_sees_are_dropped_and_counted() -> None:
    # a triangulation failure: a point put at 1 cm on its ray has a disparity of 5000 px on a
    # 160 px image; no stereo pair of this camera (f*b 50 px*m) sees nearer than 0.3125 m
    u = np.array([20.0, 40.0, 60.0, 80.0, 100.0, 170.0])
    v = np.full(6, 30.0)
    z = np.array([0.4, 0.3, 0.01, 10.0, 0.3126, 0.01])  # the last outside the image
    pixels, disparities, counts = features_to_measurements(_cloud(u, v, z), CAMERA)
    np.testing.assert_allclose(pixels[:, 0], [20.0, 80.0, 100.0], atol=1e-3)
    np.testing.assert_allclose(disparities, 50.0 / np.array([0.4, 10.0, 0.3126]), rtol=1e-6)
    assert counts["features_near"] == 2
    assert counts["features_rejected"] == 3  # with the one outside the image
    assert counts["features_behind"] == 0
