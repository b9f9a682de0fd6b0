"""`poses.run`: the stages of structure from motion in a work directory, resumable, and the output directory."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...database.atomic import write_text_atomic
from ...database.cameras import format_cameras_txt
from ...database.code_version import code_versions, kept_message, other_version
from ...database.images import check_images_decode
from ...database.json_text import json_default
from ...database.output_markers import VersionedIdentity, fingerprint, input_identity, read_json_or_none
from ...database.outputs import open_output_dir
from ...database.poses import format_poses_csv
from ...database.taken import make_dirs
from ...plugin.errors import InputError
from ...plugin.geometry import Poses
from ...plugin.gps_track import with_quantisation
from ...plugin.params import Params, params_to_dict
from .. import sfm
from ..image_priors import ImagePriors, list_images, read_image_priors
from ..pose_refinement.with_colmap import poses_of_reconstruction
from .checks import (
    NOMINAL_HEIGHT_M,
    _compare,
    _register,
    _transform_model,
    flying_height_m,
    focal_length_warnings,
    lag_corrected,
    refuse_frozen_gps,
)
from .focal import exif_focal_priors, weigh_focal_lengths
from .result import FILES, OUTPUTS, RECORD, PosesResult, _listing, _refuse_cameras, load_result, map_inputs

log = logging.getLogger(__name__)
MIN_IMAGES = 3  # the fewest images an incremental reconstruction (two-view start + one more) can pose
GROSS_GPS_SIGMAS = 10.0  # an image this many GPS sigmas off its fix, weakly tied, is a failed registration

def _image_identity(paths: Sequence[Path]) -> list[list[Any]]:
    out = []
    for p in paths:
        st = p.stat()
        out.append([p.name, st.st_size, st.st_mtime_ns])
    return out

def identity_of(image_dir: Path, params: Params, telemetry: str | Path | None = None, **options: Any) -> str:
    """What the poses of `image_dir` depend on: the image files (names, sizes, times), the SfM parameters, the
    seed, the `telemetry` file's content (`input_identity`) and `options` (take-off altitude, ...). One
    version's identity of the settings only: no setting of the sfm section is registered in
    `plugin.params.identity.ADDED` (tests/test_identity_versions.py fails when one is; then build it with
    `versioned_identity`, also for the stages' marks in `compute_poses`); `versions_of` adds the identity an
    earlier sosmatch gave the same telemetry."""
    return _identity(image_dir, params, input_identity(telemetry), options)


def versions_of(image_dir: Path, params: Params, telemetry: str | Path | None = None,
                **options: Any) -> VersionedIdentity:
    """`identity_of`, and with a telemetry file also the identity sosmatch gave these poses until fix130 (the
    telemetry keyed by its path as given, not its content; rev52 D2): such an output is this one (an upgrade
    resumes it, re-marked under today's identity). The old form was blind to an edited file; the content is
    what tells now, and the one-time acceptance takes an output made of that path's file as it was then."""
    return VersionedIdentity(identity_of(image_dir, params, telemetry, **options),
                             earlier_identities_of(image_dir, params, telemetry, **options))


def earlier_identities_of(image_dir: Path, params: Params, telemetry: str | Path | None = None,
                          **options: Any) -> tuple[str, ...]:
    """`versions_of`'s earlier identities alone (none without a telemetry file), for a caller that has today's
    already: a map's start asks for both, and today's lists and stats every image and hashes the telemetry."""
    return () if telemetry is None else (_identity(image_dir, params, telemetry, options),)


def _identity(image_dir: Path, params: Params, telemetry: Any, options: dict[str, Any]) -> str:
    return fingerprint({"images": _image_identity(list_images(image_dir)), "sfm": params_to_dict(params.sfm),
                        "seed": params.seed,
                        **{k: str(v) for k, v in {"telemetry": telemetry, **options}.items()}})


def run(
    images: str | Path,
    out: str | Path,
    params: Params | None = None,
    telemetry: str | Path | None = None,
    takeoff_altitude_m: float | None = None,
    sensor_width_mm: float | None = None,
    nominal_height_m: float = NOMINAL_HEIGHT_M,
    overwrite: bool = False,
    epsg: int | None = None,
) -> PosesResult:
    """Poses of the images in directory `images` into directory `out` (see the module doc). `epsg`: their
    projected CRS (None: the UTM zone of the flight's median fix)."""
    params = params or Params()
    image_dir = Path(images)
    if not image_dir.is_dir():
        raise InputError("image directory not found", image_dir)
    if not (math.isfinite(nominal_height_m) and nominal_height_m > 0):  # scales a block without GPS heights
        raise InputError(f"the nominal height must be a positive number of metres, got {nominal_height_m!r}")
    options = {"takeoff": takeoff_altitude_m, "sensor": sensor_width_mm,
               "nominal_height_m": nominal_height_m,
               **({} if epsg is None else {"epsg": epsg})}  # only when chosen: earlier outputs keep their identity
    sfm.refuse_pair_list_names(list_images(image_dir))  # before anything is written
    versions = versions_of(image_dir, params, telemetry, **options)
    identity = versions.today
    with open_output_dir(out, "poses", versions, inputs=[image_dir, telemetry], overwrite=overwrite,
                         files=FILES) as taken:
        if taken.was_complete and (taken.path / RECORD).is_file():
            # the same inputs and settings: the outputs stand, also those of another sosmatch (the identity keys
            # the settings, not the code), said once; --overwrite computes them again with this one
            made_by = other_version(read_json_or_none(taken.path / RECORD))
            if made_by is None or not overwrite:
                if made_by is not None:
                    log.warning("%s", kept_message(taken.path, made_by, "computes it again"))
                return load_result(taken.path)
        priors = read_image_priors(image_dir, telemetry, sensor_width_mm=sensor_width_mm,
                                   takeoff_altitude_m=takeoff_altitude_m, epsg=epsg)
        result = compute_poses(image_dir, taken.staging / "work", params, identity, telemetry, takeoff_altitude_m,
                               sensor_width_mm, nominal_height_m, priors, renew_other_versions=overwrite)
        for name in (*OUTPUTS, RECORD):
            os.replace(result.out_dir / name, taken.staged(name))
        taken.publish(list(OUTPUTS), last=RECORD)
        taken.finish()
    return load_result(taken.path)

def compute_poses(image_dir: Path, work: Path, params: Params, identity: str,
                  telemetry: str | Path | None = None, takeoff_altitude_m: float | None = None,
                  sensor_width_mm: float | None = None, nominal_height_m: float = NOMINAL_HEIGHT_M,
                  priors: ImagePriors | None = None, renew_other_versions: bool = False) -> PosesResult:
    """The stages in directory `work` (created; features and matches of an interrupted run with the same
    `identity` are reused); the outputs end up in `work/result` (a finished result there is returned as is).
    `priors`: the images' metadata when the caller has read it already (with these options). A stage another
    sosmatch finished is reused with a warning (the identity keys the settings, not the code), or done again with
    `renew_other_versions` (`--overwrite`), as a finished output is (`run`)."""
    make_dirs(work)  # a taken output directory moved away under its run is not re-created
    result_dir = work / "result"
    done = _stage_done(work, "result", identity, renew_other_versions)
    if done is not None and (result_dir / RECORD).is_file():
        return load_result(result_dir)
    shutil.rmtree(result_dir, ignore_errors=True)
    if priors is None:
        priors = read_image_priors(image_dir, telemetry, sensor_width_mm=sensor_width_mm,
                                   takeoff_altitude_m=takeoff_altitude_m)
    matched = _stage_done(work, "match", identity, renew_other_versions)
    if matched is None:  # COLMAP's reader half-decodes a truncated JPEG quietly
        check_images_decode(image_dir / n for n in priors.names)
        _drop_foreign_database(work, identity, renew_other_versions)
    result = _compute(image_dir, work, result_dir, priors, params, identity, nominal_height_m, matched)
    _mark_stage(work, "result", identity, {})
    return result

def _stage_done(work: Path, name: str, key: str, renew_other_versions: bool = False) -> dict | None:
    """The record of stage `name` of an interrupted run in `work` with the same `key` (inputs and settings), or
    None. One another sosmatch finished is said once and reused, or None with `renew_other_versions`."""
    try:
        done = json.loads((work / "stages.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    entry = done.get(name)
    if not (isinstance(entry, dict) and entry.get("key") == key):
        return None
    made_by = other_version(entry)
    if made_by is not None:
        if renew_other_versions:
            return None
        what = {"match": "features and matches", "database": "features"}.get(name, "the poses")
        log.warning("%s", kept_message(f"{work}: {what} of an interrupted run", made_by, "computes them again"))
    return {k: v for k, v in entry.items() if k not in ("key", "versions")}  # the stage's own figures

def _drop_foreign_database(work: Path, key: str, renew_other_versions: bool) -> None:
    """An interrupted extraction's database resumes only when this run's settings made it (and this sosmatch,
    or another one said once, unless `renew_other_versions`); else it is removed (the run's own file) and made
    again: COLMAP's extraction skips the images a database holds, whoever extracted them."""
    db = work / "database.db"
    if db.is_file() and _stage_done(work, "database", key, renew_other_versions) is None:
        for path in (db, db.with_name(db.name + "-wal"), db.with_name(db.name + "-shm")):
            path.unlink(missing_ok=True)

def _mark_stage(work: Path, name: str, key: str, result: dict) -> None:
    try:
        done = json.loads((work / "stages.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        done = {}
    done[name] = {"key": key, "versions": code_versions(), **result}  # which sosmatch finished it
    write_text_atomic(work / "stages.json", json.dumps(done, indent=1, default=json_default) + "\n")

@contextmanager
def _named_as(colmap_dir: Path, image_dir: Path) -> Iterator[None]:
    """COLMAP's errors name the user's folder, not the 8-bit copies it read (`sfm.colmap_image_dir`)."""
    try:
        yield
    except InputError as exc:
        if exc.path != colmap_dir:
            raise
        raise InputError(exc.problem, image_dir, exc.line) from None


def _compute(image_dir: Path, work: Path, result_dir: Path, priors: ImagePriors, params: Params, key: str,
             nominal_height_m: float, matched: dict | None) -> PosesResult:
    """Features, pairs, matches (resumable), mapping, georegistration, comparison; the files into `result_dir`."""
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    db = work / "database.db"
    sp = params.sfm
    # the receiver's sigma with the rounding of the fixes (`gps_track.with_quantisation`): one figure for the run
    gps_sigma_m = with_quantisation(sp.gps_sigma_m, priors.summary)
    # the priors' own warnings count too (a camera without a focal length in EXIF was printed but not counted);
    # the priors logged them when they were read: only those said here on are logged below (rev49 D9: twice)
    warnings: list[str] = list(priors.summary.get("warnings", []))
    said_by_priors = len(warnings)

    if len(priors.names) < MIN_IMAGES:  # said before the work: COLMAP would report "0 registered", not why
        raise InputError(f"{len(priors.names)} image(s): structure from motion needs at least {MIN_IMAGES} "
                         "overlapping images", image_dir)
    refuse_frozen_gps(priors, image_dir)  # (the intake knows it: before the work, not a traceback after it)
    # COLMAP reads 8-bit images: data of more than 8 bits as white-levelled copies (also for the mapper's colours)
    colmap_dir = sfm.colmap_image_dir(image_dir, priors.names, work / "images8")
    if matched is None or not db.is_file():  # `matched`: the match stage of an interrupted run (`_stage_done`)
        if not db.is_file():  # else kept from an interrupted run (`_drop_foreign_database`): extraction resumes
            sfm.create_database(db, priors, sp)
            _mark_stage(work, "database", key, {})
        with _named_as(colmap_dir, image_dir):
            features = sfm.extract_features(db, colmap_dir, priors, sp)
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
    with _named_as(colmap_dir, image_dir):
        model = sfm.reconstruct(db, colmap_dir, work / "models", priors, sp, params.seed, use_priors)
    timings["mapping"] = model.seconds
    n_all = len(priors.names)
    _check_registered(len(model.registered), n_all, sp, image_dir, "registered")
    links: dict[str, int] = {}
    if model.unregistered:
        links = sfm.strongest_links(db, model.unregistered, model.registered)
        warnings.append(unregistered_warning(model, links, n_all))

    # Georegistration (or a local frame) of the registered images.
    t = time.perf_counter()
    names, r_sfm, c_sfm = model.poses()
    index = np.array([priors.names.index(n) for n in names])
    transform, geo_report, geo = _register(priors, index, r_sfm, c_sfm, model, nominal_height_m, params.seed, sp,
                                           warnings)
    priors = lag_corrected(priors, index, geo)
    _transform_model(model.reconstruction, transform)
    world_r = np.einsum("ij,njk->nik", transform.rotation, r_sfm)
    world_c = transform.apply(c_sfm)
    poses = Poses(names, world_r, world_c)
    timings["georegistration"] = time.perf_counter() - t

    if model.incremental_registered is not None:
        # weakly tied to the rest (the incremental mapper could not add them): said; where the GPS disagrees too,
        # neither source can be trusted (the global mapper placed such images 2000 km off on Seneca frames), so
        # they are left out like unregistered images
        added = model.registered_only_by_global_mapper
        flagged = [n for n in (geo_report or {}).get("gps_outliers", []) if n in added]
        # left out only beyond a gross-error bound (10 GPS sigmas, at least the configured receiver's): the
        # outlier limit (~3 sigma) also flags ~1 % of good images by the GPS noise alone
        sigma = max(float(geo.horizontal.sigma_m) if geo is not None else 0.0, gps_sigma_m)
        fix = {n: priors.positions[priors.names.index(n), :2] for n in flagged}
        miss = {n: float(np.linalg.norm(poses.centers[names.index(n), :2] - fix[n])) for n in flagged}
        off = [n for n in flagged if miss[n] > GROSS_GPS_SIGMAS * sigma]
        near = [n for n in flagged if n not in off]
        warnings.append(f"{len(added)} of {n_all} images were registered only by COLMAP's global mapper (the "
                        "incremental mapper left them out: weakly tied to the others)"
                        + (f"; {len(off)} of them lie more than {GROSS_GPS_SIGMAS:g} GPS sigmas ("
                           f"{GROSS_GPS_SIGMAS * sigma:.0f} m) off their GPS fix and are left out ("
                           + _listing([f"{n} {miss[n]:.0f} m" for n in off]) + ")" if off else "")
                        + (f"; {len(near)} off their fix by more than the outlier limit ({_listing(near)})"
                           if near else "") + ": " + _listing(added))
        if off:
            poses = _without_images(model, poses, off)
            _check_registered(len(poses.names), n_all, sp, image_dir, "placed where their GPS allows")
            names = poses.names
            index = np.array([priors.names.index(n) for n in names])
    # the focal lengths weighed against EXIF's before anything is compared: over flat ground the images barely
    # know them, and a free one moves every depth (nu25: +5.7 %, the ground 4-6 m low)
    t = time.perf_counter()
    exif_cameras = exif_focal_priors(priors)
    focal_estimates, refitted = weigh_focal_lengths(model.reconstruction, exif_cameras, gps_sigma_m,
                                                    order=priors.names)
    timings["focal_lengths"] = time.perf_counter() - t
    if refitted:
        poses = poses_of_reconstruction(model.reconstruction)
        poses = poses.subset([poses.names.index(n) for n in names])
    comparison = _compare(priors, index, poses, warnings, local_frame=geo is None)
    cameras = sfm.camera_of_model(model)
    focal_warnings = focal_length_warnings(focal_estimates, exif_cameras, cameras,
                                           flying_height_m(model.reconstruction))
    warnings.extend(focal_warnings)
    camera_of_image = {im.name: int(im.camera_id) for im in model.reconstruction.images.values() if im.has_pose}
    rec = model.reconstruction
    reprojection = float(np.mean([p.error for p in rec.points3D.values()])) if rec.num_points3D() else 0.0
    for w in warnings[said_by_priors:]:
        log.warning("%s", w)

    # Outputs: model, database, pose CSV, cameras, then the record (last).
    tmp = work / "result.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "sparse").mkdir(parents=True)
    rec.write_binary(tmp / "sparse")
    epsg = priors.epsg if geo is not None else 0
    write_text_atomic(tmp / "poses.csv", format_poses_csv(poses, epsg))
    write_text_atomic(tmp / "cameras.txt", format_cameras_txt(cameras))
    sfm.publish_database(db, tmp / "database.db")  # the work directory's copy is not needed any more
    timings["total"] = time.perf_counter() - t0
    report = {
        "format": "sosmatch-poses", "version": 1, "versions": code_versions(),  # which sosmatch made them
        "images": n_all, "registered": len(names), "unregistered": model.unregistered,
        "left_out_off_gps": sorted(set(model.registered) - set(names)),
        "other_models": model.other_models,
        "mapper": model.mapper, "incremental_registered": model.incremental_registered,
        "registered_only_by_global_mapper": model.registered_only_by_global_mapper,
        "unregistered_strongest_link_inliers": links,
        "epsg": epsg, "crs": f"EPSG:{epsg}" if epsg else "local",
        "points": int(rec.num_points3D()), "reprojection_px": reprojection,
        "cameras": {str(k): {"model": c.model, "width": c.width, "height": c.height, "params": c.params}
                    for k, c in cameras.items()},
        "camera_of_image": camera_of_image,
        "focal_lengths": [e.to_dict() for e in focal_estimates], "focal_length_warnings": focal_warnings,
        "priors": priors.summary, "matching": matched, "gps_priors_in_bundle_adjustment": use_priors,
        "georegistration": geo_report, "comparison": comparison,
        "params": params_to_dict(sp), "warnings": warnings,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    write_text_atomic(tmp / RECORD, json.dumps(report, indent=1, default=json_default) + "\n")
    os.replace(tmp, result_dir)
    return load_result(result_dir)

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
    # the projected CRS of the poses (None: the UTM zone of the flight's median fix, `image_priors`): flights of
    # one site across a zone edge mapped in one (`map --epsg`, `batch --epsg`)
    epsg: int | None = None

    def _options(self) -> dict[str, Any]:
        # the CRS only when chosen: sessions mapped before the option keep their identity (and resume)
        return {"takeoff": self.takeoff_altitude_m, "sensor": self.sensor_width_mm,
                "nominal_height_m": self.nominal_height_m, **({} if self.epsg is None else {"epsg": self.epsg})}

    def identity(self) -> str:
        """What the poses depend on; and the inputs' refusals that need no work (map asks before it takes its
        output directory)."""
        if not Path(self.images).is_dir():
            raise InputError("image directory not found", self.images)
        sfm.refuse_pair_list_names(list_images(Path(self.images)))
        return identity_of(Path(self.images), self.params, self.telemetry, **self._options())

    def earlier_identities(self) -> tuple[str, ...]:
        """The identities earlier sosmatch versions gave these same poses (`versions_of`): a map made of them is
        this map."""
        return earlier_identities_of(Path(self.images), self.params, self.telemetry, **self._options())

    def input_paths(self) -> list[Path]:
        return [Path(self.images)] + ([Path(self.telemetry)] if self.telemetry else [])

    def resolve(self, out: Any, renew_other_versions: bool = False) -> tuple[Any, tuple[str, ...]]:
        """Poses (in OUT/.partial/poses_work, reused when an interrupted run finished them; computed again when
        another sosmatch did, with `renew_other_versions`) -> map inputs; the result directory is staged as
        OUT/.partial/poses."""
        image_dir = Path(self.images)
        priors = read_image_priors(image_dir, self.telemetry, sensor_width_mm=self.sensor_width_mm,
                                   takeoff_altitude_m=self.takeoff_altitude_m, epsg=self.epsg)
        if len(priors.cameras) > 1:  # before the structure from motion: map takes one camera
            # the focal length named too: a zoom's settings are cameras of one size (`camera_groups`)
            _refuse_cameras([f"{c.width}x{c.height} fx {c.fx:.0f} px" for c in priors.cameras], image_dir)
        work = out.staging / "poses_work"
        result = compute_poses(image_dir, work, self.params, self.identity(), self.telemetry,
                               self.takeoff_altitude_m, self.sensor_width_mm, self.nominal_height_m, priors,
                               renew_other_versions=renew_other_versions)
        staged = out.staging / "poses"
        shutil.rmtree(staged, ignore_errors=True)
        shutil.copytree(result.out_dir, staged)  # the work copy stays for a resumed run until the map is done
        self.result = load_result(staged)
        source = f"structure from motion of {image_dir} (SESSION_DIR/poses)"
        return map_inputs(self.result, image_dir, source), ("poses",)


def unregistered_warning(model: sfm.SfmModel, links: dict[str, int], n_all: int) -> str:
    """What is said of the images the largest model left out: each with its strongest link to it (`links`:
    inliers), the weakest first, and the distinct images the separate models hold."""
    weak = sorted(model.unregistered, key=lambda n: (links[n], n))
    return (f"{len(model.unregistered)} of {n_all} images could not be registered and are left out (too few verified "
            f"matches with the registered images: at most {max(links.values())} inliers with any one of them"
            + (f"; {len(model.other_models)} separate model(s) hold {len(model.other_model_images)} images"
               if model.other_models else "") + "): " + _listing([f"{n} ({links[n]})" for n in weak]))


def _check_registered(count: int, n_all: int, sp: Any, image_dir: Path, how: str) -> None:
    """InputError when fewer than `sfm.min_registered_fraction` of the images (at least MIN_IMAGES) have poses."""
    if count < max(MIN_IMAGES, sp.min_registered_fraction * n_all):
        raise InputError(f"structure from motion {how} only {count} of {n_all} images (sfm.min_registered_fraction "
                         f"= {sp.min_registered_fraction}); the images may not overlap enough or lack texture; "
                         "`sosmatch poses-from-exif` gives the EXIF/XMP poses instead", image_dir)


def _without_images(model: Any, poses: Poses, left_out: list[str]) -> Poses:
    """`poses` without the images `left_out`, which are also de-registered from the model (with their
    observations), so that the published sparse model and poses.csv agree."""
    rec = model.reconstruction
    for image in list(rec.images.values()):
        if image.name in left_out and image.has_pose:
            rec.deregister_frame(image.frame_id)
    return poses.subset([i for i, n in enumerate(poses.names) if n not in left_out])
