"""Compiled kernels of the solver (numba): the CLIPPER relaxation, its rounding, and the drivers that select a
consistent set from a graph (with a clique bound from `kernels_cliques.py` first where asked). The graph's CSR
is built in `kernels_csr.py`.

NumPy is memory-bound on these loops (gathers over edge lists, a sparse mat-vec per gradient step, a peel that
revisits every edge each round); compiled, each is a single pass over its arrays. Every kernel is plain numpy in,
numpy out, deterministic, and cached on disk by numba (`cache=True`: the first call in a fresh environment
compiles for a few seconds, later processes load the machine code).

No fast-math: the windowed search and its straightforward reference must compute bit-identical affinities, so
every floating-point expression here is evaluated exactly as written.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_cliques import clique_weight, core_numbers, greedy_clique, top_core_clique
from .kernels_csr import csr_data, induced, sym_csr_weighted, weighted_degrees

# --- CLIPPER ---------------------------------------------------------------------------------------------------


@njit(cache=True)
def _md_matvec(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, diag: np.ndarray, d: float,
               u: np.ndarray, out: np.ndarray) -> float:
    """out = M_d u = M u - d (1 1^T - C) u; C has a unit diagonal and M's pattern; returns u . out."""
    s = 0.0
    for i in range(n):
        s += u[i]
    f = 0.0
    for i in range(n):
        acc = (diag[i] + d) * u[i]
        for p in range(indptr[i], indptr[i + 1]):
            acc += (data[p] + d) * u[indices[p]]
        acc -= d * s
        out[i] = acc
        f += u[i] * acc
    return f


@njit(cache=True)
def clipper_relax(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, diag: np.ndarray, tol_u: float,
                  max_outer: int, max_inner: int, beta: float, d0_from_violations: bool) -> tuple:
    """CLIPPER's relaxation max u^T M_d u, u >= 0, ||u|| = 1, with a penalty d that grows until supp(u) is a clique.

    Projected gradient ascent with backtracking (step doubled after each success, at most `max_inner` steps per d);
    u starts at M 1 (normalised). `d0_from_violations`: start d where CLIPPER (Lusk et al.) starts it, at the mean
    of (M u)_i / (sum of u over i's inconsistent partners) over the violating vertices, instead of at 0, so the
    penalty acts from the first step. Returns u, d and the gradient steps taken.
    """
    u = np.empty(n)
    for i in range(n):
        acc = diag[i]
        for p in range(indptr[i], indptr[i + 1]):
            acc += data[p]
        u[i] = acc + 1e-12
    nrm = np.sqrt(np.sum(u * u))
    u /= nrm
    y = np.empty(n)
    v = np.empty(n)
    yv = np.empty(n)
    cbu = np.empty(n)
    mu = np.empty(n)
    d = 0.0
    if d0_from_violations:
        d = _penalty_step(n, indptr, indices, data, diag, u, cbu, mu)
        if d < 0.0:
            d = 0.0
    steps = 0
    for _outer in range(max_outer):
        f = _md_matvec(n, indptr, indices, data, diag, d, u, y)
        alpha = 1.0
        for _inner in range(max_inner):
            while True:
                nv = 0.0
                for i in range(n):
                    x = u[i] + alpha * y[i]
                    x = x if x > 0.0 else 0.0
                    v[i] = x
                    nv += x * x
                if nv == 0.0:
                    alpha *= beta
                    continue
                nv = np.sqrt(nv)
                for i in range(n):
                    v[i] /= nv
                fv = _md_matvec(n, indptr, indices, data, diag, d, v, yv)
                if fv >= f - 1e-12 * max(1.0, abs(f)) or alpha < 1e-12:
                    break
                alpha *= beta
            steps += 1
            du = 0.0
            for i in range(n):
                du += (v[i] - u[i]) * (v[i] - u[i])
            du = np.sqrt(du)
            df = fv - f
            for i in range(n):
                u[i] = v[i]
                y[i] = yv[i]
            f = fv
            if du < tol_u or abs(df) < 1e-12 * max(1.0, abs(f)):
                break
            alpha = min(alpha * 2.0, 1e3)
        inc = _penalty_step(n, indptr, indices, data, diag, u, cbu, mu)
        if inc < 0.0:
            break
        d += inc
    return u, d, steps


@njit(cache=True)
def _penalty_step(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, diag: np.ndarray, u: np.ndarray,
                  cbu: np.ndarray, mu: np.ndarray) -> float:
    """Mean |(M u)_i / (C-bar u)_i| over the support vertices with an inconsistent support partner; -1 if none."""
    umax = 0.0
    for i in range(n):
        if u[i] > umax:
            umax = u[i]
    tol = 1e-8 * umax
    ssum = 0.0
    for i in range(n):
        if u[i] > tol:
            ssum += u[i]
    total = 0.0
    count = 0
    for i in range(n):
        if not u[i] > tol:
            continue
        cu = u[i]  # C has a unit diagonal
        m = diag[i] * u[i]
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            m += data[p] * u[j]
            if u[j] > tol:
                cu += u[j]
        c = ssum - cu
        if c > tol:
            total += abs(m / c)
            count += 1
    if count == 0:
        return -1.0
    return total / count


@njit(cache=True)
def greedy_round(n: int, indptr: np.ndarray, indices: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Greedy maximal clique, visiting vertices by decreasing u (rounded to 1e-12), then degree, then index."""
    ukey = np.empty(n, np.int64)
    deg = np.empty(n, np.int64)
    umax = 0.0
    for i in range(n):
        if u[i] > umax:
            umax = u[i]
    for i in range(n):
        ukey[i] = -np.int64(np.round(u[i] * 1e12))
        deg[i] = -(indptr[i + 1] - indptr[i])
    o1 = np.argsort(deg, kind="mergesort")  # ties keep index order
    o2 = np.argsort(ukey[o1], kind="mergesort")
    order = o1[o2]
    compat = np.ones(n, np.bool_)
    mark = np.zeros(n, np.bool_)
    chosen = np.empty(n, np.int64)
    nc = 0
    for t in range(n):
        i = order[t]
        if not compat[i]:
            continue
        chosen[nc] = i
        nc += 1
        # compat &= neighbours of i (and i itself is no longer a candidate)
        for p in range(indptr[i], indptr[i + 1]):
            mark[indices[p]] = True
        for j in range(n):
            if compat[j] and not mark[j]:
                compat[j] = False
        for p in range(indptr[i], indptr[i + 1]):
            mark[indices[p]] = False
        compat[i] = False
    out = np.sort(chosen[:nc])
    return out


# --- the solver of the search: a clique bound from the cores, CLIPPER where the bound leaves room ---------------

CLIPPER, BOUNDED = 0, 1


@njit(cache=True)
def solve_graph(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, diag: np.ndarray, method: int,
                tol_u: float, max_outer: int, max_inner: int, beta: float, d0_from_violations: bool) -> tuple:
    """Select a consistent set (a clique): returns selected (sorted), score, u, penalty d, gradient steps.

    method CLIPPER: the relaxation (`clipper_relax`) on the whole graph and greedy rounding.
    method BOUNDED: first a clique bound. A clique of size s + 1 needs s neighbours inside it, so it lies in the
    s-core; a greedy clique of the highest cores (`greedy_clique`) gives s, and only the s-core can hold a larger
    one. When it is empty the greedy clique is a maximum clique and nothing else runs; otherwise CLIPPER runs on
    the s-core and the larger set wins (a tie goes to the higher weight 1_S^T M 1_S).
    score = 1_S^T M 1_S / |S| (|S| when every affinity and weight is 1).
    """
    if n == 0:
        return np.zeros(0, np.int64), 0.0, np.zeros(0), 0.0, 0
    indptr, indices, data, wdeg = sym_csr_weighted(n, rows, cols, vals, diag)
    return solve_csr(n, indptr, indices, data, np.zeros(0, np.int64), wdeg, diag, method, tol_u, max_outer,
                     max_inner, beta, d0_from_violations)


@njit(cache=True)
def solve_graph_csr(indptr: np.ndarray, indices: np.ndarray, edge0: np.ndarray, vals: np.ndarray, diag: np.ndarray,
                    method: int, tol_u: float, max_outer: int, max_inner: int, beta: float,
                    d0_from_violations: bool) -> tuple:
    """`solve_graph` of a graph whose symmetric CSR structure is given (`kernels_problem.problem_graph`): vals the
    values of the edge list (sorted by (row, col)), edge0 its row pointers; the lists are ascending."""
    n = len(indptr) - 1
    if n == 0:
        return np.zeros(0, np.int64), 0.0, np.zeros(0), 0.0, 0
    return solve_csr(n, indptr, indices, vals, edge0, np.zeros(0), diag, method, tol_u, max_outer, max_inner, beta,
                     d0_from_violations)


@njit(cache=True)
def solve_csr(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, edge0: np.ndarray, wdeg: np.ndarray,
              diag: np.ndarray, method: int, tol_u: float, max_outer: int, max_inner: int, beta: float,
              d0_from_violations: bool) -> tuple:
    """`solve_graph` from the symmetric CSR and the weighted degrees. data: the CSR's values (edge0 empty), or an
    edge list's with edge0 its row pointers (`clique_weight`; the CSR's values are then formed, and the weighted
    degrees (wdeg empty) from them, only where a path reads them: not when the highest core is the clique)."""
    if len(indices) == n * (n - 1):
        # complete graph (common for a window pair's core): the positive M has a positive Perron vector, the
        # support is everything, consistent at d = 0, and rounding keeps all of it
        sel = np.arange(n)
        return sel, clique_weight(indptr, indices, data, edge0, diag, sel) / n, np.full(n, 1.0 / np.sqrt(n)), 0.0, 0
    if method == CLIPPER:
        if len(edge0):
            data = csr_data(indptr, indices, edge0, data)
        u, d, steps = clipper_relax(n, indptr, indices, data, diag, tol_u, max_outer, max_inner, beta,
                                    d0_from_violations)
        sel = greedy_round(n, indptr, indices, u)
        return sel, clique_weight(indptr, indices, data, np.zeros(0, np.int64), diag, sel) / len(sel), u, d, steps
    core = core_numbers(n, indptr, indices)
    best = top_core_clique(core)
    if len(best) == 0:
        if len(edge0):  # every path from here reads the CSR's values
            data = csr_data(indptr, indices, edge0, data)
            edge0 = np.zeros(0, np.int64)
        if len(wdeg) == 0:
            wdeg = weighted_degrees(indptr, data, diag)
        best = greedy_clique(n, indptr, indices, wdeg, core, 64)
    s = len(best)
    wb = clique_weight(indptr, indices, data, edge0, diag, best)
    keep = core >= s  # empty when the highest core is the clique (`top_core_clique`)
    u = np.zeros(n)
    if not keep.any():
        for v in best:
            u[v] = 1.0 / np.sqrt(s)
        return best, wb / s, u, 0.0, 0
    ids, ip, ix, dt = induced(n, indptr, indices, data, keep)
    u_sub, d, steps = clipper_relax(len(ids), ip, ix, dt, diag[ids], tol_u, max_outer, max_inner, beta,
                                    d0_from_violations)
    sel = ids[greedy_round(len(ids), ip, ix, u_sub)]
    u[ids] = u_sub
    ws = clique_weight(indptr, indices, data, np.zeros(0, np.int64), diag, sel)
    if len(sel) > s or (len(sel) == s and ws > wb):
        return sel, ws / len(sel), u, d, steps
    return best, wb / s, u, d, steps
