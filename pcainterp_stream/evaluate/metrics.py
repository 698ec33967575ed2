"""Compare a densified log with its ground truth (synthetic logs carry the true depth).

:func:`compare_with_ground_truth` is a quick library check (no command prints it;
``pcainterp evaluate`` writes the full report): mean absolute disparity error of the PCA-MAP
estimate and of the nearest-neighbour and linear baselines on exactly the same sparse
points, over the same pixels for every method: those with a ground-truth value and an
estimate. As in ``evaluate``, a pixel the log has no estimate for (NaN: outside a raw pair's
rectified box, a frame densify could not measure) is left out of every method and counted
apart. The log's depth is read as REP 118 (and REP 117, which it cites) says: +inf is "too
far" (the synthetic logs' sky), true disparity 0, and counts; NaN is "no value" and does not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import Basis, resample_grid
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.depth_image import depth_metres
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_cameras import FrameCameras
from pcainterp_stream.io.outputs import (
    EstimateTopics,
    OutputTopics,
    decode_estimate,
    estimate_topics,
    missing_outputs,
)
from pcainterp_stream.records import StereoCamera

GROUND_TRUTH_DEPTH = "/ground_truth/depth"


@dataclass
class GroundTruthComparison:
    """Mean absolute disparity errors (px) against ground truth, accumulated over frames.

    Attributes:
        frames: frames compared (a frame with no estimate at any truth pixel is not).
        pixels: ground-truth pixels compared in all, the same for every method.
        abs_error_sum: per method, the sum of absolute disparity errors (px).
        inside_2sigma: pixels whose true disparity lies within +-2 posterior std.
        no_estimate: ground-truth pixels left out of every method: the log has no estimate
            there (NaN).
        no_estimate_frames: frames with no estimate at any ground-truth pixel (not in
            ``frames``).
    """

    frames: int = 0
    pixels: int = 0
    abs_error_sum: dict[str, float] = field(default_factory=dict)
    inside_2sigma: int = 0
    no_estimate: int = 0
    no_estimate_frames: int = 0

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
        topics: output topic names (default the standard ``/pcainterp/*`` names).
        depth_topic: the ground-truth depth topic (32FC1 m, 16UC1 mm).

    Returns:
        The accumulated comparison.

    Raises:
        LogReadError: the log has no densified or no ground-truth channel.
    """
    topics = topics or OutputTopics()
    comparison = GroundTruthComparison()
    with open_log(path) as reader:
        present = reader.topics()
        where = estimate_topics(present, topics)
        wanted = [where.estimate, where.std, topics.features, depth_topic]
        if where.compact:
            wanted.append(topics.camera_info)
        metadata: dict[str, str] = {}
        missing, hint = missing_outputs(present, topics, wanted)
        if missing:
            advice = hint or (
                "; compare needs a log densified by `pcainterp densify` from a log with "
                "ground truth (e.g. `pcainterp synth`)"
            )
            raise LogReadError(f"{path} has no {', '.join(missing)}{advice}")
        pending: dict[int, dict[str, Any]] = {}
        log_times: dict[int, int] = {}  # of each stamp's estimate: its camera's f*b
        try:
            cameras = FrameCameras.of_log(Path(path), topics.prefix)
        except ValueError as err:
            raise LogReadError(str(err)) from None
        for raw in reader.messages(wanted):
            message = reader.decode(raw)
            if raw.topic == where.estimate and not metadata:
                metadata = dict(raw.channel_metadata)
            full_estimate = raw.topic == where.estimate and not where.compact
            stamp = rosmsg.stamp_ns(message.image if full_estimate else message)
            parts = pending.setdefault(stamp, {})
            parts[raw.topic] = message
            if raw.topic == where.estimate:
                log_times[stamp] = raw.log_time_ns
            if len(parts) == len(wanted):
                features = parts[topics.features] if where.compact else None
                own = cameras.metadata(metadata, log_times.pop(stamp, raw.log_time_ns), features)
                _accumulate(comparison, pending.pop(stamp), topics, depth_topic, where, own)
            # frames are written close together: keep only a few stamps waiting
            while len(pending) > 32:  # densify writes outputs ~12 frames after inputs
                log_times.pop(oldest := min(pending), None)
                pending.pop(oldest)
    return comparison


def _accumulate(
    comparison: GroundTruthComparison,
    parts: dict[str, Any],
    topics: OutputTopics,
    depth_topic: str,
    where: EstimateTopics,
    metadata: dict[str, str],
) -> None:
    decoded = decode_estimate(
        parts[where.estimate], parts[where.std], parts.get(topics.camera_info), metadata
    )
    estimate = decoded.disparity.astype(np.float64)
    std = decoded.disparity_std.astype(np.float64)
    focal_baseline = decoded.focal * decoded.baseline
    try:  # by its encoding: 16UC1 is millimetres (REP 118)
        depth = depth_metres(parts[depth_topic])
    except ValueError as err:
        raise LogReadError(f"{depth_topic}: {err}") from None
    truth = disparity_from_reference(depth, kind=ReferenceKind.DEPTH, focal_baseline=focal_baseline)
    truthful = np.isfinite(truth)
    valid = truthful & ~np.isnan(estimate)  # +inf depth (far) is an estimate; NaN none
    comparison.no_estimate += int(np.count_nonzero(truthful & ~valid))
    if not valid.any():
        comparison.no_estimate_frames += 1
        return
    features = rosmsg.pointcloud2_arrays(parts[topics.features])
    pixels = np.stack([features["u"], features["v"]], axis=1)
    image_size = (int(estimate.shape[0]), int(estimate.shape[1]))
    dense = {
        "pca_map": estimate,
        # densify's measurements: SGBM's 0 is a match (densify's zero_is_match)
        "nearest": nearest(
            pixels, features["disparity"], image_size=image_size, zero_is_match=True
        ).disparity,
        "linear": linear(
            pixels, features["disparity"], image_size=image_size, zero_is_match=True
        ).disparity,
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


# =============================================================================== paper metrics
#
# Everything below is pure maths over arrays (no I/O): the projection errors of the paper
# (section IV-B), depth-completion metrics, uncertainty calibration and the oracle. The log
# reading is in :mod:`pcainterp_stream.evaluate.report`, the figures in ``figures``.

DELTA_2D_EDGES: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 20.0, 50.0, np.inf)
"""Bin edges (px) of the Delta_2D error distribution."""

DEPTH_EDGES: tuple[float, ...] = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0, np.inf)
"""Bin edges (m) of the reference depth; sky (no surface) is the last, infinite bin."""

STD_EDGES: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, np.inf)
"""Bin edges (px) of the posterior disparity std."""

SWEEP_POINTS: tuple[int, ...] = (50, 100, 200, 400, 800)
"""Numbers of sparse points of the error-against-points sweep."""

SGBM_PARTS: tuple[str, str] = ("holes", "valid")
"""The two parts of the counted pixels a calibration is split into: SGBM's holes, the rest."""

MAX_DEPTH = 80.0
"""Depth metrics count reference depths up to this (m), KITTI's depth-completion cap."""


class Mode(StrEnum):
    """Which view B the pixels of frame A are moved into (paper section IV-B)."""

    STEREO = "stereo"
    """B is the right camera of the same pair (KITTI)."""
    TEMPORAL = "temporal"
    """B is the left camera of the next frame, moved by the poses (Virtual KITTI)."""


def disparity_from_depth(depth: npt.ArrayLike, focal_baseline: float) -> npt.NDArray[np.float64]:
    """Convert a rendered depth map to disparity; no surface (NaN, inf, <= 0) is 0 (sky).

    For the in-memory frames of :mod:`pcainterp_stream.synth` (``SynthFrame.depth``, NaN
    for sky), which are all surface or sky. A depth image read from a log holds "no value"
    as NaN (REP 118): read it with :func:`disparity_from_reference`.

    Args:
        depth: (H, W) float, depth (m), NaN or +inf where there is no surface.
        focal_baseline: f*b (px*m).

    Returns:
        (H, W) float64 disparity (px), finite everywhere.
    """
    values = np.asarray(depth, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = focal_baseline / values
    return np.where(np.isfinite(disparity) & (values > 0), disparity, 0.0)


class ReferenceKind(StrEnum):
    """What the values of a reference image are (``--reference-kind``)."""

    AUTO = "auto"
    """A ``stereo_msgs/msg/DisparityImage`` holds disparity, an Image depth."""
    DEPTH = "depth"
    """Depth (m; 16UC1 in mm, REP 118)."""
    DISPARITY = "disparity"
    """Disparity (px) of the densified log's camera."""


def disparity_from_reference(
    values: npt.ArrayLike, *, kind: ReferenceKind, focal_baseline: float
) -> npt.NDArray[np.float64]:
    """Convert a ground-truth reference image to disparity, NaN where it holds no truth.

    NaN, 0 and negative values mean "no truth at this pixel" (REP 118's "no value"), as in
    projected LiDAR or KITTI's sparse ground truth. A depth of +inf (REP 118: farther than
    measurable; the synthetic logs' sky) is disparity 0 and counts. The log's
    ``/ground_truth/depth`` and a ``--reference-topic`` are both read so.

    Args:
        values: (H, W) float, depth (m) or disparity (px) per ``kind``.
        kind: :attr:`ReferenceKind.DEPTH` or :attr:`ReferenceKind.DISPARITY`.
        focal_baseline: f*b (px*m) of the densified log's camera.

    Returns:
        (H, W) float64 disparity (px): > 0 or 0 (infinitely far) where there is truth,
        NaN elsewhere.
    """
    array = np.asarray(values, dtype=np.float64)
    if kind is ReferenceKind.DISPARITY:
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(array) & (array > 0), array, np.nan)
    if kind is not ReferenceKind.DEPTH:
        raise ValueError(f"Expected `kind` depth or disparity, got {kind}")
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = focal_baseline / array
        finite = np.isfinite(array) & (array > 0)
    return np.where(finite, disparity, np.where(array == np.inf, 0.0, np.nan))


def fill_nearest(
    disparity: npt.ArrayLike,
) -> npt.NDArray[np.float32] | None:
    """Fill the holes of a disparity map with the nearest valid pixel's value.

    The nearest valid pixel in the Euclidean sense (``scipy.ndimage.distance_transform_edt``
    with ``return_indices``); the baseline "SGBM's own map, holes filled".

    Args:
        disparity: (H, W) float, disparity (px), NaN where invalid.

    Returns:
        (H, W) float32 disparity (px) finite everywhere, or None when no pixel is valid.
    """
    from scipy.ndimage import distance_transform_edt

    values = np.asarray(disparity, dtype=np.float32)
    valid = np.isfinite(values)
    if not valid.any():
        return None
    if valid.all():
        return values.copy()
    # zero elements of the input are the "features": every pixel gets its nearest valid one
    _, (rows, columns) = distance_transform_edt(~valid, return_indices=True)
    filled: npt.NDArray[np.float32] = values[rows, columns]
    return filled


def stereo_transform(camera: StereoCamera) -> npt.NDArray[np.float64]:
    """Return the 4x4 rigid transform from the left to the right camera frame (x by -b)."""
    transform = np.eye(4)
    transform[0, 3] = -camera.baseline
    return transform


def relative_transform(
    pose_a: npt.NDArray[np.float64], pose_b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Return the 4x4 transform from camera frame A to camera frame B.

    Args:
        pose_a: (4, 4) float64, camera A to world.
        pose_b: (4, 4) float64, camera B to world.

    Returns:
        (4, 4) float64, inv(pose_b) @ pose_a.
    """
    return np.asarray(np.linalg.solve(pose_b, pose_a), dtype=np.float64)


def _rays(camera: StereoCamera) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Return (H, W) normalised image coordinates x_n = (u - cx)/fx, y_n = (v - cy)/fy."""
    xs = (np.arange(camera.width, dtype=np.float64) - camera.cx) / camera.fx
    ys = (np.arange(camera.height, dtype=np.float64) - camera.cy) / camera.fy
    return np.broadcast_to(xs[None, :], camera.image_size), np.broadcast_to(
        ys[:, None], camera.image_size
    )


def project_into(
    disparity: npt.ArrayLike,
    camera: StereoCamera,
    transform: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Back-project every pixel of view A with a disparity map and project it into view B.

    Homogeneous back-projection X = (x_n, y_n, 1, d / (f*b)) is the 3-D point scaled by
    1/depth, so disparity 0 (sky) is the point at infinity and needs no special case;
    negative disparities are clipped to 0.

    Args:
        disparity: (H, W) float, disparity (px) of view A.
        camera: the camera of both views (same intrinsics).
        transform: (4, 4) float64, camera A to camera B.

    Returns:
        u, v: (H, W) float64, pixel position in view B (NaN behind B's camera).
        z: (H, W) float64, the homogeneous depth coordinate in B (> 0 in front).
    """
    values = np.clip(np.asarray(disparity, dtype=np.float64), 0.0, None)
    x_n, y_n = _rays(camera)
    inverse_depth = values / camera.focal_baseline
    rotation, translation = transform[:3, :3], transform[:3, 3]
    moved = [
        rotation[row, 0] * x_n
        + rotation[row, 1] * y_n
        + rotation[row, 2]
        + translation[row] * inverse_depth
        for row in range(3)
    ]
    z = moved[2]
    in_front = z > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(in_front, camera.fx * moved[0] / z + camera.cx, np.nan)
        v = np.where(in_front, camera.fy * moved[1] / z + camera.cy, np.nan)
    return u, v, z


@dataclass(frozen=True, eq=False)
class ReferenceView:
    """The reference of frame A moved into view B: which pixels count, and where they land.

    Attributes:
        counted: (H, W) bool, reference valid and landing inside B's image, in front of B.
        u: (H, W) float64, x in B of each reference point (px).
        v: (H, W) float64, y in B (px).
        disparity: (H, W) float64, the reference disparity of A (px), NaN where invalid.
        depth: (H, W) float64, reference depth (m); inf for sky, NaN where invalid.
        diagonal: the image diagonal (px), the cap of Delta_2D.
    """

    counted: npt.NDArray[np.bool_]
    u: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    disparity: npt.NDArray[np.float64]
    depth: npt.NDArray[np.float64]
    diagonal: float


def reference_view(
    reference: npt.ArrayLike, camera: StereoCamera, transform: npt.NDArray[np.float64]
) -> ReferenceView:
    """Move a reference disparity map of view A into view B (paper section IV-B).

    Args:
        reference: (H, W) float, reference disparity (px); NaN where invalid (SGBM holes),
            0 for sky (counted: it lands by the rotation alone).
        camera: the camera of both views.
        transform: (4, 4) float64, camera A to camera B.

    Returns:
        The :class:`ReferenceView`; only its ``counted`` pixels enter any metric.
    """
    values = np.asarray(reference, dtype=np.float64)
    if values.shape != camera.image_size:
        raise ValueError(f"Expected `reference` of shape {camera.image_size}, got {values.shape}")
    valid = np.isfinite(values) & (values >= 0)
    filled = np.where(valid, values, 0.0)
    u, v, _ = project_into(filled, camera, transform)
    with np.errstate(invalid="ignore"):
        inside = (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
    with np.errstate(divide="ignore"):
        depth = np.where(valid, camera.focal_baseline / np.where(valid, values, 1.0), np.nan)
    depth = np.where(valid & (values == 0), np.inf, depth)
    return ReferenceView(
        counted=valid & inside,
        u=u,
        v=v,
        disparity=np.where(valid, values, np.nan),
        depth=depth,
        diagonal=float(np.hypot(camera.width, camera.height)),
    )


def projection_errors(
    estimate: npt.ArrayLike,
    view: ReferenceView,
    camera: StereoCamera,
    transform: npt.NDArray[np.float64],
    *,
    max_depth: float = MAX_DEPTH,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Return the paper's Delta_2D and Delta_3D of an estimate against a reference.

    Each pixel of A is back-projected with the reference and with the estimate, both points
    are moved into B; Delta_2D is the distance of their projections in B (px), Delta_3D the
    distance of the 3-D points (m; a rigid move keeps distances, so it is computed in A).

    Args:
        estimate: (H, W) float, estimated disparity (px) of A; NaN counts as 0 (sky).
        view: the reference moved into B (:func:`reference_view`).
        camera: the camera of both views.
        transform: (4, 4) float64, camera A to camera B.
        max_depth: Delta_3D counts reference depths up to this (m) and caps the estimated
            depth there.

    Returns:
        delta_2d: (H, W) float64 (px), NaN where the pixel does not count; capped at the
            image diagonal (an estimated point behind B lands nowhere).
        delta_3d: (H, W) float64 (m), NaN where the pixel does not count or the reference
            is farther than ``max_depth`` (sky included).
    """
    values = np.nan_to_num(np.asarray(estimate, dtype=np.float64), nan=0.0)
    u, v, _ = project_into(values, camera, transform)
    distance = np.hypot(u - view.u, v - view.v)
    delta_2d = np.where(np.isfinite(distance), np.minimum(distance, view.diagonal), view.diagonal)
    delta_2d = np.where(view.counted, delta_2d, np.nan)
    # Delta_3D: reference depths up to max_depth, estimated depth capped there (as the
    # depth metrics): a near-zero estimated disparity would otherwise put a point at
    # kilometres and one pixel would dominate the mean
    x_n, y_n = _rays(camera)
    min_disparity = camera.focal_baseline / max_depth
    with np.errstate(invalid="ignore"):
        finite = view.counted & (view.disparity >= min_disparity)
    estimated_depth = camera.focal_baseline / np.maximum(values, min_disparity)
    reference_depth = np.where(finite, view.depth, 0.0)
    delta_3d = np.where(
        finite, np.abs(estimated_depth - reference_depth) * np.sqrt(x_n**2 + y_n**2 + 1.0), np.nan
    )
    return delta_2d, delta_3d


def depth_errors(
    estimate: npt.ArrayLike,
    reference: npt.ArrayLike,
    mask: npt.NDArray[np.bool_],
    *,
    focal_baseline: float,
    max_depth: float = MAX_DEPTH,
) -> dict[str, float]:
    """Return sums for the KITTI depth-completion metrics over one frame.

    Counted pixels: ``mask`` and a reference disparity that gives a depth in (0,
    ``max_depth``]. The estimated depth f*b / d is capped at ``max_depth`` (a disparity
    <= 0 means "far").

    Args:
        estimate: (H, W) float, estimated disparity (px).
        reference: (H, W) float, reference disparity (px), NaN where invalid.
        mask: (H, W) bool, pixels that may count.
        focal_baseline: f*b (px*m).
        max_depth: largest counted reference depth (m).

    Returns:
        ``n`` (count), ``sq`` (sum of squared depth errors, m^2), ``abs`` (sum of absolute
        depth errors, m), ``isq`` (sum of squared inverse-depth errors, 1/km^2), ``iabs``
        (sum of absolute inverse-depth errors, 1/km).
    """
    ref = np.asarray(reference, dtype=np.float64)
    est = np.nan_to_num(np.asarray(estimate, dtype=np.float64), nan=0.0)
    min_disparity = focal_baseline / max_depth
    with np.errstate(invalid="ignore"):
        counted = mask & np.isfinite(ref) & (ref >= min_disparity)
    ref_d = ref[counted]
    est_d = np.maximum(est[counted], min_disparity)
    ref_depth = focal_baseline / ref_d
    est_depth = focal_baseline / est_d
    inverse_gap = (est_d - ref_d) / focal_baseline * 1000.0  # 1/km
    return {
        "n": float(ref_d.size),
        "sq": float(np.sum((est_depth - ref_depth) ** 2)),
        "abs": float(np.sum(np.abs(est_depth - ref_depth))),
        "isq": float(np.sum(inverse_gap**2)),
        "iabs": float(np.sum(np.abs(inverse_gap))),
    }


CERTAIN_STD = 1e-3
"""A predicted disparity std (px) below this is counted as "certain" by calibration_sums."""


def calibration_sums(
    estimate: npt.ArrayLike,
    std: npt.ArrayLike,
    reference: npt.ArrayLike,
    mask: npt.NDArray[np.bool_],
) -> dict[str, float]:
    """Return sums for uncertainty calibration over one frame, in disparity.

    With z = (estimate - reference) / std, a calibrated Gaussian posterior has 68.3 % of
    |z| <= 1 and 95.4 % of |z| <= 2; the negative log-likelihood is
    0.5 log(2 pi std^2) + 0.5 z^2 per pixel (nats).

    Args:
        estimate: (H, W) float, estimated disparity (px).
        std: (H, W) float, posterior std of the disparity (px), > 0.
        reference: (H, W) float, reference disparity (px), NaN where invalid.
        mask: (H, W) bool, pixels that count.

    Pixels whose std is below :data:`CERTAIN_STD` claim a certainty no Gaussian likelihood
    can score: a model that never varies there (a basis whose training maps were all sky at
    a pixel, a tiny basis learned from one or two of a log's own maps) would give an NLL of
    1e10 per wrong pixel. They are **left out of the NLL** (not floored) and counted apart
    as ``certain``; the coverage counts them inside +-k std only where the error is exactly
    0 (a std of 0 claims exactly that). Pixels with no std at all (NaN: no estimate there,
    or a std of 0 that a compact log stores as "no value") claim nothing: they are left out
    of the coverage and the NLL alike and counted apart as ``no_std``.

    Returns:
        ``n``, ``inside_1`` and ``inside_2`` (counts within +-1 and +-2 std over the counted
        pixels with a std), ``certain`` (those with a std below :data:`CERTAIN_STD`),
        ``nll`` (sum over the other pixels) and ``no_std`` (counted pixels without a std).
    """
    ref = np.asarray(reference, dtype=np.float64)
    with_truth = mask & np.isfinite(ref)
    sigmas = np.asarray(std, dtype=np.float64)
    counted = with_truth & ~np.isnan(sigmas)
    error = np.abs(np.asarray(estimate, dtype=np.float64)[counted] - ref[counted])
    raw = sigmas[counted]
    certain = ~(raw >= CERTAIN_STD)
    sigma = np.where(certain, 1.0, raw)
    z = np.where(certain, np.where(error == 0.0, 0.0, np.inf), error / sigma)
    nll = 0.5 * np.log(2.0 * np.pi * sigma[~certain] ** 2) + 0.5 * z[~certain] ** 2
    return {
        "n": float(z.size),
        "inside_1": float(np.count_nonzero(z <= 1.0)),
        "inside_2": float(np.count_nonzero(z <= 2.0)),
        "nll": float(np.sum(nll)),
        "certain": float(np.count_nonzero(certain)),
        "no_std": float(np.count_nonzero(with_truth) - z.size),
    }


def oracle_disparity(basis: Basis, reference: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Return the best any coefficient estimate could do: the reference projected on B.

    The reference is preprocessed exactly as a training map (nearest-valid fill, 5x5 box,
    area resampling to the grid), then y = B^T (g - m) (B orthonormal over the grid: the
    least-squares projection), and B y + m resampled to the image.

    Args:
        basis: the PCA basis.
        reference: (H, W) float, reference disparity (px) at the basis's image size and f*b;
            NaN where invalid.

    Returns:
        (H, W) float32 oracle disparity (px).
    """
    from pcainterp_stream.estimate.learning import preprocess_disparity

    values = np.asarray(reference, dtype=np.float32)
    grid = preprocess_disparity(values, basis.grid_size).reshape(-1)
    coefficients = basis.component_rows @ (grid - basis.mean_flat)
    dense = basis.pixel_major @ coefficients + basis.mean_flat
    return resample_grid(dense.reshape(basis.grid_size), (values.shape[0], values.shape[1]))


def _binned(
    keys: npt.NDArray[np.float64], values: npt.NDArray[np.float64], edges: Sequence[float]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Return per-bin counts and sums of ``values`` by ``keys`` (bins [e_i, e_i+1))."""
    index = np.searchsorted(np.asarray(edges), keys, side="right") - 1
    index = np.clip(index, 0, len(edges) - 2)
    counts = np.bincount(index, minlength=len(edges) - 1).astype(np.float64)
    sums = np.bincount(index, weights=values, minlength=len(edges) - 1).astype(np.float64)
    return counts, sums


def _zeros(edges: Sequence[float]) -> list[float]:
    return [0.0] * (len(edges) - 1)


@dataclass
class MethodStats:
    """Accumulated errors of one dense estimate (a method) over frames.

    Attributes:
        pixels: counted pixels (Delta_2D).
        delta_2d_sum: sum of Delta_2D (px).
        delta_2d_sq_sum: sum of Delta_2D^2 (px^2).
        delta_2d_hist: pixel counts per :data:`DELTA_2D_EDGES` bin.
        by_depth_count: pixels per :data:`DEPTH_EDGES` bin.
        by_depth_2d: sum of Delta_2D per depth bin (px).
        by_depth_3d_count: pixels with a finite Delta_3D per depth bin.
        by_depth_3d: sum of Delta_3D per depth bin (m).
        depth: sums of :func:`depth_errors`.
        disparity_abs_sum: sum of |estimate - reference| disparity (px).
        seconds: time spent computing this method's estimates (s), when timed.
        frames: frames accumulated.
    """

    pixels: float = 0.0
    delta_2d_sum: float = 0.0
    delta_2d_sq_sum: float = 0.0
    delta_2d_hist: list[float] = field(default_factory=lambda: _zeros(DELTA_2D_EDGES))
    by_depth_count: list[float] = field(default_factory=lambda: _zeros(DEPTH_EDGES))
    by_depth_2d: list[float] = field(default_factory=lambda: _zeros(DEPTH_EDGES))
    by_depth_3d_count: list[float] = field(default_factory=lambda: _zeros(DEPTH_EDGES))
    by_depth_3d: list[float] = field(default_factory=lambda: _zeros(DEPTH_EDGES))
    depth: dict[str, float] = field(
        default_factory=lambda: {"n": 0.0, "sq": 0.0, "abs": 0.0, "isq": 0.0, "iabs": 0.0}
    )
    disparity_abs_sum: float = 0.0
    seconds: float = 0.0
    frames: int = 0

    def add(
        self,
        estimate: npt.ArrayLike,
        view: ReferenceView,
        camera: StereoCamera,
        transform: npt.NDArray[np.float64],
    ) -> npt.NDArray[np.float64]:
        """Accumulate one frame; return its (H, W) Delta_2D (NaN where not counted)."""
        values = np.asarray(estimate, dtype=np.float64)
        delta_2d, delta_3d = projection_errors(values, view, camera, transform)
        counted = view.counted
        errors = delta_2d[counted]
        depths = view.depth[counted]
        self.pixels += errors.size
        self.delta_2d_sum += float(errors.sum())
        self.delta_2d_sq_sum += float(np.sum(errors**2))
        hist, _ = _binned(errors, errors, DELTA_2D_EDGES)
        self.delta_2d_hist = list(np.add(self.delta_2d_hist, hist))
        counts, sums = _binned(depths, errors, DEPTH_EDGES)
        self.by_depth_count = list(np.add(self.by_depth_count, counts))
        self.by_depth_2d = list(np.add(self.by_depth_2d, sums))
        finite_3d = counted & np.isfinite(delta_3d)
        counts, sums = _binned(view.depth[finite_3d], delta_3d[finite_3d], DEPTH_EDGES)
        self.by_depth_3d_count = list(np.add(self.by_depth_3d_count, counts))
        self.by_depth_3d = list(np.add(self.by_depth_3d, sums))
        sums_depth = depth_errors(
            values, view.disparity, counted, focal_baseline=camera.focal_baseline
        )
        self.depth = {key: self.depth[key] + sums_depth[key] for key in self.depth}
        self.disparity_abs_sum += float(
            np.sum(np.abs(np.nan_to_num(values[counted], nan=0.0) - view.disparity[counted]))
        )
        self.frames += 1
        return delta_2d

    def summary(self) -> dict[str, float]:
        """Return the mean metrics: Delta_2D (px), Delta_3D (m), RMSE/MAE (m), iRMSE/iMAE (1/km)."""
        n = max(self.pixels, 1.0)
        n_depth = max(self.depth["n"], 1.0)
        n_3d = max(float(np.sum(self.by_depth_3d_count)), 1.0)
        return {
            "pixels": self.pixels,
            "delta_2d_mean": self.delta_2d_sum / n,
            "delta_2d_rms": float(np.sqrt(self.delta_2d_sq_sum / n)),
            "delta_3d_mean": float(np.sum(self.by_depth_3d)) / n_3d,
            "disparity_mae": self.disparity_abs_sum / n,
            "rmse_m": float(np.sqrt(self.depth["sq"] / n_depth)),
            "mae_m": self.depth["abs"] / n_depth,
            "irmse_per_km": float(np.sqrt(self.depth["isq"] / n_depth)),
            "imae_per_km": self.depth["iabs"] / n_depth,
            "ms_per_frame": 1000.0 * self.seconds / max(self.frames, 1),
        }


@dataclass
class CalibrationStats:
    """Accumulated uncertainty calibration of one std map kind over frames.

    Attributes:
        sums: sums of :func:`calibration_sums`.
        by_std_count: counted pixels per :data:`STD_EDGES` bin of the predicted std.
        by_std_2d: sum of Delta_2D per std bin (px).
        by_std_abs: sum of |disparity error| per std bin (px).
        by_std_sq: sum of squared disparity error per std bin (px^2).
        by_sgbm: the sums ``n``, ``inside_1``, ``inside_2`` of :func:`calibration_sums` apart
            for the counted pixels in SGBM's holes (``holes``) and where SGBM is valid
            (``valid``), for frames given an SGBM map; the two add up to :attr:`sums` then.
        seconds: time spent densifying with this kind (s).
        frames: frames accumulated.
    """

    sums: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(
            ("n", "inside_1", "inside_2", "nll", "certain", "no_std"), 0.0
        )
    )
    by_std_count: list[float] = field(default_factory=lambda: _zeros(STD_EDGES))
    by_std_2d: list[float] = field(default_factory=lambda: _zeros(STD_EDGES))
    by_std_abs: list[float] = field(default_factory=lambda: _zeros(STD_EDGES))
    by_std_sq: list[float] = field(default_factory=lambda: _zeros(STD_EDGES))
    by_sgbm: dict[str, dict[str, float]] = field(
        default_factory=lambda: {
            part: dict.fromkeys(("n", "inside_1", "inside_2"), 0.0) for part in SGBM_PARTS
        }
    )
    seconds: float = 0.0
    frames: int = 0

    def add(
        self,
        estimate: npt.ArrayLike,
        std: npt.ArrayLike,
        view: ReferenceView,
        delta_2d: npt.NDArray[np.float64],
        *,
        sgbm_valid: npt.NDArray[np.bool_] | None = None,
    ) -> None:
        """Accumulate one frame (``delta_2d`` of the same estimate, NaN where not counted).

        Args:
            estimate: (H, W) float, estimated disparity (px).
            std: (H, W) float, its posterior std (px).
            view: the reference moved into view B.
            delta_2d: (H, W) float64 Delta_2D of ``estimate`` (px).
            sgbm_valid: (H, W) bool, where SGBM of the pair has a value; given, the
                coverage is also split into SGBM's holes and the rest (:attr:`by_sgbm`).
        """
        values = np.asarray(estimate, dtype=np.float64)
        sigma = np.asarray(std, dtype=np.float64)
        sums = calibration_sums(values, sigma, view.disparity, view.counted)
        self.sums = {key: self.sums[key] + sums[key] for key in self.sums}
        if sgbm_valid is not None:
            for part, mask in zip(SGBM_PARTS, (~sgbm_valid, sgbm_valid), strict=True):
                part_sums = calibration_sums(values, sigma, view.disparity, view.counted & mask)
                totals = self.by_sgbm[part]
                self.by_sgbm[part] = {key: totals[key] + part_sums[key] for key in totals}
        counted = view.counted & ~np.isnan(sigma)  # no std: no bin
        stds = sigma[counted]
        error = values[counted] - view.disparity[counted]
        for name, weights in (
            ("by_std_2d", delta_2d[counted]),
            ("by_std_abs", np.abs(error)),
            ("by_std_sq", error**2),
        ):
            counts, binned = _binned(stds, weights, STD_EDGES)
            setattr(self, name, list(np.add(getattr(self, name), binned)))
        self.by_std_count = list(np.add(self.by_std_count, counts))
        self.frames += 1

    def summary(self) -> dict[str, float]:
        """Return coverage of +-1 and +-2 std (fractions), mean NLL (nats) and ms per frame.

        The NLL is the mean over the pixels with a std (:func:`calibration_sums`); NaN when
        none has one. ``certain`` is the share of pixels left out of it; ``no_std`` the share
        of the counted pixels left out of every figure for having no std.
        """
        n = max(self.sums["n"], 1.0)
        scored = self.sums["n"] - self.sums["certain"]
        summary = {
            "pixels": self.sums["n"],
            "no_std": self.sums["no_std"] / max(self.sums["n"] + self.sums["no_std"], 1.0),
            "coverage_1sigma": self.sums["inside_1"] / n,
            "coverage_2sigma": self.sums["inside_2"] / n,
            "nll": self.sums["nll"] / scored if scored > 0 else math.nan,
            "certain": self.sums["certain"] / n,
            "ms_per_frame": 1000.0 * self.seconds / max(self.frames, 1),
        }
        if self.has_sgbm_split:
            for part, sums in self.by_sgbm.items():
                summary[f"pixels_sgbm_{part}"] = sums["n"]
                summary[f"coverage_2sigma_sgbm_{part}"] = sums["inside_2"] / max(sums["n"], 1.0)
        return summary

    @property
    def has_sgbm_split(self) -> bool:
        """Return whether any frame was split by an SGBM map."""
        return any(sums["n"] > 0 for sums in self.by_sgbm.values())
