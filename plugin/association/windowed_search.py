"""Windowed cross-session correspondence search (SOS-Match, method.md section 2), fast and exact.

What one window pair computes (both code paths, identical by construction):
  windows of theta_WL landmarks by id order, stride theta_SL (a last window is added so the tail is covered);
  putative associations = landmark pairs of the two windows whose size ratio r = 2|h_i - h_j| / (h_i + h_j) is
  <= theta_r (r is 0 where a size is unknown), ordered by (i, j), weighted by q_s = 1 + cos(pi r / theta_r);
  the CLIPPER consistency graph of these associations (clipper.affinity_graph);
  its theta_S-core: only vertices of core number >= theta_S can be part of a consistent set of more than
  theta_S associations, so the solver runs on that core (an empty core means the pair cannot be accepted);
  CLIPPER on the core -> S; least-squares transform A_from_B from S; tilt of R e_z against e_z;
  accepted iff |S| > theta_S and the tilt <= theta_alpha (and the transform is determined).

`search_reference` does exactly that for every window pair from scratch. `search` gets the same answers much
faster because it never recomputes what overlapping windows share:
  1. every landmark pair that shares a window is a map "edge"; the consistency of two associations is a match
     between an edge of A and an edge of B of nearly equal length whose endpoints pass the size gate. All such
     matches are found once, by a grid join on (length / eps, log size, log size), never per window pair;
  2. each consistent pair of associations belongs to a rectangle of window pairs (those containing all four
     landmarks); a global peel (degree over the union of windows >= theta_S) and then a window-aware peel of
     the (association, window pair) incidences remove everything that cannot be in a set of size theta_S + 1;
  3. only window pairs with a non-empty theta_S-core are solved, on that core, as in the reference.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..params import AssociationParams
from ..processes import exit_with_parent
from .clipper import ConsistencyGraph, affinity_graph, solve
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


# --- building blocks -----------------------------------------------------------------------------------------


def make_windows(n: int, length: int, stride: int) -> np.ndarray:
    """[start, end) of windows of `length` ids with `stride`; one window if n <= length; the tail is covered."""
    if length < 1 or stride < 1:
        raise InputError(f"window length and stride must be >= 1, got {length} and {stride}")
    if n <= length:
        return np.array([[0, n]], dtype=np.int64)
    starts = list(range(0, n - length + 1, stride))
    if starts[-1] != n - length:
        starts.append(n - length)
    s = np.array(starts, dtype=np.int64)
    return np.column_stack([s, s + length])


def size_ratio(h_a: np.ndarray, h_b: np.ndarray) -> np.ndarray:
    """r = 2 |h_a - h_b| / (h_a + h_b); 0 where either size is unknown (the gate is then off)."""
    h_a = np.asarray(h_a, dtype=np.float64)
    h_b = np.asarray(h_b, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = 2.0 * np.abs(h_a - h_b) / (h_a + h_b)
    r = np.where(np.isnan(h_a) | np.isnan(h_b), 0.0, r)
    return np.where(np.isnan(r), 0.0, r)  # both sizes 0


def size_score(r: np.ndarray, theta_h: float) -> np.ndarray:
    """q_s = 1 + cos(pi r / theta_h) for r < theta_h, else 0 (in [0, 2])."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < theta_h, 1.0 + np.cos(np.pi * r / theta_h), 0.0)


def putative_pairs(sizes_a: np.ndarray, sizes_b: np.ndarray, ids_a: np.ndarray, ids_b: np.ndarray,
                   theta_r: float) -> tuple[np.ndarray, np.ndarray]:
    """Size-gated associations between landmark ids `ids_a` x `ids_b`, ordered by (i, j), and their weights q_s."""
    ia, ib = np.meshgrid(np.asarray(ids_a), np.asarray(ids_b), indexing="ij")
    ia, ib = ia.ravel(), ib.ravel()
    r = size_ratio(sizes_a[ia], sizes_b[ib])
    ok = r <= theta_r
    return np.column_stack([ia[ok], ib[ok]]), size_score(r[ok], theta_r)


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


def _hypothesis(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, wa: np.ndarray,
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


def _check_inputs(points: np.ndarray, sizes: np.ndarray | None, name: str) -> tuple[np.ndarray, np.ndarray]:
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


def _check_params(params: AssociationParams) -> None:
    if params.distance_tolerance_m <= 0 or params.affinity_sigma_m <= 0:
        raise InputError("association.distance_tolerance_m and affinity_sigma_m must be positive")
    if params.max_size_difference < 0:
        raise InputError("association.max_size_difference must be >= 0")
    if params.transform not in ("rigid", "similarity"):
        raise InputError(f"association.transform must be 'rigid' or 'similarity', got {params.transform!r}")


def _finish(points_a: np.ndarray, points_b: np.ndarray, params: AssociationParams, hyps: list[WindowHypothesis],
            wins_a: np.ndarray, wins_b: np.ndarray, timings: dict[str, float]) -> SearchResult:
    t0 = time.perf_counter()
    accepted = [k for k, h in enumerate(hyps) if h.accepted]
    best = max(accepted, key=lambda k: (hyps[k].size, hyps[k].score, -k)) if accepted else None
    consensus = consensus_transform(points_a, points_b, hyps, accepted, params) if accepted else None
    timings["consensus_s"] = time.perf_counter() - t0
    return SearchResult(hyps, wins_a, wins_b, len(wins_a) * len(wins_b), best, consensus, timings)


# --- the straightforward reference -------------------------------------------------------------------------


def search_reference(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                     sizes_b: np.ndarray | None, params: AssociationParams) -> SearchResult:
    """Every window pair computed from scratch (slow; the definition `search` must reproduce)."""
    _check_params(params)
    pa, ha = _check_inputs(points_a, sizes_a, "A")
    pb, hb = _check_inputs(points_b, sizes_b, "B")
    t0 = time.perf_counter()
    wins_a = make_windows(len(pa), params.window_length, params.window_stride)
    wins_b = make_windows(len(pb), params.window_length, params.window_stride)
    hyps = []
    for wa in wins_a:
        for wb in wins_b:
            pairs, w = putative_pairs(ha, hb, np.arange(*wa), np.arange(*wb), params.max_size_difference)
            graph = affinity_graph(pa, pb, pairs, w, params.distance_tolerance_m, params.affinity_sigma_m)
            core = core_mask(graph, params.min_associations)
            if core.sum() > params.min_associations:
                sub, old = graph.subgraph(core)
                hyps.append(_hypothesis(pa, pb, params, wa, wb, len(pairs), pairs[old], sub))
    return _finish(pa, pb, params, hyps, wins_a, wins_b, {"total_s": time.perf_counter() - t0})


# --- the fast search -----------------------------------------------------------------------------------------


def _window_span(n: int, wins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every landmark id, the first and last index of the windows that contain it."""
    ids = np.arange(n)
    first = np.searchsorted(wins[:, 1], ids, side="right")  # first window with end > id
    last = np.searchsorted(wins[:, 0], ids, side="right") - 1  # last window with start <= id
    return first, last


def _map_edges(points: np.ndarray, wins: np.ndarray, first: np.ndarray, last: np.ndarray,
               length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmark pairs i < k that share a window, and their distances."""
    n = len(points)
    ii, kk = [], []
    for off in range(1, min(length, n)):
        i = np.arange(n - off)
        k = i + off
        ok = first[k] <= last[i]
        ii.append(i[ok])
        kk.append(k[ok])
    i = np.concatenate(ii) if ii else np.zeros(0, np.int64)
    k = np.concatenate(kk) if kk else np.zeros(0, np.int64)
    d = points[i] - points[k]
    return i, k, np.sqrt(np.einsum("ij,ij->i", d, d))


def _expand_ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ranges [lo, hi): (owner index, value) of every element, vectorised."""
    cnt = np.maximum(hi - lo, 0)
    owner = np.repeat(np.arange(len(lo)), cnt)
    start = np.cumsum(cnt) - cnt
    val = np.arange(int(cnt.sum())) - np.repeat(start, cnt) + np.repeat(lo, cnt)
    return owner, val


def _consistent_pairs(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, ea: tuple, eb: tuple,
                      params: AssociationParams) -> tuple[np.ndarray, ...]:
    """All consistent pairs of size-gated associations {(p, j), (q, l)}: A edge (p, q) ~ B edge (j, l).

    Returns (v1, v2, c): association ids p * N_B + j and q * N_B + l, and the distance mismatch c.

    Sort-merge join: B edges are sorted by (size cell of j, size cell of l, length) where a size cell is
    delta wide in log size, delta = ln((2 + theta_r) / (2 - theta_r)) the log-width of the gate
    (r <= theta_r  <=>  |ln h_a - ln h_b| <= delta). For each directed A edge and each of the 3 x 3 neighbouring
    size cells, one binary search finds the B edges of length within eps, so candidates are few and every
    candidate is then checked exactly (same arithmetic as `clipper.affinity_graph`).
    """
    eps = params.distance_tolerance_m
    theta_r = params.max_size_difference
    ia, ka, da = ea
    ib, kb, db = eb
    # directed A edges (both orientations), undirected B edges (j < l): each consistent pair occurs once
    p = np.concatenate([ia, ka])
    q = np.concatenate([ka, ia])
    dA = np.concatenate([da, da])
    sized = bool(np.all(np.isfinite(ha)) and np.all(np.isfinite(hb)) and np.all(ha > 0) and np.all(hb > 0)
                 and theta_r < 2.0)
    if sized:
        delta = max(float(np.log((2.0 + theta_r) / (2.0 - theta_r))), 1e-6)
        sa = np.floor(np.log(ha) / delta).astype(np.int64)
        sb = np.floor(np.log(hb) / delta).astype(np.int64)
        smin = min(sa.min(), sb.min()) - 1
        sa, sb = sa - smin, sb - smin
        ns = int(max(sa.max(), sb.max())) + 2
        offsets = (-1, 0, 1)
    else:  # unknown sizes somewhere: distance-only join, the exact gate check below handles the rest
        sa = np.zeros(len(ha), np.int64)
        sb = np.zeros(len(hb), np.int64)
        ns, offsets = 3, (0,)
    span = float(max(dA.max(initial=0.0), db.max(initial=0.0))) + 4.0 * eps + 1.0  # cell spacing on the key
    key_b = (sb[ib] * ns + sb[kb]) * span + db
    order = np.argsort(key_b, kind="stable")
    key_sorted = key_b[order]
    slack = 1e-9 * span * ns * ns  # rounding of the composite key; the exact check below decides
    nb = len(hb)
    out: dict[str, list] = {"v1": [], "v2": [], "c": []}
    key_a = (sa[p] * ns + sa[q]) * span + dA
    a_order = np.argsort(key_a, kind="stable")  # sorted queries make the binary searches cache-friendly
    p, q, dA, key_a = p[a_order], q[a_order], dA[a_order], key_a[a_order]
    for d1 in offsets:
        for d2 in offsets:
            base = key_a + (d1 * ns + d2) * span  # a constant shift keeps the queries sorted
            lo = np.searchsorted(key_sorted, base - eps - slack, side="left")
            hi = np.searchsorted(key_sorted, base + eps + slack, side="right")
            ea_idx, pos = _expand_ranges(lo, hi)
            if len(ea_idx) == 0:
                continue
            eb_idx = order[pos]
            c = np.abs(dA[ea_idx] - db[eb_idx])
            ok = c <= eps
            ea_idx, eb_idx, c = ea_idx[ok], eb_idx[ok], c[ok]
            pp, qq = p[ea_idx], q[ea_idx]
            jj, ll = ib[eb_idx], kb[eb_idx]
            if sized:  # same arithmetic as size_ratio, without its NaN handling (no NaN here)
                x, y = ha[pp], hb[jj]
                ok = 2.0 * np.abs(x - y) / (x + y) <= theta_r
                x, y = ha[qq], hb[ll]
                ok &= 2.0 * np.abs(x - y) / (x + y) <= theta_r
            else:
                ok = (size_ratio(ha[pp], hb[jj]) <= theta_r) & (size_ratio(ha[qq], hb[ll]) <= theta_r)
            out["v1"].append(pp[ok] * nb + jj[ok])  # association (p, j) as one id
            out["v2"].append(qq[ok] * nb + ll[ok])
            out["c"].append(c[ok])
    return tuple(np.concatenate(out[k]) if out[k] else np.zeros(0, np.float64 if k == "c" else np.int64)
                 for k in ("v1", "v2", "c"))


def _compact_ids(v1: np.ndarray, v2: np.ndarray, space: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted distinct ids of v1 and v2 and both arrays renumbered 0..; a presence table beats sorting."""
    if space > 200_000_000:
        verts, inv = np.unique(np.concatenate([v1, v2]), return_inverse=True)
        return verts, inv[: len(v1)], inv[len(v1):]
    present = np.zeros(space, dtype=bool)
    present[v1] = True
    present[v2] = True
    new_id = np.cumsum(present) - 1
    return np.flatnonzero(present), new_id[v1], new_id[v2]


def _peel_global(v1: np.ndarray, v2: np.ndarray, nv: int, k: int) -> np.ndarray:
    """Indices of the edges left after iterated removal of vertices with fewer than k neighbours."""
    idx = np.arange(len(v1))
    a, b = v1, v2
    while len(idx):
        deg = np.bincount(a, minlength=nv) + np.bincount(b, minlength=nv)
        keep = (deg[a] >= k) & (deg[b] >= k)
        if keep.all():
            break
        idx, a, b = idx[keep], a[keep], b[keep]
    return idx


def search(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
           params: AssociationParams, workers: int | None = None) -> SearchResult:
    """Windowed search between maps A and B; same hypotheses as `search_reference`, without the redundant work.

    points_*: (N, 3) landmark positions (world z up), sizes_*: (N,) metric sizes or None/NaN when unknown.
    Returns every solved window pair, the best accepted hypothesis, the consensus and stage timings.
    `workers`: processes for the solve stage (None: 2 when there are at least PARALLEL_MIN_TASKS window pairs
    to solve and 2 cores, else 1); the result does not depend on it.
    """
    _check_params(params)
    pa, ha = _check_inputs(points_a, sizes_a, "A")
    pb, hb = _check_inputs(points_b, sizes_b, "B")
    k = params.min_associations  # a set of more than k associations lives in the k-core
    if k < 1:  # every window pair is solved, isolated associations included: nothing to share or prune
        return search_reference(pa, ha, pb, hb, params)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    wins_a = make_windows(len(pa), params.window_length, params.window_stride)
    wins_b = make_windows(len(pb), params.window_length, params.window_stride)
    fa, la = _window_span(len(pa), wins_a)
    fb, lb = _window_span(len(pb), wins_b)
    ea = _map_edges(pa, wins_a, fa, la, params.window_length)
    eb = _map_edges(pb, wins_b, fb, lb, params.window_length)
    timings["edges_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    v1, v2, c = _consistent_pairs(pa, ha, pb, hb, ea, eb, params)
    timings["join_s"] = time.perf_counter() - t0
    timings["consistent_pairs"] = float(len(c))

    t0 = time.perf_counter()
    nb = len(pb)
    verts, e1, e2 = _compact_ids(v1, v2, len(pa) * nb)
    sel = _peel_global(e1, e2, len(verts), k)
    # window-pair rectangle of each surviving edge: windows holding both A landmarks x both B landmarks
    v1a, v1b = np.divmod(v1[sel], nb)
    v2a, v2b = np.divmod(v2[sel], nb)
    a_lo = fa[np.maximum(v1a, v2a)]
    a_hi = la[np.minimum(v1a, v2a)]
    b_lo = fb[np.maximum(v1b, v2b)]
    b_hi = lb[np.minimum(v1b, v2b)]
    nwb = len(wins_b)
    na_e = a_hi - a_lo + 1
    nb_e = b_hi - b_lo + 1
    num_inc = int((na_e * nb_e).sum())
    if num_inc > DIRECT_MIN_INCIDENCES * len(wins_a) * nwb:
        # dense maps (landmarks much closer than the window span): almost nothing is pruned, and bookkeeping
        # the incidences would cost more than computing each remaining window pair directly
        timings["expand_s"] = time.perf_counter() - t0
        timings["incidences"] = float(num_inc)
        timings["mode_direct"] = 1.0
        alive = np.zeros(len(verts), dtype=bool)
        alive[e1[sel]] = True
        alive[e2[sel]] = True
        va, vb = np.divmod(verts[alive], nb)
        count = _window_pair_counts(fa[va], la[va], fb[vb], lb[vb], len(wins_a), nwb)
        tasks = [(int(w), None) for w in np.flatnonzero(count.ravel() > k)]  # fewer cannot hold k + 1
        shared = (pa, ha, pb, hb, params, wins_a, wins_b)
        return _solve_all(tasks, shared, _solve_direct_chunk, workers, timings, pa, pb, params, wins_a, wins_b)
    owner, kk = _expand_ranges(np.zeros(len(sel), np.int64), na_e * nb_e)
    wpair = (a_lo[owner] + kk // nb_e[owner]) * nwb + b_lo[owner] + kk % nb_e[owner]
    inc_e = sel[owner]  # global edge index of every (edge, window pair) incidence
    timings["expand_s"] = time.perf_counter() - t0
    timings["incidences"] = float(len(inc_e))

    # window-aware peel: a node is (vertex, window pair); iterate on shrinking arrays
    t0 = time.perf_counter()
    nw = len(wins_a) * nwb
    _, ninv = np.unique(np.concatenate([e1[inc_e] * nw + wpair, e2[inc_e] * nw + wpair]), return_inverse=True)
    n1, n2 = ninv[: len(inc_e)], ninv[len(inc_e):]
    num_nodes = int(ninv.max()) + 1 if len(ninv) else 0
    # rounds stop once they remove little: each window pair finishes its own peel before solving (exact either way)
    while len(n1):
        deg = np.bincount(n1, minlength=num_nodes) + np.bincount(n2, minlength=num_nodes)
        keep = (deg[n1] >= k) & (deg[n2] >= k)
        if keep.sum() > 0.98 * len(keep):
            n1, n2, inc_e, wpair = n1[keep], n2[keep], inc_e[keep], wpair[keep]
            break
        n1, n2, inc_e, wpair = n1[keep], n2[keep], inc_e[keep], wpair[keep]
    timings["peel_s"] = time.perf_counter() - t0

    # solve the surviving window pairs exactly as the reference does, from the shared edges
    t0 = time.perf_counter()
    order = np.argsort(wpair, kind="stable")
    wp_sorted = wpair[order]
    cut = np.flatnonzero(np.diff(wp_sorted)) + 1
    starts = np.concatenate([[0], cut]).astype(np.int64)
    ends = np.concatenate([cut, [len(wp_sorted)]]).astype(np.int64)
    tasks = [(int(wp_sorted[a]), inc_e[order[a:b]]) for a, b in zip(starts, ends) if b > a]
    shared = (pa, ha, pb, hb, params, wins_a, wins_b, verts, e1, e2, c)
    timings["solve_s"] = time.perf_counter() - t0  # grouping; _solve_all adds the solving
    return _solve_all(tasks, shared, _solve_chunk, workers, timings, pa, pb, params, wins_a, wins_b)


def _window_pair_counts(a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray, b_hi: np.ndarray, nwa: int,
                        nwb: int) -> np.ndarray:
    """(nwa, nwb) number of items whose window rectangle [a_lo, a_hi] x [b_lo, b_hi] covers each window pair."""
    diff = np.zeros((nwa + 1) * (nwb + 1), dtype=np.int64)
    for ra, rb, sign in ((a_lo, b_lo, 1), (a_hi + 1, b_lo, -1), (a_lo, b_hi + 1, -1), (a_hi + 1, b_hi + 1, 1)):
        diff += sign * np.bincount(ra * (nwb + 1) + rb, minlength=len(diff))
    return diff.reshape(nwa + 1, nwb + 1).cumsum(0).cumsum(1)[:nwa, :nwb]


def _solve_all(tasks: list, shared: tuple, chunk_fn: object, workers: int | None, timings: dict[str, float],
               pa: np.ndarray, pb: np.ndarray, params: AssociationParams, wins_a: np.ndarray,
               wins_b: np.ndarray) -> SearchResult:
    """Run `chunk_fn` over the window-pair tasks, in 1 or 2 processes, and assemble the result."""
    t0 = time.perf_counter()
    if workers is None:
        workers = 2 if len(tasks) >= PARALLEL_MIN_TASKS and (os.cpu_count() or 1) >= 2 else 1
    if "fork" not in multiprocessing.get_all_start_methods():  # the workers inherit the shared arrays by fork
        workers = 1
    if workers > 1 and len(tasks) > 1:
        chunks = [tasks[w::workers] for w in range(workers)]  # interleaved: similar work per process
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(workers, initializer=_init_worker, initargs=(shared, os.getpid())) as pool:
            parts = pool.map(chunk_fn, chunks)
        hyps = [h for _, h in sorted((x for part in parts for x in part), key=lambda t: t[0])]
    else:
        _init_worker(shared)
        hyps = [h for _, h in chunk_fn(tasks)]
    timings["solve_s"] = timings.get("solve_s", 0.0) + time.perf_counter() - t0
    timings["window_pairs_solved"] = float(len(hyps))
    timings["workers"] = float(workers)
    timings["total_s"] = sum(v for key, v in timings.items() if key.endswith("_s"))
    return _finish(pa, pb, params, hyps, wins_a, wins_b, timings)


PARALLEL_MIN_TASKS = 1000  # below this many window pairs to solve, starting a second process costs more than it saves
DIRECT_MIN_INCIDENCES = 300  # mean consistent pairs per window pair above which window pairs are computed directly
_WORKER: tuple = ()


def _init_worker(shared: tuple, parent_pid: int | None = None) -> None:
    global _WORKER
    if parent_pid is not None:  # a worker process: it must not outlive the search's process
        exit_with_parent(parent_pid)
    _WORKER = shared


def _solve_direct_chunk(tasks: list[tuple[int, None]]) -> list[tuple[int, WindowHypothesis]]:
    """Window pairs computed from scratch, exactly as `search_reference` does (dense maps)."""
    pa, ha, pb, hb, params, wins_a, wins_b = _WORKER[:7]
    k = params.min_associations
    nwb = len(wins_b)
    out = []
    for w, _ in tasks:
        wa, wb = wins_a[w // nwb], wins_b[w % nwb]
        pairs, wts = putative_pairs(ha, hb, np.arange(*wa), np.arange(*wb), params.max_size_difference)
        graph = affinity_graph(pa, pb, pairs, wts, params.distance_tolerance_m, params.affinity_sigma_m)
        core = core_mask(graph, k)
        if core.sum() > k:
            sub, old = graph.subgraph(core)
            out.append((w, _hypothesis(pa, pb, params, wa, wb, len(pairs), pairs[old], sub)))
    return out


def _solve_chunk(tasks: list[tuple[int, np.ndarray]]) -> list[tuple[int, WindowHypothesis]]:
    """Solve window pairs from their surviving consistent pairs (global edge indices); returns (pair id, hyp)."""
    pa, ha, pb, hb, params, wins_a, wins_b, verts, e1, e2, c = _WORKER
    k = params.min_associations
    nb, nwb = len(pb), len(wins_b)
    sigma, theta_r = params.affinity_sigma_m, params.max_size_difference
    out = []
    for w, ge in tasks:
        wa, wb = wins_a[w // nwb], wins_b[w % nwb]
        core_v, cinv = np.unique(np.concatenate([e1[ge], e2[ge]]), return_inverse=True)
        if len(core_v) <= k:
            continue
        vid = verts[core_v]  # sorted, i.e. in the reference's (i, j) order
        pairs = np.column_stack([vid // nb, vid % nb])
        r = size_ratio(ha[pairs[:, 0]], hb[pairs[:, 1]])
        r1, r2 = cinv[: len(ge)], cinv[len(ge):]
        cc = c[ge]
        graph = ConsistencyGraph(len(core_v), np.minimum(r1, r2), np.maximum(r1, r2),
                                 np.exp(-(cc * cc) / (2.0 * sigma * sigma)), size_score(r, theta_r))
        core = core_mask(graph, k)  # finish the peel inside this window pair
        if core.sum() <= k:
            continue
        if not core.all():
            graph, old = graph.subgraph(core)
            pairs = pairs[old]
        num_putative = int(np.count_nonzero(size_ratio(ha[wa[0]:wa[1], None], hb[None, wb[0]:wb[1]]) <= theta_r))
        out.append((w, _hypothesis(pa, pb, params, wa, wb, num_putative, pairs, graph)))
    return out


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
