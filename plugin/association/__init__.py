"""Geometric association of two landmark maps (SOS-Match section 2): CLIPPER and the windowed search."""

from .clipper import ClipperResult, ConsistencyGraph, affinity_graph, associate, max_clique_exact, solve
from .rigid import Transform, fit_transform, roll_pitch_yaw_deg, rotation_from_rpy_deg, tilt_deg
from .windowed_search import (
    Consensus,
    SearchResult,
    WindowHypothesis,
    make_windows,
    putative_pairs,
    search,
    search_reference,
    size_ratio,
    size_score,
)

__all__ = [
    "ClipperResult", "Consensus", "ConsistencyGraph", "SearchResult", "Transform", "WindowHypothesis",
    "affinity_graph", "associate", "fit_transform", "make_windows", "max_clique_exact", "putative_pairs",
    "roll_pitch_yaw_deg", "rotation_from_rpy_deg", "search", "search_reference", "size_ratio", "size_score",
    "solve", "tilt_deg",
]
