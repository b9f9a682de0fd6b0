"""Compiled kernels of the windowed search (numba): window-pair solving, the peel, the window pairs' graphs, the
position-prior path. The map edges and the shared join are in `kernels_join`.

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
    local_ids,
    pair_mismatch,
    pair_slices,
    putatives,
    size_weights,
    vector_invariants,
)
from .kernels_solve import solve_graph

# --- yaw slices ----------------------------------------------------------------------------------------------------


@njit(cache=True)
def slice_buckets(s0: np.ndarray, ns: np.ndarray, use: np.ndarray, nslices: int) -> tuple:
    """Counting sort of the items `use` marks into yaw slices: item t lies in the ns[t] slices from s0[t] on
    (wrapping). Returns (cnt, items): the items of slice sl are items[cnt[sl]: cnt[sl + 1]], ascending."""
    cnt = np.zeros(nslices + 1, np.int64)
    for t in range(len(s0)):
        if use[t]:
            for x in range(ns[t]):
                cnt[(s0[t] + x) % nslices + 1] += 1
    for sl in range(nslices):
        cnt[sl + 1] += cnt[sl]
    fill = cnt[:-1].copy()
    items = np.empty(cnt[nslices], np.int64)
    for t in range(len(s0)):
        if use[t]:
            for x in range(ns[t]):
                sl = (s0[t] + x) % nslices
                items[fill[sl]] = t
                fill[sl] += 1
    return cnt, items


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
    local = np.full(n, -1, np.int64)  # work array: vertex -> index in the slice's vertex list
    for sl in range(nslices):
        be = bucket[cnt[sl]: cnt[sl + 1]]  # this slice's edges, in (row, col) order
        if len(be) < min_edges:
            continue
        # the slice's vertices in ascending order, and its graph on them
        verts = np.empty(2 * len(be), np.int64)
        for x in range(len(be)):
            verts[2 * x] = rows[be[x]]
            verts[2 * x + 1] = cols[be[x]]
        verts = np.unique(verts)
        nv = len(verts)
        if nv <= k:
            continue
        for x in range(nv):
            local[verts[x]] = x
        lr = np.empty(len(be), np.int64)
        lc = np.empty(len(be), np.int64)
        lv = np.empty(len(be))
        for x in range(len(be)):
            lr[x] = local[rows[be[x]]]
            lc[x] = local[cols[be[x]]]
            lv[x] = cs[be[x]]
        for x in range(nv):
            local[verts[x]] = -1
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
        for x in range(len(be)):
            if core[lr[x]] and core[lc[x]]:
                ce += 1
        gr = np.empty(ce, np.int64)
        gc = np.empty(ce, np.int64)
        gv = np.empty(ce)
        t = 0
        for x in range(len(be)):
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


@njit(cache=True)
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


# --- peel and the graphs of window pairs ----------------------------------------------------------------------------


@njit(cache=True)
def compact_ids(v1: np.ndarray, v2: np.ndarray, space: int) -> tuple:
    """Sorted distinct association ids of v1 and v2, and both renumbered 0.. (a presence table when the id
    space is small, else a sort)."""
    both = np.concatenate((v1, v2))
    if space <= 64 * (len(v1) + len(v2)) + 1_000_000:
        ids, inv = local_ids(both, space)
        return ids, inv[: len(v1)].copy(), inv[len(v1):].copy()
    order = np.argsort(both)
    ids = np.empty(len(both), np.int64)
    inv = np.empty(len(both), np.int64)
    nu = 0
    for t in range(len(order)):
        x = both[order[t]]
        if nu == 0 or ids[nu - 1] != x:
            ids[nu] = x
            nu += 1
        inv[order[t]] = nu - 1
    return ids[:nu].copy(), inv[: len(v1)].copy(), inv[len(v1):].copy()


@njit(cache=True)
def peel_pairs(nv: int, e1: np.ndarray, e2: np.ndarray, k: int) -> np.ndarray:
    """Pairs left after iterated removal of associations in fewer than k pairs (boolean mask), O(E).

    A few passes of plain degree counting remove the bulk (most associations of a large join are in few pairs)
    without building anything; the k-core of what is left (`kcore_mask`) finishes it."""
    alive_e = np.ones(len(e1), np.bool_)
    deg = np.zeros(nv, np.int64)
    left = len(e1)
    for _pass in range(3):
        deg[:] = 0
        for t in range(len(e1)):
            if alive_e[t]:
                deg[e1[t]] += 1
                deg[e2[t]] += 1
        removed = 0
        for t in range(len(e1)):
            if alive_e[t] and (deg[e1[t]] < k or deg[e2[t]] < k):
                alive_e[t] = False
                removed += 1
        left -= removed
        if removed == 0 or left == 0:
            return alive_e
    sel = np.flatnonzero(alive_e)
    ip, ix, _ = sym_csr(nv, e1[sel], e2[sel], np.zeros(len(sel)))
    core = kcore_mask(nv, ip, ix, np.ones(nv, np.bool_), k)
    for t in sel:
        alive_e[t] = core[e1[t]] and core[e2[t]]
    return alive_e


@njit(cache=True)
def peeled_ids(v1: np.ndarray, v2: np.ndarray, space: int, k: int) -> tuple:
    """The pairs of associations (v1[t], v2[t]) (ids < space) left by `peel_pairs`, their associations compacted:
    (ids, e1, e2, sel): `sel` the surviving pairs (ascending), ids the sorted distinct associations they hold,
    e1 / e2 their endpoints numbered into ids.

    The same pairs as `compact_ids` then `peel_pairs` (the peel's result, all pairs of the k-core, does not depend
    on the numbering), with the same relative order of the ids; but when the id space is small enough for a table
    the degrees are counted on the ids themselves, pairs are removed with their counts decremented in place, and
    only the survivors (a few percent of a large join) are renumbered: a large join is never compacted whole."""
    n = len(v1)
    if space > 64 * 2 * n + 1_000_000:  # a table would be too large: sort (`compact_ids`) and peel
        ids, e1, e2 = compact_ids(v1, v2, space)
        sel = np.flatnonzero(peel_pairs(len(ids), e1, e2, k))
        used, f1, f2 = compact_ids(e1[sel], e2[sel], len(ids))
        return ids[used], f1, f2, sel
    cnt = np.zeros(space, np.int32)
    for t in range(n):
        cnt[v1[t]] += 1
        cnt[v2[t]] += 1
    live = np.arange(n)
    nl = n
    removed = 0
    for _pass in range(8):  # passes over the pairs still alive: each removal lowers its ends' counts at once
        w = 0
        for x in range(nl):
            t = live[x]
            a = v1[t]
            b = v2[t]
            if cnt[a] < k or cnt[b] < k:
                cnt[a] -= 1
                cnt[b] -= 1
            else:
                live[w] = t
                w += 1
        removed = nl - w
        nl = w
        if removed == 0 or nl == 0:
            break
    sel = live[:nl].copy()
    if removed > 0:  # not yet converged: the k-core of what is left decides (exact, whatever the passes did)
        ids, e1, e2 = compact_ids(v1[sel], v2[sel], space)
        sel = sel[peel_pairs(len(ids), e1, e2, k)]
    # renumber the associations of the surviving pairs (few: sorted, not a scan of the whole id space)
    ends = np.empty(2 * len(sel), np.int64)
    for x in range(len(sel)):
        ends[2 * x] = v1[sel[x]]
        ends[2 * x + 1] = v2[sel[x]]
    ids = np.unique(ends)
    for x in range(len(ids)):
        cnt[ids[x]] = x
    e1 = np.empty(len(sel), np.int64)
    e2 = np.empty(len(sel), np.int64)
    for x in range(len(sel)):
        e1[x] = cnt[v1[sel[x]]]
        e2[x] = cnt[v2[sel[x]]]
    return ids, e1, e2, sel


@njit(cache=True)
def peel_pairs_sliced(nv: int, e1: np.ndarray, e2: np.ndarray, s0: np.ndarray, ns: np.ndarray, nslices: int,
                      k: int) -> np.ndarray:
    """`peel_pairs` per yaw slice: in slice s, the pairs whose yaw tolerance covers s, and an association with fewer
    than k of them (over all windows) is removed, iterated. A pair survives if it survives in at least one slice.
    Exact: such an association cannot be in that slice's k-core of any window pair. Each slice is peeled on its
    own pairs only (counting sort by slice, local vertex ids), so time and memory grow with the incidences."""
    cnt, items = slice_buckets(s0, ns, np.ones(len(e1), np.bool_), nslices)
    out = np.zeros(len(e1), np.bool_)
    local = np.full(nv, -1, np.int64)
    for sl in range(nslices):
        its = items[cnt[sl]: cnt[sl + 1]]
        m = len(its)
        if m < k:
            continue
        verts = np.empty(2 * m, np.int64)
        nl = 0
        for x in range(m):
            for v in (e1[its[x]], e2[its[x]]):
                if local[v] < 0:
                    local[v] = nl
                    verts[nl] = v
                    nl += 1
        a = np.empty(m, np.int64)
        b = np.empty(m, np.int64)
        for x in range(m):
            a[x] = local[e1[its[x]]]
            b[x] = local[e2[its[x]]]
        for x in range(nl):
            local[verts[x]] = -1
        alive = peel_pairs(nl, a, b, k)
        for x in range(m):
            if alive[x]:
                out[its[x]] = True
    return out


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
