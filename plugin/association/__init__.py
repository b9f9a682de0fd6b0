"""Geometric association of two landmark maps (SOS-Match section 2): CLIPPER and the windowed search."""

# First: numba's cache of the compiled kernels is checked against their sources before any kernel loads.
from . import kernel_cache  # noqa: F401, I001
from .clipper import ClipperResult, ConsistencyGraph, affinity_graph, associate, max_clique_exact, solve
from .gates import putative_pairs, size_ratio, size_score
from .hypotheses import Consensus, SearchResult, WindowHypothesis
from .reference import search_reference
from .rigid import Transform, fit_transform, roll_pitch_yaw_deg, rotation_from_rpy_deg, tilt_deg
from .windowed_search import search
from .windows import make_windows

__all__ = [
    "ClipperResult", "Consensus", "ConsistencyGraph", "SearchResult", "Transform", "WindowHypothesis",
    "affinity_graph", "associate", "fit_transform", "make_windows", "max_clique_exact", "putative_pairs",
    "roll_pitch_yaw_deg", "rotation_from_rpy_deg", "search", "search_reference", "size_ratio", "size_score",
    "solve", "tilt_deg",
]
