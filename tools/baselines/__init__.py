"""Feature-matching baselines of the paper (ORB+RANSAC, SIFT+RANSAC): a small registry like hloc's.

Every backend module defines `NAME`, `extract(images, config) -> Features` and uses the shared
`match_all(features_a, features_b, config) -> (inlier-count matrix, seconds)` from `base`.
"""

from __future__ import annotations

import importlib
from types import ModuleType

BACKENDS = {"orb_ransac": "orb_ransac", "sift_ransac": "sift_ransac"}


def get_backend(name: str) -> ModuleType:
    """The backend module registered as `name` (see BACKENDS)."""
    if name not in BACKENDS:
        raise KeyError(f"unknown baseline {name!r}; known: {', '.join(BACKENDS)}")
    return importlib.import_module(f"{__name__}.{BACKENDS[name]}")
