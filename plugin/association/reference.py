"""The straightforward reference of the windowed search: every window pair computed from scratch."""

from __future__ import annotations

import time

import numpy as np

from ..params import AssociationParams
from .clipper import affinity_graph
from .gates import putative_pairs
from .hypotheses import SearchResult, check_inputs, check_params, core_mask, finish_search, make_hypothesis
from .windows import make_windows


def search_reference(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                     sizes_b: np.ndarray | None, params: AssociationParams) -> SearchResult:
    """Every window pair computed from scratch (slow; the definition `search` must reproduce)."""
    check_params(params)
    pa, ha = check_inputs(points_a, sizes_a, "A")
    pb, hb = check_inputs(points_b, sizes_b, "B")
    t0 = time.perf_counter()
    wins_a = make_windows(len(pa), params.window_length, params.window_stride)
    wins_b = make_windows(len(pb), params.window_length, params.window_stride)
    hyps = []
    for wa in wins_a:
        for wb in wins_b:
            pairs, w = putative_pairs(ha, hb, np.arange(*wa), np.arange(*wb), params.max_size_difference)
            graph = affinity_graph(pa, pb, pairs, w, params.distance_tolerance_m, params.affinity_sigma_m)
            core = core_mask(graph, params.min_associations)
            if core.sum() > params.min_associations:
                sub, old = graph.subgraph(core)
                hyps.append(make_hypothesis(pa, pb, params, wa, wb, len(pairs), pairs[old], sub))
    return finish_search(pa, pb, params, hyps, wins_a, wins_b, {"total_s": time.perf_counter() - t0})
