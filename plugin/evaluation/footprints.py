"""Ground footprints of cameras: the polygon of terrain each keyframe sees (pure numpy + shapely).

Points along the image border are cast as rays from the ground-truth pose and intersected with the terrain;
the polygon through the hits, in border order, is the footprint. A flat ground is solved in closed form; a
height field by marching along each ray to the first sign change of (ray height - terrain height), then
bisection. Rays that never reach the ground (above the horizon) are cut at `max_range_m` so that oblique views
still give a finite, if approximate, footprint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely

from ..geometry import Camera, pixel_rays

#: A terrain sampler: vectorised height z(x, y) in the world frame (metres).
HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class FlatGround:
    """A horizontal plane z = `height` (the paper's assumption when no elevation model is available)."""

    height: float = 0.0

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.full(np.broadcast(x, y).shape, self.height, dtype=np.float64)

    @property
    def z_range(self) -> tuple[float, float]:
        return self.height, self.height


@dataclass(frozen=True)
class HeightField:
    """A regular grid of heights z[row, col] at x = x0 + col * dx, y = y0 + row * dy; bilinear in between.

    Outside the grid the nearest edge value is used (the terrain is assumed to continue flat).
    """

    z: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float

    def __post_init__(self) -> None:
        z = np.asarray(self.z, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 2 or not np.all(np.isfinite(z)):
            raise ValueError("height field must be a finite 2-D grid of at least 2 x 2")
        if self.dx == 0 or self.dy == 0:
            raise ValueError("grid spacing must be non-zero")
        object.__setattr__(self, "z", z)

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        rows, cols = self.z.shape
        fc = np.clip((np.asarray(x, dtype=np.float64) - self.x0) / self.dx, 0.0, cols - 1.0)
        fr = np.clip((np.asarray(y, dtype=np.float64) - self.y0) / self.dy, 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(fc).astype(np.int64), cols - 2)
        r0 = np.minimum(np.floor(fr).astype(np.int64), rows - 2)
        tc, tr = fc - c0, fr - r0
        z = self.z
        top = z[r0, c0] * (1 - tc) + z[r0, c0 + 1] * tc
        bottom = z[r0 + 1, c0] * (1 - tc) + z[r0 + 1, c0 + 1] * tc
        return top * (1 - tr) + bottom * tr

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.z.min()), float(self.z.max())


def border_pixels(camera: Camera, per_side: int = 8) -> np.ndarray:
    """(4 * per_side, 2) pixels along the image border, clockwise from the top-left corner (COLMAP convention:
    the image spans [0, W] x [0, H])."""
    t = np.arange(per_side) / per_side
    w, h = float(camera.width), float(camera.height)
    top = np.stack([t * w, np.zeros_like(t)], 1)
    right = np.stack([np.full_like(t, w), t * h], 1)
    bottom = np.stack([w - t * w, np.full_like(t, h)], 1)
    left = np.stack([np.zeros_like(t), h - t * h], 1)
    return np.concatenate([top, right, bottom, left])


def intersect_rays(
    origins: np.ndarray, directions: np.ndarray, terrain: HeightFn, max_range_m: float | np.ndarray,
    z_range: tuple[float, float] | None = None, steps: int = 64, iterations: int = 40,
) -> np.ndarray:
    """First intersection of rays with the terrain: (..., 3) points; rays that miss stop at `max_range_m`.

    Args:
        origins: (..., 3) ray origins; directions: (..., 3) ray directions (any length).
        terrain: height sampler z(x, y); `FlatGround` is solved exactly.
        max_range_m: horizontal-or-not distance along the ray where a miss (and a farther hit) is cut; one for
            every ray, or an array that broadcasts against the rays' shape (...,).
        z_range: (min, max) terrain height bounding the search (taken from the terrain if it has `z_range`).
        steps: samples of the coarse march between the heights z_max and z_min; iterations: bisection steps.
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    o, d = np.broadcast_arrays(o, d)
    if z_range is None:
        z_range = getattr(terrain, "z_range", None)
    if z_range is None:
        raise ValueError("z_range is needed for a terrain without a z_range attribute")
    zmin, zmax = z_range
    if not isinstance(terrain, FlatGround):
        # a millimetre of slack for the march: a ray reaching a flat stretch at exactly the lowest height ends
        # on it with rounding either way, and (ray - terrain) > 0 by 1e-15 there would read as a miss
        zmin, zmax = zmin - 1e-3, zmax + 1e-3
    dz = d[..., 2]
    down = dz < -1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = np.where(down, (o[..., 2] - zmin) / -dz, np.inf)  # below every terrain point: surely hit
        t_lo = np.where(down, (o[..., 2] - zmax) / -dz, np.inf)  # above every terrain point: surely not yet
    t_lo = np.maximum(t_lo, 0.0)
    if isinstance(terrain, FlatGround):
        t = t_hi
        hit = np.isfinite(t) & (t >= 0)
    else:
        t_hi_c = np.minimum(t_hi, max_range_m)
        # March from t_lo to t_hi: the first sample below the terrain brackets the first hit (no tunnelling
        # through hills narrower than a step, which at 64 steps over the terrain's relief is negligible).
        frac = np.linspace(0.0, 1.0, steps + 1)
        with np.errstate(invalid="ignore"):  # a ray that never goes down: inf - inf, zeroed below
            ts = t_lo[..., None] + (t_hi_c - t_lo)[..., None] * frac
        ts = np.where(np.isfinite(ts), ts, 0.0)
        pts = o[..., None, :] + ts[..., None] * d[..., None, :]
        f = pts[..., 2] - terrain(pts[..., 0], pts[..., 1])
        below = f <= 0
        hit = below.any(-1) & down
        first = np.argmax(below, axis=-1)
        a = np.take_along_axis(ts, np.maximum(first - 1, 0)[..., None], -1)[..., 0]
        b = np.take_along_axis(ts, first[..., None], -1)[..., 0]
        for _ in range(iterations):
            m = 0.5 * (a + b)
            p = o + m[..., None] * d
            above = p[..., 2] - terrain(p[..., 0], p[..., 1]) > 0
            a = np.where(above, m, a)
            b = np.where(above, b, m)
        t = 0.5 * (a + b)
    t = np.where(hit & (t <= max_range_m), t, max_range_m)
    return o + t[..., None] * d


def footprint_points(
    camera: Camera, rotations: np.ndarray, centers: np.ndarray, terrain: HeightFn, per_side: int = 8,
    max_range_m: float | None = None, max_depth_m: float | None = None,
) -> np.ndarray:
    """(N, M, 3) ground points seen along the border of each of N cameras: M = 4 * per_side border pixels, less
    any that the camera's lens model cannot lift to a ray.

    `rotations` are world_from_camera (N, 3, 3), `centers` (N, 3). `max_range_m` defaults to 20 x the largest
    height of a camera above the lowest terrain point. `max_depth_m`: rays are cut as well where their depth
    (distance along the optical axis) reaches it.
    """
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    uv = border_pixels(camera, per_side)
    # through the lens model: a barrel lens sees farther out at its border than the pinhole of its focal length
    d_cam = pixel_rays(camera, uv, np.eye(3))
    d_cam = d_cam[np.all(np.isfinite(d_cam), axis=1)]  # border pixels the model cannot lift have no ray
    dirs = np.einsum("nij,mj->nmi", rotations, d_cam)
    z_range = getattr(terrain, "z_range", None)
    if max_range_m is None:
        floor = z_range[0] if z_range is not None else 0.0
        max_range_m = 20.0 * max(float(np.max(centers[:, 2] - floor, initial=1.0)), 1.0)
    reach: float | np.ndarray = max_range_m
    if max_depth_m is not None:  # d_cam has unit depth: a ray reaches depth D at D x its length
        reach = np.minimum(max_range_m, max_depth_m * np.linalg.norm(d_cam, axis=1))
    return intersect_rays(centers[:, None, :], dirs, terrain, reach, z_range)


def footprint_polygons(
    camera: Camera, rotations: np.ndarray, centers: np.ndarray, terrain: HeightFn, per_side: int = 8,
    max_range_m: float | None = None, max_depth_m: float | None = None,
) -> np.ndarray:
    """Footprints of N cameras as an (N,) array of shapely polygons in world x, y (valid, possibly empty)."""
    pts = footprint_points(camera, rotations, centers, terrain, per_side, max_range_m, max_depth_m)
    if pts.shape[1] < 3:  # no border the lens model can lift: no footprint
        return np.array([shapely.Polygon() for _ in range(len(pts))], dtype=object)
    polys = shapely.polygons(pts[..., :2])
    # Terrain occlusion or extreme obliquity can make the ring self-intersect; make_valid keeps the area.
    invalid = ~shapely.is_valid(polys)
    if invalid.any():
        polys[invalid] = shapely.make_valid(polys[invalid])
    return polys


__all__ = ["FlatGround", "HeightField", "HeightFn", "border_pixels", "intersect_rays", "footprint_points",
           "footprint_polygons"]
