"""The map run: its stages as named calls and the run record (run.json); see the package doc."""

from __future__ import annotations

import json
import logging
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ...database.atomic import write_text_atomic
from ...database.colmap_db import (
    affine_keypoints,
    track_associations,
    verify_associations,
    write_colmap_database,
)
from ...database.colmap_model import write_model, write_ply
from ...database.landmark_map import (
    POSE_SOURCE_SFM,
    LandmarkMap,
    landmark_map_fingerprint,
    read_landmark_map,
    write_landmark_map,
)
from ...database.outputs import OutputDir
from ...database.segmentation_models import SegmentationModels, segmentation_models
from ...plugin.lens_check import camera_kind
from ...plugin.map_quality import MapQuality
from ...plugin.map_verdict import Verdict
from ...plugin.params import Params, for_flight, for_ground_resolution, for_image, params_to_dict, pixel_scale
from .inputs import (
    MapInputs,
    distinct_images,
    hash_json,
    in_flight_order,
    input_fingerprints,
    input_paths,
    recorded_sources,
    refuse_text_model_names,
    require_keyframes,
    sources_from_session,
)
from .keyframes import (
    CACHE_VERSION,
    cached_descriptors,
    cached_image_figures,
    cached_motion_smears,
    describe_keyframes,
    shutter_smear,
)
from .lens import lens_stage
from .output_dir import OUTPUTS, PARTIAL, POSE_CHECK, RECORD, map_identity, take_output_dir
from .quality import FIGURE, joined, pose_check_stage, quality_stage, raise_if_refused, verdict_record
from .recorded_height import ground_flying_height, height_against_takeoff, recorded_heights, takeoff_record

log = logging.getLogger(__name__)


class PosesSource(Protocol):
    """Inputs whose poses a stage computes inside the map's output directory (`workflows.poses.PosesFromImages`)."""

    def identity(self) -> str: ...

    def earlier_identities(self) -> tuple[str, ...]: ...

    def input_paths(self) -> list[Path]: ...

    def resolve(self, out: OutputDir, renew_other_versions: bool = False) -> tuple[MapInputs, tuple[str, ...]]:
        """The map inputs, and the entries it staged in `out` to publish with the map; stages of a killed run that
        another sosmatch made are computed again with `renew_other_versions` (map's `overwrite`)."""
        ...


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
    quality: MapQuality | None = None
    verdict: Verdict | None = None
    pose_check: Any = None  # workflows.pose_check.CheckResult (None: the check was off)
    remedy: str = ""  # MapInputs.remedy, when the pose check found the poses loose: said with a refusal
    lens: Any = None  # plugin.lens_check.LensCheck (None: too few landmarks to check the lens)

    def line(self) -> str:
        """The one-line summary printed at the end of `sosmatch map`."""
        line = (f"{self.out_dir}: {self.num_keyframes} keyframes, {self.num_masks} masks, {self.num_tracks} tracks, "
                f"{self.num_landmarks} landmarks, map {self.map_bytes} bytes, {self.seconds:.1f} s")
        if self.quality is not None:
            line += f"; {self.quality.line()}"
        if self.pose_check is not None:
            line += f"; {self.pose_check.check.line()}"
        if self.lens is not None:
            line += f"; {self.lens.line()}"
        if self.verdict is not None and self.verdict.warnings:
            line += f"; WARNING: {'; '.join(self.verdict.warnings)}"
        return line


def _versions() -> dict[str, str]:
    import cv2
    import pycolmap
    import scipy

    from ...database.code_version import code_versions

    # the source digest too: the package version does not change with the code (`database.code_version`); a batch
    # that keeps this map after an upgrade names both (`batch.workflow`)
    return {**code_versions(), "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__, "pycolmap": pycolmap.__version__}


def flight_views(kf_poses: Any, motion: list[tuple[float, float]], camera: Any) -> float:
    """`plugin.motion.views_per_pass` of the keyframes: each step's image motion (mu_p) and its direction of
    travel in the earlier keyframe's image axes (from the poses)."""
    from ...plugin.motion import views_per_pass

    if len(kf_poses) < 2:
        return float("nan")
    steps = np.diff(kf_poses.centers, axis=0)
    in_cam = np.einsum("kji,kj->ki", kf_poses.rotations[:-1], steps)  # R^T (C_k+1 - C_k)
    return views_per_pass(np.array([m[0] for m in motion[1:]]), in_cam[:, :2], camera.width, camera.height)


def flown_params(params: Params, views: float, kf_centers: np.ndarray) -> Params:
    """`plugin.params.for_flight` of the keyframes' `views` per pass, unless the keyframes (centres in their order)
    are not in one flight's order (`plugin.keyframes.reads_as_flight`): keyframes that jump back and forth across
    the survey (flights interleaved in a listed order) see an object on fewer steps than a pass does, so their pass
    length is no measurement (nu57: theta_n lowered 5 -> 2 without a word); `params` then, with a warning. A flight
    over its ground again in many passes is one flight (rev53 D4: 6 passes were told "not in the order of one
    flight")."""
    from ...plugin.keyframes import order_jumps, reads_as_flight

    flown = for_flight(params, views)
    xy = np.asarray(kf_centers)[:, :2]
    if flown is params or reads_as_flight(xy):
        return flown
    log.warning("%d of the %d steps between keyframes jump back and forth between places far apart (the order of "
                "no one flight): theta_n stays %d (not lowered to %d from the %.1f keyframes an object is in on "
                "their steps)", int(np.count_nonzero(order_jumps(xy))), len(xy) - 1,
                params.triangulation.min_observations, flown.triangulation.min_observations, views)
    return params


def working_resolution(params: Params, checked: Any, camera: Any) -> tuple[Params, float]:
    """(`params` with the classical segmenter's working size raised where the ground resolution the pose check
    measured (its flying height over the focal length) would make a working pixel coarser than its target
    (`plugin.params.for_ground_resolution`), the ground resolution in m/px, NaN when not measured)."""
    height = float(checked.check.flying_height_m) if checked is not None else float("nan")
    gsd = height / float(np.sqrt(camera.fx * camera.fy))
    scaled = for_ground_resolution(params, gsd, camera.width, camera.height)
    seg = scaled.segmentation
    if seg.backend == "classical":
        side = min(seg.classical_max_side, max(camera.width, camera.height))
        log.info("segmenting at %d px: %s", side, "flying height not measured" if not np.isfinite(gsd) else
                 f"{gsd * max(camera.width, camera.height) / side:.2f} m per working pixel at the measured flying "
                 f"height {height:.1f} m")
    return scaled, gsd


def gps_precheck(inputs: MapInputs, params: Params) -> Any:
    """The pose check's comparison with the images' GPS, made before the map's output directory is taken
    (`workflows.pose_check.refuse_by_gps`): poses it refuses (not in metres, mirrored) are a one-line error
    naming the pose file, with nothing written, when the pose check and refusal are on. Returns the comparison
    (None when there is none to make, or the check is off) for the pose check stage."""
    from ..pose_check import refuse_by_gps

    if not (params.pose_check.enabled and params.quality.refuse):
        return None
    source = inputs.sources.get("poses") or inputs.image_paths[0].parent
    return refuse_by_gps(inputs.image_paths, inputs.poses, inputs.epsg, params.pose_check, source)


def poses_fit(checked: Any, params: Params) -> str:
    """The pose check's phrase when it found the poses fitting the images (`plugin.pose_check.poses_fit_images`),
    "" when it did not, refused them, or did not run."""
    from ...plugin.pose_check import poses_fit_images

    if checked is None or not checked.verdict.ok:
        return ""
    return poses_fit_images(checked.check, params.pose_check)


def pose_remedy(inputs: MapInputs, checked: Any, params: Params) -> str:
    """`inputs.remedy` when the pose check found the poses loose (`plugin.pose_check.poses_loose`), else "": a map
    refused for few landmarks on EXIF tags that barely fit names `--refine` (the 26th new-user sweep: a zoom
    drone's tags at 11.7 px on a 12 px gate, 6 landmarks; refined, 197)."""
    from ...plugin.pose_check import poses_loose

    if not inputs.remedy or checked is None or not poses_loose(checked.check, params.pose_check):
        return ""
    return inputs.remedy


def map_origin(positions: np.ndarray, camera_centers: np.ndarray) -> np.ndarray:
    """A round-numbered origin near the data (median of the landmarks, else of the cameras; whole metres)."""
    pts = positions if len(positions) else camera_centers
    return np.round(np.median(pts, axis=0)) if len(pts) else np.zeros(3)


def _masks_source(masks_for: Callable[[str, np.ndarray], Any] | None) -> str:
    """Where a map's masks come from, as its identity and run.json name it: "backend", or `masks_for`'s qualified
    name (its class's for a callable object: an object's repr holds its address, another at every run)."""
    if masks_for is None:
        return "backend"
    return getattr(masks_for, "__qualname__", None) or type(masks_for).__qualname__


def run(
    params: Params,
    inputs: MapInputs | PosesSource,
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
        inputs: images, poses and camera; or a `PosesSource` (`workflows.poses.PosesFromImages`: images without
            poses), resolved inside the taken directory (structure from motion in its staging area, resumable)
            and published with the map (SESSION_DIR/poses).
        out_dir: the session directory (created; see the module doc for resume and refusal rules).
        overwrite: replace a complete session made from other inputs or parameters; per-keyframe cache entries
            another sosmatch made (a resumed run, `keep_cache`) are computed again instead of reused (and named).
        text_model: write sparse/ as a text model instead of binary.
        keep_cache: keep the per-keyframe cache (SESSION_DIR/.partial/cache) after success (default: delete).
        progress: show tqdm progress bars.
        on_keyframe: callback after each newly computed keyframe (tests use it to interrupt a run).
        workers: processes for the per-keyframe stage (segmentation dominates the run time).
        masks_for: `(image_name, image) -> MaskSet` instead of the segmentation backend (benchmarks: ground
            truth masks). Recorded in run.json and keyed by its qualified name (`__qualname__`, or its class's
            for a callable object; not its code or state): the cache is kept apart from backend results, but two
            callables of one name share a key, so give each its own SESSION_DIR.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out_dir = Path(out_dir)
    masks_source = _masks_source(masks_for)
    # the backend's model files, resolved (settings, else environment) and fingerprinted once: the identity, the
    # cache key and run.json hold them, and every keyframe is segmented with them
    models = segmentation_models(params.segmentation) if masks_for is None else SegmentationModels()
    source = None if isinstance(inputs, MapInputs) else inputs
    if source is None:
        if text_model:  # before anything is written: the text model would come back with other names
            refuse_text_model_names(inputs.image_paths)
        inputs = in_flight_order(inputs)
        inputs, digests = distinct_images(inputs)  # a copy of an image is left out before anything else
        require_keyframes(inputs, params.keyframes.interval_m)
        fps = input_fingerprints(inputs, digests)
        what, paths = fps["inputs"], input_paths(inputs)
        # pixel limits tuned at one image size scale with the image (run.json keeps the effective values)
        params = for_image(params, inputs.camera.width, inputs.camera.height)
        gps = gps_precheck(inputs, params)  # before anything is written or segmented
    else:  # the poses are computed inside the taken directory: the identity is that of their source
        what, paths = source.identity(), source.input_paths()
        gps = None  # poses made from the images' own GPS: their unit is the GPS's
    # what the outputs depend on: a complete session of another identity is replaced only with `overwrite`
    identity = map_identity(what, params, text_model, masks_source, models)
    for earlier in () if source is None else source.earlier_identities():
        # the same poses' source as an earlier sosmatch named it (rev52 D2): a map made of it is this one
        identity = identity.accepting(map_identity(earlier, params, text_model, masks_source, models))
    with take_output_dir(out_dir, identity, paths, overwrite) as out:
        extra: tuple[str, ...] = ()
        if source is not None:
            t = time.perf_counter()
            inputs, extra = source.resolve(out, renew_other_versions=overwrite)
            inputs = in_flight_order(inputs)
            inputs, digests = distinct_images(inputs)
            require_keyframes(inputs, params.keyframes.interval_m)
            timings["poses"] = time.perf_counter() - t
            fps = input_fingerprints(inputs, digests)
            params = for_image(params, inputs.camera.width, inputs.camera.height)
        timings["inputs"] = time.perf_counter() - t_start
        summary = _map_into(out, params, inputs, fps, digests, masks_source, text_model, progress,
                            on_keyframe, workers, masks_for, timings, t_start, extra, gps, models, overwrite)
        out.finish(keep_staging=keep_cache)
    if keep_cache:
        log.info("per-keyframe cache kept in %s", out_dir / PARTIAL / "cache")
    raise_if_refused(summary.verdict, params.quality, out_dir, summary.remedy)
    return summary


def _map_into(out: OutputDir, params: Params, inputs: MapInputs, fps: dict[str, str], digests: list[str],
              masks_source: str, text_model: bool, progress: bool,
              on_keyframe: Callable[[int], None] | None, workers: int,
              masks_for: Callable[[str, np.ndarray], Any] | None, timings: dict[str, float],
              t_start: float, extra_outputs: tuple[str, ...] = (), gps: Any = None,
              models: SegmentationModels | None = None, overwrite: bool = False) -> MapSummary:
    """The stages of `run` inside the taken output directory: build in its staging area, then publish
    (`overwrite`: per-keyframe cache entries another sosmatch made are computed again, `describe_keyframes`)."""
    import pycolmap

    from ...database.flight_levels import flight_white_level
    from ...database.session_images import levels_record
    from ...database.session_io import format_landmarks_csv
    from ...plugin.flight_contrast import flight_contrast
    from ...plugin.image_quality import flight_images
    from ...plugin.jpeg_quality import flight_compression
    from ...plugin.keyframes import select_keyframes
    from ...plugin.mask_features import undistort_features
    from ...plugin.motion_blur import motion_directions
    from ...plugin.tracking import track_masks
    from ...plugin.truncation import cut_masks
    from ..triangulation import fewest_observations, triangulate_landmarks

    partial = out.staging
    camera = inputs.camera
    t = time.perf_counter()
    # before the keyframes: its flying height sets the segmenter's working size (`working_resolution`)
    # one white level for every reader of the flight's images beyond 8 bits (a 16-bit sample is decoded once)
    white = flight_white_level(inputs.image_paths)
    # one contrast gain for the flight's segmentation (none where masks come from elsewhere, or at normal contrast)
    contrast = None if masks_for is not None else flight_contrast(inputs.image_paths,
                                                                    params.segmentation.contrast_reference, white)
    if contrast is not None and contrast.stretched:
        log.warning("%s", contrast.message())
    checked = pose_check_stage(inputs, params, out.staged(POSE_CHECK), gps, white)
    timings["pose_check"] = time.perf_counter() - t
    params, ground_resolution = working_resolution(params, checked, camera)
    pdict = params_to_dict(params)
    # the lens enters the cached image motion (measured in undistorted pixels); a pinhole's focal length does not
    lens = None if camera.is_pinhole else [camera.model, list(camera.params)]
    models = models or SegmentationModels()
    # the models' contents, not the settings naming them (classical has none: its keys are those of earlier versions)
    with_models = {"models": models.identity()} if models.identity() else {}
    cache_key = hash_json({"v": CACHE_VERSION, "seg": pdict["segmentation"], "kf": pdict["keyframes"],
                           "masks": masks_source, "size": [camera.width, camera.height], "lens": lens, **with_models})

    t = time.perf_counter()
    keyframes = select_keyframes(inputs.poses.centers, params.keyframes.interval_m)
    kf_poses = inputs.poses.subset(keyframes)
    segmented = replace(params, segmentation=models.params(params.segmentation))  # the files fingerprinted
    features, motion, cached = describe_keyframes(inputs, keyframes, segmented, partial / "cache", cache_key,
                                                  progress, on_keyframe, workers, masks_for, digests, white,
                                                  hold_descriptors=False, contrast=contrast,
                                                  renew_other_versions=overwrite)
    descriptors = cached_descriptors(partial / "cache", kf_poses.names)
    # the JPEG quality from the files' headers: compression fools the image figures (`plugin.jpeg_quality`)
    images = flight_images(cached_image_figures(partial / "cache", kf_poses.names), kf_poses.names,
                           flight_compression(inputs.image_paths),
                           cached_motion_smears(partial / "cache", kf_poses.names, motion_directions(kf_poses)),
                           shutter_smear(inputs, ground_resolution, min(params.segmentation.classical_max_side,
                                                                        max(camera.width, camera.height))))
    timings["keyframes"] = time.perf_counter() - t

    from ..progress import progress_bar

    stages = progress_bar(4, "tracking", "stage", progress)
    t = time.perf_counter()
    # Tracking and the epipolar check are pinhole geometry: they see undistorted centroids and covariances through
    # the equivalent pinhole camera; the database and the model keep the real camera and the real keypoints. Which
    # masks the image border cuts is decided in the real image and travels with them (`MaskFeatures.border`).
    gate_camera = camera.pinhole()
    gate_features = [undistort_features(f, camera) for f in features]
    tracking = track_masks(gate_features, gate_camera, kf_poses, motion, params.tracking, descriptors)
    views = flight_views(kf_poses, motion, camera)
    flown = flown_params(params, views, kf_poses.centers)
    if flown is not params:
        log.info("an object is in %.1f keyframes of a pass: a landmark needs more than %d observations (theta_n %d "
                 "is more than half of them); landmarks %g robust sigmas off their neighbours' ground are dropped",
                 views, flown.triangulation.min_observations, params.triangulation.min_observations,
                 flown.triangulation.height_outlier_sigmas)
        params = flown
    timings["tracking"] = time.perf_counter() - t
    stages.update()
    stages.set_description("database")

    t = time.perf_counter()
    tri = params.triangulation
    centroids = [f.centroids for f in gate_features]
    # tracks long enough to be pieces of a landmark (fused in triangulation; theta_n applies afterwards)
    pairs = track_associations(tracking.track_ids, "all", fewest_observations(tri) - 1)
    # (truncation_aware) the links of cut views are checked with the boxes the tracker gated them with
    pairs, rejected = verify_associations(gate_camera, kf_poses, centroids, pairs,
                                          params.tracking.epipolar_margin_px, tracking.shifts)
    keypoints = [affine_keypoints(f.centroids, f.covariances) for f in features]
    db_summary = write_colmap_database(out.staged("database.db"), camera, kf_poses.names, keypoints, pairs)
    timings["database"] = time.perf_counter() - t
    stages.update()
    stages.set_description("triangulation")

    t = time.perf_counter()
    pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1 if log.isEnabledFor(logging.DEBUG) else 2)
    landmarks = triangulate_landmarks(partial / "database.db", camera, kf_poses,
                                      [f.sizes for f in gate_features], tracking.track_ids, tri, seed=params.seed,
                                      centroids_px=centroids, covariances_px=[f.covariances for f in gate_features],
                                      cut_px=[cut_masks(gate_camera, f) for f in gate_features])
    timings["triangulation"] = time.perf_counter() - t
    stages.update()
    stages.set_description("outputs")

    t = time.perf_counter()
    write_model(landmarks.reconstruction, out.staged("sparse"), text=text_model)
    origin = map_origin(landmarks.positions, kf_poses.centers)
    # the noise figures travel with the map file (a map copied out of the session is matched as the session is);
    # figures no map can have (`MapNoise.problem`) are left out of it, with a warning, rather than failing the run
    noise = landmarks.noise
    problem = None if noise is None else noise.problem()
    if problem is not None:
        log.warning("the map's %s: not written into the map file", problem)
        noise = None
    # the poses' source travels with the map file (flag 4), as its noise figures do: `match` chooses its transform
    lmap = LandmarkMap(landmarks.positions, landmarks.sizes_m.astype(np.float32), origin, inputs.epsg, noise,
                       sfm_poses=inputs.pose_source == POSE_SOURCE_SFM)
    map_bytes = write_landmark_map(out.staged("landmarks.sosmap"), lmap)
    write_ply(out.staged("landmarks.ply"), landmarks.positions - origin, landmarks.sizes_m, origin, inputs.epsg)
    image_names = [[kf_poses.names[k] for k in obs[:, 0]] for obs in landmarks.observations]
    write_text_atomic(out.staged("landmarks.csv"),
                      format_landmarks_csv(lmap, landmarks.point3d_ids, landmarks.num_observations, image_names))
    timings["outputs"] = time.perf_counter() - t
    stages.update()
    stages.close()

    t = time.perf_counter()
    fitting = poses_fit(checked, params)  # the pose check's word: the quality figures and the lens check take it
    long_tracks = int(np.count_nonzero(tracking.track_lengths() > tri.min_observations))
    quality, verdict = quality_stage(landmarks, kf_poses, camera, [inputs.image_paths[i] for i in keyframes],
                                     keypoints, long_tracks, params.quality, out.staged(FIGURE), str(out.path),
                                     params.association.min_associations + 1,
                                     checked.check.flying_height_m if checked is not None else float("nan"),
                                     white, fitting, images,
                                     contrast.cause() if contrast is not None else "",
                                     params.triangulation.min_observations, views, params, inputs.vertical)
    # the poses' doubts (a georegistration leaving GPS fixes out, a lag corrected) are the map's too
    verdict = joined(Verdict(refusals=list(inputs.refusals), warnings=list(inputs.warnings)), verdict,
                     checked.verdict if checked is not None else None)
    # the recorded height above take-off: a check of the focal scale independent of the images and pose source
    relative = recorded_heights([inputs.image_paths[i] for i in keyframes])
    # measured to the ground, not to the landmarks' median: tree tops and roofs would read a correct flight low
    over_ground = ground_flying_height(landmarks.positions, [o[:, 0] for o in landmarks.observations],
                                       kf_poses.centers)
    said = height_against_takeoff(over_ground, relative, float(camera.fx))
    if said is not None:
        log.warning("%s: %s", out.path, said)
        verdict.warnings.append(said)
    timings["quality"] = time.perf_counter() - t
    t = time.perf_counter()
    # the lens against the images with the poses fixed: a wrong distortion moves the whole map in height, which
    # nothing above sees when the flight recorded no height above take-off (`plugin.lens_check`)
    # judged only on poses the pose check found fitting the images: the refit absorbs pose errors too (rev40)
    camera_source = inputs.sources.get("camera", "the camera")
    lens, lens_warnings, lens_refusals = lens_stage(landmarks, camera, camera_source, quality.flying_height_m, params,
                                                    camera_kind(camera_source, inputs.sources.get("poses", "")),
                                                    bool(fitting))
    for said in lens_warnings + lens_refusals:
        log.warning("%s: %s", out.path, said)
    verdict = joined(verdict, Verdict(refusals=lens_refusals, warnings=lens_warnings))
    timings["lens_check"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start

    counts = {
        "images": len(inputs.image_paths), "keyframes": len(keyframes),
        "masks": int(sum(len(f) for f in features)), "tracks": int(tracking.num_tracks),
        "tracks_long": long_tracks,
        "database_pairs": db_summary.num_pairs, "database_matches": db_summary.num_matches,
        "matches_rejected_epipolar": rejected, "landmarks": len(landmarks), "map_bytes": map_bytes,
        "keyframes_from_cache": cached,
        "views_per_pass": round(views, 2) if np.isfinite(views) else None,
        "min_observations": params.triangulation.min_observations,
        **{f"points_{k}": v for k, v in landmarks.counts.items()},
    }
    if checked is not None:  # the record is written in the staging folder and published beside the map
        checked = replace(checked, out=out.path / POSE_CHECK)
    summary = MapSummary(out.path, len(inputs.image_paths), len(keyframes), counts["masks"], counts["tracks"],
                         len(landmarks), map_bytes, timings["total"], cached, counts, timings, quality, verdict,
                         checked, pose_remedy(inputs, checked, params), lens)
    record = {
        "format": "sosmatch-map-run", "version": 1,
        "params": pdict, "pixel_scale": pixel_scale(params, camera.width, camera.height), "versions": _versions(),
        "inputs": recorded_sources(inputs.sources),
        # "structure from motion" or "given" (`landmark_map.POSE_SOURCE_*`): `match` searches SfM maps with a scale
        "pose_source": inputs.pose_source,
        "inputs_from_session": sources_from_session(inputs.sources, out.path), "fingerprints": fps,
        "camera": {"model": camera.model, "width": camera.width, "height": camera.height, "params": camera.params,
                   "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy},
        "epsg": inputs.epsg, "map_origin": origin.tolist(), "masks": masks_source,
        # the segmentation backend's model files (path, bytes, sha256; null for a backend without any)
        "segmentation_models": models.record(),
        # the content of landmarks.sosmap as written: readers refuse a folder whose map is another session's
        "landmarks_fingerprint": landmark_map_fingerprint(read_landmark_map(partial / "landmarks.sosmap")),
        # metres of ground per image pixel at the measured flying height (sets the segmenter's working size)
        "ground_resolution_m": round(ground_resolution, 5) if np.isfinite(ground_resolution) else None,
        # the flight's luminance range and the gain the segmenter saw its images through (plugin.flight_contrast)
        "contrast": contrast.to_dict() if contrast is not None else None,
        # what images beyond 8 bits were read between, [black, white] (database.flight_levels.flight_white_level)
        "image_levels": levels_record(white),
        "keyframes": [kf_poses.names[i] for i in range(len(kf_poses))],
        # sha256 of each keyframe's image: which images a map was made from (session_images.check_map_of_images)
        "keyframe_images": {inputs.poses.names[k]: digests[k] for k in keyframes},
        "counts": counts, "quality": {**quality.to_dict(), "images": images.to_dict()},
        "verdict": verdict_record(verdict, params.quality.refuse),
        # the flying height against the recorded height above take-off (match judges a vertical move by it)
        "height_above_takeoff": takeoff_record(over_ground, relative),
        "pose_check": checked.summary() if checked is not None else None,
        # the camera's distortion refit on the map's observations, poses fixed (plugin.lens_check)
        "lens_check": lens.to_dict() if lens is not None else None,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        # the map's own noise (plugin.map_noise): `sosmatch match` derives its tolerances from it
        "noise": landmarks.noise.to_dict() if landmarks.noise is not None else None,
    }
    write_text_atomic(out.staged(RECORD), json.dumps(record, indent=2) + "\n")
    out.publish((*OUTPUTS, *extra_outputs), last=RECORD, optional=(FIGURE,))  # a failed picture loses nothing
    return summary
