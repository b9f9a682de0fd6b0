"""Structure from motion with COLMAP itself (pycolmap 4.2): the stages, each a plain function (hloc-style).

    from sosmatch.workflows import sfm
    sfm.create_database(db, priors, params.sfm)                # one camera per group, images with fixed ids
    image_dir = sfm.colmap_image_dir(image_dir, priors.names, work / "images8")  # 8-bit copies of 16-bit data
    sfm.extract_features(db, image_dir, priors, params.sfm)     # SIFT at a bounded size
    pairs = sfm.write_pairs(pairs_txt, priors, params.sfm)      # the pairs GPS says may overlap
    sfm.match_pairs(db, pairs_txt, params.sfm)                  # SIFT matching + two-view geometry
    model = sfm.reconstruct(db, image_dir, work_dir, priors, params.sfm, seed)  # incremental or global

`workflows.poses` chains them with georegistration and the outputs; the database and models are COLMAP's own
files (they open in COLMAP's GUI). CPU only: `SfmParams` bounds the image size, the feature count and the pairs
(measured: BENCHMARKS.md, "Poses from images").
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..database.colmap_model import PAIR_LIST, colmap_text_name_problem, refuse_names_colmap_cannot_hold
from ..database.full_disk import full_disk_reported
from ..database.taken import make_dirs
from ..plugin.errors import InputError
from ..plugin.image_pairs import line_spacing_m, overlap_cap_m, select_pairs
from ..plugin.params import SfmParams

if TYPE_CHECKING:

    from .image_priors import ImagePriors

log = logging.getLogger(__name__)


def _quiet() -> None:
    import pycolmap

    pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel),
                                       1 if log.isEnabledFor(logging.DEBUG) else 2)


def _threads() -> int:
    import os

    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def _initial_camera(cam: Any, camera_id: int, model: str) -> Any:
    """The pycolmap camera `model` starting from the EXIF intrinsics `cam` (no distortion)."""
    import pycolmap

    one_focal = model in ("SIMPLE_RADIAL", "SIMPLE_PINHOLE", "RADIAL")
    focal = [cam.fx] if one_focal else [cam.fx, cam.fy]
    extra = {"SIMPLE_RADIAL": [0.0], "RADIAL": [0.0, 0.0], "OPENCV": [0.0] * 4}.get(model, [])
    return pycolmap.Camera(camera_id=camera_id, model=model, width=int(cam.width), height=int(cam.height),
                           params=[float(v) for v in [*focal, cam.cx, cam.cy, *extra]])


@full_disk_reported
def create_database(database: Path, priors: ImagePriors, params: SfmParams) -> None:
    """A COLMAP database with one camera (and rig) per make + model + size, starting from the EXIF intrinsics,
    and every image in name order with fixed ids (1, 2, ...): the ids, and so everything after, do not depend
    on which extraction thread finishes first. An existing database is kept (a resumed run)."""
    import pycolmap

    if database.is_file():
        return
    tmp = database.with_name(database.name + ".tmp")
    tmp.unlink(missing_ok=True)
    db = pycolmap.Database.open(tmp)
    try:
        with pycolmap.DatabaseTransaction(db):
            for g, cam in enumerate(priors.cameras):
                camera = _initial_camera(cam, g + 1, params.camera_model)
                db.write_camera(camera, use_camera_id=True)
                rig = pycolmap.Rig(rig_id=g + 1)
                rig.add_ref_sensor(camera.sensor_id)
                db.write_rig(rig, use_rig_id=True)
            for i, (name, g) in enumerate(zip(priors.names, priors.camera_index), start=1):
                image = pycolmap.Image(name=name, camera_id=int(g) + 1, image_id=i)
                db.write_image(image, use_image_id=True)
                frame = pycolmap.Frame(frame_id=i, rig_id=int(g) + 1)
                frame.add_data_id(image.data_id)
                db.write_frame(frame, use_frame_id=True)
    finally:
        db.close()
    tmp.replace(database)


def colmap_image_dir(image_dir: Path, names: list[str], work_dir: Path) -> Path:
    """The folder COLMAP reads the images from: `image_dir` itself for 8-bit images (nothing copied), else
    `work_dir` holding 8-bit copies under the same names, scaled from the flight's white level
    (`database.flight_levels.flight_white_level`), as ODM does for 16-bit images. COLMAP's reader scales 16-bit data
    from the container's maximum, so 12-bit data stored in 16 bits reached its SIFT at 1/16 of the contrast (a
    MicaSense band: one featureless image, 0 registered, while every other stage reads it white-levelled). The
    copies are written atomically and reused by a re-run while their image (size, modification time) and the
    white level are the same (`copies.json`); the names stay the user's, so the database and the model name the
    user's files."""
    from ..database.flight_levels import flight_white_level
    from ..database.images import read_image

    white = flight_white_level([image_dir / n for n in names])
    if white is None:
        return image_dir
    import json

    import cv2

    from ..database.atomic import write_text_atomic

    t0 = time.perf_counter()
    written = 0
    # what each copy was made from: a re-run after the user replaced an image, or added images that raise the
    # flight's white level, must not feed COLMAP the old pixels or a mix of white levels (rev22)
    manifest_path = work_dir / "copies.json"
    try:
        made = json.loads(manifest_path.read_text())
    except (OSError, ValueError):
        made = {}
    made = made if isinstance(made, dict) else {}
    for name in names:
        target = work_dir / name
        st = (image_dir / name).stat()
        source = [st.st_size, st.st_mtime_ns, white if isinstance(white, int) else str(white)]
        if target.is_file() and made.get(name) == source:
            continue
        rgb = read_image(image_dir / name, white)
        pixels = rgb[:, :, 0] if np.array_equal(rgb[:, :, 0], rgb[:, :, 1]) and np.array_equal(
            rgb[:, :, 0], rgb[:, :, 2]) else rgb[:, :, ::-1]  # single band stays gray; OpenCV writes BGR
        make_dirs(target.parent)  # a taken output directory moved away under its run is not re-created
        tmp = target.with_name(f".tmp-{target.name}")  # the extension kept: it chooses the format
        if not cv2.imwrite(str(tmp), pixels):
            raise InputError(f"could not write an 8-bit copy for COLMAP to {tmp}", image_dir / name)
        tmp.replace(target)
        made[name] = source
        written += 1
    if written:
        write_text_atomic(manifest_path, json.dumps(made, indent=0) + "\n")
    log.info("images of more than 8 bits: COLMAP reads 8-bit copies scaled from the flight's white level %s "
             "(%d written in %.1f s, %s)", white, written, time.perf_counter() - t0, work_dir)
    return work_dir


@full_disk_reported
def extract_features(database: Path, image_dir: Path, priors: ImagePriors, params: SfmParams) -> dict[str, Any]:
    """SIFT features of every image of the database (`create_database` first): images downscaled to
    `max_image_size_px`, at most `max_features` each. Images that have features already keep them (COLMAP skips
    them), so an interrupted extraction resumes."""
    import pycolmap

    _quiet()
    t0 = time.perf_counter()
    options = pycolmap.FeatureExtractionOptions()
    options.max_image_size = params.max_image_size_px
    options.num_threads = _threads()
    options.sift.max_num_features = params.max_features
    options.sift.first_octave = params.first_octave
    options.sift.peak_threshold = params.peak_threshold
    for g in range(len(priors.cameras)):
        names = [n for n, i in zip(priors.names, priors.camera_index) if i == g]
        reader = pycolmap.ImageReaderOptions()
        reader.existing_camera_id = g + 1
        pycolmap.extract_features(database, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=options, device=pycolmap.Device.cpu)
    db = pycolmap.Database.open(database)
    try:
        counts = np.array([db.num_keypoints_for_image(im.image_id) for im in db.read_all_images()])
        num_images, num_cameras = db.num_images(), db.num_cameras()
    finally:
        db.close()
    if num_images != len(priors.names) or num_cameras != len(priors.cameras):
        raise InputError(f"COLMAP's database holds {num_images} images and {num_cameras} cameras, expected "
                         f"{len(priors.names)} and {len(priors.cameras)} (unreadable files?)", image_dir)
    featureless = [n for n, c in zip(priors.names, counts) if c == 0]
    if featureless:
        log.warning("%d image(s) gave no features (unreadable or blank): %s", len(featureless),
                    ", ".join(featureless[:8]))
    return {"images": int(num_images), "keypoints_median": float(np.median(counts)) if len(counts) else 0.0,
            "keypoints_min": int(counts.min()) if len(counts) else 0, "featureless": featureless,
            "seconds": time.perf_counter() - t0}


def footprint_diagonal_m(priors: ImagePriors) -> float | None:
    """The ground diagonal of an image at the flight's height above ground, when DJI's RelativeAltitude gives
    that height (above the take-off point, taken as the ground): centres further apart cannot overlap."""
    rel = priors.relative_altitude[np.isfinite(priors.relative_altitude)]
    if len(rel) == 0 or np.median(rel) <= 0:
        return None
    # the widest view of the cameras (diagonal / focal length): a zoom's settings are cameras of one size
    # (`image_cameras.camera_groups`), and the first one's, when it was the long setting, would have cut the wide
    # images' pairs at half their overlap. 1.5 x: the ground may lie lower than the take-off point and the camera
    # may look off nadir
    view = max(math.hypot(cam.width, cam.height) / cam.fx for cam in priors.cameras)
    return 1.5 * float(np.median(rel)) * view


def refuse_pair_list_names(image_paths: Sequence[Path]) -> None:
    """InputError naming the first image whose file name COLMAP's pair list cannot hold (`write_pairs`;
    `colmap_model.colmap_text_name_problem`), before any work: matching a list of `DJI 00000.jpg` ... matched no
    pair ("Image DJI does not exist" in COLMAP's log) after the whole feature extraction."""
    refuse_names_colmap_cannot_hold(image_paths, PAIR_LIST,
                                    "rename the images (`map --poses` with given poses keeps any name)")


def write_pairs(path: Path, priors: ImagePriors, params: SfmParams) -> tuple[np.ndarray, str]:
    """Choose the pairs to match (`plugin.image_pairs.select_pairs`, images in capture order) and write them as
    COLMAP's pair list (`name_a name_b` per line). Returns the index pairs and how they were chosen."""
    from ..database.atomic import write_text_atomic
    from ..plugin.flight_lines import flight_lines

    order = np.argsort(priors.times_s, kind="stable")
    footprint = footprint_diagonal_m(priors)
    cap = footprint
    if footprint is not None:
        xy = priors.positions[order, :2]
        has = np.all(np.isfinite(xy), axis=1)
        lines = np.full(len(xy), -1, dtype=np.int64)
        lines[has] = flight_lines(xy[has])
        spacing = line_spacing_m(xy, lines)
        cap = overlap_cap_m(footprint, spacing)
        if cap is None:
            log.warning("the images' RelativeAltitude (%.0f m above the take-off point) gives %.0f m footprints, "
                        "narrower than the %.0f m between neighbouring flight lines: the take-off point probably lies "
                        "above the surveyed ground (or the lines are flown apart); image pairs are chosen without "
                        "a distance cap",
                        float(np.nanmedian(priors.relative_altitude)), footprint, spacing)
    pairs, how = select_pairs(priors.positions[order, :2], params.neighbours, params.sequential,
                              cap, params.exhaustive_up_to, params.sequential_without_gps)
    if footprint is not None and cap is None:
        how += f" (no distance cap: RelativeAltitude's {footprint:.0f} m footprints miss the neighbouring lines)"
    pairs = np.sort(order[pairs], axis=1)
    names = priors.names
    if (problem := colmap_text_name_problem(names, PAIR_LIST)) is not None:  # the callers refuse them first
        raise ValueError(problem[1])
    write_text_atomic(path, "".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    return pairs, how


@full_disk_reported
def match_pairs(database: Path, pairs_txt: Path, params: SfmParams, seed: int = 0) -> dict[str, Any]:
    """SIFT matching of the listed pairs and their two-view geometry (RANSAC seeded), in one thread: the same
    matches whatever the thread timing."""
    import pycolmap

    _quiet()
    t0 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    # One thread: COLMAP 4.2's multi-threaded CPU matcher (its threads share FAISS descriptor indexes) now and then
    # loses matches of a pair, in about 3 runs of 1000 on 26 images with 8 threads (e.g. 44 of a pair's 170 exact
    # matches), which moved the poses (a CI flake); in one thread it gave the same exact matches 600 times of 600.
    # The raw matching is ~90 % of this stage's CPU on real photos (4000 features), so matching in one thread and
    # verifying on every core (`geometric_verification`) would save little, and it writes no two-view geometry
    # for pairs without matches (a different database).
    matching.num_threads = 1
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = pairs_txt
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(seed % (2**31))
    pycolmap.match_image_pairs(database, matching_options=matching, pairing_options=pairing,
                               verification_options=verification, device=pycolmap.Device.cpu)
    db = pycolmap.Database.open(database)
    try:
        matched, verified = db.num_matched_image_pairs(), db.num_verified_image_pairs()
    finally:
        db.close()
    return {"pairs_matched": int(matched), "pairs_verified": int(verified), "seconds": time.perf_counter() - t0}


@full_disk_reported
def write_pose_priors(database: Path, priors: ImagePriors, origin: np.ndarray, params: SfmParams) -> int:
    """GPS positions (minus `origin`) as COLMAP pose priors of the images with a fix: horizontal sigma
    `gps_sigma_m` (with the rounding of fixes written to a coarse grid added: `gps_track.with_quantisation`);
    vertical `gps_sigma_m` when the heights come from RelativeAltitude (or an RTK fixed altitude),
    else effectively free (a GPS altitude may drift by tens of metres, which a prior would bend the block to).
    Returns the number written."""
    import pycolmap

    from ..plugin.gps_track import with_quantisation

    relative = priors.heights_consistent
    # fixes rounded to a coarse grid are that much noisier (`image_positions.coarse_fixes`)
    sigma = with_quantisation(params.gps_sigma_m, priors.summary)
    sigma_z = params.gps_sigma_m if relative else 1e3
    cov = np.diag([sigma**2, sigma**2, sigma_z**2])
    index = {n: i for i, n in enumerate(priors.names)}
    db = pycolmap.Database.open(database)
    written = 0
    try:
        db.clear_pose_priors()  # COLMAP's extractor writes WGS84 priors from EXIF itself; ours replace them
        for im in db.read_all_images():
            i = index[im.name]
            if priors.has_gps[i]:
                db.write_pose_prior(pycolmap.PosePrior(
                    corr_data_id=im.data_id, position=priors.positions[i] - origin, position_covariance=cov,
                    coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN))
                written += 1
    finally:
        db.close()
    return written


# The schema cookie of every published database (`publish_database`): its bytes do not count the schema changes
# of the run that made it.
PUBLISHED_SCHEMA_VERSION = 1


def publish_database(database: Path, target: Path) -> None:
    """Move COLMAP's database `database` to `target` as a compacted copy whose bytes depend on its content alone.
    COLMAP's extraction and matching threads write the rows in the order they finish, so the pages of the same
    content lay out differently run to run (40 Seneca frames: 4 runs, 4 files, the same rows); SQLite's
    `VACUUM INTO` rewrites every table in key order (167 Seneca frames, 55 MB: 0.2 s)."""
    import sqlite3

    from ..database.atomic import atomic_path

    with atomic_path(target) as tmp:  # VACUUM INTO writes a new file: the temporary path does not exist yet
        db = sqlite3.connect(database)  # only read: VACUUM INTO leaves its source as it is
        try:
            db.execute("VACUUM INTO ?", (str(tmp),))
        finally:
            db.close()
        # VACUUM INTO copies the schema cookie, which counts the schema changes of the source's history: COLMAP's
        # `clear_pose_priors` bumps it, and a run resumed after its match stage writes the pose priors again
        # (rev49 D5: header byte 44, 22 vs 23). The copy's is set to one value; no connection has it open yet
        copy = sqlite3.connect(tmp)
        try:
            copy.execute(f"PRAGMA schema_version = {PUBLISHED_SCHEMA_VERSION}")
            copy.commit()
        finally:
            copy.close()
    database.unlink()


@dataclass
class SfmModel:
    """The largest reconstruction and what became of every image."""

    reconstruction: Any  # pycolmap.Reconstruction
    registered: list[str]
    unregistered: list[str]
    other_models: list[list[str]] = field(default_factory=list)  # images of smaller, disconnected models
    seconds: float = 0.0
    mapper: str = "incremental"  # the mapper whose model this is
    # the images the incremental mapper registered, when the global mapper's model replaced its model
    incremental_registered: list[str] | None = None

    @property
    def registered_only_by_global_mapper(self) -> list[str]:
        """The images only the global mapper registered (weakly tied to the rest), sorted; empty when the
        incremental mapper's model was kept."""
        if self.incremental_registered is None:
            return []
        return sorted(set(self.registered) - set(self.incremental_registered))

    @property
    def other_model_images(self) -> list[str]:
        """The distinct images the smaller models hold, sorted: COLMAP may put an image in several of them (rev49:
        2 models of 40 and 11 images, the 11 among the 40, said as "51 images")."""
        return sorted(set().union(*self.other_models))

    def poses(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        """(names, sfm_from_cam rotations (N,3,3), centres (N,3)) of the registered images, sorted by name."""
        rec = self.reconstruction
        by_name = {im.name: im for im in rec.images.values() if im.has_pose}
        names = sorted(by_name)
        rots, centers = [], []
        for n in names:
            pose = by_name[n].cam_from_world()
            r_cw = np.asarray(pose.rotation.matrix())
            rots.append(r_cw.T)
            centers.append(-r_cw.T @ np.asarray(pose.translation))
        return names, np.array(rots).reshape(-1, 3, 3), np.array(centers).reshape(-1, 3)


def gps_priors_apply(priors: ImagePriors, params: SfmParams) -> bool:
    """Whether the GPS goes into the bundle adjustment as pose priors (`SfmParams.use_gps_priors`)."""
    if params.use_gps_priors == "auto":
        return bool(priors.has_gps.sum() >= 3 and priors.heights_consistent)
    return params.use_gps_priors == "on" and bool(priors.has_gps.sum() >= 3)


def reconstruct(database: Path, image_dir: Path, work_dir: Path, priors: ImagePriors, params: SfmParams,
                seed: int = 0, use_priors: bool = False) -> SfmModel:
    """COLMAP's incremental (or global) mapper on the matched database (`use_priors`: with the pose priors of
    `write_pose_priors` in its bundle adjustments); the largest model is kept and the images of the others are
    listed. When the incremental mapper leaves images out and `params.global_when_incomplete`, the global mapper
    runs on the same matches and its model is kept if it registers more (`SfmModel.mapper` says which).
    InputError when no model has 3 images."""
    t0 = time.perf_counter()
    model = _mapped(database, image_dir, work_dir / params.mapper, priors, params.mapper, seed, use_priors)
    if model.unregistered and params.mapper == "incremental" and params.global_when_incomplete:
        log.info("the incremental mapper registered %d of %d images (%d other models): trying COLMAP's global "
                 "mapper on the same matches", len(model.registered), len(priors.names), len(model.other_models))
        try:
            other = _mapped(database, image_dir, work_dir / "global", priors, "global", seed, use_priors)
        except InputError:
            other = None
        if other is not None and len(other.registered) > len(model.registered):
            log.info("the global mapper registered %d of %d images: its model is taken", len(other.registered),
                     len(priors.names))
            other.incremental_registered = model.registered
            model = other
    model.seconds = time.perf_counter() - t0
    return model


def _mapped(database: Path, image_dir: Path, work_dir: Path, priors: ImagePriors, mapper: str, seed: int,
            use_priors: bool) -> SfmModel:
    """One mapper's largest model (see `reconstruct`)."""
    import pycolmap

    _quiet()
    work_dir.mkdir(parents=True, exist_ok=True)
    # One thread: COLMAP's multi-threaded bundle adjustment sums in a scheduling-dependent order, so the poses
    # depended on the machine's core count (and, rarely, on the run): the same photos gave other bytes. The
    # features before it are the same with any thread count and keep them (the matching runs in one thread too:
    # `match_pairs`).
    if mapper == "global":
        options = pycolmap.GlobalPipelineOptions()
        options.num_threads = 1
        options.random_seed = int(seed % (2**31))
        options.min_model_size = 3
        models = pycolmap.global_mapping(database, image_dir, work_dir, options)
    else:
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = 1
        options.random_seed = int(seed % (2**31))
        options.min_model_size = 3
        options.use_prior_position = use_priors
        options.use_robust_loss_on_prior_position = use_priors
        models = pycolmap.incremental_mapping(database, image_dir, work_dir, options)
    recs = sorted(models.values(), key=lambda r: -r.num_reg_images())
    if not recs or recs[0].num_reg_images() < 3:
        raise InputError(f"structure from motion registered {recs[0].num_reg_images() if recs else 0} images "
                         f"(needs 3): the images do not overlap, or have too little texture", image_dir)
    best = recs[0]
    registered = sorted(im.name for im in best.images.values() if im.has_pose)
    others = [sorted(im.name for im in r.images.values() if im.has_pose) for r in recs[1:]]
    unregistered = sorted(set(priors.names) - set(registered))
    return SfmModel(best, registered, unregistered, others, mapper=mapper)


def strongest_links(database: Path, names: list[str], registered: list[str]) -> dict[str, int]:
    """Per image of `names`: the most verified (two-view geometry) inlier matches it shares with one image of
    `registered` (0: none): why an image was left out (COLMAP registers an image on 2D-3D correspondences, at
    least 30 with its defaults, so a few dozen inliers with the registered images rarely suffice)."""
    import pycolmap

    db = pycolmap.Database.open(database)
    try:
        ids = {im.image_id: im.name for im in db.read_all_images()}
        pair_ids, counts = db.read_two_view_geometry_num_inliers()
    finally:
        db.close()
    wanted, done = set(names), set(registered)
    best = dict.fromkeys(names, 0)
    for pair_id, count in zip(pair_ids, counts):
        a, b = (ids.get(int(i)) for i in pycolmap.pair_id_to_image_pair(pair_id))
        for left, other in ((a, b), (b, a)):
            if left in wanted and other in done:
                best[left] = max(best[left], int(count))
    return best


def camera_of_model(model: SfmModel) -> dict[int, Any]:
    """{camera_id: plugin Camera} of the model's cameras, as SfM refined them (focal length, distortion)."""
    from ..database.cameras import camera_from_pycolmap

    return {int(cid): camera_from_pycolmap(cam) for cid, cam in model.reconstruction.cameras.items()}
