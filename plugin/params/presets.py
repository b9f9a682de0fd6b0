"""Named parameter presets (hloc-style `confs`) and the scaling of pixel-valued parameters to an image size."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from .tree import Params, params_to_dict, with_overrides

# Height-outlier filter for landmarks from a few collinear views (robust sigmas of the difference to the
# neighbours' height): the survey preset's, measured on Seneca (BENCHMARKS.md, "Seneca end to end"), and what
# `for_flight` switches on where a flight's views lower theta_n.
FEW_VIEWS_HEIGHT_OUTLIER_SIGMAS = 6.0

# Named parameter presets (hloc-style `confs`): dotted overrides applied on top of the paper's defaults, before a
# config file and `--set`. "paper" is the method as published (keyframes every 2 m, EKF poses, 640x480).
PRESETS: dict[str, dict[str, Any]] = {
    # the search as published: id windows, 3D distance consistency, gravity checked after the solve, no prior
    "paper": {"association.consistency": "distance", "association.windows": "id",
              "association.position_prior_m": 0.0, "association.georeference_prior_m": 0.0,
              "association.solver": "clipper",
              # and the front end as published: every track its own landmark, the mean metric size. Three tracking
              # gates of ours stay on (README says so): the point-transfer gate (the paper gates every pair by the
              # epipolar line and the motion gate), the cheirality check and the centroid noise in the motion gate
              "triangulation.size_estimator": "mean", "triangulation.fuse_radius_factor": 0.0,
              "tracking.ground_band_sigmas": 0.0, "association.derive_from_maps": False,
              "association.equal_area_windows": False, "triangulation.min_observations_from_views": False,
              "triangulation.whole_masks_only": False, "tracking.truncation_aware": False},
    # Photogrammetric survey flights: one frame every 30-40 m (55-75 % forward overlap), ~1200 px images, poses
    # from GPS + autopilot refined by `poses-from-exif --refine`. Measured on Seneca (BENCHMARKS.md, "Seneca end
    # to end"). An object is in only 2-3 frames of a flight line, so a landmark needs 3 observations (theta_n = 2)
    # and a track may wait 24 keyframes for the neighbouring line (the point transfer gate, not the motion gate,
    # decides there). The classical backend segments at 400 px, a third of the image, so centroid noise, the
    # epipolar margin and the triangulation sigma scale by ~2-3; segments change more between views 300-500 px
    # apart, so sizes may differ more and the motion gate is wider.
    "survey": {
        "image.reference_size_px": 1200.0,  # tuned on Seneca's 1200x900 frames
        "tracking.epipolar_margin_px": 24.0, "tracking.centroid_sigma_px": 9.0, "tracking.size_tolerance": 0.5,
        "tracking.motion_gate_sigmas": 8.0, "tracking.max_track_age_keyframes": 24,
        # frames 300-550 px apart defeat image-only motion estimation (Seneca: 72 of 165 steps): the ground band
        # gate (on by default, `tracking.ground_band_sigmas`) predicts where a segment reappears from the poses and
        # the ground (184 -> 283 landmarks on Seneca; BENCHMARKS.md, "The ground band")
        "triangulation.min_observations": 2, "triangulation.pixel_sigma_px": 6.0,
        # 3-observation landmarks cannot vote out a bad observation: a tighter cut than the paper's 10 px
        # (Seneca: 7 px -> 194 landmarks at 3.1 px mean, 8 px -> see BENCHMARKS, 10 px -> 256 at 4.2 px)
        "triangulation.max_reprojection_error_px": 8.0,
        # 3 views along one line leave depth free along the epipolar line: wrong tracks land tens to hundreds of
        # metres below the ground at a few px (Seneca: 30 of 237 landmarks > 20 m off; neighbour spread 1.1 m)
        "triangulation.height_outlier_sigmas": FEW_VIEWS_HEIGHT_OUTLIER_SIGMAS,
    },
    # Aerial maps of a whole district (km^2) from coarse imagery (airborne or orthophoto, 1-5 m/px): hundreds of
    # landmarks tens of metres across, of which only ~10 % are segmented alike on two dates (ponds grow and merge,
    # fields change). Association only; measured on NAIP 2009 vs 2015 (BENCHMARKS.md, "Real data").
    "aerial": {
        # theta_WL / theta_SL: a window pair must hold more than theta_S of the ~10 % common landmarks: on NAIP
        # 200-landmark windows (~50 frames of flight) hold up to 18-21, 50-landmark ones at most 8; windows
        # overlapping by half still hold every stretch of flight whole, at a third of the pairs of stride 50
        "association.window_length": 200, "association.window_stride": 100,
        # theta_eps: a landmark is a segment centroid at 2.5 m/px of an object that changed shape: common
        # landmarks are 5-7 m apart horizontally across dates, pairwise distances differ by 5 m (median) to 12 m
        # (90 %), vs ~1 m for the paper's 0.3-0.5 m drone landmarks; sigma keeps the paper's ratio eps / 2
        "association.distance_tolerance_m": 10.0, "association.affinity_sigma_m": 5.0,
        # theta_r: a re-segmented pond's size differs by r = 0.21 (median) to 0.40 (75 %) between dates
        "association.max_size_difference": 0.4,
        # theta_S: with eps 5x wider, chance-consistent sets grow (up to 8 on NAIP windows): accept only > 10
        "association.min_associations": 10,
        # coarse imagery comes georeferenced (orthophotos, airborne GNSS): two dates agree to a few metres, so
        # candidates only within 50 m (10 x a 5 m registration sigma). Applied only when both maps carry one EPSG
        # code (sosmatch match ignores it otherwise); without it the NAIP-like 1100 x 1000 stand-in takes 7.7 s
        # CPU instead of a fraction of a second (BENCHMARKS.md, Association)
        "association.position_prior_m": 50.0,
    },
}


# The pixel-valued parameters that `for_image` scales: lengths by the pixel scale, areas by its square.
PIXEL_LENGTHS = ("tracking.epipolar_margin_px", "tracking.centroid_sigma_px", "triangulation.pixel_sigma_px",
                 "triangulation.max_reprojection_error_px")


PIXEL_AREAS = ("segmentation.min_mask_area_px", "segmentation.classical_min_area_px")


def pixel_scale(params: Params, width: int, height: int) -> float:
    """How much larger than `image.reference_size_px` a width x height image is (>= 1; 1 when scaling is off)."""
    ref = params.image.reference_size_px
    if ref <= 0:
        return 1.0
    return max(1.0, max(int(width), int(height)) / ref)


def for_image(params: Params, width: int, height: int) -> Params:
    """`params` with the pixel-valued parameters (PIXEL_LENGTHS, PIXEL_AREAS) scaled to a width x height image
    (`pixel_scale`); the same object at or below the reference size."""
    scale = pixel_scale(params, width, height)
    if scale == 1.0:
        return params
    data = params_to_dict(params)
    changes: dict[str, Any] = {}
    for dotted in PIXEL_LENGTHS + PIXEL_AREAS:
        section, key = dotted.split(".")
        value = data[section][key]
        if dotted in PIXEL_AREAS:
            changes[dotted] = int(round(value * scale * scale)) if isinstance(value, int) else value * scale * scale
        else:
            changes[dotted] = value * scale
    return with_overrides(params, changes)


# The working size grows at most this many times `classical_max_side`: time and memory per frame stay bounded
# (x4 pixels) whatever the image size; a 40 Mpx frame at 0.3 m/px would otherwise be segmented whole.
MAX_WORK_SIDE_FACTOR = 2


def for_ground_resolution(params: Params, ground_resolution_m: float, width: int, height: int) -> Params:
    """`params` with the classical segmenter's working pixel within [`classical_min_ground_resolution_m`,
    `classical_ground_resolution_m`] of ground where resampling can reach that range.

    `ground_resolution_m`: metres of ground per full-resolution pixel (flying height / focal length). The working
    longer side becomes max(width, height) x ground_resolution_m / bound for the bound the fixed working size
    (`classical_max_side`) crosses, and `classical_min_area_px` (full-resolution pixels) scales so that it keeps
    its number of working pixels: the segmenter's pixel-valued parameters (merge costs, kernels, smallest region)
    then cover the ground they cover at that bound.

    Ceiling (coarser than `classical_ground_resolution_m`): the side grows, at most to the full size and
    MAX_WORK_SIDE_FACTOR x the fixed one. A coarser working pixel merges neighbouring crowns and widens
    boundaries, so the same objects came out larger from higher flights (130 m against 100 m: crowns 4-16 %
    larger; BENCHMARKS.md, "One working pixel, one ground size").

    Floor (finer than `classical_min_ground_resolution_m`): the side shrinks. The Ward merge cost counts working
    pixels and the median and texture kernels span a fixed number of them, so at a finer working pixel a crown's
    lit and shaded parts and its leaf clumps stay apart: a zoom camera at 0.16 m per working pixel mapped one
    6 m crown as 12 landmarks of 0.4-1.3 m (size / (R/2) 0.32 against ~1.05 at 0.31 m; BENCHMARKS.md, "A floor
    under the working pixel"). The floor sits under Seneca's 0.227 m, whose landmarks a coarser pixel cost (at
    0.24 m 11 %, at 0.32 m 40 %), so it is a compromise: at 0.21 m a crown still comes in up to 7 pieces.

    The same object when the backend is not `classical`, the ground resolution is unknown, the fixed size's
    working pixel is already within the bounds (a bound of 0 is off), or the images are coarser than the
    ceiling: no resampling reaches it there, and the fixed size is what such imagery was measured with (the NAIP
    views at 2.5 m/px segmented at their full size instead moved the 2009 / 2015 answer from 2.4 to 5.7 m off)."""
    seg = params.segmentation
    ceiling, floor = seg.classical_ground_resolution_m, seg.classical_min_ground_resolution_m
    if ceiling > 0:
        floor = min(floor, ceiling)  # an inverted pair: the ceiling (the tuned pixel) wins
    gsd = float(ground_resolution_m)
    if seg.backend != "classical" or not (np.isfinite(gsd) and gsd > 0):
        return params
    full = max(int(width), int(height))
    fixed = min(full, seg.classical_max_side)
    working = gsd * full / fixed
    if ceiling > 0 and ceiling < working and gsd <= ceiling:
        side = min(full, MAX_WORK_SIDE_FACTOR * fixed, int(np.ceil(full * gsd / ceiling - 1e-9)))
    elif floor > 0 and working < floor:
        side = max(1, int(np.floor(full * gsd / floor + 1e-9)))  # the largest side at or above the floor
    else:
        return params
    if side == fixed:
        return params
    area = int(round(seg.classical_min_area_px * (fixed / side) ** 2))
    return with_overrides(params, {"segmentation.classical_max_side": side, "segmentation.classical_min_area_px": area})


def preset_params(name: str) -> Params:
    """The named preset (see PRESETS) as parameters; an unknown name is an InputError listing the known ones."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r} (known: {', '.join(sorted(PRESETS))})")
    return with_overrides(Params(), PRESETS[name])


# The fewest observations below which theta_n is never lowered (theta_n >= 2: three views, the fewest in which one
# bad observation shows; the survey preset's measured choice on Seneca, where an object is in 2-3 frames of a line).
MIN_THETA_N = 2


def for_flight(params: Params, views_per_pass: float) -> Params:
    """`params` with theta_n (`triangulation.min_observations`) at most half of `views_per_pass`, the keyframes
    that see a ground point on one pass of the flight (`plugin.motion.views_per_pass`), and at least MIN_THETA_N
    (never raised); the same object when `triangulation.min_observations_from_views` is off or the views are
    unknown (NaN).

    Where theta_n is lowered, the height-outlier filter is switched on too (at FEW_VIEWS_HEIGHT_OUTLIER_SIGMAS,
    unless set): a landmark from a few views along one straight line can be a wrong track whose depth those views
    do not fix. Seneca mapped with the defaults (2.4 views per pass, theta_n 2) kept landmarks 100-1100 m below
    the ground and was accepted with warnings; the survey preset has filtered them since it was measured there."""
    tri = params.triangulation
    if not tri.min_observations_from_views or not views_per_pass == views_per_pass:
        return params
    theta_n = max(MIN_THETA_N, int(views_per_pass // 2))
    if theta_n >= tri.min_observations:
        return params
    changes: dict[str, Any] = {"triangulation.min_observations": theta_n}
    if tri.height_outlier_sigmas <= 0:
        changes["triangulation.height_outlier_sigmas"] = FEW_VIEWS_HEIGHT_OUTLIER_SIGMAS
    return with_overrides(params, changes)


# The survey preset's regime, measured: an object in 2-3 keyframes of a pass (Seneca 2.4: the defaults map 5
# landmarks, the preset 58; nu58 D5). The defaults still map flights of 5 and more (40 m synthetic flights, 5.3:
# 194 landmarks; BENCHMARKS.md "40 m flights map poorly"), so the remedy is named below 4 only.
SURVEY_VIEWS_PER_PASS = 4.0
# the survey preset's own tracking settings, which neither `for_image` nor `for_flight` changes: a map made with
# all of them is a survey-preset map whatever else was set
_SURVEY_TRACKING = ("tracking.size_tolerance", "tracking.motion_gate_sigmas", "tracking.max_track_age_keyframes")


def survey_preset_remedy(params: Params, views_per_pass: float, spacing_m: float, flying_height_m: float) -> str:
    """The clause naming `--preset survey` for a thin or refused map, from what the flight measured: an object in
    fewer than SURVEY_VIEWS_PER_PASS keyframes of a pass (`plugin.motion.views_per_pass`), frames `spacing_m`
    apart (median keyframe step) at `flying_height_m` above the ground; "" when the flight sees objects more often,
    the views are unknown (NaN), or `params` already hold the survey preset's tracking settings."""
    if not views_per_pass < SURVEY_VIEWS_PER_PASS:
        return ""
    survey = PRESETS["survey"]
    if all(getattr(getattr(params, key.split(".")[0]), key.split(".")[1]) == survey[key] for key in _SURVEY_TRACKING):
        return ""
    where = ", ".join(f for f in (f"frames {spacing_m:.0f} m apart" if np.isfinite(spacing_m) else "",
                                  f"{flying_height_m:.0f} m above the ground" if np.isfinite(flying_height_m) else "")
                      if f)
    return (f"an object is in {views_per_pass:.1f} keyframes of a pass" + (f" ({where})" if where else "")
            + ": the kind of flight the survey preset is made for (an object in 2-3 frames of a line); try "
            "--preset survey")
