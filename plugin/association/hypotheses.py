"""What one solved window pair yields (a hypothesis), the search result, and the consensus of hypotheses.

Shared by the straightforward reference (`reference.py`) and the fast search (`windowed_search.py`): a window
pair's consistency graph is reduced to its theta_S-core, CLIPPER selects S, the transform A_from_B is fitted to S
and checked against gravity, and the accepted hypotheses that agree form the consensus.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..params import AssociationParams
from .clipper import ConsistencyGraph, solve
from .rigid import Transform, fit_transform, roll_pitch_yaw_deg, rotation_angle_deg, tilt_deg


@dataclass(frozen=True)
class WindowHypothesis:
    """The outcome of one solved window pair."""

    window_a: tuple[int, int]  # landmark ids [start, end) of the window in map A
    window_b: tuple[int, int]
    num_putative: int  # putative associations of the window pair (after the size gate)
    num_core: int  # associations in the theta_S-core the solver ran on
    associations: np.ndarray  # (|S|, 2) landmark ids (A, B), sorted
    score: float  # CLIPPER score of S (|S| when all affinities and weights are 1)
    transform: Transform | None  # A_from_B, None when S is degenerate (fewer than 3 or colinear)
    roll_deg: float
    pitch_deg: float
    tilt_deg: float
    accepted: bool

    @property
    def size(self) -> int:
        return len(self.associations)


@dataclass(frozen=True)
class Consensus:
    """Accepted hypotheses whose transforms agree, and the transform fitted to all their associations."""

    members: list[int]  # indices into SearchResult.hypotheses
    transform: Transform
    associations: np.ndarray  # (k, 2) associations of the members that fit the consensus transform within eps
    rms_m: float  # residual of those associations under the consensus transform


@dataclass
class SearchResult:
    hypotheses: list[WindowHypothesis]  # every solved window pair, in (window A, window B) order
    windows_a: np.ndarray  # (W_A, 2) [start, end) of every window of A
    windows_b: np.ndarray
    num_window_pairs: int
    best: int | None  # index of the accepted hypothesis with the largest |S| (then score), None if none
    consensus: Consensus | None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def accepted(self) -> list[int]:
        return [k for k, h in enumerate(self.hypotheses) if h.accepted]


def core_mask(graph: ConsistencyGraph, k: int) -> np.ndarray:
    """Vertices of the k-core (iterated removal of vertices of degree < k), as a boolean mask."""
    alive = np.ones(graph.n, dtype=bool)
    if k <= 0:
        return alive
    rows, cols = graph.rows, graph.cols
    while True:
        deg = np.bincount(rows, minlength=graph.n) + np.bincount(cols, minlength=graph.n)
        low = alive & (deg < k)
        if not low.any():
            return alive
        alive &= ~low
        e = alive[rows] & alive[cols]
        rows, cols = rows[e], cols[e]


def make_hypothesis(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, wa: np.ndarray,
                wb: np.ndarray, num_putative: int, pairs: np.ndarray, graph: ConsistencyGraph) -> WindowHypothesis:
    """Solve one window pair on the core of its graph (`pairs` in (i, j) order, `graph` over them)."""
    res = solve(graph)
    assoc = pairs[res.selected]
    transform, roll, pitch, tilt = None, np.nan, np.nan, np.nan
    if len(assoc) >= 3:
        try:
            transform = fit_transform(points_b[assoc[:, 1]], points_a[assoc[:, 0]],
                                      similarity=params.transform == "similarity")
        except InputError:  # colinear or coincident landmarks: the transform is not determined
            transform = None
    if transform is not None:
        roll, pitch, _ = roll_pitch_yaw_deg(transform.rotation)
        tilt = tilt_deg(transform.rotation)
    accepted = bool(len(assoc) > params.min_associations and transform is not None
                    and tilt <= params.max_gravity_angle_deg)
    return WindowHypothesis((int(wa[0]), int(wa[1])), (int(wb[0]), int(wb[1])), num_putative, len(pairs),
                            assoc, res.score, transform, roll, pitch, tilt, accepted)


def check_inputs(points: np.ndarray, sizes: np.ndarray | None, name: str) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"map {name}: positions must be an (N, 3) array, got shape {p.shape}")
    if len(p) < 3:
        raise InputError(f"map {name} has {len(p)} landmarks; at least 3 are needed to estimate a transform")
    if not np.all(np.isfinite(p)):
        raise InputError(f"map {name} holds NaN or infinite landmark positions")
    h = np.full(len(p), np.nan) if sizes is None else np.asarray(sizes, dtype=np.float64).reshape(-1)
    if len(h) != len(p):
        raise InputError(f"map {name}: {len(p)} positions but {len(h)} sizes")
    if np.any(h[np.isfinite(h)] < 0) or np.any(np.isinf(h)):
        raise InputError(f"map {name} holds negative or infinite sizes")
    return p, h


def check_params(params: AssociationParams) -> None:
    if params.distance_tolerance_m <= 0 or params.affinity_sigma_m <= 0:
        raise InputError("association.distance_tolerance_m and affinity_sigma_m must be positive")
    if params.max_size_difference < 0:
        raise InputError("association.max_size_difference must be >= 0")
    if params.transform not in ("rigid", "similarity"):
        raise InputError(f"association.transform must be 'rigid' or 'similarity', got {params.transform!r}")


def finish_search(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, hyps: list[WindowHypothesis],
            wins_a: np.ndarray, wins_b: np.ndarray, timings: dict[str, float]) -> SearchResult:
    t0 = time.perf_counter()
    accepted = [k for k, h in enumerate(hyps) if h.accepted]
    best = max(accepted, key=lambda k: (hyps[k].size, hyps[k].score, -k)) if accepted else None
    consensus = consensus_transform(points_a, points_b, hyps, accepted, params) if accepted else None
    timings["consensus_s"] = time.perf_counter() - t0
    return SearchResult(hyps, wins_a, wins_b, len(wins_a) * len(wins_b), best, consensus, timings)


# --- hypotheses that agree -----------------------------------------------------------------------------------


def consensus_transform(points_a: np.ndarray, points_b: np.ndarray, hyps: list[WindowHypothesis],
                        accepted: list[int], params: AssociationParams) -> Consensus | None:
    """Group accepted hypotheses whose transforms agree and fit one transform to the largest group.

    Two transforms agree when they map the landmarks of the larger hypothesis within theta_eps of each other
    and their rotations differ by less than theta_alpha. The group with the most distinct associations wins;
    the transform is refitted to all its associations, keeping those within theta_eps of the fit.
    """
    eps = params.distance_tolerance_m
    ranked = sorted(accepted, key=lambda k: (-hyps[k].size, -hyps[k].score, k))
    groups: list[list[int]] = []
    for k in ranked:
        hk = hyps[k]
        for g in groups:
            h0 = hyps[g[0]]
            xb = points_b[h0.associations[:, 1]]
            if (rotation_angle_deg(h0.transform.rotation, hk.transform.rotation) < params.max_gravity_angle_deg
                    and np.max(np.linalg.norm(h0.transform.apply(xb) - hk.transform.apply(xb), axis=1)) <= eps):
                g.append(k)
                break
        else:
            groups.append([k])

    def distinct(g: list[int]) -> np.ndarray:
        return np.unique(np.concatenate([hyps[k].associations for k in g]), axis=0)

    sizes = [len(distinct(g)) if len(g) > 1 else hyps[g[0]].size for g in groups]
    best = groups[max(range(len(groups)), key=lambda i: (sizes[i], -groups[i][0]))]
    assoc = distinct(best)
    transform = hyps[best[0]].transform
    for _ in range(3):  # refit on the associations that fit the current transform
        res = np.linalg.norm(transform.apply(points_b[assoc[:, 1]]) - points_a[assoc[:, 0]], axis=1)
        inl = assoc[res <= eps]
        if len(inl) < 3:
            break
        try:
            transform = fit_transform(points_b[inl[:, 1]], points_a[inl[:, 0]],
                                      similarity=params.transform == "similarity")
        except InputError:
            break
    res = np.linalg.norm(transform.apply(points_b[assoc[:, 1]]) - points_a[assoc[:, 0]], axis=1)
    inl = assoc[res <= eps]
    rms = float(np.sqrt(np.mean(res[res <= eps] ** 2))) if len(inl) else float("nan")
    return Consensus(sorted(best), transform, inl, rms)
