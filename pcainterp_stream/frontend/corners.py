"""Where sparse mode measures: Shi-Tomasi corners and a lattice in the gaps between them.

* :class:`GfttConfig` -- the corner detector's settings and the lattice's;
* :func:`detect_corners` -- ``cv2.goodFeaturesToTrack`` (+ ``cv2.cornerSubPix``), strongest
  first or taken in turns from the cells of a grid;
* :func:`lattice_points` -- the points of a square lattice that no measurement is near;
* :func:`patch_contrast` -- the grey-level std around points (a blank surface has none).

:func:`.stereo.sparse_lookups` looks both up in an SGBM map (docs/estimator.md, "Where the
measurements are").
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "FILL_PLACEMENTS",
    "GfttConfig",
    "detect_corners",
    "lattice_points",
    "patch_contrast",
]

FloatArray = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]

FILL_PLACEMENTS = ("nudged", "lattice", "even", "prior_std", "disparity")
"""Where the gap-filling lookups go (:attr:`GfttConfig.fill_placement`)."""


# ---------------------------------------------------------------------------------------
# Corners
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GfttConfig:
    """Shi-Tomasi corner detection (``cv2.goodFeaturesToTrack``) and the fill in their gaps.

    The defaults give ~355-405 valid lookups per KITTI frame (1242x375): 250 corners, of
    which ~200-240 pass the checks of :func:`lookup_disparities`, plus the points of a
    40 px lattice in their gaps (~150-165 with ``fill_placement="nudged"``, each rejected
    lattice point moved a quarter side to where a lookup passes). Corners cluster on
    texture (trees, lane marks, outlines); the fill points measure the surfaces between
    them, where the map erred most (``docs/options.md``, "Where the points are";
    ``docs/sharper_sparse_2.md``). Detection takes ~5-7 ms, of which ``cornerSubPix``
    ~1.5 ms (``docs/stages.md``).

    Attributes:
        max_corners: most corners returned (strongest first); 0 detects none, so the
            lattice (``fill_spacing``) alone is looked up.
        quality_level: minimum accepted corner response as a fraction of the strongest.
        min_distance: minimum distance between corners (px).
        block_size: size of the averaging block of the structure tensor (px).
        border: corners closer than this to any image edge are dropped (px).
        use_harris: use the Harris response instead of the Shi-Tomasi minimum eigenvalue.
        harris_k: Harris detector free parameter (only with ``use_harris``).
        subpixel: refine positions with ``cv2.cornerSubPix``.
        subpixel_window: half size of the ``cornerSubPix`` search window (px).
        buckets: (columns, rows) of a grid over the searched area: the corners are taken
            in turns from its cells (the strongest left in each cell first), so textured
            cells cannot take every corner; ``(1, 1)`` is plain strongest-first.
        fill_spacing: side (px) of a lattice of extra points (:func:`lattice_points`): a
            lattice point farther than half a side from every kept corner lookup is looked
            up too (same checks), so the surfaces between the corners get measurements;
            0 adds none. Past ~1920x1080 the side grows with the image
            (:func:`~pcainterp_stream.frontend.fill.scaled_spacing`).
        fill_min_contrast: a lattice point is looked up only where the grey levels of the
            7x7 px around it have at least this std: on a blank surface (saturated sky, a
            blank wall) SGBM's costs tie and it returns its smallest disparity (0, i.e.
            infinitely far) as if sure; a camera's noise alone gives ~1-2 grey levels.
        fill_placement: where the gap-filling lookups go. ``"nudged"`` (the default): the
            lattice above, each point whose lookup fails (too little contrast, an invalid
            or steep SGBM patch) moved a quarter side along an axis, else a diagonal, to
            the first place whose lookup passes (and ``nudge_min_support``), so a rejected
            point no longer leaves its cell unmeasured: 2-5 % lower mean disparity error
            than ``"lattice"`` on every source measured (``docs/sharper_sparse_2.md``).
            ``"lattice"``: the lattice's points alone. The others look up as many points
            as the lattice keeps, chosen greedily from a finer candidate lattice (side
            ``fill_spacing / 4``, the same contrast and lookup checks, so a rejected point
            leaves no gap) where the gap to the nearest measurement times a weight is
            largest (:func:`.fill.weighted_fill`): ``"even"`` weight 1; ``"prior_std"``
            the prior's disparity std at the point (the basis's per-pixel prior variance
            plus its local prior's, given by the processor) to the power
            ``fill_exponent``; ``"disparity"`` the looked-up disparity itself (floored at
            1 px) to that power, so near surfaces get more points than the far field.
            Measured against the lattice in ``docs/sharper_sparse.md``: ``"even"`` with
            ``fill_min_support=0.8`` is 4-14 % lower in mean disparity error on every
            source, but costs the front end 4-7 ms more CPU per KITTI frame (the whole job
            ~8 % more time) and raises the depth RMSE against the real LiDAR truth.
        fill_exponent: the weight's exponent of the ``"prior_std"`` and ``"disparity"``
            placements: the points' spacing then goes roughly as weight^-exponent.
        fill_min_support: a fill point (or a weighted placement's candidate) is looked
            up only where at least this share of the SGBM map's 21 x 21 px around it is
            valid: a greedy fill seeks the largest gaps, and the largest gaps are where
            SGBM failed (near objects beyond its range, blank surfaces), whose few valid
            pixels are the least sure; 0 (the default) checks nothing.
            A weighted placement still looks up as many points as the lattice without
            this check keeps; 0.8 is the measured choice for ``"even"``.
        nudge_min_support: a ``"nudged"`` point moved off its lattice position is kept
            only where at least this share of the SGBM map's 21 x 21 px around it is
            valid (:func:`.fill.valid_share`): the rejected points sit next to SGBM's
            holes, whose rims are its least sure values; 0.9 had the best mean gain over
            the four sources measured (0.8 gained little on the synthetic drives, 0.95
            less on the odometry clip).
    """

    max_corners: int = 250
    quality_level: float = 0.01
    min_distance: float = 10.0
    block_size: int = 3
    border: int = 8
    use_harris: bool = False
    harris_k: float = 0.04
    subpixel: bool = True
    subpixel_window: int = 3
    buckets: tuple[int, int] = (1, 1)
    fill_spacing: float = 40.0
    fill_min_contrast: float = 1.0
    fill_placement: str = "nudged"
    fill_exponent: float = 1.0
    fill_min_support: float = 0.0
    nudge_min_support: float = 0.9

    def __post_init__(self) -> None:
        if self.fill_placement not in FILL_PLACEMENTS:
            raise ValueError(
                f"fill_placement must be one of {', '.join(FILL_PLACEMENTS)}, "
                f"got {self.fill_placement!r}"
            )
        if not self.fill_exponent >= 0.0:
            raise ValueError(f"fill_exponent must be >= 0, got {self.fill_exponent}")
        if not 0.0 <= self.fill_min_support <= 1.0:
            raise ValueError(f"fill_min_support must be in [0, 1], got {self.fill_min_support}")
        if not 0.0 <= self.nudge_min_support <= 1.0:
            raise ValueError(f"nudge_min_support must be in [0, 1], got {self.nudge_min_support}")
        if min(self.buckets) < 1 or self.fill_spacing < 0.0:
            raise ValueError(
                f"buckets ({self.buckets}) must be >= 1 each and fill_spacing "
                f"({self.fill_spacing}) >= 0"
            )
        if self.max_corners < 0:
            raise ValueError(f"max_corners must be >= 0, got {self.max_corners}")
        if self.max_corners == 0 and self.fill_spacing <= 0.0:
            raise ValueError("max_corners 0 (no corners) needs a lattice: fill_spacing > 0")
        if not 0.0 < self.quality_level < 1.0:
            raise ValueError(f"quality_level must be in (0, 1), got {self.quality_level}")
        if self.border < 0 or self.block_size < 1 or self.subpixel_window < 1:
            raise ValueError(
                f"border ({self.border}) must be >= 0, block_size ({self.block_size}) and "
                f"subpixel_window ({self.subpixel_window}) >= 1"
            )


_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.03)


def detect_corners(
    left_grey: npt.NDArray[np.uint8],
    config: GfttConfig = GfttConfig(),  # frozen, so a shared default is safe
    *,
    min_x: int = 0,
) -> FloatArray:
    """Find Shi-Tomasi corners in the left image.

    Corners are searched only inside the image minus ``config.border`` px on every side and
    right of ``min_x`` (pass ``min_disparity + num_disparities`` of the matcher: left of it
    SGBM has no disparity, so corners there would be wasted).

    Args:
        left_grey: (H, W) uint8 grey left image.
        config: detector settings.
        min_x: corners with x < min_x are not searched for (px).

    Returns:
        (k, 2) float32 corner positions (x, y) in image px, strongest first; (0, 2) when the
        image has no corners (e.g. a blank image) or ``config.max_corners`` is 0.

    Raises:
        ValueError: if ``left_grey`` is not a 2-D uint8 array.
    """
    if left_grey.ndim != 2 or left_grey.dtype != np.uint8:
        raise ValueError(
            f"left_grey must be (H, W) uint8, got {left_grey.shape} {left_grey.dtype}; "
            "convert with to_grey8"
        )
    height, width = left_grey.shape
    x_start = max(config.border, min_x)
    if x_start >= width - config.border or 2 * config.border >= height or not config.max_corners:
        return np.zeros((0, 2), np.float32)
    # searched on the area and a margin only (the response's filters and the 3x3 local
    # maximum reach block_size // 2 + 2 px): the same corners, without the response of
    # the band left of min_x nor of the borders
    margin = config.block_size // 2 + 3
    x0, y0 = max(x_start - margin, 0), max(config.border - margin, 0)
    x1 = min(width - config.border + margin, width)
    y1 = min(height - config.border + margin, height)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    mask[
        config.border - y0 : height - config.border - y0, x_start - x0 : width - config.border - x0
    ] = 255
    columns, rows = config.buckets
    bucketed = columns * rows > 1
    found = cv2.goodFeaturesToTrack(
        left_grey[y0:y1, x0:x1],
        maxCorners=0 if bucketed else config.max_corners,  # 0: every corner
        qualityLevel=config.quality_level,
        minDistance=config.min_distance,
        mask=mask,
        blockSize=config.block_size,
        useHarrisDetector=config.use_harris,
        k=config.harris_k,
    )
    if found is None or len(found) == 0:
        return np.zeros((0, 2), np.float32)
    corners = np.ascontiguousarray(found.reshape(-1, 2), dtype=np.float32)
    corners += np.array([x0, y0], np.float32)  # whole pixels: exact in float32
    if bucketed:
        area = (x_start, config.border, width - config.border, height - config.border)
        corners = _take_in_turns(corners, area, config.buckets, config.max_corners)
    if config.subpixel:
        window = (config.subpixel_window, config.subpixel_window)
        refined = cv2.cornerSubPix(left_grey, corners, window, (-1, -1), _SUBPIX_CRITERIA)
        corners = np.asarray(refined, np.float32).reshape(-1, 2)
    return corners


def _take_in_turns(
    corners: FloatArray,
    area: tuple[int, int, int, int],
    buckets: tuple[int, int],
    count: int,
) -> FloatArray:
    """Take ``count`` corners (strongest first) in turns from the cells of a grid.

    Round r takes the r-th strongest corner of every cell that has one; the result keeps
    the strongest-first order within each round.
    """
    x0, y0, x1, y1 = area
    columns, rows = buckets
    col = ((corners[:, 0] - x0) * columns / max(x1 - x0, 1)).astype(np.int64)
    row = ((corners[:, 1] - y0) * rows / max(y1 - y0, 1)).astype(np.int64)
    col, row = np.clip(col, 0, columns - 1), np.clip(row, 0, rows - 1)
    cell = row * columns + col
    # rank of each corner within its cell (corners arrive strongest first)
    order = np.argsort(cell, kind="stable")
    sorted_cells = cell[order]
    starts = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.empty_like(cell)
    rank[order] = np.arange(cell.size) - starts
    chosen = np.lexsort((np.arange(cell.size), rank))[:count]
    return np.ascontiguousarray(corners[chosen])


def lattice_points(kept: FloatArray, spacing: float, area: tuple[int, int, int, int]) -> FloatArray:
    """Return the points of a square lattice farther than ``spacing / 2`` from every kept point.

    Args:
        kept: (k, 2) float32 (x, y) px of the measurements already made.
        spacing: lattice side (px), > 0.
        area: (x0, y0, x1, y1) px; the lattice is centred in it.

    Returns:
        (m, 2) float32 (x, y) px, row by row.
    """
    x0, y0, x1, y1 = area
    if spacing <= 0.0 or x1 - x0 < spacing or y1 - y0 < spacing:
        return np.zeros((0, 2), np.float32)
    xs = np.arange(x0, x1 - spacing / 2, spacing, dtype=np.float64)
    ys = np.arange(y0, y1 - spacing / 2, spacing, dtype=np.float64)
    xs += (x1 - 1 - xs[-1]) / 2  # centred in the area (xs[0] = x0)
    ys += (y1 - 1 - ys[-1]) / 2
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2).astype(np.float32)
    if kept.shape[0]:
        # squared gaps (m, k) in float32, x and y apart: no (m, k, 2) temporary (8x faster)
        kept32 = kept.astype(np.float32)
        gap = grid[:, 0, None] - kept32[None, :, 0]
        along_y = grid[:, 1, None] - kept32[None, :, 1]
        gap *= gap
        along_y *= along_y
        gap += along_y
        grid = grid[gap.min(axis=1) > (spacing / 2) ** 2]
    return np.ascontiguousarray(grid)


def patch_contrast(grey: UInt8Array, points: FloatArray, half: int = 3) -> FloatArray:
    """Std of the grey levels in the (2 half + 1)^2 px around each point (nearest pixel)."""
    if points.shape[0] == 0:
        return np.zeros(0, np.float32)
    height, width = grey.shape
    size = 2 * half + 1
    x = np.clip(np.rint(points[:, 0]).astype(np.int64) - half, 0, width - size)
    y = np.clip(np.rint(points[:, 1]).astype(np.int64) - half, 0, height - size)
    offsets = np.arange(size)
    rows = (y[:, None] + offsets)[:, :, None]
    cols = (x[:, None] + offsets)[:, None, :]
    patches = grey[rows, cols].astype(np.float32)
    return np.asarray(patches.reshape(points.shape[0], -1).std(axis=1), np.float32)
