"""Refinement of GPS/telemetry poses from the images themselves: ORB tie points between overlapping images
(`tie_point_reconstruction`), then one of the bundle adjustments with the poses as priors, judged against them
(`refine_poses_from_images`)."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ...database.images import read_gray
from ...plugin.geometry import Poses
from .judge import RefinementRejected, RefinementStats, judge_refinement
from .with_colmap import poses_of_reconstruction, refine_poses_with_colmap
from .with_priors import refine_poses_with_priors

log = logging.getLogger(__name__)


def _orb_matches(desc_a: np.ndarray, desc_b: np.ndarray, kp_a: np.ndarray, kp_b: np.ndarray,
                 ransac_px: float) -> np.ndarray:
    """Indices (M, 2) of ORB matches between two images that pass Lowe's ratio test and a RANSAC homography
    (the ground is nearly flat, so a homography is the right image-only model; parallax outliers are dropped)."""
    from ...plugin.image_matching import homography_inliers, ratio_matches

    if desc_a is None or desc_b is None or len(desc_a) < 8 or len(desc_b) < 8:
        return np.zeros((0, 2), dtype=int)
    good = ratio_matches(desc_a, desc_b, 0.8)
    if len(good) < 12:
        return np.zeros((0, 2), dtype=int)
    inl = homography_inliers(kp_a[good[:, 0]], kp_b[good[:, 1]], ransac_px)
    if inl is None or inl.sum() < 12:
        return np.zeros((0, 2), dtype=int)
    return good[inl]


def tie_point_reconstruction(
    image_paths: list,
    poses: Poses,
    camera: object,
    max_features: int = 3000,
    neighbour_fraction: float = 0.6,
    ransac_px: float = 6.0,
    min_track_length: int = 3,
    max_neighbours: int = 8,
    min_ray_angle_deg: float = 2.0,
) -> object:
    """A pycolmap Reconstruction of ORB tie points with the given (prior) poses (changed by nothing here).

    Features per image (ORB, `max_features`); matches (ratio test + RANSAC homography at `ransac_px`) between each
    image and the next two, and between any two images whose centres are closer than `neighbour_fraction` x 4 x the
    median spacing of consecutive images (a typical 75% forward overlap puts ~4 spacings in a footprint; at most its
    `max_neighbours` nearest), which links neighbouring flight lines; tracks by union-find (tracks with two features
    in one image are dropped); points by least-squares intersection of the rays from the prior poses, dropped when
    the rays meet under less than `min_ray_angle_deg`.
    `camera` is a sosmatch Camera (any lens model: rays and the model go through it), image order = pose order.
    """
    import pycolmap

    from ...database.cameras import pycolmap_camera
    from ...plugin.image_matching import orb_features

    n = len(poses)
    kps, descs = [], []
    for path in image_paths:
        img = read_gray(path)
        if img.shape[1] != camera.width:
            raise ValueError(f"{path}: image width {img.shape[1]} differs from the camera's {camera.width}")
        features = orb_features(img, max_features)
        kps.append(features.colmap_points)
        descs.append(features.descriptors)
    spacing = np.median(np.linalg.norm(np.diff(poses.centers[:, :2], axis=0), axis=1)) if n > 1 else 1.0
    radius = neighbour_fraction * 4.0 * spacing
    d2 = np.linalg.norm(poses.centers[:, None, :2] - poses.centers[None, :, :2], axis=2)
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 3))}
    # each image with its `max_neighbours` nearest within the radius: enough to tie neighbouring flight lines
    # together, and matching cost stays linear in the number of images (all pairs in the radius: 2x the time)
    # self excluded explicitly: with two images at the same centre (hovering, quantised GPS) a stable argsort can
    # put the other one first, and the pair (i, i) would union features of one image and drop their tracks
    near = np.argsort(np.where(np.eye(n, dtype=bool), np.inf, d2), axis=1, kind="stable")[:, :max_neighbours]
    pairs |= {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in near[i] if i != j and d2[i, j] < radius}
    offsets = np.concatenate([[0], np.cumsum([len(k) for k in kps])])
    parent = np.arange(offsets[-1])

    def find(a: int) -> int:
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    n_pairs_ok = 0
    for i, j in sorted(pairs):
        m = _orb_matches(descs[i], descs[j], kps[i], kps[j], ransac_px)
        if len(m):
            n_pairs_ok += 1
        for a, b in m:
            ra, rb = find(offsets[i] + a), find(offsets[j] + b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(a) for a in range(offsets[-1])])
    img_of = np.repeat(np.arange(n), np.diff(offsets))
    order = np.argsort(roots, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(roots[order])) + 1)
    tracks = [g for g in groups if len(g) >= min_track_length and len(np.unique(img_of[g])) == len(g)]
    log.info("tie points: %d image pairs matched of %d tried, %d tracks of >= %d images", n_pairs_ok, len(pairs),
             len(tracks), min_track_length)

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap_camera(camera, 1))
    used = np.zeros(offsets[-1], dtype=bool)
    for g in tracks:
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
    for g in tracks:
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


def refine_poses_from_images(
    image_paths: list,
    poses: Poses,
    camera: object,
    position_sigma_m: float | tuple[float, float, float] = 3.0,
    attitude_sigma_deg: float = 5.0,
    pixel_sigma_px: float = 2.0,
    max_features: int = 2000,  # matching cost grows with its square: 3000 took 80 s of knnMatch on Seneca
    method: str = "colmap",
    accept_implausible: bool = False,
) -> tuple[Poses, RefinementStats]:
    """Refine GPS/telemetry poses BEFORE mapping, with ORB tie points between overlapping images and the pose
    priors (`tie_point_reconstruction`, then `refine_poses_with_colmap` (method "colmap", the default: COLMAP's
    pose-prior bundle adjustment, position priors only, seconds) or `refine_poses_with_priors` (method "scipy":
    position and attitude priors, minutes)). Returns the refined poses (same names and order, same world frame)
    and the statistics. Use it when the poses are far from EKF quality: the mapping's epipolar gate (a few
    pixels) cannot track segments across frames whose poses are 100+ px off.

    The result is judged against the priors (`judge_refinement`): warnings are logged and kept in the stats;
    errors raise RefinementRejected unless `accept_implausible` (then they are logged as warnings)."""
    if method not in ("colmap", "scipy"):
        raise ValueError(f"unknown refinement method {method!r} (colmap or scipy)")
    rec = tie_point_reconstruction(image_paths, poses, camera, max_features)
    if method == "colmap":
        sigma = float(np.max(np.atleast_1d(position_sigma_m)))
        stats = refine_poses_with_colmap(rec, poses, sigma, pixel_sigma_px)
    else:
        stats = refine_poses_with_priors(rec, poses, position_sigma_m, attitude_sigma_deg, pixel_sigma_px)
    refined = poses_of_reconstruction(rec)
    missing = [nm for nm in poses.names if nm not in refined.names]
    if missing:
        raise ValueError(f"{len(missing)} images lost their pose in the refinement (e.g. {missing[0]})")
    order = [refined.names.index(nm) for nm in poses.names]
    errors, warnings = judge_refinement(stats, position_sigma_m, attitude_sigma_deg)
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
    return refined.subset(order), stats
