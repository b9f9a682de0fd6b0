"""Windowed cross-session correspondence search (SOS-Match, the method spec section 2), fast and exact.

What one window pair computes (`reference.py` states it as code, `search` reproduces it exactly):
  windows of theta_WL landmarks with stride theta_SL (a last window covers the tail) over each map's landmarks
  in id order ("id" windows, the paper) or along a Hilbert curve of their positions ("spatial" windows);
  putative associations = landmark pairs of the two windows that pass the size gate r <= theta_r (and, with a
  position prior, lie within position_prior_m of each other), ordered by (i, j), weighted by q_s;
  the consistency graph of these associations (`consistency.py`: the paper's 3D distance test, or the gravity
  test with yaw slices); its theta_S-core (per yaw slice), since only a vertex of core number >= theta_S can
  belong to a set of more than theta_S associations; the solver on that core -> S; the least-squares transform
  A_from_B of S and its tilt; accepted iff |S| > theta_S and the tilt <= theta_alpha.

`search` never computes a window pair from scratch unless that is cheaper:
  1. every landmark pair sharing a window is a map "edge"; two associations are consistent when an edge of A and
     an edge of B pass the pair test and their endpoints pass the size gate. All such pairs are found once by a
     sort-merge join on (size cell, size cell, length) (`kernels_join.edge_join`), or, with a position prior,
     directly from the few putative associations each landmark has (`prior_join`);
  2. each pair belongs to a rectangle of window pairs (those holding all four landmarks). A global peel removes
     pairs of associations that are in fewer than theta_S pairs in all windows together; the rest are grouped
     by window pair, and each window pair is solved from its own pairs, as the reference solves it;
  3. where the maps are so dense that almost nothing can be pruned (the pairs would fill every window pair), the
     window pairs are computed directly instead, with the reference's own kernels.
Work is done in blocks of A windows sized so that the join's output stays within a fixed budget: memory grows
with the output of one block, not with the product of the map sizes.
"""

from __future__ import annotations

import numpy as np

from ..params import AssociationParams
from .hypotheses import (
    SearchMode,
    SearchResult,
    WindowHypothesis,
    check_inputs,
    check_params,
    in_window_order,
    make_hypotheses,
)
from .kernel_cache import search_clock
from .kernels_graph import gate_pairs
from .kernels_join import edge_join, edge_pair_details, map_edges, size_cells, sorted_b_edges
from .kernels_peel import peel_pairs_sliced, peeled_ids
from .kernels_problem import core_free, thread_count
from .kernels_search import (
    count_incidences,
    count_putatives,
    direct_window_pairs,
    prior_join,
    solve_groups,
    window_pair_graphs,
)
from .reference import search_reference
from .windows import map_windows, window_layouts, window_pair_counts, window_span

JOIN_BUDGET = 3_000_000  # join candidates per block of A windows (each found pair holds ~56 bytes)
DIRECT_MIN_INCIDENCES = 300  # mean pair incidences per window pair above which window pairs are computed directly


def search(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
           params: AssociationParams, workers: int | None = None) -> SearchResult:
    """Windowed search between maps A and B; the same hypotheses as `search_reference`, without redundant work.

    points_*: (N, 3) landmark positions (world z up), sizes_*: (N,) metric sizes or None/NaN when unknown.
    Returns every solved window pair, the best accepted hypothesis, the consensus and stage timings.
    `workers` is accepted for compatibility and unused: the compiled search runs in one process (a second
    process never paid for itself, BENCHMARKS.md "Association").
    """
    del workers
    check_params(params)
    pa, ha = check_inputs(points_a, sizes_a, "A")
    pb, hb = check_inputs(points_b, sizes_b, "B")
    if params.min_associations < 1:  # every window pair is solved, isolated associations included
        return search_reference(pa, ha, pb, hb, params)
    return in_window_order(pa, ha, pb, hb, params, _search)


class _Records:
    """Solved window pairs, in window-pair order, as the flat arrays `make_hypotheses` takes. The join is by
    position (five per-window-pair arrays, the selections' offsets, the two selections), so it also joins the
    shares of one block's direct window pairs (`_direct_in_threads`), whose arrays come in the kernel's order."""

    def __init__(self) -> None:
        self.parts: list[tuple] = []

    def add(self, ids: np.ndarray, nput: np.ndarray, ncore: np.ndarray, score: np.ndarray, slc: np.ndarray,
            off: np.ndarray, sel_a: np.ndarray, sel_b: np.ndarray) -> None:
        self.parts.append((ids, nput, ncore, score, slc, off, sel_a, sel_b))

    def arrays(self) -> tuple:
        if not self.parts:
            z = np.zeros(0, np.int64)
            return z, z, z, np.zeros(0), z, np.zeros(1, np.int64), z, z
        offs, base = [np.zeros(1, np.int64)], 0
        for p in self.parts:
            offs.append(p[5][1:] + base)
            base += p[5][-1]
        cat = [np.concatenate([p[i] for p in self.parts]) for i in (0, 1, 2, 3, 4, 6, 7)]
        return (*cat[:5], np.concatenate(offs), cat[5], cat[6])


def _search(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray,
            params: AssociationParams) -> tuple[list[WindowHypothesis], np.ndarray, np.ndarray, dict]:
    m = SearchMode.of(params)
    timings: dict[str, float] = {}
    t0 = search_clock()
    wins_a, wins_b = map_windows(len(pa), len(pb), params)
    fa, la = window_span(len(pa), wins_a)
    fb, lb = window_span(len(pb), wins_b)
    shared = (pa, ha, pb, hb, wins_a, wins_b, m)
    records = _Records()
    stats = {"consistent_pairs": 0, "incidences": 0, "blocks": 0, "direct_blocks": 0}
    if m.prior_m > 0:
        timings["edges_s"] = 0.0
        t1 = search_clock()
        pairs = _prior_pairs(pa, ha, pb, hb, fa, la, fb, lb, m)
        timings["join_s"] = search_clock() - t1
        _block(pairs, 0, len(wins_a), shared, records, stats, timings)
    else:
        (len_a, _), (len_b, _) = window_layouts(params)
        ea = map_edges(pa, fa, la, len_a, m.consistency)
        eb = map_edges(pb, fb, lb, len_b, m.consistency)
        cells_a, cells_b, ncell = size_cells(ha, hb, m.theta_r)
        sb = sorted_b_edges(eb, cells_b, ncell, hb)
        a_lo, a_hi = fa[ea[1]], la[ea[0]]  # A windows holding both endpoints of each A edge
        timings["edges_s"] = search_clock() - t0
        all_edges = np.arange(len(ea[0]), dtype=np.int64)
        join_args = (ea, sb, cells_a, ncell, pa, ha, pb, m.consistency, m.eps, m.tan_tilt, m.eps_z, m.theta_r,
                     m.prior_m)
        blocks = [(0, len(wins_a))]
        stride = 97  # the join's size, estimated from every 97th A edge: small problems skip the exact count
        sample = edge_join(np.ascontiguousarray(all_edges[::stride]), *join_args, False, 1024)
        estimate = int(len(sample[0]) * stride * 1.1)  # pairs, to size the output buffers
        if sample[-1].sum() * stride > JOIN_BUDGET / 2:
            blocks = _blocks(edge_join(all_edges, *join_args, True, 0)[-1], a_lo, a_hi, len(wins_a))
            estimate = 0
        for w0, w1 in blocks:
            t1 = search_clock()
            sel = all_edges[(a_lo <= w1 - 1) & (a_hi >= w0)]
            v1, v2, _ = edge_join(sel, *join_args, False, estimate or 1024)
            timings["join_s"] = timings.get("join_s", 0.0) + search_clock() - t1
            _block(_EdgePairs(v1, v2, pa, pb, fa, la, fb, lb, w0, w1, m), w0, w1,
                   shared, records, stats, timings)
    timings.update({k: float(v) for k, v in stats.items()})
    t1 = search_clock()
    ids, nput, ncore, score, slc, off, sel_a, sel_b = records.arrays()
    hyps = make_hypotheses(pa, pb, params, wins_a, wins_b, ids, nput, ncore, score, slc, off, sel_a, sel_b)
    timings["fit_s"] = search_clock() - t1
    timings["window_pairs_solved"] = float(len(hyps))
    timings["total_s"] = search_clock() - t0
    return hyps, wins_a, wins_b, timings


def _blocks(cand: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray, nwa: int) -> list[tuple[int, int]]:
    """Consecutive A windows [w0, w1) whose edges' join candidates stay within JOIN_BUDGET (at least one window)."""
    cost = np.zeros(nwa + 1, np.int64)  # an edge costs in every window it belongs to (an upper bound per block)
    np.add.at(cost, a_lo, cand)
    np.add.at(cost, a_hi + 1, -cand)
    per_window = np.cumsum(cost)[:nwa]
    blocks, w0, acc = [], 0, 0
    for w in range(nwa):
        if w > w0 and acc + per_window[w] > JOIN_BUDGET:
            blocks.append((w0, w))
            w0, acc = w, 0
        acc += per_window[w]
    blocks.append((w0, nwa))
    return blocks


def _prior_pairs(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, fa: np.ndarray, la: np.ndarray,
                 fb: np.ndarray, lb: np.ndarray, m: SearchMode) -> tuple:
    """Consistent pairs of putative associations under a position prior (`prior_join`)."""
    from scipy.spatial import cKDTree

    # candidates a little beyond the radius; `putatives` applies the exact test (same arithmetic as the reference)
    cand = cKDTree(pa[:, :2]).sparse_distance_matrix(cKDTree(pb[:, :2]), m.prior_m * (1 + 1e-6) + 1e-9,
                                                    output_type="ndarray")
    i, j = cand["i"].astype(np.int64), cand["j"].astype(np.int64)
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    keep = gate_pairs(i, j, pa, ha, pb, hb, m.theta_r, m.prior_m)  # the exact gate of `putatives`
    i, j = i[keep], j[keep]
    off = np.searchsorted(i, np.arange(len(pa) + 1)).astype(np.int64)
    return _ListedPairs(*prior_join(i, j, off, fa, la, fb, lb, pa, pb, m.consistency, m.eps, m.tan_tilt, m.eps_z,
                                    m.sin_tilt, m.nslices), len(pa) * len(pb))


class _ListedPairs:
    """Consistent pairs given as full arrays (`prior_join`)."""

    def __init__(self, v1: np.ndarray, v2: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray,
                 b_hi: np.ndarray, cs: np.ndarray, s0: np.ndarray, ns: np.ndarray, space: int) -> None:
        self.v1, self.v2, self.cs, self.s0, self.ns, self.space = v1, v2, cs, s0, ns, space
        self.ranges_all = (a_lo, a_hi, b_lo, b_hi)

    def __len__(self) -> int:
        return len(self.v1)

    def peeled(self, k: int) -> tuple:
        return peeled_ids(self.v1, self.v2, self.space, k)

    def ranges(self, sel: np.ndarray) -> tuple:
        return tuple(r[sel] for r in self.ranges_all)

    def details(self, sel: np.ndarray) -> tuple:
        return self.cs[sel], self.s0[sel], self.ns[sel]


class _EdgePairs:
    """Consistent pairs as the join gives them (association ids p * N_B + j, q * N_B + l with p < q), for A windows
    [w0, w1)."""

    def __init__(self, v1: np.ndarray, v2: np.ndarray, pa: np.ndarray, pb: np.ndarray, fa: np.ndarray,
                 la: np.ndarray, fb: np.ndarray, lb: np.ndarray, w0: int, w1: int, m: SearchMode) -> None:
        self.v1, self.v2, self.pa, self.pb, self.m = v1, v2, pa, pb, m
        self.fa, self.la, self.fb, self.lb, self.w0, self.w1 = fa, la, fb, lb, w0, w1
        self.space = len(pa) * len(pb)

    def __len__(self) -> int:
        return len(self.v1)

    def peeled(self, k: int) -> tuple:
        return peeled_ids(self.v1, self.v2, self.space, k)

    def ranges(self, sel: np.ndarray) -> tuple:
        """Window ranges of the pairs `sel`: the A windows holding both A landmarks (clipped to the block) and the
        B windows holding both B landmarks."""
        p, j = np.divmod(self.v1[sel], len(self.pb))
        q, l_ = np.divmod(self.v2[sel], len(self.pb))
        return (np.maximum(self.fa[q], self.w0), np.minimum(self.la[p], self.w1 - 1), self.fb[np.maximum(j, l_)],
                self.lb[np.minimum(j, l_)])

    def details(self, sel: np.ndarray) -> tuple:
        m = self.m
        return edge_pair_details(sel, self.v1, self.v2, self.pa, self.pb, m.consistency, m.eps, m.tan_tilt, m.eps_z,
                                 m.sin_tilt, m.nslices)


DIRECT_THREAD_MIN = 64  # window pairs per thread from which a dense block is computed on every idle core


def _direct_in_threads(tasks: np.ndarray, maps: tuple, mode: tuple) -> tuple:
    """`direct_window_pairs` of `tasks`, in one contiguous share of the tasks per thread when cores are idle
    (`kernels_problem.core_free`; the kernel releases the GIL), else in this thread. The shares' results are joined
    in task order: the same arrays as one call. Maps of two places spend nearly all their search here."""
    threads = min(thread_count(), len(tasks) // DIRECT_THREAD_MIN)
    if threads < 2 or not core_free(threads):
        return direct_window_pairs(*maps, tasks, *mode)
    from concurrent.futures import ThreadPoolExecutor

    joined = _Records()
    with ThreadPoolExecutor(threads) as pool:
        for part in pool.map(lambda share: direct_window_pairs(*maps, share, *mode), np.array_split(tasks, threads)):
            joined.add(*part)
    return joined.arrays()


def _block(pairs: _EdgePairs | _ListedPairs, w0: int, w1: int, shared: tuple, records: _Records, stats: dict,
           timings: dict) -> None:
    """Solve the window pairs of A windows [w0, w1) from the consistent pairs that fall into them."""
    pa, ha, pb, hb, wins_a, wins_b, m = shared
    nwb = len(wins_b)
    nbm = len(pb)
    stats["blocks"] += 1
    stats["consistent_pairs"] += len(pairs)
    t0 = search_clock()
    # the pairs the peel leaves (`sel`), their associations numbered 0 .. len(ids) - 1 (all of them used)
    ids, e1, e2, sel = pairs.peeled(m.k)
    cs, s0, ns = pairs.details(sel)
    if m.nslices > 1:  # the same peel per yaw slice, on what the plain peel left
        keep = peel_pairs_sliced(len(ids), e1, e2, s0, ns, m.nslices, m.k)
        sel, cs, s0, ns, e1, e2 = sel[keep], cs[keep], s0[keep], ns[keep], e1[keep], e2[keep]
    # from here on, everything is about the surviving pairs only, numbered 0 .. len(sel) - 1
    a_lo, a_hi, b_lo, b_hi = pairs.ranges(sel)
    local = np.arange(len(sel), dtype=np.int64)
    inc = count_incidences(local, a_lo, a_hi, b_lo, b_hi)
    stats["incidences"] += inc
    timings["peel_s"] = timings.get("peel_s", 0.0) + search_clock() - t0
    t0 = search_clock()
    if inc > DIRECT_MIN_INCIDENCES * (w1 - w0) * nwb:
        # dense maps: nearly every window pair keeps a core; computing them directly is cheaper than gathering
        stats["direct_blocks"] += 1
        alive = np.zeros(len(ids), bool)
        alive[e1] = True
        alive[e2] = True
        va, vb = np.divmod(ids[alive], nbm)
        fa, la = window_span(len(pa), wins_a)
        fb, lb = window_span(len(pb), wins_b)
        count = window_pair_counts(np.maximum(fa[va], w0), np.minimum(la[va], w1 - 1), fb[vb], lb[vb], len(wins_a),
                                   nwb)
        tasks = np.flatnonzero(count.ravel() > m.k).astype(np.int64)  # fewer associations cannot hold k + 1
        tasks = tasks[(tasks // nwb >= w0) & (tasks // nwb < w1)]
        found, nput, score, slc, ncore, off, sel_a, sel_b = _direct_in_threads(
            tasks, (pa, ha, pb, hb, wins_a, wins_b), (m.consistency, m.eps, m.sigma, m.tan_tilt, m.eps_z, m.sin_tilt,
                                                      m.nslices, m.theta_r, m.prior_m, m.k, m.method))
        ids_w = tasks[found]
        nput = nput[found]
    else:
        groups, goff, items = window_pair_graphs(local, a_lo, a_hi, b_lo, b_hi, nwb, w0, w1 - w0)
        found, score, slc, ncore, off, sel_a, sel_b = solve_groups(groups, goff, items, ids, e1, e2, cs, s0, ns, ha,
                                                                   hb, nbm, m.sigma, m.theta_r, m.nslices, m.k,
                                                                   m.method)
        ids_w = groups[found]
        nput = count_putatives(ids_w, wins_a, wins_b, pa, ha, pb, hb, m.theta_r, m.prior_m)
    # window pairs without a result have empty ranges in the flat selections: keep the found ones' ends
    new_off = np.concatenate([[0], off[np.flatnonzero(found) + 1]]).astype(np.int64)
    records.add(ids_w, nput, ncore[found], score[found], slc[found], new_off, sel_a, sel_b)
    timings["solve_s"] = timings.get("solve_s", 0.0) + search_clock() - t0
