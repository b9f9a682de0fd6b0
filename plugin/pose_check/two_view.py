"""The two-view geometry that given poses imply: relative poses, essential matrices, Sampson distances of
matches and the depths they triangulate at. Vectorised over pairs and matches (the systematic-error fit evaluates
thousands of matches under hundreds of essential matrices per step; `database.colmap_db.epipolar_errors_px`
answers one pair at a time through pycolmap, for the mapping's verification)."""

from __future__ import annotations

import numpy as np

from ..geometry import SAME_POSITION


def relative_poses(r_wc: np.ndarray, centers: np.ndarray, a: np.ndarray, b: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of camera b from camera a for index arrays `a`, `b` (P,): x_b = R x_a + t, shapes (P,3,3), (P,3).
    t is exactly zero for two cameras at one recorded position within rounding (`geometry.SAME_POSITION`): a
    direction of nanometres is noise, and every use of t (E = 0, Sampson distances NaN, no depths) says "no
    baseline" as it does for equal positions."""
    r_b = r_wc[b]
    rot = np.einsum("pji,pjk->pik", r_b, r_wc[a])  # R_b^T R_a
    step = centers[a] - centers[b]
    step = np.where(np.linalg.norm(step, axis=-1, keepdims=True) <= SAME_POSITION, 0.0, step)
    t = np.einsum("pji,pj->pi", r_b, step)  # R_b^T (C_a - C_b)
    return rot, t


def essential_matrices(rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """E = [t]x R (P,3,3) with t normalised (a zero baseline gives E = 0)."""
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    u = np.divide(t, norm, out=np.zeros_like(t), where=norm > 0)
    skew = np.zeros(t.shape[:-1] + (3, 3))
    skew[..., 0, 1], skew[..., 0, 2], skew[..., 1, 2] = -u[..., 2], u[..., 1], -u[..., 0]
    skew[..., 1, 0], skew[..., 2, 0], skew[..., 2, 1] = u[..., 2], -u[..., 1], u[..., 0]
    return skew @ rot


def sampson_distances(x_a: np.ndarray, x_b: np.ndarray, essential: np.ndarray) -> np.ndarray:
    """Sampson distances (M,) of normalised-coordinate matches x_a <-> x_b (M,2) under essential matrices (M,3,3)
    or one (3,3), in normalised units (x focal length = pixels). NaN where E is zero (no baseline)."""
    h_a = np.concatenate([x_a, np.ones((len(x_a), 1))], axis=1)
    h_b = np.concatenate([x_b, np.ones((len(x_b), 1))], axis=1)
    e = np.broadcast_to(essential, (len(x_a), 3, 3))
    ex = np.einsum("mij,mj->mi", e, h_a)
    etx = np.einsum("mji,mj->mi", e, h_b)
    num = np.abs(np.einsum("mi,mi->m", h_b, ex))
    den = np.sqrt(ex[:, 0] ** 2 + ex[:, 1] ** 2 + etx[:, 0] ** 2 + etx[:, 1] ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def triangulation_depths(x_a: np.ndarray, x_b: np.ndarray, rot: np.ndarray, t: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Depths (M,), (M,) along each camera's optical axis of the midpoint triangulation of matches x_a <-> x_b
    (normalised coordinates) with x_b = R x_a + t; negative = behind that camera."""
    d_a = np.concatenate([x_a, np.ones((len(x_a), 1))], axis=1) @ np.asarray(rot).T  # ray of a, in b's frame
    d_b = np.concatenate([x_b, np.ones((len(x_b), 1))], axis=1)
    aa, bb, ab = (np.einsum("mi,mi->m", u, v) for u, v in ((d_a, d_a), (d_b, d_b), (d_a, d_b)))
    ta, tb = d_a @ t, d_b @ t
    det = aa * bb - ab**2  # min |l_b d_b - l_a d_a - t|: [aa -ab; -ab bb] [l_a; l_b] = [-ta; tb]
    with np.errstate(invalid="ignore", divide="ignore"):
        l_a = np.where(det > 0, (-ta * bb + ab * tb) / det, np.nan)
        l_b = np.where(det > 0, (aa * tb - ab * ta) / det, np.nan)
    return l_a, l_b


def ray_angles(x_a: np.ndarray, x_b: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Angles (M,) in radians between each match's two rays in camera b's frame (x_b = R x_a + t; normalised
    coordinates): the parallax the camera rotation does not explain. Times the focal length it is in pixels."""
    d_a = np.concatenate([x_a, np.ones((len(x_a), 1))], axis=1) @ np.asarray(rot).T
    d_b = np.concatenate([x_b, np.ones((len(x_b), 1))], axis=1)
    cross = np.linalg.norm(np.cross(d_a, d_b), axis=1)
    return np.arctan2(cross, np.einsum("mi,mi->m", d_a, d_b))
