"""The graph of one CLIPPER problem (`clipper.affinity_graph`) in one compiled call, on both cores (numba).

The distance-consistency graph of m associations is m^2 / 2 length tests against two per-map distance tables
(`kernels_sweep`). Here the rows are cut into blocks of about equal numbers of tests, one per thread, and each
block's edges land at their place in row order, so the output is the same whatever the number of threads (one
thread included) and the same as `kernels_graph.association_graph` gives. The same call also returns the
symmetric CSR structure of the graph (what `solve` needs, built by whoever holds the rows' edges: here), so
the solver does not scatter the edge list again.

Threads: numba's `prange` (its OpenMP or TBB layer; the workqueue layer when neither is installed). The C++
reference of the benchmark runs its affinity on 2 OpenMP threads as well.
"""

from __future__ import annotations

import os
import threading
import time
import types

import numba
import numpy as np
from numba import njit, prange

from .kernels_graph import DISTANCE, PROBLEM_NONE, TABLE_MAX, _graph_direct, check_problem, distance_table, local_ids
from .kernels_sweep import expand_rows, sweep_rows


@njit(cache=True)
def row_blocks(m: int, blocks: int) -> np.ndarray:
    """Row bounds of `blocks` consecutive blocks of about equal numbers of tests (row p holds m - 1 - p), and the
    number of tests before each block."""
    total = m * (m - 1) // 2
    bounds = np.empty(blocks + 1, np.int64)
    bounds[0] = 0
    p = 0
    done = 0
    for b in range(1, blocks):
        target = total * b // blocks
        while p < m and done < target:
            done += m - 1 - p
            p += 1
        bounds[b] = p
    bounds[blocks] = m
    base = np.zeros(blocks + 1, np.int64)  # the tests of the rows before each block
    for t in range(blocks):
        r0, r1 = bounds[t], bounds[t + 1]
        base[t + 1] = base[t] + (r1 - r0) * (2 * m - r0 - r1 - 1) // 2
    return bounds, base


@njit(cache=True)
def csr_offsets(ends: np.ndarray, base: np.ndarray, count: np.ndarray, lower: np.ndarray, bounds: np.ndarray) -> tuple:
    """Where each block's edges start in row order (start), the CSR's indptr (a vertex's list: its lower
    neighbours, then its `count` higher ones), where each row's columns are in `found` (src) and the index of its
    first edge (edge0, m + 1 entries: the row pointers of the edge list), and vertex bounds of blocks of about
    equal numbers of CSR entries (vb). (A function of its own: numba's array analysis of the parallel build got the
    length of arrays allocated among its loops wrong.)"""
    blocks, m = lower.shape
    start = np.zeros(blocks + 1, np.int64)
    src = np.empty(m, np.int64)
    edge0 = np.empty(m + 1, np.int64)
    for t in range(blocks):
        start[t + 1] = start[t] + ends[t] - base[t]
        k = base[t]
        e = start[t]
        for p in range(bounds[t], bounds[t + 1]):
            src[p] = k
            edge0[p] = e
            k += count[p]
            e += count[p]
    edge0[m] = start[blocks]
    indptr = np.zeros(m + 1, np.int64)
    for v in range(m):
        d = count[v]
        for t in range(blocks):
            d += lower[t, v]
        indptr[v + 1] = indptr[v] + d
    vb = np.empty(blocks + 1, np.int64)
    vb[0] = 0
    v = 0
    for t in range(1, blocks):
        while v < m and indptr[v] < indptr[m] * t // blocks:
            v += 1
        vb[t] = v
    vb[blocks] = m
    return start, indptr, src, edge0, vb


@njit(cache=True)
def fill_csr(v0: int, v1: int, found: np.ndarray, count: np.ndarray, src: np.ndarray, indptr: np.ndarray,
             indices: np.ndarray) -> None:
    """The neighbour lists of vertices [v0, v1): the lower neighbours p < v in row order, read from every earlier
    row's columns, then v's own columns. Each block of vertices writes only its own lists (blocks of rows
    scattering into shared lists wrote the same cache lines from both cores)."""
    fill = indptr[v0:v1].copy()
    for p in range(v1):
        s0 = src[p]
        # row p's columns are ascending: those in [v0, v1) are one run, entered by a binary search (a block of
        # vertices reads only its own entries)
        lo = 0
        hi = count[p]
        while lo < hi and v0 > p + 1:
            mid = (lo + hi) >> 1
            if found[s0 + mid] < v0:
                lo = mid + 1
            else:
                hi = mid
        for k in range(lo, count[p]):
            q = found[s0 + k]
            if q >= v1:
                break
            j = fill[q - v0]
            indices[j] = p
            fill[q - v0] = j + 1
    for v in range(v0, v1):
        j = indptr[v + 1] - count[v]
        for k in range(count[v]):
            indices[j + k] = found[src[v] + k]


def _problem_graph(pa: np.ndarray, pb: np.ndarray, pairs: np.ndarray, eps: float, two_s2: float,
                  blocks: int) -> tuple:
    """The consistency graph of associations `pairs` (m, 2) between points pa and pb: (problem, rows, cols, x,
    indptr, indices, edge0).

    problem: `check_problem`'s code (nothing else is computed unless it is PROBLEM_NONE). rows < cols, sorted by
    (row, col), as `association_graph` gives them; x = -(c * c) / two_s2 of each edge's length mismatch c (the
    affinity is exp(x), taken by numpy as before: the same bits). indptr, indices (int32): the symmetric CSR of the
    edges, each vertex's neighbours ascending (its lower ones, then its higher ones: `kernels_csr.sym_csr`'s
    order); edge0: the row pointers of the edge list (row p's edges are edge0[p]:edge0[p + 1], and they are p's
    higher neighbours in the CSR: the solver reads their values there and forms the rest only when it needs it).
    With more distinct landmarks than the tables hold (`TABLE_MAX`) the CSR is left empty (indptr of length 0) and
    the solver builds it from the edge list.
    """
    empty_i = np.zeros(0, np.int64)
    empty_32 = np.zeros(0, np.int32)
    problem = check_problem(pa, pb, pairs)
    if problem != PROBLEM_NONE:
        return problem, empty_i, empty_i, np.zeros(0), empty_i, empty_32, empty_i
    m = pairs.shape[0]
    ia = pairs[:, 0].copy()
    ib = pairs[:, 1].copy()
    ids_a, la = local_ids(ia, pa.shape[0])
    ids_b, lb = local_ids(ib, pb.shape[0])
    if len(ids_a) > TABLE_MAX or len(ids_b) > TABLE_MAX:  # too many landmarks for tables: vectors on the fly
        rows, cols, x, _, _ = _graph_direct(pa, pb, ia, ib, DISTANCE, eps, 0.0, 0.0, 0.0, 0.0, 1)
        for e in range(len(x)):
            c = x[e]
            x[e] = -(c * c) / two_s2
        return problem, rows, cols, x, empty_i, empty_32, empty_i
    lena = np.empty((len(ids_a), len(ids_a)))
    lenb = np.empty((len(ids_b), len(ids_b)))
    for t in prange(2):  # the two maps' distance tables side by side
        if t == 0:
            distance_table(pa, ids_a, lena)
        else:
            distance_table(pb, ids_b, lenb)
    ua = la.astype(np.uint32)
    ub = lb.astype(np.uint32)
    # block t's columns go to found[base[t]:], base = the tests of the rows before it (no block can outgrow its
    # share; the 4 m of slack keep sweep_rows' room check for four whole rows from growing a private copy)
    bounds, base = row_blocks(m, blocks)
    found = np.empty(base[blocks] + 4 * m, np.int32)
    count = np.zeros(m, np.int64)
    ends = np.empty(blocks, np.int64)
    # how many lower neighbours each vertex has in each block (block t's rows are lower than the later blocks')
    lower = np.zeros((blocks, m), np.int64)
    for t in prange(blocks):
        _, end = sweep_rows(ua, ub, lena, lenb, eps, bounds[t], bounds[t + 1], found, base[t], count, lower[t])
        ends[t] = end
    start, indptr, src, edge0, vb = csr_offsets(ends, base, count, lower, bounds)
    ne = start[blocks]
    rows = np.empty(ne, np.int64)
    cols = np.empty(ne, np.int64)
    x = np.empty(ne)
    indices = np.empty(indptr[m], np.int32)
    # each block writes its rows' edges with the affinity argument, and the neighbour lists of its vertices
    for t in prange(blocks):
        expand_rows(ua, ub, lena, lenb, bounds[t], bounds[t + 1], found, base[t], start[t], count, rows, cols, x)
        for e in range(start[t], start[t + 1]):
            c = x[e]
            x[e] = -(c * c) / two_s2  # numpy's order before: multiply, negate, divide
        fill_csr(vb[t], vb[t + 1], found, count, src, indptr, indices)
    return problem, rows, cols, x, indptr, indices, edge0


def _named(func: types.FunctionType, name: str) -> types.FunctionType:
    """`func` under another name: numba keys its on-disk cache by the function's qualified name and not by the
    `parallel` flag, so the two builds of one source need two names (else one loads the other's machine code)."""
    out = types.FunctionType(func.__code__, func.__globals__, name, func.__defaults__, func.__closure__)
    out.__qualname__ = name
    out.__doc__ = func.__doc__
    return out


# one source, compiled twice: in the serial build prange is range (no thread pool is woken for one block)
problem_graph_serial = njit(cache=True)(_named(_problem_graph, "problem_graph_serial"))
problem_graph_parallel = njit(cache=True, parallel=True)(_named(_problem_graph, "problem_graph_parallel"))

PARALLEL_MIN = 256  # from this many associations on, one block of rows per thread when a core is free
_lock = threading.Lock()
_free: list = [-1.0, False]  # when the load was last read (monotonic s), and whether a core was free then
_threads: list = [-1.0, 1]  # when numba's thread count was last read, and the count
_pid = os.getpid()
calls = [0, 0]  # problems of >= PARALLEL_MIN associations done in one thread, and on every thread (benchmarks)


def _others_running() -> int:
    """Runnable tasks of other processes now: /proc/loadavg's count less this process's own runnable threads (the
    reader, and a thread pool still spinning after the last parallel loop). Linux only (OSError elsewhere)."""
    with open("/proc/loadavg") as f:
        running = int(f.read().split()[3].split("/")[0])
    own = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat", "rb") as f:
                stat = f.read()
        except FileNotFoundError:  # a thread that ended meanwhile
            continue
        own += stat[stat.rindex(b")") + 2: stat.rindex(b")") + 3] == b"R"
    return running - own


def thread_count() -> int:
    """numba.get_num_threads(), read at most every 0.25 s: a call costs ~1 us, 1 % of a problem of 256
    associations. (numba's count is per thread; a count read in another thread changes only how many blocks of
    rows are formed, never the output.)"""
    now = time.monotonic()
    if now - _threads[0] > 0.25:
        _threads[:] = [now, numba.get_num_threads()]
    return _threads[1]


def core_free(threads: int) -> bool:
    """Whether `threads` threads would each find a core: other processes' runnable tasks leave that many idle
    (read at most every 0.25 s). On a busy machine a thread of a parallel loop waits for a core and the call waits
    for that thread (the C++ reference's 2-thread affinity then runs 4-16x its quiet time): there one thread does
    all the rows."""
    now = time.monotonic()
    if now - _free[0] > 0.25:
        try:
            _free[1] = _others_running() <= (os.cpu_count() or 1) - threads
        except (OSError, ValueError, IndexError):
            _free[1] = False
        _free[0] = now
    return _free[1]


def problem_graph(pa: np.ndarray, pb: np.ndarray, pairs: np.ndarray, eps: float, two_s2: float) -> tuple:
    """`_problem_graph`, in one block of rows per thread from PARALLEL_MIN associations on when a core is free,
    else in this thread; the same output either way.

    One parallel call at a time (numba's workqueue layer, used when neither OpenMP nor TBB is installed, must not
    be entered by two threads; a concurrent caller takes the serial build), and none in a forked child (GNU
    OpenMP cannot run in a child of a process that used it).
    """
    threads = thread_count()
    if len(pairs) >= PARALLEL_MIN and threads > 1 and os.getpid() == _pid and core_free(threads) and \
            _lock.acquire(blocking=False):
        try:
            calls[1] += 1
            return problem_graph_parallel(pa, pb, pairs, eps, two_s2, threads)
        finally:
            _lock.release()
    calls[0] += len(pairs) >= PARALLEL_MIN
    return problem_graph_serial(pa, pb, pairs, eps, two_s2, 1)
