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

import numpy as np

from ..params import AssociationParams
from ..processes import exit_with_parent
from .clipper import ConsistencyGraph, affinity_graph
from .gates import putative_pairs, size_ratio, size_score
from .hypotheses import (
    SearchResult,
    WindowHypothesis,
    check_inputs,
    check_params,
    core_mask,
    finish_search,
    make_hypothesis,
)
from .reference import search_reference
from .windows import make_windows, map_edges, window_pair_counts, window_span


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
    check_params(params)
    pa, ha = check_inputs(points_a, sizes_a, "A")
    pb, hb = check_inputs(points_b, sizes_b, "B")
    k = params.min_associations  # a set of more than k associations lives in the k-core
    if k < 1:  # every window pair is solved, isolated associations included: nothing to share or prune
        return search_reference(pa, ha, pb, hb, params)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    wins_a = make_windows(len(pa), params.window_length, params.window_stride)
    wins_b = make_windows(len(pb), params.window_length, params.window_stride)
    fa, la = window_span(len(pa), wins_a)
    fb, lb = window_span(len(pb), wins_b)
    ea = map_edges(pa, wins_a, fa, la, params.window_length)
    eb = map_edges(pb, wins_b, fb, lb, params.window_length)
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
        count = window_pair_counts(fa[va], la[va], fb[vb], lb[vb], len(wins_a), nwb)
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
    return finish_search(pa, pb, params, hyps, wins_a, wins_b, timings)


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
            out.append((w, make_hypothesis(pa, pb, params, wa, wb, len(pairs), pairs[old], sub)))
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
        out.append((w, make_hypothesis(pa, pb, params, wa, wb, num_putative, pairs, graph)))
    return out
