"""The SfM block's focal lengths weighed against EXIF's (`weigh_focal_lengths`): two bundle adjustments per camera
(focal length free, and held at the EXIF value) measure how well the images know it (`plugin.focal_prior`), and
where the EXIF prior pulls it away from the images' optimum the block is adjusted again with the combined value."""

from __future__ import annotations

import copy
import logging
import math
from typing import Any

import numpy as np

from ...plugin.focal_prior import FocalEstimate, combine_focal, images_focal_sigma, residual_variance
from ...plugin.geometry import Camera
from ..image_cameras import exif_focal_uncertainty
from ..image_priors import ImagePriors
from ..pose_refinement.with_colmap import observation_errors, position_prior

log = logging.getLogger(__name__)

# Bundle adjustment solves per fit: a second one changed nothing (nu25 deadsea and Seneca: the same focal
# lengths, sigmas and chi-square to 0.01 px / 0.1), so one (Seneca: 5.5 s for its three fits against 6.1 s).
ADJUST_ROUNDS = 1
# The prior's pull is applied only when it moves the focal length by more than this many of the combined
# estimate's sigmas from the images' optimum: a smaller pull is within what the two sources know together, and
# the block (the mapper's optimum) stays as it was, byte for byte (Seneca: 0.005 px against +-0.29 px).
APPLY_SIGMAS = 0.5


def weigh_focal_lengths(rec: Any, exif_cameras: dict[int, tuple[Camera, str]],
                        anchor_sigma_m: float) -> tuple[list[FocalEstimate], bool]:
    """For each camera of `rec` (a georegistered pycolmap Reconstruction) with an EXIF camera in `exif_cameras`
    (camera id -> the EXIF camera and the source of its intrinsics, `exif_focal_priors`): the focal length the
    images alone give and how well (`images_focal_sigma`, from adjustments with it free and held at the EXIF
    value), combined with the EXIF one (`combine_focal`, its uncertainty from `exif_focal_uncertainty`). Where
    the EXIF prior pulls the combination away from the images' optimum (by more than `APPLY_SIGMAS` of its
    sigma), `rec` is adjusted again with it held (changed in place; the second value says whether it was).
    The camera centres are tied to where they are by Gaussian priors of `anchor_sigma_m` (the gauge: the block
    stays in its frame)."""
    estimates, changed = [], False
    for cam_id in sorted(rec.cameras):
        k = int(cam_id)
        if k not in exif_cameras:
            continue
        exif, source = exif_cameras[k]
        if not exif.fx > 0 or not any(im.has_pose and im.camera_id == k for im in rec.images.values()):
            continue
        free = copy.deepcopy(rec)
        f_free, sse_free, n_obs, n_par = _adjusted_misfit(free, k, None, anchor_sigma_m)
        held = copy.deepcopy(rec)
        _, sse_held, _, _ = _adjusted_misfit(held, k, exif.fx, anchor_sigma_m)
        variance = residual_variance(sse_free, n_obs, n_par)
        sigma = images_focal_sigma(f_free, sse_free, exif.fx, sse_held, variance)
        chi2 = (sse_held - sse_free) / variance if variance > 0 else float("nan")
        est = combine_focal(k, exif.fx, exif_focal_uncertainty(exif, source), f_free, sigma, chi2)
        if abs(est.taken_px - est.images_px) > APPLY_SIGMAS * est.taken_sigma_px:
            _adjusted_misfit(rec, k, est.taken_px, anchor_sigma_m)
            changed = True
            log.info("camera %d: the images know the focal length to +-%.1f %% (holding the EXIF one costs "
                     "chi-square %.1f): %.1f px taken (EXIF %.1f, images alone %.1f)", k,
                     100 * sigma / exif.fx if math.isfinite(sigma) else math.inf, chi2, est.taken_px, exif.fx,
                     f_free)
        estimates.append(est)
    return estimates, changed


def exif_focal_priors(priors: ImagePriors) -> dict[int, tuple[Camera, str]]:
    """Camera id of an SfM model (1-based, in the order of `priors.cameras`) -> the EXIF camera and the source of
    its intrinsics, for the cameras whose focal length came from EXIF (not guessed)."""
    sources = priors.summary.get("cameras", [])
    out = {}
    for i, cam in enumerate(priors.cameras):
        source = str(sources[i].get("intrinsics_source", "")) if i < len(sources) else ""
        if "none in EXIF" not in source:
            out[i + 1] = (cam, source)
    return out


def _adjusted_misfit(rec: Any, camera_id: int, focal_px: float | None,
                     anchor_sigma_m: float) -> tuple[float, float, int, int]:
    """Bundle-adjust `rec` in place (poses, points, the camera's distortion; its focal length free when
    `focal_px` is None, else set to it and held; other cameras held), the camera centres tied to their current
    places; returns (focal length, sum of squared reprojection errors px^2, observations, parameters)."""
    import pycolmap

    image_ids = sorted(i for i, im in rec.images.items() if im.has_pose)
    origin = np.mean([rec.images[i].projection_center() for i in image_ids], axis=0)
    # near the origin: Ceres' relative tolerances and float math behave better than at UTM magnitudes
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(np.eye(3)), -origin))
    try:
        camera = rec.cameras[camera_id]
        if focal_px is not None:
            # every focal parameter scaled alike: a camera with fx and fy (PINHOLE, OPENCV) keeps its aspect
            params = np.array(camera.params)
            idx = list(camera.focal_length_idxs())
            params[idx] *= focal_px / params[idx[0]]
            camera.params = params
        priors = [position_prior(rec.images[i].projection_center(), anchor_sigma_m, rec.images[i].data_id)
                  for i in image_ids]
        options = pycolmap.BundleAdjustmentOptions()
        options.refine_focal_length = focal_px is None
        options.refine_principal_point = False
        options.refine_extra_params = True
        options.print_summary = False
        options.ceres.solver_options.num_threads = 1  # the same result on every machine
        config = pycolmap.BundleAdjustmentConfig()
        for iid in image_ids:
            config.add_image(iid)
        for other in rec.cameras:
            if int(other) != camera_id:
                config.set_constant_cam_intrinsics(other)
        level = pycolmap.logging.minloglevel
        pycolmap.logging.minloglevel = max(int(level), 2)
        try:
            for _ in range(ADJUST_ROUNDS):
                pycolmap.create_pose_prior_bundle_adjuster(options, pycolmap.PosePriorBundleAdjustmentOptions(),
                                                           config, priors, rec).solve()
        finally:
            pycolmap.logging.minloglevel = level
    finally:
        rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(np.eye(3)), origin))
    rec.update_point_3d_errors()
    errors = observation_errors(rec)
    errors = errors[np.isfinite(errors)]
    parameters = 3 * rec.num_points3D() + 6 * len(image_ids) + len(rec.cameras[camera_id].params)
    return float(rec.cameras[camera_id].params[0]), float(np.sum(errors**2)), len(errors), parameters
