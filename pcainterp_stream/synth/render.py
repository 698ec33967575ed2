"""Column ray caster for the 2.5-D street world: image and z-depth of one pinhole view.

The camera is level (no pitch, no roll; it still climbs and turns with the road), so every
image column looks along one vertical plane. A pixel (c, r) has the ray
``C + z * (forward + a_c * right) + z * b_r * down`` with a_c = (c - cx)/fx and
b_r = (r - cy)/fy, parametrised by its optical-axis depth z. Hence:

* vertical extrusions are cut per column only (2-D ray against segment/circle footprints,
  vectorised over columns x objects); a hit at depth z covers the image rows whose height
  ``C_z - z b_r`` lies between the object's bottom and top, an interval of rows. The nearest
  ``max_layers`` hits of each column are painted far to near.
* the ground is marched per column at geometrically spaced depths (vectorised over columns x
  samples, "voxel space" style); the running minimum of the projected ground rows is the
  visible envelope, and every pixel row is located in its column's envelope by one global
  ``searchsorted``; inverse depth is interpolated between the two samples, which is exact for
  planar ground.

Textures are looked up at world surface coordinates, so the left and right views (the same
function, another camera centre) agree. The work is a fixed number of array operations per
pixel; there is no Python loop over pixels (the loop over at most ``max_layers`` depth layers
is over whole images).
"""

from __future__ import annotations

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
    Material,
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


def _column_of_pixel(width: int, height: int) -> npt.NDArray[np.intp]:
    """Return the column index of every pixel of a (W, H) column-major image, flattened."""
    return np.repeat(np.arange(width, dtype=np.intp), height)


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
    n_pixels = width * height
    centre = pose[:3, 3]
    right = pose[:3, 0]
    forward = pose[:3, 2]
    cam_z = float(centre[2])

    column = np.arange(width, dtype=np.float64)
    slope_x = (column - camera.cx) / camera.fx
    ray_x = forward[0] + slope_x * right[0]  # (W,) horizontal direction per unit depth
    ray_y = forward[1] + slope_x * right[1]
    row = np.arange(height, dtype=np.float64)
    slope_y = (row - camera.cy) / camera.fy  # (H,) downward rise per unit depth

    # ------------------------------------------------------------------ ground march
    sample_x = centre[0] + ray_x[:, None] * _DEPTHS  # (W, K)
    sample_y = centre[1] + ray_y[:, None] * _DEPTHS
    x_low, x_high = float(sample_x.min()) - 2.0, float(sample_x.max()) + 2.0
    table = world.road_table(x_low, x_high)
    blocks = world.block_table(x_low, x_high)
    ground_z, ground_l = world.ground(table, blocks, sample_x, sample_y)
    envelope = camera.cy + camera.fy * (cam_z - ground_z) / _DEPTHS
    np.minimum.accumulate(envelope, axis=1, out=envelope)
    envelope[:, 0] = height + 1.0  # the first sample covers the bottom rows
    n_samples = _DEPTHS.shape[0]
    # Sample k (k >= 1) covers the rows ceil(envelope_k) .. ceil(envelope_{k-1}) - 1 of its
    # column (the envelope is non-increasing in k); rows above the last sample are sky and
    # get the sentinel index n_samples. One np.repeat lays out every column bottom-up.
    edges = np.clip(np.ceil(envelope), 0.0, float(height)).astype(np.intp)
    covered = np.empty((width, n_samples + 1), dtype=np.intp)
    covered[:, 0] = 0
    covered[:, 1:n_samples] = edges[:, :-1] - edges[:, 1:]
    covered[:, n_samples] = edges[:, -1]
    sample_of_row = np.repeat(
        np.tile(np.arange(n_samples + 1, dtype=np.intp), width), covered.ravel()
    ).reshape(width, height)[:, ::-1]
    ground_sky = sample_of_row == n_samples
    upper = (
        np.minimum(sample_of_row, n_samples - 1)
        + (np.arange(width, dtype=np.intp) * n_samples)[:, None]
    )
    lower = upper - 1
    # One gather of (envelope row, inverse depth, lateral) for both bracketing samples.
    fields = np.stack(
        [
            envelope.ravel(),
            np.tile(1.0 / _DEPTHS, width),
            ground_l.ravel(),
        ],
        axis=1,
    ).astype(np.float32)
    low_fields = np.take(fields, lower.ravel(), axis=0)
    high_fields = np.take(fields, upper.ravel(), axis=0)
    span = low_fields[:, 0] - high_fields[:, 0]
    row_f32 = np.tile(row.astype(np.float32), width)
    weight = (low_fields[:, 0] - row_f32) / np.maximum(span, np.float32(1e-6))
    inverse_depth = low_fields[:, 1] + weight * (high_fields[:, 1] - low_fields[:, 1])
    # +0 (depth +inf) where the column sees no ground; abs turns a -0 into +0.
    inverse_depth = np.abs(inverse_depth * ~ground_sky.ravel())
    with np.errstate(divide="ignore"):
        depth = np.float32(1.0) / inverse_depth

    # ------------------------------------------------------------------ vertical objects
    layers = _object_layers(world, camera, centre, forward, ray_x, ray_y, max_layers)
    is_object = np.zeros(n_pixels, dtype=bool)
    layer_index = np.zeros(n_pixels, dtype=np.intp)
    if layers is not None:
        n_layers = layers.depth.shape[1] - 1
        with np.errstate(divide="ignore", invalid="ignore"):
            top_row = np.ceil(camera.cy + camera.fy * (cam_z - layers.top) / layers.depth)
            bottom_row = np.floor(camera.cy + camera.fy * (cam_z - layers.bottom) / layers.depth)
        finite = np.isfinite(layers.depth)
        top_row = np.clip(np.where(finite, top_row, height), -1, height).astype(np.int16)
        bottom_row = np.clip(np.where(finite, bottom_row, -1), -1, height).astype(np.int16)
        row_index = np.arange(height, dtype=np.int16)[None, :]
        # The nearest covering layer k wins: nearest = n_layers - max_k covered_k (n_layers - k).
        closeness = np.zeros((width, height), dtype=np.uint8)
        for k in range(n_layers):
            covered = (row_index >= top_row[:, k : k + 1]) & (row_index <= bottom_row[:, k : k + 1])
            np.maximum(closeness, covered * np.uint8(n_layers - k), out=closeness)
        layer_index = (
            (n_layers - closeness.astype(np.intp))
            + (np.arange(width, dtype=np.intp) * (n_layers + 1))[:, None]
        ).ravel()
        depth_object = np.take(layers.depth.astype(np.float32).ravel(), layer_index)
        is_object = depth_object < depth
        np.copyto(depth, depth_object, where=is_object)
    sky = np.isinf(depth)

    column_of = _column_of_pixel(width, height)
    illumination = world.illumination
    bank = world.textures
    image = np.empty(n_pixels, dtype=np.float32)
    sky_row = illumination.sky_top + (illumination.sky_horizon - illumination.sky_top) * np.clip(
        row / max(camera.cy, 1.0), 0.0, 1.0
    )
    sky_pixels = np.flatnonzero(sky)
    image[sky_pixels] = np.tile(sky_row.astype(np.float32), width)[sky_pixels]

    # ------------------------------------------------------------------ ground pixels
    ground_pixels = np.flatnonzero(~(is_object | sky))
    if ground_pixels.size:
        z = np.take(depth, ground_pixels)
        columns = np.take(column_of, ground_pixels)
        g_weight = np.take(weight, ground_pixels)
        lat_low = np.take(low_fields[:, 2], ground_pixels)
        lateral = lat_low + g_weight * (np.take(high_fields[:, 2], ground_pixels) - lat_low)
        rel_x = z * np.take(ray_x.astype(np.float32), columns)
        rel_y = z * np.take(ray_y.astype(np.float32), columns)
        image[ground_pixels] = _shade_ground(
            world, blocks, centre, camera, z, rel_x, rel_y, lateral
        )

    # ------------------------------------------------------------------ object pixels
    object_pixels = np.flatnonzero(is_object)
    if layers is not None and object_pixels.size:
        # One gather of every per-layer attribute the pixels need.
        attributes = np.take(
            np.stack(
                [
                    layers.surface_u,
                    layers.foot_scale,
                    layers.albedo,
                    layers.shade,
                    layers.bottom,
                    layers.material,
                ],
                axis=2,
            )
            .astype(np.float32)
            .reshape(-1, 6),
            np.take(layer_index, object_pixels),
            axis=0,
        )
        surface_u = attributes[:, 0]
        material = attributes[:, 5].astype(np.intp)
        z = np.take(depth, object_pixels)
        rows = object_pixels - np.take(column_of, object_pixels) * height
        height_world = np.float32(cam_z) - z * np.take(slope_y.astype(np.float32), rows)
        footprint = z * attributes[:, 1]
        level = _mip_level(footprint)
        s_coord = surface_u * np.float32(1.0 / TEXEL)
        t_coord = height_world * np.float32(1.0 / TEXEL)
        texture = _texture(bank, np.take(_MATERIAL_TILE_BASE, material), s_coord, t_coord, level)
        grey = attributes[:, 2] + np.take(MATERIAL_CONTRAST, material) * texture
        windowed = np.flatnonzero(np.take(MATERIAL_WINDOWS + MATERIAL_CAR_WINDOWS, material))
        if windowed.size:
            dark = _windows(
                material[windowed],
                surface_u[windowed],
                height_world[windowed] - attributes[windowed, 4],
                footprint[windowed],
            )
            grey[windowed] -= dark * (grey[windowed] - np.float32(35.0))
        grey *= attributes[:, 3] * np.float32(illumination.gain)
        image[object_pixels] = _haze(grey, z)

    depth[sky_pixels] = np.nan
    return View(
        image=np.ascontiguousarray(image.reshape(width, height).T),
        depth=np.ascontiguousarray(depth.reshape(width, height).T),
    )


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
    sidewalk_zone = blocks.has_sidewalk(along) > 0
    side_street = blocks.in_side_street(along)
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


def _windows(
    material: npt.NDArray[np.intp],
    surface_u: F32,
    height_above_bottom: F32,
    footprint: F32,
) -> F32:
    """Darkness (0..1) of windows on facades and car glass at the given surface points.

    Args:
        material: (n,) material per point.
        surface_u: (n,) float32 m along the surface.
        height_above_bottom: (n,) float32 m above the object's bottom.
        footprint: (n,) float32 pixel footprint along the surface (m), for anti-aliasing.

    Returns:
        (n,) float32 amount of window (dark glass) per point.
    """
    inv_foot = np.float32(1.0) / np.maximum(footprint, np.float32(1e-4))
    # Facades: a grid of 1.4 m x 1.5 m windows, 3.2 m apart, floors of 3 m above 3 m.
    phase_u = surface_u * np.float32(1.0 / 3.2)
    offset_u = np.abs(phase_u - np.floor(phase_u) - np.float32(0.5)) * np.float32(3.2)
    cover_u = np.clip((np.float32(0.7) - offset_u) * inv_foot + np.float32(0.5), 0.0, 1.0)
    phase_v = height_above_bottom * np.float32(1.0 / 3.0)
    frac_v = phase_v - np.floor(phase_v)
    in_floor = (frac_v > 0.35) & (frac_v < 0.85) & (height_above_bottom > 3.0)
    facade = cover_u * in_floor * np.float32(0.75)
    # Cars: a glass band in the upper part of the body (bottom is 0.3 m below ground).
    car = ((height_above_bottom > 1.3) & (height_above_bottom < 1.75)) * np.float32(0.8)
    is_car = material == Material.CAR
    return np.where(is_car, car, facade).astype(np.float32)


@dataclass(frozen=True)
class _Layers:
    """Per-column nearest object hits, nearest first, plus one empty layer at the end.

    Every attribute is (W, n_layers + 1); the last column of the layer axis is "no hit".
    """

    depth: F64
    top: F64
    bottom: F64
    surface_u: F64
    material: npt.NDArray[np.intp]
    albedo: F64
    shade: F64
    foot_scale: F64


def _object_layers(
    world: World,
    camera: StereoCamera,
    centre: F64,
    forward: F64,
    ray_x: F64,
    ray_y: F64,
    max_layers: int,
) -> _Layers | None:
    """Intersect every column's horizontal ray with the object footprints near the camera.

    Only the hit depths are computed for all columns x objects; the surface attributes are
    computed afterwards for the ``max_layers`` nearest hits of each column.
    """
    objects = world.objects(float(centre[0]) - 30.0, float(centre[0]) + OBJECT_RANGE)
    sun = world.illumination.sun
    ambient = world.illumination.ambient
    right_2d = (float(forward[1]), float(-forward[0]))
    half_fov = (camera.width - camera.cx + 2.0) / camera.fx, (camera.cx + 2.0) / camera.fx
    rx = ray_x[:, None]
    ry = ray_y[:, None]
    ray_norm_sq = ray_x * ray_x + ray_y * ray_y

    # Segments: solve C + z h = P0 + t E for (z, t) by Cramer's rule.
    start = objects.seg_start - centre[:2]
    end = objects.seg_end - centre[:2]
    keep = np.flatnonzero(_in_view(start, end, forward, right_2d, half_fov, margin=0.0))
    start, edge = start[keep], end[keep] - start[keep]
    numerator = start[:, 1] * edge[:, 0] - start[:, 0] * edge[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        det = ry * edge[:, 0] - rx * edge[:, 1]  # (W, n)
        seg_depth = numerator / det
        along = (rx * start[:, 1] - ry * start[:, 0]) / det
    seg_depth[~((along >= 0.0) & (along <= 1.0) & (seg_depth > _NEAR))] = np.inf

    # Cylinders: nearest root of |C + z h - Q|^2 = rho^2.
    offset = objects.cyl_centre - centre[:2]
    keep_c = np.flatnonzero(
        _in_view(offset, offset, forward, right_2d, half_fov, margin=objects.cyl_radius)
    )
    offset, radius = offset[keep_c], objects.cyl_radius[keep_c]
    along_c = rx * offset[:, 0] + ry * offset[:, 1]  # (W, m)
    quad_c = (offset * offset).sum(axis=1) - radius * radius
    disc = along_c * along_c - ray_norm_sq[:, None] * quad_c
    cyl_depth = (along_c - np.sqrt(np.maximum(disc, 0.0))) / ray_norm_sq[:, None]
    cyl_depth[~((disc > 0) & (cyl_depth > _NEAR))] = np.inf

    depth = np.concatenate([seg_depth, cyl_depth], axis=1)
    n_seg = keep.size
    if depth.shape[1] == 0:
        return None
    n_hits = int(np.isfinite(depth).sum(axis=1).max())
    if n_hits == 0:
        return None
    n_layers = min(max_layers, n_hits)
    if depth.shape[1] > n_layers:
        chosen = np.argpartition(depth, n_layers - 1, axis=1)[:, :n_layers]
    else:
        chosen = np.broadcast_to(np.arange(depth.shape[1]), depth.shape).copy()
    picked_depth = np.take_along_axis(depth, chosen, axis=1)
    order = np.argsort(picked_depth, axis=1, kind="stable")
    chosen = np.take_along_axis(chosen, order, axis=1)  # (W, L) candidate index
    picked_depth = np.take_along_axis(picked_depth, order, axis=1)
    valid = np.isfinite(picked_depth)
    z = np.where(valid, picked_depth, 0.0)
    is_seg = chosen < n_seg
    seg_i = np.where(is_seg, chosen, 0)
    cyl_i = np.where(is_seg, 0, chosen - n_seg)
    hit_x = z * rx
    hit_y = z * ry
    # Per-object parameters of the picked hits (segments and cylinders side by side).
    object_index = np.concatenate([keep, keep_c])
    seg_of = keep[seg_i] if keep.size else np.zeros_like(seg_i)
    cyl_of = keep_c[cyl_i] if keep_c.size else np.zeros_like(cyl_i)
    del object_index
    if keep.size:
        p0 = start[seg_i]
        e = edge[seg_i]
        length = np.sqrt((e * e).sum(axis=2))
        t = ((hit_x - p0[..., 0]) * e[..., 0] + (hit_y - p0[..., 1]) * e[..., 1]) / np.maximum(
            length * length, 1e-12
        )
        seg_u = objects.seg_u0[seg_of] + t * length
        seg_nx = e[..., 1] / np.maximum(length, 1e-9)
        seg_ny = -e[..., 0] / np.maximum(length, 1e-9)
    else:
        seg_u = seg_nx = seg_ny = np.zeros_like(z)
    if keep_c.size:
        rho = radius[cyl_i]
        cyl_nx = (hit_x - offset[cyl_i, 0]) / rho
        cyl_ny = (hit_y - offset[cyl_i, 1]) / rho
        # Pseudo-angle (exact arithmetic), seam facing +x (away from the approaching camera).
        away = -cyl_nx
        total = np.abs(away) + np.abs(cyl_ny) + 1e-12
        pseudo = np.where(
            away >= 0, cyl_ny / total, np.sign(cyl_ny) * (2.0 - np.abs(cyl_ny) / total)
        )
        cyl_u = pseudo * rho * (np.pi / 2.0) + objects.cyl_albedo[cyl_of] * 3.7
    else:
        cyl_u = cyl_nx = cyl_ny = np.zeros_like(z)
    normal_x = np.where(is_seg, seg_nx, cyl_nx)
    normal_y = np.where(is_seg, seg_ny, cyl_ny)
    # Turn segment normals towards the camera (the ray comes from the camera: n.h < 0).
    flip = np.where(normal_x * rx + normal_y * ry > 0, -1.0, 1.0)
    normal_x *= flip
    normal_y *= flip
    cos = np.abs(normal_x * rx + normal_y * ry) / np.sqrt(ray_norm_sq)[:, None]
    shade = ambient + (1.0 - ambient) * np.maximum(normal_x * sun[0] + normal_y * sun[1], 0.0)

    def pick(seg_values: npt.NDArray[np.generic], cyl_values: npt.NDArray[np.generic]) -> F64:
        values = (
            np.where(is_seg, seg_values[seg_of], cyl_values[cyl_of])
            if (keep.size and keep_c.size)
            else (seg_values[seg_of] if keep.size else cyl_values[cyl_of])
        )
        result: F64 = values.astype(np.float64)
        return result

    def with_empty(values: F64, fill: float = 0.0) -> F64:
        values = np.where(valid, values, fill)
        return np.concatenate([values, np.full((values.shape[0], 1), fill)], axis=1)

    return _Layers(
        depth=with_empty(picked_depth, np.inf),
        top=with_empty(pick(objects.seg_top, objects.cyl_top)),
        bottom=with_empty(pick(objects.seg_bottom, objects.cyl_bottom)),
        surface_u=with_empty(np.where(is_seg, seg_u, cyl_u)),
        material=with_empty(pick(objects.seg_material, objects.cyl_material)).astype(np.intp),
        albedo=with_empty(pick(objects.seg_albedo, objects.cyl_albedo)),
        shade=with_empty(shade),
        foot_scale=with_empty(1.0 / (camera.fx * np.maximum(cos, 0.12))),
    )


def _in_view(
    start: F64,
    end: F64,
    forward: F64,
    right: tuple[float, float],
    half_fov: tuple[float, float],
    *,
    margin: F64 | float,
) -> npt.NDArray[np.bool_]:
    """Keep footprints (camera-relative segments or discs) that may reach the view wedge."""
    depth_a = start @ forward[:2]
    depth_b = end @ forward[:2]
    side_a = start[:, 0] * right[0] + start[:, 1] * right[1]
    side_b = end[:, 0] * right[0] + end[:, 1] * right[1]
    ahead = np.maximum(depth_a, depth_b) + margin > _NEAR
    right_limit, left_limit = half_fov
    outside_right = (side_a - margin > right_limit * np.maximum(depth_a + margin, 0.0)) & (
        side_b - margin > right_limit * np.maximum(depth_b + margin, 0.0)
    )
    outside_left = (-side_a - margin > left_limit * np.maximum(depth_a + margin, 0.0)) & (
        -side_b - margin > left_limit * np.maximum(depth_b + margin, 0.0)
    )
    result: npt.NDArray[np.bool_] = ahead & ~outside_right & ~outside_left
    return result
