"""Map stage 3, per keyframe: segmentation, mask description and image motion, cached and resumable, in
worker processes when asked."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...database.atomic import atomic_path
from ...database.code_version import code_versions, describe, other_version
from ...database.taken import make_dirs
from ...plugin.errors import InputError
from ...plugin.geometry import Camera
from ...plugin.params import Params, params_to_dict
from .inputs import MapInputs

if TYPE_CHECKING:
    from ...database.images import Levels

log = logging.getLogger(__name__)

CACHE_VERSION = 5  # 2: image motion measured between undistorted track ends (lens cameras); 3: image figures;
# 4: motion smear; 5: the smear along every direction (the poses' direction of motion enters no key)


def _cache_path(cache_dir: Path, k: int, name: str) -> Path:
    return cache_dir / f"{k:05d}_{Path(name).stem}.npz"


def _load_cached(path: Path, key: str) -> tuple[Any, tuple[float, float], dict[str, Any]] | None:
    """(features, motion, the versions of the sosmatch that wrote the entry ({} before they were recorded)), or
    None when the entry is of another key or unreadable."""
    from ...plugin.mask_features import MaskFeatures

    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["cache_key"]) != key:
                return None
            motion = (float(data["motion"][0]), float(data["motion"][1]))
            feats = MaskFeatures.from_npz_dict({k[5:]: data[k] for k in data.files if k.startswith("feat_")})
            made = json.loads(str(data["made_by"])) if "made_by" in data.files else {}
            return feats, motion, made if isinstance(made, dict) else {}
    except (OSError, KeyError, ValueError, EOFError) as exc:  # a damaged entry is recomputed, never trusted
        log.debug("cache entry %s unusable (%s); recomputing", path, exc)
        return None


def _save_cached(path: Path, key: str, feats: Any, motion: tuple[float, float],
                 figures: np.ndarray | None = None, smears: np.ndarray | None = None) -> None:
    # Optional fields that are None become object arrays, which np.load refuses without pickle: leave them out.
    arrays = {"feat_" + k: v for k, v in feats.to_npz_dict().items() if v.dtype != object}
    # the cache folder is made (and a moved output directory noticed) by `describe_keyframes`: a pool worker never
    # re-creates it, even when the folder is moved away between its check and its write
    with atomic_path(path, make_parents=False) as tmp:
        with open(tmp, "wb") as f:
            extra = {} if figures is None else {"image_figures": np.asarray(figures, np.float64)}
            if smears is not None:
                extra["motion_smears_by_angle"] = np.asarray(smears, np.float64)
            # which code made it: a resumed map says when an earlier sosmatch's entries are reused
            # (`describe_keyframes`), as the key holds the settings, not the code
            np.savez(f, cache_key=np.array(key), motion=np.array(motion, dtype=np.float64),
                     made_by=np.array(json.dumps(code_versions(), sort_keys=True)), **extra, **arrays)


_NO_DESCRIPTORS = np.zeros((0, 128), np.float32)


def cached_descriptors(cache_dir: Path, names: Sequence[str]) -> Callable[[int], np.ndarray]:
    """descriptors(k): the SIFT descriptors of keyframe k (image `names[k]`) from the cache entry that
    `describe_keyframes` validated or wrote (only that array of the entry is read)."""
    def descriptors(k: int) -> np.ndarray:
        with np.load(_cache_path(cache_dir, k, names[k]), allow_pickle=False) as data:
            return np.asarray(data["feat_sift_desc"], np.float32)

    return descriptors


def _cached_arrays(cache_dir: Path, names: Sequence[str], key: str) -> list[np.ndarray | None]:
    """Per keyframe, the array `key` of the cache entry that `describe_keyframes` validated or wrote (only that
    array is read); None where the entry holds none."""
    out: list[np.ndarray | None] = []
    for k, name in enumerate(names):
        try:
            with np.load(_cache_path(cache_dir, k, name), allow_pickle=False) as data:
                out.append(np.asarray(data[key], np.float64))
        except (OSError, KeyError, ValueError, EOFError):
            out.append(None)
    return out


def cached_image_figures(cache_dir: Path, names: Sequence[str]) -> list[np.ndarray]:
    """Per keyframe, its image figures (`plugin.image_quality.image_figures`) from the cache entry that
    `describe_keyframes` validated or wrote; NaN where the entry holds none."""
    return [np.full(3, np.nan) if a is None else a.reshape(3)
            for a in _cached_arrays(cache_dir, names, "image_figures")]


def cached_motion_smears(cache_dir: Path, names: Sequence[str], directions: np.ndarray) -> np.ndarray:
    """Per keyframe, its smear along its direction of motion (`directions[k]`, `plugin.motion_blur.
    motion_directions` of the keyframes' poses; working px) from the smears along every direction that the cache
    entry `describe_keyframes` validated or wrote holds (`plugin.motion_blur.smears_by_angle`); NaN where the entry
    holds none or the direction is unknown. The entry depends on the image alone, so other poses for the same
    images read the smear along their own direction, as a fresh run would."""
    from ...plugin.motion_blur import smear_along

    arrays = _cached_arrays(cache_dir, names, "motion_smears_by_angle")
    return np.array([np.nan if a is None else smear_along(a, directions[k]) for k, a in enumerate(arrays)])


_WORKER_BACKEND: dict[str, Any] = {}  # per process: the segmentation backend, built once


def _describe_one(
    path: Path, prev_path: Path | None, size: tuple[int, int], params: Params, entry: Path, key: str,
    prev_gray: np.ndarray | None = None,
    masks_for: Callable[[str, np.ndarray], Any] | None = None,
    camera: Camera | None = None,
    white: Levels | int | None = None,
    contrast: Any = None,
    backend_key: str = "",
) -> tuple[Any, tuple[float, float], np.ndarray]:
    """One keyframe: read, segment, describe, motion to the previous keyframe; store in the cache atomically.

    Returns (MaskFeatures, (mu_p, sigma_p), gray image). Runs in the main process or a worker process. `camera`:
    the images' lens; the motion is measured in the undistorted pixels tracking compares (`image_motion_stats`).
    `white`: the flight's white level (`database.flight_levels.flight_white_level`). `contrast`: the flight's
    (`plugin.flight_contrast.FlightContrast`; None: as read): the segmenter sees the image through its gain, the
    masks are described on the image as read. `backend_key`: the run's cache key, which holds the contents of the
    backend's model files: the backend this process built for a run is reused by another only when both the
    settings and the model files are the same (a model file replaced at its path is read again).
    """
    from ...database.images import read_image
    from ...plugin.image_quality import image_figures
    from ...plugin.mask_features import describe_masks, segment_and_describe, to_gray_u8
    from ...plugin.motion import image_motion_stats
    from ...plugin.motion_blur import smears_by_angle
    from ...plugin.segmentation import get_backend

    image = read_image(path, white)
    if image.shape[:2] != size:
        raise InputError(f"image is {image.shape[1]}x{image.shape[0]} but the camera is {size[1]}x{size[0]}", path)
    gray = to_gray_u8(image)
    if prev_path is not None and prev_gray is None:
        prev_gray = to_gray_u8(read_image(prev_path, white))
    mu_sigma = image_motion_stats(prev_gray, gray, camera=camera) if prev_path is not None else (0.0, 0.0)
    mu_sigma = (float(mu_sigma[0]), float(mu_sigma[1]))
    seg = params.segmentation
    if masks_for is not None:
        feats = describe_masks(image, masks_for(path.name, image), seg)
    else:
        cache_name = json.dumps(params_to_dict(seg), sort_keys=True) + backend_key
        if cache_name not in _WORKER_BACKEND:
            _WORKER_BACKEND.clear()
            _WORKER_BACKEND[cache_name] = get_backend(seg.backend, seg)
        backend = _WORKER_BACKEND[cache_name]
        if contrast is not None and contrast.stretched:
            backend = _through(contrast, backend)
        # the SIFT detection runs in a second thread while the backend segments (same features)
        _, feats = segment_and_describe(image, backend, seg)
    # noise and sharpness as the segmenter sees them (its working size), from the grey image already decoded
    working = min(seg.classical_max_side, max(size))
    figures = image_figures(gray, working)
    # the smear along every direction (the track's, from the poses, is picked by `cached_motion_smears`), which
    # the isotropic sharpness above barely sees (`plugin.motion_blur`)
    _save_cached(entry, key, feats, mu_sigma, figures, smears_by_angle(gray, working))
    return feats, mu_sigma, gray


def _through(contrast: Any, backend: Callable[[np.ndarray], Any]) -> Callable[[np.ndarray], Any]:
    """`backend` segmenting the image as the flight's contrast gain makes it."""
    return lambda image: backend(contrast.apply(image))


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
    digests: Sequence[str] | None = None,
    white: Levels | int | None = None,
    hold_descriptors: bool = True,
    contrast: Any = None,
    renew_other_versions: bool = False,
) -> tuple[list[Any], list[tuple[float, float]], int]:
    """Segmentation + mask description + motion statistics per keyframe, resumed from the cache.

    Keyframes are independent given their image and the previous keyframe's image, so with `workers` > 1 they
    run in a process pool; results are identical to a sequential run.

    Returns (MaskFeatures per keyframe, (mu_p, sigma_p) per keyframe (entry 0 is (0, 0)), number of keyframes
    taken from the cache). `on_keyframe(k)` is called, in keyframe order, after keyframe k is stored (tests
    interrupt there). `masks_for(image_name, image) -> MaskSet` replaces the segmentation backend (benchmarks
    use ground-truth label masks; it must be picklable when `workers` > 1). `digests`: the images' contents
    (`inputs.image_digests`); with them, an entry is valid exactly while its image and the previous keyframe's
    are unchanged, so a run that failed on one bad image resumes every other keyframe once it is fixed.
    `white`: the flight's white level (`database.flight_levels.flight_white_level`; None: found here).
    `hold_descriptors` False: the features come without their SIFT descriptors (shape (0, 128)), which stay in the
    cache (`cached_descriptors` reads them): they are ~95 % of a keyframe's description (~1 MB at 320 px), and a
    1500-keyframe flight held 1.7 GB of them where tracking needs only the last few keyframes' at a time.
    `contrast`: the flight's contrast (`plugin.flight_contrast.FlightContrast`; None or gain 1: the segmenter sees
    the images as read). The key holds the settings, not the code: entries another sosmatch wrote (an interrupted
    run resumed after an upgrade, `--keep-cache`) are reused and said once in a warning naming the cache, both
    versions and `--overwrite`; with `renew_other_versions` (map's `overwrite`) they are computed again.
    """
    from dataclasses import replace

    from ...database.flight_levels import flight_white_level
    from ..progress import progress_bar

    def kept(feats: Any) -> Any:  # what this call returns of a keyframe's description
        return feats if hold_descriptors else replace(feats, sift_desc=_NO_DESCRIPTORS)

    make_dirs(cache_dir)  # an output directory moved away under its run is not re-created at its old place
    backend_key = cache_key
    size = (inputs.camera.height, inputs.camera.width)
    # one white level for the flight's images beyond 8 bits (none for 8-bit ones, whose cache keys stay as they were)
    white = flight_white_level(inputs.image_paths) if white is None else white
    if white is not None:
        cache_key = f"{cache_key}:white{white}"
    if contrast is not None and contrast.stretched:  # (a flight at gain 1 keeps its cache keys)
        cache_key = f"{cache_key}:contrast{contrast.gain:.6f}:{contrast.centre:.3f}:{contrast.range:.3f}"
    results: list[tuple[Any, tuple[float, float]] | None] = [None] * len(keyframes)
    todo = []
    others: dict[str, int] = {}  # entries reused that another sosmatch wrote: its description -> how many
    for k, idx in enumerate(keyframes):
        name = inputs.poses.names[idx]
        prev_name = inputs.poses.names[keyframes[k - 1]] if k else ""
        key = f"{cache_key}:{k}:{name}:{prev_name}"
        if digests is not None:
            key += f":{digests[idx]}:{digests[keyframes[k - 1]] if k else ''}"
        entry = _cache_path(cache_dir, k, name)
        hit = _load_cached(entry, key) if entry.exists() else None
        made_by = other_version({"versions": hit[2]}) if hit is not None else None
        if hit is not None and made_by is not None and renew_other_versions:
            hit = None
        if hit is not None:
            results[k] = (kept(hit[0]), hit[1])
            if made_by is not None:
                others[made_by] = others.get(made_by, 0) + 1
        else:
            prev_path = inputs.image_paths[keyframes[k - 1]] if k else None
            todo.append((k, inputs.image_paths[idx], prev_path, entry, key))
    cached = len(keyframes) - len(todo)
    if others:
        log.warning("%s: %s of %d keyframes resumed from cache entries made by %s, with the same settings; this is %s "
                    "(another version may segment them otherwise): --overwrite computes them again with this one",
                    cache_dir, sum(others.values()), len(keyframes), " and ".join(sorted(others)),
                    describe(code_versions()))
    bar = progress_bar(len(keyframes), "keyframes", "kf", progress, initial=cached)
    if workers <= 1 or len(todo) <= 1:
        prev_gray, prev_k = None, -2
        for k, path, prev_path, entry, key in todo:
            feats, mu_sigma, gray = _describe_one(path, prev_path, size, params, entry, key,
                                                  prev_gray if prev_k == k - 1 else None, masks_for, inputs.camera,
                                                  white, contrast, backend_key)
            results[k] = (kept(feats), mu_sigma)
            prev_gray, prev_k = gray, k
            bar.update()
            if on_keyframe is not None:
                on_keyframe(k)
    else:
        from ..executors import process_pool, stop_pool

        # spawn (no fork of a process holding pycolmap/OpenCV threads); the workers die with this process
        with process_pool(workers, _worker_init) as pool:
            futures = [(k, pool.submit(_describe_one, path, prev_path, size, params, entry, key, None, masks_for,
                                              inputs.camera, white, contrast, backend_key))
                       for k, path, prev_path, entry, key in todo]
            try:
                for k, fut in futures:
                    feats, mu_sigma, _ = fut.result()
                    results[k] = (kept(feats), mu_sigma)
                    bar.update()
                    if on_keyframe is not None:
                        on_keyframe(k)
            except BaseException:  # Ctrl-C: stop now, not after the keyframes being described
                stop_pool(pool)
                raise
    bar.close()
    features = [r[0] for r in results]  # type: ignore[index]
    motion = [r[1] for r in results]  # type: ignore[index]
    return features, motion, cached


def shutter_smear(inputs: MapInputs, ground_resolution: float, working_side: int) -> float:
    """The smear (working px) the flight's speed and its images' EXIF ExposureTime predict
    (`plugin.motion_blur.exposure_smear`; speed from the poses' centres and the EXIF capture times), with
    `ground_resolution` the ground one full pixel covers (m) and `working_side` the segmenter's working size;
    NaN where the images carry no exposure or capture time (or the ground resolution is not known)."""
    from ...database.exif import read_image_metadata
    from ...plugin.errors import InputError
    from ...plugin.motion_blur import exposure_smear

    times: list[float | None] = []
    exposures: list[float | None] = []
    for path in inputs.image_paths:
        try:
            meta = read_image_metadata(path)
            times.append(meta.capture_time_s)
            exposures.append(meta.exposure_s)
        except InputError:  # an unreadable image is named where its pixels are read
            times.append(None)
            exposures.append(None)
    if all(e is None for e in exposures):
        return float("nan")
    full_side = max(inputs.camera.width, inputs.camera.height)
    return exposure_smear(inputs.poses.centers, times, exposures, ground_resolution * full_side / working_side)
