"""Pose refinement with COLMAP's pose-prior bundle adjustment (`refine_poses_with_colmap`: position priors, Ceres,
seconds), its outlier pruning, and the poses of a refined reconstruction."""

from __future__ import annotations

import logging
import time

import numpy as np

from ...plugin.geometry import Poses
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
