"""Compiled kernels of the shared join (numba): the edges of a map and the one sort-merge join of A's and B's
edges that all window pairs of the fast search share.

`map_edges` lists each map's landmark pairs that share a window with their gravity-aware invariants; `edge_join`
pairs an A edge with every B edge of compatible sizes whose invariants agree (the consistency test of
`kernels_graph.pair_consistent`, done once for all window pairs instead of once per window pair) and gives each
pair as its two association ids, which `kernels_search.peeled_ids` peels; `edge_pair_details` gives the mismatch
and yaw slices of the survivors, which `kernels_search` cuts into the window pairs' graphs. Split out of
kernels_search.py along this seam.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_graph import GRAVITY, grow, pair_consistent, pair_mismatch, pair_slices, size_ratio1, vector_invariants

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
    h_j, h_l, ln h_j, ln h_l, all in group order, so the join reads them sequentially.
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
    return goff, bj, bl, bln, bz, hbj, hbl, lhbj, lhbl


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
    exactly (size gate, prior, `pair_mismatch`) with the invariants oriented as the reference orients them (a
    reversed B edge carries its negated height).
    Returns each pair as its two association ids p * N_B + j and q * N_B + l, p < q (the ids the peel counts,
    formed here where p, q, j and l are at hand), and the number of candidates per selected A edge (the join's
    cost; `count_only`: only that). `expected`: the output's size if known (its buffers then grow less).
    Mismatch and yaw slices follow from the ids (`edge_pair_details`), only for the pairs that survive the peel.
    """
    ei, ek, el, ez, af, ar = ea
    goff, bj, bl, bln, bz, hbj, hbl, lhbj, lhbl = sb
    nsel = len(ea_sel)
    nbm = len(pb)
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
        xp[x] = p
        xq[x] = q
        xl[x] = el[e]
        xz[x] = ez[e]
        xhp[x] = ha[p]
        xhq[x] = ha[q]
        xlp[x] = lha[p]
        xlq[x] = lha[q]
    cap = max(1024, expected)
    v1 = np.empty(cap, np.int64)
    v2 = np.empty(cap, np.int64)
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
                    p = xp[x]
                    q = xq[x]
                    hp = xhp[x]
                    hq = xhq[x]
                    lp = xlp[x]
                    lq = xlq[x]
                    za = xz[x]
                    if ne + (hi - lo) > cap:  # room for every candidate: the loop below stores unconditionally
                        cap = 2 * cap + (hi - lo)
                        v1 = grow(v1, cap)
                        v2 = grow(v2, cap)
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
                        v1[ne] = p * nbm + bj[f]
                        v2[ne] = q * nbm + bl[f]
                        ne += ok
    return v1[:ne].copy(), v2[:ne].copy(), counts


@njit(cache=True)
def edge_pair_details(sel: np.ndarray, v1: np.ndarray, v2: np.ndarray, pa: np.ndarray, pb: np.ndarray, mode: int,
                      eps: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    """Mismatch c and yaw slices of the joined pairs `sel` (association ids v1 = p * N_B + j, v2 = q * N_B + l,
    p < q), as `edge_join` tests them and `pair_slices` gives: the invariants of p -> q and j -> l formed as
    `map_edges` forms them (j > l: the reversed vector of l -> j, whose negated differences are exact)."""
    nbm = len(pb)
    cs = np.empty(len(sel))
    s0 = np.zeros(len(sel), np.int64)
    ns = np.ones(len(sel), np.int64)
    for x in range(len(sel)):
        p = v1[sel[x]] // nbm
        j = v1[sel[x]] % nbm
        q = v2[sel[x]] // nbm
        l_ = v2[sel[x]] % nbm
        la, za, anga = vector_invariants(pa[q, 0] - pa[p, 0], pa[q, 1] - pa[p, 1], pa[q, 2] - pa[p, 2], mode)
        lb, zb, angb = vector_invariants(pb[l_, 0] - pb[j, 0], pb[l_, 1] - pb[j, 1], pb[l_, 2] - pb[j, 2], mode)
        cs[x] = pair_mismatch(la, za, lb, zb, mode, eps, tan_tilt, eps_z)
        if mode == GRAVITY:
            s0[x], ns[x] = pair_slices(anga, angb, la, lb, za, zb, eps, sin_tilt, nslices)
    return cs, s0, ns
