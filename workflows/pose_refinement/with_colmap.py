"""Pose refinement with COLMAP's pose-prior bundle adjustment (`refine_poses_with_colmap`: position priors, Ceres,
seconds), its outlier pruning, and the poses of a refined reconstruction."""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ...plugin.geometry import Poses, rotvec_to_matrix, skew
from ...plugin.georegistration import NADIR_ASSUMPTION_SIGMA_DEG
from ..triangulation import fixed_camera_ba_options
from .judge import RefinementStats, pose_changes
from .with_priors import registered_image_ids

log = logging.getLogger(__name__)


def refine_poses_with_colmap(
    reconstruction: object,
    prior_poses: Poses,
    position_sigma_m: float = 3.0,
    pixel_sigma_px: float = 2.0,
    outlier_px: float = 4.0,
    rounds: int = 2,
    attitude_sigma_deg: float = 5.0,
) -> RefinementStats:
    """Refine poses and points of `reconstruction` (changed in place; intrinsics fixed) with COLMAP's pose-prior
    bundle adjustment (`pycolmap.create_pose_prior_bundle_adjuster`, Ceres): reprojection residuals with a Cauchy
    loss at `pixel_sigma_px`, and a Gaussian prior of `position_sigma_m` on every camera centre (the prior
    positions come from `prior_poses`, matched by image name). The priors fix the gauge (position, orientation and
    scale of the block), so the result stays in the GPS frame; the attitude is free and follows from the tie points.
    After the first solve, observations with a reprojection error above `outlier_px` are removed (the wrong tie
    points a prior-pose triangulation cannot tell from the right ones) and the problem is solved again, `rounds`
    times in all. Position priors leave the roll of the block about the axis of its track free when the track is
    (nearly) one straight line: that one rotation is set from the prior attitudes (`level_free_roll`), weighted
    against what the positions say of it (`attitude_sigma_deg`). Fast: Seneca (167 images, ~9000 points) takes
    ~15 s where `refine_poses_with_priors` takes ~12 min; use that one when attitude priors matter (few images,
    weak geometry).
    """
    import pycolmap

    t0 = time.perf_counter()
    rec = reconstruction
    image_ids = registered_image_ids(rec)
    prior_index = {name: k for k, name in enumerate(prior_poses.names)}
    before_poses = poses_of_reconstruction(rec)
    err0 = observation_errors(rec)
    # Work near the origin: Ceres' relative tolerances and float math behave better than at UTM magnitudes.
    origin = prior_poses.centers.mean(axis=0)
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(np.eye(3)), -origin))
    priors = []
    for iid in image_ids:
        im = rec.images[iid]
        if im.name not in prior_index:
            continue
        priors.append(position_prior(prior_poses.centers[prior_index[im.name]] - origin, position_sigma_m,
                                     im.data_id))
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
    level_free_roll(rec, prior_poses, position_sigma_m, attitude_sigma_deg)
    rec.update_point_3d_errors()
    err1 = observation_errors(rec)
    after = poses_of_reconstruction(rec)
    before = before_poses.subset([before_poses.names.index(n) for n in after.names])
    stats = RefinementStats(
        images=len(image_ids), points=rec.num_points3D(), observations=len(err1),
        reprojection_rmse_before_px=float(np.sqrt(np.mean(err0**2))) if len(err0) else float("nan"),
        reprojection_rmse_after_px=float(np.sqrt(np.mean(err1**2))) if len(err1) else float("nan"),
        reprojection_median_before_px=float(np.median(err0)) if len(err0) else float("nan"),
        reprojection_median_after_px=float(np.median(err1)) if len(err1) else float("nan"),
        iterations=iterations, seconds=time.perf_counter() - t0, converged=converged,
        **pose_changes(before.rotations, before.centers, after.rotations, after.centers),
    )
    log.info("COLMAP pose-prior BA: median reprojection %.2f -> %.2f px, poses moved %.2f m / %.2f deg on average",
             stats.reprojection_median_before_px, stats.reprojection_median_after_px,
             stats.position_change_mean_m, stats.rotation_change_mean_deg)
    return stats


# Prior centres spread less than this along their main axis (the largest singular value of their offsets) are one
# place: the axis the SVD returns is arbitrary (numerical noise), and turning the block about it corrects nothing.
HOVER_SPREAD_M = 0.01


def free_roll_correction(prior_centers: np.ndarray, prior_rotations: np.ndarray, rotations: np.ndarray,
                         position_sigma_m: float, attitude_sigma_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(axis, point on it, angle in radians) of the rotation about the main axis of the prior camera centres that
    brings the adjusted block's orientations (`rotations`, world_from_camera) towards the prior ones.

    Position priors constrain a rotation of the block by phi about an axis through their centroid only through the
    centres' distances d_i from that axis (information sum d_i^2 / sigma_pos^2): about the main axis of a single
    straight line, nothing, so the bundle adjustment may leave the block rolled by any angle (a straight synthetic
    line came back turned 89.5 deg, every camera looking sideways, at 0.42 px). The prior attitudes say how the
    block should be rolled (phi_att, the least-squares rotation about the axis, from the chordal mean) with
    information 1 / (sigma_att^2 / n + sigma_systematic^2); the adjusted block is at the positions' optimum
    (phi = 0), so the combined estimate is phi_att weighted by the attitudes' share of the information. A block
    spread across its axis (a lawnmower flight: d_i of tens of metres) gets ~0; a straight line gets phi_att;
    centres at one place (a hover: no main axis, HOVER_SPREAD_M) get 0."""
    c = prior_centers.mean(axis=0)
    offsets = prior_centers - c
    _, spread, vt = np.linalg.svd(offsets, full_matrices=False)
    axis = vt[0]
    if spread[0] < HOVER_SPREAD_M:  # one place (hovering): no axis, the block's turn about any is unconstrained
        return axis, c, 0.0
    d2 = np.sum(offsets**2, axis=1) - (offsets @ axis) ** 2
    info_positions = float(np.sum(d2)) / float(position_sigma_m) ** 2
    # the attitudes' errors are partly shared by every image (the level-nadir assumption without tags, a gimbal's
    # or airframe's mounting with them), and averaging does not remove that part
    block_sigma_deg = math.hypot(float(attitude_sigma_deg) / math.sqrt(len(rotations)), NADIR_ASSUMPTION_SIGMA_DEG)
    info_attitudes = 1.0 / math.radians(block_sigma_deg) ** 2
    m = np.einsum("nij,nkj->ik", rotations, prior_rotations)  # sum of R_adjusted R_prior^T
    cross = skew(axis)
    # tr(Q M) for Q the rotation by phi about the axis: cos(phi) (tr M - a^T M a) + sin(phi) tr([a]x M) + a^T M a
    phi_att = math.atan2(float(np.trace(cross @ m)), float(np.trace(m) - axis @ m @ axis))
    return axis, c, phi_att * info_attitudes / (info_attitudes + info_positions)


def position_prior(position: np.ndarray, sigma_m: float, data_id: object) -> object:
    """A pycolmap PosePrior on an image's centre alone (Cartesian, isotropic `sigma_m`), for the image whose
    `data_id` it is: the gauge of a pose-prior bundle adjustment."""
    import pycolmap

    prior = pycolmap.PosePrior(position=np.asarray(position, np.float64),
                               position_covariance=np.eye(3) * float(sigma_m) ** 2,
                               coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN)
    prior.corr_data_id = data_id
    return prior


def level_free_roll(rec: object, prior_poses: Poses, position_sigma_m: float, attitude_sigma_deg: float) -> float:
    """Turn the whole reconstruction `rec` (in place: cameras and points, so every reprojection stays) about the
    main axis of the prior centres by `free_roll_correction`; returns the angle in degrees."""
    import pycolmap

    refined = poses_of_reconstruction(rec)
    prior_index = {name: k for k, name in enumerate(prior_poses.names)}
    held = {im.name for im in rec.images.values() if im.has_pose and im.num_points3D > 0}
    both = [k for k, name in enumerate(refined.names) if name in prior_index and name in held]
    if len(both) < 2:
        return 0.0
    prior = prior_poses.subset([prior_index[refined.names[k]] for k in both])
    axis, point, phi = free_roll_correction(prior.centers, prior.rotations, refined.rotations[both],
                                            position_sigma_m, attitude_sigma_deg)
    if abs(phi) < 1e-9:
        return 0.0
    turn = rotvec_to_matrix((phi * axis)[None])[0]
    # images without a tie point are not part of the block the adjustment solved: they keep their priors
    apart = {}
    for im in rec.images.values():
        if im.has_pose and im.num_points3D == 0:
            pose = rec.frames[im.frame_id].rig_from_world
            apart[im.frame_id] = (np.array(pose.rotation.matrix()), np.array(pose.translation))
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(turn), point - turn @ point))
    for frame_id, (r_cw, t_cw) in apart.items():
        rec.frames[frame_id].rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), t_cw)
    if abs(math.degrees(phi)) > 1.0:
        log.info("the camera positions leave the block's roll about its track free (a straight line): rolled by "
                 "%.1f deg to the prior attitudes", math.degrees(phi))
    return math.degrees(phi)


def point_errors(rec: object, point: object) -> list[tuple[int, int, float]]:
    """(image id, point2D index, reprojection error px; inf behind the camera) of each observation of `point`."""
    out = []
    for el in point.track.elements:
        image = rec.images[el.image_id]
        uv = image.project_point(point.xyz)
        err = np.inf if uv is None else float(np.linalg.norm(np.asarray(uv) - image.points2D[el.point2D_idx].xy))
        out.append((el.image_id, el.point2D_idx, err))
    return out


def observation_errors(rec: object) -> np.ndarray:
    """Reprojection error (px) of every observation of every 3D point."""
    return np.asarray([e for point in rec.points3D.values() for _, _, e in point_errors(rec, point)],
                      dtype=np.float64)


def _drop_outlier_observations(rec: object, max_px: float) -> int:
    """Remove observations reprojecting worse than `max_px` (and points left with fewer than 2); returns how many
    observations were removed."""
    removed = 0
    for pid in list(rec.points3D):
        point = rec.points3D[pid]
        bad = [(image_id, idx) for image_id, idx, err in point_errors(rec, point) if err > max_px]
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
