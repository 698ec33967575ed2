"""Compare a densified log with its ground truth (synthetic logs carry the true depth).

This is the quick check ``pcainterp demo`` prints: mean absolute disparity error of the
PCA-MAP estimate and of the nearest-neighbour and linear baselines on exactly the same
sparse points, over every pixel with a ground-truth value. Sky (no surface, NaN depth in the
log, REP 118) has true disparity 0 and counts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcainterp_stream import rosmsg
from pcainterp_stream.baselines import linear, nearest
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.logreader import open_log
from pcainterp_stream.outputs import OutputTopics

GROUND_TRUTH_DEPTH = "/ground_truth/depth"


@dataclass
class GroundTruthComparison:
    """Mean absolute disparity errors (px) against ground truth, accumulated over frames.

    Attributes:
        frames: frames compared.
        pixels: ground-truth pixels compared in all.
        abs_error_sum: per method, the sum of absolute disparity errors (px).
        inside_2sigma: pixels whose true disparity lies within +-2 posterior std.
    """

    frames: int = 0
    pixels: int = 0
    abs_error_sum: dict[str, float] = field(default_factory=dict)
    inside_2sigma: int = 0

    def mean_abs_error(self, method: str) -> float:
        """Return the mean absolute disparity error (px) of ``method``."""
        return self.abs_error_sum.get(method, float("nan")) / max(self.pixels, 1)

    @property
    def coverage_2sigma(self) -> float:
        """Return the share of true disparities inside the +-2 sigma band."""
        return self.inside_2sigma / max(self.pixels, 1)


def compare_with_ground_truth(
    path: str | Path,
    *,
    topics: OutputTopics | None = None,
    depth_topic: str = GROUND_TRUTH_DEPTH,
) -> GroundTruthComparison:
    """Compare every densified frame of a log with the log's ground-truth depth.

    Args:
        path: a log written by ``pcainterp densify`` from a log with ground truth.
        topics: output topic names (default DESIGN.md's).
        depth_topic: the ground-truth depth topic (32FC1, m).

    Returns:
        The accumulated comparison.

    Raises:
        LogReadError: the log has no densified or no ground-truth channel.
    """
    topics = topics or OutputTopics()
    wanted = [topics.disparity, topics.disparity_std, topics.features, depth_topic]
    comparison = GroundTruthComparison()
    with open_log(path) as reader:
        present = reader.topics()
        missing = [topic for topic in wanted if topic not in present]
        if missing:
            raise LogReadError(
                f"{path} has no {', '.join(missing)}; compare needs a log densified by "
                "`pcainterp densify` from a log with ground truth (e.g. `pcainterp synth`)"
            )
        pending: dict[int, dict[str, Any]] = {}
        for raw in reader.messages(wanted):
            message = reader.decode(raw)
            stamp = rosmsg.stamp_ns(message)
            parts = pending.setdefault(stamp, {})
            parts[raw.topic] = message
            if len(parts) == len(wanted):
                _accumulate(comparison, pending.pop(stamp), topics, depth_topic)
            # frames are written close together: keep only a few stamps waiting
            while len(pending) > 8:
                pending.pop(min(pending))
    return comparison


def _accumulate(
    comparison: GroundTruthComparison,
    parts: dict[str, Any],
    topics: OutputTopics,
    depth_topic: str,
) -> None:
    disparity_message = parts[topics.disparity]
    estimate = rosmsg.image_array(disparity_message.image).astype(np.float64)
    std = rosmsg.image_array(parts[topics.disparity_std]).astype(np.float64)
    focal_baseline = float(disparity_message.f) * float(disparity_message.t)
    depth = rosmsg.image_array(parts[depth_topic]).astype(np.float64)
    with np.errstate(divide="ignore"):
        truth = np.where(np.isnan(depth) | np.isinf(depth), 0.0, focal_baseline / depth)
    valid = np.isfinite(truth)
    features = rosmsg.pointcloud2_arrays(parts[topics.features])
    pixels = np.stack([features["u"], features["v"]], axis=1)
    image_size = (int(estimate.shape[0]), int(estimate.shape[1]))
    dense = {
        "pca_map": estimate,
        "nearest": nearest(pixels, features["disparity"], image_size=image_size).disparity,
        "linear": linear(pixels, features["disparity"], image_size=image_size).disparity,
    }
    for method, values in dense.items():
        error = np.abs(np.asarray(values, dtype=np.float64)[valid] - truth[valid])
        comparison.abs_error_sum[method] = comparison.abs_error_sum.get(method, 0.0) + float(
            np.nansum(error)
        )
    comparison.inside_2sigma += int(
        np.count_nonzero(np.abs(estimate[valid] - truth[valid]) <= 2.0 * std[valid])
    )
    comparison.pixels += int(valid.sum())
    comparison.frames += 1
