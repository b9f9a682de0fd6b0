"""Pose refinement with pose priors: a bundle adjustment of poses and landmarks that stays in the GPS frame.

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
from dataclasses import asdict, dataclass, replace

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Poses, rotation_angle_deg
from .triangulation import fixed_camera_ba_options

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
    position_change_median_m: float = float("nan")
    block_tilt_change_deg: float = float("nan")  # the rotation all poses share, its tilt off the vertical
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["warnings"] = list(self.warnings)
        return d


def _pose_changes(before_r: np.ndarray, before_c: np.ndarray, after_r: np.ndarray, after_c: np.ndarray) -> dict:
    """How far the poses moved: per-image position and rotation changes, and the tilt of the rotation they share
    (the chordal mean of R_after R_before^T): a block that tilts as a whole moves every camera the same way."""
    dpos = np.linalg.norm(after_c - before_c, axis=1)
    drot = np.atleast_1d(rotation_angle_deg(before_r, after_r))
    mean = np.einsum("nij,nkj->ik", after_r, before_r)  # sum of R_after R_before^T
    u, _, vt = np.linalg.svd(mean)
    shared = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    tilt = float(np.degrees(np.arccos(np.clip(shared[2, 2], -1.0, 1.0))))
    return {"position_change_mean_m": float(dpos.mean()), "position_change_max_m": float(dpos.max()),
            "position_change_median_m": float(np.median(dpos)), "rotation_change_mean_deg": float(drot.mean()),
            "rotation_change_max_deg": float(drot.max()), "block_tilt_change_deg": tilt}


def judge_refinement(stats: RefinementStats, position_sigma_m: float | tuple[float, float, float],
                     attitude_sigma_deg: float) -> tuple[list[str], list[str]]:
    """(errors, warnings) of a refinement: the priors say how far the poses may move.

    Errors (the refined poses are not used): a median position change beyond 3 prior sigmas (a Gaussian prior
    puts 3 sigma in the tail of every axis: half the cameras beyond it means the tie points pulled the block away
    from the GPS, e.g. folded it); a tilt of the whole block (the rotation all poses share) beyond 3 attitude
    sigmas. Warnings: no convergence within the solver's iterations (Seneca's good refinement ends so: 0.52 px,
    poses 1.2 sigma from their priors, block tilt 2 deg; the figures above judge the result); single images moved
    beyond 5 sigmas (a wrong GPS fix, or a wrong tie point); a mean rotation change beyond 3 attitude sigmas; tie
    points that barely constrain the poses (fewer than 1.5 measured coordinates per unknown: 6 per pose, 3 per
    point)."""
    sigma = float(np.max(np.atleast_1d(position_sigma_m)))
    errors: list[str] = []
    warnings: list[str] = []
    if stats.points == 0:
        return errors, ["no tie points between the images: the poses are the priors, unrefined"]
    if not stats.converged:
        warnings.append(f"the bundle adjustment did not converge ({stats.iterations} solve(s))")
    if np.isfinite(stats.position_change_median_m) and stats.position_change_median_m > 3.0 * sigma:
        errors.append(f"it moved the cameras {stats.position_change_median_m:.1f} m (median) against a "
                      f"{sigma:g} m GPS prior (at most 3 sigma)")
    if np.isfinite(stats.block_tilt_change_deg) and stats.block_tilt_change_deg > 3.0 * attitude_sigma_deg:
        errors.append(f"it tilted the whole block by {stats.block_tilt_change_deg:.1f} deg against a "
                      f"{attitude_sigma_deg:g} deg attitude prior (at most 3 sigma)")
    if stats.position_change_max_m > 5.0 * sigma:
        warnings.append(f"some cameras moved up to {stats.position_change_max_m:.1f} m (more than 5 x the "
                        f"{sigma:g} m prior): a wrong GPS fix or wrong tie points")
    if stats.rotation_change_mean_deg > 3.0 * attitude_sigma_deg:
        warnings.append(f"the cameras turned {stats.rotation_change_mean_deg:.1f} deg on average (more than 3 x the "
                        f"{attitude_sigma_deg:g} deg attitude prior)")
    unknowns = 6 * stats.images + 3 * stats.points
    if unknowns and 2 * stats.observations < 1.5 * unknowns:
        warnings.append(f"only {stats.points} tie points ({stats.observations} observations) for {stats.images} "
                        "images: the poses are barely constrained")
    return errors, warnings


class RefinementRejected(InputError):
    """The refined poses are implausible against their priors (`judge_refinement`); the message says why (one
    line; the command line prints it and exits 2, nothing is written)."""


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


def _skew(v: np.ndarray) -> np.ndarray:
    """(N,3) -> (N,3,3) cross-product matrices [v]x."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 0] = -v[..., 2], v[..., 1], v[..., 2]
    out[..., 1, 2], out[..., 2, 0], out[..., 2, 1] = -v[..., 0], -v[..., 1], v[..., 0]
    return out


def _matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """(N,3,3) -> (N,3) rotation vectors (angles below pi, which is all the priors need)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def _registered_image_ids(rec: object) -> list[int]:
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
    image_ids = _registered_image_ids(rec)
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
    from ..database.cameras import camera_from_pycolmap

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
        return np.transpose(_rotvec_to_matrix(w) @ rp_cw, (0, 2, 1)), c, p

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
        wx = _skew(wo)
        j_l = np.eye(3)[None] + a[:, None, None] * wx + b[:, None, None] * (wx @ wx)
        d_p_d_w = -_skew(pc) @ j_l
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

    w0 = _matrix_to_rotvec(np.einsum("nji,nkj->nik", r_wc0, r_prior)) if n_img else np.zeros((0, 3))  # R0_cw Rp_wc
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
        **_pose_changes(r_prior, c_prior, r_wc, c + origin),
    )
    log.info("pose refinement: %d images, %d points, reprojection RMSE %.2f -> %.2f px, poses moved %.2f m / %.2f deg "
             "on average (%.1f s)", n_img, n_pts, stats.reprojection_rmse_before_px, stats.reprojection_rmse_after_px,
             stats.position_change_mean_m, stats.rotation_change_mean_deg, stats.seconds)
    return stats


def refine_poses_with_colmap(
    reconstruction: object,
    prior_poses: Poses,
    position_sigma_m: float = 3.0,
    pixel_sigma_px: float = 2.0,
    outlier_px: float = 4.0,
    rounds: int = 2,
) -> RefinementStats:
    """Refine poses and points of `reconstruction` (changed in place; intrinsics fixed) with COLMAP's pose-prior
    bundle adjustment (`pycolmap.create_pose_prior_bundle_adjuster`, Ceres): reprojection residuals with a Cauchy
    loss at `pixel_sigma_px`, and a Gaussian prior of `position_sigma_m` on every camera centre (the prior
    positions come from `prior_poses`, matched by image name). The priors fix the gauge (position, orientation and
    scale of the block), so the result stays in the GPS frame; the attitude is free and follows from the tie points.
    After the first solve, observations with a reprojection error above `outlier_px` are removed (the wrong tie
    points a prior-pose triangulation cannot tell from the right ones) and the problem is solved again, `rounds`
    times in all. Fast: Seneca (167 images, ~9000 points) takes ~15 s where `refine_poses_with_priors` takes
    ~12 min; use that one when attitude priors matter (few images, weak geometry).
    """
    import pycolmap

    t0 = time.perf_counter()
    rec = reconstruction
    image_ids = _registered_image_ids(rec)
    prior_index = {name: k for k, name in enumerate(prior_poses.names)}
    before_poses = poses_of_reconstruction(rec)
    err0 = _observation_errors(rec)
    # Work near the origin: Ceres' relative tolerances and float math behave better than at UTM magnitudes.
    origin = prior_poses.centers.mean(axis=0)
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(np.eye(3)), -origin))
    priors = []
    for iid in image_ids:
        im = rec.images[iid]
        if im.name not in prior_index:
            continue
        prior = pycolmap.PosePrior(position=prior_poses.centers[prior_index[im.name]] - origin,
                                   position_covariance=np.eye(3) * float(position_sigma_m) ** 2,
                                   coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN)
        prior.corr_data_id = im.data_id
        priors.append(prior)
    options = fixed_camera_ba_options(pycolmap.LossFunctionType.CAUCHY, pixel_sigma_px, refine_poses=True)
    prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
    converged, iterations = False, 0
    log_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(int(log_level), 2)  # Ceres' per-step warnings would flood the console
    try:
        for round_ in range(max(1, int(rounds))):
            if round_:
                _drop_outlier_observations(rec, outlier_px)
            config = pycolmap.BundleAdjustmentConfig()
            for iid in image_ids:
                config.add_image(iid)
            summary = pycolmap.create_pose_prior_bundle_adjuster(options, prior_options, config, priors, rec).solve()
            converged = summary.termination_type == pycolmap.BundleAdjustmentTerminationType.CONVERGENCE
            iterations += 1
        _drop_outlier_observations(rec, outlier_px)
    finally:  # a failed solve must not leave the caller's log level changed nor its model shifted
        pycolmap.logging.minloglevel = log_level
        rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(np.eye(3)), origin))
    rec.update_point_3d_errors()
    err1 = _observation_errors(rec)
    after = poses_of_reconstruction(rec)
    before = before_poses.subset([before_poses.names.index(n) for n in after.names])
    stats = RefinementStats(
        images=len(image_ids), points=rec.num_points3D(), observations=len(err1),
        reprojection_rmse_before_px=float(np.sqrt(np.mean(err0**2))) if len(err0) else float("nan"),
        reprojection_rmse_after_px=float(np.sqrt(np.mean(err1**2))) if len(err1) else float("nan"),
        reprojection_median_before_px=float(np.median(err0)) if len(err0) else float("nan"),
        reprojection_median_after_px=float(np.median(err1)) if len(err1) else float("nan"),
        iterations=iterations, seconds=time.perf_counter() - t0, converged=converged,
        **_pose_changes(before.rotations, before.centers, after.rotations, after.centers),
    )
    log.info("COLMAP pose-prior BA: median reprojection %.2f -> %.2f px, poses moved %.2f m / %.2f deg on average",
             stats.reprojection_median_before_px, stats.reprojection_median_after_px,
             stats.position_change_mean_m, stats.rotation_change_mean_deg)
    return stats


def _point_errors(rec: object, point: object) -> list[tuple[int, int, float]]:
    """(image id, point2D index, reprojection error px; inf behind the camera) of each observation of `point`."""
    out = []
    for el in point.track.elements:
        image = rec.images[el.image_id]
        uv = image.project_point(point.xyz)
        err = np.inf if uv is None else float(np.linalg.norm(np.asarray(uv) - image.points2D[el.point2D_idx].xy))
        out.append((el.image_id, el.point2D_idx, err))
    return out


def _observation_errors(rec: object) -> np.ndarray:
    """Reprojection error (px) of every observation of every 3D point."""
    return np.asarray([e for point in rec.points3D.values() for _, _, e in _point_errors(rec, point)],
                      dtype=np.float64)


def _drop_outlier_observations(rec: object, max_px: float) -> int:
    """Remove observations reprojecting worse than `max_px` (and points left with fewer than 2); returns how many
    observations were removed."""
    removed = 0
    for pid in list(rec.points3D):
        point = rec.points3D[pid]
        bad = [(image_id, idx) for image_id, idx, err in _point_errors(rec, point) if err > max_px]
        if not bad:
            continue
        if point.track.length() - len(bad) < 2:
            removed += point.track.length()
            rec.delete_point3D(pid)
            continue
        for image_id, idx in bad:
            rec.delete_observation(image_id, idx)
            removed += 1
    return removed


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


def _orb_matches(desc_a: np.ndarray, desc_b: np.ndarray, kp_a: np.ndarray, kp_b: np.ndarray,
                 ransac_px: float) -> np.ndarray:
    """Indices (M, 2) of ORB matches between two images that pass Lowe's ratio test and a RANSAC homography
    (the ground is nearly flat, so a homography is the right image-only model; parallax outliers are dropped)."""
    from ..plugin.image_matching import homography_inliers, ratio_matches

    if desc_a is None or desc_b is None or len(desc_a) < 8 or len(desc_b) < 8:
        return np.zeros((0, 2), dtype=int)
    good = ratio_matches(desc_a, desc_b, 0.8)
    if len(good) < 12:
        return np.zeros((0, 2), dtype=int)
    inl = homography_inliers(kp_a[good[:, 0]], kp_b[good[:, 1]], ransac_px)
    if inl is None or inl.sum() < 12:
        return np.zeros((0, 2), dtype=int)
    return good[inl]


def tie_point_reconstruction(
    image_paths: list,
    poses: Poses,
    camera: object,
    max_features: int = 3000,
    neighbour_fraction: float = 0.6,
    ransac_px: float = 6.0,
    min_track_length: int = 3,
    max_neighbours: int = 8,
    min_ray_angle_deg: float = 2.0,
) -> object:
    """A pycolmap Reconstruction of ORB tie points with the given (prior) poses (changed by nothing here).

    Features per image (ORB, `max_features`); matches (ratio test + RANSAC homography at `ransac_px`) between each
    image and the next two, and between any two images whose centres are closer than `neighbour_fraction` x 4 x the
    median spacing of consecutive images (a typical 75% forward overlap puts ~4 spacings in a footprint; at most its
    `max_neighbours` nearest), which links neighbouring flight lines; tracks by union-find (tracks with two features
    in one image are dropped); points by least-squares intersection of the rays from the prior poses, dropped when
    the rays meet under less than `min_ray_angle_deg`.
    `camera` is a sosmatch Camera (any lens model: rays and the model go through it), image order = pose order.
    """
    import cv2
    import pycolmap

    from ..database.cameras import pycolmap_camera
    from ..plugin.image_matching import orb_features

    n = len(poses)
    kps, descs = [], []
    for path in image_paths:
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            from ..plugin.errors import InputError

            raise InputError("cannot read image", path)
        if img.shape[1] != camera.width:
            raise ValueError(f"{path}: image width {img.shape[1]} differs from the camera's {camera.width}")
        features = orb_features(img, max_features)
        kps.append(features.colmap_points)
        descs.append(features.descriptors)
    spacing = np.median(np.linalg.norm(np.diff(poses.centers[:, :2], axis=0), axis=1)) if n > 1 else 1.0
    radius = neighbour_fraction * 4.0 * spacing
    d2 = np.linalg.norm(poses.centers[:, None, :2] - poses.centers[None, :, :2], axis=2)
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 3))}
    # each image with its `max_neighbours` nearest within the radius: enough to tie neighbouring flight lines
    # together, and matching cost stays linear in the number of images (all pairs in the radius: 2x the time)
    # self excluded explicitly: with two images at the same centre (hovering, quantised GPS) a stable argsort can
    # put the other one first, and the pair (i, i) would union features of one image and drop their tracks
    near = np.argsort(np.where(np.eye(n, dtype=bool), np.inf, d2), axis=1, kind="stable")[:, :max_neighbours]
    pairs |= {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in near[i] if i != j and d2[i, j] < radius}
    offsets = np.concatenate([[0], np.cumsum([len(k) for k in kps])])
    parent = np.arange(offsets[-1])

    def find(a: int) -> int:
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    n_pairs_ok = 0
    for i, j in sorted(pairs):
        m = _orb_matches(descs[i], descs[j], kps[i], kps[j], ransac_px)
        if len(m):
            n_pairs_ok += 1
        for a, b in m:
            ra, rb = find(offsets[i] + a), find(offsets[j] + b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(a) for a in range(offsets[-1])])
    img_of = np.repeat(np.arange(n), np.diff(offsets))
    order = np.argsort(roots, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(roots[order])) + 1)
    tracks = [g for g in groups if len(g) >= min_track_length and len(np.unique(img_of[g])) == len(g)]
    log.info("tie points: %d image pairs matched of %d tried, %d tracks of >= %d images", n_pairs_ok, len(pairs),
             len(tracks), min_track_length)

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap_camera(camera, 1))
    used = np.zeros(offsets[-1], dtype=bool)
    for g in tracks:
        used[g] = True
    local_index = np.full(offsets[-1], -1)
    for i in range(n):
        sel = np.flatnonzero(used[offsets[i]:offsets[i + 1]])
        local_index[offsets[i] + sel] = np.arange(len(sel))
        pts = [pycolmap.Point2D(kps[i][s]) for s in sel]
        im = pycolmap.Image(name=poses.names[i], camera_id=1, image_id=i + 1, points2D=pycolmap.Point2DList(pts))
        r_cw = poses.rotations[i].T
        rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), -r_cw @ poses.centers[i]))
    origin = poses.centers.mean(axis=0)
    for g in tracks:
        imgs = img_of[g]
        uv = np.stack([kps[i][a - offsets[i]] for i, a in zip(imgs, g)])
        d_cam = np.concatenate([camera.cam_from_img(uv), np.ones((len(uv), 1))], 1)  # through the lens model
        d = np.einsum("nij,nj->ni", poses.rotations[imgs], d_cam)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        m = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        a_mat = m.sum(0)
        b_vec = np.einsum("nij,nj->i", m, poses.centers[imgs] - origin)
        try:
            x = np.linalg.solve(a_mat, b_vec) + origin
        except np.linalg.LinAlgError:
            continue
        depth = np.einsum("nj,nj->n", x - poses.centers[imgs], poses.rotations[imgs][:, :, 2])
        if np.any(depth <= 0):
            continue
        # Nearly parallel rays leave the depth unconstrained: such points make the bundle adjustment's normal
        # equations indefinite (Ceres: "Matrix not positive definite") and teach the poses nothing.
        if np.degrees(np.arccos(np.clip(np.min(d @ d.T), -1.0, 1.0))) < min_ray_angle_deg:
            continue
        track = pycolmap.Track()
        for i, a in zip(imgs, g):
            track.add_element(int(i) + 1, int(local_index[a]))
        rec.add_point3D(x, track)
    return rec


def refine_poses_from_images(
    image_paths: list,
    poses: Poses,
    camera: object,
    position_sigma_m: float | tuple[float, float, float] = 3.0,
    attitude_sigma_deg: float = 5.0,
    pixel_sigma_px: float = 2.0,
    max_features: int = 2000,  # matching cost grows with its square: 3000 took 80 s of knnMatch on Seneca
    method: str = "colmap",
    accept_implausible: bool = False,
) -> tuple[Poses, RefinementStats]:
    """Refine GPS/telemetry poses BEFORE mapping, with ORB tie points between overlapping images and the pose
    priors (`tie_point_reconstruction`, then `refine_poses_with_colmap` (method "colmap", the default: COLMAP's
    pose-prior bundle adjustment, position priors only, seconds) or `refine_poses_with_priors` (method "scipy":
    position and attitude priors, minutes)). Returns the refined poses (same names and order, same world frame)
    and the statistics. Use it when the poses are far from EKF quality: the mapping's epipolar gate (a few
    pixels) cannot track segments across frames whose poses are 100+ px off.

    The result is judged against the priors (`judge_refinement`): warnings are logged and kept in the stats;
    errors raise RefinementRejected unless `accept_implausible` (then they are logged as warnings)."""
    if method not in ("colmap", "scipy"):
        raise ValueError(f"unknown refinement method {method!r} (colmap or scipy)")
    rec = tie_point_reconstruction(image_paths, poses, camera, max_features)
    if method == "colmap":
        sigma = float(np.max(np.atleast_1d(position_sigma_m)))
        stats = refine_poses_with_colmap(rec, poses, sigma, pixel_sigma_px)
    else:
        stats = refine_poses_with_priors(rec, poses, position_sigma_m, attitude_sigma_deg, pixel_sigma_px)
    refined = poses_of_reconstruction(rec)
    missing = [nm for nm in poses.names if nm not in refined.names]
    if missing:
        raise ValueError(f"{len(missing)} images lost their pose in the refinement (e.g. {missing[0]})")
    order = [refined.names.index(nm) for nm in poses.names]
    errors, warnings = judge_refinement(stats, position_sigma_m, attitude_sigma_deg)
    for w in warnings:
        log.warning("pose refinement: %s", w)
    stats = replace(stats, warnings=tuple(warnings))
    if errors and not accept_implausible:
        before, after = stats.reprojection_median_before_px, stats.reprojection_median_after_px
        raise RefinementRejected("pose refinement rejected: " + "; ".join(errors) + f" (a median reprojection of "
                                 f"{before:.2f} -> {after:.2f} px says nothing about that); map without --refine, "
                                 "or with better priors")
    for e in errors:
        log.warning("pose refinement: %s (accepted on request)", e)
    return refined.subset(order), stats
