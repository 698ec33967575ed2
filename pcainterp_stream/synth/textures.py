"""Procedural texture tiles with mip levels, sampled by world surface coordinates.

Every surface of the synthetic world is textured by a periodic noise tile looked up at the
surface's own coordinates (metres along the surface and up, or world x, y on the ground), so a
surface point has the same brightness in the left and the right image: that is what makes the
synthetic pairs matchable by SGBM. A tile is stored with a mip pyramid (2x2 box averages) and a
lookup picks the level whose texel matches the pixel's footprint along the image row; texture
finer than a pixel would alias differently in the two views and break matching (moire).

Tiles are generated once per seed from a :class:`numpy.random.Generator` and quantised to
multiples of 1/1024, so they are identical on every machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

#: Tile edge length in texels (a power of two).
TILE_SIZE = 512
#: log2(TILE_SIZE): number of mip levels below level 0.
TILE_LOG2 = 9
_SHIFT = float(TILE_SIZE * 1024)


def _noise_tile(
    rng: np.random.Generator, *, size: int, octaves: tuple[tuple[float, float], ...]
) -> npt.NDArray[np.float64]:
    """Return a periodic band-limited noise tile scaled to zero mean and unit std.

    Args:
        rng: the seeded generator.
        size: edge length (texels).
        octaves: (Gaussian sigma in texels, amplitude) pairs summed into the tile.

    Returns:
        (size, size) float64 noise.
    """
    tile = np.zeros((size, size))
    for sigma, amplitude in octaves:
        white = rng.standard_normal((size, size))
        smooth = ndimage.gaussian_filter(white, sigma, mode="wrap") if sigma > 0 else white
        tile += amplitude * smooth / max(float(smooth.std()), 1e-12)
    tile -= tile.mean()
    return tile / max(float(tile.std()), 1e-12)


#: Per-tile octave recipes (sigma in texels, amplitude). The order fixes the tile ids below.
_RECIPES: tuple[tuple[tuple[float, float], ...], ...] = (
    ((0.0, 0.35), (1.0, 0.6), (4.0, 0.5), (16.0, 0.4)),  # 0 asphalt: grainy
    ((0.7, 0.5), (3.0, 0.6), (10.0, 0.5)),  # 1 pavement
    ((1.0, 0.8), (3.0, 0.7), (12.0, 0.6), (40.0, 0.5)),  # 2 grass / field
    ((1.0, 0.4), (4.0, 0.6), (20.0, 0.5)),  # 3 plaster facade
    ((0.7, 0.6), (2.0, 0.6), (8.0, 0.4)),  # 4 brick-like facade
    ((1.0, 0.5), (6.0, 0.6), (30.0, 0.4)),  # 5 car paint / metal
    ((0.7, 0.9), (2.0, 0.6), (6.0, 0.4)),  # 6 bark / foliage
    ((8.0, 0.7), (32.0, 0.7), (64.0, 0.5)),  # 7 macro variation (large blotches)
)
TILE_ASPHALT, TILE_PAVEMENT, TILE_GRASS, TILE_PLASTER, TILE_BRICK, TILE_METAL, TILE_FOLIAGE = range(
    7
)
TILE_MACRO = 7


#: Rows reserved per tile in ``TextureBank.texels``: level l starts at row 1024 - (1024 >> l)
#: and every row is TILE_SIZE texels long, so an index is pure shift arithmetic.
_TILE_ROWS = 2 * TILE_SIZE
_TILE_TEXELS_LOG2 = 2 * TILE_LOG2 + 1


@dataclass(frozen=True)
class TextureBank:
    """All texture tiles of one world with their mip pyramids, flattened for gathers.

    Tile i occupies texels ``[i << 19, (i + 1) << 19)`` as 1024 rows of TILE_SIZE texels:
    level l (size 512 >> l) starts at row 1024 - (1024 >> l); unused texels are zero.

    Attributes:
        texels: (n_tiles << 19,) float32 texel values, about in [-3, 3].
    """

    texels: npt.NDArray[np.float32]

    @property
    def n_tiles(self) -> int:
        """Return the number of tiles."""
        return int(self.texels.shape[0] >> _TILE_TEXELS_LOG2)

    def sample(
        self,
        tile_base: npt.NDArray[np.int64] | int,
        s: npt.NDArray[np.float32],
        t: npt.NDArray[np.float32],
        level: npt.NDArray[np.int32],
    ) -> npt.NDArray[np.float32]:
        """Look up texels (nearest texel of one mip level) for many points at once.

        Args:
            tile_base: (n,) int64 per point, or one int: ``tile_offset(tile)``.
            s: (n,) float32 first surface coordinate in level-0 texels.
            t: (n,) float32 second surface coordinate in level-0 texels.
            level: (n,) int32 mip level per point, 0..TILE_LOG2.

        Returns:
            (n,) float32 texel values.
        """
        # A shift by a multiple of TILE_SIZE (the period at every level) makes coordinates
        # positive so truncation is floor; float32 keeps 1/16 texel at |s| < 2**19.
        mask = np.right_shift(np.int32(TILE_SIZE - 1), level)
        si = (s + np.float32(_SHIFT)).astype(np.int32)
        np.right_shift(si, level, out=si)
        si &= mask
        ti = (t + np.float32(_SHIFT)).astype(np.int32)
        np.right_shift(ti, level, out=ti)
        ti &= mask
        # Row within the tile: level start 1024 - (1024 >> l) plus the texel row.
        ti += np.int32(_TILE_ROWS)
        ti -= np.right_shift(np.int32(_TILE_ROWS), level)
        np.left_shift(ti, np.int32(TILE_LOG2), out=ti)
        ti += si
        index = ti.astype(np.int64)
        index += tile_base
        return np.take(self.texels, index)


def tile_offset(tile: npt.NDArray[np.integer] | int) -> npt.NDArray[np.int64]:
    """Return the offset of tile(s) ``tile`` in ``TextureBank.texels`` (int64)."""
    return np.left_shift(np.asarray(tile, dtype=np.int64), _TILE_TEXELS_LOG2)


def make_texture_bank(rng: np.random.Generator) -> TextureBank:
    """Generate the world's tiles and their mip pyramids.

    Args:
        rng: the world's seeded generator (consumed).

    Returns:
        The bank; tiles are quantised to 1/1024 so results do not depend on the platform's
        floating-point library.
    """
    texels = np.zeros((len(_RECIPES), _TILE_ROWS, TILE_SIZE), dtype=np.float32)
    for tile_index, recipe in enumerate(_RECIPES):
        level_image = _noise_tile(rng, size=TILE_SIZE, octaves=recipe)
        for level in range(TILE_LOG2 + 1):
            quantised = (np.round(level_image * 1024.0) / 1024.0).astype(np.float32)
            size = quantised.shape[0]
            row = _TILE_ROWS - (_TILE_ROWS >> level)
            texels[tile_index, row : row + size, :size] = quantised
            if level < TILE_LOG2:
                # 2x2 box average, then a light wrap blur so a level holds no frequency its
                # texel grid cannot carry (anti-aliasing of the pyramid itself).
                size = level_image.shape[0] // 2
                level_image = level_image.reshape(size, 2, size, 2).mean(axis=(1, 3))
                if size >= 4:
                    level_image = ndimage.gaussian_filter(level_image, 0.5, mode="wrap")
    return TextureBank(texels=texels.ravel())
