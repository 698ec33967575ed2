"""A sparse feature stream's points as measurements: pixels and disparities of the left camera."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pcainterp_stream.records import SparseFeatures, StereoCamera


def features_to_measurements(
    features: SparseFeatures | None, camera: StereoCamera
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], dict[str, int]]:
    """Project sparse 3-D points of the left optical frame to pixels and disparities.

    Args:
        features: the frame's points, or None when the stream has none for this stamp.
        camera: the stereo calibration.

    Returns:
        pixels (k, 2) float32 (x, y) px, disparities (k,) float32 px = f*b / z, and counts:
        ``feature_cloud`` (1 when the frame had a cloud), ``features`` (its points),
        ``features_rejected`` (behind the camera or outside the image) and
        ``features_behind`` (of those, behind the camera: z <= 0).
    """
    cloud = int(features is not None)
    if features is None or features.points.size == 0:
        empty = np.zeros((0, 2), dtype=np.float32)
        counts = {"feature_cloud": cloud, "features": 0, "features_rejected": 0}
        return empty, np.zeros(0, dtype=np.float32), counts | {"features_behind": 0}
    points = features.points.astype(np.float64)
    z = points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * points[:, 0] / z + camera.cx
        v = camera.fy * points[:, 1] / z + camera.cy
        disparity = camera.focal_baseline / z
    keep = (
        np.isfinite(u)
        & np.isfinite(v)
        & (z > 0)
        & (u >= -0.5)
        & (u <= camera.width - 0.5)
        & (v >= -0.5)
        & (v <= camera.height - 0.5)
    )
    pixels = np.stack([u[keep], v[keep]], axis=1).astype(np.float32)
    counts = {
        "feature_cloud": cloud,
        "features": int(points.shape[0]),
        "features_rejected": int((~keep).sum()),
        "features_behind": int((~(z > 0)).sum()),
    }
    return pixels, disparity[keep].astype(np.float32), counts
