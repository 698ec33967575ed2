"""Does the prior fit the log? The fit check, and a basis learned from the log's own stereo.

A basis is a prior on disparity maps of one kind of camera and scene. Used elsewhere (the
built-in street basis on an indoor drone log) it can pull the map away from its own
measurements and do worse than plain interpolation of the same points. A stereo log carries
its own check and its own training data: the SGBM maps the stereo front end computes anyway.

**Fit check** (:func:`check_frame`, :class:`FitCheck`): on a frame, the densified map, the
piecewise-linear and the nearest-neighbour interpolation of the same measurements are
compared with SGBM's map at pixels the estimate did not see: valid SGBM pixels away from
every measurement, a fixed, evenly spaced sample of them (:data:`HELDOUT_SAMPLES`). The
figure is the prior's mean absolute error over linear interpolation's ("0.41x linear").

**Self-supervised basis** (:func:`own_basis`, :func:`refit_prior`): a PCA basis learned from
the log's own SGBM maps at the log's own camera (no mapping of pixels or f*b), with the
prior refitted by the evidence of the frames' measurements (local kernel and sigma,
:func:`fitting.fit_local_prior`) and the std calibrated against the SGBM maps
(:func:`fitting.fit_std_scale`) of frames the basis did not learn from. From one map it is
that map as the mean with no direction of variation worth the name: the frame's own
stereo, smoothed, which the measurements then correct. Its held-out figure and its std's
calibration are measured leaving each checked frame, its neighbours and every copy of it
(:func:`view_labels`: a camera standing still repeats one view) out of the maps
(:func:`leave_one_out`): the honest figures for the frames that follow. (Calibrated on the
frames it learned from, its std fits the maps it reproduces: on a KITTI drive measured on a
34 px lattice, 44 % of the frames' errors then fell inside +-2 sigma.)

Everything here is deterministic: the same maps and measurements give the same basis.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from pcainterp_stream import compiled
from pcainterp_stream.estimate import fitting
from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.estimator import clean_measurements, densify
from pcainterp_stream.estimate.finetune import camera_mismatch
from pcainterp_stream.estimate.learning import learn_basis, preprocess_disparity
from pcainterp_stream.estimate.prior import Kernel, LocalPrior

HELDOUT_SAMPLES = 20_000
"""Held-out SGBM pixels scored per checked frame (evenly spaced over the valid ones)."""

HELDOUT_GAP = 2
"""Pixels within this many px (Chebyshev) of a measurement are not held out."""

UNCHECKED_COLUMNS = 16
"""A check none of whose pixels lies left of this column (px) says the columns it covered:
SGBM leaves its left band (x < min_disparity + num_disparities, at least 16 px) empty unless
it matches the whole width, so there the check has nothing to score (bug hunt 9B F6)."""

ADAPT_ABOVE = 1.0
"""A prior whose error is at least this times linear interpolation's does not fit."""

EXACT_LINEAR_PX = 1e-3
"""Held-out error (px) below which linear interpolation is exact: the check compares nothing.

No measured disparity is that exact: SGBM's are sixteenths of a pixel, a triangulated
point's depth has noise of centimetres. Linear interpolation scores below it only on
measurements that are constant (every point at one depth) or exactly planar at the scored
pixels; a ratio of the prior's error to such a ~0 (1e-14 px: 2.4e14x) says nothing of
the prior."""

ADAPT_GAIN = 0.5
"""A log's own basis also replaces a prior that fits when its held-out (leave-one-out) error
is below this share of the prior's. Its leave-one-out figure still flatters it: the
reference is the SGBM it learns to reproduce (and on a short warm-up, :data:`LEAVE_OUT_MAPS`,
the maps it learns from include the left-out frame's neighbours). On synthetic indoor logs
it was chosen over the built-in indoor basis at 0.7x and was worse against the truth (seed
4: 0.233 against 0.204 px)."""

GRID_SCALE = 0.25
"""Grid scale of a basis learned from a log's own maps (the built-in basis's)."""

MAX_COMPONENTS = 64
"""Most components of a log's own basis."""

SINGLE_MAP_VARIANCE = 1e-3
"""Eigenvalue (px^2 over the grid) of the one placeholder component of a one-map basis."""

FIT_FRAMES = 8
"""Most frames the prior is refitted on."""

FIT_POINTS = 200
"""Measurements per frame the evidence fit uses (the first ones)."""

PROCESS_NOISE = 0.1
"""The temporal prior's process noise when it cannot be fitted (frames not consecutive)."""

ROUGH_KERNEL = LocalPrior(40.0, 64.0, Kernel.LAPLACE)
"""The local kernel the fit check tries on the built-in indoor basis (:mod:`.rougher`).

Laplace, 64 px, 40 px^2 in the indoor basis's px (752x480, f*b 48 px*m): the values of the
street basis's fitted kernel, copied as numbers, measured as such on the indoor basis (EuRoC
2.49 -> 2.32 px, MyntEye 1.96 -> 1.75, synthetic rooms 3-16 % less error; bughunt10B Q2). It
is not the street prior (its disparity units are 8x the indoor basis's: the same variance in
inverse depth would be ~65x smaller), and a refit of the street basis does not change it."""


@dataclass(frozen=True)
class FitCheck:
    """Held-out errors of a prior and of plain interpolation, summed over checked frames.

    Attributes:
        frames: frames checked.
        pixels: held-out pixels scored, all frames.
        prior: mean |d - SGBM| of the densified map at those pixels (px).
        linear: the same for linear interpolation of the same points (px).
        nearest: the same for nearest-neighbour interpolation (px).
        first_column: the leftmost column (px) of those pixels: left of it nothing was
            checked (SGBM's left band when it is not matched); 0 for a feature stream's
            left-out check, where there is no band.
        far: those of the pixels the prior's map puts below its smallest resolvable
            disparity: the output writes them as too far (depth ``+inf``, disparity 0), and
            they are scored so (bug hunt 16D F8).
        cut: that smallest resolvable disparity (px; the largest of the frames').
    """

    frames: int
    pixels: int
    prior: float
    linear: float
    nearest: float
    first_column: int = 0
    far: int = 0
    cut: float = 0.0

    @property
    def ratio(self) -> float:
        """Return the prior's error over linear interpolation's (inf when linear is 0)."""
        return self.prior / self.linear if self.linear > 0 else math.inf

    @property
    def fits(self) -> bool:
        """Return whether the prior beats linear interpolation by the check's standard."""
        return self.frames > 0 and self.ratio < ADAPT_ABOVE

    @property
    def degenerate(self) -> bool:
        """Return whether linear interpolation is exact (:data:`EXACT_LINEAR_PX`): no check."""
        return self.frames > 0 and self.linear < EXACT_LINEAR_PX

    def describe(self, where: str = "held-out SGBM pixels") -> str:
        """Return "0.41x linear, 0.35x nearest on held-out SGBM pixels (1.21 px ...)"."""
        if self.frames == 0:
            return f"not checked (no frame had {where})"
        if self.degenerate:
            return (
                f"not checked: linear interpolation is exact on {where} ({self.linear:.2g} px; "
                f"they are constant or exactly planar), the prior off by {self.prior:.2f} px "
                f"({self.frames} frame{'s' if self.frames != 1 else ''})"
            )
        nearest = self.prior / self.nearest if self.nearest > 0 else math.inf
        if self.first_column >= UNCHECKED_COLUMNS:  # SGBM's left band: nothing checked there
            where = f"{where} in columns >= {self.first_column}"
        return (
            f"{self.ratio:.2f}x linear, {nearest:.2f}x nearest on {where} "
            f"({self.prior:.2f} px against {self.linear:.2f} and {self.nearest:.2f}; "
            f"{self.frames} frame{'s' if self.frames != 1 else ''}{self._far()})"
        )

    def _far(self) -> str:
        """Return "; 40 % of them written as too far ..." when that share is noticeable."""
        if self.pixels == 0 or self.far < FAR_NOTED * self.pixels:
            return ""
        return (
            f"; {100 * self.far / self.pixels:.0f} % of them written as too far and scored so: "
            f"below {self.cut:.2g} px, the smallest disparity the estimate resolves (its noise "
            "sigma in this camera's px; densify --sigma sets it on the basis's image)"
        )

    @classmethod
    def combine(cls, checks: Sequence[FrameCheck]) -> FitCheck:
        """Pool per-frame checks, weighting each frame by its held-out pixels."""
        used = [check for check in checks if check.pixels > 0]
        total = sum(check.pixels for check in used)
        if total == 0:
            return cls(0, 0, math.nan, math.nan, math.nan)

        def mean(name: str) -> float:
            return float(sum(getattr(check, name) * check.pixels for check in used)) / total

        first = min(check.first_column for check in used)
        errors = mean("prior"), mean("linear"), mean("nearest")
        far, cut = sum(check.far for check in used), max(check.cut for check in used)
        return cls(len(used), total, *errors, first, far, cut)


FAR_NOTED = 0.05
"""The share of a check's pixels written as too far from which its line says so."""


@dataclass(frozen=True)
class FrameCheck:
    """One frame's held-out errors (px), how many pixels they are over and the leftmost's column.

    ``far``: those of the pixels the estimate puts below ``cut``, its smallest resolvable
    disparity (px): written as too far, so scored as disparity 0 (:attr:`FitCheck.far`).
    """

    pixels: int
    prior: float
    linear: float
    nearest: float
    first_column: int = 0
    far: int = 0
    cut: float = 0.0


def heldout_pixels(
    reference: npt.NDArray[np.floating[Any]],
    pixels: npt.NDArray[np.floating[Any]],
    samples: int = HELDOUT_SAMPLES,
    clipped: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.intp]:
    """Return flat indices of held-out pixels: valid in ``reference``, away from ``pixels``.

    Args:
        reference: (H, W) SGBM disparity (px); NaN or <= 0 is invalid.
        pixels: (k, 2) measurement positions (x, y) px.
        samples: at most this many, evenly spaced in raster order (deterministic).
        clipped: (H, W) pixels left out too (an over-exposed pair's clipped ones:
            :func:`~pcainterp_stream.frontend.levels.clipped_pixels`); None: none.
    """
    valid = np.isfinite(reference) & (reference > 0)
    if clipped is not None:
        valid &= ~clipped
    height, width = valid.shape
    if pixels.size:
        cols = np.clip(np.rint(pixels[:, 0]).astype(np.intp), 0, width - 1)
        rows = np.clip(np.rint(pixels[:, 1]).astype(np.intp), 0, height - 1)
        seen = np.zeros_like(valid)
        for dy in range(-HELDOUT_GAP, HELDOUT_GAP + 1):
            for dx in range(-HELDOUT_GAP, HELDOUT_GAP + 1):
                seen[np.clip(rows + dy, 0, height - 1), np.clip(cols + dx, 0, width - 1)] = True
        valid &= ~seen
    flat = np.flatnonzero(valid)
    if flat.size > samples:
        flat = flat[np.linspace(0, flat.size - 1, samples).round().astype(np.intp)]
    return flat


def interpolation_at(
    pixels: npt.ArrayLike,
    disparities: npt.ArrayLike,
    image_size: tuple[int, int],
    flat: npt.NDArray[np.intp],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Return (linear, nearest) interpolation of the measurements at flat pixel indices.

    The same rules as :mod:`~pcainterp_stream.estimate.baselines` (linear on the Delaunay
    triangulation, nearest outside its hull), evaluated only where needed.
    """
    # the front end's measurements: SGBM's 0 is a match (estimator.densify, zero_is_match)
    points, values, _ = clean_measurements(pixels, disparities, image_size, zero_is_match=True)
    width = image_size[1]
    at = np.stack([flat % width, flat // width], axis=1).astype(np.float64)
    if values.size == 0:
        empty = np.full(flat.size, np.nan)
        return empty, empty
    # scipy's k-d tree and Qhull without the rest of scipy.spatial (~0.2 s of imports),
    # loaded on first use; densify loads them beside the first stereo frames
    qhull = compiled.module("spatial._qhull")
    _, nearest_index = compiled.module("spatial._ckdtree").cKDTree(points).query(at)
    nearest = values[nearest_index]
    linear = nearest.copy()
    if values.size >= 3:
        try:
            inside = _linear_at(points, values, at)
        except qhull.QhullError:  # collinear points: nearest everywhere
            inside = np.full(flat.size, np.nan)
        found = np.isfinite(inside)
        linear[found] = inside[found]
    return linear, nearest


def _linear_at(
    points: npt.NDArray[np.float64], values: npt.NDArray[np.float64], at: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Linear interpolation on the Delaunay triangulation at ``at`` (m, 2); NaN outside it.

    scipy's ``LinearNDInterpolator`` in two dimensions, value for value (the same
    triangulation, triangle search and barycentric sums in the same order), without
    importing ``scipy.interpolate`` (~0.15 s of CPU, most of it ``scipy.optimize``).
    """
    triangulation = compiled.module("spatial._qhull").Delaunay(points)
    simplex = triangulation.find_simplex(at)
    found = simplex >= 0
    which = simplex[found]
    transform = triangulation.transform[which]  # (m, 3, 2): inverse rows, then the origin
    dx = at[found, 0] - transform[:, 2, 0]
    dy = at[found, 1] - transform[:, 2, 1]
    first = transform[:, 0, 0] * dx + transform[:, 0, 1] * dy
    second = transform[:, 1, 0] * dx + transform[:, 1, 1] * dy
    third = (1.0 - first) - second
    corner = values[triangulation.simplices[which]]
    inside = np.full(at.shape[0], np.nan)
    inside[found] = (first * corner[:, 0] + second * corner[:, 1]) + third * corner[:, 2]
    return inside


def check_frame(
    estimate: npt.NDArray[np.floating[Any]],
    reference: npt.NDArray[np.floating[Any]],
    pixels: npt.NDArray[np.floating[Any]],
    disparities: npt.NDArray[np.floating[Any]],
    min_disparity: float = 0.0,
) -> FrameCheck:
    """Score one frame's densified map and plain interpolation against its SGBM map.

    Args:
        estimate: (H, W) densified disparity (px).
        reference: (H, W) SGBM disparity of the same pair (px; NaN or <= 0 invalid).
        pixels: (k, 2) the measurements the estimate used, (x, y) px.
        disparities: (k,) their disparities (px).
        min_disparity: the estimate's smallest resolvable disparity (px): below it the
            output writes too far, so it is scored as 0 (:meth:`HeldOut.score`).
    """
    return HeldOut.of(reference, pixels, disparities).score(estimate, min_disparity)


@dataclass(frozen=True)
class HeldOut:
    """One frame's held-out pixels, their SGBM values and plain interpolation there.

    What :func:`check_frame` scores a densified map against; built once per frame, it
    scores the maps of several bases (the built-in ones checked in turn) at the cost of one.
    """

    flat: npt.NDArray[np.intp]
    truth: npt.NDArray[np.float64]
    linear: npt.NDArray[np.float64]
    nearest: npt.NDArray[np.float64]
    width: int = 1  # the image's (px): a flat index's column is flat % width

    @classmethod
    def of(
        cls,
        reference: npt.NDArray[np.floating[Any]],
        pixels: npt.NDArray[np.floating[Any]],
        disparities: npt.NDArray[np.floating[Any]],
        clipped: npt.NDArray[np.bool_] | None = None,
    ) -> HeldOut:
        """Hold pixels out of ``reference`` away from ``pixels``, not ``clipped``; interpolate."""
        flat = heldout_pixels(reference, pixels, clipped=clipped)
        if flat.size == 0 or disparities.size == 0:
            empty = np.zeros(0)
            return cls(np.zeros(0, np.intp), empty, empty, empty)
        truth = reference.ravel()[flat].astype(np.float64)
        linear, nearest = interpolation_at(pixels, disparities, reference.shape[:2], flat)
        return cls(flat, truth, linear, nearest, reference.shape[1])

    def score(
        self, estimate: npt.NDArray[np.floating[Any]], min_disparity: float = 0.0
    ) -> FrameCheck:
        """Score a densified (H, W) map and the interpolation at the held-out pixels.

        ``min_disparity``: the estimate's smallest resolvable disparity (px,
        :attr:`~.estimator.DensifyResult.min_disparity`): the output writes a pixel below
        it as too far (depth ``+inf``: disparity 0 as read back), so it is scored as 0, as
        ``evaluate`` scores the output (bug hunt 16D F8: a sigma-2 basis on a camera of
        f*b 9.6 px*m checked 0.39 px, its output 1.16 px). 0: as estimated.
        """
        if self.flat.size == 0:
            return FrameCheck(0, 0.0, 0.0, 0.0)
        columns = self.flat % self.width
        at = estimate.ravel()[self.flat]
        return _score(at, self.truth, self.linear, self.nearest, columns, min_disparity)


def _score(
    prior: npt.NDArray[np.floating[Any]],
    truth: npt.NDArray[np.float64],
    linear: npt.NDArray[np.float64],
    nearest: npt.NDArray[np.float64],
    columns: npt.NDArray[np.intp] | None = None,
    min_disparity: float = 0.0,
) -> FrameCheck:
    """Mean |error| of the prior's map, linear and nearest where all three and the truth exist.

    ``columns`` are the pixels' columns (px) of an SGBM held-out check: the leftmost scored
    one is kept (None, a left-out check of a feature stream: 0, no band to say; review 57c F3).
    The prior's values below ``min_disparity`` are scored as 0 (written as too far).
    """
    estimate = prior.astype(np.float64)
    ok = np.isfinite(estimate) & np.isfinite(linear) & np.isfinite(truth)
    if not ok.any():
        return FrameCheck(0, 0.0, 0.0, 0.0)
    # the float32 comparison the output's depth makes (estimator.depth_from_disparity)
    far = ok & (prior.astype(np.float32) < np.float32(min_disparity))
    estimate[far] = 0.0
    return FrameCheck(
        int(ok.sum()),
        float(np.abs(estimate[ok] - truth[ok]).mean()),
        float(np.abs(linear[ok] - truth[ok]).mean()),
        float(np.abs(nearest[ok] - truth[ok]).mean()),
        0 if columns is None else int(columns[ok].min()),
        int(far.sum()),
        float(min_disparity),
    )


LEFT_OUT_EVERY = 5
"""The left-out check (:func:`left_out_split`) holds out every 5th measurement."""


def left_out_split(count: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Return (kept, left out) indices of ``count`` measurements: every 5th one left out.

    For logs without a dense stereo map to hold pixels out of (a sparse feature stream):
    the estimate from the kept points is scored at the left-out ones.
    """
    indices = np.arange(count)
    left_out = indices % LEFT_OUT_EVERY == LEFT_OUT_EVERY - 1
    return indices[~left_out], indices[left_out]


def check_left_out(
    estimate: npt.NDArray[np.floating[Any]],
    pixels: npt.NDArray[np.floating[Any]],
    disparities: npt.NDArray[np.floating[Any]],
    kept: npt.NDArray[np.intp],
    left_out: npt.NDArray[np.intp],
    min_disparity: float = 0.0,
) -> FrameCheck:
    """Score a map estimated from the ``kept`` measurements at the ``left_out`` ones.

    Args:
        estimate: (H, W) disparity densified from ``pixels[kept]`` (px).
        pixels: (k, 2) all measurements (x, y) px.
        disparities: (k,) their disparities (px).
        kept: indices the estimate used.
        left_out: indices it did not see.
        min_disparity: the estimate's smallest resolvable disparity (px): scored as 0
            below it, as written (:meth:`HeldOut.score`).
    """
    height, width = estimate.shape[:2]
    at = pixels[left_out]
    cols = np.clip(np.rint(at[:, 0]).astype(np.intp), 0, width - 1)
    rows = np.clip(np.rint(at[:, 1]).astype(np.intp), 0, height - 1)
    flat = rows * width + cols
    if flat.size == 0 or kept.size == 0:
        return FrameCheck(0, 0.0, 0.0, 0.0)
    truth = disparities[left_out].astype(np.float64)
    linear, nearest = interpolation_at(pixels[kept], disparities[kept], (height, width), flat)
    # no SGBM band to say
    return _score(estimate.ravel()[flat], truth, linear, nearest, None, min_disparity)


def own_grid_size(image_size: tuple[int, int]) -> tuple[int, int]:
    """Return the grid of a basis learned from a log's own maps at this image size."""
    return grid_size_for(image_size, GRID_SCALE)


def grid_map(disparity_map: npt.ArrayLike, image_size: tuple[int, int]) -> npt.NDArray[np.float32]:
    """Preprocess one SGBM map for :func:`own_basis` (holes filled, blurred, on the grid).

    Filling SGBM's holes along rows (interpolated, or the farther side at occlusions)
    instead of by the nearest valid pixel was tried and measured no better (EuRoC held out
    1.31 against 1.21 px; synthetic indoor against ground truth 1.753 against 1.755 px).
    """
    return preprocess_disparity(disparity_map, own_grid_size(image_size))


def own_basis(
    grid_maps: Sequence[npt.NDArray[np.float32]],
    image_size: tuple[int, int],
    focal_baseline: float,
) -> Basis:
    """Learn a basis from a log's own preprocessed SGBM maps (:func:`grid_map`).

    Args:
        grid_maps: one or more (gh, gw) float32 maps of one camera, in stream order.
        image_size: (height, width) of that camera (px).
        focal_baseline: its f*b (px*m).

    Returns:
        The basis, at the camera's own size and f*b. From one map, or maps that are all the
        same (a static pair repeated): that map as the mean and one placeholder component of
        negligible variance.

    Raises:
        ValueError: no map.
    """
    if not grid_maps:
        raise ValueError("Expected at least one map to learn a basis from")
    meta = {"source": "self-supervised: the log's own SGBM maps", "maps": len(grid_maps)}
    if all(np.array_equal(grid_maps[0], other) for other in grid_maps[1:]):
        grid = grid_maps[0].shape
        component = np.zeros((1, *grid), dtype=np.float32)
        component[0].flat[0] = 1.0
        return Basis(
            mean=np.ascontiguousarray(grid_maps[0], dtype=np.float32),
            components=component,
            eigenvalues=np.array([SINGLE_MAP_VARIANCE]),
            total_variance=SINGLE_MAP_VARIANCE,
            image_size=image_size,
            focal_baseline=float(focal_baseline),
            n_train=1,
            meta={**meta, "grid_scale": GRID_SCALE},
        )
    return learn_basis(
        list(grid_maps),
        n_components=min(MAX_COMPONENTS, len(grid_maps) - 1),
        grid_scale=GRID_SCALE,
        focal_baseline=float(focal_baseline),
        preprocessed=True,
        image_size=image_size,
        method="exact",
        meta=meta,
    )


TYPICAL_SHARE = 0.5
"""A frame whose measurements, or SGBM-matched pixels, are fewer than this share of the
median frame's of the fit check is left out of it (:func:`typical_frames`)."""


class _CheckFrame(Protocol):
    """What :func:`typical_frames` reads of a frame."""

    @property
    def pixels(self) -> npt.NDArray[np.float32]: ...
    @property
    def sgbm_map(self) -> npt.NDArray[np.float32] | None: ...
    @property
    def index(self) -> int: ...


_Frame = TypeVar("_Frame", bound=_CheckFrame)


def typical_frames(frames: list[_Frame], lines: list[str]) -> list[_Frame]:
    """Return the frames the fit check may score on; add a line naming those left out.

    Held-out SGBM pixels are the check's reference: a frame of a broken pair or scene (a
    textureless wall, a capped lens, a blanked swapped pair) has few measurements and few
    SGBM matches, and its pixels are no reference. Three such frames among the 8 of a
    synthetic street chose the indoor basis for the whole log (its clean frames' error up to
    2.8x): a frame with fewer measurements or matched SGBM pixels than
    :data:`TYPICAL_SHARE` of the median frame's is left out (a wall 0.19 and 0.35 of them,
    a lens cap 0-0.03 and 0.05-0.11; clean KITTI and synthetic frames 0.7-1.2).
    """
    if len(frames) < 3:
        return frames
    counts = np.array([f.pixels.shape[0] for f in frames], dtype=np.float64)
    matched = np.array([np.mean(f.sgbm_map > 0) if f.sgbm_map is not None else 0.0 for f in frames])
    keep = (counts >= TYPICAL_SHARE * np.median(counts)) & (
        matched >= TYPICAL_SHARE * np.median(matched)
    )
    if keep.all() or not keep.any():
        return frames
    out = [f.index for f, k in zip(frames, keep, strict=True) if not k]
    lines.append(
        f"prior: {len(out)} of the check's {len(frames)} frames left out (frame(s) "
        f"{', '.join(map(str, out))}): fewer than {TYPICAL_SHARE:.0%} of the median frame's "
        "measurements or SGBM matches (a blank, textureless or capped view, or a pair not "
        "matched), their SGBM pixels are no reference"
    )
    return [f for f, k in zip(frames, keep, strict=True) if k]


@dataclass(frozen=True)
class Measured:
    """One frame's measurements and SGBM map, for refitting and checking a prior."""

    pixels: npt.NDArray[np.float32]
    disparities: npt.NDArray[np.float32]
    reference: npt.NDArray[np.float32]


def refit_prior(
    basis: Basis,
    frames: Sequence[Measured],
    *,
    robust: str,
    calibrate: bool = True,
    keep: Basis | None = None,
    calibrate_with: Basis | None = None,
) -> Basis:
    """Return ``basis`` with its prior fitted on ``frames`` (``meta["prior"]``).

    The local kernel and sigma by the evidence of the frames' measurements
    (:func:`fitting.fit_local_prior`); with ``calibrate``, the std scale that makes the
    posterior std match the error against the frames' SGBM maps (:func:`fitting.fit_std_scale`),
    of the frames densified with ``calibrate_with`` (a basis that did not learn from them,
    so the errors are those of frames to come; None: ``basis`` itself, which may have).
    Uses at most :data:`FIT_FRAMES` frames, evenly spaced, and the first
    :data:`FIT_POINTS` measurements of each (the evidence's k x k Cholesky per candidate
    dominates: 14 s per fit on 8 full frames of a 752x480 log, measured). With ``keep``
    (the basis this one relearns), its kernel is kept and only sigma refitted, and its
    process noise kept: the cost of a streaming update stays small.
    """
    step = max(1, math.ceil(len(frames) / FIT_FRAMES))
    used = list(frames[::step])
    size, fb = basis.image_size, basis.focal_baseline
    fit_frames = [
        fitting.fit_frame(
            basis,
            frame.pixels,
            frame.disparities,
            image_size=size,
            focal_baseline=fb,
            max_points=FIT_POINTS,
        )
        for frame in used
    ]
    if not any(frame.residual.size for frame in fit_frames):
        return basis
    kept = keep.meta.get("prior", {}) if keep is not None else {}
    fixed = LocalPrior.from_meta(kept["local"]) if kept.get("local") else None
    if fixed is not None:
        local_fit = fitting.fit_local_prior(basis, fit_frames, fixed=fixed)
    else:
        local_fit = fitting.fit_local_prior(basis, fit_frames)
    prior: dict[str, Any] = local_fit.to_meta()
    prior["source"] = "self-supervised"
    prior["process_noise"] = float(kept.get("process_noise", PROCESS_NOISE))
    if keep is None and len(fit_frames) >= 2 and step == 1:  # consecutive: temporal prior too
        prior["process_noise"], _ = fitting.fit_process_noise(
            basis, [fit_frames], local=local_fit.local, sigma=local_fit.sigma
        )
    if calibrate:
        estimates, stds, references = [], [], []
        for frame in used:
            result = densify(
                basis if calibrate_with is None else calibrate_with,
                frame.pixels,
                frame.disparities,
                sigma=local_fit.sigma,
                local_prior=local_fit.local,
                robust=robust,
                uncertainty="exact-coarse",
                zero_is_match=True,
            )
            if result.disparity_std is None:
                continue
            estimates.append(result.disparity)
            stds.append(result.disparity_std)
            references.append(frame.reference)
        if estimates:
            prior["std_scale"] = fitting.fit_std_scale(estimates, stds, references)
    return with_prior(basis, prior)


def with_prior(basis: Basis, prior: dict[str, Any]) -> Basis:
    """Return ``basis`` with ``prior`` as its ``meta["prior"]``."""
    meta = dict(basis.meta)
    meta["prior"] = prior
    return Basis(
        mean=basis.mean,
        components=basis.components,
        eigenvalues=basis.eigenvalues,
        total_variance=basis.total_variance,
        image_size=basis.image_size,
        focal_baseline=basis.focal_baseline,
        n_train=basis.n_train,
        meta=meta,
    )


def other_camera(basis: Basis, image_size: tuple[int, int], focal_baseline: float) -> str:
    """Say, for a warning, that ``basis`` was learned for another camera than the log's, or "".

    Another camera as ``learn`` would not merge its maps into the basis
    (:func:`~pcainterp_stream.estimate.finetune.camera_mismatch`): "; the basis was learned
    for another camera (320x240 px, f*b 9.6 px*m; this log's 620x188 px, f*b 193.1 px*m:
    aspect ratio 3.30 against 1.33)".
    """
    why = camera_mismatch(basis, image_size, focal_baseline)
    if why is None or basis.focal_baseline <= 0 or focal_baseline <= 0:
        return ""
    (height, width), (basis_height, basis_width) = image_size, basis.image_size
    return (
        f"; the basis was learned for another camera ({basis_width}x{basis_height} px, f*b "
        f"{basis.focal_baseline:.1f} px*m; this log's {width}x{height} px, f*b "
        f"{focal_baseline:.1f} px*m: {why})"
    )


LEAVE_OUT_GAP = 2
"""Maps of frames within this many frames of a left-out one are left out with it.

Consecutive frames of a log are near copies: a basis that learned a frame's neighbour
reproduces the frame, and the figure flatters it against the frames that follow (on a KITTI
drive measured on a 34 px lattice: 0.94 px held out against 1.86 px over the drive). The
log's own basis meets those frames 1-8 frames after its newest map before it relearns."""

LEAVE_OUT_MAPS = 3
"""Fewest maps a left-out frame's basis learns from; with fewer beyond the gap, every other
map that is no copy of it is used (a short warm-up: its figure flatters the basis more)."""

SAME_VIEW = 0.1
"""Two frames whose grid maps (:func:`grid_map`) differ by less than this median |difference|
(px of disparity) are one view: a camera standing still, or a driver sending its last pair
again. Measured on grid maps (the median over the grid, per pair of frames): one frame
repeated with 1-2 grey levels of noise 0.04-0.07 px (KITTI odometry, EuRoC machine hall, a
synthetic room); the slowest motion seen, a synthetic indoor walk at 20 Hz and half size,
0.11-0.23 px between consecutive frames and 0.16 or more three frames apart; the two EuRoC
pairs 0.30 px; KITTI frames at 10 Hz 0.58 px or more. The median, not the mean: SGBM's noisy
pixels (a standing KITTI view: mean 0.55-1.2 px) or a person walking past a robot that
stands change a few cells, not the view."""


def view_distance(grid: npt.NDArray[np.float32], other: npt.NDArray[np.float32]) -> float:
    """Return the median |difference| (px) of two grid maps (:func:`grid_map`) of one camera."""
    return float(np.median(np.abs(grid - other)))


def view_labels(
    grid_maps: Sequence[npt.NDArray[np.float32]],
    *,
    tolerance: float = SAME_VIEW,
    same_as: Sequence[int] | None = None,
) -> npt.NDArray[np.intp]:
    """Label each map with its view: maps closer than ``tolerance`` share one.

    In stream order, a map joins the first view whose first map is closer to it than
    ``tolerance`` (:func:`view_distance`), else starts a view of its own. Maps of one view
    are one piece of evidence: a basis that learned one reproduces the others. Fresh sensor
    noise in every frame puts the maps of a camera standing still 0.07-0.10 px apart, close
    to ``tolerance``: ``same_as`` (from the ego-motion) says which maps are one view anyway.

    Args:
        grid_maps: (gh, gw) float32 maps of one camera (:func:`grid_map`), in stream order.
        tolerance: the largest median |difference| (px of disparity) within a view.
        same_as: for each map, the index of an earlier map of the same view (the camera
            has not moved since), or its own index; None: the maps alone decide.

    Returns:
        (n,) view index of each map: 0 for the first map's view, then 1, 2... in the order
        they first appear.

    Examples:
        >>> import numpy as np
        >>> still = np.full((4, 4), 10.0, dtype=np.float32)
        >>> moved = still + 1.0
        >>> view_labels([still, still + 0.01, moved, still]).tolist()
        [0, 0, 1, 0]
    """
    labels = np.zeros(len(grid_maps), dtype=np.intp)
    firsts: list[int] = []
    for index, grid in enumerate(grid_maps):
        if same_as is not None and same_as[index] < index:
            labels[index] = labels[same_as[index]]
            continue
        for label, first in enumerate(firsts):
            if view_distance(grid, grid_maps[first]) < tolerance:
                labels[index] = label
                break
        else:
            labels[index] = len(firsts)
            firsts.append(index)
    return labels


class OwnCheck(NamedTuple):
    """A log's own basis on frames left out of its maps (:func:`leave_one_out`).

    Attributes:
        check: the held-out errors, as :func:`check_frame` scores a frame.
        std_scale: the std scale that puts 95.4 % of the left-out frames' errors against
            their SGBM maps inside +-2 std (:func:`fitting.fit_std_scale`); None when not
            asked for.
    """

    check: FitCheck
    std_scale: float | None
    left_out: tuple[int, ...] = ()


class LeaveOut(NamedTuple):
    """One frame :func:`leave_one_out` leaves out, and the maps its basis learns.

    Attributes:
        frame: the left-out frame (its index).
        others: the maps learned (indices).
        near: fewer than :data:`LEAVE_OUT_MAPS` maps lie beyond the gap, so ``others`` has
            the frame's neighbours too (the short warm-up's fallback): its figure flatters
            the basis.
    """

    frame: int
    others: list[int]
    near: bool


def leave_out_plan(
    grid_maps: Sequence[npt.NDArray[np.float32]],
    *,
    max_frames: int = 4,
    gap: int = LEAVE_OUT_GAP,
    tolerance: float = SAME_VIEW,
    views: npt.NDArray[np.intp] | None = None,
) -> list[LeaveOut]:
    """Return the frames :func:`leave_one_out` leaves out and what each one's basis learns.

    Empty with fewer than 2 views. A plan with a ``near`` frame is a warm-up too short for
    the gap rule: on a 4-frame synthetic room its own basis scored 0.15 px held out, 0.35 px
    against the truth, and its std calibrated there held 52 % of the truth.
    """
    labels = view_labels(grid_maps, tolerance=tolerance) if views is None else views
    _, firsts = np.unique(labels, return_index=True)
    if firsts.size < 2:
        return []
    picks = np.linspace(0, firsts.size - 1, min(max_frames, firsts.size)).round()
    chosen = firsts[np.unique(picks).astype(np.intp)]
    plan = []
    for index in chosen.astype(int):
        # a map closer to the left-out frame's than ``tolerance`` is a copy: never learned
        differ = [
            i
            for i, grid in enumerate(grid_maps)
            if labels[i] != labels[index] and view_distance(grid, grid_maps[index]) >= tolerance
        ]
        others = [i for i in differ if abs(i - index) > gap]
        near = len(others) < min(LEAVE_OUT_MAPS, len(differ))
        plan.append(LeaveOut(index, differ if near else others, near))
    return plan


def leave_one_out(
    grid_maps: Sequence[npt.NDArray[np.float32]],
    frames: Sequence[Measured],
    prior: dict[str, Any],
    *,
    image_size: tuple[int, int],
    focal_baseline: float,
    robust: str,
    max_frames: int = 4,
    calibrate: bool = False,
    gap: int = LEAVE_OUT_GAP,
    tolerance: float = SAME_VIEW,
    views: npt.NDArray[np.intp] | None = None,
    held_out: Sequence[HeldOut] | None = None,
) -> OwnCheck | None:
    """Check a log's own basis on frames left out of its maps (None with fewer than 2 views).

    For up to ``max_frames`` views (:func:`view_labels` with ``tolerance``; evenly spaced, a
    view's first frame), learn from the maps of the frames more than ``gap`` frames away
    that are no copy of it (closer than ``tolerance``; when that leaves fewer than
    :data:`LEAVE_OUT_MAPS`, from every map that is no copy), densify the left-out frame with
    ``prior`` (its fitted local kernel and sigma: hyperparameters of all frames, a small
    leak) and score it as :func:`check_frame` does. With ``calibrate``, the left-out frames'
    posterior std is computed too and calibrated against their maps. A log whose frames all
    differ is checked on evenly spaced frames, its copies (a camera standing still) on one
    frame per view and never with a copy among the maps: ``tolerance=0`` checks every frame
    as a view of its own. ``views``: the maps' view labels when known beyond the maps
    (:func:`view_labels` with ``same_as``); maps of the left-out frame's view are never
    learned either. ``held_out``: each frame's held-out pixels when made already (the
    other bases' check scored the same pixels); :attr:`OwnCheck.left_out` names the frames.
    """
    plan = leave_out_plan(
        grid_maps, max_frames=max_frames, gap=gap, tolerance=tolerance, views=views
    )
    if not plan:
        return None
    local = LocalPrior.from_meta(prior["local"]) if prior.get("local") else None
    sigma = float(prior.get("sigma" if local is not None else "plain_sigma", 2.0))
    checks = []
    estimates, stds, references = [], [], []
    for index, learned, _ in plan:
        basis = own_basis([grid_maps[i] for i in learned], image_size, focal_baseline)
        frame = frames[index]
        result = densify(
            basis,
            frame.pixels,
            frame.disparities,
            sigma=sigma,
            local_prior=local,
            robust=robust,
            uncertainty="exact-coarse" if calibrate else "none",
            zero_is_match=True,
        )
        scored = (
            held_out[index]
            if held_out is not None
            else HeldOut.of(frame.reference, frame.pixels, frame.disparities)
        )
        checks.append(scored.score(result.disparity, result.min_disparity))
        if result.disparity_std is not None:
            estimates.append(result.disparity)
            stds.append(result.disparity_std)
            references.append(frame.reference)
    std_scale = fitting.fit_std_scale(estimates, stds, references) if estimates else None
    left_out = tuple(step.frame for step in plan)
    return OwnCheck(FitCheck.combine(checks), std_scale, left_out)
