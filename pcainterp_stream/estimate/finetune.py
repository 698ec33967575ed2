"""Fine-tuning a basis with a user's maps: a learned basis as the prior sample of a PCA.

A user with few real frames cannot learn a good basis from them alone (n maps span at most
n - 1 directions), and a basis learned elsewhere (the built-in one, from the synthetic
world) misses what is particular to their scenes. :func:`finetune_basis` pools the two.
The basis stands for ``n_prior`` maps with its mean m_s and its low-rank covariance
C_s = U_s Lambda_s U_s^T; the user's n_r maps have mean m_r and covariance C_r. The
covariance of all n = n_s + n_r maps together is exact (the pooled scatter of two groups):

    (n - 1) C = (n_s - 1) C_s + (n_r - 1) C_r + (n_s n_r / n) (m_s - m_r)(m_s - m_r)^T,

whose factor is [U_s sqrt((n_s - 1) Lambda_s) | D_r | sqrt(n_s n_r / n) (m_s - m_r)] with
D_r the centred user maps: the thin SVD of that stack (:func:`learning.truncated_product`,
its c x c Gram matrix, cheap) gives the top eigenpairs. It is the incremental SVD of
:mod:`learning` seeded with the basis's factor, so the user's maps stream in batches and
memory does not grow with their number. When the basis kept every component of its
training maps and n_prior is their number, the result is the basis those maps and the
user's would have given together (up to the ``keep`` truncation of each batch).

The user's maps are mapped onto the basis's camera first, as ``densify`` maps a camera
(docs/estimator.md, "Camera mapping"): disparities scaled by
(f*b)_basis / (f*b)_maps, then the usual preprocessing, its area resampling going straight
to the basis grid. The result is for the basis's image size and f*b, and ``densify`` maps
it onto the user's camera like any basis.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate.basis import BUILTIN_KINDS, Basis, builtin_basis
from pcainterp_stream.estimate.estimator import disparity_array
from pcainterp_stream.estimate.learning import (
    DEFAULT_BOX_SIZE,
    PcaFit,
    Sketch,
    basis_from_fit,
    fit_from_factor,
    merge_sketches,
    preprocess_disparity,
    streaming_fit,
)

ASPECT_TOLERANCE = 0.10
"""``camera_mismatch``: largest relative difference of the width/height ratio."""

DISPARITY_TOLERANCE = 1.5
"""``camera_mismatch``: largest factor between the disparity ranges (f*b per image width)."""


def camera_mismatch(basis: Basis, image_size: tuple[int, int], focal_baseline: float) -> str | None:
    """Say why a camera's maps should not be merged into a basis's statistics, or None.

    The maps are mapped onto the basis's camera as ``densify`` maps a log
    (docs/estimator.md, "Camera mapping"): pixels scaled to its image size, disparities by
    the f*b ratio. That keeps
    the street's depths but not its look, so the two cameras must agree on:

    - the **aspect ratio** (width / height) within :data:`ASPECT_TOLERANCE`: otherwise the
      horizon, the road and the sky land on other grid rows than in the basis;
    - the **disparity range**, f*b per image width (the disparity of one depth as a share
      of the image width; it is the field of view times the baseline), within a factor
      :data:`DISPARITY_TOLERANCE`: otherwise the same scene has another disparity range
      and the basis's statistics (and the SGBM search range of the maps) do not carry over.

    The camera's mounting (height, pitch) and the kind of scene cannot be checked here;
    ``--with-synthetic 0`` turns the merge off.

    Args:
        basis: the basis to merge into (its ``image_size`` and ``focal_baseline``).
        image_size: (height, width) of the maps' camera (px).
        focal_baseline: f*b of the maps' camera (px*m); <= 0: unknown.

    Returns:
        None when the cameras agree, else a short reason ("aspect ratio 1.78 against 3.30",
        the camera's first).
    """
    height, width = image_size
    basis_height, basis_width = basis.image_size
    aspect, basis_aspect = width / height, basis_width / basis_height
    if abs(aspect / basis_aspect - 1.0) > ASPECT_TOLERANCE:
        return f"aspect ratio {aspect:.2f} against {basis_aspect:.2f}"
    if not (np.isfinite(focal_baseline) and focal_baseline > 0) or basis.focal_baseline <= 0:
        return "f*b unknown"
    ratio = (focal_baseline / width) / (basis.focal_baseline / basis_width)
    if not 1.0 / DISPARITY_TOLERANCE <= ratio <= DISPARITY_TOLERANCE:
        return (
            f"disparity range (f*b / image width) {focal_baseline / width:.3g} m against "
            f"{basis.focal_baseline / basis_width:.3g} m"
        )
    return None


def camera_distance(basis: Basis, image_size: tuple[int, int], focal_baseline: float) -> float:
    """Return how far a camera is from a basis's, in units of :func:`camera_mismatch`'s limits.

    The larger of |aspect / basis aspect - 1| / :data:`ASPECT_TOLERANCE` and
    |log(disparity range ratio)| / log(:data:`DISPARITY_TOLERANCE`) (the aspect term alone
    when either f*b is unknown): at most 1 when :func:`camera_mismatch` finds nothing. It
    ranks the built-in bases for a camera (:func:`builtin_fits`).

    Args:
        basis: the basis (its ``image_size`` and ``focal_baseline``).
        image_size: (height, width) of the maps' camera (px).
        focal_baseline: f*b of the maps' camera (px*m); <= 0: unknown.
    """
    height, width = image_size
    basis_height, basis_width = basis.image_size
    aspect = abs((width / height) / (basis_width / basis_height) - 1.0) / ASPECT_TOLERANCE
    if not (np.isfinite(focal_baseline) and focal_baseline > 0) or basis.focal_baseline <= 0:
        return float(aspect)
    ratio = (focal_baseline / width) / (basis.focal_baseline / basis_width)
    return float(max(aspect, abs(np.log(ratio)) / np.log(DISPARITY_TOLERANCE)))


@dataclass(frozen=True)
class BuiltinFit:
    """How a camera fits one built-in basis (:func:`builtin_fits`).

    Attributes:
        kind: "street" or "indoor" (:data:`~pcainterp_stream.estimate.basis.BUILTIN_KINDS`).
        basis: that built-in basis.
        mismatch: :func:`camera_mismatch`'s reason, None when the camera is like its.
        distance: :func:`camera_distance` of the camera from its.
    """

    kind: str
    basis: Basis
    mismatch: str | None
    distance: float


def builtin_fits(image_size: tuple[int, int], focal_baseline: float) -> list[BuiltinFit]:
    """Return how a camera fits each installed built-in basis, the closest first.

    Every built-in basis (street and indoor), as ``densify``'s fit check considers every
    installed one; a tie keeps :data:`~pcainterp_stream.estimate.basis.BUILTIN_KINDS`'
    order (street first).

    Args:
        image_size: (height, width) of the maps' camera (px).
        focal_baseline: f*b of the maps' camera (px*m); <= 0: unknown.

    Raises:
        BasisError: no built-in basis is installed (the street basis's error).
    """
    fits: list[BuiltinFit] = []
    errors: list[BasisError] = []
    for kind in BUILTIN_KINDS:
        try:
            basis = builtin_basis(kind)
        except BasisError as err:
            errors.append(err)
            continue
        fits.append(
            BuiltinFit(
                kind,
                basis,
                camera_mismatch(basis, image_size, focal_baseline),
                camera_distance(basis, image_size, focal_baseline),
            )
        )
    if not fits:
        raise errors[0]
    return sorted(fits, key=lambda fit: fit.distance)


def basis_sketch(basis: Basis, n_prior: int) -> Sketch:
    """Return the incremental-SVD state of ``n_prior`` maps with the basis's statistics.

    Args:
        basis: the basis (its mean, components and eigenvalues).
        n_prior: the number of maps n_s it stands for, >= 2.

    Returns:
        The :class:`learning.Sketch`: mean m_s, factor U_s sqrt((n_s - 1) Lambda_s) and
        scatter trace (n_s - 1) * total_variance.
    """
    if n_prior < 2:
        raise ValueError(f"Expected `n_prior` >= 2 maps, got {n_prior}")
    # C_s = scatter / (n_s - 1) as learning normalises it, so scatter = (n_s - 1) C_s
    weights = np.sqrt((n_prior - 1) * basis.eigenvalues)
    factor = basis.pixel_major.astype(np.float64) * weights[None, :]
    return Sketch(
        mean=basis.mean_flat.astype(np.float64),
        factor=np.ascontiguousarray(factor, dtype=np.float32),
        squares=float((n_prior - 1) * basis.total_variance),
        n_maps=n_prior,
    )


def finetune_basis(
    basis: Basis,
    maps: Iterable[npt.ArrayLike],
    *,
    n_prior: int,
    n_components: int | None = None,
    variance: float | None = None,
    focal_baseline: float | None = None,
    min_disparity: float = 0.0,
    preprocessed: bool = False,
    batch_size: int = 64,
    oversampling: int = 20,
    progress: Callable[[int], None] | None = None,
    meta: dict[str, Any] | None = None,
) -> Basis:
    """Merge a basis, standing for ``n_prior`` maps, with more maps into a new basis.

    Args:
        basis: the basis to start from (e.g. :meth:`Basis.default`).
        maps: iterable of (H, W) float disparity maps (px) of one camera (any size: they
            are resampled onto the basis grid; NaN or < ``min_disparity`` invalid, so 0 is
            valid by default: see :func:`~.learning.preprocess_disparity`), consumed once.
            With ``preprocessed=True``, (gh, gw) float32 maps already on the basis grid
            and in the basis's disparity units.
        n_prior: n_s, how many maps the basis counts for, >= 2 (its ``n_train`` gives it
            the weight of its own training set).
        n_components: l of the result, at most; None: the basis's.
        variance: keep the fewest components reaching this variance ratio, or None.
        focal_baseline: f*b (px*m) of the maps' camera; their disparities are scaled by
            basis.focal_baseline / focal_baseline. None (or either 0): not scaled.
        min_disparity: smallest valid disparity of the maps (px).
        preprocessed: the maps are on the basis grid already.
        batch_size: maps merged per incremental-SVD step.
        oversampling: columns kept beyond l between batches.
        progress: called with the number of maps consumed so far, after each map.
        meta: extra entries for the result's ``meta``.

    Returns:
        The merged :class:`Basis`, for the basis's image size, grid and f*b; ``n_train``
        is n_s + n_r and ``meta["finetune"]`` records what was merged.

    Raises:
        ValueError: no maps, a map of the wrong shape or bad options.
        TypeError: a map of 16-bit integers (fixed point), boolean or complex.
    """
    l_out = basis.n_components if n_components is None else n_components
    if l_out < 1:
        raise ValueError(f"Expected `n_components` >= 1, got {l_out}")
    if variance is not None and not 0.0 < variance <= 1.0:
        raise ValueError(f"Expected `variance` in (0, 1], got {variance}")
    scale = disparity_scale(basis, focal_baseline)
    preprocessing = basis.meta.get("preprocessing", {})
    box_size = int(preprocessing.get("box_size", DEFAULT_BOX_SIZE))
    grid_size = basis.grid_size
    counted = [0]
    sizes: list[tuple[int, int]] = []

    def grid_maps() -> Iterator[npt.NDArray[np.float32]]:
        for index, raw in enumerate(maps):
            array = disparity_array(raw, f"maps[{index}]", np.float32)
            if array.ndim != 2 or (preprocessed and array.shape != grid_size):
                expected = grid_size if preprocessed else "(H, W)"
                raise ValueError(f"map {index} has shape {array.shape}, expected {expected}")
            if preprocessed:
                grid = np.ascontiguousarray(array)
            else:
                if not sizes:
                    sizes.append((int(array.shape[0]), int(array.shape[1])))
                # disparities in basis units; invalid (NaN, < min) stays invalid
                with np.errstate(invalid="ignore"):
                    valid = np.isfinite(array) & (array >= min_disparity)
                scaled = np.where(valid, array * np.float32(scale), np.nan).astype(np.float32)
                grid = preprocess_disparity(scaled, grid_size, box_size=box_size)
            counted[0] = index + 1
            yield grid.reshape(-1)
            if progress is not None:
                progress(index + 1)

    stream = grid_maps()
    first = next(stream, None)
    if first is None:
        raise ValueError("`maps` is empty; fine-tuning needs at least one disparity map")
    start = basis_sketch(basis, n_prior)
    fit = streaming_fit(
        itertools.chain([first], stream), l_out + oversampling, batch_size, start=start
    )
    return _finetuned(
        basis,
        fit,
        n_prior=n_prior,
        n_maps=counted[0],
        maps_image_size=sizes[0] if sizes else basis.image_size,
        focal_baseline=focal_baseline,
        n_components=l_out,
        variance=variance,
        used="finetune",
        min_disparity=min_disparity,
        preprocessed=preprocessed,
        batch_size=batch_size,
        oversampling=oversampling,
        meta=meta,
    )


def disparity_scale(basis: Basis, focal_baseline: float | None) -> float:
    """Return the factor taking a camera's disparities into the basis's: (f*b)_basis / f*b.

    Args:
        basis: the basis.
        focal_baseline: f*b of the maps' camera (px*m); None or 0 (or the basis's 0): 1.

    Raises:
        ValueError: ``focal_baseline`` is negative or not finite.
    """
    if focal_baseline is None:
        return 1.0
    if not (np.isfinite(focal_baseline) and focal_baseline >= 0):
        raise ValueError(f"Expected `focal_baseline` >= 0 (px*m), got {focal_baseline}")
    if focal_baseline > 0 and basis.focal_baseline > 0:
        return float(basis.focal_baseline / focal_baseline)
    return 1.0


def finetune_from_sketch(
    basis: Basis,
    sketch: Sketch,
    *,
    n_prior: int,
    maps_image_size: tuple[int, int],
    n_components: int | None = None,
    variance: float | None = None,
    focal_baseline: float | None = None,
    oversampling: int = 20,
    used: str = "finetune",
    meta: dict[str, Any] | None = None,
) -> Basis:
    """Merge a basis, standing for ``n_prior`` maps, with the sketch of more maps.

    What :func:`finetune_basis` does with a stream of maps, for maps whose statistics were
    gathered elsewhere (on a cluster): ``sketch`` holds them on the basis grid, in the
    basis's disparity units (scaled by :func:`disparity_scale`).

    Args:
        basis: the basis to start from.
        sketch: the maps' :class:`learning.Sketch` on the basis grid.
        n_prior: n_s, how many maps the basis counts for, >= 2.
        maps_image_size: (height, width) of the maps' camera (recorded).
        n_components: l of the result, at most; None: the basis's.
        variance: keep the fewest components reaching this variance ratio, or None.
        focal_baseline: f*b of the maps' camera (recorded).
        oversampling: columns kept beyond l in the merge.
        used: the learning method recorded.
        meta: extra entries for the result's ``meta``.

    Returns:
        The merged :class:`Basis`, as :func:`finetune_basis` returns it.
    """
    l_out = basis.n_components if n_components is None else n_components
    if l_out < 1:
        raise ValueError(f"Expected `n_components` >= 1, got {l_out}")
    if sketch.factor.shape[0] != basis.grid_size[0] * basis.grid_size[1]:
        raise ValueError(
            f"the sketch has {sketch.factor.shape[0]} grid pixels, the basis "
            f"{basis.grid_size[0] * basis.grid_size[1]}"
        )
    merged = merge_sketches(basis_sketch(basis, n_prior), sketch, l_out + oversampling)
    fit = fit_from_factor(merged.mean, merged.factor, merged.squares, merged.n_maps)
    return _finetuned(
        basis,
        fit,
        n_prior=n_prior,
        n_maps=sketch.n_maps,
        maps_image_size=maps_image_size,
        focal_baseline=focal_baseline,
        n_components=l_out,
        variance=variance,
        used=used,
        min_disparity=0.0,
        preprocessed=False,
        batch_size=None,
        oversampling=oversampling,
        meta=meta,
    )


def _finetuned(
    basis: Basis,
    fit: PcaFit,
    *,
    n_prior: int,
    n_maps: int,
    maps_image_size: tuple[int, int],
    focal_baseline: float | None,
    n_components: int,
    variance: float | None,
    used: str,
    min_disparity: float,
    preprocessed: bool,
    batch_size: int | None,
    oversampling: int,
    meta: dict[str, Any] | None,
) -> Basis:
    """Build the fine-tuned basis from the merged eigenpairs, recording what was merged."""
    preprocessing = basis.meta.get("preprocessing", {})
    grid_size = basis.grid_size
    merged: dict[str, Any] = {
        "finetune": {
            "prior_basis": {
                "fingerprint": basis.fingerprint,
                "n_train": basis.n_train,
                "n_components": basis.n_components,
                "explained_variance_ratio": basis.explained_variance_ratio,
                "source": basis.meta.get("source"),
            },
            "n_prior": n_prior,
            "n_maps": n_maps,
            "maps_image_size": list(maps_image_size),
            "maps_focal_baseline": focal_baseline,
            "disparity_scale": disparity_scale(basis, focal_baseline),
        }
    }
    if meta:
        merged.update(meta)
    return basis_from_fit(
        fit,
        grid_size=grid_size,
        image_size=basis.image_size,
        n_components=n_components,
        variance=variance,
        grid_scale=float(preprocessing.get("grid_scale", grid_size[1] / basis.image_size[1])),
        used=used,
        requested=used,
        focal_baseline=basis.focal_baseline,
        min_disparity=min_disparity,
        box_size=int(preprocessing.get("box_size", DEFAULT_BOX_SIZE)),
        preprocessed=preprocessed,
        batch_size=batch_size,
        oversampling=oversampling,
        meta=merged,
    )
