"""The baselines' rows of the evaluation: ORB+RANSAC and SIFT+RANSAC (tools/baselines) on the keyframe images,
each keyframe pair scored by its inliers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .ground_truth import GroundTruthSession


def _load_images(gt: GroundTruthSession, image_dir: Path) -> list[np.ndarray]:
    from ...database.flight_levels import flight_white_level
    from ...database.images import read_gray

    paths = [image_dir / name for name in gt.names]
    white = flight_white_level(paths)
    return [read_gray(path, white) for path in paths]


def _run_baseline(name: str, gt_a: GroundTruthSession, gt_b: GroundTruthSession, images_a: list[np.ndarray],
                  images_b: list[np.ndarray], config: Any) -> dict:
    from ...tools.baselines import get_backend

    backend = get_backend(name)
    fa, fb = backend.extract(images_a, config), backend.extract(images_b, config)
    counts, seconds = backend.match_all(fa, fb, config)
    scores = counts.astype(np.float64)
    scores[counts <= 0] = np.nan  # no (or too few) matches: no claim at any threshold
    return {"search_seconds": seconds, "search_seconds_runs": [seconds], "extract_seconds": fa.seconds + fb.seconds,
            "map_bytes": [fa.nbytes, fb.nbytes], "scores": scores}
