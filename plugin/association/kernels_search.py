"""Compiled kernels of the windowed search (numba): map edges, the shared join, the peel, window-pair solving.

A window pair's hypothesis (`solve_window_pair`) is computed from its consistency graph; the reference builds
that graph from scratch per window pair (`kernels_graph.association_graph`), the fast search gathers it from one
join shared by all window pairs (`edge_join`, `window_pair_graphs`). Both then call the same function on the
same sorted edge list, so their hypotheses are identical.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_graph import (
    GRAVITY,
    affinity_values,
    association_graph,
    gate1,
    grow,
    local_ids,
    pair_consistent,
    pair_mismatch,
    pair_slices,
    putatives,
    size_ratio1,
    size_weights,
    vector_invariants,
)
from .kernels_solve import kcore_mask, solve_graph, sym_csr

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


# --- edges of a map and the shared join ----------------------------------------------------------------------------


@njit(cache=True)
def map_edges(points: np.ndarray, first: np.ndarray, last: np.ndarray, length: int, mode: int) -> tuple:
    """Landmark pairs i < k sharing a window, with the invariants of i -> k and of k -> i.

    Returns i, k, L, z (of i -> k; k -> i has -z), ang of i -> k, ang of k -> i.
    """
    n = len(points)
    cnt = 0
    for off in range(1, min(length, n)):
        for i in range(n - off):
            if first[i + off] <= last[i]:
                cnt += 1
    ei = np.empty(cnt, np.int64)
    ek = np.empty(cnt, np.int64)
    el = np.empty(cnt)
    ez = np.empty(cnt)
    af = np.empty(cnt)
    ar = np.empty(cnt)
    t = 0
    for off in range(1, min(length, n)):
        for i in range(n - off):
            k = i + off
            if first[k] <= last[i]:
                x = points[k, 0] - points[i, 0]
                y = points[k, 1] - points[i, 1]
                z = points[k, 2] - points[i, 2]
                ln, zz, ang = vector_invariants(x, y, z, mode)
                ei[t] = i
                ek[t] = k
                el[t] = ln
                ez[t] = zz
                af[t] = ang
                _, _, ang = vector_invariants(-x, -y, -z, mode)
                ar[t] = ang
                t += 1
    return ei, ek, el, ez, af, ar


@njit(cache=True)
def size_cells(ha: np.ndarray, hb: np.ndarray, theta_r: float) -> tuple:
    """Log-size cells of both maps' landmarks (one origin) and the number of cells (1: no cells).

    r <= theta_r  <=>  |ln h_a - ln h_b| <= ln((2 + theta_r) / (2 - theta_r)) = delta, so partners lie in
    neighbouring cells of width delta. One cell (the gate decides alone) when a size is unknown or 0, or
    theta_r >= 2 opens the gate.
    """
    ca = np.zeros(len(ha), np.int64)
    cb = np.zeros(len(hb), np.int64)
    if theta_r >= 2.0 or len(ha) == 0 or len(hb) == 0:
        return ca, cb, 1
    lo = np.inf
    for h in (ha, hb):
        for i in range(len(h)):
            if not (h[i] > 0.0) or np.isinf(h[i]):
                return ca, cb, 1
            lo = min(lo, np.log(h[i]))
    delta = np.log((2.0 + theta_r) / (2.0 - theta_r))
    if delta <= 0.0:
        return ca, cb, 1
    mx = 0
    for i in range(len(ha)):
        ca[i] = np.int64(np.floor((np.log(ha[i]) - lo) / delta)) + 1
        mx = max(mx, ca[i])
    for i in range(len(hb)):
        cb[i] = np.int64(np.floor((np.log(hb[i]) - lo) / delta)) + 1
        mx = max(mx, cb[i])
    return ca, cb, mx + 2


@njit(cache=True)
def grouped_order(grp: np.ndarray, order: np.ndarray, ng: int) -> tuple:
    """The items `order` lists, grouped by grp (0 .. ng - 1) and in `order`'s order within a group (a counting
    sort: what a stable sort by grp of `order` gives), and the groups' offsets (ng + 1)."""
    off = np.zeros(ng + 1, np.int64)
    for x in order:
        off[grp[x] + 1] += 1
    for g in range(ng):
        off[g + 1] += off[g]
    fill = off[:-1].copy()
    out = np.empty(len(order), np.int64)
    for x in order:
        out[fill[grp[x]]] = x
        fill[grp[x]] += 1
    return out, off


@njit(cache=True)
def sorted_b_edges(eb: tuple, cells_b: np.ndarray, ncell: int, hb: np.ndarray) -> tuple:
    """B edges grouped by (cell of j, cell of l), each group sorted by length, stored in that order.

    Returns the group offsets (ncell * ncell + 1) and the edges' j, l, L, z, ang, ang reversed, h_j, h_l,
    original edge id, ln h_j, ln h_l, all in group order, so the join reads them sequentially.
    """
    fj, fl, fln, fz, fang, fangr = eb
    ne = len(fj)
    ng = ncell * ncell
    grp = np.empty(ne, np.int64)
    for f in range(ne):
        grp[f] = cells_b[fj[f]] * ncell + cells_b[fl[f]]
    # by group, then length (stable: ties keep the edge order)
    order, goff = grouped_order(grp, np.argsort(fln, kind="mergesort"), ng)
    lh = np.log(hb)  # NaN / -inf for unknown / zero sizes: only used when every size is positive (ncell > 1)
    return (goff, fj[order], fl[order], fln[order], fz[order], fang[order], fangr[order], hb[fj[order]],
            hb[fl[order]], order, lh[fj[order]], lh[fl[order]])


@njit(cache=True)
def edge_join(ea_sel: np.ndarray, ea: tuple, sb: tuple, cells_a: np.ndarray, ncell: int, pa: np.ndarray,
              ha: np.ndarray, pb: np.ndarray, mode: int, eps: float, tan_tilt: float, eps_z: float, theta_r: float,
              prior_m: float, count_only: bool, expected: int) -> tuple:
    """Every consistent pair of associations {(p, j), (q, l)} whose A landmarks form one of the edges `ea_sel`.

    A directed A edge p -> q (both orientations o of each undirected edge) meets an undirected B edge j < l (so
    each pair of associations is found once). Directed A edges are grouped by (cell of p, cell of q) and sorted by
    length like the B edges (`sorted_b_edges`); each A group is swept against its 3 x 3 neighbouring B groups
    with two pointers, so the candidates (lengths within eps) cost no search. Every candidate is then tested
    exactly (size gate, prior, `pair_mismatch`) with the invariants oriented as the reference orients them.
    Returns each pair as its A edge, B edge (original id) and orientation (9 bytes: a large join is mostly pairs
    the peel removes), and the number of candidates per selected A edge (the join's cost; `count_only`: only
    that). `expected`: the output's size if known (its buffers then grow less). Association ids, mismatch and
    yaw slices follow from the edges (`edge_pair_ids`, `edge_pair_details`), the latter only for the pairs that
    survive the peel.
    """
    ei, ek, el, ez, af, ar = ea
    goff, bj, bl, bln, bz, bang, bangr, hbj, hbl, border, lhbj, lhbl = sb
    nsel = len(ea_sel)
    # directed A edges grouped by cells, sorted by length within a group
    nd = 2 * nsel
    dgrp = np.empty(nd, np.int64)
    ulen = np.empty(nsel)
    for t in range(nsel):
        e = ea_sel[t]
        dgrp[2 * t] = cells_a[ei[e]] * ncell + cells_a[ek[e]]
        dgrp[2 * t + 1] = cells_a[ek[e]] * ncell + cells_a[ei[e]]
        ulen[t] = el[e]
    # directed edge d = 2 t + o in the order (group, length, d): both orientations share the length
    uo = np.argsort(ulen, kind="mergesort")
    by_len = np.empty(nd, np.int64)
    for x in range(nsel):
        by_len[2 * x] = 2 * uo[x]
        by_len[2 * x + 1] = 2 * uo[x] + 1
    ng = ncell * ncell
    dord, aoff = grouped_order(dgrp, by_len, ng)
    sized = ncell > 1
    lha = np.log(ha) if sized else ha
    # the directed A edges' data in sweep order (each A group is swept up to 9 times: sequential reads)
    xt = np.empty(nd, np.int64)
    xe = np.empty(nd, np.int64)
    xo = np.empty(nd, np.int8)
    xp = np.empty(nd, np.int64)
    xq = np.empty(nd, np.int64)
    xl = np.empty(nd)
    xz = np.empty(nd)
    xhp = np.empty(nd)
    xhq = np.empty(nd)
    xlp = np.empty(nd)
    xlq = np.empty(nd)
    for x in range(nd):
        d = dord[x]
        t = d >> 1
        o = d & 1
        e = ea_sel[t]
        p = ei[e] if o == 0 else ek[e]
        q = ek[e] if o == 0 else ei[e]
        xt[x] = t
        xe[x] = e
        xo[x] = o
        xp[x] = p
        xq[x] = q
        xl[x] = el[e]
        xz[x] = ez[e]
        xhp[x] = ha[p]
        xhq[x] = ha[q]
        xlp[x] = lha[p]
        xlq[x] = lha[q]
    cap = max(1024, expected)
    eae = np.empty(cap, np.int32)
    ebe = np.empty(cap, np.int32)
    ori = np.empty(cap, np.int8)
    counts = np.zeros(nsel, np.int64)
    ne = 0
    r2 = prior_m * prior_m
    dlo = -1 if sized else 0
    dhi = 1 if sized else 0
    delta = np.log((2.0 + theta_r) / (2.0 - theta_r)) if sized else 0.0
    delta_hi = delta * (1.0 + 1e-9) + 1e-12
    delta_lo = delta * (1.0 - 1e-9) - 1e-12
    for ga in range(ng):
        if aoff[ga + 1] == aoff[ga]:
            continue
        ca1 = ga // ncell
        ca2 = ga % ncell
        for d1 in range(dlo, dhi + 1):
            c1 = ca1 + d1
            if c1 < 0 or c1 >= ncell:
                continue
            for d2 in range(dlo, dhi + 1):
                c2 = ca2 + d2
                if c2 < 0 or c2 >= ncell:
                    continue
                g = c1 * ncell + c2
                b0 = goff[g]
                b1 = goff[g + 1]
                if b1 == b0:
                    continue
                lo = b0
                hi = b0
                for x in range(aoff[ga], aoff[ga + 1]):
                    la = xl[x]
                    # a little wider than eps: the exact test below decides, whatever the rounding here; both
                    # ends grow with la (A edges ascend in length), so both pointers only move forward
                    slack = 1e-9 * (la + eps) + 1e-12
                    while lo < b1 and bln[lo] < la - eps - slack:
                        lo += 1
                    if hi < lo:
                        hi = lo
                    while hi < b1 and bln[hi] <= la + eps + slack:
                        hi += 1
                    counts[xt[x]] += hi - lo
                    if count_only or hi == lo:
                        continue
                    e = xe[x]
                    o = xo[x]
                    p = xp[x]
                    q = xq[x]
                    hp = xhp[x]
                    hq = xhq[x]
                    lp = xlp[x]
                    lq = xlq[x]
                    za = xz[x]
                    if ne + (hi - lo) > cap:  # room for every candidate: the loop below stores unconditionally
                        cap = 2 * cap + (hi - lo)
                        eae = grow(eae, cap)
                        ebe = grow(ebe, cap)
                        ori = grow(ori, cap)
                    # about half the candidates pass, at random: every test is evaluated without a branch (a
                    # mispredicted branch costs more than the tests) and the pair stored, kept when it passes
                    for f in range(lo, hi):
                        zb = bz[f] if o == 0 else -bz[f]
                        ok = pair_consistent(la, za, bln[f], zb, mode, eps, tan_tilt, eps_z)
                        if sized:
                            # r <= theta_r <=> |ln h_a - ln h_b| <= delta: decided by the logs away from the
                            # boundary, by the exact ratio (the reference's expression) within 1e-9 of it
                            d1 = abs(lp - lhbj[f])
                            d2 = abs(lq - lhbl[f])
                            ok = ok & (d1 <= delta_hi) & (d2 <= delta_hi)
                            if ok & ((d1 > delta_lo) | (d2 > delta_lo)):  # rare: near the gate's boundary
                                ok = ((d1 <= delta_lo) | (size_ratio1(hp, hbj[f]) <= theta_r)) & (
                                    (d2 <= delta_lo) | (size_ratio1(hq, hbl[f]) <= theta_r))
                        else:
                            ok = ok & (size_ratio1(hp, hbj[f]) <= theta_r) & (size_ratio1(hq, hbl[f]) <= theta_r)
                        if prior_m > 0.0:
                            j = bj[f]
                            l_ = bl[f]
                            dx = pa[p, 0] - pb[j, 0]
                            dy = pa[p, 1] - pb[j, 1]
                            dx2 = pa[q, 0] - pb[l_, 0]
                            dy2 = pa[q, 1] - pb[l_, 1]
                            ok = ok & (dx * dx + dy * dy <= r2) & (dx2 * dx2 + dy2 * dy2 <= r2)
                        eae[ne] = e
                        ebe[ne] = border[f]
                        ori[ne] = o
                        ne += ok
    return eae[:ne].copy(), ebe[:ne].copy(), ori[:ne].copy(), counts


@njit(cache=True)
def edge_pair_ids(e_a: np.ndarray, e_b: np.ndarray, ori: np.ndarray, ea: tuple, eb: tuple, nbm: int,
                  space: int) -> tuple:
    """`compact_ids` of the joined pairs' associations (p, j) and (q, l), formed from their edges."""
    ei, ek = ea[0], ea[1]
    fj, fl = eb[0], eb[1]
    v1 = np.empty(len(e_a), np.int64)
    v2 = np.empty(len(e_a), np.int64)
    for t in range(len(e_a)):
        e = e_a[t]
        f = e_b[t]
        p, q = (ei[e], ek[e]) if ori[t] == 0 else (ek[e], ei[e])
        v1[t] = p * nbm + fj[f]
        v2[t] = q * nbm + fl[f]
    return compact_ids(v1, v2, space)


@njit(cache=True)
def edge_pair_details(sel: np.ndarray, e_a: np.ndarray, e_b: np.ndarray, ori: np.ndarray, ea: tuple, eb: tuple,
                      mode: int, eps: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    """Mismatch c and yaw slices of the joined pairs `sel`, as `edge_join` tests them and `pair_slices` gives."""
    cs = np.empty(len(sel))
    s0 = np.zeros(len(sel), np.int64)
    ns = np.ones(len(sel), np.int64)
    for x in range(len(sel)):
        t = sel[x]
        e = e_a[t]
        f = e_b[t]
        zb = eb[3][f] if ori[t] == 0 else -eb[3][f]
        cs[x] = pair_mismatch(ea[2][e], ea[3][e], eb[2][f], zb, mode, eps, tan_tilt, eps_z)
        if mode == GRAVITY:
            s0[x], ns[x] = pair_slices(ea[4][e], eb[4][f] if ori[t] == 0 else eb[5][f], ea[2][e], eb[2][f],
                                       ea[3][e], zb, eps, sin_tilt, nslices)
    return cs, s0, ns


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
