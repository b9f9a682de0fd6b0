"""What one solved window pair yields (a hypothesis), the search result, and the consensus of hypotheses.

Shared by the straightforward reference (`reference.py`) and the fast search (`windowed_search.py`): a window
pair's consistency graph is reduced to its theta_S-core (per yaw slice with the gravity test), the solver selects S
(`kernels_search.solve_window_pair`), the transform A_from_B is fitted to S and checked against gravity, and the
accepted hypotheses that agree form the consensus.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..params import AssociationParams
from .kernel_cache import search_clock
from .kernels_fit import agreeing_groups, fit_many
from .kernels_graph import DISTANCE, GRAVITY
from .kernels_solve import BOUNDED, CLIPPER
from .rigid import Transform, fit_transform, rolls_pitches_deg, tilts_deg
from .windows import hilbert_order


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
    yaw_slice: int | None = None  # the yaw slice S was found in (gravity consistency with yaw slices), else None

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
    # the consensus holds more than theta_S associations itself, the bar every window hypothesis met (spec section
    # 2.6, |S| > theta_S): agreeing chance hypotheses of two different worlds (8 associations each) refitted to 5 and
    # were once the accepted answer; it was ">= theta_S" until rev42, one below the hypotheses' own bar
    accepted: bool = True


@dataclass
class SearchResult:
    hypotheses: list[WindowHypothesis]  # every solved window pair, in (window A, window B) order
    windows_a: np.ndarray  # (W_A, 2) [start, end) of every window of A
    windows_b: np.ndarray
    num_window_pairs: int
    best: int | None  # index of the accepted hypothesis with the largest |S| (then score), None if none
    consensus: Consensus | None
    timings: dict[str, float] = field(default_factory=dict)
    # "spatial" windows: the landmark order the windows run over (window ranges index into it), else None
    order_a: np.ndarray | None = None
    order_b: np.ndarray | None = None

    @property
    def accepted(self) -> list[int]:
        return [k for k, h in enumerate(self.hypotheses) if h.accepted]


@dataclass(frozen=True)
class SearchMode:
    """The association parameters as the compiled kernels take them."""

    consistency: int  # kernels_graph.DISTANCE or GRAVITY
    eps: float
    sigma: float
    tan_tilt: float
    eps_z: float  # height tolerance of the gravity test
    sin_tilt: float
    nslices: int  # yaw slices (1: none)
    theta_r: float
    prior_m: float
    k: int  # theta_S
    method: int  # kernels_solve.CLIPPER or BOUNDED

    @classmethod
    def of(cls, params: AssociationParams, prior_m: float | None = None) -> SearchMode:
        gravity = params.consistency == "gravity"
        tilt = np.radians(params.gravity_tilt_deg) if gravity else 0.0
        nslices = max(1, int(round(360.0 / params.yaw_slice_deg))) if gravity and params.yaw_slice_deg > 0 else 1
        return cls(GRAVITY if gravity else DISTANCE, float(params.distance_tolerance_m),
                   float(params.affinity_sigma_m), float(np.tan(tilt)),
                   float(params.height_tolerance_factor * params.distance_tolerance_m),
                   float(np.sin(tilt)), nslices,
                   float(params.max_size_difference),
                   float(params.position_prior_m if prior_m is None else prior_m), int(params.min_associations),
                   BOUNDED if params.solver == "bounded" else CLIPPER)


def make_hypotheses(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, wins_a: np.ndarray,
                    wins_b: np.ndarray, pair_ids: np.ndarray, num_putative: np.ndarray, num_core: np.ndarray,
                    score: np.ndarray, yaw_slice: np.ndarray, off: np.ndarray, sel_a: np.ndarray,
                    sel_b: np.ndarray) -> list[WindowHypothesis]:
    """Hypotheses of solved window pairs (index wa * W_B + wb, with their selected associations at
    sel_a/sel_b[off[h]:off[h + 1]]): transform A_from_B fitted to S, gravity check, acceptance |S| > theta_S."""
    rot, tr, sc, ok = fit_many(points_a, points_b, off, sel_a, sel_b, params.transform == "similarity")
    nwb = len(wins_b)
    sliced = params.consistency == "gravity" and params.yaw_slice_deg > 0
    # the angles of every fitted rotation at once; NaN where no transform was fitted
    rolls, pitches = rolls_pitches_deg(rot)
    roll = np.where(ok, rolls, np.nan).tolist()
    pitch = np.where(ok, pitches, np.nan).tolist()
    tilts = np.where(ok, tilts_deg(rot), np.nan)
    size = np.diff(off)
    accepted = ((size > params.min_associations) & ok & (tilts <= params.max_gravity_angle_deg)).tolist()
    pairs = np.column_stack([sel_a, sel_b]) if len(pair_ids) else np.zeros((0, 2), np.int64)
    wa_of, wb_of = np.divmod(np.asarray(pair_ids, np.int64), nwb)
    wins_a_l, wins_b_l = np.asarray(wins_a).tolist(), np.asarray(wins_b).tolist()
    offs, oks, tilt_l = np.asarray(off).tolist(), ok.tolist(), tilts.tolist()
    nput, ncore = np.asarray(num_putative, np.int64).tolist(), np.asarray(num_core, np.int64).tolist()
    scores = np.asarray(score, np.float64).tolist()
    slices = np.asarray(yaw_slice, np.int64).tolist() if sliced else None
    out = []
    for h, (a, b) in enumerate(zip(wa_of.tolist(), wb_of.tolist())):
        transform = Transform(rot[h].copy(), tr[h].copy(), float(sc[h])) if oks[h] else None
        wa, wb = wins_a_l[a], wins_b_l[b]
        out.append(WindowHypothesis((wa[0], wa[1]), (wb[0], wb[1]), nput[h], ncore[h], pairs[offs[h]:offs[h + 1]],
                                    scores[h], transform, roll[h], pitch[h], tilt_l[h], accepted[h],
                                    slices[h] if sliced else None))
    return out


MIN_LANDMARKS_TO_ALIGN = 3  # a rigid transform in 3-D needs three non-collinear points


def check_inputs(points: np.ndarray, sizes: np.ndarray | None, name: str) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"map {name}: positions must be an (N, 3) array, got shape {p.shape}")
    if len(p) < MIN_LANDMARKS_TO_ALIGN:
        raise InputError(f"map {name} has {len(p)} landmarks; at least {MIN_LANDMARKS_TO_ALIGN} are needed to "
                         "estimate a transform")
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
    for key, known in (("consistency", ("distance", "gravity")), ("windows", ("id", "spatial")),
                       ("solver", ("clipper", "bounded"))):
        if getattr(params, key) not in known:
            raise InputError(f"association.{key} must be one of {', '.join(known)}, got {getattr(params, key)!r}")
    if (params.position_prior_m < 0 or params.yaw_slice_deg < 0 or not 0 <= params.gravity_tilt_deg < 90
            or params.height_tolerance_factor < 0):
        raise InputError("association.position_prior_m, yaw_slice_deg and height_tolerance_factor must be >= 0, "
                         "gravity_tilt_deg in [0, 90)")
    if params.transform not in ("rigid", "similarity"):
        raise InputError(f"association.transform must be 'rigid' or 'similarity', got {params.transform!r}")


def in_window_order(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, params: AssociationParams,
                    core: object) -> SearchResult:
    """Run `core(pa, ha, pb, hb, params) -> (hypotheses, windows A, windows B, timings)` on the landmarks in the
    order their windows run over (id order, or a Hilbert curve for "spatial" windows) and return the result
    in the maps' own landmark ids."""
    if params.windows != "spatial":
        hyps, wins_a, wins_b, timings = core(pa, ha, pb, hb, params)
        return finish_search(pa, pb, params, hyps, wins_a, wins_b, timings)
    t0 = search_clock()
    oa, ob = hilbert_order(pa), hilbert_order(pb)
    hyps, wins_a, wins_b, timings = core(pa[oa], ha[oa], pb[ob], hb[ob], params)
    out = []
    for h in hyps:
        assoc = np.column_stack([oa[h.associations[:, 0]], ob[h.associations[:, 1]]])
        out.append(dataclasses.replace(h, associations=assoc[np.lexsort((assoc[:, 1], assoc[:, 0]))]))
    timings["order_s"] = search_clock() - t0 - timings.get("total_s", 0.0)
    res = finish_search(pa, pb, params, out, wins_a, wins_b, timings)
    res.order_a, res.order_b = oa, ob
    return res


def finish_search(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, hyps: list[WindowHypothesis],
            wins_a: np.ndarray, wins_b: np.ndarray, timings: dict[str, float]) -> SearchResult:
    t0 = search_clock()
    accepted = [k for k, h in enumerate(hyps) if h.accepted]
    best = max(accepted, key=lambda k: (hyps[k].size, hyps[k].score, -k)) if accepted else None
    consensus = consensus_transform(points_a, points_b, hyps, accepted, params) if accepted else None
    timings["consensus_s"] = search_clock() - t0
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
    # each hypothesis joins the first group (in order of creation) whose first member it agrees with, else starts a
    # group (`kernels_fit.agreeing_groups`)
    groups: list[list[int]] = []
    if ranked:
        rot = np.stack([hyps[k].transform.scale * hyps[k].transform.rotation for k in ranked])
        tr = np.stack([hyps[k].transform.translation for k in ranked])
        pure = np.stack([hyps[k].transform.rotation for k in ranked])
        off = np.concatenate([[0], np.cumsum([hyps[k].size for k in ranked])]).astype(np.int64)
        pts = points_b[np.concatenate([hyps[k].associations[:, 1] for k in ranked])]
        group_of = agreeing_groups(rot, tr, pure, off, np.ascontiguousarray(pts, dtype=np.float64), float(eps),
                                   float(params.max_gravity_angle_deg))
        groups = [[] for _ in range(int(group_of.max()) + 1)]
        for x, g in enumerate(group_of.tolist()):
            groups[g].append(ranked[x])

    nb = max(len(points_b), 1)

    def distinct(g: list[int]) -> np.ndarray:  # the distinct associations in (A, B) order, as np.unique(axis=0)
        both = np.concatenate([hyps[k].associations for k in g])
        a, b = np.divmod(np.unique(both[:, 0] * nb + both[:, 1]), nb)
        return np.column_stack([a, b])

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
    return Consensus(sorted(best), transform, inl, rms, bool(len(inl) > params.min_associations))
