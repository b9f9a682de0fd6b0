"""Compiled kernels of the solver (numba): symmetric CSR, k-cores, the CLIPPER relaxation, rounding, clique bound.

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

# --- symmetric CSR -------------------------------------------------------------------------------------------


@njit(cache=True)
def sym_csr(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> tuple:
    """Symmetric CSR (no diagonal) of the upper-triangle edge list rows < cols: indptr, indices, data.

    An edge list sorted by (row, col) gives ascending neighbour lists (the edges (r, i), r < i, come before
    (i, c) and each group in order), which makes every sum over a neighbourhood independent of how the graph was
    built.
    """
    indptr, indices, data, _ = _sym_csr(n, rows, cols, vals, np.zeros(0), False)
    return indptr, indices, data


@njit(cache=True)
def sym_csr_weighted(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, diag: np.ndarray) -> tuple:
    """`sym_csr` and the weighted degrees diag[i] + sum of i's affinities, summed in i's neighbour-list order (the
    order the scatter delivers them in, so the same bits as a sum over the finished list), in the same pass."""
    return _sym_csr(n, rows, cols, vals, diag, True)


@njit(cache=True)
def _sym_csr(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, diag: np.ndarray, weighted: bool) -> tuple:
    deg = np.zeros(n, np.int64)
    last = 0
    run = 0  # a run of equal rows counted in a register (an increment of deg[r] per edge waits for the previous one)
    for e in range(len(rows)):
        r = rows[e]
        if r != last:
            deg[last] += run
            run = 0
            last = r
        run += 1
        deg[cols[e]] += 1
    if len(rows):
        deg[last] += run
    indptr = np.zeros(n + 1, np.int64)
    for i in range(n):
        indptr[i + 1] = indptr[i] + deg[i]
    fill = indptr[:-1].copy()
    indices = np.empty(indptr[n], np.int32)  # int32: half the scattered writes (and reads by every consumer)
    data = np.empty(indptr[n], np.float64)
    wdeg = diag.copy() if weighted else np.zeros(0)
    for e in range(len(rows)):  # both ends appended in edge order (ascending lists when sorted by (row, col))
        r, c, v = rows[e], cols[e], vals[e]
        k = fill[r]
        indices[k] = c
        data[k] = v
        fill[r] = k + 1
        k = fill[c]
        indices[k] = r
        data[k] = v
        fill[c] = k + 1
        if weighted:
            wdeg[r] += v
            wdeg[c] += v
    return indptr, indices, data, wdeg


# --- k-cores -------------------------------------------------------------------------------------------------


@njit(cache=True)
def kcore_mask(n: int, indptr: np.ndarray, indices: np.ndarray, alive_in: np.ndarray, k: int) -> np.ndarray:
    """Vertices of the k-core of the subgraph induced by `alive_in` (queue-based peel, O(E))."""
    alive = alive_in.copy()
    deg = np.zeros(n, np.int64)
    for i in range(n):
        if alive[i]:
            d = 0
            for p in range(indptr[i], indptr[i + 1]):
                if alive[indices[p]]:
                    d += 1
            deg[i] = d
    queue = np.empty(n, np.int64)
    head = 0
    tail = 0
    for i in range(n):
        if alive[i] and deg[i] < k:
            alive[i] = False
            queue[tail] = i
            tail += 1
    while head < tail:
        i = queue[head]
        head += 1
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if alive[j]:
                deg[j] -= 1
                if deg[j] < k:
                    alive[j] = False
                    queue[tail] = j
                    tail += 1
    return alive


@njit(cache=True)
def core_numbers(n: int, indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Core number of every vertex (Batagelj-Zaversnik bucket algorithm, O(E))."""
    deg = np.empty(n, np.int64)
    md = 0
    for i in range(n):
        deg[i] = indptr[i + 1] - indptr[i]
        if deg[i] > md:
            md = deg[i]
    bin_ = np.zeros(md + 2, np.int64)
    for i in range(n):
        bin_[deg[i]] += 1
    start = 0
    for d in range(md + 1):
        num = bin_[d]
        bin_[d] = start
        start += num
    pos = np.empty(n, np.int64)
    vert = np.empty(n, np.int64)
    for i in range(n):
        pos[i] = bin_[deg[i]]
        vert[pos[i]] = i
        bin_[deg[i]] += 1
    for d in range(md, 0, -1):
        bin_[d] = bin_[d - 1]
    bin_[0] = 0
    for a in range(n):
        v = vert[a]
        dv = deg[v]  # final: v is taken at its core number, and only higher-degree neighbours change below
        if dv >= n - 1 - a:
            # The n - a vertices left have at most n - 1 - a neighbours among themselves, so a k-core with k > dv
            # (which holds none of the vertices taken, their core numbers are <= dv) cannot exist: every vertex left
            # has core number dv (>= dv, as they are taken in order). Typically the true associations' clique,
            # whose lists (most of the graph's entries) need not be walked.
            for b in range(a + 1, n):
                deg[vert[b]] = dv
            break
        for p in range(indptr[v], indptr[v + 1]):
            u = np.uint32(indices[p])  # unsigned: no negative-index wraparound on the reads below
            du = deg[u]
            if du > dv:
                pu = pos[u]
                pw = bin_[du]
                w = vert[pw]
                if u != w:
                    pos[u] = pw
                    vert[pu] = w
                    pos[w] = pu
                    vert[pw] = u
                bin_[du] += 1
                deg[u] = du - 1
    return deg


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


@njit(cache=True)
def greedy_clique(n: int, indptr: np.ndarray, indices: np.ndarray, weighted_degree: np.ndarray, core: np.ndarray,
                  max_starts: int) -> np.ndarray:
    """A large clique, grown greedily from the vertices of highest core number (the PMC heuristic).

    A clique of size s + 1 lies in the s-core, so growing from v only considers neighbours whose core number
    is at least the best size so far, and the search stops once no vertex can start a larger clique. Returns the
    clique's vertices (sorted). Vertices are visited by decreasing core number, then decreasing weighted degree
    (diagonal weight + affinities, `sym_csr_weighted`: of two equally large cliques the heavier one is found
    first), then index.
    """
    wdeg = -weighted_degree
    # The visiting order is (-core, -weighted degree, index). The search stops after a few starts (usually one,
    # in the highest core), so the order is formed lazily: vertices bucketed by core number (counting sort), a
    # bucket sorted when the walk reaches it, and each start's candidates sorted among themselves by the same key.
    maxcore = 0
    for i in range(n):
        maxcore = max(maxcore, core[i])
    boff = np.zeros(maxcore + 2, np.int64)
    for i in range(n):
        boff[maxcore - core[i] + 1] += 1  # bucket 0 holds the highest core
    for c in range(maxcore + 1):
        boff[c + 1] += boff[c]
    fill = boff[:-1].copy()
    byc = np.empty(n, np.int64)
    for i in range(n):  # ascending index within a bucket
        byc[fill[maxcore - core[i]]] = i
        fill[maxcore - core[i]] += 1
    mark = np.zeros(n, np.int64)  # stamp of the current clique's common neighbourhood
    best = np.zeros(0, np.int64)
    cand = np.empty(n, np.int64)
    clique = np.empty(n, np.int64)
    stamp = 0
    t = 0
    for bk in range(maxcore + 1):
        if t >= max_starts or boff[bk + 1] == boff[bk]:
            continue
        if maxcore - bk + 1 <= len(best):
            break
        members = byc[boff[bk]: boff[bk + 1]]
        members = members[np.argsort(wdeg[members], kind="mergesort")]  # stable: ties by index
        for v in members:
            if t >= max_starts or core[v] + 1 <= len(best):
                break
            t += 1
            nc = 0
            for p in range(indptr[v], indptr[v + 1]):
                w = indices[p]
                if core[w] >= len(best):
                    cand[nc] = w
                    nc += 1
            # candidates in the global order: sorted by index, then weighted degree, then core (stable sorts; the
            # neighbour lists are ascending wherever they come from, so the index sort is only a safeguard)
            cs = cand[:nc]
            for k in range(1, nc):
                if cs[k - 1] > cs[k]:
                    cs = np.sort(cs)
                    break
            cs = cs[np.argsort(wdeg[cs], kind="mergesort")]
            negc = np.empty(nc, np.int64)
            for k in range(nc):
                negc[k] = -core[cs[k]]
            cs = cs[np.argsort(negc, kind="mergesort")]
            size = 1
            clique[0] = v
            stamp += 1
            for p in range(indptr[v], indptr[v + 1]):
                mark[indices[p]] = stamp  # common neighbours of the clique so far carry the current stamp
            for k in range(nc):
                w = cs[k]
                if mark[w] != stamp:
                    continue
                clique[size] = w
                size += 1
                stamp += 1
                for p in range(indptr[w], indptr[w + 1]):
                    x = indices[p]
                    if mark[x] == stamp - 1:
                        mark[x] = stamp
            if size > len(best):
                best = np.sort(clique[:size].copy())
    return best


@njit(cache=True)
def top_core_clique(core: np.ndarray) -> np.ndarray:
    """The vertices of the highest core (ascending) when they are a clique, else an empty array.

    With c the highest core number, the c-core is the set of vertices of core number c, and each has >= c
    neighbours in it; when it holds exactly c + 1 vertices, each is adjacent to all the others: a clique, and a
    maximum one (a clique of k vertices lies in the (k - 1)-core, so k <= c + 1). `greedy_clique` then returns
    exactly this set (it starts in the highest core, takes the other c vertices of that core first, and no vertex
    outside can join a clique of c + 1: that would make one of c + 2), so it need not run, nor need the weighted
    degrees that order it be formed. Typical of a CLIPPER problem: the true associations are the highest core."""
    n = len(core)
    c = -1
    k = 0
    for i in range(n):
        if core[i] > c:
            c = core[i]
            k = 1
        elif core[i] == c:
            k += 1
    if n == 0 or k != c + 1:
        return np.zeros(0, np.int64)
    out = np.empty(k, np.int64)
    j = 0
    for i in range(n):
        if core[i] == c:
            out[j] = i
            j += 1
    return out


@njit(cache=True)
def induced(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, keep: np.ndarray) -> tuple:
    """CSR of the subgraph induced by `keep`: (vertex ids, indptr, indices, data)."""
    new = np.full(n, -1, np.int64)
    k = 0
    for i in range(n):
        if keep[i]:
            new[i] = k
            k += 1
    ids = np.empty(k, np.int64)
    ip = np.zeros(k + 1, np.int64)
    cnt = 0
    for i in range(n):
        if keep[i]:
            for p in range(indptr[i], indptr[i + 1]):
                if keep[indices[p]]:
                    cnt += 1
            ip[new[i] + 1] = cnt
            ids[new[i]] = i
    ix = np.empty(cnt, np.int64)
    dt = np.empty(cnt, np.float64)
    e = 0
    for i in range(n):
        if keep[i]:
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if keep[j]:
                    ix[e] = new[j]
                    dt[e] = data[p]
                    e += 1
    return ids, ip, ix, dt


@njit(cache=True)
def clique_weight(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, edge0: np.ndarray, diag: np.ndarray,
                  sel: np.ndarray) -> float:
    """1_S^T M 1_S of the sorted vertex set `sel`, edges summed in (v, w) order: with sorted neighbour lists (an
    edge list sorted by (row, col) gives them, see `sym_csr`) the same value whatever else differs.

    data: the CSR's values (edge0 empty), or the edge list's (sorted by (row, col); edge0 its row pointers: v's
    edges are v's higher neighbours, the last edge0[v + 1] - edge0[v] entries of its ascending list), read there
    without forming the CSR's values."""
    inside = np.zeros(len(indptr) - 1, np.bool_)
    for v in sel:
        inside[v] = True
    s = 0.0
    for v in sel:
        if len(edge0):
            e = edge0[v]
            higher = indptr[v + 1] - (edge0[v + 1] - e)
            for k in range(indptr[v + 1] - higher):
                if inside[indices[higher + k]]:
                    s += data[e + k]
        else:
            for p in range(indptr[v], indptr[v + 1]):
                if indices[p] > v and inside[indices[p]]:
                    s += data[p]
    t = 0.0
    for v in sel:
        t += diag[v]
    return 2.0 * s + t


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
def csr_data(indptr: np.ndarray, indices: np.ndarray, edge0: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """The values `vals` of an edge list sorted by (row, col) (row p's edges vals[edge0[p]:edge0[p + 1]], p's
    higher neighbours) in the order of the CSR's entries: each vertex's lower entries, filled in row order, then its
    higher ones."""
    n = len(indptr) - 1
    data = np.empty(indptr[n])
    fill = indptr[:-1].copy()
    for p in range(n):
        e = edge0[p]
        higher = indptr[p + 1] - (edge0[p + 1] - e)
        for k in range(edge0[p + 1] - e):
            v = vals[e + k]
            data[higher + k] = v
            q = indices[higher + k]
            data[fill[q]] = v
            fill[q] += 1
    return data


@njit(cache=True)
def weighted_degrees(indptr: np.ndarray, data: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """diag[i] + the affinities of i's entries, summed in i's neighbour-list order (`sym_csr_weighted`'s bits)."""
    n = len(indptr) - 1
    wdeg = np.empty(n)
    for i in range(n):
        w = diag[i]
        for k in range(indptr[i], indptr[i + 1]):
            w += data[k]
        wdeg[i] = w
    return wdeg


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
