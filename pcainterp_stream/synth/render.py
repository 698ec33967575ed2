"""Column ray caster for the 2.5-D street world: image and z-depth of one pinhole view.

The camera is level (no pitch, no roll; it still climbs and turns with the road), so every
image column looks along one vertical plane. A pixel (c, r) has the ray
``C + z * (forward + a_c * right) + z * b_r * down`` with a_c = (c - cx)/fx and
b_r = (r - cy)/fy, parametrised by its optical-axis depth z. Hence:

* vertical extrusions are cut per column only (2-D ray against segment/circle footprints),
  each footprint only against the columns its projection spans (vectorised over those
  (column, object) pairs); a hit at depth z covers the image rows whose height
  ``C_z - z b_r`` lies between the object's bottom and top, an interval of rows. The nearest
  ``max_layers`` hits of each column are painted far to near.
* the ground is marched per column at geometrically spaced depths (vectorised over columns x
  samples, "voxel space" style); the running minimum of the projected ground rows is the
  visible envelope. Between two samples the ground is taken as planar, so inverse depth and
  lateral offset are linear in the row: every (column, sample interval) is a segment with
  its coefficients, and one ``np.repeat`` assigns every pixel its segment.

Textures are looked up at world surface coordinates, so the left and right views (the same
function, another camera centre) agree. The work is a fixed number of array operations per
pixel; there is no Python loop over pixels (the loop over at most ``max_layers`` depth layers
is over whole images).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth import textures
from pcainterp_stream.synth.world import (
    LANE_EDGE,
    MATERIAL_CAR_WINDOWS,
    MATERIAL_CONTRAST,
    MATERIAL_TILE,
    MATERIAL_WINDOWS,
    ROAD_HALF_WIDTH,
    SIDEWALK_WIDTH,
    BlockTable,
    RoadTable,
    World,
)

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

#: Texel size of level 0 of every tile (m).
TEXEL = 0.015
#: Macro-variation tile texel (m): breaks the repetition of the fine tiles.
MACRO_TEXEL = TEXEL * 19.0
#: Ground march: first sample depth (m), ratio between samples, number of samples.
_MARCH_START = 2.5
_MARCH_RATIO = 1.065
_MARCH_SAMPLES = 120  # reaches ~4.4 km
#: Objects are generated up to this far ahead along the road (m).
OBJECT_RANGE = 350.0
#: Nearest allowed hit (m).
_NEAR = 0.3
#: Mip bias in levels: positive blurs a little more than one texel per pixel.
_MIP_BIAS = 0.35
#: Atmospheric haze: brightness of the haze and the depth at which it is half mixed in (m).
_HAZE_GREY = 200.0
_HAZE_HALF_DEPTH = 900.0


def _march_depths() -> F64:
    """Return the ground march depths (m), by repeated multiplication (bit-reproducible)."""
    factors = np.full(_MARCH_SAMPLES, _MARCH_RATIO)
    factors[0] = _MARCH_START
    return np.cumprod(factors)


_DEPTHS = _march_depths()
#: Texel offset of each material's tile in the texture bank.
_MATERIAL_TILE_BASE = textures.tile_offset(MATERIAL_TILE)


@dataclass(frozen=True)
class View:
    """One rendered view.

    Attributes:
        image: (H, W) float32 grey level before sensor noise and quantisation (about 0..255).
        depth: (H, W) float32 z-depth (m), NaN where the ray sees sky.
    """

    image: F32
    depth: F32


#: Float32 bit pattern arithmetic of :func:`_mip_level`: adding this to the bits carries
#: into the exponent exactly when the mantissa 1.m >= sqrt(2), i.e. rounds log2 at sqrt(2).
_LOG2_ROUND = (1 << 23) - 3474676
_MIP_SCALE = 2.0**_MIP_BIAS / TEXEL


def _mip_level(footprint: F32) -> npt.NDArray[np.int32]:
    """Return the mip level round(log2(footprint / TEXEL) + bias), clipped to the pyramid.

    Args:
        footprint: (n,) float32 pixel footprint on the surface (m), > 0.

    Returns:
        (n,) int32 level in 0..TILE_LOG2, from the float32 exponent bits (exact, no log).
    """
    bits = (footprint * np.float32(_MIP_SCALE)).view(np.int32)
    bits += np.int32(_LOG2_ROUND)
    np.right_shift(bits, np.int32(23), out=bits)
    bits -= np.int32(127)
    np.clip(bits, np.int32(0), np.int32(textures.TILE_LOG2), out=bits)
    return bits


@functools.lru_cache(maxsize=4)
def _pixel_slopes(width: int, height: int, cy: float, fy: float) -> F32:
    """Return (W * H,) float32 downward ray slope (r - cy) / fy of every pixel, column-major."""
    slope = ((np.arange(height, dtype=np.float64) - cy) / fy).astype(np.float32)
    result: F32 = np.tile(slope, width)
    result.flags.writeable = False
    return result


@dataclass(frozen=True)
class _Ground:
    """The marched ground of one view, as straight row segments per column.

    Segment j = c * (K + 1) + k (k = 1..K-1) covers the rows of column c between march
    samples k - 1 and k; there inverse depth and lateral offset are linear in the row:
    ``value = value_{k-1} + (envelope_{k-1} - row) * slope``. Segment k = K of each column
    is the sky above its last sample (inverse depth 0).

    Attributes:
        segment: (W * H,) intp segment of every pixel, column-major.
        inverse: (W * (K + 1), 4) float32 per segment: envelope_{k-1} (row), inverse depth
            at k - 1 (1/m), its slope per row, 0.
        lateral: (W * (K + 1), 4) float32 per segment: lateral offset at k - 1 (m), its
            slope per row, and the column's ray direction x, y per unit depth.
    """

    segment: npt.NDArray[np.intp]
    inverse: F32
    lateral: F32


def _march_ground(
    world: World,
    camera: StereoCamera,
    centre: F64,
    ray_x: F64,
    ray_y: F64,
    table: RoadTable,
    blocks: BlockTable,
) -> _Ground:
    """March the ground along every column and cut it into straight row segments."""
    width, height = camera.width, camera.height
    cam_z = float(centre[2])
    sample_x = centre[0] + ray_x[:, None] * _DEPTHS  # (W, K)
    sample_y = centre[1] + ray_y[:, None] * _DEPTHS
    ground_z, ground_l = world.ground(table, blocks, sample_x, sample_y)
    envelope = camera.cy + camera.fy * (cam_z - ground_z) / _DEPTHS
    np.minimum.accumulate(envelope, axis=1, out=envelope)
    envelope[:, 0] = height + 1.0  # the first sample covers the bottom rows
    n_samples = _DEPTHS.shape[0]
    # Segment k (k >= 1) covers the rows ceil(envelope_k) .. ceil(envelope_{k-1}) - 1 of its
    # column (the envelope is non-increasing in k); the rows above the last sample are sky.
    # One np.repeat lays out every column top-down: sky, then segments K-1 .. 1.
    edges = np.clip(np.ceil(envelope), 0.0, float(height)).astype(np.intp)
    covered = np.empty((width, n_samples + 1), dtype=np.intp)
    covered[:, 0] = edges[:, -1]
    covered[:, 1:n_samples] = edges[:, -2::-1] - edges[:, :0:-1]
    covered[:, n_samples] = 0
    order = np.arange(width * (n_samples + 1), dtype=np.intp).reshape(width, n_samples + 1)
    segment = np.repeat(order[:, ::-1].ravel(), covered.ravel())

    span = np.maximum(envelope[:, :-1] - envelope[:, 1:], 1e-6)  # (W, K - 1)
    inverse_depth = 1.0 / _DEPTHS
    inverse = np.zeros((width, n_samples + 1, 4), dtype=np.float32)
    inverse[:, 1:n_samples, 0] = envelope[:, :-1]
    inverse[:, 1:n_samples, 1] = inverse_depth[:-1]
    inverse[:, 1:n_samples, 2] = (inverse_depth[1:] - inverse_depth[:-1]) / span
    lateral = np.zeros((width, n_samples + 1, 4), dtype=np.float32)
    lateral[:, 1:n_samples, 0] = ground_l[:, :-1]
    lateral[:, 1:n_samples, 1] = (ground_l[:, 1:] - ground_l[:, :-1]) / span
    lateral[:, :, 2] = ray_x[:, None]
    lateral[:, :, 3] = ray_y[:, None]
    return _Ground(
        segment=segment,
        inverse=inverse.reshape(-1, 4),
        lateral=lateral.reshape(-1, 4),
    )


def render_view(
    world: World,
    camera: StereoCamera,
    camera_to_world: F64,
    *,
    max_layers: int = 8,
) -> View:
    """Ray-cast one view of the world.

    Internally the image is processed column-major, (W, H), so that a column's pixels are
    contiguous; the result is transposed to (H, W) at the end.

    Args:
        world: the procedural world.
        camera: intrinsics (the baseline is not used here).
        camera_to_world: (4, 4) float64 pose of this camera's optical frame (x right, y down,
            z forward) in the world frame (z up); must be level: y axis = (0, 0, -1).
        max_layers: vertical-object hits kept per image column (nearest first).

    Returns:
        The view's image and depth.

    Raises:
        ValueError: if the pose is not a level (4, 4) transform.
    """
    pose = np.asarray(camera_to_world, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"Expected camera_to_world of shape (4, 4), got {pose.shape}")
    if abs(pose[2, 1] + 1.0) > 1e-9:
        raise ValueError("camera_to_world must be level: its y axis must be (0, 0, -1)")
    width, height = camera.width, camera.height
    centre = pose[:3, 3]
    right = pose[:3, 0]
    forward = pose[:3, 2]
    cam_z = float(centre[2])

    column = np.arange(width, dtype=np.float64)
    slope_x = (column - camera.cx) / camera.fx
    ray_x = forward[0] + slope_x * right[0]  # (W,) horizontal direction per unit depth
    ray_y = forward[1] + slope_x * right[1]
    row = np.arange(height, dtype=np.float64)

    # ------------------------------------------------------------------ ground
    reach_x = centre[0] + np.concatenate([ray_x * _DEPTHS[0], ray_x * _DEPTHS[-1]])
    x_low, x_high = float(reach_x.min()) - 2.0, float(reach_x.max()) + 2.0
    table = world.road_table(x_low, x_high)
    blocks = world.block_table(x_low, x_high)
    ground = _march_ground(world, camera, centre, ray_x, ray_y, table, blocks)
    fields = np.take(ground.inverse, ground.segment, axis=0)  # (W * H, 4)
    # Rows below the envelope row of the segment's upper sample, per pixel (>= 0).
    below = fields[:, 0].reshape(width, height) - row.astype(np.float32)
    inverse = below * fields[:, 2].reshape(width, height)
    inverse += fields[:, 1].reshape(width, height)
    with np.errstate(divide="ignore"):
        depth = np.reciprocal(inverse).ravel()  # +inf where the column sees sky
    below = below.ravel()
    del fields, inverse

    # ------------------------------------------------------------------ vertical objects
    layers = _object_layers(world, camera, centre, right, forward, ray_x, ray_y, max_layers)
    is_object: npt.NDArray[np.bool_] | None = None
    layer_index: npt.NDArray[np.intp] | None = None
    if layers is not None:
        n_layers = layers.depth.shape[1] - 1
        with np.errstate(divide="ignore", invalid="ignore"):
            top_row = np.ceil(camera.cy + camera.fy * (cam_z - layers.top) / layers.depth)
            bottom_row = np.floor(camera.cy + camera.fy * (cam_z - layers.bottom) / layers.depth)
        finite = np.isfinite(layers.depth)
        top_row = np.clip(np.where(finite, top_row, height), -1, height).astype(np.int16)
        bottom_row = np.clip(np.where(finite, bottom_row, -1), -1, height).astype(np.int16)
        # Layer k covers rows top_k .. bottom_k: (row - top_k) as uint16 <= bottom_k - top_k
        # (empty layers get top = height + 1, so the difference wraps to a large number).
        empty = bottom_row < top_row
        top_row[empty] = height + 1
        extent = np.where(empty, 0, bottom_row - top_row).astype(np.uint16)
        row_index = np.arange(height, dtype=np.int16)[None, :]
        # Paint far to near: the nearest covering layer wins; n_layers is "no object".
        nearest = np.full((width, height), n_layers, dtype=np.uint8)
        offset = np.empty((width, height), dtype=np.int16)
        for k in range(n_layers - 1, -1, -1):
            np.subtract(row_index, top_row[:, k : k + 1], out=offset)
            covered = offset.view(np.uint16) <= extent[:, k : k + 1]
            np.copyto(nearest, np.uint8(k), where=covered)
        layer_index = np.add(
            (np.arange(width, dtype=np.intp) * (n_layers + 1))[:, None], nearest, dtype=np.intp
        ).ravel()
        depth_object = np.take(layers.depth.astype(np.float32).ravel(), layer_index)
        is_object = depth_object < depth
        np.copyto(depth, depth_object, where=is_object)
        del depth_object, nearest, offset
    sky = np.isinf(depth)

    illumination = world.illumination
    image = np.empty(width * height, dtype=np.float32)
    sky_row = illumination.sky_top + (illumination.sky_horizon - illumination.sky_top) * np.clip(
        row / max(camera.cy, 1.0), 0.0, 1.0
    )
    sky_pixels = np.flatnonzero(sky)
    image[sky_pixels] = np.take(np.tile(sky_row.astype(np.float32), width), sky_pixels)

    # ------------------------------------------------------------------ ground pixels
    ground_mask = ~sky if is_object is None else ~(is_object | sky)
    ground_pixels = np.flatnonzero(ground_mask)
    if ground_pixels.size:
        z = np.take(depth, ground_pixels)
        g_below = np.take(below, ground_pixels)
        lateral_fields = np.take(ground.lateral, np.take(ground.segment, ground_pixels), axis=0)
        lateral = lateral_fields[:, 0] + g_below * lateral_fields[:, 1]
        rel_x = z * lateral_fields[:, 2]
        rel_y = z * lateral_fields[:, 3]
        image[ground_pixels] = _shade_ground(
            world, blocks, centre, camera, z, rel_x, rel_y, lateral
        )

    # ------------------------------------------------------------------ object pixels
    if layers is not None and is_object is not None and layer_index is not None:
        object_pixels = np.flatnonzero(is_object)
        if object_pixels.size:
            attributes = np.take(layers.shading, np.take(layer_index, object_pixels), axis=0)
            z = np.take(depth, object_pixels)
            slope = np.take(_pixel_slopes(width, height, camera.cy, camera.fy), object_pixels)
            image[object_pixels] = _shade_objects(world, cam_z, z, slope, attributes)

    depth[sky_pixels] = np.nan
    return View(
        image=np.ascontiguousarray(image.reshape(width, height).T),
        depth=np.ascontiguousarray(depth.reshape(width, height).T),
    )


def _shade_objects(world: World, cam_z: float, depth: F32, slope: F32, attributes: F32) -> F32:
    """Grey level of pixels on vertical surfaces: texture, windows, lighting and haze.

    Args:
        world: the world (textures, lighting).
        cam_z: camera height in the world (m).
        depth: (n,) float32 z-depth of the pixels (m).
        slope: (n,) float32 downward ray slope (row - cy) / fy of the pixels.
        attributes: (n, 8) float32 ``_Layers.shading`` rows of the pixels' layers.

    Returns:
        (n,) float32 grey levels.
    """
    surface_u = attributes[:, 0]
    height_world = np.float32(cam_z) - depth * slope
    footprint = depth * attributes[:, 1]
    level = _mip_level(footprint)
    tile_base = attributes[:, 7].astype(np.int64)
    s_coord = surface_u * np.float32(1.0 / TEXEL)
    t_coord = height_world * np.float32(1.0 / TEXEL)
    texture = _texture(world.textures, tile_base, s_coord, t_coord, level)
    texture *= attributes[:, 5]
    grey = texture
    grey += attributes[:, 2]
    height_world -= attributes[:, 4]
    dark = _windows(attributes[:, 6], surface_u, height_world, footprint)
    dark *= grey - np.float32(35.0)
    grey -= dark
    grey *= attributes[:, 3]
    return _haze(grey, depth)


def _haze(grey: F32, depth: F32) -> F32:
    """Mix distant surfaces towards the haze grey (atmospheric perspective)."""
    amount = depth / (depth + np.float32(_HAZE_HALF_DEPTH))
    result: F32 = grey + amount * (np.float32(_HAZE_GREY) - grey)
    return result


_MACRO_BASE = int(textures.tile_offset(textures.TILE_MACRO))
_MACRO_SCALE = TEXEL / MACRO_TEXEL


def _texture(
    bank: textures.TextureBank,
    tile_base: npt.NDArray[np.int64],
    s_coord: F32,
    t_coord: F32,
    level: npt.NDArray[np.int32],
) -> F32:
    """Fine tile plus the macro-variation tile at the same surface point.

    Args:
        bank: the world's tiles.
        tile_base: (n,) int64 ``textures.tile_offset`` of each point's fine tile.
        s_coord: (n,) float32 first surface coordinate (level-0 texels).
        t_coord: (n,) float32 second surface coordinate (level-0 texels).
        level: (n,) int32 mip level of the fine tile.

    Returns:
        (n,) float32 texture value (about -4..4).
    """
    fine = bank.sample(tile_base, s_coord, t_coord, level)
    scale = np.float32(_MACRO_SCALE)
    macro_level = level - np.int32(4)
    np.maximum(macro_level, np.int32(0), out=macro_level)
    macro = bank.sample(_MACRO_BASE, s_coord * scale, t_coord * scale, macro_level)
    macro *= np.float32(0.8)
    fine += macro
    return fine


def _shade_ground(
    world: World,
    blocks: BlockTable,
    centre: F64,
    camera: StereoCamera,
    depth: F32,
    rel_x: F32,
    rel_y: F32,
    lateral: F32,
) -> F32:
    """Grey level of ground pixels: asphalt with markings, pavement and kerb, grass.

    Args:
        world: the world (textures, lighting).
        blocks: block table covering the pixels.
        centre: (3,) float64 camera centre (m).
        camera: intrinsics.
        depth: (n,) float32 z-depth of the pixels (m).
        rel_x: (n,) float32 world x of the ground point minus the camera's (m).
        rel_y: (n,) float32 same for y.
        lateral: (n,) float32 lateral road coordinate (m).

    Returns:
        (n,) float32 grey levels.
    """
    period = textures.TILE_SIZE * TEXEL
    origin_x = np.float32(np.fmod(centre[0], period))
    origin_y = np.float32(np.fmod(centre[1], period))
    s_coord = (rel_x + origin_x) * np.float32(1.0 / TEXEL)
    t_coord = (rel_y + origin_y) * np.float32(1.0 / TEXEL)
    along = rel_x + np.float32(centre[0])  # the along-road coordinate u
    distance = np.abs(lateral)
    # Sidewalk and side-street flags change only at whole metres (block and street edges):
    # tabulate them per metre of u and look them up once.
    u_first = float(np.floor(along.min()))
    metres = u_first + 0.5 + np.arange(int(along.max() - u_first) + 1, dtype=np.float64)
    flags = (blocks.has_sidewalk(metres) > 0) + 2 * blocks.in_side_street(metres).astype(np.uint8)
    cell = np.take(flags.astype(np.uint8), (along - np.float32(u_first)).astype(np.intp))
    sidewalk_zone = (cell & 1).view(np.bool_)
    side_street = (cell >> 1).view(np.bool_)
    on_road = distance < ROAD_HALF_WIDTH
    on_pavement = sidewalk_zone & (distance < ROAD_HALF_WIDTH + SIDEWALK_WIDTH)
    # ASPHALT = 0, PAVEMENT = 1, GRASS = 2.
    paved = on_road | side_street
    material = (~paved) * (2 - on_pavement.astype(np.intp))
    footprint = depth * np.float32(1.0 / camera.fx)
    level = _mip_level(footprint)
    texture = _texture(
        world.textures, np.take(_MATERIAL_TILE_BASE, material), s_coord, t_coord, level
    )
    albedo = np.take(np.array([95.0, 135.0, 105.0], dtype=np.float32), material)
    grey = albedo + np.take(MATERIAL_CONTRAST, material) * texture
    # Lane markings and kerb stones, anti-aliased by coverage of the pixel footprint.
    inv_foot = np.float32(1.0) / footprint
    centre_line = np.clip((np.float32(0.06) - distance) * inv_foot + np.float32(0.5), 0.0, 1.0)
    dash_phase = along * np.float32(1.0 / 9.0)
    dashes = dash_phase - np.floor(dash_phase) < np.float32(1.0 / 3.0)
    edge_line = np.clip(
        (np.float32(0.08) - np.abs(distance - np.float32(LANE_EDGE))) * inv_foot + np.float32(0.5),
        0.0,
        1.0,
    )
    kerb = np.clip(
        (np.float32(0.18) - np.abs(distance - np.float32(ROAD_HALF_WIDTH + 0.1))) * inv_foot
        + np.float32(0.5),
        0.0,
        1.0,
    )
    paint = (on_road & ~side_street) * (centre_line * dashes + edge_line)
    paint += sidewalk_zone * (kerb * np.float32(0.35))
    grey += paint * (np.float32(215.0) - grey)
    illumination = world.illumination
    ground_shade = illumination.ambient + (1.0 - illumination.ambient) * illumination.sun[2]
    grey *= np.float32(ground_shade * illumination.gain)
    return _haze(grey, depth)


def _windows(kind: F32, surface_u: F32, height_above_bottom: F32, footprint: F32) -> F32:
    """Darkness (0..1) of windows on facades and car glass at the given surface points.

    Args:
        kind: (n,) float32 window pattern per point: 0 none, 1 facade, 2 car.
        surface_u: (n,) float32 m along the surface.
        height_above_bottom: (n,) float32 m above the object's bottom.
        footprint: (n,) float32 pixel footprint along the surface (m), for anti-aliasing.

    Returns:
        (n,) float32 amount of window (dark glass) per point.
    """
    inv_foot = np.maximum(footprint, np.float32(1e-4))
    np.reciprocal(inv_foot, out=inv_foot)
    # Facades: a grid of 1.4 m x 1.5 m windows, 3.2 m apart, floors of 3 m above 3 m.
    phase_u = surface_u * np.float32(1.0 / 3.2)
    phase_u -= np.floor(phase_u)
    phase_u -= np.float32(0.5)
    offset_u = np.abs(phase_u, out=phase_u)
    offset_u *= np.float32(-3.2)
    offset_u += np.float32(0.7)
    offset_u *= inv_foot
    offset_u += np.float32(0.5)
    cover_u: F32 = np.clip(offset_u, np.float32(0.0), np.float32(1.0), out=offset_u)
    phase_v = height_above_bottom * np.float32(1.0 / 3.0)
    phase_v -= np.floor(phase_v)
    in_floor = (phase_v > np.float32(0.35)) & (phase_v < np.float32(0.85))
    in_floor &= height_above_bottom > np.float32(3.0)
    in_floor &= kind == np.float32(1.0)
    cover_u *= in_floor
    cover_u *= np.float32(0.75)
    # Cars: a glass band in the upper part of the body (bottom is 0.3 m below ground).
    car = (height_above_bottom > np.float32(1.3)) & (height_above_bottom < np.float32(1.75))
    car &= kind == np.float32(2.0)
    cover_u += car * np.float32(0.8)
    result: F32 = cover_u
    return result


@dataclass(frozen=True)
class _Layers:
    """Per-column nearest object hits, nearest first, plus one empty layer at the end.

    Attributes:
        depth: (W, L + 1) float64 hit depth (m), +inf for no hit (always so in layer L).
        top: (W, L + 1) float64 object top height (m).
        bottom: (W, L + 1) float64 object bottom height (m).
        shading: (W * (L + 1), 8) float32 per layer: metres along the surface, footprint
            per unit depth (m/m), albedo, lighting (shade x exposure gain), bottom height,
            texture contrast, window kind (0 none, 1 facade, 2 car), tile offset.
    """

    depth: F64
    top: F64
    bottom: F64
    shading: F32


#: Window kind per material (0 none, 1 facade, 2 car), see :func:`_windows`.
_WINDOW_KIND = (MATERIAL_WINDOWS + 2.0 * MATERIAL_CAR_WINDOWS).astype(np.float32)


def _column_span(
    side_a: F64, depth_a: F64, side_b: F64, depth_b: F64, camera: StereoCamera
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """First and last image column (inclusive, one column of margin) between two directions.

    Both directions must be in front of the camera (depth > 0); the span is empty
    (first > last) when it misses the image.
    """
    column_a = camera.cx + camera.fx * side_a / depth_a
    column_b = camera.cx + camera.fx * side_b / depth_b
    low = np.clip(np.floor(np.minimum(column_a, column_b)) - 1.0, -1.0, camera.width)
    high = np.clip(np.ceil(np.maximum(column_a, column_b)) + 1.0, -1.0, camera.width)
    first = np.maximum(low, 0.0).astype(np.intp)
    last = np.minimum(high, camera.width - 1.0).astype(np.intp)
    return first, last


def _object_layers(
    world: World,
    camera: StereoCamera,
    centre: F64,
    right: F64,
    forward: F64,
    ray_x: F64,
    ray_y: F64,
    max_layers: int,
) -> _Layers | None:
    """Intersect every column's horizontal ray with the object footprints near the camera.

    Each footprint is only tested against the image columns its projection spans (one
    (column, object) pair per entry, vectorised); the hits are sorted by (column, depth)
    and the ``max_layers`` nearest of every column get their surface attributes.
    """
    objects = world.objects(float(centre[0]) - 30.0, float(centre[0]) + OBJECT_RANGE)
    sun = world.illumination.sun
    ambient = world.illumination.ambient
    width = camera.width
    fwd = forward[:2]
    side_axis = right[:2]

    # Segments: clip to the half plane depth >= _NEAR, then the columns they span.
    start = objects.seg_start - centre[:2]
    end = objects.seg_end - centre[:2]
    depth_a, depth_b = start @ fwd, end @ fwd
    side_a, side_b = start @ side_axis, end @ side_axis
    seen = np.maximum(depth_a, depth_b) > _NEAR
    clip_a = seen & (depth_a < _NEAR)
    clip_b = seen & (depth_b < _NEAR)
    # Where an end is clipped the depths differ, so the cut is finite; elsewhere unused.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        cut = (_NEAR - depth_a) / (depth_b - depth_a)
        side_cut = side_a + cut * (side_b - side_a)
    side_a = np.where(clip_a, side_cut, side_a)
    side_b = np.where(clip_b, side_cut, side_b)
    depth_a = np.where(clip_a | ~seen, _NEAR, depth_a)
    depth_b = np.where(clip_b | ~seen, _NEAR, depth_b)
    seg_first, seg_last = _column_span(side_a, depth_a, side_b, depth_b, camera)
    seg_last = np.where(seen, seg_last, -1)

    # Cylinders: columns of the footprint's bounding box (all columns when it is close).
    offset = objects.cyl_centre - centre[:2]
    radius = objects.cyl_radius
    cyl_depth_c = offset @ fwd
    cyl_side = offset @ side_axis
    near_edge = cyl_depth_c - radius
    close = near_edge <= _NEAR
    far_edge = cyl_depth_c + radius
    # Placeholders 1.0 where the span is replaced below (close or behind the camera).
    safe_near = np.where(close, 1.0, near_edge)
    safe_far = np.where(close, 1.0, far_edge)
    low_side, high_side = cyl_side - radius, cyl_side + radius
    cyl_first, cyl_last = _column_span(
        low_side,
        np.where(low_side < 0.0, safe_near, safe_far),
        high_side,
        np.where(high_side > 0.0, safe_near, safe_far),
        camera,
    )
    cyl_first = np.where(close, 0, cyl_first)
    cyl_last = np.where(close, width - 1, cyl_last)
    cyl_last = np.where(far_edge > _NEAR, cyl_last, -1)

    n_seg = start.shape[0]
    first = np.concatenate([seg_first, cyl_first])
    counts = np.maximum(np.concatenate([seg_last, cyl_last]) - first + 1, 0)
    n_pairs = int(counts.sum())
    if n_pairs == 0:
        return None
    owner = np.repeat(np.arange(counts.shape[0], dtype=np.intp), counts)
    pair_column = np.arange(n_pairs, dtype=np.intp)
    pair_column -= np.repeat(np.cumsum(counts) - counts - first, counts)
    rx = ray_x[pair_column]
    ry = ray_y[pair_column]
    hit_depth = np.full(n_pairs, np.inf)
    # Segment pairs: solve C + z h = P0 + t E for (z, t) by Cramer's rule.
    is_seg_pair = owner < n_seg
    n_seg_pairs = int(np.count_nonzero(is_seg_pair))  # segments come first
    if n_seg_pairs:
        j = owner[:n_seg_pairs]
        sx, sy = start[j, 0], start[j, 1]
        ex, ey = end[j, 0] - sx, end[j, 1] - sy
        srx, sry = rx[:n_seg_pairs], ry[:n_seg_pairs]
        with np.errstate(divide="ignore", invalid="ignore"):
            det = sry * ex - srx * ey
            seg_depth = (sy * ex - sx * ey) / det
            along = (srx * sy - sry * sx) / det
        ok = (along >= 0.0) & (along <= 1.0) & (seg_depth > _NEAR)
        hit_depth[:n_seg_pairs] = np.where(ok, seg_depth, np.inf)
    if n_pairs > n_seg_pairs:
        j = owner[n_seg_pairs:] - n_seg
        ox, oy = offset[j, 0], offset[j, 1]
        crx, cry = rx[n_seg_pairs:], ry[n_seg_pairs:]
        norm_sq = crx * crx + cry * cry
        along_c = crx * ox + cry * oy
        quad_c = (ox * ox + oy * oy) - radius[j] * radius[j]
        disc = along_c * along_c - norm_sq * quad_c
        cyl_depth = (along_c - np.sqrt(np.maximum(disc, 0.0))) / norm_sq
        ok = (disc > 0) & (cyl_depth > _NEAR)
        hit_depth[n_seg_pairs:] = np.where(ok, cyl_depth, np.inf)

    hits = np.flatnonzero(np.isfinite(hit_depth))
    if hits.size == 0:
        return None
    hit_column = pair_column[hits]
    order = np.lexsort((hit_depth[hits], hit_column))
    hits = hits[order]
    hit_column = hit_column[order]
    per_column = np.bincount(hit_column, minlength=width)
    n_layers = min(max_layers, int(per_column.max()))
    rank = np.arange(hits.size, dtype=np.intp) - (np.cumsum(per_column) - per_column)[hit_column]
    keep = rank < n_layers
    hits, hit_column, rank = hits[keep], hit_column[keep], rank[keep]
    slot = hit_column * (n_layers + 1) + rank

    z = hit_depth[hits]
    hx, hy = rx[hits], ry[hits]
    hit_x, hit_y = z * hx, z * hy
    who = owner[hits]
    is_seg = who < n_seg
    seg_i = np.where(is_seg, who, 0)
    cyl_i = np.where(is_seg, 0, who - n_seg)
    if n_seg:
        p0 = start[seg_i]
        e = end[seg_i] - p0
        length = np.sqrt((e * e).sum(axis=1))
        t = ((hit_x - p0[:, 0]) * e[:, 0] + (hit_y - p0[:, 1]) * e[:, 1]) / np.maximum(
            length * length, 1e-12
        )
        seg_u = objects.seg_u0[seg_i] + t * length
        seg_nx = e[:, 1] / np.maximum(length, 1e-9)
        seg_ny = -e[:, 0] / np.maximum(length, 1e-9)
    else:
        seg_u = seg_nx = seg_ny = np.zeros_like(z)
    if offset.shape[0]:
        rho = radius[cyl_i]
        cyl_nx = (hit_x - offset[cyl_i, 0]) / rho
        cyl_ny = (hit_y - offset[cyl_i, 1]) / rho
        # Pseudo-angle (exact arithmetic), seam facing +x (away from the approaching camera).
        away = -cyl_nx
        total = np.abs(away) + np.abs(cyl_ny) + 1e-12
        pseudo = np.where(
            away >= 0, cyl_ny / total, np.sign(cyl_ny) * (2.0 - np.abs(cyl_ny) / total)
        )
        cyl_u = pseudo * rho * (np.pi / 2.0) + objects.cyl_albedo[cyl_i] * 3.7
    else:
        cyl_u = cyl_nx = cyl_ny = np.zeros_like(z)
    normal_x = np.where(is_seg, seg_nx, cyl_nx)
    normal_y = np.where(is_seg, seg_ny, cyl_ny)
    # Turn segment normals towards the camera (the ray comes from the camera: n.h < 0).
    flip = np.where(normal_x * hx + normal_y * hy > 0, -1.0, 1.0)
    normal_x *= flip
    normal_y *= flip
    cos = np.abs(normal_x * hx + normal_y * hy) / np.sqrt(hx * hx + hy * hy)
    shade = ambient + (1.0 - ambient) * np.maximum(normal_x * sun[0] + normal_y * sun[1], 0.0)

    def pick(seg_values: npt.NDArray[np.generic], cyl_values: npt.NDArray[np.generic]) -> F64:
        if not n_seg:
            return cyl_values[cyl_i].astype(np.float64)
        if not offset.shape[0]:
            return seg_values[seg_i].astype(np.float64)
        result: F64 = np.where(is_seg, seg_values[seg_i], cyl_values[cyl_i]).astype(np.float64)
        return result

    def layer_table(values: F64, fill: float) -> F64:
        table = np.full(width * (n_layers + 1), fill)
        table[slot] = values
        return table.reshape(width, n_layers + 1)

    material = pick(objects.seg_material, objects.cyl_material).astype(np.intp)
    shading = np.zeros((width * (n_layers + 1), 8), dtype=np.float32)
    shading[slot] = np.stack(
        [
            np.where(is_seg, seg_u, cyl_u),
            1.0 / (camera.fx * np.maximum(cos, 0.12)),
            pick(objects.seg_albedo, objects.cyl_albedo),
            shade * world.illumination.gain,
            pick(objects.seg_bottom, objects.cyl_bottom),
            MATERIAL_CONTRAST[material],
            _WINDOW_KIND[material],
            _MATERIAL_TILE_BASE[material],
        ],
        axis=1,
    )
    return _Layers(
        depth=layer_table(z, np.inf),
        top=layer_table(pick(objects.seg_top, objects.cyl_top), 0.0),
        bottom=layer_table(pick(objects.seg_bottom, objects.cyl_bottom), 0.0),
        shading=shading,
    )
