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
_MARCH_START = 1.0
_MARCH_RATIO = 1.045
_MARCH_SAMPLES = 190  # reaches ~4.2 km
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


@dataclass(frozen=True)
class View:
    """One rendered view.

    Attributes:
        image: (H, W) float32 grey level before sensor noise and quantisation (about 0..255).
        depth: (H, W) float32 z-depth (m), NaN where the ray sees sky.
    """

    image: F32
    depth: F32


def _mip_level(footprint_texels: F32) -> npt.NDArray[np.int32]:
    """Return round(log2(footprint) + bias) clipped to the mip range, via exact frexp."""
    mantissa, exponent = np.frexp(footprint_texels * np.float32(2.0**_MIP_BIAS))
    # log2(x) = exponent - 1 + log2(2 * mantissa); round at 2 * mantissa = sqrt(2).
    level = exponent - 1 + (mantissa >= np.float32(0.70710678)).astype(np.int32)
    return np.clip(level, 0, textures.TILE_LOG2).astype(np.int32)


def render_view(
    world: World,
    camera: StereoCamera,
    camera_to_world: F64,
    *,
    max_layers: int = 8,
) -> View:
    """Ray-cast one view of the world.

    Args:
        world: the procedural world.
        camera: intrinsics (the baseline is not used here).
        camera_to_world: (4, 4) float64 pose of this camera's optical frame (x right, y down,
            z forward) in the world frame (z up); must be level: y axis = (0, 0, -1).
        max_layers: vertical-object hits kept per image column (nearest first).

    Returns:
        The view's image and depth.

    Raises:
        ValueError: if the pose is not a level (4, 4) rigid transform.
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
    slope_y = (row - camera.cy) / camera.fy  # (H,) downward rise per unit depth

    # ------------------------------------------------------------------ ground march
    sample_x = centre[0] + ray_x[:, None] * _DEPTHS  # (W, K)
    sample_y = centre[1] + ray_y[:, None] * _DEPTHS
    table = world.road_table(float(sample_x.min()) - 2.0, float(sample_x.max()) + 2.0)
    blocks = world.block_table(float(sample_x.min()) - 2.0, float(sample_x.max()) + 2.0)
    ground_z, ground_l = world.ground(table, blocks, sample_x, sample_y)
    sample_row = camera.cy + camera.fy * (cam_z - ground_z) / _DEPTHS
    envelope = np.minimum.accumulate(sample_row, axis=1)
    np.clip(envelope, -2.0, height + 1.0, out=envelope)
    envelope[:, 0] = height + 1.0  # the first sample covers the bottom rows
    stride = float(height + 8)
    n_samples = _DEPTHS.shape[0]
    keys = (column * stride)[:, None] - envelope  # (W, K), ascending when flattened
    # Queries in (W, H) layout: every pixel row of every column.
    query = (column * stride)[:, None] - row[None, :]
    upper = np.searchsorted(keys.ravel(), query.ravel(), side="right").reshape(width, height)
    ground_sky = upper % n_samples == 0
    upper[ground_sky] -= 1
    lower = upper - 1
    keys_flat = keys.ravel()
    key_low = keys_flat[lower]
    span = np.maximum(keys_flat[upper] - key_low, 1e-9)
    weight = ((query - key_low) / span).astype(np.float32)
    inverse_depth = (1.0 / _DEPTHS).astype(np.float32)
    inv_flat = np.tile(inverse_depth, width)
    inv_low = inv_flat[lower]
    depth_ground = 1.0 / (inv_low + weight * (inv_flat[upper] - inv_low))
    depth_ground[ground_sky] = np.inf
    lateral_flat = ground_l.astype(np.float32).ravel()
    lat_low = lateral_flat[lower]
    lateral = lat_low + weight * (lateral_flat[upper] - lat_low)  # (W, H) float32

    # ------------------------------------------------------------------ vertical objects
    layers = _object_layers(world, camera, centre, forward, ray_x, ray_y, max_layers)

    fy = camera.fy
    if layers is None:
        depth = depth_ground
        is_object = np.zeros((width, height), dtype=bool)
        flat_index = None
    else:
        n_layers = layers.depth.shape[1] - 1
        top_row = np.ceil(camera.cy + fy * (cam_z - layers.top) / layers.depth)
        bottom_row = np.floor(camera.cy + fy * (cam_z - layers.bottom) / layers.depth)
        finite = np.isfinite(layers.depth)
        top_row = np.where(finite, top_row, height).astype(np.int32)
        bottom_row = np.where(finite, bottom_row, -1).astype(np.int32)
        row_index = np.arange(height, dtype=np.int32)[None, :]
        paint = np.full((width, height), n_layers, dtype=np.int32)
        for k in range(n_layers - 1, -1, -1):
            covered = (row_index >= top_row[:, k : k + 1]) & (row_index <= bottom_row[:, k : k + 1])
            np.copyto(paint, k, where=covered)
        flat_index = paint + (np.arange(width, dtype=np.int32) * (n_layers + 1))[:, None]
        depth_object = layers.depth.astype(np.float32).ravel()[flat_index]
        is_object = depth_object < depth_ground
        depth = np.where(is_object, depth_object, depth_ground)
    sky = np.isinf(depth)

    # ------------------------------------------------------------------ surface attributes
    depth_safe = np.where(sky, np.float32(1e4), depth).astype(np.float32)
    period = textures.TILE_SIZE * TEXEL
    # Ground texture coordinates: world x, y in texels, camera offset reduced mod the period.
    origin_x = float(np.fmod(centre[0], period))
    origin_y = float(np.fmod(centre[1], period))
    rel_x = depth_safe * ray_x.astype(np.float32)[:, None]
    rel_y = depth_safe * ray_y.astype(np.float32)[:, None]
    s_coord = (rel_x + np.float32(origin_x)) * np.float32(1.0 / TEXEL)
    t_coord = (rel_y + np.float32(origin_y)) * np.float32(1.0 / TEXEL)
    world_x = rel_x + np.float32(centre[0])  # along-road coordinate u of ground pixels
    # Ground material from the lateral coordinate.
    distance = np.abs(lateral)
    side_street = blocks.in_side_street(world_x)
    sidewalk_zone = blocks.has_sidewalk(world_x) > 0
    material = np.where(
        (distance < ROAD_HALF_WIDTH) | side_street,
        Material.ASPHALT,
        np.where(
            sidewalk_zone & (distance < ROAD_HALF_WIDTH + SIDEWALK_WIDTH),
            Material.PAVEMENT,
            Material.GRASS,
        ),
    ).astype(np.intp)
    illumination = world.illumination
    ground_shade = illumination.ambient + (1.0 - illumination.ambient) * illumination.sun[2]
    albedo = np.where(
        material == Material.ASPHALT,
        np.float32(95.0),
        np.where(material == Material.PAVEMENT, np.float32(135.0), np.float32(105.0)),
    ).astype(np.float32)
    shade = np.full((width, height), np.float32(ground_shade), dtype=np.float32)
    footprint = depth_safe * np.float32(1.0 / camera.fx)
    # Lane markings (anti-aliased by coverage over the pixel footprint across the line).
    on_road = (distance < ROAD_HALF_WIDTH) & ~side_street
    inv_foot = np.float32(1.0) / np.maximum(footprint, np.float32(1e-4))
    centre_line = np.clip((0.06 - distance) * inv_foot + 0.5, 0.0, 1.0)
    dashes = np.fmod(np.abs(world_x), np.float32(9.0)) < 3.0
    edge_line = np.clip((0.08 - np.abs(distance - LANE_EDGE)) * inv_foot + 0.5, 0.0, 1.0)
    paint_amount = np.where(on_road, centre_line * dashes + edge_line, np.float32(0.0))
    kerb = np.clip((0.18 - np.abs(distance - ROAD_HALF_WIDTH - 0.1)) * inv_foot + 0.5, 0.0, 1.0)
    paint_amount += np.where(sidewalk_zone & ~side_street, kerb * np.float32(0.35), 0.0)

    if layers is not None and flat_index is not None:
        n_layers = layers.depth.shape[1] - 1
        obj_material = layers.material.ravel()[flat_index]
        material = np.where(is_object, obj_material, material)
        surface_u = layers.surface_u.astype(np.float32).ravel()[flat_index]
        height_world = np.float32(cam_z) - depth_safe * slope_y.astype(np.float32)[None, :]
        s_coord = np.where(is_object, surface_u * np.float32(1.0 / TEXEL), s_coord)
        t_coord = np.where(is_object, height_world * np.float32(1.0 / TEXEL), t_coord)
        albedo = np.where(is_object, layers.albedo.astype(np.float32).ravel()[flat_index], albedo)
        shade = np.where(is_object, layers.shade.astype(np.float32).ravel()[flat_index], shade)
        foot_scale = layers.foot_scale.astype(np.float32).ravel()[flat_index]
        footprint = np.where(is_object, depth_safe * foot_scale, footprint)
        paint_amount = np.where(is_object, np.float32(0.0), paint_amount)
        windowed = np.flatnonzero(
            (MATERIAL_WINDOWS[obj_material] + MATERIAL_CAR_WINDOWS[obj_material] > 0).ravel()
            & is_object.ravel()
        )
        window_dark = np.zeros(width * height, dtype=np.float32)
        if windowed.size:
            window_dark[windowed] = _windows(
                obj_material.ravel()[windowed],
                surface_u.ravel()[windowed],
                height_world.ravel()[windowed]
                - layers.bottom.astype(np.float32).ravel()[flat_index.ravel()[windowed]],
                footprint.ravel()[windowed],
            )
        window_dark = window_dark.reshape(width, height)
    else:
        window_dark = np.zeros((width, height), dtype=np.float32)

    # ------------------------------------------------------------------ shading
    bank = world.textures
    footprint_texels = footprint * np.float32(1.0 / TEXEL)
    level = _mip_level(footprint_texels)
    tile = MATERIAL_TILE[material]
    fine = bank.sample(tile.ravel(), s_coord.ravel(), t_coord.ravel(), level.ravel())
    macro_scale = np.float32(TEXEL / MACRO_TEXEL)
    macro_level = _mip_level(footprint_texels * macro_scale)
    macro = bank.sample(
        np.full(fine.shape, textures.TILE_MACRO, dtype=np.intp),
        (s_coord * macro_scale).ravel(),
        (t_coord * macro_scale).ravel(),
        macro_level.ravel(),
    )
    contrast = MATERIAL_CONTRAST[material].ravel()
    grey = albedo.ravel() + contrast * (fine + np.float32(0.8) * macro)
    grey += paint_amount.ravel() * (np.float32(215.0) - grey)
    grey -= window_dark.ravel() * (grey - np.float32(35.0))
    grey *= shade.ravel() * np.float32(illumination.gain)
    haze = depth_safe.ravel() / (depth_safe.ravel() + np.float32(_HAZE_HALF_DEPTH))
    grey += haze * (np.float32(_HAZE_GREY) - grey)
    sky_row = illumination.sky_top + (illumination.sky_horizon - illumination.sky_top) * np.clip(
        row / max(camera.cy, 1.0), 0.0, 1.0
    )
    sky_grey = np.broadcast_to(sky_row.astype(np.float32)[None, :], (width, height))
    image = np.where(sky, sky_grey, grey.reshape(width, height))
    depth_out = np.where(sky, np.float32(np.nan), depth).astype(np.float32)
    return View(
        image=np.ascontiguousarray(image.T, dtype=np.float32),
        depth=np.ascontiguousarray(depth_out.T),
    )


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
    """Intersect every column's horizontal ray with the object footprints near the camera."""
    objects = world.objects(float(centre[0]) - 30.0, float(centre[0]) + OBJECT_RANGE)
    sun = world.illumination.sun
    ambient = world.illumination.ambient
    right_x, right_y = forward[1], -forward[0]
    half_fov = (camera.width - camera.cx + 2.0) / camera.fx, (camera.cx + 2.0) / camera.fx
    ray_norm = np.sqrt(ray_x * ray_x + ray_y * ray_y)[:, None]
    rx = ray_x[:, None]
    ry = ray_y[:, None]

    # Segments ----------------------------------------------------------------
    start = objects.seg_start - centre[:2]
    end = objects.seg_end - centre[:2]
    keep = _in_view(start, end, forward, (right_x, right_y), half_fov, margin=0.0)
    start, end = start[keep], end[keep]
    edge = end - start
    length = np.sqrt((edge * edge).sum(axis=1))
    det = ry * edge[:, 0] - rx * edge[:, 1]  # (W, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / det
        seg_depth = (start[:, 1] * edge[:, 0] - start[:, 0] * edge[:, 1]) * inv_det
        along = (rx * start[:, 1] - ry * start[:, 0]) * inv_det
    hit = (along >= 0.0) & (along <= 1.0) & (seg_depth > _NEAR)
    seg_depth = np.where(hit, seg_depth, np.inf)
    seg_u = objects.seg_u0[keep] + along * length
    normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1) / np.maximum(length, 1e-9)[:, None]
    facing = np.where((normal * start).sum(axis=1) > 0, -1.0, 1.0)  # towards the camera
    normal *= facing[:, None]
    seg_shade = ambient + (1 - ambient) * np.maximum(normal @ sun[:2], 0.0)
    seg_cos = np.abs(rx * normal[:, 0] + ry * normal[:, 1]) / ray_norm

    # Cylinders ---------------------------------------------------------------
    offset = objects.cyl_centre - centre[:2]
    radius = objects.cyl_radius
    keep_c = _in_view(offset, offset, forward, (right_x, right_y), half_fov, margin=radius)
    offset, radius = offset[keep_c], radius[keep_c]
    along_c = rx * offset[:, 0] + ry * offset[:, 1]  # (W, m)
    quad_a = ray_norm * ray_norm
    quad_c = (offset * offset).sum(axis=1) - radius * radius
    disc = along_c * along_c - quad_a * quad_c
    cyl_depth = (along_c - np.sqrt(np.maximum(disc, 0.0))) / quad_a
    cyl_depth = np.where((disc > 0) & (cyl_depth > _NEAR), cyl_depth, np.inf)
    depth_safe = np.where(np.isfinite(cyl_depth), cyl_depth, 0.0)
    normal_x = (depth_safe * rx - offset[:, 0]) / radius
    normal_y = (depth_safe * ry - offset[:, 1]) / radius
    # Pseudo-angle (exact arithmetic), seam facing +x (away from the approaching camera).
    away = -normal_x
    total = np.abs(away) + np.abs(normal_y) + 1e-12
    pseudo = np.where(
        away >= 0, normal_y / total, np.sign(normal_y) * (2.0 - np.abs(normal_y) / total)
    )
    cyl_u = pseudo * radius * (np.pi / 2.0) + objects.cyl_albedo[keep_c] * 3.7
    cyl_shade = ambient + (1 - ambient) * np.maximum(normal_x * sun[0] + normal_y * sun[1], 0.0)
    cyl_cos = np.abs(rx * normal_x + ry * normal_y) / ray_norm

    depth = np.concatenate([seg_depth, cyl_depth], axis=1)
    n_candidates = depth.shape[1]
    if n_candidates == 0:
        return None
    n_hits = int(np.isfinite(depth).sum(axis=1).max())
    if n_hits == 0:
        return None
    n_layers = min(max_layers, n_hits)
    if n_candidates > n_layers:
        chosen = np.argpartition(depth, n_layers - 1, axis=1)[:, :n_layers]
    else:
        chosen = np.broadcast_to(np.arange(n_candidates), depth.shape).copy()
    order = np.argsort(np.take_along_axis(depth, chosen, axis=1), axis=1, kind="stable")
    chosen = np.take_along_axis(chosen, order, axis=1)

    def gather(per_column: F64, per_object: F64 | None = None) -> F64:
        values = per_column if per_object is None else np.broadcast_to(per_object, depth.shape)
        picked = np.take_along_axis(values, chosen, axis=1)
        return np.concatenate([picked, np.zeros((picked.shape[0], 1))], axis=1)

    def per_object(seg_values: F64, cyl_values: F64) -> F64:
        return np.concatenate([seg_values, cyl_values])

    picked_depth = gather(depth)
    picked_depth[:, -1] = np.inf
    cos = gather(np.concatenate([seg_cos, cyl_cos], axis=1))
    shade = gather(
        np.concatenate([np.broadcast_to(seg_shade, seg_depth.shape), cyl_shade], axis=1)
    )
    material = gather(
        np.zeros(depth.shape),
        per_object(
            objects.seg_material[keep].astype(np.float64),
            objects.cyl_material[keep_c].astype(np.float64),
        ),
    ).astype(np.intp)
    return _Layers(
        depth=picked_depth,
        top=gather(depth, per_object(objects.seg_top[keep], objects.cyl_top[keep_c])),
        bottom=gather(depth, per_object(objects.seg_bottom[keep], objects.cyl_bottom[keep_c])),
        surface_u=gather(np.concatenate([seg_u, cyl_u], axis=1)),
        material=material,
        albedo=gather(
            depth, per_object(objects.seg_albedo[keep], objects.cyl_albedo[keep_c])
        ),
        shade=shade,
        foot_scale=1.0 / (camera.fx * np.maximum(cos, 0.12)),
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
