"""Compiled kernels of the windowed search (numba): window-pair solving, the window pairs' graphs, the
position-prior path. The map edges and the shared join are in `kernels_join`, the yaw slices and the peel in
`kernels_peel`.

A window pair's hypothesis (`solve_window_pair`) is computed from its consistency graph; the reference builds
that graph from scratch per window pair (`kernels_graph.association_graph`), the fast search gathers it from one
join shared by all window pairs (`kernels_join.edge_join`, `window_pair_graphs`). Both then call the same function
on the same sorted edge list, so their hypotheses are identical.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_cliques import kcore_mask
from .kernels_csr import sym_csr
from .kernels_graph import (
    GRAVITY,
    affinity_values,
    association_graph,
    gate1,
    grow,
    pair_mismatch,
    pair_slices,
    putatives,
    size_weights,
    vector_invariants,
)
from .kernels_peel import slice_buckets
from .kernels_solve import solve_graph

# --- one window pair ---------------------------------------------------------------------------------------------


@njit(cache=True)
def solve_window_pair(n: int, rows: np.ndarray, cols: np.ndarray, cs: np.ndarray, s0: np.ndarray, ns: np.ndarray,
                      diag: np.ndarray, nslices: int, k: int, method: int, sigma: float) -> tuple:
    """The hypothesis of one window pair from its consistency graph (edges sorted by (row, col)).

    Only the k-core (k = theta_S) can hold a set of more than k associations. Without yaw slices the solver runs
    on that core; with them, on the k-core of every slice's subgraph (pairs whose yaw tolerance covers the
    slice), and the largest set wins (then the higher score, then the lower slice).
    Returns (found, selected vertices, score, slice, core size); found is False when no core holds more than k.
    """
    empty = np.zeros(0, np.int64)
    if n <= k:
        return False, empty, 0.0, -1, 0
    indptr, indices, _ = sym_csr(n, rows, cols, cs)
    alive = kcore_mask(n, indptr, indices, np.ones(n, np.bool_), k)
    ncore = 0
    for i in range(n):
        ncore += alive[i]
    if ncore <= k:
        return False, empty, 0.0, -1, 0
    # edges of the core, bucketed by yaw slice (an edge in every slice its tolerance covers)
    in_core = np.empty(len(rows), np.bool_)
    for e in range(len(rows)):
        in_core[e] = alive[rows[e]] and alive[cols[e]]
    cnt, bucket = slice_buckets(s0, ns, in_core, nslices)
    found = False
    best_sel = empty
    best_score = 0.0
    best_slice = -1
    best_core = 0
    min_edges = k * (k + 1) // 2  # a set of k + 1 associations is a clique with this many pairs
    local = np.full(n, -1, np.int64)  # work arrays: vertex -> index in the slice's vertex list, and its degree
    deg = np.zeros(n, np.int64)
    verts = np.empty(n, np.int64)
    for sl in range(nslices):
        be = bucket[cnt[sl]: cnt[sl + 1]]  # this slice's edges, in (row, col) order
        if len(be) < min_edges:
            continue
        # the slice's vertices of degree >= k in ascending order, and its graph on them: a vertex of lower degree
        # is outside the k-core (the peel's first round, done on the edge list), and a slice with too few of them
        # holds no set of k + 1. Degrees and a scan of the n vertices: no sort of the slice's endpoints (which cost
        # half the search on dense maps of two places, BENCHMARKS.md "Refusals of season maps").
        for x in range(len(be)):
            deg[rows[be[x]]] += 1
            deg[cols[be[x]]] += 1
        nv = 0
        for v in range(n):
            if deg[v] >= k:
                local[v] = nv
                verts[nv] = v
                nv += 1
        ne = 0
        if nv > k:
            for x in range(len(be)):
                if local[rows[be[x]]] >= 0 and local[cols[be[x]]] >= 0:
                    ne += 1
        lr = np.empty(ne, np.int64)
        lc = np.empty(ne, np.int64)
        lv = np.empty(ne)
        if ne >= min_edges:
            t = 0
            for x in range(len(be)):
                r, c = local[rows[be[x]]], local[cols[be[x]]]
                if r >= 0 and c >= 0:
                    lr[t] = r
                    lc[t] = c
                    lv[t] = cs[be[x]]
                    t += 1
        for x in range(len(be)):  # the work arrays back to their rest state, for the next slice
            deg[rows[be[x]]] = 0
            deg[cols[be[x]]] = 0
        for x in range(nv):
            local[verts[x]] = -1
        if ne < min_edges:
            continue
        ip, ix, _ = sym_csr(nv, lr, lc, lv)
        core = kcore_mask(nv, ip, ix, np.ones(nv, np.bool_), k)
        nc = 0
        for x in range(nv):
            nc += core[x]
        if nc <= k:
            continue
        # the core's own graph, vertices renumbered in order (edges stay sorted)
        new = np.full(nv, -1, np.int64)
        ids = np.empty(nc, np.int64)
        t = 0
        for x in range(nv):
            if core[x]:
                new[x] = t
                ids[t] = verts[x]
                t += 1
        ce = 0
        for x in range(ne):
            if core[lr[x]] and core[lc[x]]:
                ce += 1
        gr = np.empty(ce, np.int64)
        gc = np.empty(ce, np.int64)
        gv = np.empty(ce)
        t = 0
        for x in range(ne):
            if core[lr[x]] and core[lc[x]]:
                gr[t] = new[lr[x]]
                gc[t] = new[lc[x]]
                gv[t] = lv[x]
                t += 1
        # affinities only for the core's pairs, the ones the solver reads
        sel, score, _, _, _ = solve_graph(nc, gr, gc, affinity_values(gv, sigma), diag[ids], method, 1e-6, 60, 100,
                                          0.25, True)
        if not found or len(sel) > len(best_sel) or (len(sel) == len(best_sel) and score > best_score):
            found = True
            best_sel = ids[sel]
            best_score = score
            best_slice = sl
            best_core = nc
    return found, best_sel, best_score, best_slice, best_core


@njit(cache=True)
def _append_selection(sel_a: np.ndarray, sel_b: np.ndarray, off: np.ndarray, t: int, va: np.ndarray,
                      vb: np.ndarray) -> tuple:
    """Append one window pair's selected associations (va, vb) as entry t of the flat selections."""
    need = off[t] + len(va)
    if need > len(sel_a):
        sel_a = grow(sel_a, 2 * need)
        sel_b = grow(sel_b, 2 * need)
    sel_a[off[t]: need] = va
    sel_b[off[t]: need] = vb
    off[t + 1] = need
    return sel_a, sel_b


@njit(cache=True, nogil=True)  # nogil: `windowed_search` runs blocks of tasks in threads when cores are idle
def direct_window_pairs(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, wins_a: np.ndarray,
                        wins_b: np.ndarray, tasks: np.ndarray, mode: int, eps: float, sigma: float,
                        tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int, theta_r: float, prior_m: float,
                        k: int, method: int) -> tuple:
    """Window pairs `tasks` (index wa * W_B + wb) computed from scratch, exactly as the reference does.

    Returns per task: found, num_putative, score, slice, core size, and the selected associations as offsets into
    flat (index in A, index in B) arrays.
    """
    nt = len(tasks)
    nwb = len(wins_b)
    found = np.zeros(nt, np.bool_)
    nput = np.zeros(nt, np.int64)
    score = np.zeros(nt)
    slc = np.full(nt, -1, np.int64)
    ncore = np.zeros(nt, np.int64)
    off = np.zeros(nt + 1, np.int64)
    sel_a = np.empty(1024, np.int64)
    sel_b = np.empty(1024, np.int64)
    for t in range(nt):
        wa = tasks[t] // nwb
        wb = tasks[t] % nwb
        ia, ib, w = putatives(wins_a[wa, 0], wins_a[wa, 1], wins_b[wb, 0], wins_b[wb, 1], pa, ha, pb, hb, theta_r,
                              prior_m)
        nput[t] = len(ia)
        off[t + 1] = off[t]
        if len(ia) <= k:
            continue
        rows, cols, cs, s0, ns = association_graph(pa, pb, ia, ib, mode, eps, sigma, tan_tilt, eps_z, sin_tilt,
                                                        nslices)
        ok, sel, sc, s, nc = solve_window_pair(len(ia), rows, cols, cs, s0, ns, w, nslices, k, method, sigma)
        if not ok:
            continue
        found[t] = True
        score[t] = sc
        slc[t] = s
        ncore[t] = nc
        sel_a, sel_b = _append_selection(sel_a, sel_b, off, t, ia[sel], ib[sel])
    return found, nput, score, slc, ncore, off, sel_a[: off[nt]].copy(), sel_b[: off[nt]].copy()


# --- the graphs of window pairs ---------------------------------------------------------------------------------


@njit(cache=True)
def count_incidences(sel: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray,
                     b_hi: np.ndarray) -> int:
    total = 0
    for t in sel:
        total += (a_hi[t] - a_lo[t] + 1) * (b_hi[t] - b_lo[t] + 1)
    return total


@njit(cache=True)
def window_pair_graphs(sel: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray, b_hi: np.ndarray,
                       nwb: int, w_off: int, nw_block: int) -> tuple:
    """Group the pairs `sel` by the window pairs that contain them (A windows w_off .. w_off + nw_block - 1).

    Returns the window pairs (index wa * W_B + wb) that hold at least one pair, CSR offsets and the pair ids of
    each (counting sort: pairs of a window pair in the order of `sel`).
    """
    ng = nw_block * nwb
    cnt = np.zeros(ng + 1, np.int64)
    for t in sel:
        for wa in range(a_lo[t], a_hi[t] + 1):
            for wb in range(b_lo[t], b_hi[t] + 1):
                cnt[(wa - w_off) * nwb + wb + 1] += 1
    for g in range(ng):
        cnt[g + 1] += cnt[g]
    fill = cnt[:-1].copy()
    out = np.empty(cnt[ng], np.int64)
    for t in sel:
        for wa in range(a_lo[t], a_hi[t] + 1):
            for wb in range(b_lo[t], b_hi[t] + 1):
                g = (wa - w_off) * nwb + wb
                out[fill[g]] = t
                fill[g] += 1
    ngr = 0
    for g in range(ng):
        if cnt[g + 1] > cnt[g]:
            ngr += 1
    groups = np.empty(ngr, np.int64)
    goff = np.empty(ngr + 1, np.int64)
    t = 0
    goff[0] = 0
    pos = 0
    items = np.empty(cnt[ng], np.int64)
    for g in range(ng):
        if cnt[g + 1] > cnt[g]:
            groups[t] = (g // nwb + w_off) * nwb + g % nwb
            for x in range(cnt[g], cnt[g + 1]):
                items[pos] = out[x]
                pos += 1
            goff[t + 1] = pos
            t += 1
    return groups, goff, items


@njit(cache=True)
def solve_groups(groups: np.ndarray, goff: np.ndarray, items: np.ndarray, ids: np.ndarray, e1: np.ndarray,
                 e2: np.ndarray, cs: np.ndarray, s0: np.ndarray, nsl: np.ndarray, ha: np.ndarray, hb: np.ndarray,
                 nbm: int, sigma: float, theta_r: float, nslices: int, k: int, method: int) -> tuple:
    """Solve every window pair of `groups` from its pairs, as `solve_window_pair` does for the reference.

    The window pair's graph: its associations (sorted ids, i.e. the reference's (i, j) order), its pairs as edges
    sorted by (row, col), affinities and size weights computed as the reference computes them.
    """
    ngr = len(groups)
    found = np.zeros(ngr, np.bool_)
    score = np.zeros(ngr)
    slc = np.full(ngr, -1, np.int64)
    ncore = np.zeros(ngr, np.int64)
    off = np.zeros(ngr + 1, np.int64)
    sel_a = np.empty(1024, np.int64)
    sel_b = np.empty(1024, np.int64)
    min_edges = k * (k + 1) // 2
    loc = np.full(len(ids), -1, np.int64)
    for g in range(ngr):
        off[g + 1] = off[g]
        m = goff[g + 1] - goff[g]
        if m < min_edges:
            continue
        its = items[goff[g]: goff[g + 1]]
        # local vertex ids in ascending association id (a stamp array maps global ids to local ones)
        verts = np.empty(2 * m, np.int64)
        nv = 0
        for x in range(m):
            for v in (e1[its[x]], e2[its[x]]):
                if loc[v] < 0:
                    loc[v] = 0
                    verts[nv] = v
                    nv += 1
        verts = np.sort(verts[:nv])
        for x in range(nv):
            loc[verts[x]] = x
        lo = np.empty(m, np.int64)
        hi = np.empty(m, np.int64)
        for x in range(m):
            a = loc[e1[its[x]]]
            b = loc[e2[its[x]]]
            lo[x] = min(a, b)
            hi[x] = max(a, b)
        for x in range(nv):
            loc[verts[x]] = -1
        order = np.argsort(lo * nv + hi)
        rows = lo[order]
        cols = hi[order]
        cc = np.empty(m)
        ss = np.empty(m, np.int64)
        nn = np.empty(m, np.int64)
        for x in range(m):
            cc[x] = cs[its[order[x]]]
            ss[x] = s0[its[order[x]]]
            nn[x] = nsl[its[order[x]]]
        va = np.empty(nv, np.int64)
        vb = np.empty(nv, np.int64)
        for x in range(nv):
            va[x] = ids[verts[x]] // nbm
            vb[x] = ids[verts[x]] % nbm
        diag = size_weights(ha, hb, va, vb, theta_r)
        ok, sel, sc, s, nc = solve_window_pair(nv, rows, cols, cc, ss, nn, diag, nslices, k, method, sigma)
        if not ok:
            continue
        found[g] = True
        score[g] = sc
        slc[g] = s
        ncore[g] = nc
        sel_a, sel_b = _append_selection(sel_a, sel_b, off, g, va[sel], vb[sel])
    return found, score, slc, ncore, off, sel_a[: off[ngr]].copy(), sel_b[: off[ngr]].copy()


@njit(cache=True)
def count_putatives(tasks: np.ndarray, wins_a: np.ndarray, wins_b: np.ndarray, pa: np.ndarray, ha: np.ndarray,
                    pb: np.ndarray, hb: np.ndarray, theta_r: float, prior_m: float) -> np.ndarray:
    """Number of putative associations of each window pair (as `putatives` counts them)."""
    nwb = len(wins_b)
    out = np.zeros(len(tasks), np.int64)
    r2 = prior_m * prior_m
    for t in range(len(tasks)):
        wa = tasks[t] // nwb
        wb = tasks[t] % nwb
        c = 0
        for i in range(wins_a[wa, 0], wins_a[wa, 1]):
            for j in range(wins_b[wb, 0], wins_b[wb, 1]):
                c += gate1(i, j, pa, ha, pb, hb, theta_r, r2, prior_m > 0.0) >= 0.0
        out[t] = c
    return out


@njit(cache=True)
def prior_join(put_a: np.ndarray, put_b: np.ndarray, put_off: np.ndarray, fa: np.ndarray, la: np.ndarray,
               fb: np.ndarray, lb: np.ndarray, pa: np.ndarray, pb: np.ndarray, mode: int, eps: float,
               tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    """Every consistent pair of putative associations that share a window pair, found from the associations.

    With a position prior each landmark has a handful of putative partners, so pairs are enumerated directly:
    for each putative (p, j), every putative (q, l) with p < q sharing an A window with p and l != j sharing a
    B window with j. `put_a`, `put_b`: putative associations sorted by (i, j); `put_off[i]`: CSR offsets by A
    landmark. Returns the same columns as `edge_join` with A and B window ranges instead of edge ids.
    """
    nbm = len(pb)
    cap = 1024
    v1 = np.empty(cap, np.int64)
    v2 = np.empty(cap, np.int64)
    alo = np.empty(cap, np.int64)
    ahi = np.empty(cap, np.int64)
    blo = np.empty(cap, np.int64)
    bhi = np.empty(cap, np.int64)
    cs = np.empty(cap)
    s0 = np.empty(cap, np.int64)
    nsl = np.empty(cap, np.int64)
    ne = 0
    na = len(pa)
    for p in range(na):
        for x in range(put_off[p], put_off[p + 1]):
            j = put_b[x]
            q = p + 1
            while q < na and fa[q] <= la[p]:
                for y in range(put_off[q], put_off[q + 1]):
                    l_ = put_b[y]
                    if l_ == j:
                        continue
                    lo_b, hi_b = (j, l_) if j < l_ else (l_, j)
                    if fb[hi_b] > lb[lo_b]:
                        continue  # j and l share no B window
                    lna, za, anga = vector_invariants(pa[q, 0] - pa[p, 0], pa[q, 1] - pa[p, 1],
                                                      pa[q, 2] - pa[p, 2], mode)
                    lnb, zb, angb = vector_invariants(pb[l_, 0] - pb[j, 0], pb[l_, 1] - pb[j, 1],
                                                      pb[l_, 2] - pb[j, 2], mode)
                    c = pair_mismatch(lna, za, lnb, zb, mode, eps, tan_tilt, eps_z)
                    if c < 0.0:
                        continue
                    if ne == cap:
                        cap *= 2
                        v1 = grow(v1, cap)
                        v2 = grow(v2, cap)
                        alo = grow(alo, cap)
                        ahi = grow(ahi, cap)
                        blo = grow(blo, cap)
                        bhi = grow(bhi, cap)
                        cs = grow(cs, cap)
                        s0 = grow(s0, cap)
                        nsl = grow(nsl, cap)
                    v1[ne] = p * nbm + j
                    v2[ne] = q * nbm + l_
                    alo[ne] = fa[q]
                    ahi[ne] = la[p]
                    blo[ne] = fb[hi_b]
                    bhi[ne] = lb[lo_b]
                    cs[ne] = c
                    if mode == GRAVITY:
                        s0[ne], nsl[ne] = pair_slices(anga, angb, lna, lnb, za, zb, eps, sin_tilt, nslices)
                    else:
                        s0[ne], nsl[ne] = 0, 1
                    ne += 1
                q += 1
    return (v1[:ne].copy(), v2[:ne].copy(), alo[:ne].copy(), ahi[:ne].copy(), blo[:ne].copy(), bhi[:ne].copy(),
            cs[:ne].copy(), s0[:ne].copy(), nsl[:ne].copy())
