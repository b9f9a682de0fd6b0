"""The ground truth of an evaluated session pair: each session's keyframes (chosen on its true poses) with their
footprints, the checks that two sessions can be scored against one another, and how a map's frame and landmarks
relate to that truth (its observing keyframes, its frame's camera centres)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...database.cameras import read_cameras_txt
from ...database.evaluation_io import check_same_crs, read_landmark_table, terrain_of_session
from ...database.landmark_map import LandmarkMap, read_landmark_map
from ...database.poses import read_poses_csv
from ...database.session_io import read_map_record
from ...database.synth_session import ground_truth_crs, ground_truth_frame
from ...plugin.errors import InputError
from ...plugin.evaluation.claims import observer_matrix
from ...plugin.evaluation.footprints import footprint_polygons
from ...plugin.evaluation.metrics import TP_IOU
from ...plugin.keyframes import select_keyframes
from ...plugin.multisession import Sim3
from ...plugin.params import Params


@dataclasses.dataclass
class GroundTruthSession:
    """Keyframes of one session with ground-truth poses and footprints."""

    path: Path
    names: list[str]  # keyframe image names
    frame_index: np.ndarray  # keyframe -> row of poses.csv
    centers: np.ndarray  # (K, 3) ground-truth camera centres of the keyframes
    all_names: list[str]
    all_centers: np.ndarray
    footprints: np.ndarray  # (K,) shapely polygons
    camera: Any = None  # the session's camera (cameras.txt)
    off_nadir_deg: float = 0.0  # the keyframes' median viewing angle from straight down
    height_m: float = float("nan")  # the keyframes' median camera height above the terrain


def load_ground_truth(params: Params, session: str | Path, dem: str | Path | None = None,
                      ground_height: float = 0.0, poses_file: str = "poses.csv") -> GroundTruthSession:
    """Keyframes (by travel on the ground-truth poses) and their footprints for one session directory."""
    session = Path(session)
    poses, epsg = read_poses_csv(session / poses_file)
    if len(poses) == 0:
        raise InputError("no poses", session / poses_file)
    cameras = read_cameras_txt(session / "cameras.txt")
    camera = cameras[min(cameras)]
    keys = select_keyframes(poses.centers, params.keyframes.interval_m)
    terrain = terrain_of_session(session, dem, ground_height, epsg, poses.centers[:, :2], session / poses_file)
    polys = footprint_polygons(camera, poses.rotations[keys], poses.centers[keys], terrain)
    from ...plugin.gps_track import off_nadir_deg

    centers = poses.centers[keys]
    return GroundTruthSession(session, [poses.names[k] for k in keys], keys, centers,
                              list(poses.names), poses.centers, polys, camera,
                              float(np.median(off_nadir_deg(poses.rotations[keys]))) if len(keys) else 0.0,
                              float(np.median(centers[:, 2] - terrain(centers[:, 0], centers[:, 1])))
                              if len(keys) else float("nan"))


def check_same_ground_truth_frame(session_a: Path, session_b: Path) -> None:
    """Refuse two synthetic sessions whose ground truths lie in different frames (two worlds, or a world and an
    orthophoto): the protocol compares their footprints and objects in one frame, and across worlds it would
    score a match against ground that neither map saw (footprints overlapping by coordinates only)."""
    frame_a, frame_b = ground_truth_frame(session_a), ground_truth_frame(session_b)
    if frame_a is not None and frame_b is not None and frame_a != frame_b:
        raise InputError(f"rendered in another world than {session_a} ({frame_b}, not {frame_a}): the two "
                         "sessions share no ground truth to score a match against", session_b / "session.json")


def _across_deg(camera: Any) -> float:
    """The camera's field of view across its width through the principal point (degrees; NaN when unknown)."""
    if camera is None:
        return float("nan")
    x = camera.cam_from_img(np.array([[0.0, camera.cy], [float(camera.width), camera.cy]]))[:, 0]
    return float(np.degrees(np.arctan(x[1]) - np.arctan(x[0])))


def footprint_size_cause(gt_a: GroundTruthSession, gt_b: GroundTruthSession, area_a: float, area_b: float) -> str:
    """Why two sessions' footprints differ in area, as measured: a footprint grows with the square of the camera's
    height above the ground and with its lens' field of view, so B's area over A's is the heights' factor (h_B /
    h_A)^2 times the rest (the fields of view, and how obliquely the cameras look); the larger of the two is named
    first (factors of B's area over A's). A wide-angle flight at 80 m against a zoom at 120 m was told they
    "differ this much in height"."""
    fov = f"{_across_deg(gt_a.camera):.0f} and {_across_deg(gt_b.camera):.0f} deg across"
    heights = f"{gt_a.height_m:.0f} and {gt_b.height_m:.0f} m above ground"
    if not (gt_a.height_m > 0 and gt_b.height_m > 0 and area_a > 0 and area_b > 0):
        return f"fields of view {fov}, heights {heights}"
    by_height = (gt_b.height_m / gt_a.height_m) ** 2
    by_lens = area_b / area_a / by_height
    parts = [(abs(np.log(by_height)), f"the heights ({heights}: x{by_height:.2f})"),
             (abs(np.log(by_lens)), f"the fields of view ({fov}: x{by_lens:.2f})")]
    parts.sort(key=lambda p: -p[0])
    return f"mostly by {parts[0][1]}, less by {parts[1][1]}"


def check_positive_pairs(gt_a: GroundTruthSession, gt_b: GroundTruthSession, iou: np.ndarray, where: Path) -> None:
    """Refuse a pair without one keyframe pair of IoU > TP_IOU: recall and F1 are undefined there, and the table
    said 0.000 with exit 0, also for a right alignment. IoU cannot exceed the ratio of the footprints' areas, so
    flights at very different heights (80 m and 150 m: 0.23) or with very different lenses (84 and 30 deg across:
    0.20) never reach it, nor do flights that do not overlap; the message names which of these it measured."""
    if iou.size and np.any(iou > TP_IOU):
        return
    import shapely

    area_a, area_b = (float(np.median(shapely.area(g.footprints))) if len(g.footprints) else 0.0
                      for g in (gt_a, gt_b))
    largest = float(iou.max()) if iou.size else 0.0
    head = f"no keyframe pair of the two sessions overlaps by IoU > {TP_IOU:.3f} (largest {largest:.2f})"
    cap = min(area_a, area_b) / max(area_a, area_b) if min(area_a, area_b) > 0 else 0.0
    if cap > TP_IOU or not min(area_a, area_b) > 0:  # the sizes allow it: where the footprints lie does not
        raise InputError(f"{head}; median footprints {area_a:.0f} and {area_b:.0f} m^2, whose sizes allow IoU up to "
                         f"{cap:.2f}: the flights do not overlap enough; the protocol's recall and F1 are undefined "
                         "for flights that do not overlap", where)
    raise InputError(f"{head}: median footprints {area_a:.0f} and {area_b:.0f} m^2 (IoU cannot exceed {cap:.2f}), "
                     f"{footprint_size_cause(gt_a, gt_b, area_a, area_b)}: the protocol's recall and F1 are undefined "
                     "for footprints this different in size", where)


def _keyframe_of_names(gt: GroundTruthSession, names: Sequence[str], where: Path) -> np.ndarray:
    """Evaluation keyframe index of each image name: the keyframe nearest to the image's ground-truth centre.

    Mapping may pick its keyframes on noisy (EKF) poses, so its images need not be the evaluation keyframes;
    at 2 m keyframe spacing against footprints ~100 m wide, snapping to the nearest one changes IoU by ~2 %.
    """
    from scipy.spatial import cKDTree

    row = {n: i for i, n in enumerate(gt.all_names)}
    missing = [n for n in names if n not in row]
    if missing:
        raise InputError(f"{len(missing)} image name(s) not in {gt.path / 'poses.csv'}, e.g. {missing[0]!r}", where)
    idx = np.fromiter((row[n] for n in names), dtype=np.int64, count=len(names))
    _, kf = cKDTree(gt.centers).query(gt.all_centers[idx]) if len(idx) else (None, np.zeros(0, np.int64))
    return np.asarray(kf, dtype=np.int64)


def world_from_map(session: Path, map_dir: Path, epsg: int) -> Sim3:
    """The transform from a map's frame into its session's ground-truth frame: the identity for a map in the
    world frame (built on the session's poses.csv or poses_ekf.csv), the world_to_crs offset taken off for a map
    georeferenced in the session's CRS (built from its DJI / EXIF geotags: UTM). Without it a right alignment of
    such a map with a local one was scored 5.2e6 m off, F1 0, "limited by front end", exit 0. A map in another CRS
    (the session's flight crossed a UTM zone edge) has no rigid relation to the truth: an error."""
    crs = ground_truth_crs(session)
    if crs is None or not epsg:
        return Sim3.identity()
    truth_epsg, offset = crs
    check_same_crs("map", epsg, f"the ground truth of {session}", truth_epsg, map_dir / "landmarks.sosmap")
    return Sim3(np.eye(3), -offset)


def _map_frame_centers(gt: GroundTruthSession, map_dir: Path, world_from: Sim3) -> np.ndarray:
    """The evaluation keyframes' camera centres in the frame of the map (the poses it was built on, as run.json
    records them: a synthetic session's EKF poses); else the ground-truth centres moved into the map's frame
    (`world_from`: `world_from_map`)."""
    truth = world_from.inverse().apply(gt.centers)
    try:
        source = Path((read_map_record(map_dir) or {})["inputs"]["poses"])
    except (InputError, KeyError, TypeError):
        return truth
    if not source.is_absolute():
        # a map made before run.json recorded absolute paths: its path is relative to a folder nobody knows now
        # (the cwd of `map`); the session's own file of that name is the one a synthetic session's map was built on
        source = Path(gt.path) / source.name
    if source.suffix != ".csv" or not source.is_file():
        return truth
    poses, _ = read_poses_csv(source)
    row = {n: i for i, n in enumerate(poses.names)}
    if not all(n in row for n in gt.names):
        return truth
    return poses.centers[[row[n] for n in gt.names]]


def _observers(gt: GroundTruthSession, map_dir: Path, max_observers: int | None,
               centers: np.ndarray) -> tuple[Any, Any]:
    """Each landmark's observing keyframes; `centers`: the keyframes' centres in the map's frame."""
    table = read_landmark_table(map_dir / "landmarks.csv")
    image_names = table.names_or_raise(map_dir / "landmarks.csv")  # not names an older format cut apart
    flat = [n for names in image_names for n in names]
    kf = _keyframe_of_names(gt, flat, map_dir / "landmarks.csv")
    splits = np.cumsum([len(n) for n in image_names])[:-1]
    obs = np.split(kf, splits) if len(image_names) else []
    return observer_matrix(obs, len(gt.names), table.positions[:, :2], centers[:, :2], max_observers), table


def _map_arrays(map_dir: Path) -> tuple[np.ndarray, np.ndarray, int, LandmarkMap | None]:
    """Landmark positions, sizes and the map's byte size (landmarks.sosmap if present, else the csv), and the
    landmark map itself (None without landmarks.sosmap)."""
    sosmap = map_dir / "landmarks.sosmap"
    if sosmap.exists():
        lmap = read_landmark_map(sosmap)
        return lmap.positions, lmap.sizes.astype(np.float64), sosmap.stat().st_size, lmap
    table = read_landmark_table(map_dir / "landmarks.csv")
    return table.positions, table.sizes, 52 + 14 * len(table.positions), None
