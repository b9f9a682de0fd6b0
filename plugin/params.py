"""Every parameter of the method, with the paper's defaults, in one frozen dataclass tree.

Field comments give the symbol used in SOS-Match (Thomas et al., IROS 2024) and `../shared/spec/method.md`.
Values marked *(ours)* are not fixed by the paper; the module that uses them documents how they were chosen.
Parameters are plain data: `params_from_dict` / `params_to_dict` convert to and from nested dicts (TOML lives in
`sosmatch.database.config_io`), and unknown keys are rejected rather than silently ignored.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from typing import Any

from .errors import InputError


# ---------------------------------------------------------------------------------------------------------------
# Valid values: every field declares its range or choices (metadata "valid"); `params_from_dict` (and so every
# config file, --set and `config check`) refuses a value outside it. tests/test_params.py fails for a field
# without a declaration, so a field added later must declare one.
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Valid:
    """The values a parameter may take: a closed or open numeric range, odd integers, a set of choices, text."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    odd: bool = False
    choices: tuple[Any, ...] | None = None

    def describe(self) -> str:
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.lo is None and self.hi is None:
            return "any value"
        lo = "-inf" if self.lo is None else (f"{self.lo:g}" if isinstance(self.lo, float) else str(self.lo))
        hi = "inf" if self.hi is None else (f"{self.hi:g}" if isinstance(self.hi, float) else str(self.hi))
        text = f"within {'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open or self.hi is None else ']'}"
        return text + (", odd" if self.odd else "")

    def accepts(self, value: Any) -> bool:
        if self.choices is not None:
            return value in self.choices
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return True  # text and flags: the type check is all
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)):
            return False
        if self.hi is not None and (value > self.hi or (self.hi_open and value == self.hi)):
            return False
        return not self.odd or value % 2 == 1


def _valid(default: Any, valid: Valid) -> Any:
    return field(default=default, metadata={"valid": valid})


def within(default: float, lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False) -> Any:
    """A number within [lo, hi] (None: unbounded; *_open: that end excluded); never NaN or infinite."""
    return _valid(default, Valid(lo, hi, lo_open, hi_open))


def positive(default: float) -> Any:
    return within(default, 0.0, None, lo_open=True)


def non_negative(default: float) -> Any:
    return within(default, 0.0, None)


def fraction(default: float) -> Any:
    return within(default, 0.0, 1.0)


MAX_COUNT = 2**31 - 1  # counts reach COLMAP's options and compiled kernels as C ints: a larger one overflows there


def count(default: int, lo: int = 0, hi: int | None = None, odd: bool = False) -> Any:
    """An integer of at least `lo` and at most `hi` (None: MAX_COUNT)."""
    return _valid(default, Valid(lo, MAX_COUNT if hi is None else hi, odd=odd))


def one_of(default: Any, *choices: Any) -> Any:
    return _valid(default, Valid(choices=tuple(choices)))


def flag(default: bool) -> Any:
    return _valid(default, Valid())


def text(default: str) -> Any:
    """Free text (a path; "" = unset)."""
    return _valid(default, Valid())


class Checked:
    """Base of the params dataclasses: a value outside its declaration is refused however the params are made
    (`params_from_dict` names the dotted key; `dataclasses.replace` and direct construction land here)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            valid = f.metadata.get("valid")
            value = getattr(self, f.name)
            if valid is not None and not valid.accepts(value):
                raise InputError(f"{type(self).__name__}.{f.name} must be {valid.describe()}, got {value!r}")


def valid_values(cls: type, name: str) -> Valid | None:
    """The declaration of field `name` of params dataclass `cls` (None if it has none)."""
    f = next((f for f in dataclasses.fields(cls) if f.name == name), None)
    return None if f is None else f.metadata.get("valid")


@dataclass(frozen=True)
class KeyframeParams(Checked):
    interval_m: float = positive(2.0)  # theta_T: camera travel between keyframes


@dataclass(frozen=True)
class SegmentationParams(Checked):
    backend: str = one_of("classical", "classical", "sam-onnx")  # registry name in sosmatch.plugin.segmentation
    min_mask_area_px: int = count(3, 0)  # the paper keeps masks "larger than 2 px"
    max_sift_per_mask: int = count(64, 0)  # SIFT features kept per mask A_k (ours; tracking only, never stored)
    # SIFT runs once per image on a copy whose longer side is at most this (0 = full resolution). (ours) OpenCV
    # doubles the image first, so 1200x900 at full size costs ~0.3 s; 480 px detects in ~0.04 s and still
    # gives thousands of keypoints; descriptors are computed only for the ones masks keep.
    sift_max_side: int = count(480, 0)
    # (ours) distinct keypoints per image at most (0 = no limit): bounds descriptor time
    sift_max_keypoints: int = count(2000, 0)
    # (ours) OpenCV's 0.04 finds ~100 keypoints on low-contrast NIR frames
    sift_contrast_threshold: float = non_negative(0.01)
    # -- backend `classical` (sosmatch.plugin.segmentation.classical; all ours, tuned on synthetic + Seneca) --
    classical_max_side: int = count(400, 1)  # working resolution (longer side, px); masks are mapped back to full size
    # median filter (working px) that removes leaf / furrow texture
    classical_median_ksize: int = count(5, 1, 255, odd=True)
    classical_smooth_sigma_color: float = non_negative(40.0)  # bilateral filter colour sigma (0..255 units)
    # gradient percentile below which pixels seed watershed regions; 60 (was 40): fewer, larger seeds, 2x faster
    # Ward merge, summer / winter recall 0.809 / 0.614 -> 0.822 / 0.644, summer-winter average F1 0.715 -> 0.843
    classical_flat_percentile: float = within(60.0, 0.0, 100.0)
    # gradient minima at least this x the flat level deep seed watershed regions too (h-minima; 0: flat zones
    # only): small textured objects on snow had no flat pixel and no seed (winter bushes 5-8/21-27 found -> 14-24)
    classical_minima_depth: float = non_negative(1.0)
    classical_merge_cost: float = positive(2000.0)  # Ward merge cost of the finest level (working px x Delta E^2)
    classical_merge_levels: int = count(7, 1)  # levels of the merge hierarchy whose object-like regions become masks
    classical_merge_level_factor: float = within(2.5, 1.0, None, lo_open=True)  # cost ratio between consecutive levels
    # weight of the mean gradient along a shared boundary in the merge cost
    classical_edge_weight: float = non_negative(0.15)
    # nested masks of two levels more alike than this: keep the more contrasted
    classical_dedup_iou: float = fraction(0.8)
    # larger regions are background (fields, lawns) and dropped
    classical_max_area_frac: float = within(0.08, 0.0, 1.0, lo_open=True)
    classical_min_area_px: int = count(100, 0)  # smaller regions (full-resolution px) are dropped
    # sqrt(lambda_max / lambda_min) above this: sliver (road, hedge edge)
    classical_max_elongation: float = within(5.0, 1.0, None)
    # area / area of the moment ellipse below this: branchy or ring-shaped region
    classical_min_fill: float = fraction(0.75)
    classical_min_contrast: float = non_negative(6.0)  # mean Delta E to the neighbours below this: not an object
    # >0: non-convex masks (area / convex hull below this) also give their distance-transform parts. Off: on the
    # synthetic sessions 0.95 doubled the masks per frame for +0.03 recall in winter and none in summer.
    classical_split_solidity: float = fraction(0.0)
    # weight of CIELAB L in merging (lit / shaded halves of a crown join)
    classical_lightness_weight: float = non_negative(0.7)
    # weight of local lightness std (texture) next to L, a, b (0 = off)
    classical_texture_weight: float = non_negative(1.0)
    classical_texture_window: int = count(5, 1)  # window (working px) of the texture measure
    # weight of normalised r, g chromaticity (x 300) in merging: unchanged by shading, so a crown's lit and shaded
    # halves join and a cast shadow stays with the ground it falls on (0 = off; summer recall 0.745 -> 0.85)
    classical_chroma_weight: float = non_negative(2.0)
    # parts of a whole: a mask that is at least this share of a coarser, more contrasted candidate with fill >=
    # `classical_fragment_parent_fill` (a single crown, not a clump) is dropped; its centroid is off the object's
    # (0 = off; map median horizontal error 1.0 -> 0.44 m, BENCHMARKS Mapping)
    classical_fragment_ratio: float = fraction(0.15)
    classical_fragment_parent_fill: float = fraction(0.9)
    # -- backend `sam-onnx` (sosmatch.plugin.segmentation.sam_onnx) --
    sam_encoder: str = text("")  # image-encoder ONNX path ("" = $SOSMATCH_SAM_ENCODER)
    sam_decoder: str = text("")  # prompt-decoder ONNX path ("" = $SOSMATCH_SAM_DECODER)
    sam_points_per_side: int = count(16, 1, 256)  # grid of point prompts (SAM's automatic generator uses 32)
    sam_points_per_batch: int = count(64, 1)  # prompts per decoder call
    sam_pred_iou_thresh: float = fraction(0.86)  # keep masks whose predicted IoU is at least this (SAM's default 0.88)
    sam_stability_score_thresh: float = fraction(0.92)  # keep masks at least this stable (SAM's default 0.95)
    sam_stability_score_offset: float = positive(1.0)  # logit offset of the stability score (SAM's default)
    sam_box_nms_thresh: float = fraction(0.7)  # duplicate removal: mask IoU above this suppresses the lower-scored mask
    # masks covering more of the image are background and dropped
    sam_max_area_frac: float = within(0.5, 0.0, 1.0, lo_open=True)
    sam_threads: int = count(2, 0)  # onnxruntime intra-op threads


@dataclass(frozen=True)
class TrackingParams(Checked):
    # theta_t (ours): tracks whose last observation is older are not candidates. On synthetic sessions 1 -> 2 -> 3
    # bridges segmentation misses (mean track length +17-22 %); beyond 3 gains little and adds duplicates/impurity.
    max_track_age_keyframes: int = count(3, 1)
    # theta_a (ours): max centroid distance to the epipolar line (px, both images). EKF-noisy poses put 95 % of
    # true pairs within ~8 px (exact poses: ~4 px); 12 keeps >99 % of them while purity falls for wider margins.
    # Scale it with focal length x attitude error for other cameras. Evidence: BENCHMARKS.md, Tracking parameters.
    epipolar_margin_px: float = positive(12.0)
    motion_gate_sigmas: float = positive(4.0)  # theta_v: | |m_i - m_j| - mu_p | / sigma_p must stay below this
    min_score: float = fraction(0.2)  # theta_q: minimum q = sqrt(q_s * q_f)
    size_tolerance: float = positive(0.2)  # theta_h: relative size difference at which q_s reaches 0
    # Lowe's ratio test for q_f (ours; the paper does not state it)
    sift_ratio: float = within(0.8, 0.0, 1.0, lo_open=True)
    # (ours) centroid noise added in quadrature to sigma_p in the motion gate
    centroid_sigma_px: float = non_negative(3.0)
    # (ours) reject pairs whose centroid lies behind camera s along the epipolar line
    cheirality_check: bool = flag(True)
    # (ours) a track whose observations already triangulate (rays meeting at >= point_gate_min_ray_angle_deg) is
    # gated by where its point projects into the new keyframe (within epipolar_margin_px) instead of by the
    # epipolar line of its last observation and the motion gate: the line lets every segment along it through,
    # the point picks one spot, and across flight lines the motion gate's summed image motion means nothing.
    point_transfer_gate: bool = flag(True)
    point_gate_min_ray_angle_deg: float = within(5.0, 0.0, 180.0)
    # (ours) ground band gate (`plugin.ground_band`): a track without a point yet must reappear within
    # epipolar_margin_px of the stretch of its epipolar line between the heights of the local ground, i.e. the
    # median height of the candidate tracks' confirmed points +- this many robust standard deviations; 0 = off.
    # Needs the point transfer gate (its points are the ground). Where frames are 300-550 px apart and image motion
    # often unmeasurable it decides (Seneca, survey preset: 184 -> 283 landmarks); with the paper's 2 m keyframes
    # it changes little (BENCHMARKS.md, "The ground band"; the seasons worlds). Off (0) in the "paper" preset.
    ground_band_sigmas: float = non_negative(6.0)


@dataclass(frozen=True)
class TriangulationParams(Checked):
    min_observations: int = count(5, 1)  # theta_n: tracks with MORE than this many observations become landmarks
    pixel_sigma_px: float = positive(3.0)  # sigma: centroid noise used in triangulation and bundle adjustment
    max_reprojection_error_px: float = positive(10.0)  # (ours) landmarks above this mean error are dropped
    # (ours) landmarks seen under a smaller ray angle are dropped
    min_triangulation_angle_deg: float = within(1.0, 0.0, 180.0)
    # (ours) duplicate suppression: a landmark whose ground-plane (x, y) distance to a better-supported one is
    # at most this times the larger of their metric sizes h is a duplicate (a nested or partial mask of the same
    # object: a crown part, a crown and its clump, a split track) and is dropped; 0 = off. h = sqrt(lambda_max)
    # is half the radius of a disc, so 2 h = "inside the other's footprint": a part's centroid lies within
    # ~0.85 h of the whole's, a 2-crown clump's within ~0.9 h of each crown, while two touching distinct discs
    # are 2 (h_1 + h_2) > 2 max(h) apart. Measured (BENCHMARKS.md, Mapping): 2.0 lowers the median horizontal
    # error 1.30 -> 0.50 m. OFF by default, as in the paper: on the evaluation suite (BENCHMARKS.md, "Duplicate
    # suppression and matching") 2.0 cut cross-season average F1 from 0.58 to 0.33 (summer-winter) and from
    # 0.76 to 0.30 (spring-autumn): the parts of an object that both seasons segment alike are evidence too.
    duplicate_radius_factor: float = non_negative(0.0)
    # (ours) height outliers (`plugin.landmark_filters.height_outliers`): a landmark whose height differs from the
    # median of its `height_outlier_neighbours` nearest landmarks (horizontally) by more than this many robust
    # standard deviations of that difference is a wrong track triangulated along a straight flight line, where
    # collinear views cannot fix the depth; 0 = off (the paper's EKF keyframes every 2 m see an object from many
    # views). On in the "survey" preset.
    height_outlier_sigmas: float = non_negative(0.0)
    height_outlier_neighbours: int = count(8, 1)
    # metric size h_S of a landmark (`plugin.landmark_size`): "mean" = the paper's mean of h_px x depth / f over the
    # observations; "nadir" (ours) = sqrt(lambda_max) of the object's footprint covariance fitted jointly over the
    # observations with the relief displacement of off-nadir views removed and masks cut by the image border left
    # out: sizes of one object then agree across flights, altitudes and crossing directions (median r 0.09 -> 0.04)
    size_estimator: str = one_of("nadir", "nadir", "mean")
    # (ours) split tracks of one object (one per pass, or around a segmentation gap) become one landmark
    # (`plugin.track_fusion`): pieces that never share a keyframe, lie within this factor x the larger metric size
    # horizontally, agree in size within `fuse_size_tolerance` and are explained by one point within
    # max_reprojection_error_px; 0 = off (the paper: every track its own landmark). theta_n applies to the fused
    # landmark, and tracks with at least `min_piece_observations` observations are triangulated as pieces
    fuse_radius_factor: float = non_negative(2.0)
    fuse_size_tolerance: float = positive(0.5)
    min_piece_observations: int = count(3, 2)


@dataclass(frozen=True)
class AssociationParams(Checked):
    # theta_WL: landmarks per window; with factors > 1 below, the window of the map whose factor is 1 (the sparser)
    window_length: int = count(50, 3)
    window_stride: int = count(10, 1)  # theta_SL: stride between windows (scaled by the same factors)
    # (ours) each map's windows are window_length x its factor landmarks, stride window_stride x its factor: the
    # paper's windows are one length in both maps, which in maps of unequal density cover unequal ground (world 97,
    # 284 summer landmarks at 100 m against 95 winter ones at 130 m: 50-landmark windows span 9 400 and 30 400 m^2,
    # so a window pair held a third of the common objects at most and no true set reached theta_S). With
    # `equal_area_windows` and `derive_from_maps` the factors are derived from the maps
    # (`window_chance.area_factors`: the denser map's window grows by the largest power of two whose window spans
    # no more ground than the sparser map's; 1 and 1 for maps within a factor of two of each other's density, the
    # paper's windows); otherwise they are used as configured (1 and 1: the same length in both maps, literally)
    equal_area_windows: bool = flag(True)
    window_factor_a: int = count(1, 1)
    window_factor_b: int = count(1, 1)
    max_size_difference: float = fraction(0.2)  # theta_r: putative pairs need r(h_i, h_j) <= this
    distance_tolerance_m: float = positive(2.0)  # theta_eps: pairwise distance mismatch still called consistent
    # sigma (ours) of the CLIPPER affinity exp(-c^2 / 2 sigma^2): the spread of the distance mismatch c of a true
    # pair (four landmarks with ~0.3-0.5 m noise each give ~1 m); affinity at the gate eps = 2 m is exp(-2) = 0.14
    affinity_sigma_m: float = positive(1.0)
    # theta_alpha: max roll/pitch difference of an accepted transform
    max_gravity_angle_deg: float = within(22.5, 0.0, 180.0)
    # theta_S (ours default; swept for precision-recall): accept if |S| > this. On synthetic 1000-landmark survey
    # maps (tools/benchmarks/bench_match.py) theta_S = 4 accepts wrong window pairs, 5 and 6 none: 6 keeps a margin,
    # and a larger theta_S also makes the search faster (only theta_S-cores are solved)
    min_associations: int = count(6, 2)
    transform: str = one_of("rigid", "rigid", "similarity")  # "rigid" (Arun/Umeyama) or "similarity"
    # -- how the search forms its graphs (all ours; the paper's method is consistency "distance", windows "id",
    # no position prior: the "paper" preset). One definition of each test: plugin/association/consistency.py.
    # consistency: "distance" = the paper's | ||a|| - ||b|| | <= theta_eps on 3D landmark-pair vectors a (map A)
    # and b (map B); "gravity" = both maps are gravity-aligned, so a pair carries two invariants: the horizontal
    # lengths agree within theta_eps and the height differences agree within theta_eps + L tan(gravity_tilt_deg)
    # (L the longer horizontal length); and with yaw_slice_deg > 0 a consistent set must also share one yaw.
    consistency: str = one_of("gravity", "distance", "gravity")
    # (ours) tilt between the two maps' vertical axes the gravity test tolerates (EKF frames: 0.4-2.1 deg measured)
    gravity_tilt_deg: float = within(5.0, 0.0, 90.0, hi_open=True)
    # (ours) gravity: the height differences of a landmark pair may disagree by this times theta_eps beyond the
    # tilt's share. Landmark heights are noisier than their ground positions: on the evaluation suite's EKF maps
    # the 95th percentile of the height mismatch of true pairs is ~1.5x the horizontal one (BENCHMARKS.md)
    height_tolerance_factor: float = non_negative(2.0)
    # (ours) gravity: the yaw that a pair of associations implies (direction of a in A minus direction of b in B,
    # within asin(theta_eps / length)) must fall in one slice of this width for all pairs of a set; every window
    # pair is solved per slice and keeps its largest set. Chance-consistent pairs scatter over the 360 degrees,
    # a true set (and never a mirror image) shares one yaw. 0 = off.
    yaw_slice_deg: float = within(7.5, 0.0, 180.0)
    # windows: "id" = theta_WL landmarks in id (time) order, as in the paper; "spatial" = the same windows over
    # each map's landmarks sorted along a Hilbert curve of their horizontal positions in the map's own frame, so a
    # window is a compact patch of ground whatever the flight path (crossing flights share windows)
    windows: str = one_of("id", "id", "spatial")
    # (ours) position prior: > 0 = putative associations only between landmarks whose horizontal positions, in
    # the maps' common world frame (both georeferenced in one EPSG, or one shared local frame), are within this
    # distance (GNSS sigma x k); 0 = off (maps in unrelated frames)
    position_prior_m: float = non_negative(0.0)
    # solver of each window pair (plugin/association/clipper.solve): "clipper" = the relaxation and greedy rounding
    # on the theta_S-core (the paper); "bounded" = a greedy clique of the highest cores bounds the answer and the
    # relaxation runs only on the part of the core that could hold a larger set (ours; never a smaller set)
    solver: str = one_of("bounded", "clipper", "bounded")
    # (ours) derive theta_eps, sigma and theta_r from the two maps' own noise figures (`plugin.map_noise`: the
    # per-observation residual and size spread each mapped session records in run.json) instead of the values
    # above; maps without the figures (.sosmap files, COLMAP models) keep the values above. On by default: with
    # the fixed 2 m / 0.2 the held-out worlds 23 and 42 lost summer vs winter at 130 m (recall 0 on both: the
    # 130 m map's residual is 1.15 m, its common landmarks 3 m apart) and world 42 on the same path (0); derived,
    # every summer-winter case of worlds 5, 11, 23, 42 reaches recall 0.90-1.00 at P >= 0.99 and NAIP matches
    # (BENCHMARKS.md, issue 16). The paper preset keeps the paper's values
    derive_from_maps: bool = flag(True)


@dataclass(frozen=True)
class VerificationParams(Checked):
    """Verification of a match on the full maps (`plugin.verification.verify_search`; a stage of `sosmatch match`,
    all ours). Across seasons one window pair's |S| is 4-14 for true and chance hypotheses alike; over the full
    maps a true transform brings many more landmarks of B onto landmarks of A (BENCHMARKS.md, Multi-session)."""

    enabled: bool = flag(True)  # off (`match --no-verify`): the answer is the window consensus as it is
    dof: int = one_of(4, 4, 6)  # ICP degrees of freedom: 4 = yaw + translation (gravity-aligned maps), 6 = rigid
    final_dof: int = one_of(6, 0, 6)  # the winner refitted 6-DOF on its pairs (0: keep the `dof` fit)
    min_ratio: float = within(1.2, 1.0, None)  # the winner's support over the best alignment that puts B elsewhere
    z_weight: float = positive(0.5)  # heights count this much in the nearest-neighbour distance (noisier)
    max_candidates: int = count(400, 1)  # window hypotheses tried, largest first (bounds dense maps)
    # The chance model (`plugin.chance.chance_test`): B refined from this many random placements over A
    # measures the support chance alignments of these two maps reach (0: off, the ratio alone decides, which
    # accepted 2 of 8 pairs of maps of different worlds). The winner is the best of N_eff ~1e5 distinct
    # alignments (`effective_trials`), so it is accepted only when the probability that the best of N_eff
    # chance alignments reaches its support is at most `false_alarm`: the rate at which two maps of different
    # places would be reported as aligned. At most this many placements: `sequential_chance` stops after 16 once
    # the answer is beyond doubt (its bootstrap interval past a stop) and draws more while in doubt, as the tail is
    # extrapolated from the samples' moments and a few dozen samples of a skewed count scatter widely: a true
    # sparse winter pair of world 64 (never used before; support 32, chance max 11) read p 0.037 (refused) from
    # 64 samples, 0.005 from 128, 3e-4 from 256, 2e-5 from 512 (0.6 s of CPU for 1,000 refinements there; the
    # model then without each placement's opportunity, `chance.chance_opportunity`)
    chance_starts: int = count(512, 0)
    false_alarm: float = within(1e-2, 0.0, 1.0, lo_open=True)
    # the size gate of the verification's pairs (r of mutual nearest neighbours within theta_eps). Across seasons
    # one object's sizes differ by r 0.12 (median) / 0.3-0.4 (80th percentile) between two maps (worlds 5, 11);
    # inside an alignment the positions already single out the partner, so this gate follows that spread while
    # the search's theta_r, where a wrong pair makes a wrong transform, stays tight (BENCHMARKS.md, issue 16)
    max_size_difference: float = fraction(0.4)
    # the verification's candidates and displaced rivals are refined first at this many gates, then at the gate
    # (`refinement.refine_alignment`; the chance placements stay one-gate, `verify_alignments` says why): 2 = the
    # resolution at which the verification tells two alignments apart (`chance.converged_to_winner`); at the gate
    # alone the fit stopped in a fragment's local optimum (world 97's crossing flight: 18 pairs where 22 were
    # 1.7 m away). 1: one stage, as before
    coarse_factor: float = within(2.0, 1.0, None)


@dataclass(frozen=True)
class ChangeParams(Checked):
    """Object-level change detection between two aligned sessions (`sosmatch.plugin.changes`; all ours)."""

    # A landmark is compared only where the other session's keyframes should have seen it (projected inside the
    # image with its own extent as margin) at least this often: theta_n + 1, the fewest observations a landmark
    # can have (`triangulation.min_observations`), so fewer views could not have mapped it at all.
    min_views: int = count(6, 1)
    # counterpart gate = this x theta_eps (`association.distance_tolerance_m`), distance in x, y and z_weight x z.
    # theta_eps is the landmark scatter the association already allows (2 m on drone maps, 10 m in the aerial
    # preset); between two EKF maps 90 % of the landmarks of one object have the other map's nearest landmark of
    # that object within 2.8-3.9 m (BENCHMARKS.md, Change detection), so 1.5 theta_eps = 3 m.
    tolerance_factor: float = positive(1.5)
    z_weight: float = non_negative(0.5)  # heights are the noisy direction of a nadir survey (as in refinement)
    # r = 2 |h_a - h_b| / (h_a + h_b) of a counterpart (theta_r is 0.2 for association, where a wrong pair costs
    # a wrong transform; here a re-segmented object must still count as present: sizes within a factor 1.67)
    max_size_difference: float = within(0.5, 0.0, 2.0)
    # A landmark without a counterpart is kept when a larger landmark of the other map (up to this many times
    # its size) holds it in its footprint (ground distance <= 2 h) and this session shows that landmark too (a
    # counterpart here, or this session's segments): the other session mapped the object whole where this map
    # has a part of it; a ground patch seen where this map's object stood is no such whole. 0 = off.
    nest_max_ratio: float = non_negative(2.0)
    # One object is often several landmarks of one map (a crown, its lit half, the clump it stands in; split
    # tracks), and the other session may have mapped only some of them: a landmark inside the footprint of a
    # larger own landmark (at most this many times its size) that the other session shows directly (a
    # counterpart, or its segments) or holds in a landmark of its own is kept with it (not through a whole
    # kept only by a part link itself: chained links let ground regions hold what really went), and so is
    # a landmark whose footprint holds smaller landmarks of the other map (down to 1 / this of its size) that
    # have counterparts in its own map (the object whole here, as parts there; on the 7 development worlds this
    # removed 5 of 6 false same-season new claims for 2 of 15 found). A wider reach lets large ground regions
    # and neighbouring crowns hold objects that really went. 0 = off.
    part_max_ratio: float = non_negative(2.5)
    # A place without a counterpart landmark is still called occupied when the other session's own segments
    # (every mask in its database, tracked or not) show a size-compatible segment at the landmark's projection
    # in significantly more of its keyframes than at probe points around it: binomial tail probability below this
    # (0.05: on worlds 7 and 11 it cut the false gone / new claims from 9 to 5 for 2 of 38 changed objects found
    # fewer than at 0.01; worlds 23 and 31 showed no difference; BENCHMARKS.md, Change detection, ablation)
    segment_evidence_p: float = fraction(0.05)
    # probes for the chance rate of segments: this many points on a circle of radius (probe_radius_factor x the
    # counterpart gate + 2 h) around the landmark
    probe_count: int = count(8, 1)
    probe_radius_factor: float = positive(2.0)
    # The presence rate (how often the other session's segments show an object of a given size that is there) is
    # measured on the landmarks with a counterpart, pooled with a Gaussian kernel of this width in log size
    # (0.3: sizes within a factor 1.35 count fully; a landmark's size scatters by about that between sessions)
    presence_bandwidth: float = positive(0.3)
    # A gone / new claim needs the other session's segments to say the object is absent: its confidence is
    # P(absent | segment hits) (quasi-binomial, prior odds 1, `verdict.absence_probability`); claims below this
    # are reported as unseen (the other session cannot tell). 0.8 (odds 4:1) on the 7 development worlds of
    # BENCHMARKS.md raised same-season gone precision from 0.71 to 0.91 at unchanged recall; 0 reports every
    # claim. Without the other session's database the confidence is its re-observation rate of such landmarks.
    min_confidence: float = fraction(0.8)
    # (ours) objects a session saw but never mapped (`plugin.changes.unmapped`): the tracks of its database that
    # no landmark holds, triangulated, not explained by its own map and shown by its own segments in at least
    # min_views keyframes, are judged against the other session as its landmarks are (direct evidence only; they
    # vouch for nothing). An object whose track broke into pieces too short for a landmark can then still be
    # reported gone / new. False: landmarks only.
    unmapped_objects: bool = flag(True)
    # the mean reprojection error (px) such a track's point may have: the map's own landmark limit
    # (triangulation.max_reprojection_error_px, 10 px by default)
    unmapped_max_error_px: float = positive(10.0)
    # the centroid noise (px) behind such a point's position uncertainty (the map's triangulation.pixel_sigma_px):
    # its place must be known to within the counterpart gate at 2 sigma to ask the other session what is there
    unmapped_pixel_sigma_px: float = positive(3.0)
    # A landmark (or an object never mapped) lower than the ground by more than this many robust standard
    # deviations of its own map's heights above the ground (1.4826 x their median absolute deviation, about 2 m
    # on drone maps) is a wrong triangulation (two patches linked into one track): no object lies under the
    # ground its session looked at, and its place is wrong with its height (a ground patch triangulated 33 m
    # deep fell inside the other session's images, 3.4 m outside its footprint). It is compared with nothing
    # (unseen, evidence 'height'). The development maps' object landmarks lie at most 2.3-7 m below the ground
    # field (1 %), wrong triangulations down to 40 m.
    max_depth_sigmas: float = positive(4.0)


@dataclass(frozen=True)
class QualityParams(Checked):
    # (ours) plausibility limits of a map (`plugin.map_quality.judge`): beyond them `sosmatch map` refuses it
    # landmarks higher than a camera that flew over them (within their footprint), of those under the flight path:
    # the aircraft would have flown through the object; 0 in every consistent map measured
    max_share_above_cameras: float = fraction(0.05)
    max_block_tilt_deg: float = within(20.0, 0.0, 90.0)  # tilt that the ground and the cameras share
    # the worst pair of passes: lower quartile of |dz| of their neighbouring landmarks over that of one pass's
    # (`map_quality.pass_disagreement`): consistent maps 1.0-3.5 (32 synthetic and real maps), a 50 m altitude
    # drift 26, flight lines 30 m apart in height 34
    max_pass_disagreement: float = within(6.0, 1.0, None)
    # ... and refused only when those two passes also put the same ground this far apart in height, as a fraction
    # of the flying height (the pose check's warn_height_drift): the ratio proves that the passes differ, this
    # says that it matters. An EKF's scale drift along a pass puts passes a few % of H apart (world 64: 2.7 m at
    # 98 m, ratio 6.1; the matcher's derived tolerances absorb it: a warning); the lines 30 m apart above: 27.7 m,
    # 27 % (bench_plausibility; the 50 m pose-CSV drift was not re-measured in metres)
    max_pass_offset: float = fraction(0.05)
    # p90 of |landmark height - its 8 neighbours' median| over the flying height: beyond 1 a tenth of the map sits
    # farther from its neighbours' ground than the cameras fly above it (a drone flies above what it maps; a pit
    # that deep under a tenth of the landmarks is no survey site); consistent maps 0.03-0.07, Seneca 0.04
    max_height_spread: float = positive(1.0)
    # warnings only
    # a whole block's ground steeper than this is rare (synthetic and real maps: <= 2 deg); GPS heights that drift
    # tilt it too (a 50 m drift over a 100-frame survey: 12-27 deg)
    warn_ground_tilt_deg: float = within(20.0, 0.0, 90.0)
    min_keyframes_with_landmarks: float = fraction(0.5)
    min_track_yield: float = fraction(0.05)
    refuse: bool = flag(True)  # False: a map beyond the limits is kept with a loud warning (run.json says so)


@dataclass(frozen=True)
class PoseCheckParams(Checked):
    """(ours) The poses checked against what the images show (`plugin.pose_check`): pose-free matches of a
    bounded subsample of overlapping image pairs, explained by the poses' epipolar geometry. Limits measured on
    good poses (exact, EKF, refined, structure from motion; synthetic and real) against deliberately wrong ones:
    BENCHMARKS.md, "Poses against the images"."""

    enabled: bool = flag(True)  # `sosmatch map` runs the check (its refusals refuse the map, as quality.refuse says)
    max_pairs: int = count(240, 3)  # a third each: consecutive images, k apart, another flight line
    max_image_side_px: int = count(1024, 64)  # features on images downscaled to this longer side
    max_features: int = count(2000, 64)  # ORB features per image
    ratio: float = within(0.8, 0.0, 1.0, lo_open=True)  # Lowe's ratio test
    ransac_px: float = positive(1.5)  # fundamental-matrix RANSAC threshold at the working size
    min_inliers: int = count(30, 8)  # fewer agreeing matches: no evidence (chance matches reach ~20 in turns)
    noise_px: float = positive(1.0)  # ORB keypoint noise at the working size (the fit's pixel scale)
    wide_shift: float = within(0.4, 0.0, 1.0, lo_open=True)  # "wide" pairs move the image by this much
    max_wide_offset: int = count(10, 1)
    cross_radius: float = positive(0.5)  # cross-line partners within this fraction of the footprint's short side
    min_pairs: int = count(10, 1)  # fewer checked pairs: a warning that the check saw too little
    # refusals / warnings (plugin.pose_check.judge_poses); systematic errors only beyond 2 sigma of their fit
    max_epipolar_gate_fraction: float = positive(1.0)  # median pair error beyond the tracker's epipolar gate
    warn_epipolar_gate_fraction: float = positive(0.25)
    max_height_drift: float = positive(0.2)  # heights drifting over the flight, as a fraction of the flying height
    warn_height_drift: float = positive(0.05)
    max_height_tilt_deg: float = within(20.0, 0.0, 90.0)  # the same limit as the map's block tilt
    warn_height_tilt_deg: float = within(5.0, 0.0, 90.0)
    max_attitude_bias_deg: float = within(10.0, 0.0, 180.0)
    warn_attitude_bias_deg: float = within(2.0, 0.0, 180.0)
    # the systematic errors are judged only when the flight separates them: the fit's condition index (Belsley,
    # Kuh & Welsch: above 30 the estimates are degraded by near-collinearity; measured 3-5 on lawnmower flights,
    # 122 on a single straight line)
    max_condition_index: float = positive(30.0)


@dataclass(frozen=True)
class ImageParams(Checked):
    # (ours) the longer image side (px) at which the pixel-valued parameters hold: the tracking margins and noise
    # (`tracking.*_px`), the triangulation sigma and reprojection limit (`triangulation.*_px`) and the pixel
    # areas (`segmentation.min_mask_area_px`, `classical_min_area_px`). Mapping a larger image scales lengths by
    # (longer side / this) and areas by its square (`pixel_scale`, `for_image`): at one field of view, pose errors
    # in pixels grow with the focal length and centroid noise with the ratio of the image to the segmentation's
    # working size, both in proportion to the image. Smaller images keep the values as they are (mask boundaries
    # and JPEG blocks put a floor of a few native pixels under the noise). 0 = never scale.
    reference_size_px: float = non_negative(640.0)  # the defaults were chosen on 640x480 synthetic sessions


@dataclass(frozen=True)
class SfmParams(Checked):
    """(ours) Poses from images by structure from motion (`sosmatch poses`, `workflows/sfm.py`), on CPU.

    Measured on Seneca's 167 1200x900 frames on 2 busy cores (BENCHMARKS.md, "Poses from images"): SIFT at the
    image's own octave (first_octave 0) costs a quarter of COLMAP's default upsampled one (-1); a low-contrast
    threshold below COLMAP's 0.0067 keeps feature-poor frames of fields and water registrable, and the feature
    cap bounds the work on textured ones; only pairs that GPS says may overlap are matched."""

    max_image_size_px: int = count(1000, 64)  # features on images downscaled to this longer side
    max_features: int = count(4000, 64)  # per image (the strongest, larger scales first)
    first_octave: int = count(0, -1, 4)  # SIFT's first octave: -1 doubles the image first (4x the work)
    peak_threshold: float = positive(0.004)  # SIFT difference-of-Gaussian contrast threshold
    camera_model: str = one_of("SIMPLE_RADIAL", "SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
    neighbours: int = count(10, 1)  # GPS nearest neighbours matched per image (`plugin.image_pairs`)
    sequential: int = count(2, 0)  # plus this many successors in capture order
    exhaustive_up_to: int = count(40, 0)  # without GPS: all pairs up to this many images, else a sequence
    sequential_without_gps: int = count(10, 1)
    mapper: str = one_of("incremental", "incremental", "global")
    # GPS positions as pose priors in COLMAP's bundle adjustment (sigma gps_sigma_m): "auto" = when the heights come
    # from DJI RelativeAltitude, consistent in 3-D; never on a GPS altitude alone, which may drift (COLMAP aligns
    # the block to the priors in 3-D first, and a 50 m drift would tilt it). Measured (BENCHMARKS.md): on a
    # 26-frame 320 px flight centres 1.01 -> 0.56 m, the focal length 24 -> 11 % off; 90-frame flights unchanged
    use_gps_priors: str = one_of("auto", "auto", "on", "off")
    gps_sigma_m: float = positive(3.0)  # a consumer receiver's horizontal error: the expected GPS noise
    min_registered_fraction: float = fraction(0.5)  # fewer registered images than this is an error


@dataclass(frozen=True)
class Params(Checked):
    image: ImageParams = field(default_factory=ImageParams)
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    tracking: TrackingParams = field(default_factory=TrackingParams)
    triangulation: TriangulationParams = field(default_factory=TriangulationParams)
    association: AssociationParams = field(default_factory=AssociationParams)
    verification: VerificationParams = field(default_factory=VerificationParams)
    changes: ChangeParams = field(default_factory=ChangeParams)
    quality: QualityParams = field(default_factory=QualityParams)
    pose_check: PoseCheckParams = field(default_factory=PoseCheckParams)
    sfm: SfmParams = field(default_factory=SfmParams)
    seed: int = count(0, 0, 2**63 - 1)  # every random choice in the pipeline derives from this


def params_to_dict(params: Any) -> dict[str, Any]:
    """Nested plain dict of a params dataclass (sections become sub-dicts)."""
    return dataclasses.asdict(params)


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    """Check a config value against the field type; ints are accepted where floats are expected."""
    kind = {"float": float, "int": int, "str": str, "bool": bool}.get(annotation, annotation)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind in (float, int, str, bool) and (type(value) is not kind):
        raise InputError(f"{where} must be {kind.__name__}, got {value!r}")
    return value


def params_from_dict(data: dict[str, Any], cls: type = Params, where: str = "") -> Any:
    """Build a params dataclass from a nested dict; missing keys keep defaults, unknown keys are an error."""
    if not isinstance(data, dict):
        raise InputError(f"{where or 'config'} must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        name = f"[{where}]" if where else "top level"
        raise InputError(f"unknown key(s) {', '.join(unknown)} in {name}; known: {', '.join(fields)}")
    kwargs = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            kwargs[key] = params_from_dict(value, hint, path)
        else:
            kwargs[key] = _coerce(value, hint, path)
            valid = fields[key].metadata.get("valid")
            if valid is not None and not valid.accepts(kwargs[key]):
                raise InputError(f"{path} must be {valid.describe()}, got {kwargs[key]!r}")
    return cls(**kwargs)


# Named parameter presets (hloc-style `confs`): dotted overrides applied on top of the paper's defaults, before a
# config file and `--set`. "paper" is the method as published (keyframes every 2 m, EKF poses, 640x480).
PRESETS: dict[str, dict[str, Any]] = {
    # the search as published: id windows, 3D distance consistency, gravity checked after the solve, no prior
    "paper": {"association.consistency": "distance", "association.windows": "id",
              "association.position_prior_m": 0.0, "association.solver": "clipper",
              # and the front end as published: every track its own landmark, the mean metric size
              "triangulation.size_estimator": "mean", "triangulation.fuse_radius_factor": 0.0,
              "tracking.ground_band_sigmas": 0.0, "association.derive_from_maps": False,
              "association.equal_area_windows": False},
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
        "triangulation.height_outlier_sigmas": 6.0,
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


def preset_params(name: str) -> Params:
    """The named preset (see PRESETS) as parameters; an unknown name is an InputError listing the known ones."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r} (known: {', '.join(sorted(PRESETS))})")
    return with_overrides(Params(), PRESETS[name])


def with_overrides(params: Params, overrides: dict[str, Any]) -> Params:
    """Apply dotted-key overrides such as {"tracking.epipolar_margin_px": 8.0}."""
    data = params_to_dict(params)
    for dotted, value in overrides.items():
        *sections, key = dotted.split(".")
        node = data
        for section in sections:
            if not isinstance(node.get(section), dict):
                raise InputError(f"unknown parameter section {section!r} in {dotted!r}")
            node = node[section]
        if key not in node or isinstance(node[key], dict):
            raise InputError(f"unknown parameter {dotted!r}")
        node[key] = value
    return params_from_dict(data)
