"""Camera headings from the image motion (pure numpy + OpenCV on arrays): where images carry no attitude tags.

Without attitude tags the heading of a camera is unknown; the course over ground (EXIF GPSTrack, or the direction
to the neighbouring images) says where the aircraft went, not where the image top points. The two agree only for
a camera mounted with the image top forward on an aircraft that flies nose first: a camera mounted sideways, a
portrait export (pixels turned by 90 degrees), a multirotor that keeps its heading and flies the return lines
backwards, a fixed wing crabbing in wind all break it, and a refinement from tie points cannot turn a camera by
90 degrees out of its starting point (Seneca's first 30 frames turned to portrait ended 90 degrees off).

The images say it. Two overlapping views of (nearly) flat ground are related by a homography
H = R + t n^T / d (normalised coordinates, x_b ~ H x_a for a ground point, X_b = R X_a + t); its decomposition
gives the direction in which camera b's centre lies as seen from camera a (-R^T t), in a's own axes, whatever the
relative rotation (a fixed wing's roll between frames moves the image by hundreds of pixels; the direction of the
translation is free of it). The GPS gives the same direction in the world. The turn about the vertical that
brings the first onto the second is the error of the camera's prior heading (`heading_corrections`); per image,
the pairs it belongs to are averaged robustly (weights: the pairs' numbers of matches). Per image, not one offset
per flight: a multirotor that flies the return lines backwards has two.
"""

from __future__ import annotations

import cv2
import numpy as np


def directions_of_motion(x_a: np.ndarray, x_b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The horizontal direction (unit 2-vector, camera x right, y down) of camera b's centre in camera a's axes and
    of camera a's centre in camera b's axes, from matches x_a <-> x_b (M,2) of ground points in normalised camera
    coordinates (homography inliers). None when no plausible decomposition exists (fewer than 8 matches, no motion).

    Of the homography's decompositions, the ones that put the matched points in front of camera a (n^T x_a > 0)
    are kept and the one whose ground normal is closest to a's optical axis is taken: the cameras look down at the
    ground (the other solution tilts the plane towards the direction of motion)."""
    if len(x_a) < 8:
        return None
    h, _ = cv2.findHomography(np.asarray(x_a, np.float64), np.asarray(x_b, np.float64), 0)
    if h is None or not np.all(np.isfinite(h)):
        return None
    _, rotations, translations, normals = cv2.decomposeHomographyMat(h, np.eye(3))
    ha = np.column_stack([x_a, np.ones(len(x_a))])
    best, best_nz = None, -np.inf
    for r, t, n in zip(rotations, translations, normals):
        n = n.ravel()
        if np.mean(ha @ n > 0) < 0.9 or n[2] <= best_nz:
            continue
        best, best_nz = (np.asarray(r), t.ravel()), n[2]
    if best is None:
        return None
    r, t = best
    in_a, in_b = -r.T @ t, t  # camera b's centre in a's frame, a's centre in b's frame (scale: the plane distance)
    out = []
    for v in (in_a, in_b):
        norm = float(np.hypot(v[0], v[1]))
        if norm < 1e-6:
            return None
        out.append(v[:2] / norm)
    return out[0], out[1]


def heading_corrections(rotations: np.ndarray, centers: np.ndarray,
                        pairs: list[tuple[int, int, np.ndarray, np.ndarray, float]],
                        position_sigma_m: float = 0.0) -> np.ndarray:
    """(N,) turn about the world vertical (radians, counter-clockwise seen from above; world z up) that brings each
    camera's prior rotation (world_from_camera) onto the images' direction of motion, NaN for images in no pair
    and for images whose pairs disagree.

    `pairs`: (a, b, d_a, d_b, weight) with d_a the direction of camera b's centre in camera a's axes and d_b the
    reverse (`directions_of_motion`), weight the pair's number of matches. For camera a the GPS says b lies along
    C_b - C_a, the prior rotation says along R_a [d_a, 0]; the difference of their azimuths is a's heading error.
    Per image, a robust mean of its pairs' turns (`robust_circular_mean`): a homography of a dozen matches can
    decompose into a direction 180 degrees off, and one such pair must not turn an image that its other pairs
    place.
    `position_sigma_m`: the GPS fixes' sigma per horizontal axis. The GPS direction of a pair is then known to
    about sqrt(2) sigma / baseline (radians); a pair whose baseline leaves it uncertain beyond OUTLIER_TURN_RAD says
    nothing about the heading, however many matches it has, and is not used (nu58 D2: Seneca's IMG_0521 and
    IMG_0527, from two lines 5.7 m apart, 342 matches, turned each other -156 / -173 deg against their other pairs'
    -5..+9 / -28..-18 deg at 21-34 m; the weight of the matches outvoted them and both were mapped ~140 deg off)."""
    min_baseline = np.sqrt(2.0) * position_sigma_m / np.tan(OUTLIER_TURN_RAD)
    per_image: list[list[tuple[float, float]]] = [[] for _ in range(len(rotations))]
    for a, b, d_a, d_b, weight in pairs:
        for i, j, d in ((a, b, d_a), (b, a, d_b)):
            g = centers[j, :2] - centers[i, :2]
            w = rotations[i] @ np.array([d[0], d[1], 0.0])
            if np.hypot(w[0], w[1]) < 1e-6 or np.hypot(g[0], g[1]) < max(1e-6, min_baseline):
                continue  # no horizontal direction to compare (a camera looking along the ground; a hover; GPS noise)
            per_image[i].append((float(np.arctan2(g[1], g[0]) - np.arctan2(w[1], w[0])), float(weight)))
    out = np.full(len(rotations), np.nan)
    for i, found in enumerate(per_image):
        if found:
            angles, weights = np.array(found).T
            out[i] = robust_circular_mean(angles, weights)
    return out


# Estimates further than this from the weighted circular median are left out of the mean: a wrong decomposition is
# tens of degrees to 180 off, the GPS noise over a baseline of a few image spacings a few degrees.
OUTLIER_TURN_RAD = np.radians(30.0)


def robust_circular_mean(angles: np.ndarray, weights: np.ndarray) -> float:
    """The weighted circular mean (radians) of the angles within OUTLIER_TURN_RAD of their weighted circular
    median (the angle of the set with the least weighted sum of angular distances to the others); NaN when those
    hold no more than half the weight (the estimates do not agree: an image whose pairs are all weak)."""
    angles, weights = np.asarray(angles, np.float64), np.asarray(weights, np.float64)
    dist = np.abs(np.angle(np.exp(1j * (angles[:, None] - angles[None, :]))))
    median = angles[int(np.argmin(dist @ weights))]
    near = np.abs(np.angle(np.exp(1j * (angles - median)))) <= OUTLIER_TURN_RAD
    if weights[near].sum() <= 0.5 * weights.sum():
        return float("nan")
    return float(np.angle(np.sum(weights[near] * np.exp(1j * angles[near]))))


def turned_about_vertical(rotations: np.ndarray, turns: np.ndarray) -> np.ndarray:
    """world_from_camera rotations turned by `turns` (radians, counter-clockwise about the world z axis; NaN: kept)."""
    out = np.array(rotations, dtype=np.float64, copy=True)
    for i in np.flatnonzero(np.isfinite(turns)):
        c, s = np.cos(turns[i]), np.sin(turns[i])
        out[i] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ out[i]
    return out
