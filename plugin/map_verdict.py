"""A map's verdict: `judge` turns its quality figures (`plugin.map_quality.MapQuality`) into refusals (the map is
unusable) and warnings (it looks doubtful), with limits and their reasons in `QualityParams`; a warning names the
likelier cause (the images' own figures, the pose check's finding) where it can.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .georegistration import NADIR_SOURCE
from .image_quality import FlightImages, blank_warning, image_causes
from .map_quality import MapQuality
from .params import QualityParams
from .pass_heights import PASS_EVIDENCE_SIGMAS

# a ground tilted beyond this many of that vertical's sigmas is said (`judge`): level ground reads the vertical
# too, and the two readings disagree. Real sites slope 1-2 deg (synthetic and real maps); the nadir sigma is 3 deg,
# so only a ground past 4.5 deg is said. Seneca without GPS altitude (a camera 6.6 deg nose-up, the block 4.8 deg
# off): 5.2 deg, 1.7 sigmas; its reference map's ground 1.5 deg (nu58 D1)
NADIR_GROUND_TILT_SIGMAS = 1.5


@dataclass
class Verdict:
    """`judge`'s result: refusals make the map unusable; warnings say what looks doubtful."""

    refusals: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.refusals


def _likely_cause(poses: str, poses_fit: str, causes: list[str]) -> str:
    """The cause a warning names: the images when they measure poor, the poses otherwise, but never the poses
    alone when the pose check found them fitting (`poses_fit`, its phrase)."""
    if causes:
        short = ", ".join(c.split(":")[0] for c in causes)  # the figures stand in the images' own warning
        return f"more likely the images: {short}" + (f"; {poses_fit}" if poses_fit else "")
    if poses_fit:
        return f"{poses}, though {poses_fit}: poor images?"
    return poses


def _nadir_ground_tilt(q: MapQuality) -> str:
    """A warning when the poses' vertical rests on the nadir assumption alone (`georegistration.NADIR_SOURCE`) and
    the mapped ground tilts more than `NADIR_GROUND_TILT_SIGMAS` of its sigma against it; "" otherwise. Level
    ground is a reading of the vertical too, and neither is measured: the site may slope, or the cameras were
    tilted on average (a fixed-wing's pitch) and the whole block with them. Both are said; nothing is corrected."""
    sigma = q.vertical_sigma_deg
    if q.vertical_source != NADIR_SOURCE or not (np.isfinite(sigma) and sigma > 0) or \
            not (np.isfinite(q.ground_tilt_deg) and q.ground_tilt_deg > NADIR_GROUND_TILT_SIGMAS * sigma):
        return ""
    return (f"the mapped ground tilts {q.ground_tilt_deg:.1f} deg against the poses' vertical, "
            f"{q.ground_tilt_deg / sigma:.1f} x the +-{sigma:.1f} deg of the nadir assumption it rests on (no "
            "attitude tags, no GPS heights): either the site slopes that much, or the cameras looked that far off "
            "straight down on average (a fixed-wing's pitch) and the whole map is tilted with them, positions off "
            f"by about the flying height x tan({q.ground_tilt_deg:.1f} deg)"
            + (f" = {abs(q.flying_height_m) * np.tan(np.radians(q.ground_tilt_deg)):.0f} m"
               if np.isfinite(q.flying_height_m) else "")
            + "; not corrected: give attitude tags (--telemetry) or the GPS altitudes to measure the vertical")


def landmark_views(theta_n: int | None = None) -> str:
    """What a landmark needs, in words: the demo's refusal of too few frames and the map's of no landmarks on too
    few keyframes say it alike (`theta_n`: the value, when known)."""
    return f"a landmark needs more than theta_n{'' if theta_n is None else f' = {theta_n}'} views, one per keyframe"


def judge(q: MapQuality, limits: QualityParams, min_landmarks: int = 1,
          images_flying_height_m: float = float("nan"), poses_fit: str = "",
          images: FlightImages | None = None, contrast: str = "", min_observations: int = 0,
          remedy: str = "") -> Verdict:
    """Refusals and warnings for a map's figures (limits and their reasons: `QualityParams`). `min_landmarks`:
    fewer make no usable map (`sosmatch map` passes association.min_associations + 1: a match needs more than
    theta_S landmarks in common). `images_flying_height_m`: the flying height the pose check's own matches
    triangulate to (NaN: not checked), which the map's must agree with. `poses_fit`: the pose check's phrase
    when it found the poses fitting the images (`pose_check.poses_fit_images`, "" otherwise); `images`: the
    keyframes' image figures (`plugin.image_quality`). With them, warnings about a thin map name the images
    (blank keyframes, noise, blur) rather than the poses. `contrast`: the flight's low contrast as a cause
    (`FlightContrast.cause`, "" when it was normal), said when the map is thin. `min_observations`: the theta_n the
    map was made with (0: unknown); a map of no more keyframes than that can hold no landmark, which is said as the
    cause. `remedy`: what the flight's own figures say would map it better (`params.survey_preset_remedy`), said
    with a thin, empty or refused-as-too-small map (nu58 D5: the refusal blamed the ground and the images only)."""
    tail = f"; {remedy}" if remedy else ""
    v = Verdict()
    causes = image_causes(images, limits.min_image_contrast_to_noise, limits.min_image_sharpness,
                          limits.min_jpeg_quality, limits.max_motion_smear_px)
    blank = blank_warning(images, q.keyframes)
    if blank:
        v.warnings.append(blank)
    if q.landmarks == 0 and 0 < q.keyframes <= min_observations:
        # the cause is certain, whatever the images (nu49: a 5-frame flight refused with no cause named)
        v.refusals.append(f"the map has no landmarks: {landmark_views(min_observations)}, and the flight has "
                          f"{q.keyframes} keyframes (fly more frames, or set triangulation.min_observations lower)")
        return v
    if q.landmarks == 0:
        said = causes + ([contrast] if contrast else [])
        v.refusals.append("the map has no landmarks" + (f" ({'; '.join(said)})" if said else "")
                          + (f" ({blank.split(' (')[0]})" if blank else "") + tail)
        return v
    # a thin map may still match, but the user must know it is thin, and why, before trusting a "no match"
    thin = 0 < q.landmarks_per_keyframe < limits.warn_landmarks_per_keyframe
    said = causes + ([contrast] if contrast and thin else [])
    if said:
        v.warnings.append(f"{'; '.join(said)}: expect a thin map (here {q.landmarks_per_keyframe:.2f} landmarks "
                          f"per keyframe, {q.landmarks} in all){tail}")
    elif thin:
        v.warnings.append(f"a thin map: {q.landmarks_per_keyframe:.2f} landmarks per keyframe, {q.landmarks} in "
                          f"all (normal maps have {limits.warn_landmarks_per_keyframe:g} or more): few distinct "
                          "objects on the ground, or images that do not show them (see the figure)" + tail)
    if q.landmarks < min_landmarks:
        v.refusals.append(f"only {q.landmarks} landmark(s): a map needs at least {min_landmarks} to be matched"
                          + tail)
    if q.landmarks_under_cameras and \
            q.landmarks_above_cameras / q.landmarks_under_cameras > limits.max_share_above_cameras:
        v.refusals.append(f"{q.landmarks_above_cameras} of the {q.landmarks_under_cameras} landmarks under the flight "
                          "path lie above a camera that flew over them (the poses do not fit the images)")
    if np.isfinite(q.block_tilt_deg) and q.block_tilt_deg > limits.max_block_tilt_deg:
        v.refusals.append(f"the block is tilted {q.block_tilt_deg:.0f} deg against gravity: ground and cameras lean "
                          f"together (ground {q.ground_tilt_deg:.0f} deg, view {q.view_tilt_deg:.0f} deg); the "
                          "poses' vertical is wrong")
    if np.isfinite(q.flying_height_m) and q.flying_height_m <= 0:
        v.refusals.append(f"the cameras fly below the ground they see (height {q.flying_height_m:.1f} m)")
    h_map, h_images = q.flying_height_m, images_flying_height_m
    if np.isfinite(h_map) and np.isfinite(h_images) and h_map > 0 and h_images > 0 and \
            max(h_map / h_images, h_images / h_map) > limits.max_height_disagreement:
        v.refusals.append(f"the landmarks put the cameras {h_map:.0f} m above the ground, the images' own matches "
                          f"{h_images:.0f} m (at most {limits.max_height_disagreement:g} x apart): the landmarks are "
                          "triangulated wrong (poses that do not fit the images, or wrong tracks)")
    if np.isfinite(q.height_spread) and q.height_spread > limits.max_height_spread:
        v.refusals.append(f"landmark heights scatter by {q.height_spread:.1f} x the flying height "
                          f"({q.flying_height_m:.0f} m) around their neighbours' ground (at most "
                          f"{limits.max_height_spread:g}): wrong tracks or wrong poses")
    # judged on what the pairs prove (figures made before that bound existed: the ratio itself)
    proven = q.pass_disagreement_low if np.isfinite(q.pass_disagreement_low) else q.pass_disagreement
    if np.isfinite(proven) and proven > limits.max_pass_disagreement:
        offset_limit = limits.max_pass_offset * abs(q.flying_height_m)
        said = (f"landmarks seen from two passes of the flight disagree in height {q.pass_disagreement:.1f} x more "
                f"than neighbours of one pass (at least {proven:.1f} x at {PASS_EVIDENCE_SIGMAS:g} sigma; at most "
                f"{limits.max_pass_disagreement:g}), by {q.pass_offset_m:.1f} m")
        if not np.isfinite(offset_limit) or q.pass_offset_m > offset_limit:
            v.refusals.append(f"{said} (at most {offset_limit:.1f} m, {limits.max_pass_offset:.0%} of the flying "
                              "height): the passes' poses disagree (altitude drift?)")
        else:
            v.warnings.append(f"{said}: " + _likely_cause("the passes' poses differ a little (drifting odometry?)",
                                                           poses_fit, causes))
    offset_limit = limits.max_pass_offset * abs(q.flying_height_m)
    if np.isfinite(q.pass_height_offset_z) and q.pass_height_offset_z > limits.pass_offset_margin and \
            np.isfinite(offset_limit) and q.pass_height_offset_m > offset_limit:
        v.refusals.append(f"two passes of the flight, each triangulating the landmarks both saw, put them "
                          f"{q.pass_height_offset_m:.1f} m apart in height ({q.pass_height_offset_z:.0f} standard "
                          f"errors; at most {offset_limit:.1f} m, {limits.max_pass_offset:.0%} of the flying "
                          "height): the passes' poses disagree in height (altitude drift, tilted or offset heights)")
    nadir_doubt = _nadir_ground_tilt(q)
    if nadir_doubt:
        v.warnings.append(nadir_doubt)
    elif np.isfinite(q.ground_tilt_deg) and q.ground_tilt_deg > limits.warn_ground_tilt_deg and \
            not (np.isfinite(q.block_tilt_deg) and q.block_tilt_deg > limits.max_block_tilt_deg):
        v.warnings.append(f"the ground tilts {q.ground_tilt_deg:.0f} deg under cameras tilted "
                          f"{q.view_tilt_deg:.0f} deg: a steep site, or GPS heights that drift along the flight")
    if np.isfinite(q.flying_height_m) and q.flying_height_m > limits.warn_flying_height_m:
        v.warnings.append(f"the cameras fly {q.flying_height_m:.0f} m above the ground they see (more than "
                          f"{limits.warn_flying_height_m:.0f} m, beyond any mapping flight): are the poses in "
                          "centimetres, millimetres or feet instead of metres?")
    if q.passes_without_landmarks:
        cause = _likely_cause("their poses may not fit their images, e.g. a wrong heading", poses_fit, causes)
        v.warnings.append(f"{q.passes_without_landmarks} of {q.passes} passes of the flight see no landmark at all "
                          f"({cause})")
    if np.isfinite(q.keyframes_with_landmarks) and q.keyframes_with_landmarks < limits.min_keyframes_with_landmarks:
        v.warnings.append(f"only {q.keyframes_with_landmarks:.0%} of the keyframes see a landmark")
    if np.isfinite(q.track_yield) and q.track_yield < limits.min_track_yield:
        cause = _likely_cause("poses or camera doubtful", poses_fit, causes)
        v.warnings.append(f"only {q.track_yield:.0%} of the long tracks triangulated ({cause})")
    return v
