"""Where sparse mode's gap-filling lookups go (``GfttConfig.fill_placement``).

* :func:`nudged_lattice` -- the lattice, each rejected point moved a quarter side to where
  a lookup passes (the default);
* :func:`weighted_fill` -- a greedy choice of a given number of points where the gap to
  the nearest measurement times a weight (1, the prior's std, the disparity) is largest;
* :func:`fill_points` -- the points :func:`.stereo.sparse_lookups` looks up in the corners'
  gaps: the lattice's, nudged or not, or as many chosen by :func:`greedy_fill`;
* :func:`greedy_fill` -- the candidates (a lattice 4x finer than the fill's, looked up with
  the usual checks), their weights and the choice;
* :func:`valid_share` -- the share of valid SGBM pixels around points;
* :func:`scaled_spacing` -- the fill's side on a large image: ``fill_spacing`` up to
  :data:`FILL_REFERENCE_AREA`, beyond it grown with the square root of the area.

Measurements: ``docs/sharper_sparse_2.md`` (the nudged lattice) and
``docs/sharper_sparse.md``, "Where the fill points go" (the greedy fill).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.corners import GfttConfig, lattice_points, patch_contrast

__all__ = [
    "FILL_REFERENCE_AREA",
    "fill_points",
    "greedy_fill",
    "scaled_spacing",
    "valid_share",
    "weighted_fill",
]

FloatArray = npt.NDArray[np.float32]


class Looked(Protocol):
    """What a lookup returns that the fill uses (:class:`.stereo.Lookup` is one)."""

    @property
    def pixels(self) -> FloatArray: ...  # (m, 2) float32 (x, y) px of the kept points

    @property
    def disparities(self) -> FloatArray: ...  # (m,) float32 px

    @property
    def indices(self) -> npt.NDArray[np.int64]: ...  # (m,) index of each kept point


LookUp = Callable[[FloatArray], Looked]
"""Points -> their lookups that pass the checks (:func:`.stereo.lookup_disparities`)."""

FILL_REFERENCE_AREA = 2_000_000
"""Largest searched area (px^2) whose fill keeps ``fill_spacing`` as given: a 1920 x 1080
pair's (1.90e6 px^2, 1215 lattice points at 40 px) and every smaller camera's. Measured
(docs/benchmarks.md, "A large image's fill lattice"): on a 4096 x 2160 pair the 40 px
lattice had 5229 points and took 43 s per frame; here it keeps ~1300 points."""


def scaled_spacing(spacing: float, area: tuple[int, int, int, int]) -> float:
    """The fill's side (px) on ``area``: ``spacing``, grown on an area above the reference.

    The estimate's k x k solve grows with the cube of its points, and a lattice of a fixed
    side with the image's area. On a searched area ``a`` larger than
    :data:`FILL_REFERENCE_AREA` the side is ``spacing * sqrt(a / FILL_REFERENCE_AREA)``, so
    the lattice keeps the points it has on the reference area, spread evenly over the
    image (the basis is resampled to the image, so they cover the same share of its grid),
    and the frame's time grows about with its pixels (SGBM) instead of their cube. Up to
    the reference (KITTI, EuRoC, 1280 x 720, 1920 x 1080) the side is ``spacing`` itself.
    """
    x0, y0, x1, y1 = area
    size = max(x1 - x0, 0) * max(y1 - y0, 0)
    if spacing <= 0.0 or size <= FILL_REFERENCE_AREA:
        return spacing
    return spacing * math.sqrt(size / FILL_REFERENCE_AREA)


SUPPORT_HALF = 10
"""Half side (px) of the window whose valid share :func:`valid_share` gives."""


def valid_share(disparity: FloatArray, points: FloatArray) -> FloatArray:
    """Share of valid (finite) SGBM pixels in the 21 x 21 px around each point (nearest px)."""
    if points.shape[0] == 0:
        return np.zeros(0, np.float32)
    height, width = disparity.shape
    counts = cv2.integral(np.isfinite(disparity).view(np.uint8))
    half = SUPPORT_HALF
    x = np.rint(points[:, 0]).astype(np.int64)
    y = np.rint(points[:, 1]).astype(np.int64)
    x0, x1 = np.clip(x - half, 0, width), np.clip(x + half + 1, 0, width)
    y0, y1 = np.clip(y - half, 0, height), np.clip(y + half + 1, 0, height)
    inside = counts[y1, x1] - counts[y0, x1] - counts[y1, x0] + counts[y0, x0]
    return np.asarray(inside / ((2 * half + 1) ** 2), np.float32)


def fill_points(
    left_grey: npt.NDArray[np.uint8],
    disparity: FloatArray,
    gftt: GfttConfig,
    area: tuple[int, int, int, int],
    kept: FloatArray,
    look_up: LookUp,
    prior_std: FloatArray | None = None,
) -> FloatArray:
    """The points to look up in the gaps of the ``kept`` corner lookups (``fill_spacing`` > 0).

    ``"lattice"``: the points of :func:`lattice_points` with a 7x7 grey-level std of at
    least ``gftt.fill_min_contrast`` (and the support check when ``fill_min_support`` > 0).
    ``"nudged"``: those of :func:`nudged_lattice` (the same checks, then the moves).
    Otherwise as many as those pass the lookups' checks, chosen by :func:`greedy_fill`
    (each then passes them again). Arguments as :func:`greedy_fill`'s. On an area larger
    than :data:`FILL_REFERENCE_AREA` the side is :func:`scaled_spacing`'s.
    """
    spacing = scaled_spacing(gftt.fill_spacing, area)
    if spacing != gftt.fill_spacing:
        gftt = dataclasses.replace(gftt, fill_spacing=spacing)
    points = lattice_points(kept, gftt.fill_spacing, area)
    if gftt.fill_placement == "nudged":
        return nudged_lattice(left_grey, disparity, gftt, area, points, look_up)
    points = points[patch_contrast(left_grey, points) >= gftt.fill_min_contrast]
    if gftt.fill_placement == "lattice":
        if gftt.fill_min_support > 0.0:
            points = points[valid_share(disparity, points) >= gftt.fill_min_support]
        return points
    count = look_up(points).pixels.shape[0]
    return greedy_fill(left_grey, disparity, gftt, area, kept, count, look_up, prior_std)[0]


NUDGES = np.array(
    [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1)], np.float32
)
"""The moves tried for a rejected lattice point, first passing one kept (x a quarter side)."""


def nudged_lattice(
    left_grey: npt.NDArray[np.uint8],
    disparity: FloatArray,
    gftt: GfttConfig,
    area: tuple[int, int, int, int],
    nodes: FloatArray,
    look_up: LookUp,
) -> FloatArray:
    """The lattice's points, each rejected one moved a quarter side to where a lookup passes.

    A lattice point whose lookup fails (too little contrast, an invalid or steep SGBM
    patch) leaves its whole cell unmeasured. Here it is moved a quarter side along the
    axes, else the diagonals, to the first position of :data:`NUDGES` that passes the same
    checks (with ``fill_min_support`` > 0 its support check too) and at least
    ``nudge_min_support`` valid SGBM pixels around it (:func:`valid_share`); one that
    passes nowhere is dropped. A moved point stays farther than (1/2 - sqrt(2)/4) of a
    side (~0.15 s, 5.9 px at 40) from every kept corner lookup: the lattice keeps half a
    side from them and a diagonal move is sqrt(2)/4 of a side.

    Args:
        left_grey: (H, W) uint8 grey left image.
        disparity: (H, W) float32 SGBM map (px), NaN where invalid.
        gftt: the fill's settings.
        area: (x0, y0, x1, y1) px searched.
        nodes: (n, 2) float32 (x, y) px, the lattice's points (:func:`lattice_points`).
        look_up: the lookups with their checks.

    Returns:
        (m, 2) float32 (x, y) px: the points that passed, then the moved ones.
    """
    textured = patch_contrast(left_grey, nodes) >= gftt.fill_min_contrast
    if gftt.fill_min_support > 0.0:
        textured &= valid_share(disparity, nodes) >= gftt.fill_min_support
    passed = np.zeros(nodes.shape[0], bool)
    passed[np.flatnonzero(textured)[look_up(nodes[textured]).indices]] = True
    open_ = nodes[~passed]
    if open_.shape[0] == 0:
        return np.ascontiguousarray(nodes)
    x0, y0, x1, y1 = area
    trials = open_[:, None, :] + np.float32(gftt.fill_spacing / 4.0) * NUDGES[None, :, :]
    trials = trials.reshape(-1, 2)
    ok = (trials[:, 0] >= x0) & (trials[:, 0] <= x1 - 1)
    ok &= (trials[:, 1] >= y0) & (trials[:, 1] <= y1 - 1)
    where = np.flatnonzero(ok)
    where = where[look_up(trials[where]).indices]
    where = where[patch_contrast(left_grey, trials[where]) >= gftt.fill_min_contrast]
    support = max(gftt.fill_min_support, gftt.nudge_min_support)
    if support > 0.0:
        where = where[valid_share(disparity, trials[where]) >= support]
    hit = np.zeros(trials.shape[0], bool)
    hit[where] = True
    hits = hit.reshape(open_.shape[0], NUDGES.shape[0])  # per open point, per move
    found = hits.any(axis=1)
    first = hits.argmax(axis=1)[found]
    moved = trials.reshape(open_.shape[0], NUDGES.shape[0], 2)[found, first]
    return np.ascontiguousarray(np.concatenate([nodes[passed], moved]), dtype=np.float32)


def greedy_fill(
    left_grey: npt.NDArray[np.uint8],
    disparity: FloatArray,
    gftt: GfttConfig,
    area: tuple[int, int, int, int],
    kept: FloatArray,
    count: int,
    look_up: LookUp,
    prior_std: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``count`` fill points placed by :func:`weighted_fill` among a finer lattice's lookups.

    Args:
        left_grey: (H, W) uint8 grey left image.
        disparity: (H, W) float32 SGBM map (px), NaN where invalid.
        gftt: the fill's settings (``fill_placement`` other than ``"lattice"``).
        area: (x0, y0, x1, y1) px searched.
        kept: (k, 2) float32 (x, y) px of the corners' lookups.
        count: how many points to choose.
        look_up: the lookups with their checks (points -> the ones kept and their values).
        prior_std: (gh, gw) prior disparity std (px) spanning the image (``"prior_std"``).

    Returns:
        The chosen points' pixels (m, 2) and disparities (m,), in the order chosen.

    Raises:
        ValueError: if ``fill_placement`` is ``"prior_std"`` and ``prior_std`` is None.
    """
    # the cheap checks first, the gaps to the kept points last (in weighted_fill), on the
    # fewest candidates; every check is per point, so the order changes nothing
    spacing = gftt.fill_spacing / 4.0
    candidates = lattice_points(np.zeros((0, 2), np.float32), spacing, area)
    if gftt.fill_min_support > 0.0:
        candidates = candidates[valid_share(disparity, candidates) >= gftt.fill_min_support]
    found = look_up(candidates)
    pixels, values = found.pixels, found.disparities
    textured = patch_contrast(left_grey, pixels) >= gftt.fill_min_contrast
    pixels, values = pixels[textured], values[textured]
    if gftt.fill_placement == "even":
        weights = np.ones(values.size, np.float32)
    elif gftt.fill_placement == "disparity":
        weights = np.maximum(values, 1.0) ** np.float32(gftt.fill_exponent)
    else:
        if prior_std is None:
            raise ValueError(
                "fill_placement 'prior_std' needs the prior's std map (prior_std=); the frame "
                "processor gives it from its basis"
            )
        height, width = left_grey.shape
        rows, cols = prior_std.shape
        gx = np.clip((pixels[:, 0] * cols / width).astype(np.int64), 0, cols - 1)
        gy = np.clip((pixels[:, 1] * rows / height).astype(np.int64), 0, rows - 1)
        weights = np.maximum(prior_std[gy, gx], 1e-3) ** np.float32(gftt.fill_exponent)
    weights = np.asarray(weights, np.float32)
    chosen = weighted_fill(kept, pixels, weights, count, area, min_gap=spacing / 2)
    return np.ascontiguousarray(pixels[chosen]), np.ascontiguousarray(values[chosen])


def weighted_fill(
    kept: FloatArray,
    candidates: FloatArray,
    weights: FloatArray,
    count: int,
    area: tuple[int, int, int, int] | None = None,
    min_gap: float = 0.0,
) -> npt.NDArray[np.int64]:
    """Choose ``count`` candidates greedily where gap to the nearest point x weight is largest.

    Each step takes the candidate c maximising w(c) g(c), g(c) = min_p |c - p| over the
    kept points and those chosen so far, then shrinks every candidate's gap by the new
    point. With weight 1 this is farthest-point sampling (an even cover); with a weight the
    final gaps go as about 1 / w, so the points' density grows as w^2. With ``area`` the
    gap is also at most twice the distance to the area's edge, as if the edge were
    mirrored measurements: plain farthest-point sampling would put its first points on the
    edges, where a point covers half the pixels an inner one does.

    Args:
        kept: (k, 2) float32 (x, y) px of the measurements already made.
        candidates: (m, 2) float32 (x, y) px to choose from.
        weights: (m,) float32 >= 0, each candidate's weight.
        count: how many to choose (at most m; fewer when the weighted gaps reach 0).
        area: (x0, y0, x1, y1) px the candidates lie in, or None (no edge term).
        min_gap: candidates this near a kept point (px) or nearer are never chosen.

    Returns:
        The chosen candidates' indices, in the order chosen.
    """
    total = min(int(count), candidates.shape[0])
    if total <= 0:
        return np.zeros(0, np.int64)
    xs = candidates[:, 0].astype(np.float32)
    ys = candidates[:, 1].astype(np.float32)
    if kept.shape[0]:
        gap = xs[:, None] - kept[None, :, 0].astype(np.float32)
        along_y = ys[:, None] - kept[None, :, 1].astype(np.float32)
        gap *= gap
        along_y *= along_y
        gap += along_y
        squared = gap.min(axis=1)
    else:
        squared = np.full(xs.shape, np.float32(np.inf))
    # compare w^2 gap^2: no square root per step
    weight_sq = np.square(np.asarray(weights, np.float32))
    weight_sq[squared <= min_gap**2] = 0.0
    if area is not None:
        x0, y0, x1, y1 = area
        edge = np.minimum(np.minimum(xs - x0, x1 - 1 - xs), np.minimum(ys - y0, y1 - 1 - ys))
        np.minimum(squared, np.square(2.0 * np.maximum(edge, 0.0)), out=squared)
    score = np.empty_like(squared)
    step_x, step_y = np.empty_like(xs), np.empty_like(ys)
    chosen = np.empty(total, np.int64)
    taken = 0
    for taken in range(total):
        if np.isfinite(squared[0]):
            np.multiply(squared, weight_sq, out=score)
            best = int(np.argmax(score))
            if not score[best] > 0.0:
                break
        else:  # no measurement and no edge yet: the heaviest candidate starts
            best = int(np.argmax(weight_sq))
        chosen[taken] = best
        np.subtract(xs, xs[best], out=step_x)
        np.subtract(ys, ys[best], out=step_y)
        step_x *= step_x
        step_y *= step_y
        step_x += step_y
        np.minimum(squared, step_x, out=squared)
    else:
        taken = total
    return chosen[:taken]
