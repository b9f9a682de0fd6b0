"""The objects of a synthetic world: placement of every kind off roads and water without overlaps, their shapes,
and the pool of extra objects a session can add (`place_objects`, called once when a `World` is built)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .noise import rng_for
from .world import _T_OBJECTS, ASPHALT, BANK, EXTRA_FRACTION, GRAVEL, KIND_DENSITY, KINDS, MARGIN, WATER, WorldObject

if TYPE_CHECKING:
    from .world import World, WorldConfig


def place_objects(cfg: WorldConfig, world: World) -> list[WorldObject]:
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
