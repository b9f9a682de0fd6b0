"""The synthetic world of one seed: terrain, ground cover, objects and their per-season look.

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
        self.objects = _place_objects(config, self)

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


# ---------------------------------------------------------------------------------------------------- objects

def _place_objects(cfg: WorldConfig, world: World) -> list[WorldObject]:
    """Objects of every kind, placed off roads and water, not overlapping; then the 'extra' pool."""
    rng = rng_for(cfg.seed, _T_OBJECTS)
    area_km2 = (cfg.size_m / 1000.0) ** 2
    scale = cfg.object_density_per_km2 / sum(KIND_DENSITY.values())
    # Distance (m) to the nearest road / stream bank, on a 1 m grid, for the "off the road" test.
    step = max(1, int(round(1.0 / cfg.resolution_m)))
    coarse = world.cover[::step, ::step]
    free = ~np.isin(coarse, (ASPHALT, GRAVEL, WATER, BANK))
    dist = cv2.distanceTransform(free.astype(np.uint8), cv2.DIST_L2, 5) * np.float32(step * cfg.resolution_m)
    margin_rc = np.argwhere(world.cover[::step, ::step] == MARGIN)

    placed: list[WorldObject] = []
    pos = np.zeros((0, 2))
    rad = np.zeros(0)
    size = cfg.size_m
    groves = rng.uniform(0.1 * size, 0.9 * size, size=(max(1, int(round(area_km2 * 12))), 2))

    def free_at(x: float, y: float, r: float, clearance: float) -> bool:
        if not (r + 5 <= x <= size - r - 5 and r + 5 <= y <= size - r - 5):
            return False
        gi = min(dist.shape[0] - 1, int(y / (step * cfg.resolution_m)))
        gj = min(dist.shape[1] - 1, int(x / (step * cfg.resolution_m)))
        if dist[gi, gj] < r + 1.0:
            return False
        if len(pos):
            d = np.hypot(pos[:, 0] - x, pos[:, 1] - y)
            if np.any(d < (rad + r) * clearance):
                return False
        return True

    def propose(kind: str) -> tuple[float, float]:
        u = rng.random()
        if kind in ("deciduous", "conifer") and u < 0.45:
            g = groves[rng.integers(len(groves))]
            return tuple(g + rng.normal(0, 18.0, 2))
        if kind in ("deciduous", "bush") and u < 0.75 and len(margin_rc):
            r, c = margin_rc[rng.integers(len(margin_rc))]
            return ((c + 0.5) * step * cfg.resolution_m, (r + 0.5) * step * cfg.resolution_m)
        if kind == "building" and u < 0.8:
            kind_road, _, pts = world.roads[rng.integers(2)]
            i = rng.integers(len(pts) - 1)
            a, b = pts[i], pts[i + 1]
            t = rng.random()
            p = a + t * (b - a)
            nrm = np.array([-(b - a)[1], (b - a)[0]]) / (np.linalg.norm(b - a) + 1e-9)
            return tuple(p + nrm * rng.choice([-1, 1]) * rng.uniform(14, 26))
        return (rng.uniform(0, size), rng.uniform(0, size))

    kinds_order = ["pond", "building", "deciduous", "conifer", "bush", "boulder"]
    counts = {k: int(round(KIND_DENSITY[k] * scale * area_km2)) for k in KINDS}
    plan: list[tuple[str, bool]] = []
    for k in kinds_order:
        plan += [(k, True)] * counts[k]
    n_extra = int(round(EXTRA_FRACTION * len(plan)))
    extra_kinds = rng.choice(["deciduous", "conifer", "bush", "boulder", "building"], size=n_extra,
                             p=[0.35, 0.25, 0.2, 0.1, 0.1])
    plan += [(str(k), False) for k in extra_kinds]
    for kind, present in plan:
        shape = _draw_shape(kind, rng)
        for _ in range(40):
            x, y = propose(kind)
            clearance = 0.75 if kind in ("deciduous", "conifer", "bush") else 1.15
            if free_at(x, y, shape["r_nominal"], clearance):
                break
        else:
            continue
        obj = _finish_object(len(placed) + 1, kind, x, y, shape, present, world)
        placed.append(obj)
        pos = np.vstack([pos, [x, y]])
        rad = np.append(rad, shape["r_nominal"] + (3.0 if kind == "building" else 0.0))
    return placed


def _draw_shape(kind: str, rng: np.random.Generator) -> dict:
    if kind == "deciduous":
        r = float(np.clip(rng.lognormal(math.log(3.8), 0.35), 1.5, 8.0))
        h = float(np.clip(r * rng.uniform(1.6, 2.6), 5.0, 22.0))
        return {"r_nominal": r, "height": h}
    if kind == "conifer":
        r = float(rng.uniform(1.2, 3.8))
        h = float(np.clip(r * rng.uniform(4.0, 6.5), 6.0, 25.0))
        return {"r_nominal": r, "height": h}
    if kind == "bush":
        r = float(rng.uniform(0.8, 2.4))
        return {"r_nominal": r, "height": float(rng.uniform(0.8, 2.2))}
    if kind == "boulder":
        r = float(rng.uniform(0.6, 1.8))
        return {"r_nominal": r, "height": float(r * rng.uniform(0.5, 0.9))}
    if kind == "building":
        length = float(rng.uniform(8, 22))
        width = float(rng.uniform(6, min(14, length)))
        roof = str(rng.choice(["gable", "gable", "gable", "flat"]))
        eave = float(rng.uniform(3.0, 7.0))
        ridge = float(width * rng.uniform(0.25, 0.45)) if roof == "gable" else 0.0
        return {"r_nominal": 0.5 * math.hypot(length, width), "length": length, "width": width, "roof": roof,
                "eave_h": eave, "height": eave + ridge, "angle": float(rng.uniform(0, math.pi))}
    if kind == "pond":
        return {"r_nominal": float(rng.uniform(4.0, 11.0)), "height": 0.0}
    raise ValueError(kind)


def _finish_object(oid: int, kind: str, x: float, y: float, shape: dict, present: bool,
                   world: World) -> WorldObject:
    ground = float(world.terrain_sampler.height_at(x, y))
    r = shape["r_nominal"]
    if kind == "building":
        radius = math.sqrt(shape["length"] * shape["width"] / math.pi)
        top = ground + shape["height"]
        return WorldObject(oid, kind, x, y, ground, top, radius, shape["height"], present, r,
                           angle=shape["angle"], length=shape["length"], width=shape["width"],
                           eave_h=shape["eave_h"], roof=shape["roof"])
    if kind == "pond":
        # Water level: just below the lowest terrain under the pond, so the surface is flat and sunken.
        ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        xs = np.concatenate([[x], x + r * np.cos(ang), x + 0.5 * r * np.cos(ang)])
        ys = np.concatenate([[y], y + r * np.sin(ang), y + 0.5 * r * np.sin(ang)])
        level = float(world.terrain_sampler.height_at(xs, ys).min()) - 0.3
        return WorldObject(oid, kind, x, y, ground, level, r, 0.0, present, r)
    return WorldObject(oid, kind, x, y, ground, ground + shape["height"], r, shape["height"], present, r)


# --------------------------------------------------------------------------------------------------- stamping

@dataclass
class Scene:
    """The rasters one session renders from: the world with the session's objects, in one season."""

    world: World
    season: str
    present: np.ndarray  # bool per object (index = id - 1)
    dsm: np.ndarray  # float32 surface heights (terrain + objects)
    ids: np.ndarray  # uint16 object id of the surface (0 = ground)
    ids_dilated: np.ndarray  # ids grown by one cell (for rays that hit object walls at a cell edge)
    albedo: np.ndarray  # uint8 (n, n, 3) sRGB
    wall_colour: np.ndarray  # uint8 (max id + 1, 3): wall albedo of buildings by id, 0 for other objects


def build_scene(world: World, season: str, present: np.ndarray) -> Scene:
    """Stamp the present objects into the DSM, the id raster and the season's albedo."""
    present = np.asarray(present, bool)
    if len(present) != len(world.objects):
        raise ValueError("present must have one flag per world object")
    dsm = world.terrain.copy()
    ids = np.zeros(dsm.shape, np.uint16)
    albedo = world.ground_albedo(season).copy()
    order = sorted((o for o, p in zip(world.objects, present) if p), key=lambda o: (o.kind != "pond", o.top_z))
    for obj in order:
        _stamp(world, obj, season, dsm, ids, albedo)
    # Anti-aliasing: a pixel of the camera integrates ~0.2 m of ground; blur the albedo by about a cell.
    albedo = cv2.GaussianBlur(albedo, (0, 0), 0.6)
    ids_dilated = cv2.dilate(ids, np.ones((3, 3), np.uint8))
    walls = np.zeros((len(world.objects) + 1, 3), np.uint8)
    plaster = [(206, 200, 188), (188, 176, 160), (160, 96, 76), (128, 104, 84), (214, 212, 206)]
    for o in world.objects:
        if o.kind == "building":
            walls[o.id] = plaster[int(rng_for(world.config.seed, _T_OBJECT, o.id).random(9)[8] * len(plaster))]
    return Scene(world, season, present, dsm, ids, ids_dilated, albedo, walls)


def _outline(rng: np.random.Generator, ang: np.ndarray, amp: float) -> np.ndarray:
    """Irregular outline radius factor around 1 (a few random harmonics)."""
    f = np.ones_like(ang)
    for k in range(2, 7):
        f += np.float32(amp * rng.normal(0, 1.0) / k ** 0.7) * np.cos(k * ang + np.float32(rng.uniform(0, 2 * np.pi)))
    return f


def _stamp(world: World, obj: WorldObject, season: str, dsm: np.ndarray, ids: np.ndarray, albedo: np.ndarray) -> None:
    res, n = world.res, world.n
    rng = rng_for(world.config.seed, _T_OBJECT, obj.id)  # per object: independent of the others present
    ext = obj.r_nominal * (1.35 if obj.kind != "building" else 1.05) + 2 * res
    c0 = max(0, int(math.floor((obj.x - ext) / res)))
    c1 = min(n, int(math.ceil((obj.x + ext) / res)) + 1)
    r0 = max(0, int(math.floor((obj.y - ext) / res)))
    r1 = min(n, int(math.ceil((obj.y + ext) / res)) + 1)
    if c1 <= c0 or r1 <= r0:
        return
    xs = ((np.arange(c0, c1, dtype=np.float32) + 0.5) * np.float32(res) - np.float32(obj.x))[None, :]
    ys = ((np.arange(r0, r1, dtype=np.float32) + 0.5) * np.float32(res) - np.float32(obj.y))[:, None]
    shape = (r1 - r0, c1 - c0)
    rho = np.sqrt(xs * xs + ys * ys)
    ang = np.arctan2(ys, xs)
    patch_m = (shape[0] * res, shape[1] * res)
    clump = value_noise(rng, shape, (patch_m[0] / 0.9, patch_m[1] / 0.9))
    clump2 = value_noise(rng, shape, (patch_m[0] / 0.4, patch_m[1] / 0.4))
    u = rng.random(8)  # per-object look choices, drawn before any season-specific use
    g = np.float32(obj.ground_z)
    kind = obj.kind
    colour: np.ndarray
    if kind == "building":
        ca, sa = np.float32(math.cos(obj.angle)), np.float32(math.sin(obj.angle))
        lu = xs * ca + ys * sa
        lv = -xs * sa + ys * ca
        inside = (np.abs(lu) <= obj.length / 2) & (np.abs(lv) <= obj.width / 2)
        if obj.roof == "gable":
            frac = 1.0 - np.abs(lv) / np.float32(obj.width / 2)
            z = g + np.float32(obj.eave_h) + np.float32(obj.height - obj.eave_h) * frac
        else:
            edge = np.minimum(obj.length / 2 - np.abs(lu), obj.width / 2 - np.abs(lv))
            z = g + np.float32(obj.eave_h) + np.where(edge < 0.35, np.float32(0.3), np.float32(0.0))
            frac = np.zeros_like(z)
        z = np.broadcast_to(z, shape)
        roofs = [(150, 72, 56), (118, 84, 62), (104, 106, 110), (66, 66, 72), (92, 110, 100), (170, 96, 70)]
        base = np.asarray(roofs[int(u[0] * len(roofs))], np.float32)
        if obj.roof == "flat":
            base = np.asarray([(120, 120, 118), (96, 96, 98), (140, 136, 128)][int(u[1] * 3)], np.float32)
            pattern = 1.0 + 0.05 * clump2 + 0.04 * clump
        else:
            pattern = 0.93 + 0.07 * np.cos(2 * np.pi * lv / 0.6) + 0.04 * clump + 0.03 * clump2
            pattern = np.where(frac > 0.97, np.float32(0.75), pattern)  # ridge cap
        if season == "winter":
            snowy = (np.asarray((234, 237, 243), np.float32) * (1.0 + 0.02 * clump2)[..., None])
            eave_band = np.minimum(obj.length / 2 - np.abs(lu), obj.width / 2 - np.abs(lv)) < 0.3
            colour = np.where(eave_band[..., None], base * 0.8, snowy)
        else:
            colour = base * pattern[..., None]
        mask = np.broadcast_to(inside, shape)
    elif kind == "pond":
        edge = np.float32(obj.r_nominal) * _outline(rng, ang, 0.12)
        rn = rho / edge
        mask = rn < 1.0
        z = np.full(shape, np.float32(obj.top_z))
        water = np.asarray(GROUND["water"][season], np.float32)
        bank = np.asarray(GROUND["bank"][season], np.float32)
        depth = np.clip(1.0 - rn, 0, 1)
        if season == "winter":
            colour = water * (0.97 + 0.03 * clump2)[..., None]
            colour = np.where((clump2 > 1.2)[..., None], colour * 0.85, colour)  # cracks / thin ice
        else:
            colour = water * (1.15 - 0.35 * depth + 0.04 * clump2)[..., None]
            shore = np.clip((rn - 0.82) / 0.18, 0, 1)[..., None]
            colour = colour * (1 - shore) + bank * shore
    else:
        amp = {"deciduous": 0.10, "conifer": 0.06, "bush": 0.12, "boulder": 0.10}[kind]
        edge = np.float32(obj.r_nominal) * _outline(rng, ang, amp)
        rn = rho / edge
        mask = rn < 1.0
        q = np.sqrt(np.clip(1.0 - rn * rn, 0.0, 1.0))
        # Surface roughness (leaf clumps) fades out at the centre so that the top is exactly top_z.
        rough = clump * q * np.clip(rn / 0.25, 0.0, 1.0)
        h = np.float32(obj.height)
        if kind == "deciduous":
            crown = np.float32(min(0.65 * obj.height, 1.2 * obj.r_nominal))
            z = g + (h - crown) + crown * q + np.float32(0.35) * rough
        elif kind == "conifer":
            # A cone with a small rounded tip (radius 15 % of the crown): a needle-thin apex would be
            # narrower than a pixel and than the renderer's march step.
            rt = np.float32(0.15)
            prof = np.where(rn >= rt, 1.0 - rn, 1.0 - rt / 2 - rn * rn / (2 * rt)) / (1.0 - rt / 2)
            z = g + np.float32(0.8) + (h - np.float32(0.8)) * np.clip(prof, 0, 1) + np.float32(0.15) * rough
        elif kind == "bush":
            z = g + h * q ** 0.7 + np.float32(0.12) * rough
        else:
            z = g + h * q + np.float32(0.04) * rough
        colour = _vegetation_colour(kind, season, u, rn, ang, clump, clump2)
    inside = mask & (z >= dsm[r0:r1, c0:c1] - 1e-3) if kind != "pond" else mask
    if not inside.any():
        return
    dsm[r0:r1, c0:c1][inside] = z[inside]
    ids[r0:r1, c0:c1][inside] = obj.id
    albedo[r0:r1, c0:c1][inside] = np.clip(colour[inside], 0, 255).astype(np.uint8)


_DECID = {
    "summer": [(62, 100, 40), (74, 110, 46), (54, 88, 38), (82, 112, 50)],
    "autumn": [(196, 112, 40), (166, 62, 40), (204, 170, 62), (124, 112, 52), (180, 140, 50)],
    "spring": [(112, 152, 62), (128, 160, 70), (98, 140, 56)],
}
_CONIFER = [(34, 62, 38), (40, 70, 44), (30, 54, 36)]
_BUSH = {"summer": (72, 106, 44), "autumn": (150, 104, 52), "spring": (104, 142, 58)}
_SNOW = np.asarray((232, 235, 242), np.float32)
_BARK = np.asarray((92, 82, 72), np.float32)


def _vegetation_colour(kind: str, season: str, u: np.ndarray, rn: np.ndarray, ang: np.ndarray,
                       clump: np.ndarray, clump2: np.ndarray) -> np.ndarray:
    leaves = 0.80 + 0.14 * clump + 0.08 * clump2  # leaf clumps: brighter tops, darker gaps
    edge_dark = 1.0 - 0.12 * np.clip(rn, 0, 1) ** 2
    shade = (leaves * edge_dark)[..., None]
    if kind == "deciduous":
        if season == "winter":  # leaf-off: a fuzzy web of branches over the snow
            branches = np.abs(np.cos(7 * ang + 2.5 * clump)) ** 6
            density = np.clip(0.30 + 0.55 * (1 - rn) + 0.25 * branches + 0.12 * clump2, 0, 1)[..., None]
            return _SNOW * (1 - density) + _BARK * density
        palette = _DECID[season]
        base = np.asarray(palette[int(u[1] * len(palette))], np.float32)
        if season == "autumn":  # mixed colours inside one crown
            other = np.asarray(palette[int(u[2] * len(palette))], np.float32)
            t = np.clip(0.5 + 0.5 * clump, 0, 1)[..., None]
            base = base * (1 - t) + other * t
        if season == "spring" and u[3] < 0.15:  # a blossoming tree
            base = np.asarray((226, 214, 222), np.float32)
        return base * shade
    if kind == "conifer":
        base = np.asarray(_CONIFER[int(u[1] * len(_CONIFER))], np.float32)
        whorl = (0.85 + 0.15 * np.cos(9 * ang + 1.5 * clump) * np.clip(rn * 2, 0, 1))[..., None]
        colour = base * shade * whorl
        if season == "winter":
            specks = (clump2 > 0.9)[..., None]
            colour = np.where(specks, _SNOW * 0.9, colour * 0.9)
        return colour
    if kind == "bush":
        if season == "winter":
            density = np.clip(0.45 + 0.35 * (1 - rn) + 0.2 * clump2, 0, 1)[..., None]
            return _SNOW * (1 - density) + np.asarray((118, 100, 84), np.float32) * density
        return np.asarray(_BUSH[season], np.float32) * shade * np.float32(0.9 + 0.2 * u[4])
    # boulder
    grey = np.float32(100 + 50 * u[1])
    base = np.asarray((grey, grey * 0.98, grey * 0.93), np.float32)
    colour = base * (0.9 + 0.08 * clump + 0.06 * clump2)[..., None]
    if season == "winter":
        cap = (rn < 0.72)[..., None]
        colour = np.where(cap, _SNOW, colour)
    return colour


# ------------------------------------------------------------------------------------------- ground truth

def visible_top_centres(scene: Scene) -> np.ndarray:
    """Ground truth of every world object's position: the 3D centre of its visible top surface (float64, one
    row x, y, z per object, index = id - 1).

    The centre is the mean over the object's cells in the scene's object-id raster (its footprint as a nadir
    camera sees it: other objects covering part of it are excluded) of the cell centres' x, y and the DSM
    height: the area-weighted mean of the top surface seen from straight above. A mask centroid triangulated
    from several views lands about there, not at the apex (a tree's crown centre is metres below its tip).
    Objects absent from the scene or entirely hidden by others get the centre they would have alone (each
    stamped on the bare terrain); an object too small to cover any cell keeps (x, y, top_z).
    """
    world = scene.world
    out = np.array([(o.x, o.y, o.top_z) for o in world.objects], np.float64).reshape(-1, 3)
    counts = _footprint_means(world, scene.ids, scene.dsm, out)
    missing = [o for o in world.objects if counts[o.id] == 0]
    if missing:
        # Alone on the bare terrain, in the order build_scene stamps (ponds first, then by height).
        dsm = world.terrain.copy()
        ids = np.zeros(dsm.shape, np.uint16)
        albedo = np.zeros(dsm.shape + (3,), np.uint8)  # needed by _stamp, discarded
        for obj in sorted(missing, key=lambda o: (o.kind != "pond", o.top_z)):
            _stamp(world, obj, scene.season, dsm, ids, albedo)
        alone = out.copy()
        _footprint_means(world, ids, dsm, alone)
        idx = np.array([o.id - 1 for o in missing])
        out[idx] = alone[idx]
    return out


def _footprint_means(world: World, ids: np.ndarray, dsm: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Write into `out` (rows id - 1) the mean cell-centre x, y and DSM height of every id present in `ids`;
    return the cell count per id (index = id)."""
    rows, cols = np.nonzero(ids)  # objects cover a few % of the world: index them, not the whole raster
    lab = ids[rows, cols].astype(np.int64)
    m = len(world.objects) + 1
    count = np.bincount(lab, minlength=m)
    seen = np.nonzero(count)[0]
    seen = seen[seen > 0]
    for axis, values in enumerate(((cols + 0.5) * world.res, (rows + 0.5) * world.res,
                                   dsm[rows, cols].astype(np.float64))):
        sums = np.bincount(lab, weights=values, minlength=m)
        out[seen - 1, axis] = sums[seen] / count[seen]
    return count
