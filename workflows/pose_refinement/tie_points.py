"""Refinement of GPS/telemetry poses from the images themselves: ORB tie points between overlapping images
(`tie_point_reconstruction`), then one of the bundle adjustments with the poses as priors, judged against them
(`refine_poses_from_images`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from ...database.flight_levels import flight_white_level
from ...database.images import read_gray
from ...plugin.fixed_in_frame import FixedInFrame, learn_fixed_in_frame
from ...plugin.geometry import Poses, rotation_angle_deg
from .judge import (
    WEAK_OBSERVATIONS,
    RefinementRejected,
    RefinementStats,
    judge_refinement,
    pose_changes,
    tilt_changes_deg,
)
from .with_colmap import point_errors, poses_of_reconstruction, refine_poses_with_colmap
from .with_priors import refine_poses_with_priors

log = logging.getLogger(__name__)

# The longer side (px) of the copy the tie points are detected on. The refinement's pixel figures (`ransac_px`,
# `pixel_sigma_px`) and the feature count were measured on Seneca's 1200 px frames; on a 4000 px copy of the same
# frames, ORB's strongest features at full size are fine texture that does not repeat (356 tracks instead of 1027,
# 19 images without a tie point instead of 14) and the verdict changed with the file size (the seventeenth
# sweep). Detected at this size, a frame gives the same tie points whatever its pixel count; the thresholds are
# then scaled to the full-size pixels the poses and the camera use (`TiePoints.pixel_scale`).
TIE_POINT_MAX_SIDE = 1200


def _ratio_matches(desc_a: np.ndarray, desc_b: np.ndarray) -> np.ndarray:
    """Indices (M, 2) of ORB matches between two images that pass Lowe's ratio test."""
    from ...plugin.image_matching import ratio_matches

    if desc_a is None or desc_b is None or len(desc_a) < 8 or len(desc_b) < 8:
        return np.zeros((0, 2), dtype=int)
    return ratio_matches(desc_a, desc_b, 0.8)


def _orb_matches(good: np.ndarray, kp_a: np.ndarray, kp_b: np.ndarray, ransac_px: float) -> np.ndarray:
    """The ratio-test matches `good` (M, 2) of two images that pass a RANSAC homography (the ground is nearly
    flat, so a homography is the right image-only model; parallax outliers are dropped)."""
    from ...plugin.image_matching import homography_inliers

    if len(good) < 12:
        return np.zeros((0, 2), dtype=int)
    inl = homography_inliers(kp_a[good[:, 0]], kp_b[good[:, 1]], ransac_px)
    if inl is None or inl.sum() < 12:
        return np.zeros((0, 2), dtype=int)
    return good[inl]


def _detect(image_paths: list, camera: object, max_features: int, max_side: int | None,
            mask: np.ndarray | None = None) -> tuple[list[np.ndarray], list[np.ndarray | None], float]:
    """ORB features of every image (`image_matching.orb_features`, only where `mask` at the detection size is
    non-zero): keypoints in full-size COLMAP pixels, descriptors, and the full-size pixels per detection pixel."""
    from ...plugin.image_matching import orb_features

    kps, descs = [], []
    pixel_scale = 1.0
    white = flight_white_level(image_paths)  # one scale for a flight of more than 8 bits (nothing decoded at 8)
    for path in image_paths:
        img = read_gray(path, white)
        if img.shape[1] != camera.width:
            raise ValueError(f"{path}: image width {img.shape[1]} differs from the camera's {camera.width}")
        features = orb_features(img, max_features, max_side, mask)
        pixel_scale = 1.0 / features.scale  # one camera: one scale for every image
        kps.append(features.colmap_points)
        descs.append(features.descriptors)
    return kps, descs, pixel_scale


@dataclass
class TiePoints:
    """ORB tie points of a set of images, found with nothing from the poses but the camera centres (which pairs to
    match): per image its keypoints (COLMAP pixels), per matched pair the homography-inlier matches, and the
    tracks (feature indices into the concatenation of the images' keypoints, `offsets[i]` the first of image i)."""

    keypoints: list[np.ndarray]
    pair_matches: dict[tuple[int, int], np.ndarray]
    tracks: list[np.ndarray]
    offsets: np.ndarray
    pairs_tried: int
    pixel_scale: float = 1.0  # full-size pixels per pixel of the copy the features were detected on
    # regions fixed in the image frame whose matches were left out (`plugin.fixed_in_frame`; None: not learned)
    fixed_in_frame: FixedInFrame | None = None

    @property
    def observations(self) -> int:
        return int(sum(len(g) for g in self.tracks))

    def image_of(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.keypoints)), np.diff(self.offsets))


def match_tie_points(
    image_paths: list,
    centers: np.ndarray,
    camera: object,
    max_features: int = 3000,
    neighbour_fraction: float = 0.6,
    ransac_px: float = 6.0,
    min_track_length: int = 3,
    max_neighbours: int = 8,
    max_side: int | None = TIE_POINT_MAX_SIDE,
) -> TiePoints:
    """ORB tie points between overlapping images (image order = the order of `centers`, the camera centres).

    Features per image (ORB, `max_features`, detected on a copy at most `max_side` px on its longer side; keypoints
    in full-size COLMAP pixels); matches (ratio test + RANSAC homography at `ransac_px` pixels of that copy)
    between each image and the next two, and between any two images whose centres are closer than
    `neighbour_fraction` x 4 x the median spacing of consecutive images (a typical 75% forward overlap puts ~4
    spacings in a footprint; at most its `max_neighbours` nearest), which links neighbouring flight lines; tracks by
    union-find (tracks with two features in one image are dropped). The orientations play no part: the matches
    are what the images show.
    """
    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    kps, descs, pixel_scale = _detect(image_paths, camera, max_features, max_side)
    spacing = np.median(np.linalg.norm(np.diff(centers[:, :2], axis=0), axis=1)) if n > 1 else 1.0
    radius = neighbour_fraction * 4.0 * spacing
    d2 = np.linalg.norm(centers[:, None, :2] - centers[None, :, :2], axis=2)
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 3))}
    # each image with its `max_neighbours` nearest within the radius: enough to tie neighbouring flight lines
    # together, and matching cost stays linear in the number of images (all pairs in the radius: 2x the time)
    # self excluded explicitly: with two images at the same centre (hovering, quantised GPS) a stable argsort can
    # put the other one first, and the pair (i, i) would union features of one image and drop their tracks
    near = np.argsort(np.where(np.eye(n, dtype=bool), np.inf, d2), axis=1, kind="stable")[:, :max_neighbours]
    pairs |= {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in near[i] if i != j and d2[i, j] < radius}
    # features fixed in the image frame (a burned-in stamp, a logo, the landing gear) match in every pair with no
    # displacement: points at infinity that pull all cameras toward one attitude, and in a pair of little ground
    # overlap the homography's identity (the nu35 sweep); learned from all pairs before any is kept, at the
    # detection size, and left out of every pair
    ratio = {(i, j): _ratio_matches(descs[i], descs[j]) for i, j in sorted(pairs)}
    work = [k / pixel_scale - 0.5 for k in kps]  # pixels of the detection copy, as detected
    fixed = learn_fixed_in_frame([(work[i][m[:, 0]], work[j][m[:, 1]]) for (i, j), m in ratio.items()],
                                 camera.width / pixel_scale, camera.height / pixel_scale)
    if fixed:
        log.warning("tie points: %s", fixed.describe(pixel_scale))
        # detected again with the overlay masked out: ORB keeps a fixed number of features per pyramid level, and
        # a stamp's sharp glyphs took two thirds of them (nu35 stamp: 1300 tracks instead of B's 2360, the block
        # refined 0.56 deg off the truth instead of 0.20); masked, the budget goes to the ground
        kps, descs, _ = _detect(image_paths, camera, max_features, max_side, fixed.detection_mask())
        ratio = {(i, j): _ratio_matches(descs[i], descs[j]) for i, j in sorted(pairs)}
        work = [k / pixel_scale - 0.5 for k in kps]
    offsets = np.concatenate([[0], np.cumsum([len(k) for k in kps])]).astype(np.int64)
    parent = np.arange(offsets[-1])

    def find(a: int) -> int:
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    matched: dict[tuple[int, int], np.ndarray] = {}
    for i, j in sorted(pairs):
        good = ratio[(i, j)]
        if fixed and len(good):
            good = good[fixed.keep(work[i][good[:, 0]], work[j][good[:, 1]])]
        m = _orb_matches(good, kps[i], kps[j], ransac_px * pixel_scale)
        if len(m):
            matched[(i, j)] = m
        for a, b in m:
            ra, rb = find(offsets[i] + a), find(offsets[j] + b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(a) for a in range(offsets[-1])])
    img_of = np.repeat(np.arange(n), np.diff(offsets))
    order = np.argsort(roots, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(roots[order])) + 1)
    tracks = [g for g in groups if len(g) >= min_track_length and len(np.unique(img_of[g])) == len(g)]
    log.info("tie points: %d image pairs matched of %d tried, %d tracks of >= %d images", len(matched), len(pairs),
             len(tracks), min_track_length)
    return TiePoints(kps, matched, tracks, offsets, len(pairs), pixel_scale, fixed if fixed else None)


def reconstruction_of_tie_points(tie: TiePoints, poses: Poses, camera: object,
                                 min_ray_angle_deg: float = 2.0) -> object:
    """A pycolmap Reconstruction of the tie points with the given poses (changed by nothing here): points by
    least-squares intersection of the rays from the poses, dropped when behind a camera or when the rays meet under
    less than `min_ray_angle_deg`. `camera` is a sosmatch Camera (any lens model: rays and the model go through
    it), image order = pose order."""
    import pycolmap

    from ...database.cameras import pycolmap_camera

    n, kps, offsets = len(poses), tie.keypoints, tie.offsets
    img_of = tie.image_of()
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap_camera(camera, 1))
    used = np.zeros(offsets[-1], dtype=bool)
    for g in tie.tracks:
        used[g] = True
    local_index = np.full(offsets[-1], -1)
    for i in range(n):
        sel = np.flatnonzero(used[offsets[i]:offsets[i + 1]])
        local_index[offsets[i] + sel] = np.arange(len(sel))
        pts = [pycolmap.Point2D(kps[i][s]) for s in sel]
        im = pycolmap.Image(name=poses.names[i], camera_id=1, image_id=i + 1, points2D=pycolmap.Point2DList(pts))
        r_cw = poses.rotations[i].T
        rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), -r_cw @ poses.centers[i]))
    origin = poses.centers.mean(axis=0)
    for g in tie.tracks:
        imgs = img_of[g]
        uv = np.stack([kps[i][a - offsets[i]] for i, a in zip(imgs, g)])
        d_cam = np.concatenate([camera.cam_from_img(uv), np.ones((len(uv), 1))], 1)  # through the lens model
        d = np.einsum("nij,nj->ni", poses.rotations[imgs], d_cam)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        m = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        a_mat = m.sum(0)
        b_vec = np.einsum("nij,nj->i", m, poses.centers[imgs] - origin)
        try:
            x = np.linalg.solve(a_mat, b_vec) + origin
        except np.linalg.LinAlgError:
            continue
        depth = np.einsum("nj,nj->n", x - poses.centers[imgs], poses.rotations[imgs][:, :, 2])
        if np.any(depth <= 0):
            continue
        # Nearly parallel rays leave the depth unconstrained: such points make the bundle adjustment's normal
        # equations indefinite (Ceres: "Matrix not positive definite") and teach the poses nothing.
        if np.degrees(np.arccos(np.clip(np.min(d @ d.T), -1.0, 1.0))) < min_ray_angle_deg:
            continue
        track = pycolmap.Track()
        for i, a in zip(imgs, g):
            track.add_element(int(i) + 1, int(local_index[a]))
        rec.add_point3D(x, track)
    return rec


def tie_point_reconstruction(image_paths: list, poses: Poses, camera: object, max_features: int = 3000) -> object:
    """A pycolmap Reconstruction of ORB tie points with the given (prior) poses (changed by nothing here):
    `match_tie_points` (pairs from the centres of `poses`), then `reconstruction_of_tie_points`."""
    tie = match_tie_points(image_paths, poses.centers, camera, max_features)
    return reconstruction_of_tie_points(tie, poses, camera)


def headings_from_image_motion(tie: TiePoints, poses: Poses, camera: object, unknown: np.ndarray,
                               position_sigma_m: float = 0.0) -> tuple[Poses, np.ndarray]:
    """The poses with the headings of the images marked `unknown` (no attitude tags) turned to what the images'
    motion and the GPS say (`plugin.heading`), and the turn of every image in degrees (NaN: not turned). An unknown
    image in no matched pair, or whose pairs disagree, keeps its prior turned by the mean turn of the others (the
    camera's mounting relative to the course is one per flight as often as not); the rest is left to the
    refinement. `position_sigma_m`: the GPS sigma; pairs too close for the GPS to give their direction are not
    used (`heading_corrections`)."""
    from ...plugin.heading import directions_of_motion, heading_corrections, turned_about_vertical

    unknown = np.asarray(unknown, dtype=bool)
    pairs = []
    for (i, j), m in sorted(tie.pair_matches.items()):
        if not (unknown[i] or unknown[j]):
            continue
        x_a = camera.cam_from_img(tie.keypoints[i][m[:, 0]])
        x_b = camera.cam_from_img(tie.keypoints[j][m[:, 1]])
        found = directions_of_motion(x_a, x_b)
        if found is not None:
            pairs.append((i, j, *found, float(len(m))))
    turns = np.where(unknown, heading_corrections(poses.rotations, poses.centers, pairs, position_sigma_m), np.nan)
    solved = np.isfinite(turns)
    if solved.any():
        typical = float(np.angle(np.mean(np.exp(1j * turns[solved]))))
        turns[unknown & ~solved] = typical
    return Poses(poses.names, turned_about_vertical(poses.rotations, turns), poses.centers), np.degrees(turns)


def refine_poses_from_images(
    image_paths: list,
    poses: Poses,
    camera: object,
    position_sigma_m: float | tuple[float, float, float] = 3.0,
    attitude_sigma_deg: float = 5.0,
    pixel_sigma_px: float = 2.0,  # at the tie points' detection size (TIE_POINT_MAX_SIDE)
    max_features: int = 2000,  # matching cost grows with its square: 3000 took 80 s of knnMatch on Seneca
    method: str = "colmap",
    accept_implausible: bool = False,
    unknown_headings: np.ndarray | None = None,
    tilt_sigma_deg: float | None = None,
) -> tuple[Poses, RefinementStats]:
    """Refine GPS/telemetry poses BEFORE mapping, with ORB tie points between overlapping images and the pose
    priors (`tie_point_reconstruction`, then `refine_poses_with_colmap` (method "colmap", the default: COLMAP's
    pose-prior bundle adjustment, position priors only, seconds) or `refine_poses_with_priors` (method "scipy":
    position and attitude priors, minutes)). Returns the refined poses (same names and order, same world frame)
    and the statistics. Use it when the poses are far from EKF quality: the mapping's epipolar gate (a few
    pixels) cannot track segments across frames whose poses are 100+ px off.

    `unknown_headings` (N,) bool: images whose prior heading is a guess (no attitude tags: the course over
    ground); their headings are first turned to what the image motion says (`headings_from_image_motion`), as a
    bundle adjustment does not turn a camera by 90 degrees out of its starting point.

    The result is judged against the priors and against the tie points (`judge_refinement`; `explained_share`:
    the share of the tie-point observations the refined poses explain within 2 pixel sigmas, every track
    triangulated anew with them, so tracks the starting poses could not triangulate count too): warnings are
    logged and kept in the stats; errors raise RefinementRejected unless `accept_implausible` (then they are
    logged as warnings). `tilt_sigma_deg`: how well the priors give the cameras' tilt off the vertical (gimbal
    tags: `judge.GIMBAL_TILT_SIGMA_DEG`; None: not judged)."""
    if method not in ("colmap", "scipy"):
        raise ValueError(f"unknown refinement method {method!r} (colmap or scipy)")
    tie = match_tie_points(image_paths, poses.centers, camera, max_features)
    pixel_sigma_px *= tie.pixel_scale  # given at the tie points' detection size; the adjustment is in full pixels
    turns = np.full(len(poses), np.nan)
    if unknown_headings is not None and np.any(unknown_headings):
        poses, turns = headings_from_image_motion(tie, poses, camera, unknown_headings,
                                                  float(np.max(np.atleast_1d(position_sigma_m))))
        solved = turns[np.isfinite(turns)]
        if len(solved):
            log.info("headings of %d images without attitude tags from the image motion: turned %.1f deg from the "
                     "course over ground (median of |turn|; circular mean %+.1f deg)", len(solved),
                     float(np.median(np.abs(solved))), float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(
                         solved)))))))
    rec = reconstruction_of_tie_points(tie, poses, camera)
    if method == "colmap":
        sigma = float(np.max(np.atleast_1d(position_sigma_m)))
        # its outlier cut (4 px at 2 px sigma) is in full-size pixels too (review rev19: unscaled, it dropped
        # good observations at 1.2 sigma on 4000 px frames)
        stats = refine_poses_with_colmap(rec, poses, sigma, pixel_sigma_px, outlier_px=2.0 * pixel_sigma_px,
                                         attitude_sigma_deg=attitude_sigma_deg)
    else:
        stats = refine_poses_with_priors(rec, poses, position_sigma_m, attitude_sigma_deg, pixel_sigma_px)
    refined = poses_of_reconstruction(rec)
    missing = [nm for nm in poses.names if nm not in refined.names]
    if missing:
        raise ValueError(f"{len(missing)} images lost their pose in the refinement (e.g. {missing[0]})")
    order = [refined.names.index(nm) for nm in poses.names]
    refined = refined.subset(order)
    if not tie.tracks:
        # nothing but the priors: the adjustment can only drift them (the sixteenth sweep: every camera moved by
        # one 1.95 m while the log said "the priors, unrefined"); the priors are the answer, as the log says
        refined = poses
        stats = replace(stats, position_change_mean_m=0.0, position_change_max_m=0.0, rotation_change_mean_deg=0.0,
                        rotation_change_max_deg=0.0, position_change_median_m=0.0,
                        tilt_change_median_deg=0.0)
    # cameras a handful of tie points turned far from their priors: one wrong tie point decides such a turn (nu53:
    # lossless PNG copies, 154 and 75 deg on 3-4 observations, written and mapped), so they keep the pose they
    # started from, as cameras without any tie point do (the ninth sweep: two DJI frames of 3 observations 23-26
    # deg off their gimbal tags, which agree with SfM within 2 deg); well-held cameras turn far too where the
    # priors are poor, and rightly (Seneca's telemetry: 59 of 167 beyond 15 deg, after it 1-5 deg from SfM)
    turned = turned_images(poses, refined, attitude_sigma_deg, observations_by_image(tie, len(poses)))
    if turned:
        refined = kept_starting_poses(poses, refined, [n for n, _ in turned])
        stats = replace(stats, **pose_changes(poses.rotations, poses.centers, refined.rotations, refined.centers))
    # judged against gimbal tags (`judge_refinement`): cameras tilted far off them, whatever their tie points
    stats = replace(stats, tilt_change_by_image_deg=tuple(float(t) for t in tilt_changes_deg(poses.rotations,
                                                                                            refined.rotations)))
    explained, observed = explained_by_image(tie, refined, camera, 2.0 * pixel_sigma_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_image = np.where(observed > 0, explained / np.maximum(observed, 1), np.nan)
    stats = replace(stats, explained_share=float(explained.sum() / observed.sum()) if observed.sum() else float("nan"),
                    explained_share_by_image=tuple(float(v) for v in per_image),
                    observations_by_image=tuple(int(n) for n in observed),
                    heading_turns_deg=tuple(float(t) for t in turns),
                    fixed_in_frame_px=tuple(tie.fixed_in_frame.boxes(tie.pixel_scale)) if tie.fixed_in_frame else ())
    errors, warnings = judge_refinement(stats, position_sigma_m, attitude_sigma_deg, poses.names, tilt_sigma_deg)
    blind = [nm for nm, k, guess in zip(poses.names, observed, unknown_headings if unknown_headings is not None
                                        else np.zeros(len(poses), bool)) if k == 0 and not guess]
    if blind and tie.tracks:
        # their poses are the priors, untouched (the seventeenth sweep: 19 of 60 frames, telemetry headings 10-36
        # deg off, in a refinement that said nothing); images without attitude tags are named by the caller
        warnings.append(f"{len(blind)} of {len(poses)} images share no tie point with the others "
                        f"({', '.join(blind[:4])}{', ...' if len(blind) > 4 else ''}): their poses are the priors, "
                        "unrefined")
    if turned and (accept_implausible or not errors):  # a rejected refinement: its rejection says more
        warnings.append(f"{len(turned)} of {len(poses)} cameras were turned more than 3 x the "
                        f"{attitude_sigma_deg:g} deg attitude prior by fewer than {WEAK_OBSERVATIONS} tie-point "
                        "observations (one wrong tie point decides): " + ", ".join(f"{n} {d:.0f} deg" for n, d in
                                                                                  turned[:5])
                        + (", ..." if len(turned) > 5 else "") + "; their poses are the priors, unrefined")
    for w in warnings:
        log.warning("pose refinement: %s", w)
    stats = replace(stats, warnings=tuple(warnings))
    if errors and not accept_implausible:
        before, after = stats.reprojection_median_before_px, stats.reprojection_median_after_px
        raise RefinementRejected("pose refinement rejected: " + "; ".join(errors) + f" (a median reprojection of "
                                 f"{before:.2f} -> {after:.2f} px says nothing about that); map without --refine, "
                                 "or with better priors")
    for e in errors:
        log.warning("pose refinement: %s (accepted on request)", e)
    return refined, stats




def turned_images(before: Poses, after: Poses, attitude_sigma_deg: float,
                  observations_by_image: tuple[int, ...] | np.ndarray | None = None) -> list[tuple[str, float]]:
    """(name, degrees) of the cameras whose orientation `after` differs from `before` (same names and order) by
    more than 3 attitude sigmas, the largest turn first; with `observations_by_image`, only those held by fewer
    than `WEAK_OBSERVATIONS` tie-point observations (an image without any is not turned by the adjustment)."""
    turn = np.atleast_1d(rotation_angle_deg(before.rotations, after.rotations))
    weak = np.ones(len(turn), bool) if observations_by_image is None or len(observations_by_image) != len(turn) \
        else np.asarray(observations_by_image) < WEAK_OBSERVATIONS
    odd = np.flatnonzero((turn > 3.0 * attitude_sigma_deg) & weak)
    return [(before.names[i], float(turn[i])) for i in odd[np.argsort(-turn[odd], kind="stable")]]


def kept_starting_poses(start: Poses, refined: Poses, names: list[str]) -> Poses:
    """`refined` (same names and order as `start`) with the images `names` back at their poses in `start`."""
    keep = np.isin(np.asarray(start.names, dtype=object), list(names))
    return Poses(list(refined.names), np.where(keep[:, None, None], start.rotations, refined.rotations),
                 np.where(keep[:, None], start.centers, refined.centers))


def observations_by_image(tie: TiePoints, count: int) -> np.ndarray:
    """Per image (0 .. `count`-1): how many tie-point observations it has."""
    return np.bincount(tie.image_of()[np.concatenate(tie.tracks)] if tie.tracks else np.zeros(0, np.int64),
                       minlength=count)


def explained_by_image(tie: TiePoints, poses: Poses, camera: object, max_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Per image: how many of its tie-point observations `poses` explain, and how many it has. Every track is
    triangulated with these poses (`reconstruction_of_tie_points`) and an observation is explained when it
    reprojects within `max_px`; a track that cannot be triangulated (behind a camera, parallel rays) explains
    none of its observations."""
    rec = reconstruction_of_tie_points(tie, poses, camera)
    explained = np.zeros(len(poses), dtype=np.int64)
    for point in rec.points3D.values():
        for image_id, _, err in point_errors(rec, point):
            if err <= max_px:
                explained[image_id - 1] += 1
    return explained, observations_by_image(tie, len(poses))
