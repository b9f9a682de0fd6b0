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

`max_clique_exact` (Bron-Kerbosch with pivoting) is the exhaustive reference for small problems and tests.

Default sigma = 1.0 m: with landmark position noise of 0.3-0.5 m per axis in each map, the mismatch of a true
distance pair involves four noisy points, std ~ 2 x 0.5 m / sqrt(2) x sqrt(2) ~ 1 m; exp(-c^2/2) keeps true pairs
near 1 while the affinity at the gate eps = 2 m is exp(-2) = 0.14, so borderline pairs count little.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import InputError

DENSE_MAX = 160  # up to this many associations dense products beat scipy.sparse whatever the density (measured)
DENSE_FILL = 0.25  # above this edge density dense products win at any size


@dataclass(frozen=True)
class ConsistencyGraph:
    """The CLIPPER affinity as an edge list: edges (rows[k] < cols[k]) with affinity values, and the diagonal."""

    n: int  # number of putative associations (vertices)
    rows: np.ndarray  # int64 (E,)
    cols: np.ndarray  # int64 (E,)
    values: np.ndarray  # float64 (E,), in (0, 1]
    diag: np.ndarray  # float64 (n,), weights on the diagonal (1 when unweighted)

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


def _validate(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray,
              weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    pa = np.asarray(points_a, dtype=np.float64)
    pb = np.asarray(points_b, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    for name, pts in (("points_a", pa), ("points_b", pb)):
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"{name} must be an (N, 3) array, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise InputError(f"{name} holds NaN or infinite coordinates")
    if len(pairs) and (pairs.min() < 0 or pairs[:, 0].max() >= len(pa) or pairs[:, 1].max() >= len(pb)):
        raise InputError("association pairs index a landmark that does not exist")
    if weights is None:
        w = np.ones(len(pairs))
    else:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(w) != len(pairs) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError("weights must be one finite, non-negative value per association pair")
    return pa, pb, pairs, w


def affinity_graph(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray,
                   weights: np.ndarray | None = None, eps: float = 2.0, sigma: float = 1.0) -> ConsistencyGraph:
    """CLIPPER consistency graph of putative associations `pairs` (m, 2) between `points_a` and `points_b`.

    Vectorised over all m^2 / 2 pairs in row blocks (bounded memory); distances are gathered from the per-map
    distance matrices of the landmarks that occur, which the associations share.
    """
    pa, pb, pairs, w = _validate(points_a, points_b, pairs, weights)
    if eps <= 0 or sigma <= 0:
        raise InputError(f"eps and sigma must be positive, got eps={eps}, sigma={sigma}")
    m = len(pairs)
    ua, ia = np.unique(pairs[:, 0], return_inverse=True)
    ub, ib = np.unique(pairs[:, 1], return_inverse=True)
    da = _pdist(pa[ua])  # float64: the windowed search must reproduce these values bit for bit
    db = _pdist(pb[ub])
    # a shared landmark gives an infinite distance on that side, so c is inf or NaN and fails the test below:
    # no separate masks for "shares a landmark"
    np.fill_diagonal(da, np.inf)
    np.fill_diagonal(db, np.inf)
    rows_l, cols_l, c_l = [], [], []
    # row blocks over the upper triangle: bounded memory, and about half of the m^2 work
    block = int(min(max(1, 2_000_000 // max(m, 1)), max(128, m // 8)))
    for s in range(0, m, block):
        r = np.arange(s, min(s + block, m))
        ja, jb = ia[s:], ib[s:]  # columns from s on: the upper triangle and a little of the block's diagonal
        with np.errstate(invalid="ignore"):
            c = np.abs(da[ia[r]][:, ja] - db[ib[r]][:, jb])
            ok = c <= eps
        ok[:, : len(r)] &= np.arange(len(r))[:, None] < np.arange(len(r))[None, :]
        rr, cc = np.nonzero(ok)
        rows_l.append(rr + s)
        cols_l.append(cc + s)
        c_l.append(c[rr, cc])
    if not rows_l:
        return ConsistencyGraph(0, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), w)
    cv = np.concatenate(c_l)
    values = np.exp(-(cv * cv) / (2.0 * sigma * sigma))
    return ConsistencyGraph(m, np.concatenate(rows_l).astype(np.int64), np.concatenate(cols_l).astype(np.int64),
                            values, w)


def _pdist(p: np.ndarray) -> np.ndarray:
    d = p[:, None, :] - p[None, :, :]
    return np.sqrt(np.einsum("ijk,ijk->ij", d, d))


class _Operator:
    """y = (M + d C) u, dense or CSR; M and C share one sparsity pattern so one product serves both."""

    def __init__(self, g: ConsistencyGraph) -> None:
        n = g.n
        self.dense = n <= DENSE_MAX or 2 * len(g.rows) > DENSE_FILL * n * n
        if self.dense:
            self.m = np.zeros((n, n))
            self.m[g.rows, g.cols] = g.values
            self.m[g.cols, g.rows] = g.values
            self.m[np.arange(n), np.arange(n)] = g.diag
            self.c = np.zeros((n, n))
            self.c[g.rows, g.cols] = 1.0
            self.c[g.cols, g.rows] = 1.0
            self.c[np.arange(n), np.arange(n)] = 1.0
            self.a = self.m
        else:
            # symmetric CSR assembled directly (one sort of row * n + col); M and C share the pattern
            idx = np.arange(n)
            r = np.concatenate([g.rows, g.cols, idx])
            c = np.concatenate([g.cols, g.rows, idx])
            v = np.concatenate([g.values, g.values, g.diag])
            order = np.argsort(r * n + c, kind="stable")
            indices = c[order].astype(np.int32)
            indptr = np.zeros(n + 1, dtype=np.int32)
            np.cumsum(np.bincount(r, minlength=n), out=indptr[1:])
            self.mdata = v[order]
            self.msp = sp.csr_matrix((self.mdata, indices, indptr), shape=(n, n))
            self.a = sp.csr_matrix((self.mdata.copy(), indices, indptr), shape=(n, n))
            self.c = sp.csr_matrix((np.ones(len(v)), indices, indptr), shape=(n, n))

    def set_penalty(self, d: float) -> None:
        if self.dense:
            self.a = self.m + d * self.c
        else:
            self.a.data = self.mdata + d

    def matvec(self, u: np.ndarray) -> np.ndarray:
        return self.a @ u

    def m_matvec(self, u: np.ndarray) -> np.ndarray:
        if self.dense:
            return self.m @ u
        return self.msp @ u

    def c_matvec(self, u: np.ndarray) -> np.ndarray:
        return self.c @ u

    def c_row(self, i: int, n: int) -> np.ndarray:
        if self.dense:
            return self.c[i] > 0
        row = np.zeros(n, dtype=bool)
        row[self.c.indices[self.c.indptr[i]: self.c.indptr[i + 1]]] = True
        return row


def solve(graph: ConsistencyGraph, tol_u: float = 1e-6, max_outer: int = 60, max_inner: int = 100,
          beta: float = 0.25) -> ClipperResult:
    """Densest consistent subset of the associations of `graph` (CLIPPER relaxation + rounding).

    Deterministic: u starts at the weighted degree vector M 1 (normalised), which favours well-connected
    associations exactly as the first power iteration of the unpenalised problem would. `max_inner` caps the
    gradient steps per penalty value: the penalty keeps growing, so full convergence at an intermediate d is not
    needed (100 instead of 300 steps saved a third of the time on dense window pairs; |S| changed by 1-2 on 25 of
    3835 window pairs of the demo maps, all borderline spurious sets).
    """
    n = graph.n
    if n == 0:
        return ClipperResult(np.zeros(0, np.int64), 0.0, np.zeros(0), 0.0, 0)
    if 2 * len(graph.rows) == n * (n - 1):
        # complete consistency graph (common for a window pair's core): the positive M has a positive Perron
        # vector, so the support is everything, consistent at d = 0, and rounding keeps all of it
        selected = np.arange(n, dtype=np.int64)
        return ClipperResult(selected, _score(graph, selected), np.full(n, 1.0 / np.sqrt(n)), 0.0, 0)
    op = _Operator(graph)
    u = op.m_matvec(np.ones(n)) + 1e-12
    u /= np.sqrt(u @ u)
    d = 0.0
    op.set_penalty(d)
    steps = 0
    support_tol = 1e-8
    for _outer in range(max_outer):
        y = op.matvec(u) - d * u.sum()  # M_d u
        f = float(u @ y)
        alpha = 1.0
        for _inner in range(max_inner):
            while True:  # backtracking: shrink the step until F does not decrease
                v = np.maximum(u + alpha * y, 0.0)
                nv = np.sqrt(v @ v)
                if nv == 0.0:
                    alpha *= beta
                    continue
                v /= nv
                yv = op.matvec(v) - d * v.sum()
                fv = float(v @ yv)
                if fv >= f - 1e-12 * max(1.0, abs(f)) or alpha < 1e-12:
                    break
                alpha *= beta
            steps += 1
            du = float(np.sqrt((v - u) @ (v - u)))
            df = fv - f
            u, y, f = v, yv, fv
            if du < tol_u or abs(df) < 1e-12 * max(1.0, abs(f)):
                break
            alpha = min(alpha * 2.0, 1e3)  # grow again after a successful step: fewer products overall
        # raise d while the support still contains an inconsistent pair
        sup = u > support_tol * u.max()
        cbu = u[sup].sum() - op.c_matvec(np.where(sup, u, 0.0))  # sum of u over inconsistent partners
        viol = sup & (cbu > support_tol * u.max())
        if not viol.any():
            break
        mu = op.m_matvec(u)
        d += float(np.mean(np.abs(mu[viol] / cbu[viol])))
        op.set_penalty(d)
    selected = _round(op, u, graph)
    return ClipperResult(selected, _score(graph, selected), u, d, steps)


def _round(op: _Operator, u: np.ndarray, graph: ConsistencyGraph) -> np.ndarray:
    """Greedy maximal clique, visiting associations by decreasing u, then degree, then index."""
    n = graph.n
    order = np.lexsort((np.arange(n), -graph.degrees, -np.round(u, 12)))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    compat = np.ones(n, dtype=bool)
    chosen = []
    # usual case: the converged support is already a clique; take it in one step (the greedy walk below would
    # take exactly these first, as they lead the order and are pairwise consistent)
    insup = u > 1e-6 * u.max()
    ns = int(insup.sum())
    if ns and 2 * int(np.count_nonzero(insup[graph.rows] & insup[graph.cols])) == ns * (ns - 1):
        chosen = np.flatnonzero(insup).tolist()
        compat = (op.c_matvec(insup.astype(np.float64)) > ns - 0.5) & ~insup  # consistent with all of them
    while True:
        cand = np.flatnonzero(compat)
        if len(cand) == 0:
            break
        i = int(cand[np.argmin(rank[cand])])
        chosen.append(i)
        compat &= op.c_row(i, n)
        compat[i] = False
    return np.sort(np.array(chosen, dtype=np.int64))


def _score(graph: ConsistencyGraph, selected: np.ndarray) -> float:
    if len(selected) == 0:
        return 0.0
    inside = np.zeros(graph.n, dtype=bool)
    inside[selected] = True
    e = inside[graph.rows] & inside[graph.cols]
    # sorted before summing: the same value whatever order the edges were listed in (fast vs reference search)
    return float((2.0 * np.sort(graph.values[e]).sum() + graph.diag[selected].sum()) / len(selected))


def associate(points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray, weights: np.ndarray | None = None,
              eps: float = 2.0, sigma: float = 1.0) -> ClipperResult:
    """Affinity + solve in one call: returns the selected association indices (into `pairs`) and the score."""
    return solve(affinity_graph(points_a, points_b, pairs, weights, eps, sigma))


def core_numbers(graph: ConsistencyGraph) -> np.ndarray:
    """Core number of every vertex (Batagelj-Zaversnik peeling); a clique of size k lies in the (k-1)-core."""
    n = graph.n
    adj = [[] for _ in range(n)]
    for r, c in zip(graph.rows.tolist(), graph.cols.tolist()):
        adj[r].append(c)
        adj[c].append(r)
    deg = [len(a) for a in adj]
    core = np.zeros(n, dtype=np.int64)
    removed = [False] * n
    buckets: dict[int, set[int]] = {}
    for v, k in enumerate(deg):
        buckets.setdefault(k, set()).add(v)
    k = 0
    for _ in range(n):
        while not buckets.get(k):
            k += 1
        v = min(buckets[k])
        buckets[k].discard(v)
        removed[v] = True
        core[v] = k
        for w in adj[v]:
            if not removed[w] and deg[w] > k:
                buckets[deg[w]].discard(w)
                deg[w] -= 1
                buckets.setdefault(deg[w], set()).add(w)
        k = max(0, k - 1)
    return core


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
