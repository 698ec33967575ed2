"""The procedural street world: road, ground height field and vertical extrusions.

World frame: x along the road's general direction, y to the left, z up (metres). The road
centre line is the graph y = y_c(x) of a few long sinusoids (gentle curves), its height
profile H(x) another few (gentle hills). Road coordinates are (u, l): u = x along the road and
l the signed lateral offset from the centre line (left positive), l = (y - y_c(x)) cos(theta),
theta the road heading; objects are placed in (u, l) and converted to world x, y.

The world is a "2.5-D" scene, the classic column ray caster's: a ground height field
z = h(x, y) plus vertical extrusions of 2-D footprints (facade and car-box segments, pole,
trunk and crown cylinders), each between a bottom and a top height. It is generated in 50 m
blocks along u, each from its own generator seeded by (seed, block), so any stretch of road is
the same whatever was generated before, and only the blocks near the camera are kept: memory
does not grow with the length of the drive.

Determinism: transcendental functions only ever fill small tables (road profile on a 1 m grid,
hill grid), which are quantised (1e-6 m) before use; per-sample and per-pixel work uses only
+ - * / sqrt and comparisons, which IEEE 754 makes identical on every machine.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from pcainterp_stream.synth import textures

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

#: Length of a generation block along the road (m).
BLOCK_LENGTH = 50.0
#: Blocks per district; a district has one zone type.
BLOCKS_PER_DISTRICT = 4
#: Half width of the paved road incl. parking lanes (m); driving lanes are |l| < LANE_EDGE.
ROAD_HALF_WIDTH = 5.5
LANE_EDGE = 3.5
#: Width of the sidewalk beyond the road edge in towns (m) and its kerb height (m).
SIDEWALK_WIDTH = 2.6
KERB_HEIGHT = 0.12
#: Half length of a side street's crossing along u (m).
SIDE_STREET_HALF = 5.0
#: Hill grid: cell size (m) and cells per side (periodic).
HILL_CELL = 40.0
HILL_CELLS = 64


class Zone(IntEnum):
    """Kind of surroundings of a district."""

    URBAN = 0
    SUBURBAN = 1
    COUNTRY = 2


class Material(IntEnum):
    """Surface kinds; each has a texture tile, a contrast and maybe a pattern."""

    ASPHALT = 0
    PAVEMENT = 1
    GRASS = 2
    PLASTER = 3
    BRICK = 4
    CAR = 5
    POLE = 6
    BARK = 7
    FOLIAGE = 8
    HEDGE = 9


#: Per material: tile id, texture contrast (grey levels per unit noise), windows (0/1).
MATERIAL_TILE = np.array([0, 1, 2, 3, 4, 5, 5, 6, 6, 6], dtype=np.intp)
MATERIAL_CONTRAST = np.array(
    [13.0, 15.0, 22.0, 16.0, 20.0, 14.0, 10.0, 22.0, 30.0, 26.0], dtype=np.float32
)
MATERIAL_WINDOWS = np.array([0, 0, 0, 1, 1, 0, 0, 0, 0, 0], dtype=np.float32)
MATERIAL_CAR_WINDOWS = np.array([0, 0, 0, 0, 0, 1, 0, 0, 0, 0], dtype=np.float32)


def _quantise(values: F64) -> F64:
    """Round to 1e-6 so platform ulp differences of transcendental functions vanish."""
    return np.round(values * 1e6) / 1e6


@dataclass(frozen=True)
class Objects:
    """Vertical extrusions of a stretch of road, as flat arrays (one row per object).

    Attributes:
        seg_start: (n, 2) float64 segment start (x, y), m.
        seg_end: (n, 2) float64 segment end (x, y), m.
        seg_bottom: (n,) float64 bottom height, m.
        seg_top: (n,) float64 top height, m.
        seg_u0: (n,) float64 texture coordinate at the start (m along the surface).
        seg_material: (n,) int64 :class:`Material`.
        seg_albedo: (n,) float64 base grey level.
        cyl_centre: (m, 2) float64 cylinder axis (x, y), m.
        cyl_radius: (m,) float64 radius, m.
        cyl_bottom: (m,) float64 bottom height, m.
        cyl_top: (m,) float64 top height, m.
        cyl_material: (m,) int64 :class:`Material`.
        cyl_albedo: (m,) float64 base grey level.
    """

    seg_start: F64
    seg_end: F64
    seg_bottom: F64
    seg_top: F64
    seg_u0: F64
    seg_material: npt.NDArray[np.int64]
    seg_albedo: F64
    cyl_centre: F64
    cyl_radius: F64
    cyl_bottom: F64
    cyl_top: F64
    cyl_material: npt.NDArray[np.int64]
    cyl_albedo: F64


@dataclass(frozen=True)
class Block:
    """The content of one 50 m block: its zone, side street and objects."""

    index: int
    zone: Zone
    side_street_u: float  # NaN when the block has none
    objects: Objects


@dataclass(frozen=True)
class Illumination:
    """Scene lighting of one world (one seed).

    Attributes:
        sun: (3,) float64 unit vector towards the sun, world frame.
        ambient: fraction of light that is not direct sun.
        gain: global exposure factor.
        sky_top: sky grey level at the top of the image.
        sky_horizon: sky grey level at the horizon.
    """

    sun: F64
    ambient: float
    gain: float
    sky_top: float
    sky_horizon: float


@dataclass(frozen=True)
class RoadTable:
    """Road centre line and height profile sampled on an integer-metre grid of x.

    Attributes:
        x0: x of the first grid point (integer m).
        centre_y: (n,) float64 y_c(x).
        sin_heading: (n,) float64 sin(theta(x)).
        cos_heading: (n,) float64 cos(theta(x)).
        height: (n,) float64 H(x).
    """

    x0: float
    centre_y: F64
    sin_heading: F64
    cos_heading: F64
    height: F64

    def lookup(self, x: F64) -> tuple[F64, F64, F64, F64]:
        """Linearly interpolate the table at x.

        Args:
            x: (...) float64 world x (m), inside the table's range.

        Returns:
            y_c, sin(theta), cos(theta), H at x, each like ``x`` (float64).
        """
        position = np.clip(x - self.x0, 0.0, self.centre_y.shape[0] - 1.000001)
        index = position.astype(np.intp)
        weight = position - index
        out = []
        for table in (self.centre_y, self.sin_heading, self.cos_heading, self.height):
            low = table[index]
            out.append(low + weight * (table[index + 1] - low))
        return out[0], out[1], out[2], out[3]


class World:
    """A procedural street world for one seed, generated block by block on demand.

    Args:
        seed: any non-negative integer; the same seed gives the same world everywhere.
    """

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        rng = np.random.default_rng([self.seed, 1])
        self.textures = textures.make_texture_bank(rng)
        # Road curves: y_c(x) = sum A sin(k x + phi); slope amplitude 0.03..0.09 each.
        wavelengths = rng.uniform(250.0, 900.0, 3)
        self._curve_k = 2 * np.pi / wavelengths
        self._curve_a = rng.uniform(0.03, 0.09, 3) / self._curve_k
        self._curve_phase = rng.uniform(0, 2 * np.pi, 3)
        # Hills: H(x) = sum B sin(m x + psi); grade amplitude 0.4 %..1.8 % each.
        hill_lengths = rng.uniform(300.0, 1200.0, 3)
        self._hill_k = 2 * np.pi / hill_lengths
        self._hill_a = rng.uniform(0.004, 0.018, 3) / self._hill_k
        self._hill_phase = rng.uniform(0, 2 * np.pi, 3)
        # Off-road terrain: periodic smooth grid, amplitude rising away from the road.
        grid = rng.standard_normal((HILL_CELLS, HILL_CELLS))
        from scipy import ndimage

        grid = ndimage.gaussian_filter(grid, 2.0, mode="wrap")
        grid /= max(float(np.abs(grid).max()), 1e-12)
        self._hill_grid = _quantise(grid)
        # Per cell: corner value and step to the next x corner, for this row and the next.
        wrapped = np.pad(self._hill_grid, ((0, 1), (0, 1)), mode="wrap")
        corners = np.empty((HILL_CELLS, HILL_CELLS, 4))
        corners[:, :, 0] = wrapped[:-1, :-1]
        corners[:, :, 1] = wrapped[:-1, 1:] - wrapped[:-1, :-1]
        corners[:, :, 2] = wrapped[1:, :-1]
        corners[:, :, 3] = wrapped[1:, 1:] - wrapped[1:, :-1]
        self._hill_cells = corners.reshape(-1, 4)
        self.hill_amplitude = float(rng.uniform(8.0, 30.0))
        azimuth = rng.uniform(0, 2 * np.pi)
        elevation = rng.uniform(np.radians(25), np.radians(60))
        self.illumination = Illumination(
            sun=_quantise(
                np.array(
                    [
                        np.cos(elevation) * np.cos(azimuth),
                        np.cos(elevation) * np.sin(azimuth),
                        np.sin(elevation),
                    ]
                )
            ),
            ambient=float(np.round(rng.uniform(0.45, 0.65), 6)),
            gain=float(np.round(rng.uniform(0.85, 1.1), 6)),
            sky_top=float(np.round(rng.uniform(200.0, 245.0), 3)),
            sky_horizon=float(np.round(rng.uniform(215.0, 252.0), 3)),
        )
        self._blocks: OrderedDict[int, Block] = OrderedDict()
        self._zones: dict[int, Zone] = {}
        # Views may be rendered in threads (left and right at once): guard the caches.
        self._lock = threading.RLock()
        self._streets: dict[int, float] = {}

    # ----------------------------------------------------------------- road and ground
    def road_table(self, x_min: float, x_max: float) -> RoadTable:
        """Return the road profile tabulated on integer metres covering [x_min, x_max].

        Args:
            x_min: smallest world x needed (m).
            x_max: largest world x needed (m).

        Returns:
            The table; its values depend only on the grid points, not on the range.
        """
        x = np.arange(np.floor(x_min) - 1.0, np.ceil(x_max) + 2.0)
        phase = x[:, None] * self._curve_k + self._curve_phase
        centre = (self._curve_a * np.sin(phase)).sum(axis=1)
        slope = (self._curve_a * self._curve_k * np.cos(phase)).sum(axis=1)
        norm = np.sqrt(1.0 + slope * slope)
        height = (self._hill_a * np.sin(x[:, None] * self._hill_k + self._hill_phase)).sum(axis=1)
        return RoadTable(
            x0=float(x[0]),
            centre_y=_quantise(centre),
            sin_heading=_quantise(slope / norm),
            cos_heading=_quantise(1.0 / norm),
            height=_quantise(height),
        )

    def road_point(self, table: RoadTable, u: F64, lateral: F64) -> tuple[F64, F64]:
        """Convert road coordinates to world x, y.

        Args:
            table: a road table covering u (with a margin of |lateral|).
            u: (...) float64 along-road coordinate (m).
            lateral: (...) float64 signed lateral offset, left positive (m).

        Returns:
            x, y (float64, broadcast shape), m.
        """
        centre, sin_h, cos_h, _ = table.lookup(np.asarray(u, dtype=np.float64))
        return u - lateral * sin_h, centre + lateral * cos_h

    def ground(self, table: RoadTable, zones: BlockTable, x: F64, y: F64) -> tuple[F64, F64]:
        """Ground height and lateral road coordinate at world points.

        Args:
            table: road table covering x.
            zones: block table covering x.
            x: (...) float64 world x (m).
            y: (...) float64 world y (m).

        Returns:
            height z (m) and lateral offset l (m), float64 like ``x``.
        """
        n = table.centre_y.shape[0]
        position = np.clip(x - table.x0, 0.0, n - 1.000001)
        index = position.astype(np.intp)
        weight = position - index

        # Value plus weight times the step to the next metre of y_c, cos(theta), H (steps
        # tabulated once), and the sidewalk flag, which changes only at whole metres (block
        # and side-street edges).
        def lerp(values: F64) -> F64:
            step = np.zeros_like(values)
            np.subtract(values[1:], values[:-1], out=step[:-1])
            result: F64 = np.take(values, index) + weight * np.take(step, index)
            return result

        sidewalk = zones.has_sidewalk(table.x0 + 0.5 + np.arange(n, dtype=np.float64))
        lateral = (y - lerp(table.centre_y)) * lerp(table.cos_heading)
        distance = np.abs(lateral)
        # Kerb: a 0.12 m step at the road edge, ramped over 0.15 m, absent in the country
        # and across side streets.
        kerb = np.clip((distance - ROAD_HALF_WIDTH) * (1.0 / 0.15), 0.0, 1.0)
        kerb *= np.take(sidewalk * KERB_HEIGHT, index)
        # Off-road hills: zero near the road, full amplitude 150 m away.
        rise = np.clip((distance - 14.0) * (self.hill_amplitude / 150.0), 0.0, self.hill_amplitude)
        return lerp(table.height) + kerb + rise * self._hills(x, y), lateral

    def _hills(self, x: F64, y: F64) -> F64:
        """Bilinear lookup of the periodic hill grid (values in [-1, 1])."""
        gx = x * (1.0 / HILL_CELL)
        gy = y * (1.0 / HILL_CELL)
        fx = np.floor(gx)
        fy = np.floor(gy)
        wx = gx - fx
        wy = gy - fy
        cell = (fy.astype(np.intp) & (HILL_CELLS - 1)) * HILL_CELLS + (
            fx.astype(np.intp) & (HILL_CELLS - 1)
        )
        corners = np.take(self._hill_cells, cell, axis=0)
        top = corners[..., 0] + wx * corners[..., 1]
        bottom = corners[..., 2] + wx * corners[..., 3]
        result: F64 = top + wy * (bottom - top)
        return result

    # ----------------------------------------------------------------- blocks
    def zone_of_block(self, index: int) -> Zone:
        """Return the zone of the district that holds block ``index``."""
        district = index // BLOCKS_PER_DISTRICT
        cached = self._zones.get(district)
        if cached is None:
            cached = self._zone_of_district(district)
            if len(self._zones) > 4096:
                self._zones.clear()
            self._zones[district] = cached
        return cached

    def _zone_of_district(self, district: int) -> Zone:
        rng = np.random.default_rng([self.seed, 2, district + 2**31])
        if -1 <= district <= 0:
            return Zone.URBAN  # every drive starts in town
        return Zone(int(rng.choice(3, p=[0.45, 0.35, 0.20])))

    def block(self, index: int) -> Block:
        """Return block ``index`` (cached; at most 24 blocks are kept)."""
        with self._lock:
            return self._block(index)

    def _block(self, index: int) -> Block:
        cached = self._blocks.get(index)
        if cached is not None:
            self._blocks.move_to_end(index)
            return cached
        made = _make_block(self, index)
        self._blocks[index] = made
        while len(self._blocks) > 24:
            self._blocks.popitem(last=False)
        return made

    def block_table(self, u_min: float, u_max: float) -> BlockTable:
        """Return per-block zone data covering [u_min, u_max] for vectorised lookups."""
        with self._lock:
            return self._block_table(u_min, u_max)

    def _block_table(self, u_min: float, u_max: float) -> BlockTable:
        first = int(np.floor(u_min / BLOCK_LENGTH)) - 1
        last = int(np.floor(u_max / BLOCK_LENGTH)) + 1
        zones = []
        streets = []
        for index in range(first, last + 1):
            zone = self.zone_of_block(index)
            zones.append(int(zone))
            street = self._streets.get(index)
            if street is None:
                street = _side_street_u(self.seed, index, zone)
                if len(self._streets) > 4096:
                    self._streets.clear()
                self._streets[index] = street
            streets.append(street)
        return BlockTable(
            first=first,
            zone=np.array(zones, dtype=np.int64),
            side_street_u=np.array(streets, dtype=np.float64),
        )

    def objects(self, u_min: float, u_max: float) -> Objects:
        """Return all objects of the blocks overlapping [u_min, u_max], concatenated."""
        first = int(np.floor(u_min / BLOCK_LENGTH))
        last = int(np.floor(u_max / BLOCK_LENGTH))
        parts = [self.block(index).objects for index in range(first, last + 1)]
        return Objects(
            **{
                name: np.concatenate([getattr(part, name) for part in parts])
                for name in Objects.__dataclass_fields__
            }
        )


@dataclass(frozen=True)
class BlockTable:
    """Zone and side street of consecutive blocks, for per-pixel lookups by u.

    Attributes:
        first: index of the first block.
        zone: (n,) int64 :class:`Zone` per block.
        side_street_u: (n,) float64 u of the block's side street, NaN if none.
    """

    first: int
    zone: npt.NDArray[np.int64]
    side_street_u: F64

    def _index(self, u: npt.NDArray[np.floating]) -> npt.NDArray[np.intp]:
        block = np.floor(u * (1.0 / BLOCK_LENGTH)).astype(np.intp) - self.first
        result: npt.NDArray[np.intp] = np.clip(block, 0, self.zone.shape[0] - 1)
        return result

    def in_side_street(self, u: npt.NDArray[np.floating]) -> npt.NDArray[np.bool_]:
        """Return whether u lies on a side street crossing (bool like ``u``)."""
        street = self.side_street_u[self._index(u)]
        with np.errstate(invalid="ignore"):
            return np.abs(u - street) < SIDE_STREET_HALF

    def has_sidewalk(self, u: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Return 1.0 where the road has sidewalks (town, not a side street), else 0.0."""
        index = self._index(u)
        town = self.zone[index] != Zone.COUNTRY
        with np.errstate(invalid="ignore"):
            street = np.abs(u - self.side_street_u[index]) < SIDE_STREET_HALF
        result: npt.NDArray[np.float64] = (town & ~street).astype(u.dtype)
        return result


def _side_street_u(seed: int, index: int, zone: Zone) -> float:
    """Return u of block ``index``'s side street or NaN (deterministic per seed, block)."""
    rng = np.random.default_rng([seed, 3, index + 2**31])
    chance = 0.1 if zone == Zone.COUNTRY else 0.3
    if index != 0 and rng.random() < chance:
        return (index + 0.5) * BLOCK_LENGTH
    return float("nan")


class _Builder:
    """Accumulates segments and cylinders of one block."""

    def __init__(self) -> None:
        self.segments: list[tuple[float, ...]] = []
        self.cylinders: list[tuple[float, ...]] = []

    def segment(
        self,
        start: tuple[float, float],
        end: tuple[float, float],
        bottom: float,
        top: float,
        u0: float,
        material: Material,
        albedo: float,
    ) -> None:
        self.segments.append((*start, *end, bottom, top, u0, float(material), albedo))

    def cylinder(
        self,
        centre: tuple[float, float],
        radius: float,
        bottom: float,
        top: float,
        material: Material,
        albedo: float,
    ) -> None:
        self.cylinders.append((*centre, radius, bottom, top, float(material), albedo))

    def build(self) -> Objects:
        seg = np.array(self.segments, dtype=np.float64).reshape(-1, 9)
        cyl = np.array(self.cylinders, dtype=np.float64).reshape(-1, 7)
        return Objects(
            seg_start=seg[:, 0:2].copy(),
            seg_end=seg[:, 2:4].copy(),
            seg_bottom=seg[:, 4].copy(),
            seg_top=seg[:, 5].copy(),
            seg_u0=seg[:, 6].copy(),
            seg_material=seg[:, 7].astype(np.int64),
            seg_albedo=seg[:, 8].copy(),
            cyl_centre=cyl[:, 0:2].copy(),
            cyl_radius=cyl[:, 2].copy(),
            cyl_bottom=cyl[:, 3].copy(),
            cyl_top=cyl[:, 4].copy(),
            cyl_material=cyl[:, 5].astype(np.int64),
            cyl_albedo=cyl[:, 6].copy(),
        )


def _make_block(world: World, index: int) -> Block:
    """Generate the objects of block ``index`` from its own generator."""
    rng = np.random.default_rng([world.seed, 4, index + 2**31])
    zone = world.zone_of_block(index)
    street_u = _side_street_u(world.seed, index, zone)
    start = index * BLOCK_LENGTH
    end = start + BLOCK_LENGTH
    table = world.road_table(start - 80.0, end + 80.0)
    zones = world.block_table(start - 80.0, end + 80.0)
    builder = _Builder()

    def point(u: float, lateral: float) -> tuple[float, float]:
        x, y = world.road_point(table, np.array([u]), np.array([lateral]))
        return float(x[0]), float(y[0])

    def ground_at(u: float, lateral: float) -> float:
        x, y = point(u, lateral)
        height, _ = world.ground(table, zones, np.array([x]), np.array([y]))
        return float(height[0])

    def free(u_a: float, u_b: float) -> bool:
        """Whether [u_a, u_b] keeps clear of the side street."""
        if np.isnan(street_u):
            return True
        return u_b < street_u - SIDE_STREET_HALF - 1.0 or u_a > street_u + SIDE_STREET_HALF + 1.0

    def box(
        u: float,
        lateral: float,
        length: float,
        width: float,
        height: float,
        yaw: float,
        material: Material,
        albedo: float,
    ) -> None:
        """A box footprint (4 two-sided segments) centred at road coordinates (u, l)."""
        cx, cy = point(u, lateral)
        ux, uy = point(u + 1.0, lateral)
        heading = np.arctan2(uy - cy, ux - cx) + yaw
        dx, dy = np.cos(heading), np.sin(heading)
        corners = [
            (
                cx + sx * length / 2 * dx - sy * width / 2 * dy,
                cy + sx * length / 2 * dy + sy * width / 2 * dx,
            )
            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
        ]
        bottom = ground_at(u, lateral) - 0.3
        u0 = float(rng.uniform(0, 100))
        for k in range(4):
            builder.segment(
                corners[k],
                corners[(k + 1) % 4],
                bottom,
                bottom + 0.3 + height,
                u0 + k * 5.0,
                material,
                albedo,
            )

    for side in (1.0, -1.0):
        if zone in (Zone.URBAN, Zone.SUBURBAN):
            urban = zone == Zone.URBAN
            # Facades: a row of buildings with gaps, each a front face and two side faces.
            u = start + float(rng.uniform(0.0, 4.0))
            while u < end - 3.0:
                width = float(rng.uniform(8.0, 22.0) if urban else rng.uniform(8.0, 14.0))
                if rng.random() < (0.2 if urban else 0.45):
                    u += float(rng.uniform(3.0, 9.0) if urban else rng.uniform(5.0, 14.0))
                    continue
                u_b = min(u + width, end)
                if u_b - u > 3.0 and free(u, u_b):
                    setback = float(rng.uniform(6.8, 11.0) if urban else rng.uniform(9.0, 16.0))
                    height = float(rng.uniform(7.0, 19.0) if urban else rng.uniform(4.5, 8.0))
                    depth = float(rng.uniform(8.0, 14.0))
                    material = Material.BRICK if rng.random() < 0.4 else Material.PLASTER
                    albedo = float(rng.uniform(70.0, 175.0))
                    front_a = point(u, side * setback)
                    front_b = point(u_b, side * setback)
                    back_a = point(u, side * (setback + depth))
                    back_b = point(u_b, side * (setback + depth))
                    bottom = min(ground_at(u, side * setback), ground_at(u_b, side * setback))
                    bottom -= 0.5
                    top = bottom + 0.5 + height
                    u0 = float(rng.uniform(0, 1000))
                    builder.segment(front_a, front_b, bottom, top, u0, material, albedo)
                    builder.segment(back_a, front_a, bottom, top, u0 - depth, material, albedo)
                    builder.segment(front_b, back_b, bottom, top, u0 + u_b - u, material, albedo)
                u = u_b
            # Parked cars in the parking lane.
            u = start + float(rng.uniform(0.0, 6.0))
            while u < end - 2.5:
                length = float(rng.uniform(3.9, 4.7))
                if rng.random() < (0.65 if urban else 0.4) and free(u - 3, u + length + 3):
                    box(
                        u + length / 2,
                        side * float(rng.uniform(4.3, 4.6)),
                        length,
                        float(rng.uniform(1.7, 1.85)),
                        float(rng.uniform(1.4, 1.6)),
                        float(rng.uniform(-0.05, 0.05)),
                        Material.CAR,
                        float(rng.choice([40.0, 70.0, 110.0, 150.0, 190.0, 215.0])),
                    )
                u += length + float(rng.uniform(0.8, 6.0))
            # Street lights / sign poles on the sidewalk.
            u = start + float(rng.uniform(0.0, 30.0))
            while u < end:
                lateral = side * (ROAD_HALF_WIDTH + 0.5)
                if free(u - 1, u + 1):
                    bottom = ground_at(u, lateral) - 0.3
                    builder.cylinder(
                        point(u, lateral),
                        float(rng.uniform(0.06, 0.12)),
                        bottom,
                        bottom + float(rng.uniform(3.0, 8.0)),
                        Material.POLE,
                        float(rng.uniform(90, 170)),
                    )
                u += float(rng.uniform(20.0, 40.0))
            # Trees: on the sidewalk in town, in front yards in the suburbs.
            spacing = 14.0 if urban else 11.0
            u = start + float(rng.uniform(0.0, spacing))
            while u < end:
                lateral = side * (ROAD_HALF_WIDTH + 1.6 if urban else float(rng.uniform(7.0, 12.0)))
                if rng.random() < (0.35 if urban else 0.55) and free(u - 3, u + 3):
                    _tree(builder, rng, point(u, lateral), ground_at(u, lateral))
                u += spacing * float(rng.uniform(0.7, 1.3))
            if not urban and rng.random() < 0.5:
                # A hedge along the front yards.
                lateral = side * float(rng.uniform(7.0, 8.5))
                u_a = start + float(rng.uniform(0, 10))
                u_b = min(u_a + float(rng.uniform(10, 35)), end)
                if free(u_a, u_b):
                    bottom = ground_at(u_a, lateral) - 0.4
                    builder.segment(
                        point(u_a, lateral),
                        point(u_b, lateral),
                        bottom,
                        bottom + float(rng.uniform(1.3, 2.0)),
                        float(rng.uniform(0, 500)),
                        Material.HEDGE,
                        float(rng.uniform(50, 90)),
                    )
        else:
            # Open country: scattered trees and clumps at various distances.
            for _ in range(int(rng.integers(2, 9))):
                u = float(rng.uniform(start, end))
                lateral = side * float(rng.uniform(7.0, 60.0))
                _tree(builder, rng, point(u, lateral), ground_at(u, lateral))
    return Block(index=index, zone=zone, side_street_u=street_u, objects=builder.build())


def _tree(
    builder: _Builder, rng: np.random.Generator, centre: tuple[float, float], ground: float
) -> None:
    """Add a tree: a trunk cylinder and a wider crown cylinder above it."""
    trunk_top = ground + float(rng.uniform(2.0, 3.2))
    builder.cylinder(
        centre,
        float(rng.uniform(0.12, 0.3)),
        ground - 0.3,
        trunk_top + 0.5,
        Material.BARK,
        float(rng.uniform(50, 90)),
    )
    builder.cylinder(
        centre,
        float(rng.uniform(1.2, 2.8)),
        trunk_top,
        trunk_top + float(rng.uniform(3, 6)),
        Material.FOLIAGE,
        float(rng.uniform(55, 100)),
    )
