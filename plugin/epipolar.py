"""Two-view geometry of the tracking gates (method spec 1.5; `plugin.tracking`, `plugin.truncation`): the
fundamental matrix of two fixed poses, the symmetric epipolar distance of every centroid pair (through the rotation
homography K R K^-1 when the two poses share a centre) and the cheirality test (a partner beyond the vanishing point
of the ray lies at negative depth).
"""

from __future__ import annotations

import numpy as np

from .geometry import Camera, Poses

_MIN_BASELINE_M = 1e-6  # below this the two poses share a centre; fall back to the rotation homography


def fundamental_matrix(camera: Camera, poses: Poses, s: int, t: int) -> np.ndarray:
    """F with x_t^T F x_s = 0 for pixels (COLMAP convention) of keyframes s and t of `poses`."""
    r_cw, t_cw = poses.cam_from_world()
    r_rel = r_cw[t] @ r_cw[s].T
    t_rel = t_cw[t] - r_rel @ t_cw[s]
    tx = np.array([[0.0, -t_rel[2], t_rel[1]], [t_rel[2], 0.0, -t_rel[0]], [-t_rel[1], t_rel[0], 0.0]])
    k_inv = np.linalg.inv(camera.K)
    f = k_inv.T @ tx @ r_rel @ k_inv
    return f / max(np.linalg.norm(f), 1e-300)


def _homog(xy: np.ndarray) -> np.ndarray:
    return np.concatenate([np.asarray(xy, np.float64).reshape(-1, 2), np.ones((len(xy), 1))], axis=1)


def epipolar_distances(camera: Camera, poses: Poses, s: int, t: int, xy_s: np.ndarray, xy_t: np.ndarray) -> np.ndarray:
    """(n, m) symmetric epipolar distance (px, max of the two point-to-line distances) of all centroid pairs."""
    hs, ht = _homog(xy_s), _homog(xy_t)
    baseline = np.linalg.norm(poses.centers[t] - poses.centers[s])
    if baseline < _MIN_BASELINE_M:
        r_cw, _ = poses.cam_from_world()
        h = camera.K @ r_cw[t] @ r_cw[s].T @ np.linalg.inv(camera.K)
        p = hs @ h.T
        p = p[:, :2] / p[:, 2:3]
        return np.linalg.norm(p[:, None, :] - ht[None, :, :2], axis=2)
    f = fundamental_matrix(camera, poses, s, t)
    lines_t = hs @ f.T  # (n, 3): epipolar lines in image t of the s points
    lines_s = ht @ f  # (m, 3): epipolar lines in image s of the t points
    alg = hs @ f.T @ ht.T  # (n, m): x_t^T F x_s, the shared numerator
    alg = np.abs(alg)
    d_t = alg / np.maximum(np.linalg.norm(lines_t[:, :2], axis=1), 1e-300)[:, None]
    d_s = alg / np.maximum(np.linalg.norm(lines_s[:, :2], axis=1), 1e-300)[None, :]
    return np.maximum(d_t, d_s)


def behind_camera(
    camera: Camera, poses: Poses, s: int, t: int, xy_s: np.ndarray, xy_t: np.ndarray, slack_px: float
) -> np.ndarray:
    """(n, m) True where m_j lies beyond the vanishing point of the ray of m_i, i.e. at negative depth.

    The ray of pixel x_i from camera s is X(Z) = C_s + Z d (Z > 0: in front of camera s). In image t it projects
    to pi(e + Z v), with e the epipole (image of C_s) and v the image of the direction d (its vanishing point).
    pi(e + Z v) - pi(v) = w / (v_2 (e_2 + Z v_2)) with w = v_2 e_xy - e_2 v_xy, so points at positive depth that are
    visible in t (e_2 + Z v_2 > 0) lie on the sign(v_2) w side of the vanishing point, negative depths on the other.
    The test is made in pixels along that direction; `slack_px` absorbs centroid and pose noise near zero parallax.
    """
    r_cw, t_cw = poses.cam_from_world()
    k = camera.K
    rays_s = _homog(xy_s) @ np.linalg.inv(k).T  # camera-s directions with unit depth
    v = rays_s @ (k @ r_cw[t] @ r_cw[s].T).T  # (n, 3) vanishing points in image t (homogeneous)
    e = k @ (r_cw[t] @ poses.centers[s] + t_cw[t])  # (3,) epipole in image t (homogeneous)
    w = v[:, 2:3] * e[None, :2] - e[2] * v[:, :2]  # (n, 2) direction of positive depth from the vanishing point
    w *= np.sign(v[:, 2:3])
    with np.errstate(divide="ignore", invalid="ignore"):
        vp = v[:, :2] / v[:, 2:3]
        w_unit = w / np.linalg.norm(w, axis=1, keepdims=True)
        along = np.einsum("nmk,nk->nm", np.asarray(xy_t, np.float64)[None, :, :] - vp[:, None, :], w_unit)
    return np.isfinite(along) & (along < -slack_px)
