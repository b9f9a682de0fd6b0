"""Pose refinement with pose priors: a bundle adjustment of poses and landmarks that stays in the GPS frame.

SOS-Match assumes EKF-quality poses. Consumer GPS (metre-level) and autopilot attitude (a degree or two, no
gimbal; on Seneca the telemetry mispredicts image motion by ~140 px, see BENCHMARKS.md) are far from that, so
landmark tracks triangulate badly. `refine_poses_with_priors` jointly adjusts every registered image's pose and
every 3D point of a pycolmap Reconstruction, minimising

    sum_obs rho(|project(R_i, C_i, X_j) - x_ij|^2 / sigma_px^2)            (robust reprojection, Huber)
  + sum_i |C_i - C_i^prior|^2 / sigma_pos^2                                 (GPS position prior)
  + sum_i |Log(R_i R_i^prior^T)|^2 / sigma_att^2                            (attitude prior)

so the map stays georeferenced (no gauge freedom: the priors fix position, orientation and scale) but becomes
self-consistent. Intrinsics are held fixed.

Why not COLMAP's own pose-prior adjuster: pycolmap 4.2.1 exposes `create_pose_prior_bundle_adjuster` with
`PosePrior`, but its priors are positions only (with covariance; gravity is stored but not used), it first
re-aligns the model to the priors with a RANSAC Sim3, and no Ceres cost functions are exposed to Python to add
attitude priors. A fixed-wing survey over flat ground needs the attitude prior (a tilt and a shift of a nadir
camera are nearly interchangeable over a plane), so the problem is solved here with scipy's sparse trust-region
least squares: the Jacobian is finite-differenced with its block sparsity given, which costs ~9 residual
evaluations per iteration because no residual touches two images or two points.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np

from ..plugin.geometry import Poses

log = logging.getLogger(__name__)


@dataclass
class RefinementStats:
    """What the refinement did. Errors in pixels, metres and degrees; 'prior' = the given poses."""

    images: int
    points: int
    observations: int
    reprojection_rmse_before_px: float
    reprojection_rmse_after_px: float
    reprojection_median_before_px: float
    reprojection_median_after_px: float
    position_change_mean_m: float
    position_change_max_m: float
    rotation_change_mean_deg: float
    rotation_change_max_deg: float
    iterations: int
    seconds: float
    converged: bool

    def to_dict(self) -> dict:
        return asdict(self)


def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues, vectorised: (N,3) rotation vectors -> (N,3,3)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = np.where(small[:, None], 0.0, w / np.where(small, 1.0, theta)[:, None])
    kx = np.zeros((len(w), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    kx[:, 1, 2], kx[:, 2, 0], kx[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3)[None] + s * kx + (1 - c) * (kx @ kx)


def _matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """(N,3,3) -> (N,3) rotation vectors (angles below pi, which is all the priors need)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Angles (degrees) of the relative rotations between two stacks of rotation matrices."""
    rel = np.einsum("nij,nkj->nik", r_a, r_b)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def refine_poses_with_priors(
    reconstruction: object,
    prior_poses: Poses,
    position_sigma_m: float | tuple[float, float, float] = 2.0,
    attitude_sigma_deg: float = 2.0,
    pixel_sigma_px: float = 3.0,
    huber_sigmas: float = 2.0,
    max_iterations: int = 100,
    min_track_length: int = 2,
) -> RefinementStats:
    """Refine the poses of the registered images and the 3D points of `reconstruction` (a pycolmap
    Reconstruction, changed in place; intrinsics fixed) with priors on every pose.

    `prior_poses` (world_from_camera, matched to images by name; images without a prior are refined without one)
    give the prior centres and rotations, with standard deviations `position_sigma_m` (one value or east,
    north, up) and `attitude_sigma_deg` (per axis). Reprojection residuals are scaled by `pixel_sigma_px` and
    robustified with a Huber loss at `huber_sigmas`. Points seen by fewer than `min_track_length` images keep
    their position. Afterwards the point errors are updated (`update_point_3d_errors`).
    """
    import pycolmap
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    t0 = time.perf_counter()
    rec = reconstruction
    image_ids = sorted(i for i, im in rec.images.items() if im.has_pose)
    if not image_ids:
        raise ValueError("the reconstruction has no registered image")
    prior_index = {name: k for k, name in enumerate(prior_poses.names)}
    n_img = len(image_ids)
    img_pos = {iid: k for k, iid in enumerate(image_ids)}

    # Current poses as world_from_camera.
    r_wc0 = np.empty((n_img, 3, 3))
    c0 = np.empty((n_img, 3))
    for k, iid in enumerate(image_ids):
        cfw = rec.images[iid].cam_from_world()
        r_cw = np.asarray(cfw.rotation.matrix())
        r_wc0[k] = r_cw.T
        c0[k] = -r_cw.T @ np.asarray(cfw.translation)
    has_prior = np.array([rec.images[iid].name in prior_index for iid in image_ids])
    pk = np.array([prior_index.get(rec.images[iid].name, 0) for iid in image_ids])
    r_prior = np.where(has_prior[:, None, None], prior_poses.rotations[pk], r_wc0)
    c_prior = np.where(has_prior[:, None], prior_poses.centers[pk], c0)
    origin = c_prior.mean(axis=0)  # a local origin keeps finite-difference steps meaningful at UTM magnitudes

    # Observations.
    point_ids = [pid for pid, p in rec.points3D.items()
                 if len({e.image_id for e in p.track.elements if e.image_id in img_pos}) >= min_track_length]
    pt_pos = {pid: k for k, pid in enumerate(point_ids)}
    obs_img, obs_pt, obs_uv, obs_cam = [], [], [], []
    for pid in point_ids:
        for e in rec.points3D[pid].track.elements:
            if e.image_id not in img_pos:
                continue
            im = rec.images[e.image_id]
            obs_img.append(img_pos[e.image_id])
            obs_pt.append(pt_pos[pid])
            obs_uv.append(np.asarray(im.points2D[e.point2D_idx].xy))
            obs_cam.append(im.camera_id)
    n_pts, n_obs = len(point_ids), len(obs_img)
    obs_img_a, obs_pt_a = np.array(obs_img, dtype=int), np.array(obs_pt, dtype=int)
    obs_uv_a = np.array(obs_uv, dtype=np.float64).reshape(-1, 2)
    cams = {cid: np.asarray(rec.cameras[cid].calibration_matrix()) for cid in set(obs_cam)}
    k_obs = np.stack([cams[c] for c in obs_cam]) if n_obs else np.zeros((0, 3, 3))
    x0_pts = np.array([rec.points3D[pid].xyz for pid in point_ids], dtype=np.float64).reshape(-1, 3) - origin

    pos_sigma = np.broadcast_to(np.asarray(position_sigma_m, dtype=np.float64), (3,))
    att_sigma = np.radians(attitude_sigma_deg)
    prior_rows = np.flatnonzero(has_prior)

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = x[: 3 * n_img].reshape(n_img, 3)
        c = x[3 * n_img: 6 * n_img].reshape(n_img, 3)
        p = x[6 * n_img:].reshape(n_pts, 3)
        return _rotvec_to_matrix(w) @ r_wc0, c, p

    def reprojection(r_wc: np.ndarray, c: np.ndarray, p: np.ndarray) -> np.ndarray:
        pc = np.einsum("nji,nj->ni", r_wc[obs_img_a], p[obs_pt_a] - c[obs_img_a])  # R_wc^T (X - C)
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        uv = np.stack([k_obs[:, 0, 0] * pc[:, 0] / z + k_obs[:, 0, 2], k_obs[:, 1, 1] * pc[:, 1] / z + k_obs[:, 1, 2]],
                      1)
        return uv - obs_uv_a

    def residuals(x: np.ndarray) -> np.ndarray:
        r_wc, c, p = unpack(x)
        rep = reprojection(r_wc, c, p).ravel() / pixel_sigma_px
        dpos = ((c - (c_prior - origin))[prior_rows] / pos_sigma).ravel()
        datt = (_matrix_to_rotvec(np.einsum("nij,nkj->nik", r_wc[prior_rows], r_prior[prior_rows])) / att_sigma).ravel()
        return np.concatenate([rep, dpos, datt])

    # Block sparsity of the Jacobian.
    n_par = 6 * n_img + 3 * n_pts
    n_res = 2 * n_obs + 6 * len(prior_rows)
    sp = lil_matrix((n_res, n_par), dtype=np.int8)
    rows = np.arange(n_obs)
    for comp in range(2):
        rr = 2 * rows + comp
        for j in range(3):
            sp[rr, 3 * obs_img_a + j] = 1
            sp[rr, 3 * n_img + 3 * obs_img_a + j] = 1
            sp[rr, 6 * n_img + 3 * obs_pt_a + j] = 1
    base = 2 * n_obs
    for q, i in enumerate(prior_rows):
        for j in range(3):
            sp[base + 3 * q + j, 3 * n_img + 3 * i + j] = 1
            sp[base + 3 * len(prior_rows) + 3 * q + j, 3 * i: 3 * i + 3] = 1

    x0 = np.concatenate([np.zeros(3 * n_img), (c0 - origin).ravel(), x0_pts.ravel()])
    before = np.linalg.norm(reprojection(r_wc0, c0 - origin, x0_pts), axis=1) if n_obs else np.zeros(0)

    # Huber on the whitened reprojection residuals only: scipy's loss acts on every residual, so the priors are
    # kept quadratic by a loss scale large enough for them and the reprojection part is pre-robustified here.
    def robust_residuals(x: np.ndarray) -> np.ndarray:
        r = residuals(x)
        rep = r[: 2 * n_obs].reshape(-1, 2)
        norm = np.linalg.norm(rep, axis=1)
        scale = np.where(norm > huber_sigmas, np.sqrt(np.maximum(2 * huber_sigmas * norm - huber_sigmas**2, 0.0))
                         / np.maximum(norm, 1e-12), 1.0)
        r[: 2 * n_obs] = (rep * scale[:, None]).ravel()
        return r

    result = least_squares(robust_residuals, x0, jac_sparsity=sp.tocsr(), method="trf", x_scale="jac",
                           tr_solver="lsmr", max_nfev=max_iterations, xtol=1e-8, ftol=1e-6, verbose=0)
    r_wc, c, p = unpack(result.x)
    after = np.linalg.norm(reprojection(r_wc, c, p), axis=1) if n_obs else np.zeros(0)

    # Write back: trivial rigs, so the frame pose is the camera pose.
    for k, iid in enumerate(image_ids):
        r_cw = r_wc[k].T
        t_cw = -r_cw @ (c[k] + origin)
        rec.frames[rec.images[iid].frame_id].rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), t_cw)
    for k, pid in enumerate(point_ids):
        rec.points3D[pid].xyz = p[k] + origin
    rec.update_point_3d_errors()

    dpos = np.linalg.norm(c + origin - c_prior, axis=1)
    drot = rotation_angle_deg(r_wc, r_prior)
    stats = RefinementStats(
        images=n_img, points=n_pts, observations=n_obs,
        reprojection_rmse_before_px=float(np.sqrt(np.mean(before**2))) if n_obs else 0.0,
        reprojection_rmse_after_px=float(np.sqrt(np.mean(after**2))) if n_obs else 0.0,
        reprojection_median_before_px=float(np.median(before)) if n_obs else 0.0,
        reprojection_median_after_px=float(np.median(after)) if n_obs else 0.0,
        position_change_mean_m=float(dpos.mean()), position_change_max_m=float(dpos.max()),
        rotation_change_mean_deg=float(drot.mean()), rotation_change_max_deg=float(drot.max()),
        iterations=int(result.nfev), seconds=time.perf_counter() - t0, converged=bool(result.status > 0),
    )
    log.info("pose refinement: %d images, %d points, reprojection RMSE %.2f -> %.2f px, poses moved %.2f m / %.2f deg "
             "on average (%.1f s)", n_img, n_pts, stats.reprojection_rmse_before_px, stats.reprojection_rmse_after_px,
             stats.position_change_mean_m, stats.rotation_change_mean_deg, stats.seconds)
    return stats


def poses_of_reconstruction(reconstruction: object) -> Poses:
    """world_from_camera poses of the registered images of a pycolmap Reconstruction, by image id order."""
    ids = sorted(i for i, im in reconstruction.images.items() if im.has_pose)
    names, r_cw, t_cw = [], [], []
    for iid in ids:
        cfw = reconstruction.images[iid].cam_from_world()
        names.append(reconstruction.images[iid].name)
        r_cw.append(np.asarray(cfw.rotation.matrix()))
        t_cw.append(np.asarray(cfw.translation))
    return Poses.from_cam_from_world(names, np.array(r_cw).reshape(-1, 3, 3), np.array(t_cw).reshape(-1, 3))
