"""A session's scene of a synthetic world: the present objects stamped into the surface model, the object-id
raster and the season's albedo (`build_scene`), and the ground truth the renderer's cameras see of them
(`visible_top_centres`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .appearance import GROUND
from .noise import rng_for, value_noise
from .world import _T_OBJECT, World, WorldObject


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
