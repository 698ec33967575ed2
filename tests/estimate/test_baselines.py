from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream.estimate.baselines import linear, nearest


def test_linear_reproduces_a_plane_inside_hull() -> None:
    rng = np.random.default_rng(0)
    pixels = rng.uniform(0, [59, 39], (80, 2))
    plane = 3.0 + 0.2 * pixels[:, 0] - 0.1 * pixels[:, 1]
    result = linear(pixels, plane, image_size=(40, 60))
    ys, xs = np.mgrid[0:40, 0:60]
    truth = 3.0 + 0.2 * xs - 0.1 * ys
    assert result.disparity.dtype == np.float32
    assert result.disparity.shape == (40, 60)
    assert np.isfinite(result.disparity).all()
    inside = (xs > 8) & (xs < 50) & (ys > 8) & (ys < 30)
    np.testing.assert_allclose(result.disparity[inside], truth[inside], atol=1e-3)


def test_nearest_takes_closest_measurement() -> None:
    pixels = np.array([[2.0, 2.0], [17.0, 8.0]])
    result = nearest(pixels, np.array([5.0, 9.0]), image_size=(10, 20))
    assert result.disparity[0, 0] == 5.0
    assert result.disparity[9, 19] == 9.0
    assert set(np.unique(result.disparity)) == {5.0, 9.0}


def test_baselines_drop_bad_measurements_and_handle_empty() -> None:
    pixels = np.array([[1.0, 1.0], [np.nan, 1.0], [100.0, 1.0]])
    result = linear(pixels, np.array([4.0, 5.0, 6.0]), image_size=(10, 20))
    assert result.n_dropped == 2
    np.testing.assert_array_equal(result.disparity, 4.0)
    empty = nearest(np.zeros((0, 2)), np.zeros(0), image_size=(3, 4))
    assert np.isnan(empty.disparity).all()


def test_baselines_validate_shapes() -> None:
    with pytest.raises(ValueError, match=r"`pixels` of shape \(k, 2\)"):
        nearest(np.zeros((2, 3)), np.zeros(2), image_size=(3, 4))


def test_linear_matches_scipy_linear_nd_interpolator_inside_the_hull() -> None:
    from scipy.interpolate import LinearNDInterpolator

    from pcainterp_stream.estimate.baselines import linear

    rng = np.random.default_rng(3)
    height, width = 90, 300
    pixels = np.c_[rng.uniform(0, width - 1, 150), rng.uniform(0, height - 1, 150)]
    values = rng.uniform(0, 60, 150)
    dense = linear(pixels, values, image_size=(height, width)).disparity
    xs, ys = np.meshgrid(np.arange(width), np.arange(height))
    reference = LinearNDInterpolator(pixels, values)(xs, ys)
    inside = np.isfinite(reference)
    assert inside.mean() > 0.8
    np.testing.assert_allclose(dense[inside], reference[inside], atol=1e-4)


def test_baselines_drop_disparities_at_or_below_zero() -> None:
    pixels = np.array([[1.0, 1.0], [10.0, 5.0], [15.0, 8.0], [3.0, 8.0]])
    values = np.array([4.0, 0.0, -1.0, 6.0])
    for baseline in (nearest, linear):
        result = baseline(pixels, values, image_size=(10, 20))
        assert result.n_dropped == 2
        assert set(np.unique(result.disparity)) <= {4.0, 6.0}
        kept = baseline(pixels, values, image_size=(10, 20), zero_is_match=True)
        assert kept.n_dropped == 1
        assert 0.0 in kept.disparities
    with pytest.raises(TypeError, match="int16"):
        nearest(pixels, (values * 16).astype(np.int16), image_size=(10, 20))
