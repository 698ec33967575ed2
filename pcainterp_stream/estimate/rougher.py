"""The fit check's tuning: the built-in indoor basis with a rougher local kernel.

When the fit check chooses the built-in indoor basis over the street one and it still fits
the log badly (at least ``FITS_BELOW`` times linear interpolation's held-out error), the same
basis is scored with :data:`~.adapt.ROUGH_KERNEL` (Laplace 64 px, 40 px^2) instead of its own
(Gaussian 32 px, 2.4 px^2) on the same held-out SGBM pixels (:func:`try_rougher`), and taken
when it errs less, its std scale refitted on the warm-up's SGBM maps (:func:`sgbm_std_scale`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate import fitting
from pcainterp_stream.estimate.adapt import (
    FIT_FRAMES,
    ROUGH_KERNEL,
    UNCHECKED_COLUMNS,
    FitCheck,
    Measured,
)
from pcainterp_stream.estimate.basis import Basis, builtin_kind
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.estimate.wording import figures

PER_FRAME = True
"""The refitted std scale multiplies each frame's covariance scale too (``scale_by_innovation``),
as the indoor basis's own fitted scale does (``innovation_std_scale``)."""

LIKELIHOOD = True
"""The std scale is the larger of the one that puts 95.4 % of the errors against SGBM inside
+-2 std (:func:`fitting.fit_std_scale`) and the one that maximises their Gaussian likelihood,
sqrt(mean((e / std)^2)). The rougher kernel's errors are heavy-tailed: the 4-5 % outside the
band were many std out, and the band-fitted scale alone (x0.17-0.23 on rooms) made NLL
against the truth 0.5-0.7 nats worse than the indoor kernel's (review58b R7); the
likelihood's alone narrowed EuRoC's band to 94.3 %. Measured on 7 rooms, EuRoC and MyntEye
(docs/bases.md, "The indoor basis with the street basis's kernel")."""


def sgbm_std_scale(
    basis: Basis,
    frames: Sequence[Measured],
    options: dict[str, Any],
    *,
    image_size: tuple[int, int],
    focal_baseline: float,
    robust: str,
    per_frame: bool = PER_FRAME,
    likelihood: bool = LIKELIHOOD,
) -> float:
    """Return the std scale of ``basis`` with ``options`` fitted against the frames' SGBM maps.

    The frames (at most :data:`~.adapt.FIT_FRAMES`, evenly spaced) are densified at their
    camera with the posterior std unscaled (``"exact-coarse"``; with ``per_frame``, scaled by
    each frame's covariance scale as ``densify`` will), and the scale fitted on their errors
    against SGBM: :func:`fitting.fit_std_scale`'s (95.4 % inside +-2 std), with
    ``likelihood`` at least the Gaussian maximum-likelihood one (:data:`LIKELIHOOD`). A
    built-in basis learned none of the frames: the errors are those of frames to come.
    """
    used = list(frames[:: max(1, math.ceil(len(frames) / FIT_FRAMES))])
    unscaled = {**options, "std_scale": 1.0, "scale_by_innovation": per_frame}
    results = densify_batch(
        basis,
        [frame.pixels for frame in used],
        [frame.disparities for frame in used],
        image_size=image_size,
        focal_baseline=focal_baseline,
        robust=robust,
        uncertainty="exact-coarse",
        with_depth=False,
        **unscaled,
    )
    estimates, stds, references = [], [], []
    for result, frame in zip(results, used, strict=True):
        if result.disparity_std is not None:
            estimates.append(result.disparity)
            stds.append(result.disparity_std)
            references.append(frame.reference)
    if not estimates:
        return 1.0
    return fitted_std_scale(estimates, stds, references, likelihood=likelihood)


def fitted_std_scale(
    estimates: Sequence[npt.NDArray[Any]],
    stds: Sequence[npt.NDArray[Any]],
    references: Sequence[npt.NDArray[Any]],
    *,
    likelihood: bool = LIKELIHOOD,
) -> float:
    """Return the std scale of the rougher kernel's maps against their SGBM references.

    :func:`fitting.fit_std_scale`'s (95.4 % of the errors inside +-2 std), with
    ``likelihood`` at least the Gaussian maximum-likelihood one, sqrt(mean((e / std)^2))
    (:data:`LIKELIHOOD`). The one rule for this kernel: ``densify``'s fit check
    (:func:`sgbm_std_scale`) and ``learn``'s held-out choice (``pipeline/held_out.py``).
    """
    band = fitting.fit_std_scale(estimates, stds, references)
    if not likelihood:
        return band
    ratios = []
    for estimate, std, reference in zip(estimates, stds, references, strict=True):
        valid = np.isfinite(reference) & np.isfinite(estimate) & (std > 0)
        ratios.append((estimate[valid] - reference[valid]) / std[valid])
    joined = np.concatenate(ratios)
    if joined.size == 0:
        return band
    return max(band, float(np.sqrt(np.mean(np.square(joined, dtype=np.float64)))))


def rough_kernel_words(rough: LocalPrior = ROUGH_KERNEL) -> str:
    """Return "the street basis's local kernel (laplace, 64 px, 40 px^2)": both lines' name."""
    return (
        f"the street basis's local kernel ({rough.kernel}, {rough.length_scale:g} px, "
        f"{rough.variance:g} px^2)"
    )


def band_left_out(first_column: int) -> str | None:
    """Return why the rougher kernel is not tried, or None: the held-out pixels' columns.

    When they leave SGBM's unmatched left band out (:data:`~.adapt.UNCHECKED_COLUMNS`), the
    kernel would extrapolate there unchecked: ``densify``'s fit check and ``learn`` keep the
    indoor kernel then.
    """
    if first_column < UNCHECKED_COLUMNS:
        return None
    return (
        f"not tried: the held-out pixels cover columns >= {first_column} only, and "
        "left of them (SGBM's unmatched band), unchecked, it erred up to 2.2x more than "
        "the basis's own kernel on synthetic rooms"
    )


def compared(check: FitCheck, against: FitCheck, taken: bool, own: str = "its own kernel") -> str:
    """Return "taken: 0.27 px against 0.28 with its own kernel on the same held-out SGBM pixels"."""
    mine, theirs = figures(check.prior, against.prior)
    verdict = "taken" if taken else "not taken"
    return f"{verdict}: {mine} px against {theirs} with {own} on the same held-out SGBM pixels"


class Rougher(NamedTuple):
    """The built-in indoor basis with :data:`~.adapt.ROUGH_KERNEL`, scored (:func:`try_rougher`).

    Attributes:
        line: the ``prior:`` line saying whether it was taken, with the held-out figures.
        check: its held-out figure.
        tuned: when taken, the estimate's settings that differ from the indoor basis's own
            (the kernel, the std scale refitted); None when not taken.
    """

    line: str
    check: FitCheck
    tuned: dict[str, object] | None


def try_rougher(
    street: Basis,
    indoor: tuple[Basis, str, dict[str, Any]],
    score: Callable[[dict[str, Any]], FitCheck],
    against: FitCheck,
    warmup: tuple[Sequence[Measured], tuple[int, int], float],
    *,
    robust: str,
    calibrate: bool,
) -> Rougher | None:
    """Score the built-in indoor basis chosen with :data:`~.adapt.ROUGH_KERNEL`.

    The fit check chose the built-in indoor basis over the basis given (``street``: only
    whether it is the built-in street basis matters; the kernel tried is the constant
    :data:`~.adapt.ROUGH_KERNEL`) and it scored ``against`` (at least ``FITS_BELOW`` times
    linear interpolation); ``indoor`` is (basis, name, options).
    The indoor kernel (Gaussian 32 px, 2.4 px^2) is too smooth and weak to bend the basis to
    its own points where the basis misfits: with Laplace 64 px, 40 px^2 (the street basis's
    values, as numbers in the indoor basis's px) on the same basis the EuRoC machine hall went
    2.49 -> 2.32 px, the MyntEye fisheye pair 1.96 -> 1.75, synthetic rooms 3-16 % less error
    against the truth (bughunt10B Q2). ``score`` checks the options on the warm-up's
    held-out SGBM pixels; the candidate is taken when its error is lower, its std scale then
    refitted on the warm-up's SGBM maps (``calibrate``; :func:`sgbm_std_scale`): the indoor
    kernel's was 2-5x too wide for it. None when there is no candidate: the street basis not
    the one given, an indoor basis without a local kernel (``--prior paper``), or one whose
    kernel is already :data:`~.adapt.ROUGH_KERNEL`. The street
    basis is never given another kernel: on KITTI 07 the variants of it the check preferred
    lost against the LiDAR truth. Not tried (a line says so) when the held-out pixels leave
    SGBM's unmatched left band out (:data:`~.adapt.UNCHECKED_COLUMNS`): with no point there,
    this kernel extrapolates unchecked (synthetic rooms at 376x240, a 129 px band: taken on 3
    of 5, it erred 2.25x, 1.42x, 0.93x the indoor kernel's error there, its std holding
    21-92 %).
    """
    basis, name, options = indoor
    if builtin_kind(street) != "street" or builtin_kind(basis) != "indoor":
        return None
    local, rough = options.get("local_prior"), ROUGH_KERNEL
    if not isinstance(local, LocalPrior) or rough == local:
        return None
    line = f"prior: {name} with {rough_kernel_words(rough)}"
    left_out = band_left_out(against.first_column)
    if left_out is not None:
        return Rougher(f"{line}: {left_out}", against, None)
    check = score({**options, "local_prior": rough})
    line += f" {check.describe()}"
    if not (check.frames and check.prior < against.prior):
        return Rougher(f"{line}; {compared(check, against, False)}", check, None)
    tuned: dict[str, object] = {"local_prior": rough}
    why = compared(check, against, True)
    if calibrate:
        frames, size, fb = warmup
        scale = sgbm_std_scale(
            basis, frames, {**options, **tuned}, image_size=size, focal_baseline=fb, robust=robust
        )
        tuned |= {"std_scale": scale, "scale_by_innovation": PER_FRAME}
        why += f"; its std scale x{scale:.2f}, refitted on the warm-up's SGBM maps"
    return Rougher(f"{line}; {why}", check, tuned)
