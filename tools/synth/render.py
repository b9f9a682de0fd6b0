"""Perspective rendering of a scene by ray marching its digital surface model (vectorised with cv2.remap).

For every pixel the camera ray is followed down through horizontal levels from just above the highest surface
in view to just below the lowest terrain; at each level one `cv2.remap` samples the DSM where the rays cross
that level. The first level at which a ray is below the surface brackets the hit, which regula falsi refines
to millimetres. Tall objects therefore lean outward off-nadir and hide what is behind them, exactly as in a
real perspective image. Albedo, light and object id are then sampled at the hit point; rays that hit the side
of an object (a wall of the DSM) take the colour and id of that object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ...plugin.geometry import Camera
from .appearance import srgb_to_linear_lut
from .scene import Scene

MAX_STEP_M = 0.3  # horizontal distance a ray moves between two levels at most (thin objects are >= 1 m)
MAX_LEVEL_STEP_M = 0.6
REFINE_ITERATIONS = 2
WALL_PUSH_M = 0.2  # how far behind a hit to look for a wall of the DSM
COARSE_LEVEL_STEP_M = 1.0  # vertical step of the first, conservative pass
COARSE_BLOCK = 4  # cells per block of the conservative DSM
COARSE_PIXELS = 4  # the first pass traces one ray per COARSE_PIXELS x COARSE_PIXELS pixels


@dataclass
class RenderResult:
    linear: np.ndarray  # (H, W, 3) float32 linear radiance (1.0 = white ground in full sun)
    labels: np.ndarray  # (H, W) uint16 object id of the surface each pixel sees (0 = ground)
    hit: np.ndarray  # (H, W, 3) float32 world point each pixel sees


class ViewOutsideWorld(ValueError):
    """The camera sees beyond the edge of the world rasters."""


def _level_maps(camera: Camera, r_wc: np.ndarray, center: np.ndarray, scene: Scene,
                step_px: int = 1) -> tuple:
    """Per-pixel (A, B) with raster coordinates (col, row) = A + h * B for the ray at height h.

    With step_px > 1, the rays through the centres of step_px x step_px pixel blocks instead."""
    w, h = camera.width, camera.height
    half = step_px / 2.0
    cols = np.arange(0, w, step_px) + half
    rows = np.arange(0, h, step_px) + half
    if camera.is_pinhole:  # separable: a row of u and a column of v broadcast over the image
        u = ((cols - camera.cx) / camera.fx).astype(np.float32)[None, :]
        v = ((rows - camera.cy) / camera.fy).astype(np.float32)[:, None]
    else:  # every pixel's ray through the lens model
        grid = np.stack(np.meshgrid(cols, rows), -1)
        normal = camera.cam_from_img(grid.reshape(-1, 2)).reshape(grid.shape).astype(np.float32)
        if not np.all(np.isfinite(normal)):
            raise ViewOutsideWorld("the lens model cannot lift every pixel to a ray")
        u, v = np.ascontiguousarray(normal[..., 0]), np.ascontiguousarray(normal[..., 1])
    r = np.asarray(r_wc, dtype=np.float64)
    uu, vv = _extremes(np.broadcast_to(u, (len(rows), len(cols))), camera), \
        _extremes(np.broadcast_to(v, (len(rows), len(cols))), camera)
    if np.max(r[2, 0] * uu + r[2, 1] * vv + r[2, 2]) >= -1e-3:  # dz is affine in (u, v): its max is on the border
        raise ViewOutsideWorld("some camera rays do not point down (camera too tilted)")
    r32 = r.astype(np.float32)
    inv_dz = np.float32(1.0) / (r32[2, 0] * u + r32[2, 1] * v + r32[2, 2])
    res = np.float32(scene.world.res)
    cx, cy, cz = (np.float32(c) for c in center)
    shape = (v.shape[0], u.shape[1], 2)
    a = np.empty(shape, np.float32)
    b = np.empty(shape, np.float32)
    for k in (0, 1):  # b = (d_xy / d_z) / res: raster cells moved per metre of height; a = position at h = 0
        np.multiply(r32[k, 0] * u + r32[k, 1] * v + r32[k, 2], inv_dz / res, out=b[..., k])
        a[..., k] = (cx if k == 0 else cy) / res - np.float32(0.5) - cz * b[..., k]
    # |d_xy / d_z| is largest on the border of the image (its level sets are conics around the nadir point), at a
    # corner of a pinhole image
    tan_max = float(np.hypot(_extremes(b[..., 0], camera), _extremes(b[..., 1], camera)).max() * scene.world.res)
    return a, b, tan_max


def _extremes(values: np.ndarray, camera: Camera) -> np.ndarray:
    """Where a per-pixel (H, W) map of a ray quantity can take its extremes: the four corners of a pinhole image
    (the rays of its border are straight lines between them), the whole border of an image with a lens model."""
    if camera.is_pinhole:
        return values[[0, 0, -1, -1], [0, -1, 0, -1]]
    return np.concatenate([values[0], values[-1], values[1:-1, 0], values[1:-1, -1]])


def _lens_stretch(camera: Camera) -> float:
    """Largest ratio, over the image border, of a pixel step's ray change to the pinhole's (1 for a pinhole):
    how much farther apart neighbouring rays of a distorted image can be on the ground."""
    if camera.is_pinhole:
        return 1.0
    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, 65)
    border = np.concatenate([np.stack([t * w, np.zeros_like(t)], 1), np.stack([t * w, np.full_like(t, h)], 1),
                             np.stack([np.zeros_like(t), t * h], 1), np.stack([np.full_like(t, w), t * h], 1)])
    jac = camera.undistortion_jacobians(border)
    return float(max(1.0, np.linalg.norm(jac, ord=2, axis=(1, 2)).max()))


def _scene_stats(scene: Scene) -> dict:
    """Per-scene constants the renderer needs every frame (computed once)."""
    stats = scene.__dict__.get("_render_stats")
    if stats is None:
        block = COARSE_BLOCK
        n = scene.dsm.shape[0]
        m = -(-n // block)
        pad = np.full((m * block, m * block), -1e6, np.float32)
        pad[:n, :n] = scene.dsm
        stats = {
            "zmin": float(scene.world.terrain.min()),
            "zmax": float(scene.dsm.max()),
            "pooled_max": pad.reshape(m, block, m, block).max(axis=(1, 3)),  # DSM max per block
            "conservative": {},
        }
        scene.__dict__["_render_stats"] = stats
    return stats


def view_height_range(scene: Scene, a: np.ndarray, b: np.ndarray, camera: Camera) -> tuple[float, float]:
    """(lowest terrain, highest surface) in the part of the world the view can see; raises if outside."""
    world = scene.world
    n = world.n
    st = _scene_stats(scene)
    zmin, zmax = st["zmin"] - 0.5, st["zmax"] + 0.5
    corners = np.stack([_extremes(a, camera), _extremes(b, camera)])
    pts = np.concatenate([corners[0] + z * corners[1] for z in (zmin, zmax)])
    lo = np.floor(pts.min(axis=0)).astype(int) - 2
    hi = np.ceil(pts.max(axis=0)).astype(int) + 3
    if lo.min() < 0 or hi.max() > n:
        raise ViewOutsideWorld("the view extends beyond the world")
    blk = COARSE_BLOCK
    top = float(st["pooled_max"][lo[1] // blk:-(-hi[1] // blk), lo[0] // blk:-(-hi[0] // blk)].max())
    ts = world.terrain_sampler  # the fine terrain interpolates this grid: its minimum bounds the fine one
    f = world.res / ts.resolution_m
    r0, c0 = int(max(0, (lo[1] + 0.5) * f - 1)), int(max(0, (lo[0] + 0.5) * f - 1))
    r1, c1 = int((hi[1] + 0.5) * f + 2), int((hi[0] + 0.5) * f + 2)
    low = float(ts.heights[r0:r1, c0:c1].min())
    return low, top


def conservative_dsm(scene: Scene, radius_m: float) -> tuple[np.ndarray, int]:
    """A coarse DSM whose bilinear value at any point is >= the true DSM anywhere within `radius_m` of it.

    Max-pooled by `block` cells, then dilated by enough blocks to cover the radius plus the bilinear footprint.
    Cached on the scene per radius."""
    st = _scene_stats(scene)
    cache = st["conservative"]
    block = COARSE_BLOCK
    key = int(math.ceil(radius_m / (block * scene.world.res))) + 1  # dilation in blocks
    if key not in cache:
        k = 2 * key + 1
        cache[key] = cv2.dilate(st["pooled_max"], np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return cache[key], block


# cv2.remap refuses maps (and sources) of SHRT_MAX = 32767 rows or more: rows of 512 points reach that at 16.7 M
# points, i.e. a frame above ~16.7 MP (a 20 MP survey camera). Each sample depends only on its own map entry, so
# remapping in blocks of rows gives the same samples as one call.
_REMAP_MAX_ROWS = 16384


def _remap_points(src: np.ndarray, maps: np.ndarray, max_rows: int = _REMAP_MAX_ROWS) -> np.ndarray:
    """Bilinear samples of `src` at N raster points given as a (rows * 512, 2) buffer whose first N rows are
    used (rows of 512 points keep cv2's threads busy), remapped `max_rows` rows at a time."""
    rows = len(maps) // 512
    grid = maps.reshape(rows, 512, 2)
    if rows <= max_rows:
        return cv2.remap(src, grid, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1)
    out = np.empty((rows, 512), src.dtype)
    for r in range(0, rows, max_rows):
        out[r:r + max_rows] = cv2.remap(src, grid[r:r + max_rows], None, cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)


def _first_crossing(surface: np.ndarray, a: np.ndarray, b: np.ndarray, start: np.ndarray, step: float,
                    bottom: float, max_levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ray, the index j >= 1 of the first level `start - j * step` at which the ray is at or below
    `surface` (sampled bilinearly at raster coordinates a + h * b), or below `bottom`; with the ray's height
    above the surface at that level (<= 0) and at the level before (> 0; approximated at j = 1).

    Rays leave the work arrays once they hit, so the levels after most rays have hit the ground cost little."""
    n = start.size
    j_hit = np.full(n, max_levels, np.int32)
    gap_below = np.zeros(n, np.float32)
    gap_above = np.full(n, np.float32(step), np.float32)
    idx = np.arange(n)
    a_f = a.reshape(-1, 2)
    b_f = b.reshape(-1, 2)
    s_f = start.reshape(-1)
    prev = np.full(n, np.nan, np.float32)  # surface under the ray at the previous level
    active = np.ones(n, bool)
    buf = np.zeros((-(-n // 512) * 512, 2), np.float32)
    j_bottom = int((float(s_f.min()) - bottom) / step)  # before this level no ray can be below `bottom`
    for j in range(1, max_levels + 1):
        m = len(s_f)
        h = s_f - np.float32(j * step)
        maps = buf[:m]
        np.multiply(b_f, h[:, None], out=maps)
        maps += a_f
        surf = _remap_points(surface, buf[:-(-m // 512) * 512])[:m]
        hit = surf >= h
        if j >= j_bottom:
            hit |= h <= bottom
        hit &= active
        if hit.any():
            where = idx[hit]
            j_hit[where] = j
            below = h[hit] - surf[hit]
            gap_below[where] = below
            above = (h[hit] + np.float32(step)) - prev[hit]
            gap_above[where] = np.where(np.isnan(above), below + np.float32(step), above)
            active &= ~hit
        prev = surf
        n_active = int(np.count_nonzero(active))
        if n_active == 0:
            break
        if n_active < 0.6 * m:
            idx, a_f, b_f, s_f, prev = idx[active], a_f[active], b_f[active], s_f[active], prev[active]
            active = np.ones(n_active, bool)
    shape = start.shape
    return j_hit.reshape(shape), gap_above.reshape(shape), gap_below.reshape(shape)


def render_view(scene: Scene, light: np.ndarray, camera: Camera, r_wc: np.ndarray,
                center: np.ndarray) -> RenderResult:
    """Render one camera (world_from_camera rotation r_wc, centre) of a scene lit by `light`."""
    a, b, tan_max = _level_maps(camera, r_wc, np.asarray(center, dtype=np.float64), scene)
    dsm = scene.dsm
    res = scene.world.res
    h_low, h_high = view_height_range(scene, a, b, camera)
    top, bottom = h_high + 0.01, h_low - 0.01
    shape = (camera.height, camera.width)
    # Stage 1, on rays through the centres of COARSE_PIXELS x COARSE_PIXELS pixel blocks: coarse levels
    # against a conservative (max-filtered) DSM give, per block, a height at which every ray of the block is
    # still above the true surface. The filter radius covers the horizontal travel between two coarse
    # levels plus the spread of the block's rays at the lowest height.
    cp = COARSE_PIXELS
    a_cp, b_cp, tan_cp = _level_maps(camera, r_wc, np.asarray(center, dtype=np.float64), scene, cp)
    coarse_step = COARSE_LEVEL_STEP_M
    spread = ((cp * 0.75) * (float(center[2]) - bottom) / min(camera.fx, camera.fy) * (1.0 + tan_max * tan_max)
              * _lens_stretch(camera))
    cons, block = conservative_dsm(scene, coarse_step * max(tan_max, tan_cp) + spread)
    scale = np.float32(1.0 / block)
    a_c = (a_cp + np.float32(0.5)) * scale - np.float32(0.5)
    b_c = b_cp * scale
    n_coarse = int(math.ceil((top - bottom) / coarse_step)) + 1
    start_top = np.full(a_c.shape[:2], np.float32(top))
    k1, _, _ = _first_crossing(cons, a_c, b_c, start_top, coarse_step, bottom, n_coarse)
    start_c = (top - (k1 - 1) * coarse_step).astype(np.float32)
    start = np.repeat(np.repeat(start_c, cp, axis=0), cp, axis=1)[:shape[0], :shape[1]]
    start = np.ascontiguousarray(start)
    # Stage 2: fine levels against the true DSM from there.
    step = min(MAX_LEVEL_STEP_M, MAX_STEP_M / max(tan_max, 1e-6))
    n_fine = int(math.ceil((top - bottom) / step)) + 2
    j, f_a, f_b = _first_crossing(dsm, a, b, start, step, bottom - step, n_fine)
    h_b = (start - j * np.float32(step)).astype(np.float32)  # first level below the surface
    h_a = h_b + np.float32(step)  # last level above it

    def gap(hh: np.ndarray) -> np.ndarray:
        m = a + hh[..., None] * b
        return hh - cv2.remap(dsm, m, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    h_hit = h_b
    for _ in range(REFINE_ITERATIONS):  # regula falsi inside [h_b, h_a]
        denom = f_a - f_b
        t = np.where(denom > 1e-6, f_a / np.maximum(denom, 1e-6), 0.5).astype(np.float32)
        h_hit = h_a + t * (h_b - h_a)
        f_m = gap(h_hit)
        above = f_m > 0
        h_a = np.where(above, h_hit, h_a)
        f_a = np.where(above, f_m, f_a)
        h_b = np.where(above, h_b, h_hit)
        f_b = np.where(above, f_b, f_m)
    hit_maps = a + h_hit[..., None] * b
    # A ray that hits a wall (the DSM rises sharply just behind the hit) sees the object's side: take the
    # object's id from just behind the hit instead of the ground at the wall's foot. b points back toward the
    # camera as h grows, so "behind" is along -b.
    inv_len = np.float32(1.0) / np.maximum(np.hypot(b[..., 0], b[..., 1]), np.float32(1e-9))
    push = hit_maps - b * (inv_len * np.float32(WALL_PUSH_M / res))[..., None]
    behind = cv2.remap(dsm, push, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    ground = cv2.remap(scene.world.terrain, hit_maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    depth = behind - h_hit  # on a wall: how far below the object's top edge the ray hits its side
    wall_idx = np.flatnonzero(depth > 0.3)
    above_ground = (h_hit - ground) > 0.15
    id_maps, colour_maps = hit_maps, hit_maps
    if wall_idx.size:
        flat_hit = hit_maps.reshape(-1, 2)
        id_maps = flat_hit.copy()
        id_maps[wall_idx] = push.reshape(-1, 2)[wall_idx]
        id_maps = id_maps.reshape(hit_maps.shape)
        # Texture the side with the object's own colours: the sample point wanders over ~1 m of the top as the
        # depth changes (a sawtooth inward, a sine sideways), so a crown's side shows leaves, not streaks.
        d_w = depth.reshape(-1)[wall_idx]
        dirs = (b.reshape(-1, 2)[wall_idx] * inv_len.reshape(-1)[wall_idx, None])  # unit, toward the camera
        inward = np.float32(WALL_PUSH_M) + np.float32(0.9) * ((d_w * np.float32(1.7)) % np.float32(1.0))
        sideways = np.float32(0.45) * np.sin(d_w * np.float32(2.3))
        side = np.stack([-dirs[:, 1], dirs[:, 0]], axis=1)
        colour_maps = flat_hit.copy()
        colour_maps[wall_idx] += (side * sideways[:, None] - dirs * inward[:, None]) * np.float32(1.0 / res)
        colour_maps = colour_maps.reshape(hit_maps.shape)
    albedo = cv2.remap(scene.albedo, colour_maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    lit = cv2.remap(light, hit_maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    ids = cv2.remap(scene.ids, id_maps, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    ids_grown = cv2.remap(scene.ids_dilated, id_maps, None, cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    labels = np.where(above_ground & (ids == 0), ids_grown, ids).astype(np.uint16)
    if wall_idx.size:
        # Buildings have walls of their own colour (plaster, brick, timber), not their roof's.
        flat_albedo = albedo.reshape(-1, 3)
        wall_rgb = scene.wall_colour[labels.reshape(-1)[wall_idx]]
        own = wall_rgb.max(axis=1) > 0
        flat_albedo[wall_idx[own]] = wall_rgb[own]
    linear = cv2.LUT(albedo, srgb_to_linear_lut().reshape(1, 256))
    linear *= lit[..., None]
    if wall_idx.size:  # lower parts of a side are darker (self-shading)
        flat_linear = linear.reshape(-1, 3)
        shade = np.float32(1.0) - np.float32(0.4) * np.minimum(d_w / np.float32(6.0), np.float32(1.0))
        flat_linear[wall_idx] *= shade[:, None]
    hit = np.empty(shape + (3,), np.float32)
    hit[..., 0] = (hit_maps[..., 0] + 0.5) * res
    hit[..., 1] = (hit_maps[..., 1] + 0.5) * res
    hit[..., 2] = h_hit
    return RenderResult(linear, labels, hit)
