"""Stereo front end: Shi-Tomasi corners, SGBM disparity, and the disparity at the corners.

This is the paper's KITTI measurement setup (Ochs, Bradler & Mester 2017, section IV):
"good features to track" corners on the left image whose disparities are read from an
SGBM disparity map. Everything here is a pure function over arrays (no log I/O, no PCA):

* :func:`detect_corners` -- ``cv2.goodFeaturesToTrack`` (+ ``cv2.cornerSubPix``; from
  :mod:`.corners`, with :class:`GfttConfig` and :func:`lattice_points`);
* :func:`compute_disparity` -- ``cv2.StereoSGBM`` as float32 px, NaN where invalid;
* :func:`compute_right_disparity` -- the right view's map, for an explicit left-right check;
* :func:`lookup_disparities` -- sub-pixel disparity at the corners, with validity checks;
* :func:`lattice_points` and :func:`sparse_lookups` -- the corners' lookups plus those of a
  lattice in their gaps (the surfaces between textured spots), as ``densify`` measures;
* :class:`StereoFrontEnd` -- the whole front end for one stereo pair.

Corners like to sit on object outlines, exactly where a disparity map jumps and where SGBM
is least reliable (foreground fattening, occlusions). A lookup is therefore kept only when
the disparity map is valid and smooth around the corner, and, optionally, when the right
view's map agrees with it.

Defaults were chosen from measurements on real KITTI raw frames (1242x375, 2 cores); see
``docs/stages.md``, section "Stereo front end", and ``tools/bench_stereo.py``.

Threading: OpenCV releases the GIL inside SGBM, so a worker thread can compute frame t+1
while the main thread densifies frame t. A ``cv2.StereoSGBM`` object is not safe to share
between threads; the matcher cache here is per thread (and per configuration).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from functools import partial
from typing import Any, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.corners import GfttConfig, detect_corners, lattice_points
from pcainterp_stream.frontend.far import rematch_far
from pcainterp_stream.frontend.fill import fill_points
from pcainterp_stream.frontend.grey import is_blank, to_grey8, to_grey8_pair
from pcainterp_stream.frontend.refine import halved as _halved
from pcainterp_stream.frontend.refine import refined_match
from pcainterp_stream.frontend.sgbm_limits import (
    ImageTooNarrowError,
    needed_width,
)

__all__ = [
    "GfttConfig",
    "Lookup",
    "LookupConfig",
    "LookupMethod",
    "Measurements",
    "RejectionCounts",
    "SgbmConfig",
    "SgbmMode",
    "StereoFrontEnd",
    "compute_disparity",
    "compute_right_disparity",
    "compute_weak_disparity",
    "detect_corners",
    "lattice_points",
    "lookup_disparities",
    "sparse_lookups",
    "to_grey8",
    "to_grey8_pair",
]

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]

# ---------------------------------------------------------------------------------------
# SGBM
# ---------------------------------------------------------------------------------------


class SgbmMode(Enum):
    """The dynamic-programming variant of ``cv2.StereoSGBM``.

    ``SGBM`` aggregates 5 directions in one pass; ``SGBM_3WAY`` 3 directions, parallelised
    over image strips (fastest, and the default); ``HH`` the full 8-direction
    Hirschmuller algorithm (much more memory); ``HH4`` 4 directions.
    """

    SGBM = cv2.STEREO_SGBM_MODE_SGBM
    HH = cv2.STEREO_SGBM_MODE_HH
    SGBM_3WAY = cv2.STEREO_SGBM_MODE_SGBM_3WAY
    HH4 = cv2.STEREO_SGBM_MODE_HH4


@dataclass(frozen=True)
class SgbmConfig:
    """``cv2.StereoSGBM`` settings (see the OpenCV documentation of ``StereoSGBM_create``).

    The defaults are for KITTI size (1242x375, disparities up to ~100 px for objects at
    4 m) and were chosen from the measurements in ``docs/stages.md``: ``SGBM_3WAY``
    with 128 disparities and 5 px blocks takes ~55-65 ms per frame on 2 cores (~100 ms on
    one), 2-3x less than ``SGBM`` (~130-180 ms) and ``HH4`` (~200-400 ms), and its lookups
    at the corners are all within 1 px of ``SGBM`` mode's (mean difference 0.03 px).
    ``downscale=2`` takes ~15-25 ms; 98 % of its lookups are within 1 px of full
    resolution (mean difference 0.32 px), and the dense maps densified from them are as
    good: ``densify`` matches at half resolution by default (``ProcessorConfig``),
    while this default (full resolution) stays for ``learn`` and for ``evaluate``'s reference.

    Attributes:
        min_disparity: smallest disparity searched (px).
        num_disparities: number of disparities searched (px), a multiple of 16; pixels with
            x < min_disparity + num_disparities have no full search range and are mostly
            invalid.
        block_size: matched block size (odd, px).
        p1: penalty on disparity changes of 1 px between neighbours; ``None`` means
            8 * 1 * block_size**2 (one grey channel).
        p2: penalty on larger changes; ``None`` means 32 * 1 * block_size**2.
        disp12_max_diff: OpenCV's built-in left-right check tolerance (px, integer);
            negative disables it.
        uniqueness_ratio: margin (%) by which the best cost must beat the second best.
        speckle_window_size: largest connected region (px) of similar disparity that is
            removed as a speckle; 0 disables speckle filtering.
        speckle_range: largest disparity variation inside a connected region (px; OpenCV
            multiplies it by 16 internally).
        pre_filter_cap: clip value of the x-derivative prefilter.
        mode: the aggregation variant.
        downscale: 1 matches at full resolution; 2 matches at half resolution (INTER_AREA)
            with half the disparity range and upsamples the map (INTER_LINEAR, values x2),
            ~4x cheaper and coarser.
        full_width: also match the left band x < min_disparity + num_disparities: both
            images are padded on the left by that many px (edge pixels repeated) before
            matching and the padding is cut off again, so every pixel gets the whole search
            range. A band pixel whose match lies inside the right image is then found as
            anywhere else; one whose match would lie left of it (out of the right camera's
            view) can only match the padding: a disparity d > x is removed. Costs
            (W + band) / W of the matching time.
        near_at_half: match the far half of the range at full resolution, the whole range
            at half resolution, and take the latter's value where it lies in the near half
            (from :data:`NEAR_MARGIN` px below the far range's end): ~0.75x the time;
            measured for dense mode, not its default (docs/dense.md). ``downscale=1`` and
            at least 32 disparities only.
        refine_range: 0, or a positive multiple of 8 (px): match the whole range at half
            resolution, warp the right image by that map and match again at full
            resolution within +-``refine_range`` px of it (:mod:`.refine`); ``downscale=1``.
        by_camera: ``densify``'s default (``--stereo-downscale auto``): ``downscale`` is
            chosen for the log's camera at its first pair (:func:`.sgbm_resolution.by_camera`;
            at full resolution ``full_width`` too); a configuration never resolved matches
            at ``downscale``.
    """

    min_disparity: int = 0
    num_disparities: int = 128
    block_size: int = 5
    p1: int | None = None
    p2: int | None = None
    disp12_max_diff: int = 1
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    pre_filter_cap: int = 63
    mode: SgbmMode = SgbmMode.SGBM_3WAY
    downscale: int = 1
    full_width: bool = False
    near_at_half: bool = False
    refine_range: int = 0
    by_camera: bool = False

    def __post_init__(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(
                f"num_disparities must be a positive multiple of 16, got {self.num_disparities}"
            )
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 1, got {self.block_size}")
        if self.downscale not in (1, 2):
            raise ValueError(f"downscale must be 1 or 2, got {self.downscale}")
        if self.refine_range < 0 or self.refine_range % 8:
            raise ValueError(
                f"refine_range must be 0 or a positive multiple of 8, got {self.refine_range}"
            )
        if self.refine_range and self.near_at_half:
            raise ValueError("near_at_half and refine_range are alternatives; set one")

    @property
    def penalty_small(self) -> int:
        """Return P1, the resolved penalty for 1 px disparity changes."""
        return self.p1 if self.p1 is not None else 8 * self.block_size**2

    @property
    def penalty_large(self) -> int:
        """Return P2, the resolved penalty for larger disparity changes."""
        return self.p2 if self.p2 is not None else 32 * self.block_size**2

    @property
    def valid_min_x(self) -> int:
        """Return the first column (px) where the full disparity range can be searched."""
        return 0 if self.full_width else self.band

    @property
    def band(self) -> int:
        """Return the width (px) of the left band SGBM cannot search fully without padding."""
        return self.min_disparity + self.num_disparities

    def matched(self) -> SgbmConfig:
        """Return the configuration SGBM actually runs with at the matching resolution."""
        if self.downscale == 1:
            return self
        factor = self.downscale
        num = -(-self.num_disparities // (16 * factor)) * 16
        return SgbmConfig(
            min_disparity=self.min_disparity // factor,
            num_disparities=num,
            block_size=self.block_size,
            p1=self.p1,
            p2=self.p2,
            disp12_max_diff=self.disp12_max_diff,
            uniqueness_ratio=self.uniqueness_ratio,
            speckle_window_size=self.speckle_window_size // (factor * factor),
            speckle_range=self.speckle_range,
            pre_filter_cap=self.pre_filter_cap,
            mode=self.mode,
            downscale=1,
            full_width=self.full_width,
        )

    def split(self) -> tuple[SgbmConfig, SgbmConfig] | None:
        """Return the (far, whole-range) matchers of ``near_at_half``, None when not split."""
        far_count = self.num_disparities // 32 * 16
        if not self.near_at_half or self.downscale != 1 or far_count == 0:
            return None
        whole = replace(self, near_at_half=False)
        return replace(whole, num_disparities=far_count), replace(whole, downscale=2)


NEAR_MARGIN = 8
"""``SgbmConfig.near_at_half``: a half-resolution value this many px below the far range's
end or above is taken (nearer than the full-resolution matcher can see well)."""


_matchers = threading.local()


class _Checked:
    """``cv2.StereoSGBM`` for a configuration, refusing images too narrow for it."""

    def __init__(self, config: SgbmConfig) -> None:
        self.config = config

    def compute(self, left: UInt8Array, right: UInt8Array) -> npt.NDArray[np.int16]:
        needed = needed_width(self.config)
        if left.shape[1] < needed:
            raise ImageTooNarrowError(left.shape[1], needed, self.config.num_disparities)
        return np.asarray(_matcher(self.config).compute(left, right), np.int16)


def _matcher(config: SgbmConfig) -> cv2.StereoSGBM:
    """Return this thread's cached ``cv2.StereoSGBM`` for ``config`` (full resolution)."""
    cache: dict[SgbmConfig, cv2.StereoSGBM] | None = getattr(_matchers, "cache", None)
    if cache is None:
        cache = {}
        _matchers.cache = cache
    matcher = cache.get(config)
    if matcher is None:
        matcher = cv2.StereoSGBM.create(
            minDisparity=config.min_disparity,
            numDisparities=config.num_disparities,
            blockSize=config.block_size,
            P1=config.penalty_small,
            P2=config.penalty_large,
            disp12MaxDiff=config.disp12_max_diff,
            uniquenessRatio=config.uniqueness_ratio,
            speckleWindowSize=config.speckle_window_size,
            speckleRange=config.speckle_range,
            preFilterCap=config.pre_filter_cap,
            mode=config.mode.value,
        )
        cache[config] = matcher
    return matcher


def _flip(image: UInt8Array) -> UInt8Array:
    """Mirror an image left to right (contiguous)."""
    return np.asarray(cv2.flip(image, 1), np.uint8)


def _match(
    left: UInt8Array, right: UInt8Array, matched: SgbmConfig, full_width: bool
) -> FloatArray:
    """Run SGBM at the images' own resolution: float32 px, NaN where invalid.

    ``matched`` is the configuration at that resolution (:meth:`SgbmConfig.matched`);
    ``full_width`` pads the left band (a match into the padding, d > x, is removed).
    """
    pad = max(matched.band, 0) if full_width else 0
    if pad:
        left = np.asarray(cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE), np.uint8)
        right = np.asarray(cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE), np.uint8)
    fixed = _Checked(matched).compute(left, right)
    if pad:
        fixed = fixed[:, pad:]
    # SGBM returns 16 * disparity as int16; invalid pixels are (min_disparity - 1) * 16.
    disparity = fixed.astype(np.float32)
    disparity *= np.float32(1.0 / 16.0)
    disparity[fixed < matched.min_disparity * 16] = np.nan
    if pad:
        # a match left of the right image's first column is a match into the padding
        columns = np.arange(disparity.shape[1], dtype=np.float32)
        disparity[disparity > columns] = np.nan
    return disparity


def _upsampled(disparity: FloatArray, height: int, width: int) -> FloatArray:
    """Upsample a map to (height, width), values scaled by the width ratio (NaN spreads)."""
    # Pixel-centre aligned upsampling; a NaN spreads to every output it touches.
    scale = np.float32(width / disparity.shape[1])
    upsampled = cv2.resize(disparity, (width, height), interpolation=cv2.INTER_LINEAR)
    return np.asarray(upsampled, np.float32) * scale


def _sgbm_weak(
    left: UInt8Array, right: UInt8Array, config: SgbmConfig
) -> tuple[FloatArray, npt.NDArray[np.bool_] | None]:
    """:func:`_sgbm_grey` and the map's weak pixels (``refine_range`` only, else None)."""
    if config.refine_range and config.downscale == 1:
        return refined_match(left, right, config, _match, _Checked)
    return _sgbm_grey(left, right, config), None


def _sgbm_grey(left: UInt8Array, right: UInt8Array, config: SgbmConfig) -> FloatArray:
    """Run SGBM on an 8-bit pair, returning float32 px with NaN where invalid."""
    split = config.split()
    if split is not None:
        far_config, whole_config = split
        far = _sgbm_grey(left, right, far_config)
        whole = _sgbm_grey(left, right, whole_config)
        start = far_config.min_disparity + far_config.num_disparities - NEAR_MARGIN
        with np.errstate(invalid="ignore"):
            near = whole >= np.float32(start)
        far[near] = whole[near]
        return far
    if config.refine_range and config.downscale == 1:
        return refined_match(left, right, config, _match, _Checked).disparity
    if config.downscale == 1:
        return _match(left, right, config, config.full_width)
    coarse = _match(_halved(left), _halved(right), config.matched(), config.full_width)
    return _upsampled(coarse, *left.shape)


def compute_disparity(
    left: npt.NDArray[Any],
    right: npt.NDArray[Any],
    config: SgbmConfig = SgbmConfig(),  # frozen, so a shared default is safe
) -> FloatArray:
    """Compute the left view's SGBM disparity map.

    The matcher is created once per configuration and thread and reused. Images are
    converted with :func:`to_grey8_pair` (uint8 grey as is; RGB to grey; uint16 scaled by
    the pair's 99.9th percentile).

    Args:
        left: (H, W) uint8/uint16 grey or (H, W, 3) RGB rectified left image.
        right: rectified right image, same shape and dtype.
        config: matcher settings.

    Returns:
        (H, W) float32 disparity (px) of each left pixel; NaN where SGBM found none
        (occlusions, failed uniqueness or left-right checks, speckles, and, unless
        ``config.full_width``, most of the left band x < min_disparity + num_disparities).

    Raises:
        ValueError: if the images differ in shape or dtype or are not images.
    """
    grey_left, grey_right = to_grey8_pair(left, right)
    return _sgbm_grey(grey_left, grey_right, config)


def compute_weak_disparity(
    left: npt.NDArray[Any], right: npt.NDArray[Any], config: SgbmConfig
) -> tuple[FloatArray, npt.NDArray[np.bool_] | None]:
    """:func:`compute_disparity` and its weak pixels (``Measurements.weak``)."""
    grey_left, grey_right = to_grey8_pair(left, right)
    return _sgbm_weak(grey_left, grey_right, config)


def compute_right_disparity(
    left: npt.NDArray[Any],
    right: npt.NDArray[Any],
    config: SgbmConfig = SgbmConfig(),  # frozen, so a shared default is safe
) -> FloatArray:
    """Compute the right view's disparity map, for an explicit left-right check.

    SGBM only searches leftwards, so the right view's map is SGBM on the horizontally
    flipped, swapped pair, flipped back: right pixel (x_r, y) matches left pixel
    (x_r + d_r, y). It costs a second SGBM.

    Args:
        left: (H, W) uint8/uint16 grey or (H, W, 3) RGB rectified left image.
        right: rectified right image, same shape and dtype.
        config: matcher settings (as for :func:`compute_disparity`).

    Returns:
        (H, W) float32 disparity (px) of each right pixel, NaN where invalid (including
        the right band x >= W - min_disparity - num_disparities).
    """
    grey_left, grey_right = to_grey8_pair(left, right)
    flipped = _sgbm_grey(_flip(grey_right), _flip(grey_left), config)
    return np.ascontiguousarray(flipped[:, ::-1])


# ---------------------------------------------------------------------------------------
# Lookup
# ---------------------------------------------------------------------------------------


class LookupMethod(Enum):
    """How the disparity at a sub-pixel corner is read from the map."""

    BILINEAR = "bilinear"
    """Bilinear interpolation of the 2x2 pixel cell around the corner."""
    MEDIAN = "median"
    """Median of a small square window around the nearest pixel (robust, integer-ish)."""


@dataclass(frozen=True)
class LookupConfig:
    """Validity checks of :func:`lookup_disparities`.

    Attributes:
        method: bilinear (sub-pixel) or window median.
        max_gradient: largest |d difference| between 4-neighbouring pixels (px per px)
            allowed in the support patch; larger means a depth discontinuity is near.
        discontinuity_radius: the support patch is the sampled pixels (2x2 cell or median
            window) grown by this many px on each side; every pixel in it must be valid
            and smooth. A hole next to a valid sample is usually an occlusion at an object
            outline.
        median_window: side of the median window (odd px), for ``MEDIAN``.
        lr_max_diff: largest |left - right| disparity difference (px) of the explicit
            left-right check (used only when a right map is given).
    """

    method: LookupMethod = LookupMethod.BILINEAR
    max_gradient: float = 1.0
    discontinuity_radius: int = 1
    median_window: int = 3
    lr_max_diff: float = 1.0

    def __post_init__(self) -> None:
        if self.median_window < 1 or self.median_window % 2 == 0:
            raise ValueError(f"median_window must be odd and >= 1, got {self.median_window}")
        if self.discontinuity_radius < 0 or not self.max_gradient > 0.0:
            raise ValueError(
                f"discontinuity_radius ({self.discontinuity_radius}) must be >= 0 and "
                f"max_gradient ({self.max_gradient}) > 0"
            )


@dataclass(frozen=True)
class RejectionCounts(Mapping[str, int]):
    """How many corners a lookup kept and why it rejected the others.

    Each rejected corner is counted once, under the first failed check in this order:
    outside, invalid, discontinuity, inconsistent. ``corners == kept + outside + invalid +
    discontinuity + inconsistent``. Read a count as an attribute (``counts.kept``) or by
    name; ``dict(counts)`` gives a plain ``{name: count}`` dict (e.g. for
    ``DensifiedFrame.counts``).

    Attributes:
        corners: corners given.
        kept: lookups returned.
        outside: the support patch left the image.
        invalid: a sampled pixel has no disparity.
        discontinuity: a hole or a gradient above ``max_gradient`` in the support patch.
        inconsistent: the right view's disparity disagrees by more than ``lr_max_diff``.
        far_zeros: kept lookups the front end's map (at ``downscale``'s resolution, half or
            full) read as exactly 0 (not a rejection: :mod:`.far`).
        far_rematched: of those, how many the far re-match (at full resolution, range
            centred on 0) read again, 0 included (a value it finds at or below 0 is 0).
    """

    corners: int
    kept: int
    outside: int
    invalid: int
    discontinuity: int
    inconsistent: int
    far_zeros: int = 0
    far_rematched: int = 0

    def __getitem__(self, name: str) -> int:
        if name not in _COUNT_NAMES:
            raise KeyError(name)
        value: int = getattr(self, name)
        return value

    def __iter__(self) -> Iterator[str]:
        return iter(_COUNT_NAMES)

    def __len__(self) -> int:
        return len(_COUNT_NAMES)


_COUNT_NAMES = tuple(name.name for name in fields(RejectionCounts))


class Lookup(NamedTuple):
    """Disparities read at corners.

    Attributes:
        pixels: (m, 2) float32 (x, y) image px of the kept corners.
        disparities: (m,) float32 disparity at each kept corner (px).
        indices: (m,) int64 index of each kept corner in the input ``corners``.
        counts: kept and rejected counts by reason.
    """

    pixels: FloatArray
    disparities: FloatArray
    indices: npt.NDArray[np.int64]
    counts: RejectionCounts


def _patches(
    image: FloatArray, top: npt.NDArray[np.int64], left: npt.NDArray[np.int64], size: int
) -> FloatArray:
    """Gather (m, size, size) patches at top-left corners (top, left), clipped to the image."""
    offsets = np.arange(size)  # (clipped: a map smaller than a patch has no patch inside)
    rows = np.minimum(top[:, None] + offsets, image.shape[0] - 1)[:, :, None]
    cols = np.minimum(left[:, None] + offsets, image.shape[1] - 1)[:, None, :]
    return np.asarray(image[rows, cols], np.float32)


def _bilinear(image: FloatArray, x: FloatArray, y: FloatArray) -> FloatArray:
    """Sample ``image`` bilinearly at (x, y) px; NaN outside or when a neighbour is NaN."""
    height, width = image.shape
    inside = np.isfinite(x) & np.isfinite(y)
    inside &= (x >= 0) & (y >= 0) & (x <= width - 1) & (y <= height - 1)
    x_safe = np.where(inside, x, 0).astype(np.float32)
    y_safe = np.where(inside, y, 0).astype(np.float32)
    x0 = np.minimum(np.floor(x_safe).astype(np.int64), width - 2)
    y0 = np.minimum(np.floor(y_safe).astype(np.int64), height - 2)
    cell = _patches(image, y0, x0, 2)
    fx = x_safe - x0
    fy = y_safe - y0
    top = cell[:, 0, 0] * (1 - fx) + cell[:, 0, 1] * fx
    bottom = cell[:, 1, 0] * (1 - fx) + cell[:, 1, 1] * fx
    values = np.asarray(top * (1 - fy) + bottom * fy, np.float32)
    values[~inside] = np.nan
    return values


def lookup_disparities(
    disparity: FloatArray,
    corners: FloatArray,
    *,
    right_disparity: FloatArray | None = None,
    method: LookupMethod = LookupMethod.BILINEAR,
    max_gradient: float = 1.0,
    discontinuity_radius: int = 1,
    median_window: int = 3,
    lr_max_diff: float = 1.0,
) -> Lookup:
    """Read the disparity at (sub-pixel) corners and keep only trustworthy values.

    A corner's value is the bilinear interpolation of the 2x2 pixel cell containing it
    (``BILINEAR``), or the median of a ``median_window`` square around its nearest pixel
    (``MEDIAN``). It is kept only when (checks in this order):

    1. the support patch (the sampled pixels grown by ``discontinuity_radius``) is inside
       the image;
    2. every sampled pixel is valid (not NaN);
    3. every pixel of the support patch is valid and no two 4-neighbours in it differ by
       more than ``max_gradient`` px: a corner near a depth discontinuity, where SGBM
       is unreliable, is rejected;
    4. with ``right_disparity``: the right view's map at (x - d, y) (bilinear) does not
       disagree with d by more than ``lr_max_diff`` px (where the right map has no value
       there is no evidence against d, and the lookup is kept).

    Args:
        disparity: (H, W) float32 left disparity map (px), NaN where invalid.
        corners: (k, 2) float32 (x, y) corner positions (px); (0, 2) is allowed.
        right_disparity: optional (H, W) float32 right disparity map (px) from
            :func:`compute_right_disparity`, for the explicit left-right check.
        method: bilinear (sub-pixel) or window median.
        max_gradient: largest neighbour difference (px per px) in the support patch.
        discontinuity_radius: growth of the support patch around the samples (px).
        median_window: odd side of the median window (px), for ``MEDIAN``.
        lr_max_diff: tolerance of the left-right check (px).

    Returns:
        The kept pixels (m, 2) float32, their disparities (m,) float32 (px), their indices
        into ``corners`` and the counts of rejections by reason.

    Raises:
        ValueError: if ``disparity`` is not 2-D, ``corners`` not (k, 2), or
            ``right_disparity`` differs in shape from ``disparity``.
    """
    if disparity.ndim != 2:
        raise ValueError(f"disparity must be a 2-D (H, W) map, got shape {disparity.shape}")
    if corners.ndim != 2 or corners.shape[1] != 2:
        raise ValueError(f"corners must have shape (k, 2) of (x, y), got {corners.shape}")
    if right_disparity is not None and right_disparity.shape != disparity.shape:
        raise ValueError(
            f"right_disparity has shape {right_disparity.shape} but disparity has "
            f"{disparity.shape}; compute both from the same pair"
        )
    if median_window < 1 or median_window % 2 == 0:
        raise ValueError(f"median_window must be odd and >= 1, got {median_window}")
    disparity = np.asarray(disparity, np.float32)
    height, width = disparity.shape
    count = corners.shape[0]
    x = corners[:, 0].astype(np.float32)
    y = corners[:, 1].astype(np.float32)
    finite = np.isfinite(x) & np.isfinite(y)
    x_safe = np.where(finite, x, 0)
    y_safe = np.where(finite, y, 0)

    if method is LookupMethod.BILINEAR:
        sample_x0 = np.floor(x_safe).astype(np.int64)
        sample_y0 = np.floor(y_safe).astype(np.int64)
        sample_size = 2
    else:
        half = median_window // 2
        sample_x0 = np.floor(x_safe + 0.5).astype(np.int64) - half
        sample_y0 = np.floor(y_safe + 0.5).astype(np.int64) - half
        sample_size = median_window
    radius = discontinuity_radius
    size = sample_size + 2 * radius
    top = sample_y0 - radius
    left = sample_x0 - radius
    inside = finite & (top >= 0) & (left >= 0) & (top + size <= height) & (left + size <= width)

    patch = _patches(disparity, np.where(inside, top, 0), np.where(inside, left, 0), size)
    samples = patch[:, radius : radius + sample_size, radius : radius + sample_size]
    sampled_valid = ~np.isnan(samples).any(axis=(1, 2))
    # Any hole or jump between 4-neighbours of the patch (NaN differences compare False,
    # so holes are tested separately).
    jump_x = np.abs(np.diff(patch, axis=2)) > max_gradient
    jump_y = np.abs(np.diff(patch, axis=1)) > max_gradient
    smooth = ~(np.isnan(patch).any(axis=(1, 2)) | jump_x.any(axis=(1, 2)) | jump_y.any(axis=(1, 2)))

    if method is LookupMethod.BILINEAR:
        fx = x_safe - sample_x0
        fy = y_safe - sample_y0
        upper = samples[:, 0, 0] * (1 - fx) + samples[:, 0, 1] * fx
        lower = samples[:, 1, 0] * (1 - fx) + samples[:, 1, 1] * fx
        values = (upper * (1 - fy) + lower * fy).astype(np.float32)
    else:
        values = np.median(samples.reshape(count, -1), axis=1).astype(np.float32)

    is_outside = ~inside
    is_invalid = inside & ~sampled_valid
    is_discontinuity = inside & sampled_valid & ~smooth
    passed = inside & sampled_valid & smooth
    consistent = np.ones(count, bool)
    if right_disparity is not None:
        right_values = _bilinear(
            np.asarray(right_disparity, np.float32), x_safe - np.where(passed, values, 0), y_safe
        )
        # Only a disagreement rejects: where the right map has no value (its own right
        # band x_r >= W - min_disparity - num_disparities, occlusions) there is no evidence
        # against the left value, which already passed SGBM's disp12MaxDiff check.
        consistent = ~(np.abs(right_values - values) > lr_max_diff)
    is_inconsistent = passed & ~consistent
    kept = passed & consistent

    indices = np.flatnonzero(kept).astype(np.int64)
    counts = RejectionCounts(
        corners=count,
        kept=int(indices.size),
        outside=int(is_outside.sum()),
        invalid=int(is_invalid.sum()),
        discontinuity=int(is_discontinuity.sum()),
        inconsistent=int(is_inconsistent.sum()),
    )
    pixels = np.ascontiguousarray(np.stack([x[indices], y[indices]], axis=1), np.float32)
    return Lookup(pixels.reshape(-1, 2), values[indices], indices, counts)


_DEFAULT_GFTT = GfttConfig()  # frozen, so a shared default is safe


def sparse_lookups(
    left_grey: UInt8Array,
    disparity: FloatArray,
    gftt: GfttConfig = _DEFAULT_GFTT,
    lookup: LookupConfig = LookupConfig(),  # frozen, so a shared default is safe
    *,
    min_x: int = 0,
    right_disparity: FloatArray | None = None,
    prior_std: FloatArray | None = None,
) -> Lookup:
    """The sparse measurements of a pair as ``densify`` makes them: corners, then the fill.

    The corners of :func:`detect_corners` are looked up (:func:`lookup_disparities`); with
    ``gftt.fill_spacing`` > 0 the points of :func:`lattice_points` in their gaps (farther
    than half a side from every kept corner lookup, with a 7x7 grey-level std of at least
    ``gftt.fill_min_contrast``) are looked up with the same checks and appended; with a
    ``gftt.fill_placement`` other than ``"lattice"``, as many chosen by :mod:`.fill`.

    Args:
        left_grey: (H, W) uint8 grey left image.
        disparity: (H, W) float32 left disparity map (px), NaN where invalid.
        gftt: corner and fill settings.
        lookup: the lookup checks.
        min_x: first column SGBM can match (px); nothing left of it is looked up.
        right_disparity: optional right map for the explicit left-right check.
        prior_std: (gh, gw) prior disparity std (px), required by ``"prior_std"`` fills.

    Returns:
        The kept pixels (corners first), disparities, indices into the corners followed by
        the fill points looked up, and the counts of both together (``corners`` counts
        every point looked up; of a greedy fill only the chosen ones).
    """
    corners = detect_corners(left_grey, gftt, min_x=min_x)
    found = _lookup(disparity, corners, lookup, right_disparity)
    if gftt.fill_spacing <= 0.0:
        return found
    height, width = left_grey.shape
    border = gftt.border
    area = (max(border, min_x), border, width - border, height - border)
    look_up = partial(_lookup, disparity, config=lookup, right_disparity=right_disparity)
    points = fill_points(left_grey, disparity, gftt, area, found.pixels, look_up, prior_std)
    extra = look_up(points)
    a, b = found.counts, extra.counts
    counts = RejectionCounts(*(getattr(a, n) + getattr(b, n) for n in _COUNT_NAMES))
    return Lookup(
        np.concatenate([found.pixels, extra.pixels]),
        np.concatenate([found.disparities, extra.disparities]),
        np.concatenate([found.indices, extra.indices + a.corners]),
        counts,
    )


def _lookup(
    disparity: FloatArray,
    points: FloatArray,
    config: LookupConfig,
    right_disparity: FloatArray | None,
) -> Lookup:
    return lookup_disparities(
        disparity,
        points,
        right_disparity=right_disparity,
        method=config.method,
        max_gradient=config.max_gradient,
        discontinuity_radius=config.discontinuity_radius,
        median_window=config.median_window,
        lr_max_diff=config.lr_max_diff,
    )


# ---------------------------------------------------------------------------------------
# Front end
# ---------------------------------------------------------------------------------------


class Measurements(NamedTuple):
    """Sparse disparity measurements of one stereo pair.

    Attributes:
        pixels: (k, 2) float32 (x, y) left-image px of the measurements.
        disparities: (k,) float32 disparities (px).
        disparity_map: (H, W) float32 SGBM left disparity map (px), NaN where invalid.
        counts: corners found, lookups kept and rejected by reason.
        weak: (H, W) bool, valid pixels whose value is less sure than a matched pixel's
            (``SgbmConfig.refine_range`` only: :class:`.refine.Refined`), else None.
    """

    pixels: FloatArray
    disparities: FloatArray
    disparity_map: FloatArray
    counts: RejectionCounts
    weak: npt.NDArray[np.bool_] | None = None


@dataclass(frozen=True)
class StereoFrontEnd:
    """GFTT corners + SGBM disparity + checked lookup, for one stereo pair at a time.

    Safe to call from several threads at once (each thread gets its own SGBM matcher).

    Attributes:
        gftt: corner detector settings.
        sgbm: matcher settings.
        lookup: lookup checks.
        lr_check: also compute the right view's map (a second SGBM, doubling the cost)
            and reject lookups whose two disparities disagree. Off by default: on KITTI it
            removed 0.1 lookups per frame beyond SGBM's own ``disp12_max_diff=1`` check,
            and none on synthetic scenes with ground truth.
        prior_std: the prior's std map of ``"prior_std"`` fills (:func:`sparse_lookups`).

    Example:
        >>> front_end = StereoFrontEnd()
        >>> result = front_end.measure(left, right)  # doctest: +SKIP
        >>> result.pixels.shape, result.counts.kept  # doctest: +SKIP
    """

    gftt: GfttConfig = field(default_factory=GfttConfig)
    sgbm: SgbmConfig = field(default_factory=SgbmConfig)
    lookup: LookupConfig = field(default_factory=LookupConfig)
    lr_check: bool = False
    prior_std: FloatArray | None = field(default=None, compare=False, repr=False)

    def measure(self, left: npt.NDArray[Any], right: npt.NDArray[Any]) -> Measurements:
        """Measure sparse disparities of one rectified stereo pair.

        Args:
            left: (H, W) uint8/uint16 grey or (H, W, 3) RGB rectified left image.
            right: rectified right image, same shape and dtype.

        A pair with a blank image (:func:`.grey.is_blank`: a dropped-out or capped camera)
        has no measurement and an all-NaN map: SGBM would resolve a uniform right image's
        ties to disparity 0 and every lookup would read "far".

        Returns:
            The kept measurements, the full disparity map and the counts.

        Raises:
            ValueError: if the images differ in shape or dtype or are not images.
        """
        grey_left, grey_right = to_grey8_pair(left, right)
        if is_blank(grey_left) or is_blank(grey_right):  # SGBM's ties there: 0, "far"
            nothing = np.zeros((0, 2), np.float32)
            return Measurements(
                nothing,
                np.zeros(0, np.float32),
                np.full(grey_left.shape, np.nan, np.float32),
                RejectionCounts(0, 0, 0, 0, 0, 0),
            )
        disparity_map, weak = _sgbm_weak(grey_left, grey_right, self.sgbm)
        right_map = None
        if self.lr_check:
            flipped = _sgbm_grey(_flip(grey_right), _flip(grey_left), self.sgbm)
            right_map = np.ascontiguousarray(flipped[:, ::-1])
        found = sparse_lookups(
            grey_left,
            disparity_map,
            self.gftt,
            self.lookup,
            min_x=self.sgbm.valid_min_x,
            right_disparity=right_map,
            prior_std=self.prior_std,
        )
        if not self.sgbm.refine_range:  # a far surface's exact 0: matched again
            far = rematch_far(
                grey_left,
                grey_right,
                disparity_map,
                found,
                self.sgbm,
                match=_match,
                look_up=partial(_lookup, config=self.lookup, right_disparity=None),
            )
            counts = replace(found.counts, far_zeros=far.zeros, far_rematched=far.rematched)
            found, disparity_map = far.lookup._replace(counts=counts), far.disparity_map
        return Measurements(found.pixels, found.disparities, disparity_map, found.counts, weak)
