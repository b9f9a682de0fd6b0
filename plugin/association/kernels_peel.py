"""Compiled kernels of the windowed search (numba): the yaw slices and the peel, which drops the associations no
window pair's core can hold before any window pair's graph is gathered (`kernels_search.py` then solves them).

Compiled, cached on disk and without fast-math for the reasons `kernels_solve.py` gives.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels_cliques import kcore_mask
from .kernels_csr import sym_csr
from .kernels_graph import local_ids

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


# --- the peel ----------------------------------------------------------------------------------------------------


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
    # renumber the associations of the surviving pairs: where they are many against the id space (maps of two
    # places: nearly every pair survives), marked in the table and read off a scan of it; where they are few, sorted
    if space <= 8 * len(sel):
        for x in range(len(sel)):
            cnt[v1[sel[x]]] = -1
            cnt[v2[sel[x]]] = -1
        nu = 0
        for v in range(space):
            nu += cnt[v] == -1
        ids = np.empty(nu, np.int64)
        nu = 0
        for v in range(space):
            if cnt[v] == -1:
                ids[nu] = v
                nu += 1
    else:
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
