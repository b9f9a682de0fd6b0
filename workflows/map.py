"""`sosmatch map`: images + fixed poses -> a mapped session directory (SOS-Match section 1).

Stages (docs/ARCHITECTURE.md, "The data walk"):
1. inputs: poses from a pose CSV (quaternion or yaw/pitch/roll), a COLMAP model or a `sosmatch synth` session;
   intrinsics from a cameras file, the COLMAP model or the synth session; images matched to poses by name;
2. keyframes every `keyframes.interval_m` of travel;
3. per keyframe (cached): segmentation, mask description, image-motion statistics to the previous keyframe;
4. tracking (method.md 1.5);
5. COLMAP database: mask centroids as keypoints, every pair of observations of a long-enough track as a
   verified match (checked against the known poses with the Sampson distance);
6. pycolmap triangulation with the fixed poses, points-only BA, landmark filters, metric sizes
   (`sosmatch.workflows.triangulation`);
7. outputs: database.db, sparse/, landmarks.sosmap, landmarks.ply, landmarks.csv, run.json.

Robustness: everything is built in SESSION_DIR/.partial and moved into place at the end (run.json last, so a
directory with run.json is complete). The per-keyframe results live in SESSION_DIR/.partial/cache/, each
written atomically, so a killed run resumes where it stopped and ends with the same outputs. An existing
session made from other inputs is refused unless `overwrite=True`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import atomic_path, write_text_atomic
from ..database.cameras import read_cameras_txt
from ..database.colmap_db import (
    affine_keypoints,
    check_database_writable,
    track_associations,
    verify_associations,
    write_colmap_database,
)
from ..database.colmap_model import is_colmap_model, read_camera_file, read_colmap_model_poses, write_model, write_ply
from ..database.landmark_map import LandmarkMap, write_landmark_map
from ..database.poses import read_poses_csv
from ..plugin import __version__
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..plugin.params import Params, params_to_dict

log = logging.getLogger(__name__)

PARTIAL = ".partial"
CACHE_VERSION = 1
OUTPUTS = ("database.db", "sparse", "landmarks.sosmap", "landmarks.ply", "landmarks.csv")
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")


# ---------------------------------------------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class MapInputs:
    """Resolved inputs: images in acquisition order with their poses, the camera, and where each came from."""

    image_paths: list[Path]
    poses: Poses  # same order as image_paths; names are the image names stored in the database
    camera: Camera
    epsg: int = 0
    sources: dict[str, str] = field(default_factory=dict)


def _is_synth_session(path: Path) -> bool:
    return path.is_dir() and (path / "session.json").is_file() and (path / "poses.csv").is_file()


def load_inputs(
    images: str | Path | None,
    poses: str | Path,
    camera: str | Path | None = None,
    convention: str | None = None,
    ekf: bool = False,
    strict: bool = False,
) -> MapInputs:
    """Read and validate poses, intrinsics and the image list; pair images with poses by name.

    Args:
        images: image directory (optional when `poses` is a synth session: its images/ is used).
        poses: a pose CSV, a COLMAP model directory (or its images.bin/.txt), or a `sosmatch synth` session.
        camera: cameras.txt / cameras.bin / model directory; optional when `poses` provides the intrinsics (a
            synth session, a COLMAP model, or a pose CSV with a one-camera cameras.txt beside it).
        convention: overrides the pose CSV's `# convention:` comment.
        ekf: with a synth session, use its noisy poses_ekf.csv instead of the ground truth.
        strict: images without a pose or poses without an image are an error instead of a warning.
    """
    poses = Path(poses)
    sources: dict[str, str] = {}
    cam_from_poses: Camera | None = None
    epsg = 0
    if not poses.exists():
        raise InputError("pose file not found", poses)
    if _is_synth_session(poses):
        pose_file = poses / ("poses_ekf.csv" if ekf else "poses.csv")
        pose_list, epsg = read_poses_csv(pose_file, convention)
        sources["poses"] = str(pose_file)
        cams = read_cameras_txt(poses / "cameras.txt")
        cam_from_poses = next(iter(cams.values())) if len(cams) == 1 else None
        if images is None:
            images = poses / "images"
    elif is_colmap_model(poses):
        pose_list, cams, _ = read_colmap_model_poses(poses)
        sources["poses"] = str(poses)
        if len(cams) == 1:
            cam_from_poses = next(iter(cams.values()))
    else:
        if ekf:
            raise InputError("--ekf needs a synth session directory as --poses", poses)
        pose_list, epsg = read_poses_csv(poses, convention)
        sources["poses"] = str(poses)
        beside = poses.parent / "cameras.txt"  # where `sosmatch poses-from-exif` puts the intrinsics
        if camera is None and beside.is_file():
            cams = read_cameras_txt(beside)
            if len(cams) == 1:
                cam_from_poses = next(iter(cams.values()))
                sources["camera"] = str(beside)
    if camera is not None:
        cam = read_camera_file(camera)
        sources["camera"] = str(camera)
    elif cam_from_poses is not None:
        cam = cam_from_poses
        sources.setdefault("camera", sources["poses"])
    else:
        raise InputError("no camera intrinsics: give --camera (cameras.txt, cameras.bin or a COLMAP model)", poses)
    if images is None:
        raise InputError("no image directory: give --images", poses)
    images = Path(images)
    if not images.is_dir():
        raise InputError("image directory not found", images)
    sources["images"] = str(images)
    files = {f.name: f for f in images.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_EXTENSIONS}
    keep = []
    missing = []
    for i, name in enumerate(pose_list.names):
        path = images / name
        if path.is_file():
            keep.append((i, path))
        elif Path(name).name in files:  # poses may carry a sub-path ("images/x.jpg"); match by file name
            keep.append((i, files[Path(name).name]))
        else:
            missing.append(name)
    used = {p.name for _, p in keep}
    unposed = sorted(n for n in files if n not in used)
    for what, names in (("pose(s) without an image", missing), ("image(s) without a pose", unposed)):
        if names:
            listing = ", ".join(names[:8]) + (f" ... ({len(names)} in all)" if len(names) > 8 else "")
            if strict:
                raise InputError(f"{len(names)} {what}: {listing}", images)
            log.warning("skipping %d %s: %s", len(names), what, listing)
    if len(keep) < 2:
        raise InputError(f"only {len(keep)} image(s) have a pose; need at least 2", images)
    sub = pose_list.subset([i for i, _ in keep])
    sub.names = [p.name for _, p in keep]
    return MapInputs([p for _, p in keep], sub, cam, epsg, sources)


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def input_fingerprints(inputs: MapInputs) -> dict[str, str]:
    """sha256 of the images (names + contents), the poses (as used, full precision) and the camera."""
    h_img = hashlib.sha256()
    for p in inputs.image_paths:
        h_img.update(p.name.encode() + b"\0" + _sha256_file(p).encode() + b"\n")
    h_pose = hashlib.sha256()
    h_pose.update("\n".join(inputs.poses.names).encode())
    h_pose.update(np.ascontiguousarray(inputs.poses.rotations).tobytes())
    h_pose.update(np.ascontiguousarray(inputs.poses.centers).tobytes())
    h_pose.update(str(inputs.epsg).encode())
    c = inputs.camera
    h_cam = hashlib.sha256(repr((c.width, c.height, c.fx, c.fy, c.cx, c.cy)).encode())
    combined = hashlib.sha256((h_img.hexdigest() + h_pose.hexdigest() + h_cam.hexdigest()).encode())
    return {"images": h_img.hexdigest(), "poses": h_pose.hexdigest(), "camera": h_cam.hexdigest(),
            "inputs": combined.hexdigest()}


def _hash_json(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------------------------
# Output directory
# ---------------------------------------------------------------------------------------------------------------
def prepare_output_dir(out_dir: Path, fingerprint: str, overwrite: bool) -> Path:
    """Check that `out_dir` may receive this run; create SESSION_DIR/.partial and return it.

    Refuses (InputError) a directory that cannot be written, a session made from other inputs, a non-empty
    directory that is not a sosmatch session (unless `overwrite`), and a database locked by another process.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("output path exists and is not a directory", out_dir)
    run_json = out_dir / "run.json"
    if out_dir.is_dir() and not overwrite:
        if run_json.is_file():
            try:
                previous = json.loads(run_json.read_text(encoding="utf-8"))["fingerprints"]["inputs"]
            except (OSError, ValueError, KeyError, TypeError):
                previous = None
            if previous != fingerprint:
                raise InputError("output directory holds a session made from other inputs (use --overwrite to "
                                 "replace it)", out_dir)
        else:
            others = [p.name for p in out_dir.iterdir() if p.name != PARTIAL]
            try:  # an interrupted run (possibly killed while moving its outputs into place) left its inputs here
                started = json.loads((out_dir / PARTIAL / "inputs.json").read_text(encoding="utf-8"))["inputs"]
            except (OSError, ValueError, KeyError, TypeError):
                started = None
            if started is not None and started != fingerprint:
                raise InputError("output directory holds an interrupted run from other inputs (use --overwrite to "
                                 "replace it)", out_dir)
            if others and started is None:
                raise InputError(f"output directory is not empty and is not a sosmatch session ({others[0]}, ...);"
                                 " use --overwrite to write into it anyway", out_dir)
    check_database_writable(out_dir / "database.db")
    partial = out_dir / PARTIAL
    try:
        partial.mkdir(parents=True, exist_ok=True)
        write_text_atomic(partial / "inputs.json", json.dumps({"inputs": fingerprint}) + "\n")
    except OSError as exc:
        raise InputError(f"cannot write output directory: {exc.strerror or exc}", out_dir) from None
    return partial


def _publish(partial: Path, out_dir: Path, names: Sequence[str]) -> None:
    """Move finished outputs from .partial into out_dir; run.json goes last so its presence means complete."""
    (out_dir / "run.json").unlink(missing_ok=True)
    for name in names:
        src, dst = partial / name, out_dir / name
        if dst.is_dir() and not dst.is_symlink():
            old = partial / (name + ".old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(dst, old)
            os.replace(src, dst)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(src, dst)
    os.replace(partial / "run.json", out_dir / "run.json")


# ---------------------------------------------------------------------------------------------------------------
# Per-keyframe stage (cached)
# ---------------------------------------------------------------------------------------------------------------
def _cache_path(cache_dir: Path, k: int, name: str) -> Path:
    return cache_dir / f"{k:05d}_{Path(name).stem}.npz"


def _load_cached(path: Path, key: str) -> tuple[Any, tuple[float, float]] | None:
    from ..plugin.mask_features import MaskFeatures

    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["cache_key"]) != key:
                return None
            motion = (float(data["motion"][0]), float(data["motion"][1]))
            feats = MaskFeatures.from_npz_dict({k[5:]: data[k] for k in data.files if k.startswith("feat_")})
            return feats, motion
    except (OSError, KeyError, ValueError, EOFError) as exc:  # a damaged entry is recomputed, never trusted
        log.debug("cache entry %s unusable (%s); recomputing", path, exc)
        return None


def _save_cached(path: Path, key: str, feats: Any, motion: tuple[float, float]) -> None:
    # Optional fields that are None become object arrays, which np.load refuses without pickle: leave them out.
    arrays = {"feat_" + k: v for k, v in feats.to_npz_dict().items() if v.dtype != object}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, cache_key=np.array(key), motion=np.array(motion, dtype=np.float64), **arrays)


_WORKER_BACKEND: dict[str, Any] = {}  # per process: the segmentation backend, built once


def _describe_one(
    path: Path, prev_path: Path | None, size: tuple[int, int], params: Params, entry: Path, key: str,
    prev_gray: np.ndarray | None = None,
    masks_for: Callable[[str, np.ndarray], Any] | None = None,
) -> tuple[Any, tuple[float, float], np.ndarray]:
    """One keyframe: read, segment, describe, motion to the previous keyframe; store in the cache atomically.

    Returns (MaskFeatures, (mu_p, sigma_p), gray image). Runs in the main process or a worker process.
    """
    from ..database.images import read_image
    from ..plugin.mask_features import describe_masks, segment_and_describe, to_gray_u8
    from ..plugin.motion import image_motion_stats
    from ..plugin.segmentation import get_backend

    image = read_image(path)
    if image.shape[:2] != size:
        raise InputError(f"image is {image.shape[1]}x{image.shape[0]} but the camera is {size[1]}x{size[0]}", path)
    gray = to_gray_u8(image)
    if prev_path is not None and prev_gray is None:
        prev_gray = to_gray_u8(read_image(prev_path))
    mu_sigma = image_motion_stats(prev_gray, gray) if prev_path is not None else (0.0, 0.0)
    mu_sigma = (float(mu_sigma[0]), float(mu_sigma[1]))
    seg = params.segmentation
    if masks_for is not None:
        feats = describe_masks(image, masks_for(path.name, image), seg)
    else:
        cache_name = json.dumps(params_to_dict(seg), sort_keys=True)
        if cache_name not in _WORKER_BACKEND:
            _WORKER_BACKEND.clear()
            _WORKER_BACKEND[cache_name] = get_backend(seg.backend, seg)
        # the SIFT detection runs in a second thread while the backend segments (same features)
        _, feats = segment_and_describe(image, _WORKER_BACKEND[cache_name], seg)
    _save_cached(entry, key, feats, mu_sigma)
    return feats, mu_sigma, gray


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)  # one process per core already; OpenCV's own threads would oversubscribe


def describe_keyframes(
    inputs: MapInputs,
    keyframes: np.ndarray,
    params: Params,
    cache_dir: Path,
    cache_key: str,
    progress: bool = True,
    on_keyframe: Callable[[int], None] | None = None,
    workers: int = 1,
    masks_for: Callable[[str, np.ndarray], Any] | None = None,
) -> tuple[list[Any], list[tuple[float, float]], int]:
    """Segmentation + mask description + motion statistics per keyframe, resumed from the cache.

    Keyframes are independent given their image and the previous keyframe's image, so with `workers` > 1 they
    run in a process pool; results are identical to a sequential run.

    Returns (MaskFeatures per keyframe, (mu_p, sigma_p) per keyframe (entry 0 is (0, 0)), number of keyframes
    taken from the cache). `on_keyframe(k)` is called, in keyframe order, after keyframe k is stored (tests
    interrupt there). `masks_for(image_name, image) -> MaskSet` replaces the segmentation backend (benchmarks
    use ground-truth label masks; it must be picklable when `workers` > 1).
    """
    from tqdm import tqdm

    cache_dir.mkdir(parents=True, exist_ok=True)
    size = (inputs.camera.height, inputs.camera.width)
    results: list[tuple[Any, tuple[float, float]] | None] = [None] * len(keyframes)
    todo = []
    for k, idx in enumerate(keyframes):
        name = inputs.poses.names[idx]
        prev_name = inputs.poses.names[keyframes[k - 1]] if k else ""
        key = f"{cache_key}:{k}:{name}:{prev_name}"
        entry = _cache_path(cache_dir, k, name)
        hit = _load_cached(entry, key) if entry.exists() else None
        if hit is not None:
            results[k] = hit
        else:
            prev_path = inputs.image_paths[keyframes[k - 1]] if k else None
            todo.append((k, inputs.image_paths[idx], prev_path, entry, key))
    cached = len(keyframes) - len(todo)
    bar = tqdm(total=len(keyframes), initial=cached, desc="keyframes", unit="kf", disable=not progress,
               leave=False)
    if workers <= 1 or len(todo) <= 1:
        prev_gray, prev_k = None, -2
        for k, path, prev_path, entry, key in todo:
            feats, mu_sigma, gray = _describe_one(path, prev_path, size, params, entry, key,
                                                  prev_gray if prev_k == k - 1 else None, masks_for)
            results[k] = (feats, mu_sigma)
            prev_gray, prev_k = gray, k
            bar.update()
            if on_keyframe is not None:
                on_keyframe(k)
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        ctx = multiprocessing.get_context("spawn")  # no fork of a process holding pycolmap/OpenCV threads
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init) as pool:
            futures = [(k, pool.submit(_describe_one, path, prev_path, size, params, entry, key, None, masks_for))
                       for k, path, prev_path, entry, key in todo]
            try:
                for k, fut in futures:
                    feats, mu_sigma, _ = fut.result()
                    results[k] = (feats, mu_sigma)
                    bar.update()
                    if on_keyframe is not None:
                        on_keyframe(k)
            except BaseException:
                for _, fut in futures:
                    fut.cancel()
                raise
    bar.close()
    features = [r[0] for r in results]  # type: ignore[index]
    motion = [r[1] for r in results]  # type: ignore[index]
    return features, motion, cached


# ---------------------------------------------------------------------------------------------------------------
# The workflow
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class MapSummary:
    """What `run` produced (also written to run.json)."""

    out_dir: Path
    num_images: int
    num_keyframes: int
    num_masks: int
    num_tracks: int
    num_landmarks: int
    map_bytes: int
    seconds: float
    keyframes_from_cache: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    def line(self) -> str:
        """The one-line summary printed at the end of `sosmatch map`."""
        return (f"{self.out_dir}: {self.num_keyframes} keyframes, {self.num_masks} masks, {self.num_tracks} tracks, "
                f"{self.num_landmarks} landmarks, map {self.map_bytes} bytes, {self.seconds:.1f} s")


def _versions() -> dict[str, str]:
    import cv2
    import pycolmap
    import scipy

    return {"sosmatch": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__, "pycolmap": pycolmap.__version__}


def map_origin(positions: np.ndarray, camera_centers: np.ndarray) -> np.ndarray:
    """A round-numbered origin near the data (median of the landmarks, else of the cameras; whole metres)."""
    pts = positions if len(positions) else camera_centers
    return np.round(np.median(pts, axis=0)) if len(pts) else np.zeros(3)


def run(
    params: Params,
    inputs: MapInputs,
    out_dir: str | Path,
    overwrite: bool = False,
    text_model: bool = False,
    keep_cache: bool = False,
    progress: bool = True,
    on_keyframe: Callable[[int], None] | None = None,
    workers: int = 1,
    masks_for: Callable[[str, np.ndarray], Any] | None = None,
) -> MapSummary:
    """Map one session: `inputs` (from `load_inputs`) -> SESSION_DIR with the outputs listed in the module doc.

    Args:
        params: method parameters.
        inputs: images, poses and camera.
        out_dir: the session directory (created; see the module doc for resume and refusal rules).
        overwrite: replace a session made from other inputs, or write into a foreign non-empty directory.
        text_model: write sparse/ as a text model instead of binary.
        keep_cache: keep the per-keyframe cache (SESSION_DIR/.partial/cache) after success (default: delete).
        progress: show tqdm progress bars.
        on_keyframe: callback after each newly computed keyframe (tests use it to interrupt a run).
        workers: processes for the per-keyframe stage (segmentation dominates the run time).
        masks_for: `(image_name, image) -> MaskSet` instead of the segmentation backend (benchmarks: ground
            truth masks). Recorded in run.json; the cache is kept apart from backend results.
    """
    import pycolmap

    from ..database.session_io import format_landmarks_csv
    from ..plugin.keyframes import select_keyframes
    from ..plugin.tracking import track_masks
    from .triangulation import triangulate_landmarks

    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out_dir = Path(out_dir)
    fps = input_fingerprints(inputs)
    partial = prepare_output_dir(out_dir, fps["inputs"], overwrite)
    timings["inputs"] = time.perf_counter() - t_start
    pdict = params_to_dict(params)
    masks_source = getattr(masks_for, "__qualname__", repr(masks_for)) if masks_for is not None else "backend"
    cache_key = _hash_json({"v": CACHE_VERSION, "inputs": fps["inputs"], "seg": pdict["segmentation"],
                            "kf": pdict["keyframes"], "masks": masks_source})

    t = time.perf_counter()
    keyframes = select_keyframes(inputs.poses.centers, params.keyframes.interval_m)
    kf_poses = inputs.poses.subset(keyframes)
    features, motion, cached = describe_keyframes(inputs, keyframes, params, partial / "cache", cache_key,
                                                  progress, on_keyframe, workers, masks_for)
    timings["keyframes"] = time.perf_counter() - t

    from tqdm import tqdm

    stages = tqdm(total=4, desc="tracking", unit="stage", disable=not progress, leave=False)
    t = time.perf_counter()
    tracking = track_masks(features, inputs.camera, kf_poses, motion, params.tracking)
    timings["tracking"] = time.perf_counter() - t
    stages.update()
    stages.set_description("database")

    t = time.perf_counter()
    tri = params.triangulation
    centroids = [f.centroids for f in features]
    pairs = track_associations(tracking.track_ids, "all", tri.min_observations)
    pairs, rejected = verify_associations(inputs.camera, kf_poses, centroids, pairs,
                                          params.tracking.epipolar_margin_px)
    keypoints = [affine_keypoints(f.centroids, f.covariances) for f in features]
    db_summary = write_colmap_database(partial / "database.db", inputs.camera, kf_poses.names, keypoints, pairs)
    timings["database"] = time.perf_counter() - t
    stages.update()
    stages.set_description("triangulation")

    t = time.perf_counter()
    pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1 if log.isEnabledFor(logging.DEBUG) else 2)
    landmarks = triangulate_landmarks(partial / "database.db", inputs.camera, kf_poses,
                                      [f.sizes for f in features], tracking.track_ids, tri, seed=params.seed)
    timings["triangulation"] = time.perf_counter() - t
    stages.update()
    stages.set_description("outputs")

    t = time.perf_counter()
    write_model(landmarks.reconstruction, partial / "sparse", text=text_model)
    origin = map_origin(landmarks.positions, kf_poses.centers)
    lmap = LandmarkMap(landmarks.positions, landmarks.sizes_m.astype(np.float32), origin, inputs.epsg)
    map_bytes = write_landmark_map(partial / "landmarks.sosmap", lmap)
    write_ply(partial / "landmarks.ply", landmarks.positions - origin, landmarks.sizes_m, origin, inputs.epsg)
    image_names = [[kf_poses.names[k] for k in obs[:, 0]] for obs in landmarks.observations]
    write_text_atomic(partial / "landmarks.csv",
                      format_landmarks_csv(lmap, landmarks.point3d_ids, landmarks.num_observations, image_names))
    timings["outputs"] = time.perf_counter() - t
    stages.update()
    stages.close()
    timings["total"] = time.perf_counter() - t_start

    counts = {
        "images": len(inputs.image_paths), "keyframes": len(keyframes),
        "masks": int(sum(len(f) for f in features)), "tracks": int(tracking.num_tracks),
        "tracks_long": int(np.count_nonzero(tracking.track_lengths() > tri.min_observations)),
        "database_pairs": db_summary.num_pairs, "database_matches": db_summary.num_matches,
        "matches_rejected_epipolar": rejected, "landmarks": len(landmarks), "map_bytes": map_bytes,
        "keyframes_from_cache": cached,
        **{f"points_{k}": v for k, v in landmarks.counts.items()},
    }
    summary = MapSummary(out_dir, len(inputs.image_paths), len(keyframes), counts["masks"], counts["tracks"],
                         len(landmarks), map_bytes, timings["total"], cached, counts, timings)
    record = {
        "format": "sosmatch-map-run", "version": 1,
        "params": pdict, "versions": _versions(),
        "inputs": inputs.sources, "fingerprints": fps,
        "camera": {"width": inputs.camera.width, "height": inputs.camera.height, "fx": inputs.camera.fx,
                   "fy": inputs.camera.fy, "cx": inputs.camera.cx, "cy": inputs.camera.cy},
        "epsg": inputs.epsg, "map_origin": origin.tolist(), "masks": masks_source,
        "keyframes": [kf_poses.names[i] for i in range(len(kf_poses))],
        "counts": counts, "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    write_text_atomic(partial / "run.json", json.dumps(record, indent=2) + "\n")
    _publish(partial, out_dir, OUTPUTS)
    if keep_cache:
        log.info("per-keyframe cache kept in %s", partial / "cache")
    else:
        shutil.rmtree(partial, ignore_errors=True)
    return summary
