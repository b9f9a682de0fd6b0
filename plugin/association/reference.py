"""The straightforward reference of the windowed search: every window pair computed from scratch.

For every window pair: its putative associations (size gate, position prior), the consistency graph of all of
them (`kernels_graph.association_graph`: every pair of associations tested), and the hypothesis of that graph
(`kernels_search.solve_window_pair`: theta_S-core, per yaw slice with the gravity test, solver). The fast search
(`windowed_search.search`) must give exactly these hypotheses.
"""

from __future__ import annotations

import numpy as np

from ..params import AssociationParams
from .hypotheses import (
    SearchMode,
    SearchResult,
    WindowHypothesis,
    check_inputs,
    check_params,
    in_window_order,
    make_hypotheses,
)
from .kernel_cache import search_clock
from .kernels_graph import association_graph, putatives
from .kernels_search import solve_window_pair
from .windows import map_windows


def search_reference(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                     sizes_b: np.ndarray | None, params: AssociationParams) -> SearchResult:
    """Every window pair computed from scratch (slow; the definition `search` must reproduce)."""
    check_params(params)
    pa, ha = check_inputs(points_a, sizes_a, "A")
    pb, hb = check_inputs(points_b, sizes_b, "B")
    return in_window_order(pa, ha, pb, hb, params, _reference)


def _reference(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray,
               params: AssociationParams) -> tuple[list[WindowHypothesis], np.ndarray, np.ndarray, dict]:
    t0 = search_clock()
    m = SearchMode.of(params)
    wins_a, wins_b = map_windows(len(pa), len(pb), params)
    ids, nput, ncore, score, slc, sel = [], [], [], [], [], []
    for a, wa in enumerate(wins_a):
        for b, wb in enumerate(wins_b):
            ia, ib, w = putatives(wa[0], wa[1], wb[0], wb[1], pa, ha, pb, hb, m.theta_r, m.prior_m)
            rows, cols, cs, s0, ns = association_graph(pa, pb, ia, ib, m.consistency, m.eps, m.sigma,
                                                            m.tan_tilt, m.eps_z, m.sin_tilt, m.nslices)
            ok, chosen, sc, s, nc = solve_window_pair(len(ia), rows, cols, cs, s0, ns, w, m.nslices, m.k,
                                                      m.method, m.sigma)
            if ok:
                ids.append(a * len(wins_b) + b)
                nput.append(len(ia))
                ncore.append(nc)
                score.append(sc)
                slc.append(s)
                sel.append(np.column_stack([ia[chosen], ib[chosen]]))
    off = np.concatenate([[0], np.cumsum([len(x) for x in sel])]).astype(np.int64)
    flat = np.concatenate(sel) if sel else np.zeros((0, 2), np.int64)
    hyps = make_hypotheses(pa, pb, params, wins_a, wins_b, np.array(ids, np.int64), np.array(nput), np.array(ncore),
                           np.array(score), np.array(slc), off, flat[:, 0].copy(), flat[:, 1].copy())
    return hyps, wins_a, wins_b, {"total_s": search_clock() - t0}


def differences(fast: SearchResult, ref: SearchResult) -> list[str]:
    """What differs between two search results (empty: the same hypotheses, bit for bit, and the same answer).

    Compares the solved window pairs, each hypothesis' associations, counts, score (exactly), slice,
    acceptance and transform (to 1e-9), the accepted list and the best hypothesis.
    """
    out = []
    kf = {(h.window_a, h.window_b): h for h in fast.hypotheses}
    kr = {(h.window_a, h.window_b): h for h in ref.hypotheses}
    if set(kf) != set(kr):
        out.append(f"solved window pairs differ: {sorted(set(kf) ^ set(kr))[:5]}")
    for key in sorted(set(kf) & set(kr)):
        g, h = kf[key], kr[key]
        for name in ("num_putative", "num_core", "score", "accepted", "yaw_slice"):
            if getattr(g, name) != getattr(h, name):
                out.append(f"{key}: {name} {getattr(g, name)} != {getattr(h, name)}")
        if not np.array_equal(g.associations, h.associations):
            out.append(f"{key}: associations differ")
        if (g.transform is None) != (h.transform is None) or (
                h.transform is not None and not np.allclose(g.transform.to_matrix(), h.transform.to_matrix(),
                                                            atol=1e-9)):
            out.append(f"{key}: transforms differ")
    if [fast.hypotheses[i].window_a for i in fast.accepted] != [ref.hypotheses[i].window_a for i in ref.accepted]:
        out.append("accepted hypotheses differ")
    bf = None if fast.best is None else (fast.hypotheses[fast.best].window_a, fast.hypotheses[fast.best].window_b)
    br = None if ref.best is None else (ref.hypotheses[ref.best].window_a, ref.hypotheses[ref.best].window_b)
    if bf != br:
        out.append(f"best differs: {bf} != {br}")
    return out
