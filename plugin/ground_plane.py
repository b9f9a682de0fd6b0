"""The ground's plane through a map's landmarks, and the tilt the ground and the cameras share (pure numpy).

A whole block rotated off gravity tilts the ground and the cameras together; a real slope tilts only the ground,
an oblique camera only the cameras (`plugin.map_quality`'s tilt figures, `plugin.pass_heights`' heights above
the plane).
"""

from __future__ import annotations

import numpy as np

UP = np.array([0.0, 0.0, 1.0])


def robust_plane_normal(points: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Upward unit normal of a plane through (N, 3) points, by iteratively reweighted total least squares
    (Cauchy weights at 2 robust sigmas of the distances): trees, roofs and wrong landmarks do not tilt it. The
    first weights are those of the horizontal plane through the median height: from uniform weights, a few
    landmarks hundreds of metres below a narrow strip of the others made a vertical plane the best fit, and the
    iteration stayed there (Seneca mapped with the default parameters: a 89 deg "ground tilt" over flat fields;
    1.4 deg from this start). A sloped site still pulls the fit onto its slope."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normal = UP.copy()
    w = _cauchy_weights(p[:, 2] - np.median(p[:, 2])) if len(p) else np.ones(0)
    for _ in range(iterations):
        c = np.average(p, axis=0, weights=w)
        d = p - c
        cov = (d * w[:, None]).T @ d
        _, vecs = np.linalg.eigh(cov)
        normal = vecs[:, 0]
        w = _cauchy_weights(d @ normal)
    return normal if normal[2] >= 0 else -normal


def _cauchy_weights(dist: np.ndarray) -> np.ndarray:
    """Cauchy weights of distances to a plane at 2 robust sigmas (1.4826 x their median absolute value)."""
    scale = 1.4826 * np.median(np.abs(dist)) + 1e-9
    return 1.0 / (1.0 + (dist / (2.0 * scale)) ** 2)


def shared_tilt_deg(ground_up: np.ndarray, camera_up: np.ndarray) -> float:
    """The tilt (deg) that the ground's normal and the cameras' up direction (opposite of the view) share: the
    smaller of their horizontal components, counted only as far as they lean the same way."""
    tg, tc = np.asarray(ground_up, float)[:2], np.asarray(camera_up, float)[:2]
    ng, nc = float(np.hypot(*tg)), float(np.hypot(*tc))
    if ng < 1e-12 or nc < 1e-12:
        return 0.0
    cos_phi = float(tg @ tc) / (ng * nc)
    s = min(ng, nc) * max(0.0, cos_phi)
    return float(np.degrees(np.arcsin(min(1.0, s))))



def plane_height(normal: np.ndarray, point: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height of the plane through `point` with upward `normal` at horizontal positions xy (M, 2)."""
    return point[2] - (normal[0] * (xy[:, 0] - point[0]) + normal[1] * (xy[:, 1] - point[1])) / normal[2]
