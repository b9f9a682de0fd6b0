"""The settings' registry (plugin/params/identity.ADDED) cannot be forgotten: a setting added to Params changes the
identity of every output unless it is registered with its neutral value (nu36: every earlier output refused after an
upgrade)."""

from __future__ import annotations

import dataclasses
import typing

from sosmatch.plugin.params import ADDED, Params

# Every setting of Params when the registry was made (ac8cd72, 2026-12-06; section -> names, "" the top level).
# Frozen: a setting added later goes into ADDED, never here; the registered ones are in both.
SETTINGS_AT_REGISTRY = {
    "image": ("reference_size_px",),
    "keyframes": ("interval_m",),
    "segmentation": (
        "backend", "min_mask_area_px", "max_sift_per_mask", "sift_max_side", "sift_max_keypoints",
        "sift_contrast_threshold", "contrast_reference", "classical_max_side", "classical_ground_resolution_m",
        "classical_min_ground_resolution_m", "classical_median_ksize", "classical_smooth_sigma_color",
        "classical_flat_percentile", "classical_minima_depth", "classical_merge_cost", "classical_merge_levels",
        "classical_merge_level_factor", "classical_edge_weight", "classical_dedup_iou", "classical_max_area_frac",
        "classical_min_area_px", "classical_max_elongation", "classical_min_fill", "classical_min_contrast",
        "classical_split_solidity", "classical_lightness_weight", "classical_texture_weight",
        "classical_texture_window", "classical_chroma_weight", "classical_fragment_ratio",
        "classical_fragment_parent_fill", "sam_encoder", "sam_decoder", "sam_points_per_side", "sam_points_per_batch",
        "sam_pred_iou_thresh", "sam_stability_score_thresh", "sam_stability_score_offset", "sam_box_nms_thresh",
        "sam_max_area_frac", "sam_threads",
    ),
    "tracking": (
        "max_track_age_keyframes", "epipolar_margin_px", "motion_gate_sigmas", "min_score", "size_tolerance",
        "sift_ratio", "centroid_sigma_px", "cheirality_check", "point_transfer_gate", "point_gate_min_ray_angle_deg",
        "ground_band_sigmas",
    ),
    "triangulation": (
        "min_observations", "min_observations_from_views", "pixel_sigma_px", "max_reprojection_error_px",
        "min_triangulation_angle_deg", "duplicate_radius_factor", "height_outlier_sigmas", "height_outlier_neighbours",
        "size_estimator", "fuse_radius_factor", "fuse_size_tolerance", "min_piece_observations", "whole_masks_only",
    ),
    "association": (
        "window_length", "window_stride", "equal_area_windows", "window_factor_a", "window_factor_b",
        "max_size_difference", "distance_tolerance_m", "affinity_sigma_m", "max_gravity_angle_deg", "min_associations",
        "transform", "consistency", "gravity_tilt_deg", "height_tolerance_factor", "yaw_slice_deg", "windows",
        "position_prior_m", "georeference_prior_m", "solver", "derive_from_maps",
    ),
    "verification": (
        "enabled", "dof", "final_dof", "tilt_prior_deg", "min_ratio", "z_weight", "max_candidates", "chance_starts",
        "false_alarm", "max_size_difference", "coarse_factor",
    ),
    "changes": (
        "min_views", "tolerance_factor", "z_weight", "max_size_difference", "nest_max_ratio", "part_max_ratio",
        "segment_evidence_p", "probe_count", "probe_radius_factor", "presence_bandwidth", "min_confidence",
        "min_jpeg_quality", "surface_evidence", "surface_views", "surface_overrules_links", "object_height_p",
        "object_height_ring", "unmapped_objects", "unmapped_max_error_px", "unmapped_pixel_sigma_px",
        "max_depth_sigmas",
    ),
    "quality": (
        "max_share_above_cameras", "max_block_tilt_deg", "max_pass_disagreement", "max_pass_offset",
        "pass_offset_margin", "max_height_spread", "max_height_disagreement", "warn_ground_tilt_deg",
        "warn_flying_height_m", "min_keyframes_with_landmarks", "min_track_yield", "min_image_contrast_to_noise",
        "min_image_sharpness", "min_jpeg_quality", "refuse",
    ),
    "pose_check": (
        "enabled", "max_pairs", "max_image_side_px", "max_features", "ratio", "ransac_px", "min_inliers", "noise_px",
        "wide_shift", "max_wide_offset", "cross_radius", "min_pairs", "min_pair_share", "max_epipolar_gate_fraction",
        "warn_epipolar_gate_fraction", "warn_pair_gate_fraction", "max_height_drift", "warn_height_drift",
        "max_height_tilt_deg", "warn_height_tilt_deg", "max_attitude_bias_deg", "warn_attitude_bias_deg",
        "max_condition_index", "systematic_significance", "min_systematic_share", "max_gps_scale_error",
        "warn_gps_offset_m", "min_gps_agreement",
    ),
    "sfm": (
        "max_image_size_px", "max_features", "first_octave", "peak_threshold", "camera_model", "neighbours",
        "sequential", "exhaustive_up_to", "sequential_without_gps", "mapper", "global_when_incomplete",
        "use_gps_priors", "gps_sigma_m", "min_registered_fraction",
    ),
    "": ("seed",),
}


def _dotted_settings(cls: type = Params, prefix: str = "") -> list[str]:
    """The dotted name of every setting of `cls`, recursively through its sections."""
    hints = typing.get_type_hints(cls)
    out: list[str] = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            out += _dotted_settings(hints[f.name], f"{prefix}{f.name}.")
        else:
            out.append(f"{prefix}{f.name}")
    return out


def _frozen() -> set[str]:
    return {f"{section}.{name}" if section else name for section, names in SETTINGS_AT_REGISTRY.items()
            for name in names}


def test_every_new_setting_is_registered():
    unknown = sorted(set(_dotted_settings()) - _frozen() - {a.name for a in ADDED})
    assert not unknown, (f"settings added to Params without an entry in the registry: {unknown}; register it in "
                         "plugin/params/identity.ADDED with its neutral value (the value at which sosmatch behaves as "
                         "before the setting existed, or NO_NEUTRAL), else every earlier output is refused as "
                         "another one after an upgrade")


def test_no_setting_is_removed():
    # earlier outputs recorded every setting: one removed (or renamed) changes all their identities, and the
    # registry has no entry for that yet (it would need the value the removed setting had)
    removed = sorted(_frozen() - set(_dotted_settings()))
    assert not removed, (f"settings removed from Params: {removed}; every earlier output recorded them and would be "
                         "refused after an upgrade: teach plugin/params/identity.py to rebuild the identity with the "
                         "removed setting at the value it had before removing it")
