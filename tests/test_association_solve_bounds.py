"""The solver's shortcuts are exact: core numbers (with the early exit once the vertices left cannot hold a higher
core), the highest core taken as the clique when it is one (instead of the greedy clique), and the values of the
edge list read through its row pointers (the clique weight, the CSR's values and weighted degrees formed from
them)."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sosmatch.plugin.association import max_clique_exact
from sosmatch.plugin.association.clipper import ConsistencyGraph
from sosmatch.plugin.association.kernels_cliques import clique_weight, core_numbers, greedy_clique, top_core_clique
from sosmatch.plugin.association.kernels_csr import csr_data, sym_csr_weighted, weighted_degrees


def random_graph(seed: int, n: int, density: float, clique: int) -> tuple:
    """Edges (rows < cols, sorted by (row, col)) of a random graph with a clique planted on random vertices."""
    rng = np.random.default_rng(seed)
    adj = np.triu(rng.random((n, n)) < density, 1)
    members = rng.choice(n, min(clique, n), replace=False)
    adj[np.ix_(members, members)] = True
    adj = np.triu(adj, 1)
    r, c = np.nonzero(adj)
    return r.astype(np.int64), c.astype(np.int64), rng.random(len(r)), rng.uniform(0.5, 2.0, n)


def peeled_core_numbers(n: int, rows: np.ndarray, cols: np.ndarray) -> list:
    """Core numbers by their definition: repeatedly remove a vertex of least degree; its core number is the
    largest least degree seen so far."""
    nbr = [set() for _ in range(n)]
    for r, c in zip(rows.tolist(), cols.tolist()):
        nbr[r].add(c)
        nbr[c].add(r)
    alive = set(range(n))
    core = [0] * n
    level = 0
    while alive:
        v = min(alive, key=lambda x: (len(nbr[x] & alive), x))
        level = max(level, len(nbr[v] & alive))
        core[v] = level
        alive.remove(v)
    return core


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), density=st.floats(0.0, 1.0),
       clique=st.integers(0, 40))
def test_core_numbers_and_the_top_core_clique(seed, n, density, clique):
    rows, cols, vals, diag = random_graph(seed, n, density, clique)
    indptr, indices, data, wdeg = sym_csr_weighted(n, rows, cols, vals, diag)
    core = core_numbers(n, indptr, indices)
    assert core.tolist() == peeled_core_numbers(n, rows, cols)
    top = top_core_clique(core)
    greedy = greedy_clique(n, indptr, indices, wdeg, core, 64)
    if len(top):
        # the shortcut's answer is the greedy clique's, and a maximum clique
        assert top.tolist() == greedy.tolist()
        g = ConsistencyGraph(n, rows, cols, vals, diag)
        assert len(top) == len(max_clique_exact(g))
    else:
        assert (core == core.max()).sum() != core.max() + 1


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 40), density=st.floats(0.0, 1.0), clique=st.integers(0, 20))
def test_values_through_the_edge_lists_row_pointers(seed, n, density, clique):
    """From a sorted edge list and its row pointers: the CSR's values (`csr_data`), the weighted degrees and the
    clique weight (read in the edge list) have the bits of those of the CSR with its values (`sym_csr_weighted`)."""
    if n:
        rows, cols, vals, diag = random_graph(seed, n, density, clique)
    else:
        rows, cols, vals, diag = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    indptr, indices, data, wdeg = sym_csr_weighted(n, rows, cols, vals, diag)
    edge0 = np.searchsorted(rows, np.arange(n + 1))
    assert csr_data(indptr, indices, edge0, vals).tobytes() == data.tobytes()
    assert weighted_degrees(indptr, data, diag).tobytes() == wdeg.tobytes()
    rng = np.random.default_rng(seed)
    none = np.zeros(0, np.int64)
    for sel in (np.arange(n), np.sort(rng.choice(n, n // 2, replace=False)) if n else none):
        assert clique_weight(indptr, indices, vals, edge0, diag, sel) == clique_weight(indptr, indices, data, none,
                                                                                         diag, sel)


def window_pair_by_definition(n: int, rows: np.ndarray, cols: np.ndarray, cs: np.ndarray, s0: np.ndarray,
                              ns: np.ndarray, diag: np.ndarray, nslices: int, k: int, method: int,
                              sigma: float) -> tuple:
    """`solve_window_pair` as its docstring states it, with plain numpy: per yaw slice, the graph of the edges
    whose tolerance covers it on its vertices in ascending order, that graph's k-core, the solver on the core;
    the largest set wins, then the higher score, then the lower slice."""
    from sosmatch.plugin.association.kernels_cliques import kcore_mask
    from sosmatch.plugin.association.kernels_csr import sym_csr
    from sosmatch.plugin.association.kernels_graph import affinity_values
    from sosmatch.plugin.association.kernels_solve import solve_graph

    best = (False, [], 0.0, -1, 0)
    for sl in range(nslices):
        covers = (sl - s0) % nslices < ns
        r, c, v = rows[covers], cols[covers], cs[covers]
        verts = np.unique(np.concatenate([r, c]))
        if len(verts) <= k:
            continue
        lr, lc = np.searchsorted(verts, r), np.searchsorted(verts, c)
        ip, ix, _ = sym_csr(len(verts), lr, lc, v)
        core = kcore_mask(len(verts), ip, ix, np.ones(len(verts), bool), k)
        if core.sum() <= k:
            continue
        new = np.cumsum(core) - 1
        both = core[lr] & core[lc]
        ids = verts[core]
        sel, score, *_ = solve_graph(len(ids), new[lr[both]], new[lc[both]], affinity_values(v[both], sigma),
                                     diag[ids], method, 1e-6, 60, 100, 0.25, True)
        if not best[0] or len(sel) > len(best[1]) or (len(sel) == len(best[1]) and score > best[2]):
            best = (True, ids[sel].tolist(), score, sl, int(core.sum()))
    return best


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 40), density=st.floats(0.0, 1.0), clique=st.integers(0, 20),
       nslices=st.integers(1, 12), k=st.integers(1, 7), method=st.sampled_from([0, 1]))
def test_window_pair_per_slice_equals_its_definition(seed, n, density, clique, nslices, k, method):
    """The window pair's per-slice work (degrees on the slice's edge list, the vertices of degree >= k found by a
    scan instead of a sort of the endpoints) selects what the plain statement of the method selects."""
    from sosmatch.plugin.association.kernels_search import solve_window_pair

    rows, cols, cs, diag = random_graph(seed, n, density, clique)
    cs = cs * 3.0  # distance mismatches in metres, some beyond sigma
    rng = np.random.default_rng(seed + 1)
    s0 = rng.integers(0, nslices, len(rows)).astype(np.int64)
    ns = rng.integers(1, nslices + 1, len(rows)).astype(np.int64)
    found, sel, score, sl, ncore = solve_window_pair(n, rows, cols, cs, s0, ns, diag, nslices, k, method, 1.0)
    want = window_pair_by_definition(n, rows, cols, cs, s0, ns, diag, nslices, k, method, 1.0)
    assert (found, sel.tolist(), sl, ncore) == (want[0], want[1], want[3], want[4])
    assert score == want[2]
