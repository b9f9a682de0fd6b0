"""Compiled kernels of the solver (numba), the graph's storage: the symmetric CSR of an edge list, its values
and weighted degrees, induced subgraphs. The cores and cliques (`kernels_cliques.py`) and the relaxation
(`kernels_solve.py`) read it.

Compiled, cached on disk and without fast-math for the reasons `kernels_solve.py` gives.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
