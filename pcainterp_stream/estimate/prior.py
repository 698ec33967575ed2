"""Prior and noise models beyond the paper's (docs/estimator.md, "Beyond the paper").

A hybrid local prior, robust weights, noise by evidence and a temporal coefficient prior.

The paper's prior is d ~ N(m, B Lambda B^T): only what the l kept components can express.
The **hybrid prior** adds a stationary kernel for what the basis misses,

    d ~ N(m, B P B^T + C_local),   C_local(x, x') = v * k_x(x - x') * k_y(y - y')

with a separable kernel in basis-image px (``laplace``: exp(-|dx| / ell), a product of
Matern-1/2 kernels, or ``gaussian``: exp(-dx^2 / (2 ell^2))). Separable means the local
part of the dense map, sum_j alpha_j c(x, p_j), is one (H, k) @ (k, W) product, and its
covariance with the variance grid one outer product per measurement: never a loop over
pixels. Everything stays closed-form in measurement space (K is k x k):

    K = B~ P B~^T + C_pp + R,           R = diag(sigma^2 / w_j)
    alpha = K^-1 (z~ - B~ mu)
    y_hat = mu + P B~^T alpha,          Sigma_y = P - P B~^T K^-1 B~ P
    d_hat(x) = m(x) + b(x)^T y_hat + c(x, P) alpha
    var(x) = b(x)^T P b(x) + v - || L^-1 (B~ P b(x) + c(P, x)) ||^2,   L L^T = K

The static prior is mu = 0, P = Lambda; the temporal prior takes mu and the diagonal of P
from the previous frame's posterior plus process noise q * Lambda. Robust weights w_j
come from iteratively reweighted least squares on the leave-one-out standardised residuals
t_j = alpha_j / sqrt([K^-1]_jj) (the residual of z_j against the prediction from all other
points, over its predictive std; N(0, 1) under the model). The noise level sigma can be
the maximiser of the marginal likelihood log N(z~; B~ mu, K) (the evidence) per frame.

Pure maths over arrays: nothing here knows about logs.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class Kernel(StrEnum):
    """Separable stationary kernel of the local prior."""

    LAPLACE = "laplace"
    """exp(-|dx| / ell) * exp(-|dy| / ell): rough, keeps edges local (Matern-1/2 product)."""
    GAUSSIAN = "gaussian"
    """exp(-(dx^2 + dy^2) / (2 ell^2)): smooth."""


class Robust(StrEnum):
    """Loss on the measurement residuals (IRLS weights)."""

    NONE = "none"
    """Gaussian noise, every measurement weight 1 (the paper)."""
    HUBER = "huber"
    """w = min(1, c / |t|), c = 1.345."""
    CAUCHY = "cauchy"
    """w = 1 / (1 + (t / c)^2), c = 2.385."""


class RobustStart(StrEnum):
    """Where the IRLS weights of a frame with an outlier (:data:`ROBUST_FROM`) come from."""

    PLAIN = "plain"
    """The unweighted solve's residuals t_j (SGBM lookups, whose matcher bounds their error)."""
    TRIMMED = "trimmed"
    """A second solve without the suspects (|t_j| >= ``robust_from``), each suspect's t_j
    against it; a point still at :data:`REJECT_FROM` or beyond is left out (weight
    :data:`REJECTED_WEIGHT`). Another system's points (a feature stream) can be off by
    hundreds of px (a triangulation failure): from the plain start one such point pulls the
    fit so far that its neighbours' t_j grow past the loss's scale and the good points are
    down-weighted instead, and with the fitted noise (sigma 0.1 px) a Cauchy weight of
    1e-3 still trusts it to a few px (docs/estimator.md, "Robust")."""


ROBUST_SCALES = {Robust.HUBER: 1.345, Robust.CAUCHY: 2.385}
"""Tuning constants in units of the standardised residual (95 % Gaussian efficiency)."""

ROBUST_FROM = 4.0
"""The largest leave-one-out standardised residual from which a frame is reweighted."""

REJECT_FROM = 16.0
"""The |t_j| against the trimmed solve (:attr:`RobustStart.TRIMMED`) from which a point is
left out. On 20 synthetic frames of 300 true points each the largest was 6.2; one point per
frame moved to 0.5 m on its ray had 41-150 (all left out: RMSE 9.57 -> 1.57 px, 1.57
without it), at 2 m (~97 px) 9.6-36 (RMSE 3.98 -> 2.62 px; 1.97 at 10-12, 1.57 at 8). Real
clouds have more real points far from the prior: with each KITTI pair's SGBM cloud as the
stream, 8 rejected enough of them to move the basis choice on a near-tie (3 annotated
frames, LiDAR truth: 1.565 -> 1.726 px; 16: 1.578) and to raise the odometry clip's mean
error against its cloud (street basis 9.35 -> 11.75 %; 16: 9.11 %)."""

MAD_TO_STD = 1.4826
"""The std of a normal over its median absolute deviation: the trimmed start's suspects are
beyond ``robust_from`` times this times the median |t_j| when that exceeds 1 (one point at
a disparity of 19,000 px put most of 300 good points' t_j beyond 4)."""

REJECTED_WEIGHT = 1e-12
"""The weight of a point left out: its noise std 1e6 sigma, no pull on the fit."""

DOWNWEIGHTED_BELOW = 0.5
"""A measurement counts as down-weighted when its final IRLS weight is below this."""

GROUP_SIZE = 16
"""The fewest down-weighted measurements that agree with each other to be kept as a group."""

GROUP_RADIUS = 96.0
"""The largest distance (basis image px) between two measurements of one group."""

GROUP_AGREE = 0.25
"""The largest difference of two group members' innovations, as a share of the larger."""

GROUP_BEYOND = 10.0
"""A group is kept only when its median innovation is this many times the frame's median
absolute innovation (a surface far beyond the prior, not a modest offset)."""

GROUP_SPREAD = 0.05
"""A group's member is left out when its innovation is off the group's median by more than
3 robust std of the group's innovations, at least this share of the median and at most
:data:`GROUP_AGREE` of it."""


_CLAMP_BELOW = -40.0
"""Kernel exponents are clamped at this (see :meth:`LocalPrior.axis`)."""

SAMPLES_PER_LENGTH = {Kernel.LAPLACE: 16.0, Kernel.GAUSSIAN: 4.0}
"""Samples per length scale for which :meth:`LocalPrior.smooth_at` holds."""

SPACING_TOLERANCE = 0.01
"""Relative slack of :meth:`LocalPrior.smooth_at`'s test.

A basis grid's spacing is the image width over the grid's (1241 / 310 = 4.003 px at KITTI
size): without slack the built-in 64 px kernel missed 16 samples by 0.07 % and its local
part was computed on a 2 px grid, 4x the products of the basis grid, for the same maps
(mean |disparity error| equal to 0.001 px on real truth, synthetic truth and both real
clips; 1.2-1.7 ms less estimate CPU per KITTI frame; docs/speed_levers.md)."""


@dataclass(frozen=True)
class LocalPrior:
    """The stationary local covariance of the hybrid prior.

    Attributes:
        variance: v, prior variance of the local part (px^2, basis disparity units).
        length_scale: ell, in px of the basis image.
        kernel: the kernel shape.
        cell_weight: w of the edge-aware prior, v k(x - x') [w + (1 - w) 1{same cell}],
            cells following the front end's disparity map (:mod:`cells`); 1 (the default)
            is the stationary kernel alone, and so is any w without a map.
    """

    variance: float
    length_scale: float
    kernel: Kernel = Kernel.LAPLACE
    cell_weight: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.variance) and self.variance >= 0):
            raise ValueError(f"Expected local prior `variance` >= 0 (px^2), got {self.variance}")
        if not (math.isfinite(self.length_scale) and self.length_scale > 0):
            raise ValueError(
                f"Expected local prior `length_scale` > 0 (px), got {self.length_scale}"
            )
        if not (math.isfinite(self.cell_weight) and 0 <= self.cell_weight <= 1):
            raise ValueError(
                f"Expected local prior `cell_weight` in [0, 1], got {self.cell_weight}"
            )
        object.__setattr__(self, "kernel", Kernel(self.kernel))

    @property
    def edge_aware(self) -> bool:
        """True when the kernel has a cell term (``cell_weight`` < 1)."""
        return self.cell_weight < 1.0

    def axis(
        self, positions: FloatArray, at: FloatArray, dtype: type[np.floating[Any]] = np.float64
    ) -> npt.NDArray[Any]:
        """Return the 1-D kernel factor k(at - position), shape (k, n).

        Args:
            positions: (k,) float64, measurement coordinates along one axis (basis px).
            at: (n,) float64, evaluation coordinates along the same axis (basis px).
            dtype: float64 for the k x k system; float32 (2x faster exp) for the dense
                products with the image, which run in float32 anyway.
        """
        gap = (at[None, :] - positions[:, None]).astype(dtype, copy=False)
        return self.factor(gap)

    def factor(self, gap: npt.NDArray[Any]) -> npt.NDArray[Any]:
        """Return the 1-D kernel factor k(gap) elementwise, computed in ``gap`` (overwritten).

        ``gap``: a float32 or float64 array of coordinate differences (basis px) the caller
        owns; the result is that array.
        """
        dtype = gap.dtype.type
        if self.kernel is Kernel.LAPLACE:
            np.abs(gap, out=gap)
            gap *= dtype(-1.0 / self.length_scale)
        else:
            gap *= dtype(1.0 / self.length_scale)
            gap *= gap
            gap *= dtype(-0.5)
        # exponents clamped at -40: a factor never falls below e^-40 (4e-18 of the peak).
        # Left alone, far factors and their products with alpha land in float32's
        # subnormal range, where multiplies and the GEMM with them run many times slower
        np.maximum(gap, dtype(_CLAMP_BELOW), out=gap)
        values: npt.NDArray[Any] = np.exp(gap, out=gap)
        return values

    def pointwise(self, dx: npt.NDArray[Any], dy: npt.NDArray[Any]) -> npt.NDArray[np.float32]:
        """Return k(dx) k(dy) elementwise (float32), the product of two :meth:`axis` factors."""
        scale = np.float32(1.0 / self.length_scale)
        x = np.asarray(dx, np.float32) * scale
        y = np.asarray(dy, np.float32) * scale
        if self.kernel is Kernel.LAPLACE:
            exponent = -(np.abs(x) + np.abs(y))
        else:
            exponent = np.float32(-0.5) * (x * x + y * y)
        # each factor's clamp at -40, as in axis(): the product's at -80
        np.maximum(exponent, np.float32(2.0 * _CLAMP_BELOW), out=exponent)
        values: npt.NDArray[np.float32] = np.exp(exponent, out=exponent)
        return values

    def support(self) -> float:
        """Return the distance (px) beyond which a 1-D factor is at its clamp e^-40.

        Past it the factor is 4e-18 of its peak; a sum over measurements may leave such
        terms out (:func:`solve._local_mean` does, for short kernels).
        """
        if self.kernel is Kernel.LAPLACE:
            return -_CLAMP_BELOW * self.length_scale
        return math.sqrt(-2.0 * _CLAMP_BELOW) * self.length_scale

    def smooth_at(self, spacing: float) -> bool:
        """Return whether samples ``spacing`` px apart, interpolated bilinearly, follow it.

        True when ell spans :data:`SAMPLES_PER_LENGTH` samples: 16 for the Laplace kernel,
        whose cusp at each measurement j the interpolation rounds off by at most
        ~spacing / ell of its height v |alpha_j| (6 %; less where a sample falls near the
        cusp; on the KITTI and synthetic test logs mean Delta_2D moved by <= 0.003 px), 4 for
        the smooth Gaussian. The dense map computes the local part at the coarsest such
        spacing (:meth:`sample_spacing`): on the basis grid together with the basis part
        (1/16 of the products at the default grid scale), or on a grid 2x coarser than the
        image, resampled.
        """
        wanted = SAMPLES_PER_LENGTH[self.kernel] * spacing
        return self.length_scale >= wanted * (1.0 - SPACING_TOLERANCE)

    def sample_spacing(self, coarsest: float) -> float:
        """Return the largest of coarsest, coarsest / 2, ... (down to 1 px) it is smooth at.

        1 when it is not smooth even at 1 px (a very short kernel: full resolution).
        """
        spacing = coarsest
        while spacing > 1.0 and not self.smooth_at(spacing):
            spacing /= 2.0
        return max(spacing, 1.0)

    def matrix(
        self,
        positions: FloatArray,
        point_cells: npt.NDArray[np.int64] | None = None,
        *,
        pairs: tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]] | None = None,
    ) -> FloatArray:
        """Return C_pp (k, k) float64 between measurement positions (x, y) basis px.

        With ``point_cells`` (k,) (the measurements' cells, :mod:`cells`) and
        ``cell_weight`` w < 1, entries between different cells are scaled by w. ``pairs``:
        the (i, j) of :func:`same_cell_pairs` when the caller has them (any order).

        The kernel factors are evaluated in float32 (relative error ~1e-7 of v, far below
        the noise sigma^2 >= 0.01 px^2 it is added to): numpy's float64 exp is ~10x slower
        here (5.5 against 0.5 ms at k = 362, measured).
        """
        fx = self.axis(positions[:, 0], positions[:, 0], np.float32)
        fy = self.axis(positions[:, 1], positions[:, 1], np.float32)
        fx *= fy
        matrix: FloatArray = fx.astype(np.float64)
        if point_cells is None or not self.edge_aware:
            matrix *= self.variance
            return matrix
        # w everywhere, then v k itself back at the pairs within a cell (about k of them)
        first, second = same_cell_pairs(point_cells) if pairs is None else pairs
        kept = matrix[first, second]
        matrix *= self.variance * self.cell_weight
        matrix[first, second] = kept * self.variance
        return matrix

    def to_meta(self) -> dict[str, Any]:
        """Return the JSON form stored in a basis's ``meta["prior"]``."""
        meta: dict[str, Any] = {
            "variance": self.variance,
            "length_scale": self.length_scale,
            "kernel": self.kernel.value,
        }
        if self.edge_aware:
            meta["cell_weight"] = self.cell_weight
        return meta

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> LocalPrior:
        """Build from the JSON form of :meth:`to_meta`."""
        return cls(
            variance=float(meta["variance"]),
            length_scale=float(meta["length_scale"]),
            kernel=Kernel(str(meta.get("kernel", Kernel.LAPLACE.value))),
            cell_weight=float(meta.get("cell_weight", 1.0)),
        )


def same_cell_pairs(
    point_cells: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Return (i, j) of every ordered pair of measurements in one cell, (i, i) included."""
    order = np.argsort(point_cells, kind="stable")
    ordered = point_cells[order]
    start = np.searchsorted(ordered, ordered, side="left")
    size = np.searchsorted(ordered, ordered, side="right") - start
    first = np.repeat(np.arange(ordered.size), size)
    offset = np.arange(first.size) - np.repeat(np.cumsum(size) - size, size)
    second = np.repeat(start, size) + offset
    return order[first], order[second]


@dataclass
class TemporalPrior:
    """State of the temporal coefficient prior of a stream (an accumulator).

    Frame t's prior is N(y_hat_{t-1}, diag(kappa_{t-1}^2) + q Lambda): the previous
    posterior's mean and marginal variances, with process noise q Lambda. The correlations
    between coefficients are not carried over (a diagonal prior keeps the per-frame cost at
    the static prior's: the full l x l covariance would cost an extra l^2 s_v product per
    frame for the variance); given that prior, the posterior and its variance are exact.
    The static prior comes back when the normalised innovation squared
    (z~ - B~ mu)^T K^-1 (z~ - B~ mu) / k exceeds ``reset_threshold`` times that of the last
    static solve (at least 1): the scene changed. Relative, because on real logs the
    static model's own value is often well above its nominal mean of 1. A frame whose
    measurements are bit for bit the previous frame's (a driver sending its last pair again)
    is no new evidence: it gets the previous frame's prior again (:meth:`repeats`), not the
    previous posterior, so its std does not shrink while the error stays.

    Attributes:
        process_noise: q, process noise as a fraction of the prior eigenvalues.
        reset_threshold: largest normalised innovation squared accepted (1 is its mean).
        mean: (l,) float64 posterior mean of the last frame, None after a reset.
        variance: (l,) float64 posterior marginal variances of the last frame.
        frames: frames seen; resets: times the static prior was taken back.
        key: the camera the state belongs to (a change resets it).
        static_innovation: normalised innovation squared of the last static solve.
    """

    process_noise: float = 0.1
    reset_threshold: float = 3.0
    mean: FloatArray | None = None
    variance: FloatArray | None = None
    frames: int = 0
    resets: int = 0
    key: Any = field(default=None, repr=False)
    static_innovation: float = 1.0
    # the last frame's measurements (a digest) and the state before its update
    _digest: bytes | None = field(default=None, repr=False)
    _before: tuple[FloatArray | None, FloatArray | None] = field(default=(None, None), repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.process_noise) and self.process_noise > 0):
            raise ValueError(f"Expected `process_noise` > 0, got {self.process_noise}")
        if not (math.isfinite(self.reset_threshold) and self.reset_threshold > 0):
            raise ValueError(f"Expected `reset_threshold` > 0, got {self.reset_threshold}")

    def predict(self, eigenvalues: FloatArray) -> tuple[FloatArray, FloatArray] | None:
        """Return the prior (mu, diagonal of P) for the next frame, or None (static)."""
        if self.mean is None or self.variance is None:
            return None
        if self.mean.shape != eigenvalues.shape:
            return None
        return self.mean, self.variance + self.process_noise * eigenvalues

    def update(self, mean: FloatArray, variance: FloatArray) -> None:
        """Keep a frame's posterior mean and marginal variances as the state."""
        self._before = (self.mean, self.variance)
        self.mean = mean
        self.variance = variance
        self.frames += 1

    def repeats(self, *measurements: npt.NDArray[Any]) -> bool:
        """Return whether a frame's measurements are the previous frame's, bit for bit.

        If so, the state goes back to what it was before the previous frame's update: that
        frame's prior is predicted again, and the repeated measurements count once.

        Args:
            measurements: the frame's arrays (positions, values), in a fixed order.

        A frame without measurements is never a repeat: frames with nothing measured in a
        row each predict one step further, so the std widens across the gap.
        """
        if not measurements or measurements[0].size == 0:
            self._digest = None
            return False
        digest = hashlib.blake2b(digest_size=16)
        for array in measurements:
            digest.update(str(array.shape).encode())
            digest.update(np.ascontiguousarray(array).tobytes())
        previous, self._digest = self._digest, digest.digest()
        if previous != self._digest:
            return False
        self.mean, self.variance = self._before
        return True

    def reset(self) -> None:
        """Forget the state (scene change, camera change, a gap in the stream)."""
        self.mean = None
        self.variance = None
        self._digest = None
        self._before = (None, None)

    def accepts(self, normalised_innovation: float) -> bool:
        """Return whether a temporal solve's innovation passes the scene-change test."""
        limit = self.reset_threshold * max(1.0, self.static_innovation)
        return normalised_innovation <= limit


@dataclass(frozen=True)
class Model:
    """Everything of the estimate beyond the basis itself; the default is the paper's model.

    Attributes:
        sigma: measurement noise std (px of the basis's camera: the measurements are
            mapped to it by the f*b ratio), or None to fit it per frame by evidence.
        local: the local prior of the hybrid model, or None (the paper's prior).
        robust: the IRLS loss.
        robust_iterations: reweightings after the first (unweighted) solve. One is the
            default: on the synthetic and KITTI splits 2 or 4 changed mean Delta_2D by
            less than 0.03 px and cost a k x k factorisation each (docs/options.md).
        robust_from: the first reweighting runs only when some measurement's leave-one-out
            standardised residual reaches this (in its predictive std); otherwise the
            unweighted solve stands, and the factorisation a reweighting costs is saved.
            0: always reweight; inf: never. The default 4 (p ~ 6e-5 per point under the
            model) left the error within 0.1 % on the synthetic drives and real KITTI
            frames (docs/sharper_sparse_2.md, "Reweighting only when a point is an outlier").
        robust_start: where the first weights come from (:class:`RobustStart`).
    """

    sigma: float | None = 2.0
    local: LocalPrior | None = None
    robust: Robust = Robust.NONE
    robust_iterations: int = 1
    robust_from: float = ROBUST_FROM
    robust_start: RobustStart = RobustStart.PLAIN

    def __post_init__(self) -> None:
        if self.sigma is not None and not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"Expected `sigma` > 0 (px) or None (evidence), got {self.sigma}")
        object.__setattr__(self, "robust", Robust(self.robust))
        object.__setattr__(self, "robust_start", RobustStart(self.robust_start))
        if self.robust_iterations < 1:
            raise ValueError(f"Expected `robust_iterations` >= 1, got {self.robust_iterations}")
        if not self.robust_from >= 0:  # inf: never reweight
            raise ValueError(f"Expected `robust_from` >= 0, got {self.robust_from}")

    @property
    def is_paper(self) -> bool:
        """True when this is the paper's model (fixed sigma, no local part, no weights)."""
        return self.sigma is not None and self.local is None and self.robust is Robust.NONE


COVARIANCE_SCALE_PSEUDO = 4.0
"""Pseudo-measurements at scale 1 in :func:`covariance_scale` (few points stay near 1)."""


def covariance_scale(normalised_innovation: float, k: int) -> float:
    """Return the frame's covariance scale a fitted from its own measurements.

    Scaling the whole model covariance (prior and noise) by a, z~ ~ N(B~ mu, a K), leaves
    the MAP estimate unchanged and multiplies the posterior variance by a. Its maximum
    likelihood value is the normalised innovation squared z~^T K^-1 z~ / k; with
    :data:`COVARIANCE_SCALE_PSEUDO` extra measurements at a = 1, a frame with few points
    stays close to the model's own scale:

        a = (k * nis + n0) / (k + n0)

    On real logs the measurements of a scene the training data did not cover disagree with
    the prior more (a > 1), and so do the pixels between them: the std widens with it.

    Args:
        normalised_innovation: z~^T K^-1 z~ / k of the frame (0 when k = 0).
        k: the number of measurements.
    """
    if not (math.isfinite(normalised_innovation) and normalised_innovation >= 0):
        return 1.0
    return (k * normalised_innovation + COVARIANCE_SCALE_PSEUDO) / (k + COVARIANCE_SCALE_PSEUDO)


SIGMA_SEARCH = np.geomspace(0.1, 20.0, 160)
"""Candidate noise stds (px) of the evidence search, log-spaced (1.3 % apart)."""


def evidence_sigma(signal: FloatArray, innovation: FloatArray) -> float:
    """Return the noise std maximising the evidence log N(innovation; 0, signal + s^2 I).

    One eigendecomposition of the signal covariance makes every candidate O(k):
    log|K| = sum log(e_i + s^2), v^T K^-1 v = sum (q_i^T v)^2 / (e_i + s^2).

    Args:
        signal: (k, k) float64, B~ P B~^T + C_pp (without noise).
        innovation: (k,) float64, z~ - B~ mu.

    Returns:
        The best of :data:`SIGMA_SEARCH`, refined by a parabola in log s (px).
    """
    if innovation.size == 0:
        return float("nan")
    eigenvalues, vectors = np.linalg.eigh(signal)
    eigenvalues = np.maximum(eigenvalues, 0.0)
    projected = (vectors.T @ innovation) ** 2
    total = eigenvalues[None, :] + SIGMA_SEARCH[:, None] ** 2
    objective = -0.5 * (projected[None, :] / total + np.log(total)).sum(axis=1)
    best = int(np.argmax(objective))
    log_sigma = np.log(SIGMA_SEARCH)
    if 0 < best < SIGMA_SEARCH.size - 1:
        # parabola through the three best points, in log sigma
        y0, y1, y2 = objective[best - 1 : best + 2]
        denominator = y0 - 2.0 * y1 + y2
        if denominator < 0:
            shift = 0.5 * (y0 - y2) / denominator
            step = log_sigma[best + 1] - log_sigma[best]
            return float(np.exp(log_sigma[best] + shift * step))
    return float(SIGMA_SEARCH[best])


SCALE_SEARCH = np.geomspace(1.0 / 64.0, 4096.0, 49)
"""Candidate covariance scales of :func:`evidence_noise` (x1.41 apart)."""


def evidence_noise(
    signal: FloatArray, innovation: FloatArray, extra_variance: FloatArray | None = None
) -> tuple[float, float]:
    """Return (sigma, a) maximising the evidence log N(innovation; 0, a signal + s^2 I + E).

    :func:`evidence_sigma` fits the noise alone. When the prior does not fit the frame
    (another camera or kind of scene: measurements far outside the range the basis was
    learned on), the innovation is far larger than the signal covariance says, and the only
    way the noise-only evidence can explain it is a huge sigma: the estimate then ignores
    its measurements and returns the prior mean (3-4x worse than nearest-neighbour
    interpolation on an indoor log with the street basis). Fitting the scale a of the prior
    too lets the evidence say "the prior is too narrow" instead of "the points are noise".

    The MAP estimate depends on the prior only through the ratio of noise to signal, so the
    caller solves with the unit prior and the noise (s^2 + E) / a; the posterior variance of
    that solve is 1/a of the scaled model's (the per-frame covariance scale of
    :func:`covariance_scale` recovers it, its normalised innovation being ~a).

    Args:
        signal: (k, k) float64, B~ P B~^T + C_pp (without noise).
        innovation: (k,) float64, z~ - B~ mu.
        extra_variance: (k,) known extra noise variance per measurement (carried points);
            the fit uses the measurements without any (None: all).

    Returns:
        (s, a): the noise std (px) and the covariance scale, the best pair of
        :data:`SIGMA_SEARCH` x :data:`SCALE_SEARCH`; (nan, 1) without measurements.
    """
    if innovation.size == 0:
        return float("nan"), 1.0
    if extra_variance is not None:
        # fitted on the measurements without extra noise (this frame's own): the carried
        # ones' known noise breaks the common eigenbasis that makes the search cheap
        own = extra_variance <= 0
        if own.sum() >= 3:
            signal, innovation = signal[np.ix_(own, own)], innovation[own]
        else:  # all carried: their mean extra noise as a common floor
            signal = signal + np.diag(np.full(innovation.size, float(extra_variance.mean())))
    eigenvalues, vectors = np.linalg.eigh(signal)
    eigenvalues = np.maximum(eigenvalues, 0.0)
    projected = (vectors.T @ innovation) ** 2
    best = (-math.inf, float(SIGMA_SEARCH[0]), 1.0)
    for scale in SCALE_SEARCH:
        total = scale * eigenvalues[None, :] + SIGMA_SEARCH[:, None] ** 2
        objective = -0.5 * (projected[None, :] / total + np.log(total)).sum(axis=1)
        index = int(np.argmax(objective))
        if objective[index] > best[0]:
            best = (float(objective[index]), float(SIGMA_SEARCH[index]), float(scale))
    return best[1], best[2]


def robust_weights(standardised: FloatArray, robust: Robust) -> FloatArray:
    """Return IRLS weights (k,) float64 in (0, 1] for standardised residuals."""
    if robust is Robust.NONE:
        return np.ones_like(standardised)
    scale = ROBUST_SCALES[robust]
    magnitude = np.abs(standardised)
    if robust is Robust.HUBER:
        return np.minimum(1.0, scale / np.maximum(magnitude, 1e-12))
    return 1.0 / (1.0 + (magnitude / scale) ** 2)
