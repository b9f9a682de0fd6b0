"""`sosmatch poses IMAGES --out DIR`: camera poses and intrinsics from the images themselves, by COLMAP's
structure from motion, georegistered on the images' GPS; the default source of poses for a folder of photos.

    from sosmatch.workflows import poses
    result = poses.run("flight/images", "flight/poses")         # -> PosesResult
    print(result.line())

Stages (`run`): the images' metadata (`image_priors`: GPS, attitude tags, RelativeAltitude, cameras) ->
features -> the pairs GPS says overlap -> matching -> incremental (or global) mapping (`workflows.sfm`) ->
georegistration on GPS (`plugin.georegistration`: the vertical from the attitude tags checked against the GPS
altitudes, scale/yaw/offset robust to wrong fixes, heights that do not follow a drifting GPS altitude) ->
comparison with the tags (orientations per image, flight lines whose yaw contradicts the images) -> outputs.

Outputs in DIR (through `database.outputs`: a killed run resumes from the matched database; a directory not
written by `sosmatch poses` is never touched):
- `poses.csv`: registered images, world_from_camera, `# crs: EPSG:<utm>` (or `local`); `map` reads it,
- `cameras.txt`: the cameras as SfM refined them (focal length, distortion: SIMPLE_RADIAL by default),
- `sparse/`: the georegistered COLMAP model (cameras, images, 3D points), `database.db`: COLMAP's database,
- `poses.json` (last): what was measured: registered and unregistered images, the georegistration (GPS noise,
  outliers, vertical source, GPS altitude drift), per-image differences to the GPS and the tags, contradicting
  flight lines, warnings and timings.

Loud, never a quiet success: fewer than `sfm.min_registered_fraction` of the images registered, or fewer than
3, is an error (exit 2); unregistered images, GPS fixes far off the reconstruction, a GPS noise far above
`sfm.gps_sigma_m`, a drifting GPS altitude and contradicting tags are warnings, repeated in `poses.json` and
counted in the summary line. Without GPS the poses are in a local, levelled frame (scale from RelativeAltitude
if present, else cameras set `nominal_height_m` above the ground) with a warning.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import write_text_atomic
from ..database.cameras import format_cameras_txt
from ..database.outputs import fingerprint, open_output_dir
from ..database.poses import format_poses_csv
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..plugin.multisession import Sim3
from ..plugin.params import Params, SfmParams, params_to_dict
from . import sfm
from .image_priors import ImagePriors, list_images, read_image_priors

log = logging.getLogger(__name__)

RECORD = "poses.json"
OUTPUTS = ("poses.csv", "cameras.txt", "sparse", "database.db")
NOMINAL_HEIGHT_M = 100.0
# a registered orientation this far from its tags (and not explained by a contradicting line) is reported
ORIENTATION_WARNING_DEG = 10.0


@dataclass
class PosesResult:
    """What `run` produced (the files are in `out_dir`)."""

    out_dir: Path
    poses: Poses  # registered images, world_from_camera, sorted by name
    cameras: dict[int, Camera]  # as SfM refined them
    camera_of_image: dict[str, int]
    epsg: int  # 0: local frame
    unregistered: list[str]
    report: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def line(self) -> str:
        """The one-line summary `sosmatch poses` prints."""
        geo = self.report.get("georegistration") or {}
        frame = f"EPSG:{self.epsg}" if self.epsg else "local frame"
        text = (f"{self.out_dir}: {len(self.poses)} of {len(self.poses) + len(self.unregistered)} images registered "
                f"({frame}")
        if geo:
            text += f", GPS noise {geo['gps_horizontal_sigma_m']:.2f} m"
        text += f"), {self.report.get('points', 0)} points at {self.report.get('reprojection_px', 0.0):.2f} px"
        if self.warnings:
            text += f"; {len(self.warnings)} WARNING(S), see {RECORD}"
        return text


def _image_identity(paths: Sequence[Path]) -> list[list[Any]]:
    out = []
    for p in paths:
        st = p.stat()
        out.append([p.name, st.st_size, st.st_mtime_ns])
    return out


def identity_of(image_dir: Path, params: Params, **options: Any) -> str:
    """What the poses of `image_dir` depend on: the image files (names, sizes, times), the SfM parameters, the
    seed and `options` (telemetry, take-off altitude, ...)."""
    return fingerprint({"images": _image_identity(list_images(image_dir)), "sfm": params_to_dict(params.sfm),
                        "seed": params.seed, **{k: str(v) for k, v in options.items()}})


def run(
    images: str | Path,
    out: str | Path,
    params: Params | None = None,
    telemetry: str | Path | None = None,
    takeoff_altitude_m: float | None = None,
    sensor_width_mm: float | None = None,
    nominal_height_m: float = NOMINAL_HEIGHT_M,
    overwrite: bool = False,
) -> PosesResult:
    """Poses of the images in directory `images` into directory `out` (see the module doc)."""
    params = params or Params()
    image_dir = Path(images)
    if not image_dir.is_dir():
        raise InputError("image directory not found", image_dir)
    options = {"telemetry": telemetry, "takeoff": takeoff_altitude_m, "sensor": sensor_width_mm,
               "nominal_height_m": nominal_height_m}
    identity = identity_of(image_dir, params, **options)
    with open_output_dir(out, "poses", identity, inputs=[image_dir, telemetry], overwrite=overwrite) as taken:
        if taken.was_complete and (taken.path / RECORD).is_file():
            return load_result(taken.path)  # the same inputs and settings: the outputs stand
        result = compute_poses(image_dir, taken.staging / "work", params, identity, telemetry, takeoff_altitude_m,
                               sensor_width_mm, nominal_height_m)
        for name in (*OUTPUTS, RECORD):
            os.replace(result.out_dir / name, taken.staged(name))
        (taken.path / RECORD).unlink(missing_ok=True)  # published last: present = the outputs beside it are complete
        taken.publish(list(OUTPUTS), last=RECORD)
        taken.finish()
    return load_result(taken.path)


def compute_poses(image_dir: Path, work: Path, params: Params, identity: str,
                  telemetry: str | Path | None = None, takeoff_altitude_m: float | None = None,
                  sensor_width_mm: float | None = None, nominal_height_m: float = NOMINAL_HEIGHT_M,
                  priors: ImagePriors | None = None) -> PosesResult:
    """The stages in directory `work` (created; features and matches of an interrupted run with the same
    `identity` are reused); the outputs end up in `work/result` (a finished result there is returned as is).
    `priors`: the images' metadata when the caller has read it already (with these options)."""
    work.mkdir(parents=True, exist_ok=True)
    result_dir = work / "result"
    done = _stage_done(work, "result", identity)
    if done is not None and (result_dir / RECORD).is_file():
        return load_result(result_dir)
    shutil.rmtree(result_dir, ignore_errors=True)
    if priors is None:
        priors = read_image_priors(image_dir, telemetry, sensor_width_mm=sensor_width_mm,
                                   takeoff_altitude_m=takeoff_altitude_m)
    result = _compute(image_dir, work, result_dir, priors, params, identity, nominal_height_m)
    _mark_stage(work, "result", identity, {})
    return result


def _stage_done(work: Path, name: str, key: str) -> dict | None:
    try:
        done = json.loads((work / "stages.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    entry = done.get(name)
    return entry if isinstance(entry, dict) and entry.get("key") == key else None


def _mark_stage(work: Path, name: str, key: str, result: dict) -> None:
    try:
        done = json.loads((work / "stages.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        done = {}
    done[name] = {"key": key, **result}
    write_text_atomic(work / "stages.json", json.dumps(done, indent=1, default=_json_default) + "\n")


def _compute(image_dir: Path, work: Path, result_dir: Path, priors: ImagePriors, params: Params, key: str,
             nominal_height_m: float) -> PosesResult:
    """Features, pairs, matches (resumable), mapping, georegistration, comparison; the files into `result_dir`."""
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    db = work / "database.db"
    sp = params.sfm
    warnings: list[str] = []

    matched = _stage_done(work, "match", key)
    if matched is None or not db.is_file():
        sfm.create_database(db, priors, sp)  # kept from an interrupted run: extraction resumes
        features = sfm.extract_features(db, image_dir, priors, sp)
        timings["features"] = features["seconds"]
        pairs, how = sfm.write_pairs(work / "pairs.txt", priors, sp)
        matching = sfm.match_pairs(db, work / "pairs.txt", sp, params.seed)
        timings["matching"] = matching["seconds"]
        matched = {"features": features, "pairs": int(len(pairs)), "pairs_chosen_by": how, **matching}
        _mark_stage(work, "match", key, matched)
    else:
        log.info("features and matches of a previous run reused (%s)", db)
    origin = np.nanmedian(priors.positions, axis=0) if priors.has_gps.any() else np.zeros(3)
    origin = np.where(np.isfinite(origin), np.round(origin), 0.0)
    use_priors = sfm.gps_priors_apply(priors, sp)
    if use_priors:
        sfm.write_pose_priors(db, priors, origin, sp)
    shutil.rmtree(work / "models", ignore_errors=True)
    model = sfm.reconstruct(db, image_dir, work / "models", priors, sp, params.seed, use_priors)
    timings["mapping"] = model.seconds
    n_all = len(priors.names)
    if len(model.registered) < max(3, sp.min_registered_fraction * n_all):
        raise InputError(f"structure from motion registered only {len(model.registered)} of {n_all} images "
                         f"(sfm.min_registered_fraction = {sp.min_registered_fraction}); the images may not overlap "
                         "enough or lack texture; `sosmatch poses-from-exif` gives the EXIF/XMP poses instead",
                         image_dir)
    if model.unregistered:
        warnings.append(f"{len(model.unregistered)} of {n_all} images could not be registered and are left out: "
                        + _listing(model.unregistered))

    # Georegistration (or a local frame) of the registered images.
    t = time.perf_counter()
    names, r_sfm, c_sfm = model.poses()
    index = np.array([priors.names.index(n) for n in names])
    transform, geo_report, geo = _register(priors, index, r_sfm, c_sfm, model, nominal_height_m, params.seed, sp,
                                           warnings)
    _transform_model(model.reconstruction, transform)
    world_r = np.einsum("ij,njk->nik", transform.rotation, r_sfm)
    world_c = transform.apply(c_sfm)
    poses = Poses(names, world_r, world_c)
    timings["georegistration"] = time.perf_counter() - t

    comparison = _compare(priors, index, poses, warnings)
    cameras = sfm.camera_of_model(model)
    _check_focal_lengths(priors, cameras, warnings)
    camera_of_image = {im.name: int(im.camera_id) for im in model.reconstruction.images.values() if im.has_pose}
    rec = model.reconstruction
    reprojection = float(np.mean([p.error for p in rec.points3D.values()])) if rec.num_points3D() else 0.0
    for w in warnings:
        log.warning("%s", w)

    # Outputs: model, database, pose CSV, cameras, then the record (last).
    tmp = work / "result.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "sparse").mkdir(parents=True)
    rec.write_binary(tmp / "sparse")
    epsg = priors.epsg if geo is not None else 0
    write_text_atomic(tmp / "poses.csv", format_poses_csv(poses, epsg))
    write_text_atomic(tmp / "cameras.txt", format_cameras_txt(cameras))
    os.replace(db, tmp / "database.db")  # the work directory's copy is not needed any more
    timings["total"] = time.perf_counter() - t0
    report = {
        "format": "sosmatch-poses", "version": 1,
        "images": n_all, "registered": len(names), "unregistered": model.unregistered,
        "other_models": model.other_models,
        "epsg": epsg, "crs": f"EPSG:{epsg}" if epsg else "local",
        "points": int(rec.num_points3D()), "reprojection_px": reprojection,
        "cameras": {str(k): {"model": c.model, "width": c.width, "height": c.height, "params": c.params}
                    for k, c in cameras.items()},
        "camera_of_image": camera_of_image,
        "priors": priors.summary, "matching": matched, "gps_priors_in_bundle_adjustment": use_priors,
        "georegistration": geo_report, "comparison": comparison,
        "params": params_to_dict(sp), "warnings": warnings,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    write_text_atomic(tmp / RECORD, json.dumps(report, indent=1, default=_json_default) + "\n")
    os.replace(tmp, result_dir)
    return load_result(result_dir)


def load_result(out_dir: str | Path) -> PosesResult:
    """A finished `poses` output directory (poses.csv, cameras.txt, poses.json) as a PosesResult."""
    from ..database.cameras import read_cameras_txt
    from ..database.poses import read_poses_csv

    out_dir = Path(out_dir)
    record = out_dir / RECORD
    try:
        report = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"unreadable poses record: {exc}", record) from None
    poses, epsg = read_poses_csv(out_dir / "poses.csv")
    cameras = read_cameras_txt(out_dir / "cameras.txt")
    return PosesResult(out_dir, poses, cameras, {k: int(v) for k, v in report.get("camera_of_image", {}).items()},
                       epsg, list(report.get("unregistered", [])), report, list(report.get("warnings", [])))


def map_inputs(result: PosesResult, image_dir: Path, source: str) -> Any:
    """`workflows.map.MapInputs` of the registered images (one camera: a folder of several cameras is mapped
    camera by camera, an InputError says so)."""
    from .map import MapInputs

    if len(result.cameras) != 1:
        _refuse_cameras([f"{c.model} {c.width}x{c.height}" for c in result.cameras.values()], image_dir)
    paths = {p.name: p for p in list_images(image_dir)}
    camera = next(iter(result.cameras.values()))
    return MapInputs([paths[n] for n in result.poses.names], result.poses, camera, result.epsg,
                     {"poses": source, "camera": source, "images": str(image_dir)})


@dataclass
class PosesFromImages:
    """A folder of photos without poses as `workflows.map.run` inputs: structure from motion runs inside the
    map's output directory (staging area: resumable) and its outputs are published as SESSION_DIR/poses."""

    images: Path
    params: Params
    telemetry: Path | None = None
    takeoff_altitude_m: float | None = None
    sensor_width_mm: float | None = None
    nominal_height_m: float = NOMINAL_HEIGHT_M
    result: PosesResult | None = None  # after `resolve`

    def _options(self) -> dict[str, Any]:
        return {"telemetry": self.telemetry, "takeoff": self.takeoff_altitude_m, "sensor": self.sensor_width_mm,
                "nominal_height_m": self.nominal_height_m}

    def identity(self) -> str:
        if not Path(self.images).is_dir():
            raise InputError("image directory not found", self.images)
        return identity_of(Path(self.images), self.params, **self._options())

    def input_paths(self) -> list[Path]:
        return [Path(self.images)] + ([Path(self.telemetry)] if self.telemetry else [])

    def resolve(self, out: Any) -> tuple[Any, tuple[str, ...]]:
        """Poses (in OUT/.partial/poses_work, reused when an interrupted run finished them) -> map inputs; the
        result directory is staged as OUT/.partial/poses."""
        image_dir = Path(self.images)
        priors = read_image_priors(image_dir, self.telemetry, sensor_width_mm=self.sensor_width_mm,
                                   takeoff_altitude_m=self.takeoff_altitude_m)
        if len(priors.cameras) > 1:  # before the structure from motion: map takes one camera
            _refuse_cameras([f"{c.width}x{c.height}" for c in priors.cameras], image_dir)
        work = out.staging / "poses_work"
        result = compute_poses(image_dir, work, self.params, self.identity(), self.telemetry,
                               self.takeoff_altitude_m, self.sensor_width_mm, self.nominal_height_m, priors)
        staged = out.staging / "poses"
        shutil.rmtree(staged, ignore_errors=True)
        shutil.copytree(result.out_dir, staged)  # the work copy stays for a resumed run until the map is done
        self.result = load_result(staged)
        source = f"structure from motion of {image_dir} (SESSION_DIR/poses)"
        return map_inputs(self.result, image_dir, source), ("poses",)


def opensfm_poses(project: str | Path, image_dir: str | Path | None = None
                  ) -> tuple[Poses, dict[str, Camera], dict[str, str], int, dict[str, Any]]:
    """Poses of an OpenSfM / OpenDroneMap reconstruction (`database.opensfm`) in the UTM grid of its
    reference_lla (a local frame without one), and its cameras in pixels of the images in `image_dir` (the
    project may have processed resized copies: same aspect, rescaled). Returns (poses, cameras by OpenSfM id,
    camera of each image, EPSG (0: local), what was done)."""
    from ..database.images import image_size
    from ..database.opensfm import read_opensfm_reconstruction
    from .image_priors import topocentric_to_grid

    rec = read_opensfm_reconstruction(project)
    poses = rec.poses
    info: dict[str, Any] = {"source": str(rec.path), "shots": len(poses), "other_reconstructions":
                            rec.other_reconstructions}
    epsg = 0
    if rec.reference_lla is not None:
        centers, grid_from_topo, epsg = topocentric_to_grid(poses.centers, rec.reference_lla)
        poses = Poses(poses.names, np.einsum("nij,njk->nik", grid_from_topo, poses.rotations), centers)
        info["reference_lla"] = list(rec.reference_lla)
    else:
        log.warning("%s has no reference_lla: the poses stay in the reconstruction's local frame", rec.path)
        info["frame"] = "local (no reference_lla)"
    cameras = dict(rec.cameras)
    if image_dir is not None:
        files = {p.name: p for p in list_images(image_dir)}
        for cam_id, cam in rec.cameras.items():
            shot = next((n for n in poses.names if rec.camera_of_shot[n] == cam_id and Path(n).name in files), None)
            if shot is None:
                continue
            w, h = image_size(files[Path(shot).name])
            if (w, h) != (cam.width, cam.height):
                if abs(w / h - cam.width / cam.height) > 0.01:
                    raise InputError(f"image is {w}x{h} but OpenSfM camera {cam_id!r} is {cam.width}x{cam.height}"
                                     " (another aspect ratio)", files[Path(shot).name])
                cameras[cam_id] = cam.scaled(w / cam.width)
                info.setdefault("rescaled_cameras", {})[cam_id] = [cam.width, cam.height, w, h]
    return poses, cameras, dict(rec.camera_of_shot), epsg, info


def run_opensfm(project: str | Path, out: str | Path, images: str | Path | None = None,
                overwrite: bool = False) -> PosesResult:
    """`sosmatch poses --opensfm PROJECT --out DIR`: an OpenDroneMap / OpenSfM reconstruction as the same
    outputs as `run` (poses.csv in UTM, cameras.txt, a COLMAP model of the poses, poses.json)."""
    from ..database.cameras import pycolmap_camera
    from ..database.opensfm import find_reconstruction

    path = find_reconstruction(project)
    identity = fingerprint({"opensfm": [str(path.resolve()), *_image_identity([path])[0][1:]],
                            "images": _image_identity(list_images(images)) if images else None})
    with open_output_dir(out, "poses", identity, inputs=[path, images], overwrite=overwrite) as taken:
        poses, cameras, cam_of, epsg, info = opensfm_poses(path, images)
        import pycolmap

        ids = {cam_id: k + 1 for k, cam_id in enumerate(sorted(cameras))}
        rec = pycolmap.Reconstruction()
        for cam_id, k in ids.items():
            rec.add_camera_with_trivial_rig(pycolmap_camera(cameras[cam_id], k))
        r_cw, t_cw = poses.cam_from_world()
        for i, name in enumerate(poses.names):
            rec.add_image_with_trivial_frame(pycolmap.Image(name=Path(name).name, camera_id=ids[cam_of[name]],
                                                            image_id=i + 1),
                                             pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw[i]), t_cw[i]))
        sparse = taken.staged("sparse")
        sparse.mkdir()
        rec.write_binary(sparse)
        named = Poses([Path(n).name for n in poses.names], poses.rotations, poses.centers)
        write_text_atomic(taken.staged("poses.csv"), format_poses_csv(named, epsg))
        write_text_atomic(taken.staged("cameras.txt"), format_cameras_txt({k: cameras[c] for c, k in ids.items()}))
        warnings = [] if epsg else ["the OpenSfM reconstruction has no reference_lla: local frame"]
        report = {"format": "sosmatch-poses", "version": 1, "source": "opensfm", "opensfm": info,
                  "images": len(poses), "registered": len(poses), "unregistered": [], "epsg": epsg,
                  "crs": f"EPSG:{epsg}" if epsg else "local", "points": 0, "reprojection_px": 0.0,
                  "cameras": {str(k): {"model": cameras[c].model, "width": cameras[c].width,
                                       "height": cameras[c].height, "params": cameras[c].params}
                              for c, k in ids.items()},
                  "camera_of_image": {Path(n).name: ids[cam_of[n]] for n in poses.names}, "warnings": warnings}
        write_text_atomic(taken.staged(RECORD), json.dumps(report, indent=1, default=_json_default) + "\n")
        (taken.path / RECORD).unlink(missing_ok=True)
        taken.publish(["poses.csv", "cameras.txt", "sparse"], last=RECORD)
        taken.finish()
    return load_result(taken.path)


def _refuse_cameras(listing: list[str], image_dir: Path) -> None:
    raise InputError(f"the images come from {len(listing)} cameras ({', '.join(listing)}); map takes one camera: "
                     "put each camera's images in a folder of its own", image_dir)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _listing(names: Sequence[str], limit: int = 8) -> str:
    return ", ".join(names[:limit]) + (f" ... ({len(names)} in all)" if len(names) > limit else "")


def _transform_model(rec: Any, transform: Sim3) -> None:
    import pycolmap

    rec.transform(pycolmap.Sim3d(transform.scale, pycolmap.Rotation3d(transform.rotation), transform.translation))


def _register(priors: ImagePriors, index: np.ndarray, r_sfm: np.ndarray, c_sfm: np.ndarray, model: sfm.SfmModel,
              nominal_height_m: float, seed: int, sp: SfmParams, warnings: list[str]) -> tuple[Sim3, dict | None, Any]:
    """world_from_sfm: georegistration on GPS when >= 2 registered images have a fix, else a local levelled frame."""
    from ..plugin.georegistration import georegister, level_rotation, vertical_in_frame

    tags = priors.attitude_from_tags[index]
    # the GPS as the receiver gave it (its altitude checks the vertical and is measured for drift); the heights
    # to register on are the priors' (RelativeAltitude-based where DJI gives it)
    gps = np.column_stack([priors.positions[index, :2], priors.gps_altitude[index]])
    relative = "RelativeAltitude" in str(priors.summary.get("altitude_source", ""))
    reference = priors.positions[index, 2] if relative else None
    if np.sum(np.all(np.isfinite(gps[:, :2]), axis=1)) >= 2:
        geo = georegister(c_sfm, r_sfm, gps, priors.rotations[index], tags, priors.times_s[index], reference, seed)
        warnings.extend(geo.warnings)
        noisy = gps_noise_warning(geo.horizontal.sigma_m, sp.gps_sigma_m)
        if noisy:
            warnings.append(noisy)
        report = geo.to_dict()
        report["gps_outliers"] = [priors.names[index[geo.gps_indices[k]]]
                                  for k in np.flatnonzero(~geo.horizontal.inliers)]
        return geo.transform, report, geo
    # Local frame: levelled by the priors (tags or the nadir assumption), origin under the cameras' centre.
    vert = vertical_in_frame(r_sfm, priors.rotations[index], tags)
    level = level_rotation(vert.up)
    pts = np.array([p.xyz for p in model.reconstruction.points3D.values()]).reshape(-1, 3) @ level.T
    cams = c_sfm @ level.T
    ground = float(np.median(pts[:, 2])) if len(pts) else float(np.median(cams[:, 2])) - 1.0
    height = float(np.median(cams[:, 2]) - ground)
    rel = priors.relative_altitude[index]
    if np.isfinite(rel).all() and np.median(rel) > 0 and height > 0:
        scale, how = float(np.median(rel)) / height, "RelativeAltitude (height above take-off, taken as the ground)"
    else:
        scale = nominal_height_m / height if height > 0 else 1.0
        how = f"nominal: the cameras {nominal_height_m:g} m above the ground (no GPS, no RelativeAltitude)"
    centre = np.r_[np.median(cams[:, :2], axis=0), ground]
    transform = Sim3(level, -scale * centre, scale)
    warnings.append(f"no GPS positions: the poses are in a local frame (levelled by the {vert.source}, "
                    f"origin on the ground under the flight, scale {how})")
    return transform, {"frame": "local", "scale_from": how, "vertical_source": vert.source}, None


def _compare(priors: ImagePriors, index: np.ndarray, poses: Poses, warnings: list[str]) -> dict:
    """Registered poses against the GPS and the tags, per image; contradicting flight lines are warnings."""
    from ..plugin.georegistration import compare_with_priors, flight_lines

    gps = priors.positions[index]
    order = np.argsort(priors.times_s[index], kind="stable")
    lines = np.full(len(index), -1, dtype=np.int64)
    lines[order] = flight_lines(poses.centers[order])
    cmp = compare_with_priors(poses.rotations, poses.centers, priors.rotations[index], gps, lines)
    tags = priors.attitude_from_tags[index]
    per_image = []
    for k, i in enumerate(index):
        entry = {"name": priors.names[i], "line": int(lines[k]),
                 "gps_distance_m": None if not np.isfinite(cmp.position_m[k]) else float(cmp.position_m[k])}
        if tags[k]:
            entry.update(rotation_to_tags_deg=float(cmp.angle_deg[k]), yaw_to_tags_deg=float(cmp.yaw_deg[k]),
                         tilt_to_tags_deg=float(cmp.tilt_deg[k]), contradicting=bool(cmp.contradicting[k]))
        per_image.append(entry)
    names = [priors.names[i] for i in index]
    flagged = np.zeros(len(index), bool)
    for ln in cmp.lines if tags.any() else []:
        members = np.flatnonzero(lines == ln["line"])
        flagged[members] = True
        warnings.append(f"flight line {ln['line']} ({names[members[0]]} .. {names[members[-1]]}, {ln['images']} "
                        f"images): the attitude tags' yaw contradicts the images by {ln['median_yaw_deg']:+.0f} deg "
                        f"on {ln['contradicting']} of them")
    odd = np.flatnonzero(tags & ~flagged & (cmp.angle_deg > ORIENTATION_WARNING_DEG))
    if len(odd):
        warnings.append(f"{len(odd)} image(s) are oriented more than {ORIENTATION_WARNING_DEG:g} deg away from their "
                        "attitude tags: " + _listing([names[k] for k in odd]))
    summary: dict[str, Any] = {"images": per_image, "contradicting_lines": cmp.lines}
    if tags.any():
        agree = tags & ~cmp.contradicting
        summary.update(tags_yaw_bias_deg=cmp.yaw_bias_deg,
                       rotation_to_tags_median_deg=float(np.median(cmp.angle_deg[agree])) if agree.any() else None)
    has = np.isfinite(cmp.position_m)
    if has.any():
        summary["gps_distance_median_m"] = float(np.median(cmp.position_m[has]))
        summary["gps_distance_max_m"] = float(np.max(cmp.position_m[has]))
    return summary


# SfM's focal length this far from the EXIF one is not a calibration but a degenerate block: over flat ground a
# nadir camera's focal length trades against its height (measured: 24 % off on a 26-frame, 320 px synthetic flight
# of one line and a half; within 0.1 % on 90-frame flights)
FOCAL_WARNING_FRACTION = 0.10


def _check_focal_lengths(priors: ImagePriors, cameras: dict[int, Camera], warnings: list[str]) -> None:
    sources = priors.summary.get("cameras", [])
    for k, cam in cameras.items():
        exif = priors.cameras[k - 1] if 0 < k <= len(priors.cameras) else None
        if exif is None or "none in EXIF" in str(sources[k - 1].get("intrinsics_source", "")):
            continue
        change = cam.fx / exif.fx - 1.0
        if abs(change) > FOCAL_WARNING_FRACTION:
            warnings.append(f"camera {k}: structure from motion put the focal length {100 * change:+.0f} % off the "
                            f"EXIF one ({cam.fx:.1f} vs {exif.fx:.1f} px): the block may be degenerate (flat ground, "
                            "nadir views, few lines); heights and tilts are suspect")


def gps_noise_warning(sigma_m: float, expected_m: float) -> str | None:
    """A warning when the measured GPS noise is far above what a receiver gives (the block or the GPS is wrong)."""
    if math.isfinite(sigma_m) and sigma_m > 3.0 * expected_m:
        return (f"the GPS positions scatter by {sigma_m:.1f} m around the reconstruction (a receiver gives about "
                f"{expected_m:g} m): the reconstruction may be deformed or the GPS poor")
    return None
