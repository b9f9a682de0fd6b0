"""The synthetic world of one seed: terrain, ground cover, objects and their per-season look. The objects are
placed in `objects.py`; a session's scene (objects stamped in, one season) is built in `scene.py`.

Coordinates: world metres, x east, y north, z up; the world covers [0, size_m] x [0, size_m]. Fine rasters
(resolution_m per cell, rows = +y, cols = +x) have the centre of cell [r, c] at ((c + 0.5) res, (r + 0.5) res).
The terrain is generated on a coarse grid (terrain_resolution_m, sample [r, c] at (c res_t, r res_t)) and the
fine terrain raster is its exact bilinear interpolation, so `TerrainSampler` on the coarse grid (written as
terrain.npz) gives the ground the renderer draws.

Everything derives from `WorldConfig.seed` through independent random streams (`noise.rng_for(seed, TAG, ...)`),
so two sessions of one seed share the world exactly; a session only chooses which objects are present and
which season the albedo shows. Objects keep their geometry across seasons (a leaf-off tree keeps its crown
shape in the surface model; only its look changes).
"""

from __future__ import annotations

import functools
import logging
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ...database.synth_session import TerrainSampler
from . import world_cache
from .appearance import CROP_COLOURS, CROPS, GROUND, SEASON_NAMES
from .noise import fractal_noise, rng_for, value_noise

log = logging.getLogger(__name__)

KINDS = ("deciduous", "conifer", "bush", "boulder", "building", "pond")
# Objects per km^2 of each kind at the default density (sums to ~900: "several hundred per km^2", so that a
# 100-frame flight covering ~0.055 km^2 sees ~50 objects, enough landmarks for windowed association).
KIND_DENSITY = {"deciduous": 320.0, "conifer": 210.0, "bush": 220.0, "boulder": 92.0, "building": 42.0,
                "pond": 14.0}
EXTRA_FRACTION = 0.10  # extra objects, absent by default: the pool a session draws "added" objects from

# Ground classes of the cover raster.
GRASS, FIELD, SOIL, ASPHALT, GRAVEL, WATER, MARGIN, BANK = range(8)
CLASS_NAMES = ("grass", "field", "soil", "asphalt", "gravel", "water", "margin", "bank")

# Random stream tags (never reuse a tag for another purpose: it would change every world).
_T_TERRAIN, _T_COVER, _T_ROADS, _T_OBJECTS, _T_NOISE, _T_OBJECT = 1, 2, 3, 4, 5, 6


@dataclass(frozen=True)
class WorldConfig:
    """What defines a world. Sessions made with equal configs see the same world."""

    seed: int = 0
    size_m: float = 600.0
    resolution_m: float = 0.15  # finer than the ~0.2 m ground sampling distance of the default camera
    terrain_resolution_m: float = 1.0
    relief_m: float = 5.0  # about the peak-to-peak height of the gentle hills
    object_density_per_km2: float = 898.0

    @property
    def cells(self) -> int:
        return int(round(self.size_m / self.resolution_m))


@dataclass
class WorldObject:
    """One discrete object. x, y: centre; top_z: height of the visible top centre; radius: radius of the circle
    with the footprint's area; height: top_z - ground_z (0 for ponds, whose top is the water surface)."""

    id: int
    kind: str
    x: float
    y: float
    ground_z: float
    top_z: float
    radius: float
    height: float
    default_present: bool
    # shape parameters
    r_nominal: float  # crown / dome radius, or half the building diagonal
    angle: float = 0.0  # building orientation (rad)
    length: float = 0.0  # building extent along `angle`
    width: float = 0.0
    eave_h: float = 0.0
    roof: str = ""


class World:
    """Terrain, ground cover and objects of one seed (large rasters are built lazily and cached)."""

    def __init__(self, config: WorldConfig, parts: dict | None = None) -> None:
        """Build the world of `config`, or assemble it from `parts` (the attributes a cache entry holds:
        terrain_sampler, terrain, cover, cell, cell_params, roads, objects)."""
        self.config = config
        n = config.cells
        self.n = n
        self.res = config.resolution_m
        self.cache_entry: Path | None = None  # the world cache directory this world is saved in, if any
        self._noise: dict[str, np.ndarray] | None = None
        self._ground: dict[str, np.ndarray] = {}
        if parts is not None:
            for name in ("terrain_sampler", "terrain", "cover", "cell", "cell_params", "roads", "objects"):
                setattr(self, name, parts[name])
            return
        self.terrain_sampler = _make_terrain(config)
        self.terrain = _fine_terrain(self.terrain_sampler, n, self.res)
        cover = _ground_cover(config, n)
        self.cover, self.cell, self.cell_params, self.roads = cover
        from .objects import place_objects  # objects.py builds on this module's types: imported here, not above

        self.objects = place_objects(config, self)

    # -------------------------------------------------------------------------------------------- rasters
    def world_to_px(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple:
        """Fine raster coordinates (col, row) with integer values at cell centres (the cv2.remap convention)."""
        return (np.asarray(x) / self.res - 0.5, np.asarray(y) / self.res - 0.5)

    def noise(self) -> dict[str, np.ndarray]:
        """Shared texture noise fields (unit std, float32), identical for every season of the world."""
        if self._noise is None:
            cfg = self.config
            rng = rng_for(cfg.seed, _T_NOISE)
            shape = (self.n, self.n)
            ext = (cfg.size_m, cfg.size_m)
            fine = rng.standard_normal(shape, dtype=np.float32)
            fine = cv2.GaussianBlur(fine, (0, 0), 0.8)
            fine *= np.float32(1.0 / max(float(fine[::7, ::7].std()), 1e-6))
            self._noise = {
                "low": fractal_noise(rng, shape, ext, 60.0, octaves=3),
                "patch": fractal_noise(rng, shape, ext, 22.0, octaves=3),
                "mid": fractal_noise(rng, shape, ext, 5.0, octaves=3),
                "fine": fine,
            }
        return self._noise

    def ground_albedo(self, season: str) -> np.ndarray:
        """8-bit sRGB albedo of the bare ground (no objects) for a season, (n, n, 3) RGB."""
        if season not in SEASON_NAMES:
            raise ValueError(f"unknown season {season!r}")
        if season not in self._ground:
            entry = self.cache_entry
            albedo = world_cache.load_albedo(entry, season, (self.n, self.n)) if entry is not None else None
            if albedo is None:
                albedo = _ground_albedo(self, season)
                if entry is not None:
                    world_cache.save_albedo(entry, season, albedo)
            self._ground[season] = albedo
        return self._ground[season]


@functools.lru_cache(maxsize=2)
def get_world(config: WorldConfig) -> World:
    """The world of a config, cached per process and on disk (`world_cache`: building one takes ~9 s of CPU,
    loading it a fraction of a second)."""
    world = world_cache.load_world(config)
    if world is None:
        world = World(config)
        world_cache.save_world(world)
    return world


# ---------------------------------------------------------------------------------------------------- terrain

def _make_terrain(cfg: WorldConfig) -> TerrainSampler:
    rng = rng_for(cfg.seed, _T_TERRAIN)
    res_t = cfg.terrain_resolution_m
    m = int(round(cfg.size_m / res_t)) + 1
    hills = fractal_noise(rng, (m, m), (cfg.size_m, cfg.size_m), 260.0, octaves=4, persistence=0.45)
    # A gentle regional slope (0.3-0.6 %) so that the terrain is not just bumps around a constant.
    angle = rng.uniform(0, 2 * math.pi)
    slope = rng.uniform(0.003, 0.006)
    coords = np.arange(m, dtype=np.float32) * np.float32(res_t)
    tilt = slope * (math.cos(angle) * coords[None, :] + math.sin(angle) * coords[:, None])
    heights = hills * np.float32(cfg.relief_m / 4.0) + tilt.astype(np.float32)
    heights -= np.float32(heights.mean())
    return TerrainSampler(heights.astype(np.float32), 0.0, 0.0, res_t)


def _fine_terrain(sampler: TerrainSampler, n: int, res: float) -> np.ndarray:
    """Exact (separable) bilinear interpolation of the coarse grid at the fine cell centres (float32)."""
    coarse = sampler.heights.astype(np.float32)
    centres = (np.arange(n) + 0.5) * res / sampler.resolution_m
    i0 = np.minimum(np.floor(centres).astype(np.int64), coarse.shape[0] - 2)
    w = (centres - i0).astype(np.float32)
    cols = coarse[:, i0] * (1 - w)[None, :] + coarse[:, i0 + 1] * w[None, :]  # (m, n)
    return np.ascontiguousarray(cols[i0, :] * (1 - w)[:, None] + cols[i0 + 1, :] * w[:, None])


# ----------------------------------------------------------------------------------------------- ground cover

@dataclass
class CellParams:
    """Per ground-cover cell: class, crop, row direction and spacing, brightness."""

    cls: np.ndarray
    crop: np.ndarray
    theta: np.ndarray
    period: np.ndarray
    phase: np.ndarray
    bright: np.ndarray


def _random_polyline(rng: np.random.Generator, size: float, step: float, wander_deg: float) -> np.ndarray:
    """A smooth random path crossing the square world from one edge to the opposite one."""
    side = rng.integers(4)
    start_along = rng.uniform(0.2, 0.8) * size
    start = [(start_along, -5.0), (size + 5.0, start_along), (start_along, size + 5.0), (-5.0, start_along)][side]
    heading = [math.pi / 2, math.pi, -math.pi / 2, 0.0][side] + rng.uniform(-0.4, 0.4)
    target = heading
    pts = [np.array(start)]
    turn = 0.0
    for _ in range(int(6 * size / step)):
        turn = 0.7 * turn + rng.normal(0, math.radians(wander_deg))
        heading += turn
        heading = target + float(np.clip(heading - target, -0.9, 0.9))  # keep crossing the world
        p = pts[-1] + step * np.array([math.cos(heading), math.sin(heading)])
        pts.append(p)
        if not (-10 <= p[0] <= size + 10 and -10 <= p[1] <= size + 10):
            break
    return np.array(pts)


def _draw_polyline(img: np.ndarray, pts_m: np.ndarray, res: float, width_m: float, value: int) -> None:
    shift = 4
    px = np.round((pts_m / res - 0.5) * (1 << shift)).astype(np.int32)
    cv2.polylines(img, [px.reshape(-1, 1, 2)], False, int(value), thickness=max(1, int(round(width_m / res))),
                  lineType=cv2.LINE_8, shift=shift)


def _ground_cover(cfg: WorldConfig, n: int) -> tuple:
    """Cover class raster (uint8), cell raster (uint16), per-cell params and the road/stream polylines."""
    rng = rng_for(cfg.seed, _T_COVER)
    res = cfg.resolution_m
    n_sites = max(4, int(round((cfg.size_m / 70.0) ** 2)))
    sites = rng.uniform(0, n, size=(n_sites, 2))
    seeds_img = np.full((n, n), 255, np.uint8)
    sc = np.clip(sites.astype(int), 0, n - 1)
    seeds_img[sc[:, 1], sc[:, 0]] = 0
    _, labels = cv2.distanceTransformWithLabels(seeds_img, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    # DIST_LABEL_PIXEL numbers the zero pixels in scan order; map them to cell indices 0..K-1.
    label_of_site = labels[sc[:, 1], sc[:, 0]]
    lut = np.zeros(int(labels.max()) + 1, np.uint16)
    lut[label_of_site] = np.arange(n_sites, dtype=np.uint16)
    cell = lut[labels]
    # Slightly wavy boundaries: warp the cell map with smooth 2 m noise.
    wx = value_noise(rng, (n, n), (cfg.size_m / 40.0, cfg.size_m / 40.0)) * np.float32(2.0 / res)
    wy = value_noise(rng, (n, n), (cfg.size_m / 40.0, cfg.size_m / 40.0)) * np.float32(2.0 / res)
    gx = np.arange(n, dtype=np.float32)
    cell = cv2.remap(cell, gx[None, :] + wx, gx[:, None] + wy, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    del wx, wy, labels
    cls = rng.choice([FIELD, GRASS, SOIL], size=n_sites, p=[0.58, 0.34, 0.08]).astype(np.uint8)
    params = CellParams(
        cls=cls,
        crop=rng.integers(0, len(CROPS), n_sites),
        theta=rng.uniform(0, math.pi, n_sites),
        period=np.zeros(n_sites),
        phase=rng.uniform(0, 1, n_sites),
        bright=rng.normal(1.0, 0.05, n_sites),
    )
    row_spacing = {"wheat": 0.25, "corn": 0.75, "rapeseed": 0.45, "potato": 0.75, "hay": 5.0, "ploughed": 0.5}
    params.period = np.array([row_spacing[CROPS[c]] for c in params.crop]) * rng.uniform(0.9, 1.1, n_sites)
    cover = cls[cell]
    # Field margins: a strip of weeds/grass along every cell boundary.
    k3 = np.ones((3, 3), np.uint8)
    boundary = (cv2.dilate(cell, k3) != cv2.erode(cell, k3)).astype(np.uint8)
    half = max(1, int(round(0.7 / res)))
    boundary = cv2.dilate(boundary, np.ones((2 * half + 1, 2 * half + 1), np.uint8))
    cover[boundary.astype(bool)] = MARGIN
    # Roads (one asphalt, one gravel) and a stream with banks.
    rr = rng_for(cfg.seed, _T_ROADS)
    roads = []
    for kind, width, value in (("asphalt", 5.5, ASPHALT), ("gravel", 3.5, GRAVEL)):
        pts = _random_polyline(rr, cfg.size_m, 10.0, 3.0)
        _draw_polyline(cover, pts, res, width, value)
        roads.append((kind, width, pts))
    stream = _random_polyline(rr, cfg.size_m, 8.0, 9.0)
    _draw_polyline(cover, stream, res, 7.0, BANK)
    _draw_polyline(cover, stream, res, 3.5, WATER)
    roads.append(("stream", 3.5, stream))
    return cover, cell, params, roads


def _ground_albedo(world: World, season: str) -> np.ndarray:
    """Albedo of the bare ground, computed in blocks of rows so that the temporaries stay in cache."""
    n = world.n
    out = np.empty((n, n, 3), np.uint8)
    rows = 192
    world.noise()  # build the shared noise before the threads use it

    def block(r0: int) -> None:
        out[r0:min(n, r0 + rows)] = _ground_block(world, season, r0, min(n, r0 + rows))

    # numpy releases the GIL in its loops: two threads keep two cores busy; blocks are independent.
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(block, range(0, n, rows)))
    return out


def _ground_block(world: World, season: str, r0: int, r1: int) -> np.ndarray:
    nz = {k: v[r0:r1] for k, v in world.noise().items()}
    res = world.res
    cover = world.cover[r0:r1]
    snow = season == "winter"
    calm = np.float32(0.3 if snow else 1.0)  # snow hides most of the texture below it

    def col(name: str) -> np.ndarray:
        return np.asarray(GROUND[name][season], np.float32)

    # Grass everywhere first: two grass tones mixed by patch noise, modulated by low/mid/fine noise.
    t = np.clip(0.5 + 0.45 * nz["patch"], 0.0, 1.0)[..., None]
    texture = 1.0 + (0.10 * nz["low"] + 0.07 * nz["mid"] + 0.09 * nz["fine"]) * calm
    out = (col("grass") + (col("grass2") - col("grass")) * t) * texture[..., None]
    # Other uniform classes.
    for cls_id, name, amp in ((SOIL, "soil", 0.12), (MARGIN, "margin", 0.14), (BANK, "bank", 0.12),
                              (ASPHALT, "asphalt", 0.05), (GRAVEL, "gravel", 0.08), (WATER, "water", 0.04)):
        mask = cover == cls_id
        if not mask.any():
            continue
        tex = 1.0 + amp * (0.5 * nz["mid"][mask] + nz["fine"][mask]) * (calm if name != "asphalt" else 1.0)
        out[mask] = col(name) * tex[:, None]
    # Fields: crop rows along each cell's direction, tramlines every 18 m.
    field = cover == FIELD
    if field.any():
        rows_idx, cols_idx = np.nonzero(field)
        cell = world.cell[r0:r1][rows_idx, cols_idx]
        p = world.cell_params
        xs = (cols_idx.astype(np.float32) + 0.5) * np.float32(res)
        ys = (rows_idx.astype(np.float32) + np.float32(r0 + 0.5)) * np.float32(res)
        th = p.theta.astype(np.float32)[cell]
        u = xs * np.cos(th) + ys * np.sin(th)
        phase = p.phase.astype(np.float32)[cell]
        rowpat = 0.5 + 0.5 * np.cos(np.float32(2 * np.pi) * (u / p.period.astype(np.float32)[cell] + phase))
        tram = np.abs(((u * np.float32(1 / 18.0) + phase) % 1.0) - 0.5) < (0.5 / 18.0)
        crop_row = np.array([CROP_COLOURS[c][season][0] for c in CROPS], np.float32)
        crop_gap = np.array([CROP_COLOURS[c][season][1] for c in CROPS], np.float32)
        ci = p.crop[cell]
        a = (rowpat * np.sqrt(rowpat))[:, None]
        colour = crop_gap[ci] + (crop_row[ci] - crop_gap[ci]) * a
        colour[tram] = crop_gap[ci[tram]] * 0.92
        tex = 1.0 + (0.07 * nz["low"][field] + 0.05 * nz["mid"][field] + 0.06 * nz["fine"][field]) * (
            np.float32(0.4) if snow else np.float32(1.0))
        colour *= (tex * p.bright.astype(np.float32)[cell])[:, None]
        out[field] = colour
    if snow:
        # Snow drifts: broad, faint undulations; roads keep their wet dark tracks.
        drift = 1.0 - 0.03 * np.abs(nz["low"])
        drift[(cover == ASPHALT) | (cover == GRAVEL)] = 1.0
        out *= drift[..., None]
    np.clip(out, 0, 255, out=out)
    return out.astype(np.uint8)
