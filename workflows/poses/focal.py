"""The SfM block's focal lengths weighed against EXIF's (`weigh_focal_lengths`): two bundle adjustments per camera
(focal length free, and held at the EXIF value) and, where it can matter, a jackknife of the free one over
contiguous blocks of the flight measure how well the images know it (`plugin.focal_prior`), and where the EXIF
prior pulls it away from the images' optimum the block is adjusted again with the combined value."""

from __future__ import annotations

import copy
import logging
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...plugin.focal_prior import (
    FocalEstimate,
    combine_focal,
    contiguous_blocks,
    images_focal_sigma,
    residual_variance,
)
from ...plugin.geometry import Camera
from ...plugin.robust_fit import jackknife_sigma
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
# Contiguous stretches of the flight (capture order) left out in turn by the jackknife of the free focal length:
# one extra bundle adjustment each. Stretches, not flight lines: nu32's and nu26's flights have 2-4 lines, too
# few for a scatter (1-3 degrees of freedom), and the errors are correlated along a line as well as between
# lines. Six leave 5 degrees of freedom (the sigma known to ~30 %) at 6 fits per camera.
JACKKNIFE_BLOCKS = 6
# The fewest images of a block: with fewer, a block is not a stretch of flight whose correlated errors could show
MIN_BLOCK_IMAGES = 3
# The fewest blocks a scatter is measured over. A camera of fewer images than this many blocks has no honest
# sigma for its focal length (the curvature's understates it several times), so its EXIF value is held and
# only checked loosely (rev23: 8 images, EXIF 250 px against the images' 225 +- 2 px: then 250 taken and nothing
# said, now said; nu53: 3 and 1 images whose curvature's +-1.2 % and +-32 % set EXIF's right value aside)
MIN_JACKKNIFE_BLOCKS = 3


def jackknife_blocks(images: int) -> int:
    """The contiguous stretches a camera of `images` registered images is split into for the jackknife of its
    focal length (`JACKKNIFE_BLOCKS`, fewer where a stretch would hold fewer than `MIN_BLOCK_IMAGES`)."""
    return min(JACKKNIFE_BLOCKS, int(images) // MIN_BLOCK_IMAGES)


def weigh_focal_lengths(rec: Any, exif_cameras: dict[int, tuple[Camera, str]], anchor_sigma_m: float,
                        order: Sequence[str] | None = None) -> tuple[list[FocalEstimate], bool]:
    """For each camera of `rec` (a georegistered pycolmap Reconstruction) with an EXIF camera in `exif_cameras`
    (camera id -> the EXIF camera and the source of its intrinsics, `exif_focal_priors`): the focal length the
    images alone give and how well (`images_focal_sigma`, from adjustments with it free and held at the EXIF
    value; and, unless the images' optimum lies so near the EXIF value that no sigma of theirs could move the
    block, the larger of that and the jackknife over `JACKKNIFE_BLOCKS` contiguous stretches of the flight in
    `order`, the image names in capture order, by name when None), combined with the EXIF one
    (`combine_focal`, its uncertainty from `exif_focal_uncertainty`); a camera of too few images for that
    jackknife (`MIN_JACKKNIFE_BLOCKS`) holds the EXIF value (`FocalEstimate.exif_unchecked`). Where
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
        exif_rel = exif_focal_uncertainty(exif, source)
        blocks_sigma, blocks = math.nan, 0
        n_images = sum(1 for im in free.images.values() if im.has_pose and im.camera_id == k)
        checkable = jackknife_blocks(n_images) >= MIN_JACKKNIFE_BLOCKS
        # the pull can exceed APPLY_SIGMAS of the taken sigma only where the images' optimum lies beyond that
        # many of EXIF's own sigmas from it (the limit as the images' sigma grows): nearer, the jackknife could
        # not change the block and is not run (B_nar60, H_high: 27-60 s of CPU saved)
        if abs(f_free - exif.fx) > APPLY_SIGMAS * exif_rel * exif.fx and math.isfinite(sigma):
            if checkable:
                blocks_sigma, blocks = _blocks_focal_sigma(free, k, order, anchor_sigma_m)
            else:
                log.info("camera %d: %d images, too few for a jackknife over stretches of the flight: how well "
                         "they know the focal length is unknown, EXIF's %.1f px held (the images alone %.1f)",
                         k, n_images, exif.fx, f_free)
        est = combine_focal(k, exif.fx, exif_rel, f_free, sigma, chi2, blocks_sigma, blocks, checkable)
        adjusted = abs(est.taken_px - est.images_px) > APPLY_SIGMAS * est.taken_sigma_px
        if adjusted:
            # a few images held at an EXIF value far from their own optimum must move in depth (their distance
            # to the ground traded against f: nu53's one 12000 px frame 45 m low at 2299 px for EXIF's 8326);
            # tied to where SfM put them they tilted the whole block 4 deg instead. The other cameras' images
            # keep the gauge; a camera that is the whole block keeps its ties.
            loose = est.exif_unchecked and any(im.has_pose and im.camera_id != k for im in rec.images.values())
            before = _attitudes(rec)
            _adjusted_misfit(rec, k, est.taken_px, anchor_sigma_m, untied=loose)
            _restore_attitude(rec, before)
            changed = True
        if adjusted and not est.exif_unchecked:  # said above, and in the warning
            log.info("camera %d: the images know the focal length to +-%.1f %% (the misfit's curvature: +-%.1f %%, "
                     "holding the EXIF one costs chi-square %.1f): %.1f px taken (EXIF %.1f, images alone %.1f)",
                     k, 100 * est.images_sigma_px / exif.fx if math.isfinite(est.images_sigma_px) else math.inf,
                     100 * sigma / exif.fx if math.isfinite(sigma) else math.inf, chi2, est.taken_px, exif.fx,
                     f_free)
        estimates.append(est)
    return estimates, changed


def _attitudes(rec: Any) -> dict[int, np.ndarray]:
    """world_from_camera rotations of the registered images of a pycolmap Reconstruction, by image id."""
    return {int(i): np.asarray(im.cam_from_world().rotation.matrix()).T
            for i, im in rec.images.items() if im.has_pose}


def _restore_attitude(rec: Any, before: dict[int, np.ndarray]) -> None:
    """Turn `rec` back by the common rotation an adjustment gave its images (the chordal mean of R_after
    R_before^T), about the camera centres' centroid. The centre ties hold the gauge of a block but not a single
    line's roll about itself: a corridor's held-focal adjustment turned it 2.7 deg off the vertical the
    georegistration had set (rev49 D1, s_line); a focal length moves the depths, never the block's attitude."""
    import pycolmap

    ids = [i for i in before if rec.images[i].has_pose]
    if not ids:
        return
    after = _attitudes(rec)
    u, _, vt = np.linalg.svd(sum(after[i] @ before[i].T for i in ids))
    turn = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    centre = np.mean([np.asarray(rec.images[i].projection_center()) for i in ids], axis=0)
    back = turn.T
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(back), centre - back @ centre))


def _blocks_focal_sigma(free: Any, camera_id: int, order: Sequence[str] | None,
                        anchor_sigma_m: float) -> tuple[float, int]:
    """The jackknife's sigma (px) of camera `camera_id`'s free focal length over contiguous stretches of the
    flight, and their number: `free` (adjusted with f free; not changed) adjusted again with each stretch's
    images left out (their frames deregistered: points seen by fewer than two others go with them). NaN (not run)
    where the flight is too short for `MIN_JACKKNIFE_BLOCKS` stretches of `MIN_BLOCK_IMAGES`."""
    images = [im for im in free.images.values() if im.has_pose and im.camera_id == camera_id]
    rank = {n: i for i, n in enumerate(order)} if order is not None else {}
    images.sort(key=lambda im: (rank.get(im.name, len(rank)), im.name))
    count = jackknife_blocks(len(images))
    if count < MIN_JACKKNIFE_BLOCKS:
        return math.nan, count
    block = contiguous_blocks(len(images), count)
    values = []
    for b in range(count):
        rec = copy.deepcopy(free)
        for im, m in zip(images, block):
            if m == b:
                rec.deregister_frame(im.frame_id)
        values.append(_adjusted_misfit(rec, camera_id, None, anchor_sigma_m)[0])
    return jackknife_sigma(values), count


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


def _adjusted_misfit(rec: Any, camera_id: int, focal_px: float | None, anchor_sigma_m: float,
                     untied: bool = False) -> tuple[float, float, int, int]:
    """Bundle-adjust `rec` in place (poses, points, the camera's distortion; its focal length free when
    `focal_px` is None, else set to it and held; other cameras held), the camera centres tied to their current
    places (`untied`: but those of camera `camera_id`'s images); returns (focal length, sum of squared
    reprojection errors px^2, observations, parameters)."""
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
                  for i in image_ids if not (untied and rec.images[i].camera_id == camera_id)]
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
