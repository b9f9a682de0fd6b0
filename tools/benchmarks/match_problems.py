"""The problems of the association benchmark (`bench_match.py`): one CLIPPER problem and synthetic maps of every
kind, each deterministic in its seed.

- clipper: 100 true associations of a rigid copy (100 landmarks per map in a 100 x 100 x 10 m box, noise 0.1 m)
  plus random wrong pairs up to m putative associations; eps 2 m, sigma 0.5 m; time = affinity + solve.
- sparse: two synthetic survey maps of ~1000 landmarks (`plugin/association/synthetic.py`: 300 landmarks/km^2,
  lawnmower id order, sizes 1-8 m with 10 % noise, half of the area shared, position noise 0.4 m, 10 % missing,
  5 % added, arbitrary yaw, 2 deg tilt).
- dense: the demo's density: ~600 landmarks in 200 m x 200 m (15,000 / km^2), lines 30 m apart, 95 % overlap,
  0.7 m noise (one flight mapped twice, exact vs EKF poses, as the issue's 686 x 622 demo maps).
- nosizes: maps whose sizes say nothing (another robot's boulder maps: 392 x 212 landmarks, size gate open,
  eps 0.2 m): boulders on flat ground (60 m x 60 m, heights 0-1.5 m), B 212 of A's 392 with 3 cm noise.
- aerial: NAIP-like maps of 1000-1200 landmarks (the sharper NAIP dates give 950-1130): a 4.7 x 3.6 km tile
  flown in lines 800 m apart, landmarks 5-60 m across on flat ground (z = 0), 12 % of them segmented alike on both
  dates, those 5-7 m apart (centroid scatter 4 m plus a 3 m georeference offset), sizes re-segmented (r ~0.2);
  aerial preset; both georeferenced (the prior applies) and, for the record, without the prior.
- crossing: two flights over one area crossing at 0 / 45 / 90 deg: how many common landmarks lie in a window pair
  holding more than theta_S common ones (id vs spatial windows), and what the match finds.
- season: a season map of 100,000 landmarks (100 survey flights of ~1000 landmarks over 10 km x 10 km, each in
  its own lawnmower order, concatenated) and a new flight of 2,000 landmarks over 1.4 km x 1.4 km of it
  (georeferenced: 3 m offset, 0.5 deg yaw), with a position prior of 30 m.
- scaling: search time of two sparse survey maps of n x n landmarks without a prior, n up to --max-scaling.
"""

from __future__ import annotations

import numpy as np

from ...plugin.association.rigid import rotation_from_rpy_deg
from ...plugin.association.synthetic import survey_map_pair


def clipper_problem(m: int, n_true: int = 100, noise: float = 0.1, seed: int = 0) -> tuple:
    """Points of A and B, m putative pairs (the first n_true rows true before shuffling), truth mask."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (n_true, 3)) * [100.0, 100.0, 10.0]
    r = rotation_from_rpy_deg(*rng.uniform(-3, 3, 2), rng.uniform(-180, 180))
    b = a @ r.T + rng.uniform(-100, 100, 3) + rng.normal(0, noise, a.shape)
    wrong = set()
    while len(wrong) < m - n_true:
        i, j = rng.integers(0, n_true, 2)
        if i != j:
            wrong.add((int(i), int(j)))
    pairs = np.concatenate([np.stack([np.arange(n_true)] * 2, 1), np.array(sorted(wrong)).reshape(-1, 2)])
    perm = rng.permutation(len(pairs))
    return a, b, pairs[perm], perm < n_true


def dense_maps() -> object:
    return survey_map_pair(620, seed=3, density_per_km2=15000, strip_width_m=30, overlap=0.95, noise_m=0.7)


def boulder_maps(seed: int = 0) -> tuple:
    """392 boulders on flat ground, 212 of them seen again in another frame with 3 cm noise; no sizes."""
    rng = np.random.default_rng(seed)
    a = np.column_stack([rng.uniform(0, 60, 392), rng.uniform(0, 60, 392), rng.uniform(0, 1.5, 392)])
    keep = np.sort(rng.choice(392, 212, replace=False))
    r = rotation_from_rpy_deg(0.5, -0.3, rng.uniform(-180, 180))
    t = np.array([12.0, -40.0, 0.3])
    b = (a[keep] - t) @ r + rng.normal(0, 0.03, (212, 3))  # x_B = R^T (x_A - t)
    return a, b, r, t, {(int(i), k) for k, i in enumerate(keep)}


def aerial_maps(n_a: int = 1100, n_b: int = 1000, seed: int = 0, common: float = 0.12) -> tuple:
    """NAIP-like maps of one 4.7 km x 3.6 km tile on two dates (see the module docstring); world = UTM-like."""
    rng = np.random.default_rng(seed)
    w, h = 4700.0, 3600.0
    n_c = int(common * min(n_a, n_b))
    obj = np.column_stack([rng.uniform(0, w, n_c), rng.uniform(0, h, n_c)])
    size = np.exp(rng.uniform(np.log(5.0), np.log(60.0), n_c))

    def date(n: int, offset: np.ndarray) -> tuple:
        xy = obj + rng.normal(0, 4.0, obj.shape) + offset
        hs = size * np.exp(rng.normal(0, 0.2, n_c))
        extra = np.column_stack([rng.uniform(0, w, n - n_c), rng.uniform(0, h, n - n_c)])
        hx = np.exp(rng.uniform(np.log(5.0), np.log(60.0), n - n_c))
        pts = np.vstack([xy, extra])
        sizes = np.concatenate([hs, hx])
        ids = np.concatenate([np.arange(n_c), -np.ones(n - n_c, np.int64)])
        line = np.floor(pts[:, 1] / 800.0).astype(int)  # flight lines 800 m apart, flown back and forth
        along = np.where(line % 2 == 0, pts[:, 0], -pts[:, 0])
        order = np.lexsort((along, line))
        pos = np.column_stack([pts[order], np.zeros(n)]) + [500000.0, 4700000.0, 0.0]
        return pos, sizes[order], ids[order]

    pa, ha, ida = date(n_a, np.zeros(2))
    pb, hb, idb = date(n_b, np.array([2.0, -2.2]))
    ia = {int(o): k for k, o in enumerate(ida) if o >= 0}
    truth = {(ia[int(o)], k) for k, o in enumerate(idb) if o >= 0}
    return pa, ha, pb, hb, truth


def crossing_maps(angle_deg: float, seed: int = 5) -> tuple:
    """One 600 m x 600 m area at 1500 landmarks/km^2 flown twice, lines 30 m apart, the second flight's lines
    turned by `angle_deg` (each map in its flight's id order, B in its own frame)."""
    rng = np.random.default_rng(seed)
    n = rng.poisson(1500 * 0.36)
    world = np.column_stack([rng.uniform(0, 600, n), rng.uniform(0, 600, n), rng.uniform(0, 15, n)])
    size = rng.uniform(1, 8, n)

    def flight(turn: float, noise: float) -> tuple:
        keep = np.flatnonzero(rng.random(n) > 0.1)
        c, s_ = np.cos(np.radians(turn)), np.sin(np.radians(turn))
        u = (world[keep, 0] - 300) * c + (world[keep, 1] - 300) * s_  # across the lines
        v = -(world[keep, 0] - 300) * s_ + (world[keep, 1] - 300) * c  # along them
        line = np.floor(u / 30.0).astype(int)
        order = np.lexsort((np.where(line % 2 == 0, v, -v), line))
        keep = keep[order]
        pts = world[keep] + rng.normal(0, noise, (len(keep), 3))
        return pts, size[keep] * (1 + rng.normal(0, 0.1, len(keep))), keep

    pa, ha, ka = flight(0.0, 0.0)
    pw, hb, kb = flight(angle_deg, 0.4)
    r = rotation_from_rpy_deg(0.5, 0.3, 37.0)
    pb = (pw - [300.0, 300.0, 0.0]) @ r  # B in its own frame
    ia = {int(o): i for i, o in enumerate(ka)}
    truth = {(ia[int(o)], j) for j, o in enumerate(kb) if int(o) in ia}
    return pa, ha.clip(0.3), pb, hb.clip(0.3), truth, r


def season_maps(seed: int = 2) -> tuple:
    """A season map (100 flights of 1 km^2, ~1000 landmarks each, concatenated) and a new 2000-landmark flight."""
    rng = np.random.default_rng(seed)
    tiles = []
    for ty in range(10):
        for tx in range(10):
            n = rng.poisson(1000)
            xy = rng.uniform(0, 1000, (n, 2))
            line = np.floor(xy[:, 0] / 100.0).astype(int)
            order = np.lexsort((np.where(line % 2 == 0, xy[:, 1], -xy[:, 1]), line))
            tiles.append(np.column_stack([xy[order] + [tx * 1000.0, ty * 1000.0], rng.uniform(0, 15, n)]))
    world = np.vstack(tiles)
    sizes = rng.uniform(1, 8, len(world))
    x0, y0 = 4300.0, 5200.0
    inside = np.flatnonzero((world[:, 0] >= x0) & (world[:, 0] < x0 + 1420) & (world[:, 1] >= y0)
                            & (world[:, 1] < y0 + 1420))
    sel = inside[rng.random(len(inside)) > 0.05][:2000]
    line = np.floor((world[sel, 0] - x0) / 100.0).astype(int)
    sel = sel[np.lexsort((np.where(line % 2 == 0, world[sel, 1], -world[sel, 1]), line))]
    r = rotation_from_rpy_deg(0.0, 0.0, 0.5)
    new = (world[sel] - [x0, y0, 0]) @ r.T + [x0, y0, 0] + [3.0, -2.0, 0.5] + rng.normal(0, 0.4, (len(sel), 3))
    hn = sizes[sel] * (1 + rng.normal(0, 0.1, len(sel)))
    offset = np.array([500000.0, 4700000.0, 0.0])
    return new + offset, hn.clip(0.3), world + offset, sizes, {(k, int(i)) for k, i in enumerate(sel)}
