"""Measurements beyond the matcher's range from a cheap quarter-resolution match.

Sparse mode matches at half resolution with 64 disparities: 128 px at full resolution. A
surface nearer than that has no valid lookup; SGBM leaves holes there or, on ~40 % of its
pixels (synthetic drives), aliased values far below the truth. :func:`near_points` runs SGBM
once more at quarter resolution (64 disparities = 256 px at full resolution, ~1/4 of the
half-resolution match's cost) and returns points only where the half-resolution map cannot
measure: grid points whose quarter-resolution value is near or beyond the range's end
(>= range - ``margin``), smooth, well supported, and not already matched by the
half-resolution map. It also flags the half-resolution lookups the quarter map contradicts
there (a value well below a confident quarter value beyond the range), for dropping.

Every quarter value it uses is checked against the right view's quarter map (a second
quarter match, on the mirrored pair): where the right view, at the pixel the value matches,
disagrees by more than ``NearConfig.lr_max_diff`` quarter px, the value is not used. Left of
a near object lies a strip of background the right camera does not see; a matcher lends it
the object's disparity. Points placed there were 50-110 px too high and raised the error of
the background around them by 11-16 % at 5-20 m on a synthetic drive; the check removes 2 %
of the added points, these among them (measured in docs/sharper_sparse_2.md).

The candidate grid's side grows with the image as the fill lattice's does
(:func:`.fill.scaled_spacing`), and the points kept on a frame are capped at
:data:`MAX_NEAR_POINTS` (the lattice's count on a 1920 x 1080 pair) by laying the grid
again with a wider side: a near wall over a whole 1920 x 1080 image would otherwise add
~4,400 points (3840 x 2160: ~19,000) to a solve cubic in its points.

A cheap trigger (:func:`wants_near`) skips the extra match on frames whose half-resolution
map has (almost) no values near the range's end. The processor adds these points, with
``NearConfig.noise`` extra noise, when ``ProcessorConfig.near`` is set (``densify
--near-reach``); measured in docs/sharper_sparse_2.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.fill import scaled_spacing
from pcainterp_stream.frontend.stereo import (
    SgbmConfig,
    _bilinear,
    compute_disparity,
    compute_right_disparity,
    lookup_disparities,
    to_grey8_pair,
)

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]

__all__ = [
    "MAX_NEAR_POINTS",
    "NearConfig",
    "NearPoints",
    "extend_near",
    "lookups_only",
    "near_points",
    "quarter_disparity",
    "quarter_images",
    "wants_near",
]

MAX_NEAR_POINTS = 1250
"""Most points :func:`near_points` adds on a frame: the fill lattice's count on
:data:`.fill.FILL_REFERENCE_AREA` at its 40 px side. Above it the grid is laid again,
its side widened by the square root of the excess (an even, coarser grid over the whole
image, not one side cut off), until the kept points fit. Never reached on a KITTI-size
image (its grid has ~880 candidates in all), so nothing changes there. Measured on a
textured wall at 180 px disparity (docs/sharper_sparse_2.md, "The near reach's cost")."""


@dataclass(frozen=True)
class NearConfig:
    """Options of the quarter-resolution measurements beyond the range.

    Attributes:
        match_range: the main matcher's largest disparity (px, full resolution).
        num_disparities: disparities of the quarter-resolution match (its px).
        margin: a quarter value from ``match_range - margin`` up is a candidate (px).
        agree: a candidate whose half-resolution value is within this many px is already
            measured there and skipped (px).
        spacing: side of the candidate grid (full-resolution px) on a grid area up to
            :data:`.fill.FILL_REFERENCE_AREA`; grown beyond it as :func:`.fill.scaled_spacing`
            grows the fill lattice's.
        min_support: share of valid quarter px required in the 5 x 5 (quarter px) window.
        max_gradient: the smoothness check of the quarter lookup (quarter px per px).
        radius: the quarter lookup's support patch grows this many quarter px around it.
        drop_below: half-resolution lookups this many px below a confident quarter value
            beyond the range are flagged (px); 0: none.
        trigger_share: the frame is matched only when at least this share of the
            half-resolution map's valid pixels (sampled every 4th) is >= ``trigger_at`` x
            the range; 0: always.
        trigger_at: see ``trigger_share``.
        border: points closer than this to an image edge are not made (full px).
        noise: extra noise std of the added points (px, in quadrature with sigma).
        lr_max_diff: a quarter value is kept only where the right view's quarter map, at
            the pixel it matches, agrees within this many quarter px (a second quarter
            match); 0: no check.
    """

    match_range: float = 128.0
    num_disparities: int = 64
    margin: float = 8.0
    agree: float = 3.0
    spacing: float = 20.0
    min_support: float = 0.8
    max_gradient: float = 1.0
    radius: int = 1
    drop_below: float = 8.0
    trigger_share: float = 0.003
    trigger_at: float = 0.875
    border: int = 8
    noise: float = 1.0
    lr_max_diff: float = 2.0

    def __post_init__(self) -> None:
        # the added points are told from the front end's own by their extra noise
        # (lookups_only): a point added without any would pass for a lookup
        if not self.noise > 0.0:
            raise ValueError(f"NearConfig.noise must be > 0 px, got {self.noise}")


class NearPoints:
    """Points of one frame from the quarter match.

    Attributes:
        pixels: (m, 2) float32 (x, y) full-resolution px.
        disparities: (m,) float32 full-resolution px.
        contradicted: (k,) bool over the given half-resolution lookups: flagged to drop.
        matched: whether the quarter match ran (the trigger fired).
    """

    def __init__(
        self,
        pixels: FloatArray,
        disparities: FloatArray,
        contradicted: npt.NDArray[np.bool_],
        matched: bool,
    ) -> None:
        self.pixels = pixels
        self.disparities = disparities
        self.contradicted = contradicted
        self.matched = matched


def wants_near(half_map: FloatArray, config: NearConfig) -> bool:
    """Return whether a frame's half-resolution map has enough values near the range's end."""
    if config.trigger_share <= 0.0:
        return True
    sampled = half_map[::4, ::4]
    with np.errstate(invalid="ignore"):
        high = np.count_nonzero(sampled >= np.float32(config.trigger_at * config.match_range))
    valid = np.count_nonzero(np.isfinite(sampled))
    return bool(valid > 0 and high >= config.trigger_share * valid)


def _quarter_config(num_disparities: int) -> SgbmConfig:
    base = SgbmConfig()
    return SgbmConfig(
        num_disparities=num_disparities,
        speckle_window_size=base.speckle_window_size // 16,
    )


def quarter_images(left: UInt8Array, right: UInt8Array) -> tuple[UInt8Array, UInt8Array]:
    """The pair at quarter resolution (halved twice, INTER_AREA).

    Halving twice costs ~0.3 ms per KITTI image, one x4 INTER_AREA ~1.1 ms (OpenCV's fast
    path is for x2); the front end's own half images could be reused.
    """
    from pcainterp_stream.frontend.refine import halved

    return halved(halved(left)), halved(halved(right))


def quarter_disparity(
    small_left: UInt8Array,
    small_right: UInt8Array,
    num_disparities: int,
    *,
    right_view: bool = False,
) -> FloatArray:
    """SGBM on a quarter-resolution pair: its own px and values, NaN where invalid.

    With ``right_view``, the right view's map instead (:func:`compute_right_disparity`:
    right pixel x matches left pixel x + d), over the whole width: its own band (the right
    one, where a match would reach past the left image's right edge) padded and matched
    too, so a value near the right edge is checked as well as any other.
    """
    config = _quarter_config(num_disparities)
    if right_view:
        return compute_right_disparity(small_left, small_right, replace(config, full_width=True))
    return compute_disparity(small_left, small_right, config)


def _support(quarter: FloatArray) -> FloatArray:
    valid = np.isfinite(quarter).astype(np.float32)
    return np.asarray(cv2.blur(valid, (5, 5), borderType=cv2.BORDER_CONSTANT), np.float32)


def near_points(
    left: UInt8Array,
    right: UInt8Array,
    half_map: FloatArray,
    pixels: FloatArray,
    disparities: FloatArray,
    config: NearConfig = NearConfig(),  # frozen, so a shared default is safe
    *,
    max_points: int = MAX_NEAR_POINTS,
) -> NearPoints:
    """Measure beyond the half-resolution matcher's range where it cannot.

    Args:
        left: (H, W) uint8 grey left image.
        right: (H, W) uint8 grey right image.
        half_map: (H, W) the front end's (half-resolution, upsampled) map, NaN where invalid.
        pixels: (k, 2) the front end's lookups (x, y) px.
        disparities: (k,) their values (px).
        config: the options.
        max_points: most points added (:data:`MAX_NEAR_POINTS`); 0: no cap.

    Returns:
        The new points (full-resolution px and values) and the lookups to drop.
    """
    count = pixels.shape[0]
    none = NearPoints(
        np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros(count, bool), False
    )
    if not wants_near(half_map, config):
        return none
    pair = quarter_images(left, right)
    quarter = quarter_disparity(*pair, config.num_disparities)
    height, width = left.shape
    scale = np.float32(width / quarter.shape[1])  # full px per quarter px (~4)
    scale_y = np.float32(height / quarter.shape[0])
    start = np.float32(config.match_range - config.margin)
    support = _support(quarter)
    highest = cv2.dilate(np.nan_to_num(quarter, nan=0.0), np.ones((3, 3), np.uint8))

    def to_quarter(points: FloatArray) -> FloatArray:
        """Full-resolution (x, y) px as quarter-resolution px (pixel centres aligned)."""
        small = np.empty_like(points)
        small[:, 0] = (points[:, 0] + 0.5) / scale - 0.5
        small[:, 1] = (points[:, 1] + 0.5) / scale_y - 0.5
        return small

    def at_quarter(points: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        """Checked quarter values (full px) at full-resolution points; NaN where rejected."""
        small = to_quarter(points)
        rows = np.clip(np.rint(small[:, 1]).astype(np.int64), 0, quarter.shape[0] - 1)
        cols = np.clip(np.rint(small[:, 0]).astype(np.int64), 0, quarter.shape[1] - 1)
        # only where a value >= start is within a px (a bilinear value is at most its cell's)
        chosen = np.flatnonzero(highest[rows, cols] >= start / scale - np.float32(1e-3))
        found = lookup_disparities(
            quarter,
            small[chosen],
            max_gradient=config.max_gradient,
            discontinuity_radius=config.radius,
        )
        values = np.full(points.shape[0], np.nan, np.float32)
        values[chosen[found.indices]] = found.disparities * scale
        supported = support[rows, cols] >= config.min_support
        with np.errstate(invalid="ignore"):
            confident = supported & (values >= start)
        return values, confident

    right_views: list[FloatArray] = []  # matched once, when a value first needs the check

    def right_agrees(points: FloatArray, values: FloatArray) -> npt.NDArray[np.bool_]:
        """Whether the right view's quarter map, where each value matches, does not disagree.

        Where it has no value there (its own band, occlusions) nothing speaks against it.
        """
        if config.lr_max_diff <= 0.0 or not points.shape[0]:
            return np.ones(points.shape[0], bool)
        if not right_views:
            right_views.append(quarter_disparity(*pair, config.num_disparities, right_view=True))
        small = to_quarter(points)
        value: FloatArray = (values / scale).astype(np.float32)
        there = _bilinear(right_views[0], small[:, 0] - value, small[:, 1])
        with np.errstate(invalid="ignore"):
            disagrees: npt.NDArray[np.bool_] = np.abs(there - value) > config.lr_max_diff
        return ~disagrees

    def kept_on_grid(side: float) -> tuple[FloatArray, FloatArray]:
        """The points every check keeps, and their values, of a grid of ``side`` px.

        The grid lies right of the quarter match's own left band.
        """
        xs = np.arange(first_x, width - config.border, side, dtype=np.float32)
        ys = np.arange(config.border, height - config.border, side, dtype=np.float32)
        grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2).astype(np.float32)
        values, confident = at_quarter(grid)
        rows = np.clip(np.rint(grid[:, 1]).astype(np.int64), 0, height - 1)
        cols = np.clip(np.rint(grid[:, 0]).astype(np.int64), 0, width - 1)
        half = half_map[rows, cols]
        with np.errstate(invalid="ignore"):
            measured = np.abs(half - values) <= config.agree
        keep = confident & ~measured
        # the right view last: only the points every cheaper check kept need it
        keep[keep] = right_agrees(grid[keep], values[keep])
        return np.ascontiguousarray(grid[keep]), values[keep].astype(np.float32)

    first_x = max(config.border, int(np.ceil(config.num_disparities * scale)))
    area = (first_x, config.border, width - config.border, height - config.border)
    side = scaled_spacing(config.spacing, area)
    found, found_values = kept_on_grid(side)
    # above the cap, the grid again with a side that fits (the points are spread over a
    # near surface as over the grid: their count falls with the square of the side)
    while max_points > 0 and found.shape[0] > max_points:
        side *= max(math.sqrt(found.shape[0] / max_points), 1.02)
        found, found_values = kept_on_grid(side)
    contradicted = np.zeros(count, bool)
    if config.drop_below > 0.0 and count:
        lookups = np.asarray(pixels, np.float32)
        there, sure = at_quarter(lookups)
        with np.errstate(invalid="ignore"):
            contradicted = sure & (disparities < there - np.float32(config.drop_below))
        contradicted[contradicted] = right_agrees(lookups[contradicted], there[contradicted])
    return NearPoints(found, found_values, contradicted, True)


def extend_near(
    left: npt.NDArray[np.generic],
    right: npt.NDArray[np.generic],
    half_map: FloatArray,
    pixels: FloatArray,
    disparities: FloatArray,
    config: NearConfig,
) -> tuple[FloatArray, FloatArray, FloatArray | None, dict[str, int]]:
    """The front end's lookups with the contradicted ones dropped and the near points added.

    ``left`` and ``right`` are the pair as recorded (grey or colour): they are converted to
    grey only when the trigger fires.

    Returns:
        pixels (m, 2), disparities (m,), each one's extra noise std (m,) (0 for the kept
        lookups, ``config.noise`` for the added points; None when nothing was added), and
        the counts ``near_added``, ``near_dropped`` and ``near_matched`` (0 or 1).
    """
    unchanged = {"near_added": 0, "near_dropped": 0, "near_matched": 0}
    # narrower, the quarter match has no column right of its own left band (and OpenCV's
    # matcher could fail on it: frontend/sgbm_limits.py)
    if left.shape[1] <= 4 * config.num_disparities + 2 * config.border:
        return pixels, disparities, None, unchanged
    if not wants_near(half_map, config):
        return pixels, disparities, None, unchanged
    grey = to_grey8_pair(left, right)  # one intensity scale for both views (16-bit)
    always = replace(config, trigger_share=0.0)
    found = near_points(*grey, half_map, pixels, disparities, always)
    kept = ~found.contradicted
    added = found.pixels.shape[0]
    counts = {
        "near_added": added,
        "near_dropped": int(found.contradicted.sum()),
        "near_matched": int(found.matched),
    }
    if not added and kept.all():
        return pixels, disparities, None, counts
    own = int(kept.sum())
    noise = np.zeros(own + added, np.float32)
    noise[own:] = np.float32(config.noise)
    return (
        np.ascontiguousarray(np.concatenate([pixels[kept], found.pixels]), np.float32),
        np.ascontiguousarray(np.concatenate([disparities[kept], found.disparities]), np.float32),
        noise if added else None,
        counts,
    )


def lookups_only(
    pixels: FloatArray, disparities: FloatArray, noise: FloatArray | None
) -> tuple[FloatArray, FloatArray]:
    """:func:`extend_near`'s output without the points it added (those with extra noise).

    The basis's fit check scores against SGBM's map, which has no value beyond the range
    (or an aliased one): it judges the basis on the points SGBM's map can confirm.
    """
    if noise is None:
        return pixels, disparities
    own = noise == 0
    return pixels[own], disparities[own]
