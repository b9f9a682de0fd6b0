"""Refining a pairwise alignment on the full maps (pure numpy + scipy's KD-tree): iterated size-gated mutual
nearest neighbours with a Huber-weighted 4-DOF (yaw + translation, gravity-aligned maps) or 6-DOF refit.

Used by the match's verification (`plugin.verification`) and by `merge --refine`. Transforms are
`multisession.Sim3` a_from_b (B's landmarks into A's frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .association.gates import size_ratio
from .multisession import Sim3


def yaw_matrix(yaw: float) -> np.ndarray:
    """The rotation by `yaw` radians about the vertical (z) axis."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def tilt_of(rotation: np.ndarray) -> np.ndarray:
    """The roll/pitch part T of a rotation R = Rz(yaw) T (yaw: the heading of R's x axis): what a yaw +
    translation fit of B turned by T leaves as the rotation's tilt."""
    yaw = np.arctan2(rotation[1, 0], rotation[0, 0])
    return yaw_matrix(-yaw) @ rotation


def fit_yaw_translation(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
                        with_scale: bool = False) -> Sim3:
    """Weighted least-squares 4-DOF transform target ≈ Rz(yaw) source + t (gravity-aligned frames); with
    `with_scale` 5-DOF, target ≈ s Rz(yaw) source + t with the scale fitted on the horizontal coordinates.

    Both maps' z axes point up (roll and pitch are observable from gravity, the premise of the method's gravity
    check), so only the yaw and the translation are unknown. Fitting 4 instead of 6 degrees of freedom keeps
    the metre-level vertical noise of landmarks out of the rotation. Needs horizontal spread in the points;
    raises ValueError otherwise.
    """
    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(src) != len(dst) or len(src) != len(w) or len(src) < 2 or w.sum() <= 0:
        raise ValueError(f"need >= 2 weighted correspondences of equal count, got {len(src)} and {len(dst)}")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    num = w @ (xs[:, 0] * xd[:, 1] - xs[:, 1] * xd[:, 0])
    den = w @ (xs[:, 0] * xd[:, 0] + xs[:, 1] * xd[:, 1])
    spread = float(w @ np.sum(xs[:, :2] ** 2, axis=1))
    if np.hypot(num, den) < 1e-12 * max(spread, 1e-300):
        raise ValueError("correspondences have no horizontal spread; the yaw is not determined")
    rot = yaw_matrix(np.arctan2(num, den))
    scale = float(np.hypot(num, den) / spread) if with_scale else 1.0
    return Sim3(rot, mu_d - scale * rot @ mu_s, scale)


def mutual_nearest(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    gate_m: float, max_size_difference: float, z_weight: float = 0.5, tree_a: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours between two landmark maps already in one frame.

    Candidates are pairs within `gate_m` under the distance sqrt(dx² + dy² + (z_weight dz)²) (landmark heights
    are noisier than their ground positions) whose relative size difference is at most `max_size_difference`
    (sizes NaN or None: no size gate). A pair is kept when each is the other's nearest candidate.
    `tree_a`: `pairing_tree(points_a, z_weight)` when one map A is paired with many placements of B (built once).
    Returns ((K,2) landmark index pairs (A, B) sorted by A, (K,) distances).
    """
    from scipy.spatial import cKDTree

    pa = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, dtype=np.float64).reshape(-1, 3) * [1.0, 1.0, z_weight]
    empty = (np.zeros((0, 2), np.int64), np.zeros(0))
    if not len(pa) or not len(pb):
        return empty
    tree_a = pairing_tree(pa, z_weight) if tree_a is None else tree_a
    pairs = tree_a.sparse_distance_matrix(cKDTree(pb), gate_m, output_type="ndarray")
    i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    if sizes_a is not None and sizes_b is not None:
        ok = size_ratio(np.asarray(sizes_a, np.float64)[i], np.asarray(sizes_b, np.float64)[j]) <= max_size_difference
        i, j, d = i[ok], j[ok], d[ok]
    if not len(i):
        return empty
    # nearest candidate of every A landmark and of every B landmark (ties: lower index), then keep mutual ones
    best_a = np.full(len(pa), -1, np.int64)
    order = np.lexsort((j, d, i))
    first = np.r_[True, i[order][1:] != i[order][:-1]]
    best_a[i[order][first]] = j[order][first]
    best_b = np.full(len(pb), -1, np.int64)
    order = np.lexsort((i, d, j))
    first = np.r_[True, j[order][1:] != j[order][:-1]]
    best_b[j[order][first]] = i[order][first]
    keep = (best_a[i] == j) & (best_b[j] == i)
    order = np.argsort(i[keep], kind="stable")
    return np.column_stack([i[keep], j[keep]])[order], d[keep][order]


def pairing_distance(points_a: np.ndarray, points_b: np.ndarray, z_weight: float = 0.5) -> np.ndarray:
    """The distance `mutual_nearest` pairs landmarks by, row by row: sqrt(dx² + dy² + (z_weight dz)²) between
    (N,3) positions already in one frame (z_weight 1: the 3D distance)."""
    d = np.asarray(points_a, dtype=np.float64).reshape(-1, 3) - np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    return np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + (z_weight * d[:, 2]) ** 2)


def pairing_tree(points: np.ndarray, z_weight: float = 0.5) -> Any:
    """The KD-tree `mutual_nearest` pairs a map's landmarks with: positions with heights scaled by z_weight."""
    from scipy.spatial import cKDTree

    return cKDTree(np.asarray(points, dtype=np.float64).reshape(-1, 3) * np.array([1.0, 1.0, z_weight]))


@dataclass(frozen=True)
class Alignment:
    """A pairwise alignment refined on the full maps (`refine_alignment`)."""

    transform: Sim3  # a_from_b
    associations: np.ndarray  # (K,2) mutual nearest neighbours that support it (index in A, index in B)
    rms_m: float  # RMS residual of the supporting associations (weighted distance of `mutual_nearest`)
    iterations: int


def refine_alignment(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    initial: Sim3, gate_m: float, max_size_difference: float, dof: int = 4, with_scale: bool = False,
    max_iterations: int = 20, z_weight: float = 0.5, tree_a: Any = None, coarse_factor: float = 1.0,
) -> Alignment:
    """Refine a_from_b on every landmark the two maps share, not only on one window's associations.

    Iterates (ICP with a size gate): move B by the current transform, pair landmarks by `mutual_nearest`
    within `gate_m`, refit with Huber weights (residuals beyond gate_m / 2 count less, so a wrong pair near the
    gate pulls little), until the set of pairs stops changing. `dof` 4 fits yaw + translation
    (`fit_yaw_translation`, for gravity-aligned maps); 6 a rigid transform; `with_scale` adds a scale to either
    (5 and 7 degrees of freedom, which `dof` 5 and 7 also say: the verification's callers pass one figure through),
    kept when it explains more pairs than the same refinement without it (ties: without).
    Keeps `initial` (and its supporting pairs) when fewer than 3 pairs are found. `tree_a`: as `mutual_nearest`.
    `coarse_factor` > 1: also the same iteration first at a gate of coarse_factor x gate_m, then at gate_m from
    where it converged (coarse to fine), and the one of the two with more pairs (ties: the one-gate result). At
    gate_m alone the pairing settles in the nearest local optimum: where an object is mapped as several
    fragments a few metres apart (crowns, across seasons) and one map is stretched by its EKF drift, a start
    1-2 gates off pairs some landmarks with a neighbouring fragment and the fit stops there (world 97's crossing
    flight: 18 pairs 1.7 m from the optimum with 22; BENCHMARKS.md, issue 16). The wider first gate sees the
    partners of the whole overlap at once; its optimum is not always the one-gate optimum, hence the better of
    the two.
    """
    if dof not in (4, 5, 6, 7):
        raise ValueError(f"dof must be 4, 5, 6 or 7, got {dof}")
    with_scale, dof = with_scale or dof in (5, 7), 4 if dof in (4, 5) else 6
    if with_scale:
        # the scale is kept only where it explains more pairs than the maps' own scale: on a few tens of pairs it
        # is loosely determined, and a scale-free fit settled on fewer pairs of a crossing flight than the rigid
        # one (w229 summer against winter-x45: 19 at scale 0.985 against 21, refused at chance p 0.05 against 4e-4)
        scaled = _refine_stages(points_a, sizes_a, points_b, sizes_b, initial, gate_m, max_size_difference, dof,
                                True, max_iterations, z_weight, tree_a, coarse_factor)
        rigid = _refine_stages(points_a, sizes_a, points_b, sizes_b, initial, gate_m, max_size_difference, dof,
                               False, max_iterations, z_weight, tree_a, coarse_factor)
        return scaled if len(scaled.associations) > len(rigid.associations) else rigid
    return _refine_stages(points_a, sizes_a, points_b, sizes_b, initial, gate_m, max_size_difference, dof, False,
                          max_iterations, z_weight, tree_a, coarse_factor)


def _refine_stages(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                   sizes_b: np.ndarray | None, initial: Sim3, gate_m: float, max_size_difference: float, dof: int,
                   with_scale: bool, max_iterations: int, z_weight: float, tree_a: Any,
                   coarse_factor: float) -> Alignment:
    """`refine_alignment` with one model: at one gate, or coarse to fine (its doc)."""
    fine = _refine_at_gate(points_a, sizes_a, points_b, sizes_b, initial, gate_m, max_size_difference, dof,
                           with_scale, max_iterations, z_weight, tree_a)
    if coarse_factor <= 1.0:
        return fine
    coarse = _refine_at_gate(points_a, sizes_a, points_b, sizes_b, initial, coarse_factor * gate_m,
                             max_size_difference, dof, with_scale, max_iterations, z_weight, tree_a).transform
    polished = _refine_at_gate(points_a, sizes_a, points_b, sizes_b, coarse, gate_m, max_size_difference, dof,
                               with_scale, max_iterations, z_weight, tree_a)
    return polished if len(polished.associations) > len(fine.associations) else fine


def _refine_at_gate(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                    sizes_b: np.ndarray | None, initial: Sim3, gate_m: float, max_size_difference: float, dof: int,
                    with_scale: bool, max_iterations: int, z_weight: float, tree_a: Any) -> Alignment:
    """One stage of `refine_alignment`: the iteration at one gate."""
    pa = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    transform = initial
    tree_a = pairing_tree(pa, z_weight) if tree_a is None else tree_a
    assoc, dist = mutual_nearest(pa, sizes_a, transform.apply(pb), sizes_b, gate_m, max_size_difference, z_weight,
                                 tree_a)
    iterations = 0
    while iterations < max_iterations and len(assoc) >= 3:
        iterations += 1
        w = huber_weights(dist, gate_m)
        try:
            if dof == 4:
                new = fit_yaw_translation(pb[assoc[:, 1]], pa[assoc[:, 0]], w, with_scale)
            else:
                new = weighted_umeyama(pb[assoc[:, 1]], pa[assoc[:, 0]], w, with_scale)
        except ValueError:
            break
        new_assoc, new_dist = mutual_nearest(pa, sizes_a, new.apply(pb), sizes_b, gate_m, max_size_difference,
                                             z_weight, tree_a)
        if len(new_assoc) < 3:
            break
        same = np.array_equal(new_assoc, assoc)
        transform, assoc, dist = new, new_assoc, new_dist
        if same:
            break
    rms = float(np.sqrt(np.mean(dist**2))) if len(dist) else float("nan")
    return Alignment(transform, assoc, rms, iterations)


def weighted_umeyama(source: np.ndarray, target: np.ndarray, weights: np.ndarray, with_scale: bool) -> Sim3:
    """`umeyama` with per-correspondence weights (rows repeated in proportion would give the same result)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_s, mu_d = w @ source, w @ target
    xs, xd = source - mu_s, target - mu_d
    cov = (xd * w[:, None]).T @ xs
    u, d, vt = np.linalg.svd(cov)
    if d[1] < 1e-12 * max(d[0], 1e-300):
        raise ValueError("correspondences are collinear; the rotation is not determined")
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / (w @ np.sum(xs**2, axis=1))) if with_scale else 1.0
    return Sim3(rot, mu_d - scale * rot @ mu_s, scale)


def huber_weights(dist: np.ndarray, gate_m: float) -> np.ndarray:
    """IRLS weights of a Huber loss at half the gate: 1 inside, falling as 1/distance beyond (a wrong pair near
    the gate pulls little)."""
    huber = gate_m / 2.0
    return np.where(dist <= huber, 1.0, huber / np.maximum(dist, 1e-12))
