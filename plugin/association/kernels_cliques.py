"""Compiled kernels of the solver (numba), the combinatorial side: k-cores, core numbers, the greedy clique of
the highest cores and its weight; `kernels_solve.solve_csr` takes a clique from here as the bound CLIPPER must
beat.

Compiled, cached on disk and without fast-math for the reasons `kernels_solve.py` gives.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
