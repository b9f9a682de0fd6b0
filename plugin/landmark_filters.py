"""Landmark filters that need the whole map: pure functions on landmark arrays."""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826  # median absolute deviation -> standard deviation of a normal distribution


def height_outliers(positions: np.ndarray, neighbours: int, sigmas: float) -> np.ndarray:
    """Mask of landmarks whose height is implausible next to their horizontal neighbours.

    Why: a downward camera flying a straight line sees an object in 2-3 frames whose centres are collinear. Every
    wrong association that slides along the epipolar line then triangulates consistently (a few pixels of
    reprojection error) at a wrong depth, hundreds of metres below or above the ground (Seneca: 30 of 237
    landmarks more than 20 m off). Pose and pixel checks cannot see it; the terrain can: a landmark's height is
    compared with the median height of its `neighbours` nearest landmarks in the horizontal plane (world z up),
    and flagged when the difference exceeds `sigmas` robust standard deviations of that difference over the map.

    positions: (N, 3) world coordinates. Returns a bool (N,) mask, True = outlier. Fewer than neighbours + 1
    landmarks, or a map whose differences have no spread: nothing is flagged.
    """
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    residual = neighbour_height_residuals(p, neighbours)
    if residual is None:
        return np.zeros(len(p), dtype=bool)
    scale = MAD_TO_SIGMA * float(np.median(np.abs(residual - np.median(residual))))
    if not scale > 0:
        return np.zeros(len(p), dtype=bool)
    return np.abs(residual) > sigmas * scale


def beyond_flying_height(positions: np.ndarray, camera_centers: np.ndarray, neighbours: int) -> np.ndarray:
    """Mask of landmarks a whole flying height or more above or below the ground around them: no object seen from
    the air stands that high (it would reach the cameras) or lies that deep under its neighbours. Such a landmark
    is a wrong track triangulated along its rays (`height_outliers`' why); unlike that filter, which sizes its
    limit by the map's own spread and so is left to maps whose objects are low (tree crowns stand 20-30 m over
    the ground beside them), this limit is physical and holds for every map (the eleventh sweep: 1-6 landmarks
    per default synthetic map 150-644 m under a 100 m flight, with 6-10 observations, and the map said ok).

    positions: (N, 3) world coordinates, z up; camera_centers: (M, 3) of the cameras that observed them. The
    flying height is the median camera height over the median landmark height. Returns a bool (N,) mask, True =
    impossible; nothing is flagged without enough landmarks or cameras below the landmarks."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(camera_centers, dtype=np.float64).reshape(-1, 3)
    residual = neighbour_height_residuals(p, neighbours)
    if residual is None or not len(c):
        return np.zeros(len(p), dtype=bool)
    flying_height = float(np.median(c[:, 2]) - np.median(p[:, 2]))
    if not flying_height > 0:
        return np.zeros(len(p), dtype=bool)
    return np.abs(residual) > flying_height


def neighbour_height_residuals(positions: np.ndarray, neighbours: int) -> np.ndarray | None:
    """(N,) height of every landmark minus the median height of its `neighbours` nearest landmarks in the
    horizontal plane (its local ground, free of the terrain's slope to first order); None when the map has at
    most `neighbours` landmarks."""
    from scipy.spatial import cKDTree

    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if neighbours < 1 or len(p) <= neighbours:
        return None
    _, idx = cKDTree(p[:, :2]).query(p[:, :2], k=neighbours + 1)
    return p[:, 2] - np.median(p[idx[:, 1:], 2], axis=1)  # column 0 is the landmark itself
