"""Compiled kernels of the consistency graph (numba): the size gate, the pair test, and graphs of associations.

`consistency.py` states the tests these kernels implement. Every kernel is plain numpy in, numpy out,
deterministic, and cached on disk by numba (`cache=True`: the first call in a fresh environment compiles,
later processes load the machine code).

No fast-math, and one expression per quantity: the windowed search and its straightforward reference must
compute bit-identical graphs, so a pair's invariants are always formed the same way. The vector of a landmark
pair is oriented from its lower to its higher landmark id in map A (the B vector joins the partners in the same
order), and from that vector: L its length (3D, or horizontal for the gravity test), z its height component,
ang = atan2(y, x) its direction. A reversed vector has z -> -z exactly, and its own atan2(-y, -x).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_sweep import expand_rows, grow, sweep_rows

DISTANCE, GRAVITY = 0, 1  # association.consistency


# --- the size gate -----------------------------------------------------------------------------------------------


@njit(cache=True)
def size_ratio1(x: float, y: float) -> float:
    """r = 2 |x - y| / (x + y); 0 where a size is unknown (NaN) or both are 0 (the gate is then open)."""
    if np.isnan(x) or np.isnan(y):
        return 0.0
    s = x + y
    if s == 0.0:
        return 0.0
    return 2.0 * abs(x - y) / s


@njit(cache=True)
def size_weight1(r: float, theta_r: float) -> float:
    """q_s = 1 + cos(pi r / theta_r) for r < theta_r, else 0."""
    if r < theta_r:
        return 1.0 + np.cos(np.pi * r / theta_r)
    return 0.0


@njit(cache=True)
def gate1(i: int, j: int, pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, theta_r: float,
          r2: float, prior: bool) -> float:
    """r of landmark pair (i, j) if it passes the size gate (and the position prior), else -1."""
    r = size_ratio1(ha[i], hb[j])
    if not r <= theta_r:
        return -1.0
    if prior:
        dx = pa[i, 0] - pb[j, 0]
        dy = pa[i, 1] - pb[j, 1]
        if dx * dx + dy * dy > r2:
            return -1.0
    return r


@njit(cache=True)
def gate_pairs(ia: np.ndarray, ib: np.ndarray, pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray,
               theta_r: float, prior_m: float) -> np.ndarray:
    """Which landmark pairs (ia, ib) are putative associations (as `putatives` decides)."""
    out = np.empty(len(ia), np.bool_)
    for t in range(len(ia)):
        out[t] = gate1(ia[t], ib[t], pa, ha, pb, hb, theta_r, prior_m * prior_m, prior_m > 0.0) >= 0.0
    return out


@njit(cache=True)
def size_pass_count(ha: np.ndarray, hb: np.ndarray, theta_r: float) -> int:
    """How many of the landmark pairs ha x hb pass the size gate r <= theta_r, r as `gates.size_ratio` gives it
    (`size_ratio1`, whose NaN for two infinite sizes `gates.size_ratio` reads as 0)."""
    c = 0
    for i in range(len(ha)):
        for j in range(len(hb)):
            r = size_ratio1(ha[i], hb[j])
            c += (r <= theta_r) | (r != r)
    return c


@njit(cache=True)
def putatives(a0: int, a1: int, b0: int, b1: int, pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray,
              theta_r: float, prior_m: float) -> tuple:
    """Putative associations of landmarks [a0, a1) x [b0, b1), in (i, j) order, and their weights q_s.

    Size gate r(h_i, h_j) <= theta_r; with a position prior (prior_m > 0) also a horizontal distance within
    prior_m in the maps' common frame.
    """
    n = (a1 - a0) * (b1 - b0)
    ia = np.empty(n, np.int64)
    ib = np.empty(n, np.int64)
    w = np.empty(n)
    k = 0
    r2 = prior_m * prior_m
    for i in range(a0, a1):
        for j in range(b0, b1):
            r = gate1(i, j, pa, ha, pb, hb, theta_r, r2, prior_m > 0.0)
            if r < 0.0:
                continue
            ia[k] = i
            ib[k] = j
            w[k] = size_weight1(r, theta_r)
            k += 1
    return ia[:k].copy(), ib[:k].copy(), w[:k].copy()


@njit(cache=True)
def size_weights(ha: np.ndarray, hb: np.ndarray, ia: np.ndarray, ib: np.ndarray, theta_r: float) -> np.ndarray:
    """q_s of the associations (ia, ib)."""
    out = np.empty(len(ia))
    for t in range(len(ia)):
        out[t] = size_weight1(size_ratio1(ha[ia[t]], hb[ib[t]]), theta_r)
    return out


# --- the pair test -------------------------------------------------------------------------------------------------


@njit(cache=True)
def vector_invariants(x: float, y: float, z: float, mode: int) -> tuple:
    """(L, z, atan2(y, x)) of an oriented landmark-pair vector (L 3D for "distance", horizontal for "gravity")."""
    if mode == DISTANCE:
        return np.sqrt(x * x + y * y + z * z), z, 0.0
    return np.sqrt(x * x + y * y), z, np.arctan2(y, x)


@njit(cache=True)
def pair_mismatch(la: float, za: float, lb: float, zb: float, mode: int, eps: float, tan_tilt: float,
                  eps_z: float) -> float:
    """Mismatch c of two landmark-pair vectors (invariants of A's and B's), or -1 if they are inconsistent.

    distance: c = |L_a - L_b| <= eps. gravity: the horizontal lengths agree (|L_a - L_b| <= eps) and the height
    components agree up to the tilt: e_z = |z_a - z_b| - max(L_a, L_b) tan(tilt) <= eps_z; c = sqrt(c_h^2 + e_z+^2).
    """
    ch = abs(la - lb)
    if not ch <= eps:  # also false for NaN (inf - inf: a landmark shared on both sides)
        return -1.0
    if mode == DISTANCE:
        return ch
    ez = abs(za - zb) - max(la, lb) * tan_tilt
    if ez <= 0.0:
        return ch
    if ez > eps_z:
        return -1.0
    return np.sqrt(ch * ch + ez * ez)


@njit(cache=True)
def pair_consistent(la: float, za: float, lb: float, zb: float, mode: int, eps: float, tan_tilt: float,
                    eps_z: float) -> bool:
    """Whether `pair_mismatch` keeps the pair (its c is not -1), without a branch: the same decision for every
    input, NaN included (a NaN e_z gives pair_mismatch a NaN c, which no `c < 0` test removes)."""
    ok = abs(la - lb) <= eps
    if mode == DISTANCE:
        return ok
    ez = abs(za - zb) - max(la, lb) * tan_tilt
    return ok & ((ez <= 0.0) | (not ez > eps_z))


@njit(cache=True)
def pair_slices(anga: float, angb: float, la: float, lb: float, za: float, zb: float, eps: float,
                sin_tilt: float, nslices: int) -> tuple:
    """Yaw slices a consistent pair allows: (first slice, number of slices), slices of 2 pi / nslices.

    The pair implies the yaw theta = ang_a - ang_b (B's horizontal direction turned onto A's), known to within
    asin(err / min(L_a, L_b)), err = eps + max(|z_a|, |z_b|) sin(tilt) (a horizontal vector shorter than err
    allows any yaw). A consistent set of associations shares one yaw, so it lies in one slice.
    """
    if nslices <= 1:
        return 0, 1
    theta = anga - angb
    if theta < 0.0:
        theta += 2.0 * np.pi
    h = min(la, lb)
    err = eps + max(abs(za), abs(zb)) * sin_tilt
    if h <= err:
        return 0, nslices
    delta = np.arcsin(err / h)
    width = 2.0 * np.pi / nslices
    lo = np.int64(np.floor((theta - delta) / width))
    hi = np.int64(np.floor((theta + delta) / width))
    ns = hi - lo + 1
    if ns >= nslices:
        return 0, nslices
    return lo % nslices, ns


@njit(cache=True)
def in_slice(s: int, s0: int, ns: int, nslices: int) -> bool:
    return (s - s0) % nslices < ns


# --- the checks of a one-problem call (clipper.affinity_graph) ----------------------------------------------------

PROBLEM_NONE, PROBLEM_POINTS_A, PROBLEM_POINTS_B, PROBLEM_PAIRS = 0, 1, 2, 3


@njit(cache=True)
def check_problem(pa: np.ndarray, pb: np.ndarray, pairs: np.ndarray) -> int:
    """The first problem of (N, 3) points and (m, 2) landmark pairs: a coordinate of A or B not finite, or a pair
    indexing no landmark (PROBLEM_*); PROBLEM_NONE if there is none."""
    for i in range(pa.shape[0]):
        for c in range(pa.shape[1]):
            if not np.isfinite(pa[i, c]):
                return PROBLEM_POINTS_A
    for i in range(pb.shape[0]):
        for c in range(pb.shape[1]):
            if not np.isfinite(pb[i, c]):
                return PROBLEM_POINTS_B
    na = pa.shape[0]
    nb = pb.shape[0]
    for t in range(pairs.shape[0]):
        if pairs[t, 0] < 0 or pairs[t, 0] >= na or pairs[t, 1] < 0 or pairs[t, 1] >= nb:
            return PROBLEM_PAIRS
    return PROBLEM_NONE


# --- the graph of a set of associations ------------------------------------------------------------------------

TABLE_MAX = 2048  # up to this many distinct landmarks per map, pair invariants come from precomputed tables


@njit(cache=True)
def association_graph(pa: np.ndarray, pb: np.ndarray, ia: np.ndarray, ib: np.ndarray, mode: int, eps: float,
                      sigma: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    """Every consistent pair (p < q) of the associations (ia[p], ib[p]).

    Returns rows, cols (sorted by (row, col)), mismatch c, first yaw slice and number of slices of every edge
    (the affinity exp(-c^2 / 2 sigma^2) is computed where it is needed: `affinity_values`; sigma is unused here).
    Associations sharing a landmark on either side are never consistent. With few distinct landmarks (a window
    pair, or many putative associations among a few hundred landmarks) the m (m - 1) / 2 tests read per-map
    tables of the pair invariants (`invariant_table`), else they form the vectors on the fly; both give identical
    values.
    """
    ua, la = local_ids(ia, pa.shape[0])
    ub, lb = local_ids(ib, pb.shape[0])
    if len(ua) <= TABLE_MAX and len(ub) <= TABLE_MAX:
        ta = invariant_table(pa, ua, mode)
        tb = invariant_table(pb, ub, mode)
        return graph_from_tables(la, lb, ta, tb, mode, eps, sigma, tan_tilt, eps_z, sin_tilt, nslices)
    return _graph_direct(pa, pb, ia, ib, mode, eps, sigma, tan_tilt, eps_z, sin_tilt, nslices)


@njit(cache=True)
def local_ids(ids: np.ndarray, n: int) -> tuple:
    """Distinct values of `ids` (ascending) and each entry's index among them."""
    present = np.zeros(n, np.bool_)
    for v in ids:
        present[v] = True
    local = np.full(n, -1, np.int64)
    k = 0
    for v in range(n):
        if present[v]:
            local[v] = k
            k += 1
    uniq = np.empty(k, np.int64)
    for v in range(n):
        if present[v]:
            uniq[local[v]] = v
    out = np.empty(len(ids), np.int64)
    for t in range(len(ids)):
        out[t] = local[ids[t]]
    return uniq, out


@njit(cache=True)
def distance_table(points: np.ndarray, ids: np.ndarray, out: np.ndarray) -> None:
    """out[i, j] = the 3D distance of landmarks ids[i] and ids[j] (`vector_invariants`' expression for "distance"),
    +inf on the diagonal: `invariant_table`'s "distance" table.

    The reversed vector (-x, -y, -z) has the same squares, so the same length bit for bit: the table is formed row
    by row over every column (contiguous coordinates, a loop that vectorises; mirroring the upper triangle instead
    costs a strided store per entry, more than the square root it saves).
    """
    k = len(ids)
    xs = np.empty(k)
    ys = np.empty(k)
    zs = np.empty(k)
    for i in range(k):
        xs[i] = points[ids[i], 0]
        ys[i] = points[ids[i], 1]
        zs[i] = points[ids[i], 2]
    for i in range(k):
        row = out[i]
        xi, yi, zi = xs[i], ys[i], zs[i]
        for j in range(k):
            x = xs[j] - xi
            y = ys[j] - yi
            z = zs[j] - zi
            row[j] = np.sqrt(x * x + y * y + z * z)
        row[i] = np.inf


@njit(cache=True)
def invariant_table(points: np.ndarray, ids: np.ndarray, mode: int) -> np.ndarray:
    """(3, k, k) invariants of the vectors ids[i] -> ids[j] of landmarks `ids` (ascending): L, z, ang; for the
    "distance" test (1, k, k), L only (it reads nothing else).

    Each vector is formed from the lower to the higher id and reversed exactly, so [i, j] and [j, i] hold what
    `vector_invariants` gives for either orientation. The diagonal length is +inf: an association pair sharing
    a landmark never passes the test.
    """
    k = len(ids)
    if mode == DISTANCE:  # the 3D distance test reads the lengths only
        t = np.empty((1, k, k))
        distance_table(points, ids, t[0])
        return t
    t = np.empty((3, k, k))
    for i in range(k):
        t[0, i, i] = np.inf
        t[1, i, i] = 0.0
        t[2, i, i] = 0.0
        for j in range(i + 1, k):
            x = points[ids[j], 0] - points[ids[i], 0]
            y = points[ids[j], 1] - points[ids[i], 1]
            z = points[ids[j], 2] - points[ids[i], 2]
            ln, zz, ang = vector_invariants(x, y, z, mode)
            t[0, i, j] = ln
            t[1, i, j] = zz
            t[2, i, j] = ang
            ln, zz, ang = vector_invariants(-x, -y, -z, mode)
            t[0, j, i] = ln
            t[1, j, i] = zz
            t[2, j, i] = ang
    return t


@njit(cache=True)
def graph_from_tables(la: np.ndarray, lb: np.ndarray, ta: np.ndarray, tb: np.ndarray, mode: int, eps: float,
                      sigma: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    """`association_graph` from invariant tables; la, lb: each association's row in ta, tb."""
    m = len(la)
    cap = max(16, min(m * (m - 1) // 2 + 4 * m, 16 * m + 4096))
    # the length tests of pair_mismatch, every row in this thread (`kernels_sweep`)
    ua = la.astype(np.uint32)
    ub = lb.astype(np.uint32)
    count = np.empty(m, np.int64)
    found, ne = sweep_rows(ua, ub, ta[0], tb[0], eps, 0, m, np.empty(cap, np.int32), 0, count, np.zeros(0, np.int64))
    rows = np.empty(ne, np.int64)
    cols = np.empty(ne, np.int64)
    cs = np.empty(ne)
    # the edges with the length mismatch c (the same expression as the test)
    expand_rows(ua, ub, ta[0], tb[0], 0, m, found, 0, 0, count, rows, cols, cs)
    if mode != GRAVITY:  # the length test is the whole test, c the length mismatch
        return rows, cols, cs, np.zeros(ne, np.int64), np.ones(ne, np.int64)
    s0 = np.zeros(ne, np.int64)
    ns = np.ones(ne, np.int64)
    keep = np.ones(ne, np.bool_)
    for e in range(ne):
        p = rows[e]
        q = cols[e]
        # oriented from the lower A id, the B vector joining the partners in the same order
        if la[p] < la[q]:
            i, j, u, v = la[p], la[q], lb[p], lb[q]
        else:
            i, j, u, v = la[q], la[p], lb[q], lb[p]
        c = pair_mismatch(ta[0, i, j], ta[1, i, j], tb[0, u, v], tb[1, u, v], mode, eps, tan_tilt, eps_z)
        if c < 0.0:
            keep[e] = False
            continue
        cs[e] = c
        s0[e], ns[e] = pair_slices(ta[2, i, j], tb[2, u, v], ta[0, i, j], tb[0, u, v], ta[1, i, j], tb[1, u, v], eps,
                                   sin_tilt, nslices)
    return rows[keep], cols[keep], cs[keep], s0[keep], ns[keep]


@njit(cache=True)
def _graph_direct(pa: np.ndarray, pb: np.ndarray, ia: np.ndarray, ib: np.ndarray, mode: int, eps: float,
                  sigma: float, tan_tilt: float, eps_z: float, sin_tilt: float, nslices: int) -> tuple:
    m = len(ia)
    cap = max(16, min(m * (m - 1) // 2, 4 * m + 1024))
    rows = np.empty(cap, np.int64)
    cols = np.empty(cap, np.int64)
    cs = np.empty(cap)
    s0 = np.empty(cap, np.int64)
    ns = np.empty(cap, np.int64)
    ne = 0
    for p in range(m):
        for q in range(p + 1, m):
            if ia[p] == ia[q] or ib[p] == ib[q]:
                continue
            if ia[p] < ia[q]:
                a1, a2, b1, b2 = ia[p], ia[q], ib[p], ib[q]
            else:
                a1, a2, b1, b2 = ia[q], ia[p], ib[q], ib[p]
            lna, za, anga = vector_invariants(pa[a2, 0] - pa[a1, 0], pa[a2, 1] - pa[a1, 1], pa[a2, 2] - pa[a1, 2],
                                              mode)
            lnb, zb, angb = vector_invariants(pb[b2, 0] - pb[b1, 0], pb[b2, 1] - pb[b1, 1], pb[b2, 2] - pb[b1, 2],
                                              mode)
            c = pair_mismatch(lna, za, lnb, zb, mode, eps, tan_tilt, eps_z)
            if c < 0.0:
                continue
            if ne == cap:
                cap *= 2
                rows = grow(rows, cap)
                cols = grow(cols, cap)
                cs = grow(cs, cap)
                s0 = grow(s0, cap)
                ns = grow(ns, cap)
            rows[ne] = p
            cols[ne] = q
            cs[ne] = c
            if mode == GRAVITY:
                s0[ne], ns[ne] = pair_slices(anga, angb, lna, lnb, za, zb, eps, sin_tilt, nslices)
            else:
                s0[ne], ns[ne] = 0, 1
            ne += 1
    cs = cs[:ne].copy()
    return rows[:ne].copy(), cols[:ne].copy(), cs, s0[:ne].copy(), ns[:ne].copy()


_LN2_HI = 6.93147180369123816490e-01  # ln 2 split in two (fdlibm), so n ln 2 is exact in the reduction
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e00
_POW2_NEG = np.ldexp(1.0, -np.arange(1011))  # 2^-k, k = 0..1010 (e^x for x >= -700)


@njit(cache=True)
def exp_nonpositive(x: float) -> float:
    """e^x for x <= 0, to ~1 ulp: x = n ln 2 + r, |r| <= ln 2 / 2, e^r by its Taylor polynomial (degree 13),
    scaled by 2^n. Plain arithmetic (no library call), so the loops that use it vectorise, and every search path
    gets the same bits."""
    if x < -700.0:
        return 0.0
    if x > 0.0:
        x = 0.0
    n = np.floor(x * _INV_LN2 + 0.5)
    r = (x - n * _LN2_HI) - n * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    return p * _POW2_NEG[-np.int64(n)]


@njit(cache=True)
def affinity_values(c: np.ndarray, sigma: float) -> np.ndarray:
    """exp(-c^2 / 2 sigma^2): one evaluation shared by both search paths (bit-identical affinities)."""
    out = np.empty(len(c))
    s = 2.0 * sigma * sigma
    for e in range(len(c)):
        out[e] = exp_nonpositive(-(c[e] * c[e]) / s)
    return out
