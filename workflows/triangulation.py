"""Landmarks from a session's COLMAP database with fixed poses (SOS-Match step 6), through pycolmap.

pycolmap objects are I/O-ish (they read the database and write models), so this lives in workflows/, not in
plugin/. Steps:
1. a `pycolmap.Reconstruction` with the one camera and every keyframe registered at its known pose
   (cam_from_world; frame ids equal the database's image ids);
2. `pycolmap.triangulate_points` from the verified pairs (frames and intrinsics held fixed), with reprojection
   thresholds raised from COLMAP's 4 px to `max_reprojection_error_px` because centroid noise is ~3 px, and
   two-view tracks triangulated only where the parameters admit them (`fewest_observations`);
3. a points-only bundle adjustment: every pose and intrinsic constant, Huber loss at 2 x `pixel_sigma_px`;
4. filtering: a landmark needs more than `min_observations` observations (theta_n), a mean reprojection error
   within `max_reprojection_error_px`, positive depth in every observing camera and a largest ray angle of at
   least `min_triangulation_angle_deg`; the point is then located from the views that see its mask whole
   (`located_from_whole_masks`, `whole_masks_only`), and a point moved there records its error over those
   views (the filter judged the bundle-adjusted one). Dropped points are deleted from the reconstruction too, so
   sparse/ and the landmark map agree;
5. metric size per landmark (`plugin.landmark_size`, `size_estimator`): the paper's mean of h_px x depth / f
   over the observations, or (default) the nadir-equivalent size fitted over them;
6. duplicate suppression (`duplicate_radius_factor`, see `suppress_duplicates`): landmarks of nested or
   partial masks of one object are dropped in favour of the best-supported one (deleted from the
   reconstruction too).
7. height outliers (`height_outlier_sigmas`, see `plugin.landmark_filters.height_outliers`): wrong tracks
   that straight-line views triangulated far off the ground of their neighbours are dropped (deleted too);
   landmarks a whole flying height above or below their neighbours are dropped always
   (`landmark_filters.beyond_flying_height`: physically impossible, whatever the map's spread).
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..plugin.landmark_filters import beyond_flying_height, height_outliers
from ..plugin.landmark_size import SIZE_ESTIMATORS, cut_by_border, mean_size, nadir_size
from ..plugin.map_noise import MapNoise, measure_map_noise
from ..plugin.params import TriangulationParams
from ..plugin.track_fusion import TrackPiece, candidate_pairs, fuse_tracks

if TYPE_CHECKING:
    import pycolmap

log = logging.getLogger(__name__)


@dataclass
class Landmarks:
    """Triangulated landmarks in map order (first track id, then point id), plus what was dropped."""

    positions: np.ndarray  # (L, 3) world frame
    sizes_m: np.ndarray  # (L,) metric size h_S
    num_observations: np.ndarray  # (L,)
    point3d_ids: np.ndarray  # (L,) ids in the pycolmap reconstruction / sparse model
    track_ids: np.ndarray  # (L,) smallest tracker track id of the observations (first sighting)
    errors_px: np.ndarray  # (L,) mean reprojection error of the point: after the points-only BA, or over the
    # whole views for a landmark they locate (`located_from_whole_masks`)
    observations: list[np.ndarray]  # per landmark: (n, 2) int (keyframe index, mask index), keyframe order
    counts: dict[str, int] = field(default_factory=dict)  # triangulated / dropped_* / kept
    noise: MapNoise | None = None  # the map's own noise figures (`plugin.map_noise`), with centroids + covariances
    reconstruction: Any = field(default=None, repr=False)  # pycolmap.Reconstruction holding exactly these points

    def __len__(self) -> int:
        return len(self.positions)


def build_reconstruction(camera: Camera, poses: Poses) -> pycolmap.Reconstruction:
    """A pycolmap Reconstruction with camera id 1 (the camera's own model: pycolmap projects through its
    distortion) and image/frame ids 1..N registered at the given poses."""
    import pycolmap

    from ..database.cameras import pycolmap_camera

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap_camera(camera, 1))
    r_cw, t_cw = poses.cam_from_world()
    for i, name in enumerate(poses.names):
        image = pycolmap.Image(name=str(name), camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw[i]), t_cw[i]))
    return rec


def fixed_camera_ba_options(loss: Any, loss_scale_px: float, refine_poses: bool) -> Any:
    """pycolmap BundleAdjustmentOptions with the intrinsics and rig held fixed, points refined, poses refined only
    with `refine_poses`, the given robust loss, quiet and single-threaded (the same result on every run)."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = False
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.refine_sensor_from_rig = False
    options.refine_rig_from_world = bool(refine_poses)
    options.refine_points3D = True
    options.print_summary = False
    options.ceres.loss_function_type = loss
    options.ceres.loss_function_scale = float(loss_scale_px)
    options.ceres.solver_options.num_threads = 1
    return options


def refine_points_only(rec: pycolmap.Reconstruction, pixel_sigma_px: float) -> None:
    """Bundle adjustment of the 3D points alone (poses and intrinsics constant), Huber loss at 2 sigma."""
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    for frame_id in rec.reg_frame_ids():
        config.set_constant_rig_from_world_pose(frame_id)
    for camera_id in rec.cameras:
        config.set_constant_cam_intrinsics(camera_id)
    options = fixed_camera_ba_options(pycolmap.LossFunctionType.HUBER, 2.0 * pixel_sigma_px, refine_poses=False)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    rec.update_point_3d_errors()


def _max_ray_angles_deg(centers: np.ndarray, point: np.ndarray) -> float:
    rays = point[None, :] - centers
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    cos = np.clip(rays @ rays.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def suppress_duplicates(
    positions: np.ndarray, sizes_m: np.ndarray, num_observations: np.ndarray, errors_px: np.ndarray,
    radius_factor: float,
) -> np.ndarray:
    """Which landmarks survive duplicate suppression: a boolean (L,) keep mask.

    A segmenter that keeps several levels of a merge hierarchy (or SAM's multimask output) returns nested and
    partial masks of one object in the same frames: a crown part, the crown, the clump it belongs to. Each is
    tracked on its own and becomes its own landmark a metre or two from the others. Landmarks i, j are called
    duplicates when their ground-plane (x, y) distance is at most `radius_factor` x max(h_i, h_j) (metric sizes):
    h = sqrt(lambda_max) is half the radius of a disc, so at the default factor 2 a landmark is a duplicate when
    it lies inside the other's footprint. The centroid of a part of a disc lies within ~0.85 h of the disc's and a
    two-crown clump's within ~0.9 h of each crown, while two touching distinct discs are 2 (h_i + h_j) apart,
    more than 2 max(h_i, h_j) (elongated objects have less margin across their short axis). The vertical is
    left out because it is the noisy direction of a nadir survey (a few metres at 100 m AGL), larger than the
    offsets between nested masks.

    Greedy non-maximum suppression in order of support (most observations, then lowest reprojection error,
    then index): a landmark is dropped when a kept one is its duplicate, so every dropped landmark has a kept
    better-supported one within the radius, and two kept landmarks are never duplicates. Deterministic.
    """
    n = len(positions)
    keep = np.ones(n, dtype=bool)
    if n < 2 or radius_factor <= 0:
        return keep
    xy = np.asarray(positions, dtype=np.float64)[:, :2]
    sizes = np.asarray(sizes_m, dtype=np.float64)
    i, j = candidate_pairs(xy, radius_factor * sizes)
    if len(i) == 0:
        return keep
    dup = np.linalg.norm(xy[i] - xy[j], axis=1) <= radius_factor * np.maximum(sizes[i], sizes[j])
    i, j = i[dup], j[dup]
    order = np.lexsort((np.arange(n), np.asarray(errors_px, np.float64), -np.asarray(num_observations)))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    # orient every duplicate pair (better, worse); visit landmarks best first
    better = np.where(rank[i] < rank[j], i, j)
    worse = np.where(rank[i] < rank[j], j, i)
    by_better = np.argsort(better, kind="stable")
    starts = np.searchsorted(better[by_better], np.arange(n + 1))
    for k in order:
        if keep[k]:
            keep[worse[by_better[starts[k]:starts[k + 1]]]] = False
    return keep


def located_from_whole_masks(camera: Camera, poses: Poses, obs: np.ndarray, point: np.ndarray,
                             centroids_px: list[np.ndarray], cut_px: list[np.ndarray],
                             min_angle_deg: float) -> tuple[np.ndarray, np.ndarray] | None:
    """A landmark's point from the views that see its mask whole, and which of `obs` those are (bool (n,));
    None when they cannot fix one.

    A mask cut by the image border (`cut_px`: per keyframe, per mask, from `truncation.cut_masks`, tested in
    the real image) shows only the part of its object inside the frame, so its centroid slides with the camera
    instead of staying on one ground point: with the whole views of its track it pulls the point metres down
    (nu22, keyframes 2 m apart: 46 of 396 landmarks > 5 m below the ground, their views cut 87 % of the time
    against 4 % for the others). The cut views stay observations of the track (its evidence that the segment
    persists: theta_n counts them); only the whole ones locate it: `point` itself when no view is cut, the
    least-squares point of the whole views (`track_fusion.intersect_rays`) when at least two of them span
    `min_angle_deg`, else None. `camera` is the pinhole camera of the undistorted `centroids_px` (per keyframe,
    per mask); obs (n, 2) rows of (keyframe, mask). The point returned is `point` itself (the same object) when
    no view is cut."""
    from ..plugin.track_fusion import intersect_rays

    pixels = np.array([centroids_px[k][i] for k, i in obs], dtype=np.float64).reshape(-1, 2)
    cut = np.array([cut_px[k][i] for k, i in obs], dtype=bool).reshape(-1)
    if not cut.any():
        return point, ~cut
    whole = obs[~cut, 0]
    if len(whole) < 2:
        return None
    located = intersect_rays(camera, poses, whole, pixels[~cut])
    if not np.all(np.isfinite(located)) or _max_ray_angles_deg(poses.centers[whole], located) < min_angle_deg:
        return None
    return located, ~cut


def mean_reprojection_error(rec: pycolmap.Reconstruction, obs: np.ndarray, xyz: np.ndarray) -> float:
    """Mean pixel distance between the keypoints of observations `obs` ((n, 2) rows of (keyframe, mask); image id
    = keyframe + 1) and the projection of `xyz` through the reconstruction's camera (COLMAP's point error, over
    these observations); inf when a camera sees the point behind it."""
    errors = []
    for k, i in obs:
        image = rec.images[int(k) + 1]
        uv = image.project_point(np.asarray(xyz, np.float64))
        if uv is None:
            return float("inf")
        errors.append(np.linalg.norm(np.asarray(uv).ravel() - np.asarray(image.points2D[int(i)].xy)))
    return float(np.mean(errors))


def _observations(rec: pycolmap.Reconstruction, pid: int) -> np.ndarray:
    """(n, 2) int (keyframe index, mask index) of a point's track, in keyframe order (image id = keyframe + 1)."""
    obs = np.array([(el.image_id - 1, el.point2D_idx) for el in rec.points3D[pid].track.elements], dtype=np.int64)
    return obs[np.argsort(obs[:, 0], kind="stable")]


def fuse_split_tracks(rec: pycolmap.Reconstruction, camera: Camera, poses: Poses,
                      size_of: Callable[[np.ndarray, np.ndarray], float], params: TriangulationParams) -> int:
    """Merge the points of tracks that are pieces of one object (`plugin.track_fusion.fuse_tracks`) into one
    point each (pycolmap merge_points3D, then a points-only BA of the merged ones); returns the merges made."""
    pids = sorted(rec.point3D_ids())
    pieces = []
    for pid in pids:
        obs = _observations(rec, pid)
        xyz = np.asarray(rec.points3D[pid].xyz, dtype=np.float64)
        pixels = np.array([rec.images[int(k) + 1].points2D[int(i)].xy for k, i in obs], dtype=np.float64)
        pieces.append(TrackPiece(obs[:, 0], camera.undistort_points(pixels), xyz, size_of(obs, xyz)))
    groups = fuse_tracks(pieces, camera.pinhole(), poses, params.fuse_radius_factor, params.fuse_size_tolerance,
                         params.max_reprojection_error_px)
    merges = 0
    for group in groups:
        if len(group) < 2:
            continue
        merged = pids[group[0]]
        for k in group[1:]:
            merged = rec.merge_points3D(merged, pids[k])
            merges += 1
    if merges:
        refine_points_only(rec, params.pixel_sigma_px)
    return merges


def fewest_observations(params: TriangulationParams) -> int:
    """The fewest observations of a track that triangulation uses: theta_n + 1 for a landmark of its own, and
    `min_piece_observations` for a piece when fusion is on (pieces of one object become one landmark, to which
    theta_n applies). The map writes the matches of these tracks to the database, and pycolmap triangulates
    two-view tracks only when this is 2 (COLMAP ignores them otherwise: they cannot show a bad observation)."""
    fewest = params.min_observations + 1
    return fewest if params.fuse_radius_factor <= 0 else min(fewest, params.min_piece_observations)


class LandmarkRow(NamedTuple):
    """One landmark kept by the per-point filters of `triangulate_landmarks`, before the map-wide ones."""

    track: int  # smallest tracker track id of the observations (-1: untracked)
    point_id: int  # id in the pycolmap reconstruction
    xyz: np.ndarray  # (3,) where the map has it (moved to its whole views, `located_from_whole_masks`)
    size_m: float
    num_observations: int
    error_px: float  # recorded error: over the whole views for a moved landmark, else the bundle-adjusted one
    observations: np.ndarray  # (n, 2) (keyframe index, mask index)
    adjusted_error_px: float  # the bundle-adjusted point's error over all the track's views


def duplicates_kept(rows: list[LandmarkRow], radius_factor: float) -> np.ndarray:
    """`suppress_duplicates` over landmark rows: the boolean keep mask.

    Duplicates are ranked by the bundle-adjusted error (over all of each track's views), the error the
    reprojection filter judged, not the recorded one: a landmark moved to its whole views records an error over
    fewer, different views, and comparing errors over different views ranked moved landmarks too well (rev36: s1
    at duplicate_radius_factor 2 kept 74 landmarks instead of 79; commit aae0162).
    """
    return suppress_duplicates(np.array([r.xyz for r in rows]).reshape(-1, 3), np.array([r.size_m for r in rows]),
                               np.array([r.num_observations for r in rows]),
                               np.array([r.adjusted_error_px for r in rows]), radius_factor)


def _drop_rows(rec: pycolmap.Reconstruction, rows: list, keep: np.ndarray) -> tuple[list, int]:
    """Keep the landmark rows where `keep` (row[1] = point id); the others are deleted from `rec` too, so
    sparse/ and the landmark map agree. Returns (kept rows, number dropped)."""
    for r in (r for r, k in zip(rows, keep) if not k):
        rec.delete_point3D(r[1])
    return [r for r, k in zip(rows, keep) if k], int(np.count_nonzero(~keep))


def triangulate_landmarks(
    db_path: str | Path,
    camera: Camera,
    poses: Poses,
    sizes_px: list[np.ndarray],
    track_ids: list[np.ndarray],
    params: TriangulationParams,
    seed: int = 0,
    centroids_px: list[np.ndarray] | None = None,
    covariances_px: list[np.ndarray] | None = None,
    cut_px: list[np.ndarray] | None = None,
) -> Landmarks:
    """Triangulate the landmarks of a session database written by `write_colmap_database`.

    Args:
        db_path: the COLMAP database (image i of `poses` has image id i + 1).
        camera: the pinhole camera.
        poses: keyframe poses, in database image order (world_from_camera).
        sizes_px: per keyframe, the pixel size h = sqrt(lambda_max(Sigma)) of every mask (keypoint row order).
        track_ids: per keyframe, the tracker's track id of every mask (-1: none); used to order the landmarks.
        params: triangulation parameters (theta_n, sigma, filters).
        seed: random seed for COLMAP's RANSAC triangulation.
        centroids_px, covariances_px: per keyframe, the centroid (k, 2) and pixel covariance (k, 2, 2) of every
            mask, undistorted (pixels of `camera.pinhole()`, like `sizes_px`); needed by the "nadir" size
            estimator (without them the paper's mean is used).
        cut_px: per keyframe, (k,) whether the real image's border cuts each mask (`truncation.cut_masks` of
            the undistorted features: tested where the masks were segmented). None: tested on `centroids_px` /
            `covariances_px` against the pinhole's image, which is the real one only for a camera without
            distortion (a lens camera without them is refused: its undistorted image is not that rectangle).
    """
    import pycolmap

    if cut_px is None and centroids_px is not None and covariances_px is not None:
        if not camera.is_pinhole:
            raise ValueError("triangulate_landmarks: a lens camera's cut masks are tested in the real image: "
                             "pass cut_px (truncation.cut_masks of the undistorted features)")
        cut_px = [cut_by_border(camera, c, v) for c, v in zip(centroids_px, covariances_px)]
    rec = build_reconstruction(camera, poses)
    options = pycolmap.IncrementalPipelineOptions()
    options.triangulation.merge_max_reproj_error = params.max_reprojection_error_px
    options.triangulation.complete_max_reproj_error = params.max_reprojection_error_px
    options.triangulation.min_angle = params.min_triangulation_angle_deg
    # theta_n = 1 or pieces of two observations admit two-view tracks (README, "Triangulation"); without either
    # setting none is written to the database anyway
    options.triangulation.ignore_two_view_tracks = fewest_observations(params) > 2
    options.triangulation.random_seed = seed
    options.mapper.filter_max_reproj_error = params.max_reprojection_error_px
    options.mapper.filter_min_tri_angle = params.min_triangulation_angle_deg
    options.mapper.random_seed = seed
    options.random_seed = seed
    options.extract_colors = False
    # COLMAP ignores image pairs with fewer than 15 verified matches (min_num_matches) when it builds the
    # correspondence graph: right for SIFT, wrong for segments, where two keyframes share a handful of tracks
    # (Seneca: ~3 per pair, so 7 of ~60 consistent tracks became points). Every association counts here.
    options.min_num_matches = 1
    options.num_threads = 1  # same points on every run (resume must reproduce an uninterrupted run)
    options.mapper.num_threads = 1
    with tempfile.TemporaryDirectory(prefix="sosmatch-tri-") as tmp:
        image_dir = Path(tmp) / "images"  # never read: colours are not extracted
        out_dir = Path(tmp) / "model"
        image_dir.mkdir()
        out_dir.mkdir()
        rec = pycolmap.triangulate_points(rec, str(db_path), str(image_dir), str(out_dir), clear_points=True,
                                          options=options, refine_intrinsics=False)
    counts = {"triangulated": int(rec.num_points3D())}
    if rec.num_points3D():
        refine_points_only(rec, params.pixel_sigma_px)

    r_cw, t_cw = poses.cam_from_world()
    if params.size_estimator not in SIZE_ESTIMATORS:
        raise InputError(f"triangulation.size_estimator must be one of {', '.join(SIZE_ESTIMATORS)}, got "
                         f"{params.size_estimator!r}")
    nadir = params.size_estimator == "nadir" and centroids_px is not None and covariances_px is not None
    pinhole = camera.pinhole()  # sizes are measured on undistorted masks, through the equivalent pinhole

    def size_of(obs: np.ndarray, xyz: np.ndarray) -> float:
        kf = obs[:, 0]
        if nadir:
            return nadir_size(pinhole, poses.rotations[kf], poses.centers[kf], xyz,
                              np.array([centroids_px[k][i] for k, i in obs]),
                              np.array([covariances_px[k][i] for k, i in obs]), params.min_observations + 1,
                              np.array([cut_px[k][i] for k, i in obs], dtype=bool))
        return mean_size(pinhole, poses.rotations[kf], poses.centers[kf], xyz,
                         np.array([sizes_px[k][i] for k, i in obs], dtype=np.float64))

    counts["fused"] = fuse_split_tracks(rec, camera, poses, size_of, params) if params.fuse_radius_factor > 0 else 0
    drop = {"few_observations": 0, "reprojection": 0, "behind_camera": 0, "small_angle": 0, "cut_by_border": 0,
            "duplicate": 0, "height_outlier": 0, "beyond_flying_height": 0}
    locate_whole = params.whole_masks_only and centroids_px is not None and covariances_px is not None
    rows: list[LandmarkRow] = []

    def behind_a_camera(kf: np.ndarray, x: np.ndarray) -> bool:
        return bool(np.any(r_cw[kf, 2, :] @ x + t_cw[kf, 2] <= 0))

    for pid in sorted(rec.point3D_ids()):
        point = rec.points3D[pid]
        obs = _observations(rec, pid)
        xyz = np.asarray(point.xyz, dtype=np.float64)
        # the bundle-adjusted point's error: what the filter below and duplicate suppression judge (over all the
        # track's views, as before a landmark moved); a moved landmark records another (its whole views')
        adjusted_error = float(point.error)
        reason = None
        if len(obs) <= params.min_observations:
            reason = "few_observations"
        elif not np.isfinite(adjusted_error) or adjusted_error > params.max_reprojection_error_px:
            reason = "reprojection"
        elif behind_a_camera(obs[:, 0], xyz):
            reason = "behind_camera"
        elif _max_ray_angles_deg(poses.centers[obs[:, 0]], xyz) < params.min_triangulation_angle_deg:
            reason = "small_angle"
        elif locate_whole:
            located = located_from_whole_masks(pinhole, poses, obs, xyz, centroids_px, cut_px,
                                               params.min_triangulation_angle_deg)
            if located is None:
                reason = "cut_by_border"
            elif located[0] is not xyz:
                xyz, whole = located
                point.xyz = xyz  # sparse/ holds the landmark where the map has it
                # and its error is the one over the views that located it (errors_px, the quality line, run.json
                # read it): a cut view's centroid is off by design, by metres at the border, so over all views
                # the error measures the cut, not the landmark. The filter above judged the bundle-adjusted
                # point, as before the landmark moved (BENCHMARKS.md, "Errors of landmarks located from whole
                # views").
                point.error = mean_reprojection_error(rec, obs[whole], xyz)
                if behind_a_camera(obs[:, 0], xyz):
                    reason = "behind_camera"
        if reason is not None:
            drop[reason] += 1
            rec.delete_point3D(pid)
            continue
        tids = np.array([track_ids[k][i] for k, i in obs])
        tids = tids[tids >= 0]
        # a fused landmark holds several tracks: it takes its first sighting's (the smallest id), so that two
        # maps flown over one path order an object by the same pass (the search's windows are id ranges)
        track = int(tids.min()) if len(tids) else -1
        rows.append(LandmarkRow(track, pid, xyz, size_of(obs, xyz), len(obs), float(point.error), obs, adjusted_error))
    if rows and params.duplicate_radius_factor > 0:
        keep = duplicates_kept(rows, params.duplicate_radius_factor)
        rows, drop["duplicate"] = _drop_rows(rec, rows, keep)
    if rows and params.height_outlier_sigmas > 0:
        bad = height_outliers(np.array([r[2] for r in rows]), params.height_outlier_neighbours,
                              params.height_outlier_sigmas)
        rows, drop["height_outlier"] = _drop_rows(rec, rows, ~bad)
    if rows:  # physically impossible heights, whatever the map's spread (`landmark_filters.beyond_flying_height`)
        far = beyond_flying_height(np.array([r[2] for r in rows]), poses.centers, params.height_outlier_neighbours)
        rows, drop["beyond_flying_height"] = _drop_rows(rec, rows, ~far)
    # Map order: by track id (roughly time of first sighting), then point id (untracked last).
    rows.sort(key=lambda r: (r[0] < 0, r[0], r[1]))
    counts.update({f"dropped_{k}": v for k, v in drop.items()})
    counts["kept"] = len(rows)
    counts["tracks_split"] = len(rows) - len({r[0] for r in rows})
    noise = None
    if centroids_px is not None and covariances_px is not None:
        obs = [r[6] for r in rows]
        noise = measure_map_noise(pinhole, poses.rotations, poses.centers, [r[2] for r in rows], [o[:, 0] for o in obs],
                                  [np.array([centroids_px[k][i] for k, i in o]).reshape(-1, 2) for o in obs],
                                  [np.array([covariances_px[k][i] for k, i in o]).reshape(-1, 2, 2) for o in obs])
    return Landmarks(
        positions=np.array([r[2] for r in rows], dtype=np.float64).reshape(-1, 3),
        sizes_m=np.array([r[3] for r in rows], dtype=np.float64),
        num_observations=np.array([r[4] for r in rows], dtype=np.int64),
        point3d_ids=np.array([r[1] for r in rows], dtype=np.int64),
        track_ids=np.array([r[0] for r in rows], dtype=np.int64),
        errors_px=np.array([r[5] for r in rows], dtype=np.float64),
        observations=[r[6] for r in rows],
        counts=counts,
        noise=noise,
        reconstruction=rec,
    )
