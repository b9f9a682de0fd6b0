"""CLIPPER (Lusk, Fathian, How; ICRA 2021): the densest pairwise-consistent set of putative associations.

Written from the paper; the authors' C++ is not used. Three steps:

1. `affinity_graph`: association p = (a_p, b_p) pairs landmark a_p of map A with b_p of map B. Two associations
   p, q are consistent when the distance mismatch c = | ||A[a_p] - A[a_q]|| - ||B[b_p] - B[b_q]|| | <= eps and they
   share no landmark on either side; their affinity is exp(-c^2 / 2 sigma^2). The diagonal holds optional
   per-association weights (SOS-Match: the size score q_s). Only the consistent pairs are kept (upper triangle),
   because outliers make the graph sparse.
2. `solve`: the relaxation max u^T M_d u over u >= 0, ||u|| = 1 with M_d = M - d (1 1^T - C), C the binary
   consistency (diagonal included). Projected gradient ascent with a backtracking line search for a fixed d; then
   d grows until the support of u holds no inconsistent pair.
3. Rounding: walk the associations by decreasing u (then by degree) and keep each one that is consistent with all
   kept so far. The result is always a clique of the consistency graph, and maximal (nothing can be added).
`solve`'s default method first bounds the answer by the graph's cores (see `solve`) and runs the relaxation only
where a larger set may hide. The loops are compiled (numba): `kernels_graph.py`, `kernels_csr.py`,
`kernels_cliques.py`, `kernels_solve.py`.

`max_clique_exact` (Bron-Kerbosch with pivoting) is the exhaustive reference for small problems and tests.

Default sigma = 1.0 m: with landmark position noise of 0.3-0.5 m per axis in each map, the mismatch of a true
distance pair involves four noisy points, std ~ 2 x 0.5 m / sqrt(2) x sqrt(2) ~ 1 m; exp(-c^2/2) keeps true pairs
near 1 while the affinity at the gate eps = 2 m is exp(-2) = 0.14, so borderline pairs count little.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .kernels_cliques import core_numbers as _core_numbers
from .kernels_csr import sym_csr
from .kernels_graph import PROBLEM_PAIRS, PROBLEM_POINTS_A, PROBLEM_POINTS_B
from .kernels_problem import problem_graph
from .kernels_solve import BOUNDED, CLIPPER, solve_graph, solve_graph_csr


@dataclass(frozen=True)
class ConsistencyGraph:
    """The CLIPPER affinity as an edge list: edges (rows[k] < cols[k]) with affinity values, and the diagonal."""

    n: int  # number of putative associations (vertices)
    rows: np.ndarray  # int64 (E,)
    cols: np.ndarray  # int64 (E,)
    values: np.ndarray  # float64 (E,), in (0, 1]
    diag: np.ndarray  # float64 (n,), weights on the diagonal (1 when unweighted)
    # the symmetric CSR structure (indptr, indices) and the edge list's row pointers when `affinity_graph` built it
    # with the edges; `solve` then does not scatter the edge list again
    csr: tuple | None = field(default=None, compare=False, repr=False)

    @property
    def degrees(self) -> np.ndarray:
        return np.bincount(self.rows, minlength=self.n) + np.bincount(self.cols, minlength=self.n)

    def subgraph(self, keep: np.ndarray) -> tuple[ConsistencyGraph, np.ndarray]:
        """Induced subgraph on the vertices where boolean `keep` is True; returns it and the kept old indices."""
        keep = np.asarray(keep, dtype=bool)
        old = np.flatnonzero(keep)
        new_id = np.full(self.n, -1, dtype=np.int64)
        new_id[old] = np.arange(len(old))
        e = keep[self.rows] & keep[self.cols]
        return ConsistencyGraph(len(old), new_id[self.rows[e]], new_id[self.cols[e]], self.values[e],
                                self.diag[old]), old


@dataclass(frozen=True)
class ClipperResult:
    selected: np.ndarray  # indices of the chosen associations (sorted), a clique of the consistency graph
    score: float  # 1_S^T M 1_S / |S|: equals |S| when every affinity and weight is 1
    u: np.ndarray  # the relaxed solution
    penalty: float  # final d
    iterations: int  # gradient steps taken


def _validate(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray) -> tuple:
    """The inputs as arrays of the right shapes (the value checks are the compiled `check_problem`'s)."""
    pa = np.asarray(points_a, dtype=np.float64)
    pb = np.asarray(points_b, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    for name, pts in (("points_a", pa), ("points_b", pb)):
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"{name} must be an (N, 3) array, got shape {pts.shape}")
    return pa, pb, pairs


_PROBLEMS = {PROBLEM_POINTS_A: "points_a holds NaN or infinite coordinates",
             PROBLEM_POINTS_B: "points_b holds NaN or infinite coordinates",
             PROBLEM_PAIRS: "association pairs index a landmark that does not exist"}


def affinity_graph(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray,
                   weights: np.ndarray | None = None, eps: float = 2.0, sigma: float = 1.0) -> ConsistencyGraph:
    """CLIPPER consistency graph of putative associations `pairs` (m, 2) between `points_a` and `points_b`.

    One compiled call (`kernels_problem.problem_graph`) checks the values, tests all m (m - 1) / 2 pairs (the
    pair distances come from per-map tables of the landmarks that occur, which the associations share; the rows
    in blocks, one per thread) and builds the graph's symmetric CSR for `solve`.
    """
    pa, pb, pairs = _validate(points_a, points_b, pairs)
    scale_ok = not (eps <= 0 or sigma <= 0)
    problem, rows, cols, x, indptr, indices, edge0 = problem_graph(
        pa, pb, pairs, float(eps), 2.0 * sigma * sigma if scale_ok else 1.0)
    if problem:
        raise InputError(_PROBLEMS[problem])
    if weights is None:
        w = np.ones(len(pairs))
    else:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(w) != len(pairs) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError("weights must be one finite, non-negative value per association pair")
    if not scale_ok:
        raise InputError(f"eps and sigma must be positive, got eps={eps}, sigma={sigma}")
    # exp(-(c * c) / (2 sigma^2)): the kernel formed the argument operation by operation as numpy did; numpy's exp
    # as before (the same bits)
    csr = (indptr, indices, edge0) if len(indptr) else None
    return ConsistencyGraph(len(pairs), rows, cols, np.exp(x, out=x), w, csr)


SOLVERS = {"clipper": CLIPPER, "bounded": BOUNDED}


def solve(graph: ConsistencyGraph, tol_u: float = 1e-6, max_outer: int = 60, max_inner: int = 100,
          beta: float = 0.25, method: str = "bounded", penalty_start: str = "violations") -> ClipperResult:
    """Densest consistent subset of the associations of `graph`: always a clique of the consistency graph.

    method "clipper": CLIPPER's relaxation (projected gradient ascent on u^T M_d u with backtracking, the
    penalty d raised until the support of u holds no inconsistent pair) and greedy rounding (associations by
    decreasing u, then degree, then index, each kept when consistent with all kept so far: a maximal clique).
    u starts at the weighted degree vector M 1, normalised (deterministic). `max_inner` caps the gradient steps
    per penalty value (the penalty keeps growing, so full convergence at an intermediate d is not needed).
    penalty_start "violations" starts d where CLIPPER (Lusk et al.) does, at the mean ratio (M u)_i / (sum of u
    over i's inconsistent partners) of the violating associations, so the penalty acts from the first step
    (fewer gradient steps); "zero" starts at d = 0.
    method "bounded" (default): a clique bound first. A clique of more than s associations lies in the
    s-core of the graph; a greedy clique grown from the highest cores gives s, and when no association has core
    number >= s the greedy clique is a maximum clique and is returned; otherwise CLIPPER runs on the s-core
    only and the larger set wins. Same kind of answer, far less work when one consistent set stands out. When the
    highest core is itself a clique (c + 1 associations of core number c, as the true ones of a CLIPPER problem
    are), it is that greedy clique and a maximum one, and the greedy walk is not run.
    """
    if method not in SOLVERS:
        raise InputError(f"unknown solver {method!r} (known: {', '.join(SOLVERS)})")
    if penalty_start not in ("violations", "zero"):
        raise InputError(f"penalty_start must be 'violations' or 'zero', got {penalty_start!r}")
    if graph.csr is not None:
        indptr, indices, edge0 = graph.csr
        sel, score, u, d, steps = solve_graph_csr(indptr, indices, edge0, graph.values, graph.diag, SOLVERS[method],
                                                  tol_u, max_outer, max_inner, beta, penalty_start == "violations")
    else:
        sel, score, u, d, steps = solve_graph(graph.n, graph.rows, graph.cols, graph.values, graph.diag,
                                              SOLVERS[method], tol_u, max_outer, max_inner, beta,
                                              penalty_start == "violations")
    return ClipperResult(sel, float(score), u, float(d), int(steps))


def associate(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray, weights: np.ndarray | None = None,
              eps: float = 2.0, sigma: float = 1.0) -> ClipperResult:
    """Affinity + solve in one call: returns the selected association indices (into `pairs`) and the score."""
    return solve(affinity_graph(points_a, points_b, pairs, weights, eps, sigma))


def core_numbers(graph: ConsistencyGraph) -> np.ndarray:
    """Core number of every vertex (Batagelj-Zaversnik); a clique of size k lies in the (k-1)-core."""
    indptr, indices, _ = sym_csr(graph.n, graph.rows, graph.cols, graph.values)
    return _core_numbers(graph.n, indptr, indices)


def max_clique_exact(graph: ConsistencyGraph) -> np.ndarray:
    """A maximum clique by Bron-Kerbosch with pivoting (exponential: reference for small graphs only)."""
    n = graph.n
    nbr = [0] * n
    for r, c in zip(graph.rows.tolist(), graph.cols.tolist()):
        nbr[r] |= 1 << c
        nbr[c] |= 1 << r
    best = 0
    best_size = 0

    def bits(x: int) -> list[int]:
        out = []
        while x:
            low = x & -x
            out.append(low.bit_length() - 1)
            x ^= low
        return out

    def expand(r: int, size: int, p: int, x: int) -> None:
        nonlocal best, best_size
        if p == 0:
            if x == 0 and size > best_size:
                best, best_size = r, size
            return
        if size + bin(p).count("1") <= best_size:
            return
        pivot = max(bits(p | x), key=lambda v: bin(p & nbr[v]).count("1"))
        for v in bits(p & ~nbr[pivot]):
            expand(r | (1 << v), size + 1, p & nbr[v], x & nbr[v])
            p &= ~(1 << v)
            x |= 1 << v

    expand(0, 0, (1 << n) - 1 if n else 0, 0)
    return np.array(bits(best), dtype=np.int64)
