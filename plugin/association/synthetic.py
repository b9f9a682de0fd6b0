"""Synthetic survey landmark maps with a known transform: the test and benchmark problems of this stage.

Landmarks (trees, objects) are spread uniformly over the ground at `density_per_km2`, sized 1-8 m, and numbered
in lawnmower order (strips of `strip_width_m` flown back and forth), so id order is time order as in a real map.
Map A covers x in [0, L]; map B covers x in [(1 - overlap) L, (2 - overlap) L] of the same world, loses and gains
some landmarks, has position noise and size noise, and is expressed in its own frame: x_B = R^T (x_W - t), i.e.
the true A_from_B transform is (R, t) because A is in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rigid import rotation_from_rpy_deg


@dataclass(frozen=True)
class SyntheticPair:
    points_a: np.ndarray
    sizes_a: np.ndarray
    points_b: np.ndarray
    sizes_b: np.ndarray
    rotation: np.ndarray  # true A_from_B rotation
    translation: np.ndarray  # true A_from_B translation
    truth: np.ndarray  # (k, 2) true associations (index in A, index in B)


def _lawnmower_order(xy: np.ndarray, x0: float, strip_width_m: float) -> np.ndarray:
    strip = np.floor((xy[:, 0] - x0) / strip_width_m).astype(np.int64)
    along = np.where(strip % 2 == 0, xy[:, 1], -xy[:, 1])
    return np.lexsort((along, strip))


def survey_map_pair(n_landmarks: int, seed: int = 0, density_per_km2: float = 300.0, overlap: float = 0.5,
                    noise_m: float = 0.4, size_noise: float = 0.1, missing: float = 0.1, added: float = 0.05,
                    strip_width_m: float = 100.0, yaw_deg: float | None = None,
                    tilt_deg: float = 2.0, missing_b: float | None = None,
                    added_b: float | None = None) -> SyntheticPair:
    """Two maps of about `n_landmarks` each sharing `overlap` of their area; deterministic in `seed`.

    missing_b / added_b (default: `missing` / `added`): B's own fractions, for maps of unequal density (a winter
    map that keeps a tenth of the summer objects and segments as many again of its own)."""
    rng = np.random.default_rng(seed)
    side = 1000.0 * np.sqrt(n_landmarks / ((1.0 - missing) * density_per_km2))  # metres
    width = (2.0 - overlap) * side
    n_world = rng.poisson(density_per_km2 * width * side / 1e6)
    xy = rng.uniform([0.0, 0.0], [width, side], (n_world, 2))
    z = 0.02 * xy[:, 0] + 5.0 * np.sin(xy[:, 1] / 300.0) + rng.uniform(0.0, 15.0, n_world)  # gentle terrain + height
    world = np.column_stack([xy, z])
    size = rng.uniform(1.0, 8.0, n_world)

    def observe(lo: float, noisy: bool, missing: float, added: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ids = np.flatnonzero((xy[:, 0] >= lo) & (xy[:, 0] < lo + side) & (rng.random(n_world) >= missing))
        pos = world[ids] + (rng.normal(0.0, noise_m, (len(ids), 3)) if noisy else 0.0)
        h = size[ids] * (1.0 + (rng.normal(0.0, size_noise, len(ids)) if noisy else 0.0))
        n_add = rng.poisson(added * len(ids))
        add_xy = rng.uniform([lo, 0.0], [lo + side, side], (n_add, 2))
        add = np.column_stack([add_xy, rng.uniform(0.0, 20.0, n_add)])
        pos = np.concatenate([pos, add])
        h = np.concatenate([h, rng.uniform(1.0, 8.0, n_add)])
        ids = np.concatenate([ids, -np.ones(n_add, dtype=np.int64)])
        order = _lawnmower_order(pos, lo, strip_width_m)
        return pos[order], np.abs(h[order]).clip(0.3), ids[order]

    pa, ha, ida = observe(0.0, False, missing, added)
    pw, hb, idb = observe((1.0 - overlap) * side, True, missing if missing_b is None else missing_b,
                          added if added_b is None else added_b)
    yaw = rng.uniform(-180.0, 180.0) if yaw_deg is None else yaw_deg
    tilt_dir = rng.uniform(0, 2 * np.pi)
    r = rotation_from_rpy_deg(tilt_deg * np.cos(tilt_dir), tilt_deg * np.sin(tilt_dir), yaw)
    t = np.array([width / 2, side / 2, 0.0]) + rng.uniform(-200, 200, 3) * [1, 1, 0.1]
    pb = (pw - t) @ r  # x_B = R^T (x_W - t)
    common, ia, ib = np.intersect1d(ida[ida >= 0], idb[idb >= 0], return_indices=True)
    ia = np.flatnonzero(ida >= 0)[ia]
    ib = np.flatnonzero(idb >= 0)[ib]
    truth = np.column_stack([ia, ib])
    return SyntheticPair(pa, ha.astype(np.float32), pb, hb.astype(np.float32), r, t, truth[np.argsort(ia)])
