"""Compiled kernels of the shared join (numba): the edges of a map and the one sort-merge join of A's and B's
edges that all window pairs of the fast search share.

`map_edges` lists each map's landmark pairs that share a window with their gravity-aware invariants; `edge_join`
pairs an A edge with every B edge of compatible sizes whose invariants agree (the consistency test of
`kernels_graph.pair_consistent`, done once for all window pairs instead of once per window pair);
`edge_pair_peel` / `edge_pair_details` give the joined pairs' associations (peeled) and yaw slices, which
`kernels_search` cuts into the window pairs' graphs. Split out of kernels_search.py along this seam.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_graph import GRAVITY, grow, pair_consistent, pair_mismatch, pair_slices, size_ratio1, vector_invariants
from .kernels_search import peeled_ids

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
    """B edges in both directions j -> l, grouped by (cell of j, cell of l), each group sorted by length, stored in
    that order (each undirected edge twice: once as listed, once reversed).

    Returns the group offsets (ncell * ncell + 1) and the directed edges' j, l, L, z (negated when reversed),
    h_j, h_l, ln h_j, ln h_l, original edge id and direction (1: reversed), all in group order, so the join reads
    them sequentially.
    """
    fj, fl, fln, fz, fang, fangr = eb
    ne = len(fj)
    nd = 2 * ne
    ng = ncell * ncell
    grp = np.empty(nd, np.int64)
    for f in range(ne):
        grp[2 * f] = cells_b[fj[f]] * ncell + cells_b[fl[f]]
        grp[2 * f + 1] = cells_b[fl[f]] * ncell + cells_b[fj[f]]
    # by group, then length (stable: ties keep the edge order)
    uo = np.argsort(fln, kind="mergesort")
    by_len = np.empty(nd, np.int64)
    for x in range(ne):
        by_len[2 * x] = 2 * uo[x]
        by_len[2 * x + 1] = 2 * uo[x] + 1
    order, goff = grouped_order(grp, by_len, ng)
    lh = np.log(hb)  # NaN / -inf for unknown / zero sizes: only used when every size is positive (ncell > 1)
    bj = np.empty(nd, np.int64)
    bl = np.empty(nd, np.int64)
    bln = np.empty(nd)
    bz = np.empty(nd)
    hbj = np.empty(nd)
    hbl = np.empty(nd)
    lhbj = np.empty(nd)
    lhbl = np.empty(nd)
    bf = np.empty(nd, np.int32)
    bd = np.empty(nd, np.int8)
    for x in range(nd):
        d = order[x]
        f = d >> 1
        o = d & 1
        j = fj[f] if o == 0 else fl[f]
        l_ = fl[f] if o == 0 else fj[f]
        bj[x] = j
        bl[x] = l_
        bln[x] = fln[f]
        bz[x] = fz[f] if o == 0 else -fz[f]
        hbj[x] = hb[j]
        hbl[x] = hb[l_]
        lhbj[x] = lh[j]
        lhbl[x] = lh[l_]
        bf[x] = f
        bd[x] = o
    return goff, bj, bl, bln, bz, hbj, hbl, lhbj, lhbl, bf, bd


@njit(cache=True)
def edge_join(ea_sel: np.ndarray, ea: tuple, sb: tuple, cells_a: np.ndarray, ncell: int, pa: np.ndarray,
              ha: np.ndarray, pb: np.ndarray, mode: int, eps: float, tan_tilt: float, eps_z: float, theta_r: float,
              prior_m: float, count_only: bool, expected: int) -> tuple:
    """Every consistent pair of associations {(p, j), (q, l)} whose A landmarks form one of the edges `ea_sel`.

    An undirected A edge p < q meets a directed B edge j -> l (both directions of each B edge, `sorted_b_edges`),
    so each pair of associations is found once. The A edges are grouped by (cell of p, cell of q) and sorted by
    length like the B edges; each A group is swept against its 3 x 3 neighbouring B groups with two pointers, so
    the candidates (lengths within eps) cost no search. (Directing B rather than A halves the sweeps: an A edge
    is visited once per neighbouring group instead of once per direction.) Every candidate is then tested
    exactly (size gate, prior, `pair_mismatch`) with the invariants oriented as the reference orients them: a
    reversed B edge with A's p -> q is the B edge with A's q -> p, stored as orientation 1.
    Returns each pair as its A edge, B edge (original id) and orientation (9 bytes: a large join is mostly pairs
    the peel removes), and the number of candidates per selected A edge (the join's cost; `count_only`: only
    that). `expected`: the output's size if known (its buffers then grow less). Association ids, mismatch and
    yaw slices follow from the edges (`edge_pair_peel`, `edge_pair_details`), the latter only for the pairs that
    survive the peel.
    """
    ei, ek, el, ez, af, ar = ea
    goff, bj, bl, bln, bz, hbj, hbl, lhbj, lhbl, bf, bd = sb
    nsel = len(ea_sel)
    grp = np.empty(nsel, np.int64)
    ulen = np.empty(nsel)
    for t in range(nsel):
        e = ea_sel[t]
        grp[t] = cells_a[ei[e]] * ncell + cells_a[ek[e]]
        ulen[t] = el[e]
    ng = ncell * ncell
    # the A edges in the order (group, length, edge): a counting sort of the stable length order
    dord, aoff = grouped_order(grp, np.argsort(ulen, kind="mergesort"), ng)
    sized = ncell > 1
    lha = np.log(ha) if sized else ha
    # the A edges' data in sweep order (each A group is swept up to 9 times: sequential reads)
    xt = np.empty(nsel, np.int64)
    xe = np.empty(nsel, np.int64)
    xp = np.empty(nsel, np.int64)
    xq = np.empty(nsel, np.int64)
    xl = np.empty(nsel)
    xz = np.empty(nsel)
    xhp = np.empty(nsel)
    xhq = np.empty(nsel)
    xlp = np.empty(nsel)
    xlq = np.empty(nsel)
    for x in range(nsel):
        t = dord[x]
        e = ea_sel[t]
        p = ei[e]
        q = ek[e]
        xt[x] = t
        xe[x] = e
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
        for n1 in range(dlo, dhi + 1):
            c1 = ca1 + n1
            if c1 < 0 or c1 >= ncell:
                continue
            for n2 in range(dlo, dhi + 1):
                c2 = ca2 + n2
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
                        ok = pair_consistent(la, za, bln[f], bz[f], mode, eps, tan_tilt, eps_z)
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
                        ebe[ne] = bf[f]
                        ori[ne] = bd[f]
                        ne += ok
    return eae[:ne].copy(), ebe[:ne].copy(), ori[:ne].copy(), counts


@njit(cache=True)
def edge_pair_peel(e_a: np.ndarray, e_b: np.ndarray, ori: np.ndarray, ea: tuple, eb: tuple, nbm: int, space: int,
                   k: int) -> tuple:
    """`peeled_ids` of the joined pairs' associations (p, j) and (q, l), formed from their edges."""
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
    return peeled_ids(v1, v2, space, k)


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
