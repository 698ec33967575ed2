"""Message construction details that other readers rely on (see also test_interop.py)."""

from __future__ import annotations

import numpy as np

from pcainterp_stream.io import rosmsg


def test_pointcloud2_is_dense_only_without_non_finite_values() -> None:
    finite = {name: np.arange(3, dtype=np.float32) for name in ("x", "y", "z")}
    cloud = rosmsg.deserialize(
        rosmsg.serialize(rosmsg.pointcloud2_message(finite, 5, "left")), rosmsg.POINT_CLOUD2
    )
    assert cloud.is_dense
    np.testing.assert_array_equal(rosmsg.pointcloud2_arrays(cloud)["z"], [0, 1, 2])
    with_nan = dict(finite, z=np.array([1.0, np.nan, 2.0], dtype=np.float32))
    assert not rosmsg.pointcloud2_message(with_nan, 5, "left").is_dense
    assert rosmsg.pointcloud2_message({}, 5, "left").is_dense  # an empty cloud has no NaN
