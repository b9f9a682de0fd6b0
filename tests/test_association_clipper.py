"""CLIPPER: planted problems with known answers, agreement with an exhaustive maximum clique, invariances, bad input."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sosmatch.plugin.association import (
    affinity_graph,
    associate,
    fit_transform,
    max_clique_exact,
    rotation_from_rpy_deg,
    solve,
    tilt_deg,
)
from sosmatch.plugin.association.clipper import ConsistencyGraph, core_numbers
from sosmatch.plugin.errors import InputError


def planted(n_true, n_out, noise=0.1, seed=0, box=100.0, n_extra=0):
    """n_true true associations of a rigid copy plus n_out random wrong pairs (shuffled)."""
    rng = np.random.default_rng(seed)
    n = n_true + n_extra
    a = rng.uniform(0, box, (n, 3)) * [1, 1, 0.2]
    r = rotation_from_rpy_deg(*rng.uniform(-3, 3, 2), rng.uniform(-180, 180))
    t = rng.uniform(-500, 500, 3)
    b = a @ r.T + t + rng.normal(0, noise, a.shape)
    true = np.stack([np.arange(n_true)] * 2, 1)
    wrong = set()
    while len(wrong) < n_out:
        i, j = rng.integers(0, n, 2)
        if i != j:
            wrong.add((int(i), int(j)))
    pairs = np.concatenate([true, np.array(sorted(wrong), dtype=np.int64).reshape(-1, 2)])
    perm = rng.permutation(len(pairs))
    return a, b, pairs[perm], perm < n_true, r, t


@pytest.mark.parametrize("outlier_ratio", [0.0, 0.5, 0.8, 0.9, 0.95])
@pytest.mark.parametrize("noise", [0.0, 0.1, 0.3])
def test_planted_inliers_recovered(outlier_ratio, noise):
    n_true = 20
    n_out = int(round(n_true * outlier_ratio / (1 - outlier_ratio)))
    a, b, pairs, is_true, r, t = planted(n_true, n_out, noise, seed=int(100 * outlier_ratio + 10 * noise))
    res = associate(a, b, pairs, eps=2.0, sigma=1.0)
    sel = res.selected
    assert is_true[sel].sum() >= 0.95 * n_true
    assert not (~is_true[sel]).any()
    # the selected set is consistent by construction: every pair within eps
    da = np.linalg.norm(a[pairs[sel, 0]][:, None] - a[pairs[sel, 0]][None], axis=-1)
    db = np.linalg.norm(b[pairs[sel, 1]][:, None] - b[pairs[sel, 1]][None], axis=-1)
    assert np.abs(da - db).max() <= 2.0
    fit = fit_transform(b[pairs[sel, 1]], a[pairs[sel, 0]])
    # the truth maps a to b (b = R a + t); the fit maps b back to a
    assert np.allclose(fit.rotation, r.T, atol=0.02)
    assert np.allclose(fit.apply(b[:n_true]), a[:n_true], atol=6 * noise + 1e-6)


@pytest.mark.parametrize("seed", range(12))
def test_agrees_with_exhaustive_maximum_clique(seed):
    rng = np.random.default_rng(seed)
    n_true = int(rng.integers(4, 10))
    n_out = int(rng.integers(5, 30))
    a, b, pairs, _, _, _ = planted(n_true, n_out, noise=0.2, seed=seed, box=30.0, n_extra=3)
    graph = affinity_graph(a, b, pairs, eps=2.0, sigma=1e6)  # flat affinities: the densest set is the largest
    exact = max_clique_exact(graph)
    res = solve(graph)
    assert len(res.selected) == len(exact)
    assert _is_clique(graph, res.selected)


def _is_clique(graph, sel):
    edges = set(zip(graph.rows.tolist(), graph.cols.tolist()))
    s = sorted(sel.tolist())
    return all((i, j) in edges for k, i in enumerate(s) for j in s[k + 1:])


def test_exhaustive_reference_is_correct_on_a_known_graph():
    # two triangles joined by an edge plus a 4-clique {5, 6, 7, 8}
    edges = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (5, 6), (5, 7), (5, 8), (6, 7), (6, 8), (7, 8), (4, 5)]
    r, c = np.array(edges).T
    g = ConsistencyGraph(9, r, c, np.ones(len(r)), np.ones(9))
    assert max_clique_exact(g).tolist() == [5, 6, 7, 8]
    assert sorted(solve(g).selected.tolist()) == [5, 6, 7, 8]
    assert core_numbers(g).tolist() == [2, 2, 2, 2, 2, 3, 3, 3, 3]


def test_permutation_invariance():
    a, b, pairs, is_true, _, _ = planted(25, 100, seed=5)
    res = associate(a, b, pairs)
    rng = np.random.default_rng(1)
    perm = rng.permutation(len(pairs))
    res_p = associate(a, b, pairs[perm])
    chosen = {tuple(p) for p in pairs[res.selected].tolist()}
    chosen_p = {tuple(p) for p in pairs[perm][res_p.selected].tolist()}
    assert chosen == chosen_p
    assert res.score == pytest.approx(res_p.score, rel=1e-9)
    # relabelling the landmarks of either map does not matter either
    pa_perm = rng.permutation(len(a))
    inv = np.argsort(pa_perm)
    res_l = associate(a[pa_perm], b, np.column_stack([inv[pairs[:, 0]], pairs[:, 1]]))
    assert {tuple(p) for p in np.column_stack([pa_perm[inv[pairs[res_l.selected, 0]]],
                                               pairs[res_l.selected, 1]]).tolist()} == chosen


def test_shared_landmarks_are_inconsistent_and_weights_break_ties():
    a = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]], float)
    b = a.copy()
    # two candidates for landmark 3 of A (to 3 and to a duplicate 4 of B at the same spot)
    b = np.vstack([b, b[3]])
    pairs = np.array([[0, 0], [1, 1], [2, 2], [3, 3], [3, 4]])
    g = affinity_graph(a, b, pairs)
    assert (3, 4) not in set(zip(g.rows.tolist(), g.cols.tolist()))
    for heavier in (3, 4):
        w = np.ones(5)
        w[heavier] = 2.0
        sel = associate(a, b, pairs, weights=w).selected
        assert sel.tolist() == [0, 1, 2, heavier]


def test_degenerate_inputs():
    a, b, pairs, _, _, _ = planted(10, 10)
    assert len(associate(a, b, np.zeros((0, 2), int)).selected) == 0
    bad = a.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        associate(bad, b, pairs)
    with pytest.raises(InputError, match="does not exist"):
        associate(a, b, np.array([[0, 99]]))
    with pytest.raises(InputError, match="weights"):
        associate(a, b, pairs, weights=np.ones(3))
    with pytest.raises(InputError):
        associate(a[:, :2], b, pairs)
    # all landmarks at one spot: every distance is 0, nothing crashes, the answer is one consistent set
    same = np.zeros((5, 3))
    res = associate(same, same, np.array([[i, i] for i in range(5)]))
    assert len(res.selected) == 5


def test_fit_transform_and_gravity_angles():
    rng = np.random.default_rng(3)
    src = rng.uniform(-50, 50, (30, 3))
    r = rotation_from_rpy_deg(4.0, -3.0, 120.0)
    dst = src @ r.T + [5, -7, 2]
    fit = fit_transform(src, dst)
    assert np.allclose(fit.rotation, r, atol=1e-9) and np.allclose(fit.translation, [5, -7, 2], atol=1e-9)
    assert tilt_deg(fit.rotation) == pytest.approx(np.degrees(np.arccos(np.cos(np.radians(4)) * np.cos(np.radians(3)))))
    sim = fit_transform(src, 2.5 * dst, similarity=True)
    assert sim.scale == pytest.approx(2.5)
    with pytest.raises(InputError, match="colinear"):
        fit_transform(np.outer(np.arange(5.0), [1, 2, 0]), np.outer(np.arange(5.0), [1, 2, 0]))
    with pytest.raises(InputError, match="at least 3"):
        fit_transform(src[:2], dst[:2])


def straightforward_graph(a, b, pairs, eps, sigma):
    """The consistency graph by its definition, pair by pair in plain Python (the affinity's reference)."""
    rows, cols, vals = [], [], []
    for p in range(len(pairs)):
        for q in range(p + 1, len(pairs)):
            (i, u), (j, v) = pairs[p], pairs[q]
            if i == j or u == v:
                continue
            da, db = a[j] - a[i], b[v] - b[u]
            c = abs(np.sqrt(da[0] * da[0] + da[1] * da[1] + da[2] * da[2])
                    - np.sqrt(db[0] * db[0] + db[1] * db[1] + db[2] * db[2]))
            if c <= eps:
                rows.append(p)
                cols.append(q)
                vals.append(c)
    c = np.array(vals)
    return np.array(rows, np.int64), np.array(cols, np.int64), np.exp(-(c * c) / (2.0 * sigma * sigma))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_a=st.integers(1, 12), n_b=st.integers(1, 12), m=st.integers(0, 40),
       grid=st.booleans(), eps=st.sampled_from([1.0, 2.0]) | st.floats(0.1, 4.0), sigma=st.floats(0.1, 2.0))
def test_affinity_graph_equals_its_definition(seed, n_a, n_b, m, grid, eps, sigma):
    """The compiled graph (four rows of tests at a time, per-map distance tables) is the definition's, edge for
    edge and bit for bit, for any number of associations (also fewer than four, or not a multiple of four) and on
    integer grids where many mismatches fall exactly on eps."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(0, 8, (n_a, 3)), rng.uniform(0, 8, (n_b, 3))
    if grid:
        a, b = np.round(a), np.round(b)
    pairs = np.column_stack([rng.integers(0, n_a, m), rng.integers(0, n_b, m)]).astype(np.int64)
    g = affinity_graph(a, b, pairs, eps=eps, sigma=sigma)
    rows, cols, vals = straightforward_graph(a, b, pairs, eps, sigma)
    assert g.rows.tolist() == rows.tolist() and g.cols.tolist() == cols.tolist()
    assert g.values.tobytes() == vals.tobytes()


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 30), density=st.floats(0.0, 1.0),
       order=st.sampled_from(["sorted", "shuffled", "some reversed"]))
def test_symmetric_csr_and_weighted_degrees_equal_their_definition(seed, n, density, order):
    """sym_csr_weighted (a sorted edge list placed row by row, any other order appended edge by edge) lists each
    vertex's neighbours in the order its edges arrive and sums its weight in that order, like the plain loop."""
    from sosmatch.plugin.association.kernels_csr import sym_csr, sym_csr_weighted

    rng = np.random.default_rng(seed)
    r, c = np.nonzero(np.triu(rng.random((n, n)) < density, 1))
    v, d = rng.random(len(r)), rng.random(n)
    if order == "shuffled":
        o = rng.permutation(len(r))
        r, c, v = r[o], c[o], v[o]
    elif order == "some reversed":
        swap = rng.random(len(r)) < 0.3
        r, c = np.where(swap, c, r), np.where(swap, r, c)
    r, c = r.astype(np.int64), c.astype(np.int64)
    lists = [[] for _ in range(n)]
    for e in range(len(r)):
        lists[r[e]].append((c[e], v[e]))
        lists[c[e]].append((r[e], v[e]))
    weights = []
    for i in range(n):
        acc = d[i]
        for _, x in lists[i]:
            acc += x
        weights.append(acc)
    indptr, indices, data, wdeg = sym_csr_weighted(n, r, c, v, d)
    assert np.array_equal(indptr, np.cumsum([0] + [len(x) for x in lists]))
    assert indices.tolist() == [j for x in lists for j, _ in x] and data.tolist() == [w for x in lists for _, w in x]
    assert wdeg.tolist() == weights
    assert all(np.array_equal(x, y) for x, y in zip(sym_csr(n, r, c, v), (indptr, indices, data)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_a=st.integers(1, 12), n_b=st.integers(1, 12), m=st.integers(0, 60),
       grid=st.booleans(), eps=st.sampled_from([1.0, 2.0]) | st.floats(0.1, 4.0), blocks=st.integers(1, 7),
       parallel=st.booleans())
def test_problem_graph_in_blocks_equals_the_edge_list_graph(seed, n_a, n_b, m, grid, eps, blocks, parallel):
    """The one-problem kernel gives the edges of `association_graph` in its order and the symmetric CSR of
    `sym_csr` (entries, order, and each entry's edge) for any cut of the rows into blocks, on one thread or
    several: the cut never shows in the output. Solving from that CSR selects what solving the edge list does."""
    from sosmatch.plugin.association.kernels_csr import csr_data, sym_csr
    from sosmatch.plugin.association.kernels_graph import DISTANCE, association_graph
    from sosmatch.plugin.association.kernels_problem import problem_graph_parallel, problem_graph_serial

    rng = np.random.default_rng(seed)
    a, b = rng.uniform(0, 8, (n_a, 3)), rng.uniform(0, 8, (n_b, 3))
    if grid:
        a, b = np.round(a), np.round(b)
    pairs = np.column_stack([rng.integers(0, n_a, m), rng.integers(0, n_b, m)]).astype(np.int64)
    kernel = problem_graph_parallel if parallel else problem_graph_serial
    problem, rows, cols, x, indptr, indices, edge0 = kernel(a, b, pairs, eps, 0.5, blocks)
    r0, c0, cs, _, _ = association_graph(a, b, pairs[:, 0].copy(), pairs[:, 1].copy(), DISTANCE, eps, 1.0, 0.0, 0.0,
                                         0.0, 1)
    assert problem == 0 and rows.tolist() == r0.tolist() and cols.tolist() == c0.tolist()
    assert x.tobytes() == (-(cs * cs) / 0.5).tobytes()
    ip, ix, data = sym_csr(m, r0, c0, cs)
    assert indptr.tolist() == ip.tolist() and indices.tolist() == ix.tolist()
    assert edge0.tolist() == np.searchsorted(r0, np.arange(m + 1)).tolist()  # the edge list's row pointers
    assert csr_data(indptr, indices, edge0, cs).tobytes() == data.tobytes()
    g = affinity_graph(a, b, pairs, eps=eps, sigma=0.5)
    assert g.csr is not None
    plain = ConsistencyGraph(g.n, g.rows, g.cols, g.values, g.diag)  # no CSR: the solver builds it
    for method in ("bounded", "clipper"):
        x1, x2 = solve(g, method=method), solve(plain, method=method)
        assert x1.selected.tolist() == x2.selected.tolist() and x1.score == x2.score
        assert x1.u.tobytes() == x2.u.tobytes()


def test_problem_graph_beyond_the_tables_and_threads():
    """More distinct landmarks than the distance tables hold: the vectors are formed on the fly and the solver
    builds the CSR itself; the parallel path (forced on here) and the serial one give the same graph."""
    from sosmatch.plugin.association import kernels_problem
    from sosmatch.plugin.association.kernels_graph import TABLE_MAX

    rng = np.random.default_rng(3)
    n = TABLE_MAX + 1
    a = rng.uniform(0, 100, (n, 3))
    b = a + rng.normal(0, 0.05, a.shape)
    pairs = np.column_stack([np.arange(n), rng.permutation(n)]).astype(np.int64)
    pairs[:50, 1] = pairs[:50, 0]  # 50 true associations among 2049 wrong ones
    g = affinity_graph(a, b, pairs, eps=0.5, sigma=0.5)
    assert g.csr is None
    rows, cols, _ = straightforward_graph(a, b, pairs[:60], 0.5, 0.5)
    assert [(r, c) for r, c in zip(g.rows, g.cols) if c < 60] == list(zip(rows, cols))
    assert solve(g).selected.tolist() == np.flatnonzero(pairs[:, 0] == pairs[:, 1]).tolist()  # (a few by chance)
    small = np.column_stack([np.arange(300), np.arange(300)]).astype(np.int64)
    serial = affinity_graph(a, b, small, eps=0.5, sigma=0.5)
    free, kernels_problem.core_free = kernels_problem.core_free, lambda threads: True
    try:
        threaded = affinity_graph(a, b, small, eps=0.5, sigma=0.5)
    finally:
        kernels_problem.core_free = free
    for x, y in zip((serial.rows, serial.cols, serial.values, *serial.csr), (threaded.rows, threaded.cols,
                                                                              threaded.values, *threaded.csr)):
        assert x.tobytes() == y.tobytes()
