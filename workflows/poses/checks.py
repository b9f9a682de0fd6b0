"""The SfM block against the priors: georegistration (or a local frame), the per-image comparison with the tags and
the plausibility warnings (GPS noise, focal length)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...database.geo_txt import geo_txt_hint
from ...database.xmp_sidecar import sidecars_with_gps
from ...plugin.errors import InputError
from ...plugin.focal_prior import FocalEstimate
from ...plugin.geometry import Camera, Poses
from ...plugin.gps_track import with_quantisation
from ...plugin.multisession import Sim3
from ...plugin.params import SfmParams
from ...plugin.refinement import yaw_matrix
from .. import sfm
from ..image_cameras import EXIF_FOCAL_TOLERANCE, camera_aspect
from ..image_priors import ImagePriors
from .result import _listing

NOMINAL_HEIGHT_M = 100.0

# a registered orientation this far from its tags (and not explained by a contradicting line) is reported
ORIENTATION_WARNING_DEG = 10.0
# the images' focal length and EXIF's this far apart (in sigmas of their difference) contradict each other: beyond
# two, one of them is wrong by more than it admits (one alone would warn on a third of the flights by chance)
FOCAL_DISAGREEMENT_SIGMAS = 2.0


def _transform_model(rec: Any, transform: Sim3) -> None:
    import pycolmap

    rec.transform(pycolmap.Sim3d(transform.scale, pycolmap.Rotation3d(transform.rotation), transform.translation))

def _register(priors: ImagePriors, index: np.ndarray, r_sfm: np.ndarray, c_sfm: np.ndarray, model: sfm.SfmModel,
              nominal_height_m: float, seed: int, sp: SfmParams, warnings: list[str]) -> tuple[Sim3, dict | None, Any]:
    """world_from_sfm: georegistration on GPS when >= 2 registered images have a fix, else a local levelled frame."""
    from ...plugin.georegistration import (
        AIRFRAME_SYSTEMATIC_SIGMA_DEG,
        ATTITUDE_SYSTEMATIC_SIGMA_DEG,
        georegister,
        level_rotation,
        vertical_in_frame,
    )

    tags = priors.attitude_from_tags[index]
    # airframe angles (a camera fixed to the aircraft) know the camera's vertical only as well as its mounting
    airframe = bool(np.any(priors.attitude_kind[index] == "fixed"))
    systematic = AIRFRAME_SYSTEMATIC_SIGMA_DEG if airframe else ATTITUDE_SYSTEMATIC_SIGMA_DEG
    # the GPS as the receiver gave it (its altitude checks the vertical and is measured for drift); the heights
    # to register on are the priors' (RelativeAltitude-based where DJI gives it)
    gps = np.column_stack([priors.positions[index, :2], priors.gps_altitude[index]])
    # (not `priors.heights_consistent`: an RTK fixed altitude is consistent too, and is the GPS altitude itself)
    relative = "RelativeAltitude" in str(priors.summary.get("altitude_source", ""))
    reference = priors.positions[index, 2] if relative else None
    if np.sum(np.all(np.isfinite(gps[:, :2]), axis=1)) >= 2:
        folder = Path(priors.paths[int(index[0])]).parent
        try:
            geo = georegister(c_sfm, r_sfm, gps, priors.rotations[index], tags, priors.times_s[index], reference,
                              seed, systematic, priors.times_known)
        except ValueError as exc:  # (fixes without spread are refused before the work: `refuse_frozen_gps`)
            raise InputError(f"the GPS positions of the registered images cannot georegister them: {exc}",
                             folder) from None
        if geo.refusals:  # unusable poses are not published (the work directory keeps the features and matches)
            raise InputError("; ".join(geo.refusals), folder)
        warnings.extend(geo.warnings)
        # the fit of the block to the GPS: also the map's doubt (`result.registration_warnings` reads the
        # record's georegistration warnings), not only this command's; rounded fixes scatter by their grid too
        # (`image_positions.coarse_fixes`): not the block's fault
        gps_sigma_m = with_quantisation(sp.gps_sigma_m, priors.summary)
        cameras = [priors.cameras[i] for i in sorted(set(priors.camera_index[index].tolist()))]
        doubts = [w for w in (gps_noise_warning(geo.horizontal.sigma_m, gps_sigma_m),
                              camera_frame_offset_warning(geo, c_sfm, r_sfm, gps, gps_sigma_m, cameras)) if w]
        warnings.extend(doubts)
        report = geo.to_dict()
        report["warnings"] = report["warnings"] + doubts
        report["gps_outliers"] = [priors.names[index[geo.gps_indices[k]]]
                                  for k in np.flatnonzero(~geo.horizontal.inliers)]
        return geo.transform, report, geo
    # Local frame: levelled by the priors (tags or the nadir assumption), origin under the cameras' centre.
    vert = vertical_in_frame(r_sfm, priors.rotations[index], tags, tag_systematic_deg=systematic)
    level = level_rotation(vert.up)
    pts = np.array([p.xyz for p in model.reconstruction.points3D.values()]).reshape(-1, 3) @ level.T
    cams = c_sfm @ level.T
    ground = float(np.median(pts[:, 2])) if len(pts) else float(np.median(cams[:, 2])) - 1.0
    height = float(np.median(cams[:, 2]) - ground)
    rel = priors.relative_altitude[index]
    if np.isfinite(rel).all() and np.median(rel) > 0 and height > 0:
        scale, how = float(np.median(rel)) / height, "RelativeAltitude (height above take-off, taken as the ground)"
    else:
        scale = nominal_height_m / height if height > 0 else 1.0
        how = f"nominal: the cameras {nominal_height_m:g} m above the ground (no GPS, no RelativeAltitude)"
    centre = np.r_[np.median(cams[:, :2], axis=0), ground]
    transform = Sim3(level, -scale * centre, scale)
    sidecars = sidecars_with_gps(priors.paths)  # GPS a photo editor kept beside the images
    geo_txt = geo_txt_hint(priors.paths[0].parent)  # OpenDroneMap's positions file beside them (nu58 D4)
    warnings.append(f"no GPS positions: the poses are in a local frame (levelled by the {vert.source}, "
                    f"origin on the ground under the flight, scale {how})" + (f"; {sidecars}" if sidecars else "")
                    + (f"; {geo_txt}" if geo_txt else ""))
    return transform, {"frame": "local", "scale_from": how, "vertical_source": vert.source,
                       "vertical_sigma_deg": vert.sigma_deg}, None

def refuse_frozen_gps(priors: ImagePriors, image_dir: Path) -> None:
    """InputError before any work when the images' GPS fixes all lie at one point (`priors.summary["gps_frozen"]`,
    a receiver repeating its last fix): no georegistration can come from them (rev49 D6: a traceback after the
    whole structure from motion)."""
    if priors.summary.get("gps_frozen"):
        fixed = int(np.sum(np.all(np.isfinite(priors.positions[:, :2]), axis=1)))
        raise InputError(f"the GPS fixes of all {fixed} images that have one lie at one point (a receiver without a "
                         "lock repeats its last fix): no georegistration from them; give the positions in a "
                         "telemetry CSV (--telemetry), or remove the images' GPS tags for poses in a local frame",
                         image_dir)


def lag_corrected(priors: ImagePriors, index: np.ndarray, geo: Any) -> ImagePriors:
    """`priors` with the GPS lag the georegistration corrected (`Georegistration.position_shift`, for the images
    `index`) applied to their positions and GPS altitudes: every later comparison with the GPS (outliers, the
    per-image distances) is made with the positions the registration used."""
    import dataclasses

    shift = None if geo is None else geo.position_shift
    if shift is None:
        return priors
    positions, altitude = priors.positions.copy(), priors.gps_altitude.copy()
    positions[index] += shift
    altitude[index] += shift[:, 2]  # the climb in the lag, whichever height it was measured on
    return dataclasses.replace(priors, positions=positions, gps_altitude=altitude)

def _compare(priors: ImagePriors, index: np.ndarray, poses: Poses, warnings: list[str],
             local_frame: bool = False) -> dict:
    """Registered poses against the GPS and the tags, per image; contradicting flight lines are warnings. In a
    `local_frame` (no GPS to register on) the frame's yaw is arbitrary: the orientations are compared after the
    one turn about the vertical that best brings them onto the tags (`frame_yaw_deg`, in the summary), so only
    what the tags say of the images relative to one another is judged (nu42: every line "contradicted by
    +147 deg" with right tags)."""
    from ...plugin.flight_lines import compare_with_priors, flight_lines, frame_yaw_deg

    gps = priors.positions[index]
    order = np.argsort(priors.times_s[index], kind="stable")
    lines = np.full(len(index), -1, dtype=np.int64)
    lines[order] = flight_lines(poses.centers[order])
    tags = priors.attitude_from_tags[index]
    rotations, turn = poses.rotations, None
    if local_frame and tags.any():
        turn = frame_yaw_deg(poses.rotations[tags], priors.rotations[index][tags])
        rotations = yaw_matrix(math.radians(turn)) @ rotations
    cmp = compare_with_priors(rotations, poses.centers, priors.rotations[index], gps, lines)
    per_image = []
    for k, i in enumerate(index):
        entry = {"name": priors.names[i], "line": int(lines[k]),
                 "gps_distance_m": None if not np.isfinite(cmp.position_m[k]) else float(cmp.position_m[k])}
        if tags[k]:
            entry.update(rotation_to_tags_deg=float(cmp.angle_deg[k]), yaw_to_tags_deg=float(cmp.yaw_deg[k]),
                         tilt_to_tags_deg=float(cmp.tilt_deg[k]), contradicting=bool(cmp.contradicting[k]))
        per_image.append(entry)
    names = [priors.names[i] for i in index]
    flagged = np.zeros(len(index), bool)
    for ln in cmp.lines if tags.any() else []:
        members = np.flatnonzero(lines == ln["line"])
        flagged[members] = True
        warnings.append(f"flight line {ln['line']} ({names[members[0]]} .. {names[members[-1]]}, {ln['images']} "
                        f"images): the attitude tags' yaw contradicts the images by {ln['median_yaw_deg']:+.0f} deg "
                        f"on {ln['contradicting']} of them")
    odd = np.flatnonzero(tags & ~flagged & (cmp.angle_deg > ORIENTATION_WARNING_DEG))
    if len(odd):
        warnings.append(f"{len(odd)} image(s) are oriented more than {ORIENTATION_WARNING_DEG:g} deg away from their "
                        "attitude tags: " + _listing([names[k] for k in odd]))
    summary: dict[str, Any] = {"images": per_image, "contradicting_lines": cmp.lines}
    if turn is not None:
        summary["local_frame_turned_to_tags_deg"] = turn
    if tags.any():
        agree = tags & ~cmp.contradicting
        summary.update(tags_yaw_bias_deg=cmp.yaw_bias_deg,
                       rotation_to_tags_median_deg=float(np.median(cmp.angle_deg[agree])) if agree.any() else None)
    has = np.isfinite(cmp.position_m)
    if has.any():
        summary["gps_distance_median_m"] = float(np.median(cmp.position_m[has]))
        summary["gps_distance_max_m"] = float(np.max(cmp.position_m[has]))
    return summary


def flying_height_m(rec: Any) -> float | None:
    """The cameras' median height above the median landmark of a georegistered model (None without points or
    with the cameras not above them): the depth a focal length error scales."""
    centers = [im.projection_center()[2] for im in rec.images.values() if im.has_pose]
    points = [p.xyz[2] for p in rec.points3D.values()]
    if not centers or not points:
        return None
    height = float(np.median(centers) - np.median(points))
    return height if height > 0 else None


def focal_length_warnings(estimates: list[FocalEstimate], exif_cameras: dict[int, tuple[Camera, str]],
                          cameras: dict[int, Camera], height_m: float | None = None) -> list[str]:
    """A warning per camera whose images and EXIF contradict each other on the focal length: the images' optimum
    and the EXIF value (`weigh_focal_lengths`' `estimates`) more than `FOCAL_DISAGREEMENT_SIGMAS` apart in units
    of what the two know together (`FocalEstimate.disagreement_sigmas`). One of them is then wrong by more than
    it admits and the block's focal length (`cameras`, as adjusted) is a compromise or the images' own; with the
    scale fixed by the GPS every depth scales with it, so the warning names both focal lengths and how far the
    landmarks lie from where each would put them at `height_m`, the cameras' height above them (nu25: +5.7 % at
    ~100 m, landmarks 3.9 m too low and nothing said; nu26 A_wide100: the images at +2.8 % claiming +-0.8 %
    against EXIF's -1.2 %, a compromise that a fixed level on the focal length taken let pass)."""
    out = []
    for est in estimates:
        if est.camera_id not in exif_cameras or est.camera_id not in cameras:
            continue
        if not est.disagreement_sigmas > FOCAL_DISAGREEMENT_SIGMAS:
            continue
        _, source = exif_cameras[est.camera_id]
        f = cameras[est.camera_id].fx
        if est.exif_unchecked:
            out.append(_exif_unchecked_warning(est, source, f, height_m))
            continue
        if est.exif_set_aside:
            out.append(_exif_set_aside_warning(est, source, f, height_m))
            continue
        change = f / est.exif_px - 1.0
        by_images = f / est.images_px - 1.0
        known = est.exif_sigma_px / est.exif_px

        def off(rel: float) -> str:
            where = "low" if rel > 0 else "high"
            return (f"about {abs(rel) * height_m:.1f} m too {where} at the cameras' {height_m:.0f} m above them"
                    if height_m else f"too {where} by {100 * abs(rel):.1f} % of the cameras' height above them")

        out.append(f"camera {est.camera_id}: the images and EXIF contradict each other on the focal length by "
                   f"{est.disagreement_sigmas:.1f} sigmas (the images' {est.images_px:.1f} px +-"
                   f"{100 * est.images_sigma_px / est.exif_px:.1f} %, EXIF's {est.exif_px:.1f} px from "
                   f"{source or 'EXIF'}, known to +-{100 * known:.1f} %); {f:.1f} px was used, {100 * change:+.1f} % "
                   f"off the EXIF one: depths scale with it, so if the EXIF one is right the landmarks lie "
                   f"{off(change)}"
                   + (f", if the images' is, {off(by_images)}" if abs(by_images) > 0.001 else "")
                   + ("; the block may be degenerate (flat ground, nadir views, few lines): heights and tilts "
                      "are suspect" if abs(change) > EXIF_FOCAL_TOLERANCE else ""))
    return out


def _exif_set_aside_warning(est: FocalEstimate, source: str, f: float, height_m: float | None) -> str:
    """The warning for a camera whose EXIF focal length the images contradict so far that it was set aside
    (`FocalEstimate.exif_set_aside`): EXIF's value named as wrong, with the likely cause and what it would have
    done to the heights."""
    at = _height_error(est.exif_px / f - 1.0, height_m)
    return (f"camera {est.camera_id}: EXIF's focal length ({est.exif_px:.1f} px from {source or 'EXIF'}, known to "
            f"+-{100 * est.exif_sigma_px / est.exif_px:.1f} %) does not describe these images: they measure "
            f"{est.images_px:.1f} px +-{100 * est.images_sigma_px / est.images_px:.1f} % "
            f"({100 * (est.images_px / est.exif_px - 1.0):+.1f} %), {est.disagreement_sigmas:.1f} sigmas of the two "
            f"together apart, so the images' {f:.1f} px was used; the files were probably resized or cropped after "
            f"capture (or the tag is another lens's or zoom setting's): with EXIF's value the landmarks would lie "
            f"{at}")


def _height_error(change: float, height_m: float | None) -> str:
    """Where the landmarks lie when the focal length used is `change` (relative) longer than the true one: a
    longer focal length puts the ground farther, lower (at `height_m` of the cameras above it, when known)."""
    where = "low" if change > 0 else "high"
    return (f"about {abs(change) * height_m:.1f} m too {where} at the cameras' {height_m:.0f} m above them"
            if height_m else f"too {where} by {100 * abs(change):.1f} % of the cameras' height above them")


def _exif_unchecked_warning(est: FocalEstimate, source: str, f: float, height_m: float | None) -> str:
    """The warning for a camera of too few images to check its EXIF focal length (`FocalEstimate.exif_unchecked`)
    whose images' optimum lies far from it: EXIF's value was used, and the images' value is named with what it
    would mean for the heights, without calling either wrong (how well a few images know f cannot be measured:
    nu53, 3 frames whose curvature claimed +-1.2 % for a value 13 % off EXIF's right one)."""
    from .focal import MIN_BLOCK_IMAGES, MIN_JACKKNIFE_BLOCKS

    return (f"camera {est.camera_id}: not enough images of this camera to check its EXIF focal length (fewer "
            f"than {MIN_BLOCK_IMAGES * MIN_JACKKNIFE_BLOCKS} registered, too few to measure how well they know it), "
            f"so EXIF's {f:.1f} px ({source or 'EXIF'}) was used; the images alone put it at "
            f"{est.images_px:.1f} px ({100 * (est.images_px / est.exif_px - 1.0):+.1f} %): if theirs is right "
            f"(files resized or cropped after capture without their EXIF, another lens's tag), this camera's "
            f"landmarks lie {_height_error(f / est.images_px - 1.0, height_m)}")


def cropped_frames(cameras: Sequence[Camera]) -> list[str]:
    """The image sizes ("560x480") of `cameras` of no camera's aspect (`image_cameras.camera_aspect`, the list
    `odd_aspect` judges by too): cut after capture, so the centre of the file need not be the optical axis's."""
    return [f"{cam.width}x{cam.height}" for cam in cameras
            if cam.width > 0 and cam.height > 0 and not camera_aspect(cam.width, cam.height)]


def camera_frame_offset_warning(geo: Any, c_sfm: np.ndarray, r_sfm: np.ndarray, gps: np.ndarray,
                                expected_m: float, cameras: Sequence[Camera] = ()) -> str | None:
    """A warning when the GPS positions the georegistration `geo` kept sit off the registered camera centres by
    an offset fixed in the cameras' frame (`plugin.gps_offset`) that is significant (beyond 99.99 % of the
    residuals' scatter) and larger than `expected_m`, the receiver's noise: the reconstruction's geometry, not the
    GPS, is off by more than the GPS is (nu42 crops: the principal point 40 px off, the camera centres 7 m off,
    nothing said). `c_sfm`, `r_sfm`: the SfM centres and sfm_from_cam rotations; `gps`: the receiver's positions
    (N,3) as given to `georegister` (its lag correction is added here). `cameras` whose frame has no sensor's
    aspect (`cropped_frames`) are named as the likely cause."""
    from ...plugin.gps_offset import camera_frame_offset
    from ...plugin.robust_fit import CHI2_2DOF_9999

    idx = geo.gps_indices[geo.horizontal.inliers]
    target = np.asarray(gps, float)[idx, :2]
    if geo.position_shift is not None:
        target = target + geo.position_shift[idx, :2]
    t = geo.transform
    residual = target - t.apply(np.asarray(c_sfm, float)[idx])[:, :2]
    fit = camera_frame_offset(residual, t.rotation @ np.asarray(r_sfm, float)[idx])
    if fit is None or not (fit.chi2 > CHI2_2DOF_9999 and fit.size_m > expected_m):
        return None
    crops = cropped_frames(cameras)
    return (f"the GPS positions sit {fit.size_m:.1f} m off the camera centres in the cameras' own frame "
            f"({fit.right_m:+.1f} m toward the images' right, {fit.top_m:+.1f} m toward their top; "
            f"{math.sqrt(fit.chi2):.0f} times its error, the receiver's noise about {expected_m:g} m), the same "
            f"whichever way the images face: the reconstruction does not fit the positions, and camera centres "
            f"and landmarks may be metres off. A principal point off the image centre does this (the photos "
            f"cropped on one side after capture), as do a GPS lag left uncorrected or an antenna far from the camera"
            + (f"; the images' {', '.join(crops)} is no sensor's aspect: cropped" if crops else ""))


def gps_noise_warning(sigma_m: float, expected_m: float) -> str | None:
    """A warning when the measured GPS noise is far above what a receiver gives (the block or the GPS is wrong)."""
    if math.isfinite(sigma_m) and sigma_m > 3.0 * expected_m:
        return (f"the GPS positions scatter by {sigma_m:.1f} m around the reconstruction (a receiver gives about "
                f"{expected_m:g} m): the reconstruction may be deformed or the GPS poor")
    return None
