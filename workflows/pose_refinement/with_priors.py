"""Pose refinement with position and attitude priors (`refine_poses_with_priors`, scipy): a bundle adjustment of
poses and landmarks that stays in the GPS frame.

SOS-Match assumes EKF-quality poses. Consumer GPS (metre-level) and autopilot attitude (a degree or two, no
gimbal; on Seneca the telemetry mispredicts image motion by ~140 px, see BENCHMARKS.md) are far from that, so
landmark tracks triangulate badly. `refine_poses_with_priors` jointly adjusts every registered image's pose and
every 3D point of a pycolmap Reconstruction, minimising

    sum_obs rho(|project(R_i, C_i, X_j) - x_ij| / sigma_px)                  (reprojection, Huber)
  + sum_i |C_i - C_i^prior|^2 / sigma_pos^2                                  (GPS position prior)
  + sum_i |Log(R_i R_i^prior^T)|^2 / sigma_att^2                             (attitude prior)

so the map stays georeferenced (no gauge freedom: the priors fix position, orientation and scale) but becomes
self-consistent. Intrinsics are held fixed.

Why not COLMAP's own pose-prior adjuster: pycolmap 4.2.1 exposes `create_pose_prior_bundle_adjuster` with
`PosePrior`, but its priors are positions only (with covariance; gravity is stored but not used), it first
re-aligns the model to the priors with a RANSAC Sim3, and no Ceres cost functions are exposed to Python to add
attitude priors. A fixed-wing survey over flat ground needs the attitude prior (a tilt and a shift of a nadir
camera are nearly interchangeable over a plane), so the problem is solved here with scipy's sparse
trust-region least squares (TRF + LSMR, Huber by reweighting) and a closed-form sparse Jacobian: rotations are
parametrised as R_cw = exp(w) R_prior_cw, so the attitude prior is w / sigma and the reprojection blocks are
-duv/dp [p]x J_l(w), -duv/dp R_cw and duv/dp R_cw.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ...plugin.geometry import Poses, matrix_to_rotvec, rotvec_to_matrix, skew
from .judge import RefinementStats, pose_changes

log = logging.getLogger(__name__)


def registered_image_ids(rec: object) -> list[int]:
    """Sorted ids of the images with a pose; a reconstruction without any cannot be refined."""
    image_ids = sorted(i for i, im in rec.images.items() if im.has_pose)
    if not image_ids:
        raise ValueError("the reconstruction has no registered image")
    return image_ids


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
    from scipy.sparse import csr_matrix

    t0 = time.perf_counter()
    rec = reconstruction
    image_ids = registered_image_ids(rec)
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
    origin = c_prior.mean(axis=0)  # a local origin keeps the solver's scaling sane at UTM magnitudes

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
    # the residuals below are pinhole projections: observations of a camera with distortion are undistorted into
    # its equivalent pinhole first (the same rays), so the refinement holds for any lens model
    from ...database.cameras import camera_from_pycolmap

    obs_cam_a = np.asarray(obs_cam, dtype=np.int64)
    for cid in set(obs_cam):
        lens = camera_from_pycolmap(rec.cameras[cid])
        if not lens.is_pinhole:
            rows = np.flatnonzero(obs_cam_a == cid)
            obs_uv_a[rows] = lens.undistort_points(obs_uv_a[rows])
    cams = {cid: np.asarray(rec.cameras[cid].calibration_matrix()) for cid in set(obs_cam)}
    k_obs = np.stack([cams[c] for c in obs_cam]) if n_obs else np.zeros((0, 3, 3))
    x0_pts = np.array([rec.points3D[pid].xyz for pid in point_ids], dtype=np.float64).reshape(-1, 3) - origin

    pos_sigma = np.broadcast_to(np.asarray(position_sigma_m, dtype=np.float64), (3,))
    att_sigma = np.radians(attitude_sigma_deg)
    prior_rows = np.flatnonzero(has_prior)

    # Rotations are parametrised relative to the prior: R_cw(w) = exp(w) R_prior_cw, so the attitude prior's
    # residual is simply w / sigma (|w| is the angle to the prior) and every Jacobian block is closed-form.
    rp_cw = np.transpose(r_prior, (0, 2, 1))

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = x[: 3 * n_img].reshape(n_img, 3)
        c = x[3 * n_img: 6 * n_img].reshape(n_img, 3)
        p = x[6 * n_img:].reshape(n_pts, 3)
        return np.transpose(rotvec_to_matrix(w) @ rp_cw, (0, 2, 1)), c, p

    def reprojection(r_wc: np.ndarray, c: np.ndarray, p: np.ndarray) -> np.ndarray:
        pc = np.einsum("nji,nj->ni", r_wc[obs_img_a], p[obs_pt_a] - c[obs_img_a])  # R_wc^T (X - C)
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        uv = np.stack([k_obs[:, 0, 0] * pc[:, 0] / z + k_obs[:, 0, 2], k_obs[:, 1, 1] * pc[:, 1] / z + k_obs[:, 1, 2]],
                      1)
        return uv - obs_uv_a

    robust = {"on": False}

    def huber_scale(rep: np.ndarray) -> np.ndarray:
        """Per-observation factor that turns the squared whitened error into Huber's cost (IRLS-style)."""
        norm = np.linalg.norm(rep.reshape(-1, 2), axis=1)
        if not robust["on"]:
            return np.ones(len(norm))
        return np.where(norm > huber_sigmas,
                        np.sqrt(np.maximum(2 * huber_sigmas * norm - huber_sigmas**2, 0.0)) / np.maximum(norm, 1e-12),
                        1.0)

    def residuals(x: np.ndarray) -> np.ndarray:
        r_wc, c, p = unpack(x)
        rep = reprojection(r_wc, c, p).ravel() / pixel_sigma_px
        rep = (rep.reshape(-1, 2) * huber_scale(rep)[:, None]).ravel()
        dpos = ((c - (c_prior - origin))[prior_rows] / pos_sigma).ravel()
        datt = (x[: 3 * n_img].reshape(n_img, 3)[prior_rows] / att_sigma).ravel()
        return np.concatenate([rep, dpos, datt])

    def jacobian(x: np.ndarray) -> object:
        w = x[: 3 * n_img].reshape(n_img, 3)
        r_wc, c, p = unpack(x)
        r_cw = np.transpose(r_wc, (0, 2, 1))[obs_img_a]
        pc = np.einsum("nij,nj->ni", r_cw, p[obs_pt_a] - c[obs_img_a])
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        fx, fy = k_obs[:, 0, 0], k_obs[:, 1, 1]
        d_uv_d_p = np.zeros((n_obs, 2, 3))
        d_uv_d_p[:, 0, 0], d_uv_d_p[:, 0, 2] = fx / z, -fx * pc[:, 0] / z**2
        d_uv_d_p[:, 1, 1], d_uv_d_p[:, 1, 2] = fy / z, -fy * pc[:, 1] / z**2
        d_uv_d_p /= pixel_sigma_px
        # d(exp(w) q)/dw = -[p]x J_l(w), J_l the left Jacobian of SO(3).
        wo = w[obs_img_a]
        theta = np.linalg.norm(wo, axis=1)
        small = theta < 1e-6
        th = np.where(small, 1.0, theta)
        a = np.where(small, 0.5, (1 - np.cos(th)) / th**2)
        b = np.where(small, 1.0 / 6.0, (th - np.sin(th)) / th**3)
        wx = skew(wo)
        j_l = np.eye(3)[None] + a[:, None, None] * wx + b[:, None, None] * (wx @ wx)
        d_p_d_w = -skew(pc) @ j_l
        blocks = np.concatenate([d_uv_d_p @ d_p_d_w, d_uv_d_p @ -r_cw, d_uv_d_p @ r_cw], axis=2)  # (n_obs, 2, 9)
        rep = reprojection(r_wc, c, p) / pixel_sigma_px
        blocks *= huber_scale(rep)[:, None, None]  # the robust weight, held constant in the derivative
        data = np.concatenate([blocks.ravel(), np.tile(1.0 / pos_sigma, len(prior_rows)),
                               np.tile(np.eye(3).ravel() / att_sigma, len(prior_rows))])
        return csr_matrix((data, (jac_rows, jac_cols)), shape=(n_res, n_par))

    # Block sparsity of the Jacobian (built as COO index arrays: lil item assignment is slow at 1e5 rows).
    n_par = 6 * n_img + 3 * n_pts
    n_res = 2 * n_obs + 6 * len(prior_rows)
    rep_rows = (2 * np.arange(n_obs)[:, None] + np.arange(2)[None, :]).ravel()  # (2 n_obs,)
    rep_img = np.repeat(obs_img_a, 2)
    rep_pt = np.repeat(obs_pt_a, 2)
    j3 = np.arange(3)
    rows_list = [np.repeat(rep_rows, 9)]
    cols_list = [np.concatenate([(3 * rep_img[:, None] + j3), (3 * n_img + 3 * rep_img[:, None] + j3),
                                 (6 * n_img + 3 * rep_pt[:, None] + j3)], axis=1).ravel()]
    base = 2 * n_obs
    q = np.arange(len(prior_rows))
    rows_list.append((base + 3 * q[:, None] + j3).ravel())  # position prior: one centre coordinate each
    cols_list.append((3 * n_img + 3 * prior_rows[:, None] + j3).ravel())
    att_rows = base + 3 * len(prior_rows) + 3 * q[:, None] + j3  # attitude prior: the image's 3 rotation params
    rows_list.append(np.repeat(att_rows.ravel(), 3))
    cols_list.append(np.repeat(3 * prior_rows[:, None] + j3, 3, axis=0).reshape(-1, 3).ravel()
                     if len(prior_rows) else np.zeros(0, dtype=int))
    jac_rows, jac_cols = np.concatenate(rows_list), np.concatenate(cols_list)

    w0 = matrix_to_rotvec(np.einsum("nji,nkj->nik", r_wc0, r_prior)) if n_img else np.zeros((0, 3))  # R0_cw Rp_wc
    x0 = np.concatenate([w0.ravel(), (c0 - origin).ravel(), x0_pts.ravel()])
    before = np.linalg.norm(reprojection(r_wc0, c0 - origin, x0_pts), axis=1) if n_obs else np.zeros(0)

    # Two stages. The robust weight (Huber at `huber_sigmas`, reprojection terms only: the priors stay Gaussian
    # so no pose can wander off its GPS/attitude prior, which a Huber on the priors allowed on Seneca: poses
    # moved 34 m / 33 degrees on average) is applied IRLS-style. Started from poses 30+ sigma off, every
    # residual would be in Huber's linear part and the solve settles in a poor minimum, so a plain
    # least-squares stage comes first and brings the inliers inside the quadratic zone.
    # LSMR is capped: an inexact (truncated) step is fine inside a trust region, and uncapped LSMR runs up to
    # min(m, n) inner iterations per step, minutes each on a 167-image, 9000-track survey.
    common = {"jac": jacobian, "method": "trf", "x_scale": "jac", "tr_solver": "lsmr", "xtol": 1e-8, "ftol": 1e-6,
              "tr_options": {"maxiter": 300}}
    first = least_squares(residuals, x0, max_nfev=max(1, max_iterations // 2), **common)
    robust["on"] = True
    result = least_squares(residuals, first.x, max_nfev=max_iterations, **common)
    result.nfev += first.nfev
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

    stats = RefinementStats(
        images=n_img, points=n_pts, observations=n_obs,
        reprojection_rmse_before_px=float(np.sqrt(np.mean(before**2))) if n_obs else 0.0,
        reprojection_rmse_after_px=float(np.sqrt(np.mean(after**2))) if n_obs else 0.0,
        reprojection_median_before_px=float(np.median(before)) if n_obs else 0.0,
        reprojection_median_after_px=float(np.median(after)) if n_obs else 0.0,
        iterations=int(result.nfev), seconds=time.perf_counter() - t0, converged=bool(result.status > 0),
        **pose_changes(r_prior, c_prior, r_wc, c + origin),
    )
    log.info("pose refinement: %d images, %d points, reprojection RMSE %.2f -> %.2f px, poses moved %.2f m / %.2f deg "
             "on average (%.1f s)", n_img, n_pts, stats.reprojection_rmse_before_px, stats.reprojection_rmse_after_px,
             stats.position_change_mean_m, stats.rotation_change_mean_deg, stats.seconds)
    return stats
