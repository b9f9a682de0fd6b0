"""Parameters of mapping a session: images, keyframes, segmentation, tracking, triangulation, and the checks
of a map (quality, poses) and of its poses from images (SfM)."""

from __future__ import annotations

from dataclasses import dataclass

from .checks import (
    Checked,
    count,
    flag,
    fraction,
    non_negative,
    one_of,
    positive,
    text,
    within,
)


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
    # (ours) the luminance range (grey levels 0..255, median over sampled frames of their 1-99 % range) the
    # segmenter's absolute contrast criteria were tuned for: a flight of less contrast (haze) is stretched up to it
    # by one linear gain for segmentation (`plugin.flight_contrast`; 0: never). Normal flights measured: synthetic
    # summer 130-150, winter 121-143, spring / autumn at 100 and 130 m 123-148, sun at 5-10 deg 127-135, Seneca 120,
    # NAIP orthophoto views 94 (2015) and 115; and a scan of 310 earlier test flights (nu31, median 142): a clear
    # narrow camera at 90 m 82, a dusk flight 84, a flight over a hill 81. 70, below all of them, leaves each
    # unchanged; haze 0.3 / 0.5 on a summer flight (96 / 69) is within that spread, so only a heavier veil (fog,
    # a = 0.6 and more) is stretched: the range alone cannot tell haze from a flat scene.
    contrast_reference: float = non_negative(70.0)
    # -- backend `classical` (sosmatch.plugin.segmentation.classical; all ours, tuned on synthetic + Seneca) --
    classical_max_side: int = count(400, 1)  # working resolution (longer side, px); masks are mapped back to full size
    # (ours) the most ground one working pixel may cover (m): when the map measures its flying height (the pose
    # check's median depth) and `classical_max_side` would make working pixels coarser than this, the working size
    # grows to image side x (flying height / focal length) / this (at most the full image, and 2 x
    # `classical_max_side` so that time and memory per frame stay bounded), and `classical_min_area_px` keeps its
    # share of working pixels. At a fixed 400 px, 640 px frames flown at 130 m were segmented at 0.42 m per working
    # pixel against 0.32 m at 100 m: neighbouring crowns merged, boundaries took coarser pixels, and crowns came out
    # 4-16 % larger (BENCHMARKS.md, "One working pixel, one ground size"). Finer working pixels stay (low flights
    # keep their detail), as does imagery coarser than this (orthophoto views: no working size reaches it). 0.33:
    # the 0.32 m of the synthetic 100 m sessions the classical parameters were tuned on, with room for the 3 % by
    # which the measured flying height moves with the scene (features on crowns over snow: 96 m at 100 m), so those
    # sessions keep their 400 px. 0 = no ceiling.
    classical_ground_resolution_m: float = non_negative(0.33)
    # (ours) the least ground one working pixel may cover (m): where `classical_max_side` would make working pixels
    # finer than this (zoom cameras, low flights), the working size shrinks to image side x ground resolution /
    # this and `classical_min_area_px` keeps its working pixels. The merge costs and kernels count working pixels,
    # so finer ones split crowns into their lit, shaded and leafy parts: a zoom camera at 0.16 m mapped a 6 m
    # crown as 12 landmarks of 0.4-1.3 m, at 0.31 m as one (BENCHMARKS.md, "A floor under the working pixel").
    # 0.21: under Seneca's 0.227 m (real, 70 m) with room for the measured flying height's 3 % scatter, so
    # Seneca keeps its 400 px: at 0.24 m, where synthetic zoom flights map crowns whole (size / (R/2) 1.06 against
    # 0.40 at 0.21 m), the survey preset's Seneca map lost 11 % of its landmarks (370 -> 328), and at 0.32 m 40 %.
    # A compromise: at 0.21 m crowns still come in 1-7 pieces (12 at 0.16 m). 0 = no floor.
    classical_min_ground_resolution_m: float = non_negative(0.21)
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
    # (ours) a mask cut by the image border is a truncated view (`plugin.truncation`): its size a lower bound, its
    # centroid shifted inward. On: the size gate is one-sided against the track's latest whole view, the position
    # gates (and the database's check of the links) accept the centroid anywhere in the outward box the truncation
    # could have shifted it by, and a track's point comes from its whole views. A third to a half of the links of
    # one crown fail at the frame edge otherwise (BENCHMARKS.md, "crowns cut off at the frame edge"). On by default
    # (fix76): on four seasons worlds it raises cross-season recall at P >= 0.99 (w229 crossing 45 deg 0.769 ->
    # 0.806, summer-winter 130 m refused -> 0.933; w577 summer-winter 0.785 -> 0.820); same-season cases stay within
    # the session-to-session noise (4 of 5 sessions of w577 winter 100 / 130 m within +-0.005, one -0.040); worst
    # accepted error 2.8 m; ~2 s more CPU of tracking per 100-keyframe map (BENCHMARKS.md, "Issue 16:
    # truncation-aware maps mended and measured on four worlds"). Off in the "paper" preset;
    # `--set tracking.truncation_aware=false` gives the maps of before (and resumes them).
    truncation_aware: bool = flag(True)


@dataclass(frozen=True)
class TriangulationParams(Checked):
    min_observations: int = count(5, 1)  # theta_n: tracks with MORE than this many observations become landmarks
    # (ours) theta_n at most half the keyframes that see a ground point on one pass (`plugin.motion.views_per_pass`:
    # the image's extent along the motion over the image motion per keyframe), and never below 2
    # (`params.for_flight`): the paper's 5 assumes keyframes every 2 m that see an object many times; flying lower,
    # or with frames further apart, an object is in fewer keyframes (synthetic 640x480, 65 deg, 7 m apart: 5.4 at
    # 40 m, 13.6 at 100 m; Seneca ~2), and at 40 m no track could have 6 observations on one pass: 24 and 31
    # landmarks on two worlds against 238 and 225 at 100 m (BENCHMARKS.md, "The fourth new-user sweep"). Off in
    # the "paper" preset.
    min_observations_from_views: bool = flag(True)
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
    # views). On in the "survey" preset, and wherever `params.for_flight` lowers theta_n (a few views per pass).
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
    # (ours) a mask cut by the image border shows only the part of its object inside the frame, so its centroid
    # slides with the camera instead of staying on one ground point; with the whole views of a track it pulls the
    # point metres down (nu22, 2 m keyframes: 46 of 396 landmarks > 5 m below the ground, their views cut 87 % of
    # the time against 4 % for the rest). On: a landmark is located from the views that see its mask whole
    # (`triangulation.located_from_whole_masks`); the cut views stay in its track (theta_n counts them); one
    # without two whole views spanning min_triangulation_angle_deg is dropped. Off in the "paper" preset.
    whole_masks_only: bool = flag(True)


@dataclass(frozen=True)
class QualityParams(Checked):
    # (ours) plausibility limits of a map (`plugin.map_verdict.judge`): beyond them `sosmatch map` refuses it
    # landmarks higher than a camera that flew over them (within their footprint), of those under the flight path:
    # the aircraft would have flown through the object; 0 in every consistent map measured
    max_share_above_cameras: float = fraction(0.05)
    max_block_tilt_deg: float = within(20.0, 0.0, 90.0)  # tilt that the ground and the cameras share
    # the worst pair of passes: lower quartile of |dz| of their neighbouring landmarks over that of one pass's
    # (`pass_heights.pass_disagreement`): consistent maps 1.0-3.5 (32 synthetic and real maps), a 50 m altitude
    # drift 26, flight lines 30 m apart in height 34. Judged on the ratio the pairs prove (its quartiles' 2-sigma
    # bounds, `PassDisagreement.ratio_low`): correct poses 0.03-2.5 (76 maps of nu21/22/28/38; 3.9 on nu23's
    # dust-veiled images), 30 m altitude drifts 7.6-9.3
    max_pass_disagreement: float = within(6.0, 1.0, None)
    # ... and refused only when those two passes also put the same ground this far apart in height, as a fraction
    # of the flying height (the pose check's warn_height_drift): the ratio proves that the passes differ, this
    # says that it matters. An EKF's scale drift along a pass puts passes a few % of H apart (world 64: 2.7 m at
    # 98 m, ratio 6.1; the matcher's derived tolerances absorb it: a warning); the lines 30 m apart above: 27.7 m,
    # 27 % (bench_plausibility; the 50 m pose-CSV drift was not re-measured in metres)
    max_pass_offset: float = fraction(0.05)
    # ... and the same limit in metres on the passes' own triangulations of their common landmarks
    # (`plugin.pass_heights`, the terrain cancels), refused when the offset is also beyond this many standard
    # errors (its own scatter): nu28 consistent maps 0.3-2.2 m at 5.0 % H = 5-6.6 m (98 maps of nu21/22/26: at
    # most 2.8 m), heights tilted 15 deg along 30 deg or drifting 30 m over the flight 8-12 m at 8-19 errors
    pass_offset_margin: float = positive(5.0)
    # (ours) the lens in the camera file against the lens the map's own observations fit with the poses fixed
    # (`plugin.lens_check`; off: not checked): the median landmark height change with the refit lens, judged when
    # beyond lens_shift_margin jackknife standard errors (the images prove another lens) ...
    lens_check: bool = flag(True)
    lens_shift_margin: float = positive(5.0)
    # ... and beyond this fraction of the flying height a refusal (the map's heights are that wrong), beyond
    # warn_lens_height_shift a warning. Correct lenses (rev40, 20+ synthetic flights and Seneca) moved up to 3.7 % on
    # EKF/SfM poses but reached z 9.5-10.3 (the jackknife cannot see a pull all landmarks share), and on unrefined
    # EXIF tag poses 6.4-7.7 % (the refit turns pose errors into a barrel lens): so the lens is judged only on poses
    # the pose check found fitting the images, else at most a warning naming both causes (`judge_lens`);
    # 100 deg lenses with flipped distortion 31-37 %, left out (PINHOLE) 17-23 %, k1 -0.2 at 65 deg left out 8.9 %
    # (BENCHMARKS.md, "The lens against the images")
    max_lens_height_shift: float = fraction(0.10)
    warn_lens_height_shift: float = fraction(0.06)
    # p90 of |landmark height - its 8 neighbours' median| over the flying height: beyond 1 a tenth of the map sits
    # farther from its neighbours' ground than the cameras fly above it (a drone flies above what it maps; a pit
    # that deep under a tenth of the landmarks is no survey site); consistent maps 0.03-0.07, Seneca 0.04
    max_height_spread: float = positive(1.0)
    # the flying height two ways: the cameras over the map's landmarks (segments tracked over many keyframes) and
    # over the pose check's ORB matches triangulated pair by pair (`PoseCheck.flying_height_m`), with the same
    # poses; beyond this factor apart one of them triangulated nonsense. Consistent maps 0.92-1.04 (43 synthetic,
    # real and orthophoto maps at 40-1390 m); Seneca on EXIF poses of every 2nd frame 5.9 (landmarks at -693 ..
    # +136 m under a 62 m flight, taken as a 347 m one), 8.5 and 599 on wrong poses
    max_height_disagreement: float = within(1.5, 1.0, None)
    # warnings only
    # a whole block's ground steeper than this is rare (synthetic and real maps: <= 2 deg); GPS heights that drift
    # tilt it too (a 50 m drift over a 100-frame survey: 12-27 deg)
    warn_ground_tilt_deg: float = within(20.0, 0.0, 90.0)
    # frame cameras map from drones (tens to hundreds of metres) and aircraft (up to ~9 km); poses in centimetres
    # or millimetres read as metres put a 100 m flight at 10-100 km, with landmarks 0.2-2.4 km across (the
    # thirteenth sweep), which nothing else names: the images fix every length only up to the poses' unit
    warn_flying_height_m: float = within(10_000.0, 0.0, None, lo_open=True)
    min_keyframes_with_landmarks: float = fraction(0.5)
    min_track_yield: float = fraction(0.05)
    # the keyframes' images (`plugin.image_quality`, at the segmenter's working size, medians over the flight):
    # contrast over Immerkaer's noise sigma. Clean synthetic flights 22, the real Seneca frames 7.8 (their texture
    # counts as noise: per frame down to 2.5); Gaussian noise of sigma 20 on the synthetic images 1.75, 40 0.92,
    # `synth --noise 25` 0.69. Below it the map's thinness is put down to the images
    min_image_contrast_to_noise: float = positive(3.0)
    # fine detail over contrast: clean synthetic 0.41, Seneca 0.51; Gaussian blur of 1.5 px 0.095, 3 px 0.052,
    # 9 px motion blur 0.17 (its map kept 66 of 108 landmarks)
    min_image_sharpness: float = positive(0.15)
    # the flight's JPEG quality (`plugin.jpeg_quality`, from its files' quantization tables; 0: never said). World 7
    # session B (640 x 480, `synth --jpeg-quality Q`, EKF poses), landmarks against 205 at the default 88: Q 75
    # 181, 60 173, 50 188, 40 177, 25 152, 15 160 (seed 3: 218 at 88, 164 at 20); below 75 its comparison with a
    # clean session also made false claims (`ChangeParams.min_jpeg_quality`). Cameras write 90-97 (Seneca 90)
    min_jpeg_quality: float = within(75.0, 0.0, 100.0)
    # the flight's smear along its track (`plugin.motion_blur`, working px, median of the keyframes; 0: never
    # said). A ground texture whose detail fades smoothly along the track fits at most ~2 px; clean flights (10
    # synthetic worlds, turned and reversed lawnmowers, freeform; nu21/nu22 outputs) 0-0.5, world 7 B with a linear
    # blur along the track of 3 / 6 / 12 full px (x 0.625 to working px) 1.75 / 3.5 / 7.5 (12 px: 120 of 205
    # landmarks, and false change claims against a clean session: `ChangeParams.max_motion_smear_px`)
    max_motion_smear_px: float = within(2.0, 0.0, None)
    # below this many landmarks per keyframe a map is said to be thin, with the cause the map knows (low contrast
    # stretched for segmentation, or none found; 0: never said). Warning-free maps in nu21-nu39 (209: worlds,
    # altitudes, cameras) had 0.98 and more (5th percentile 1.16), the real Seneca flight 0.38-0.51 over its 166
    # keyframes; low-contrast thermal flights (nu39, luminance range 48-50 of 70) 0.18-0.20 with nothing said
    warn_landmarks_per_keyframe: float = within(0.3, 0.0, None)
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
    # ... and a warning when fewer than this share of the attempted pairs could be checked (misfitting poses among
    # the others go unseen). Clean flights: 0.40-0.75 (Seneca's first 50 frames 25 of 53, whose cross and wide
    # pairs in the turns do not overlap: half would warn on them); 2 stops darker 0.10 (synthetic) and 0.20
    # (Seneca, 13 of 64, where the clean images showed 2 misfitting pairs), JPEG quality 15 0.32, blur 1.5 px 0.24
    min_pair_share: float = fraction(1 / 3)
    # refusals / warnings (plugin.pose_check.judge_poses); systematic errors only beyond 2 sigma of their fit
    max_epipolar_gate_fraction: float = positive(1.0)  # median pair error beyond the tracker's epipolar gate
    # loose poses are warned by the share of the checked pairs' true matches (fundamental-matrix inliers) that the
    # poses put beyond the tracker's epipolar gate, i.e. the share of tracks the tracker would lose: the gate keeps
    # >99 % of them on EKF poses by design (`TrackingParams.epipolar_margin_px`), so a median at a quarter of the
    # gate, which the earlier warning used, is where EKF poses sit by construction (it warned on 2.9-3.3 px of
    # correct EKF poses, the 38th new-user sweep). Measured: correct poses (exact, EKF; 18 sets, 6 worlds)
    # 0.1-1.6 %; 1.5 m / 3 m GPS noise 5.8-43 %, DJI tags 6.5-13 %, each image given its neighbour's pose 39-40 %,
    # another session's poses 28 %
    warn_matches_beyond_gate: float = fraction(0.03)
    # the median's limit, as a fraction of the gate, where the share above is not known (a check without its pairs)
    warn_epipolar_gate_fraction: float = positive(0.25)
    # single pairs whose median error exceeds this times the gate: named in a warning (their images' poses are
    # wrong where the flight's median hides them; good EKF poses: at most 13 px on a 12 px gate, in 1 of 185-224
    # pairs; EXIF poses whose attitudes the tie points could not solve: 271 px on a 22 px gate)
    warn_pair_gate_fraction: float = positive(2.0)
    # a pair counts against its cameras (`verdict.wrong_cameras`: the cameras whose pose misses every pair it is
    # in are refused; `swaps.exchanged_cameras`: two cameras whose poses fit exchanged) beyond this many times the
    # flight's median pair error, and at least this fraction of the tracker's gate (a floor for flights whose median
    # sits at the feature noise). Measured (BENCHMARKS.md, "Cameras whose poses miss every pair"): sound poses'
    # worst pairs 0.47-8.1 px against limits of 6-20 px; a swapped pair of cameras 48-72 px, a 90 deg yaw 26-37 px
    camera_median_factor: float = positive(10.0)
    camera_gate_fraction: float = positive(0.5)
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
    # ... and only when they explain the checked pairs significantly better than the poses as given (an F test at
    # this level, each pair one observation: `SystematicErrors.explained_p`)
    systematic_significance: float = within(0.01, 0.0, 1.0)
    # ... and are most of the pairs' misfit (the share the fit removes; pairs that share images are not
    # independent, so significance alone passes structured random errors: correct EKF poses of a 40 m flight at
    # p 2e-4 with 48 % explained; true drifts and tilts 83-100 %)
    min_systematic_share: float = fraction(0.5)
    # the camera centres against the images' own GPS fixes (`plugin.pose_check.gps`), where the images have them:
    # the poses' length per GPS metre beyond 1 +- this by more than two of its standard deviations is refused (the
    # map's lengths and sizes would not be metres). A receiver over a survey's extent agrees to 1-3 %; feet are
    # 3.28, centimetres 100, an unscaled reconstruction anything
    max_gps_scale_error: float = positive(0.1)
    # poses in a projected CRS whose centres lie farther than this from their own fixes (median): a warning (the
    # georeference search trusts a map's georeference to association.georeference_prior_m, 50 m; GPS puts a camera
    # within metres, another datum 100-200 m off, another UTM zone or hemisphere hundreds of km). The bound for any
    # noise: below it the offset is judged against the GPS noise (`pose_check.gps.OFFSET_NOISES`)
    warn_gps_offset_m: float = positive(50.0)
    # a camera path whose similarity explains less than this share of the fixes' spread, or keeps fewer of them
    # as inliers, does not follow them: a warning, and its scale and offset are not judged (poses of another
    # flight, names paired with the wrong images; correct poses explain > 99 % on a 100 m track)
    min_gps_agreement: float = fraction(0.5)


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
    # (ours) when the incremental mapper leaves images out (it grows one model from a seed pair and starts another
    # where an image's links to it are too weak: Seneca's first 30 frames split into models of 18, 5, 5 and 3 at
    # the turns), COLMAP's global mapper on the same matches, which solves the whole view graph at once; its model
    # is kept when it registers more images (Seneca 30: all 30, within 0.81 deg / 0.52 m of the incremental model
    # on the 18 both hold; BENCHMARKS.md, "The fourth new-user sweep")
    global_when_incomplete: bool = flag(True)
    # GPS positions as pose priors in COLMAP's bundle adjustment (sigma gps_sigma_m): "auto" = when the heights come
    # from DJI RelativeAltitude, consistent in 3-D; never on a GPS altitude alone, which may drift (COLMAP aligns
    # the block to the priors in 3-D first, and a 50 m drift would tilt it). Measured (BENCHMARKS.md): on a
    # 26-frame 320 px flight centres 1.01 -> 0.56 m, the focal length 24 -> 11 % off; 90-frame flights unchanged
    use_gps_priors: str = one_of("auto", "auto", "on", "off")
    gps_sigma_m: float = positive(3.0)  # a consumer receiver's horizontal error: the expected GPS noise
    min_registered_fraction: float = fraction(0.5)  # fewer registered images than this is an error
