"""Map stage 1, inputs: poses, intrinsics and the image list read, validated and paired by name; their
fingerprints."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...database.cameras import camera_for_image_files, one_camera, read_cameras_txt
from ...database.colmap_model import (
    TEXT_MODEL,
    is_colmap_model,
    read_camera_file,
    read_colmap_model_poses,
    refuse_names_colmap_cannot_hold,
)
from ...database.images import (  # noqa: F401 (IMAGE_EXTENSIONS re-exported)
    IMAGE_EXTENSIONS,
    image_files,
    name_key,
    shared_file_name,
    unique_by_key,
)
from ...database.landmark_map import POSE_SOURCE_GIVEN, POSE_SOURCE_SFM
from ...database.opensfm import is_opensfm
from ...database.output_markers import check_finished, sha256_file
from ...database.poses import read_poses_csv
from ...plugin.errors import InputError
from ...plugin.geodesy import ecef_to_grid, looks_like_ecef
from ...plugin.geometry import Camera, Poses, position_groups, rotation_angle_deg
from ...plugin.keyframes import flight_order_message, ordered_flight

log = logging.getLogger(__name__)



@dataclass
class MapInputs:
    """Resolved inputs: images in acquisition order with their poses, the camera, and where each came from."""

    image_paths: list[Path]
    poses: Poses  # same order as image_paths; names are the image names stored in the database
    camera: Camera
    epsg: int = 0
    sources: dict[str, str] = field(default_factory=dict)
    # what would give better poses, said when the pose check finds these loose (EXIF tags: `--refine`); not part of
    # the inputs' identity
    remedy: str = ""
    # what the pose source found doubtful (the georegistration's warnings of structure from motion): the map's
    # verdict says them, run.json and the summary line, not only the poses' record; not part of the identity
    warnings: list[str] = field(default_factory=list)
    # what the pose source found wrong enough to refuse a map of these poses (a GPS-image offset of more than one
    # capture interval left uncorrected: `poses.result.registration_refusals`): the map's verdict refuses with it
    refusals: list[str] = field(default_factory=list)
    # where the poses came from (`landmark_map.POSE_SOURCE_*`): run.json's `pose_source` and the map file's flag
    # (`match` searches a map of SfM poses with a similarity: `workflows.match.transform_choice`)
    pose_source: str = POSE_SOURCE_GIVEN
    # what the poses' vertical rests on and its sigma (deg), from their `sosmatch poses` record
    # (`poses.result.poses_vertical`; "", NaN: not known): the map's quality weighs its ground's tilt against it
    vertical: tuple[str, float] = ("", float("nan"))


def _is_synth_session(path: Path) -> bool:
    return path.is_dir() and (path / "session.json").is_file() and (path / "poses.csv").is_file()


def _refuse_shared_images(keep: list[tuple[int, Path]], names: list[str], poses: Path, images: Path) -> None:
    """InputError naming both when two poses pair with one image file, or two image files (in sub-folders of
    `images`) would be stored under one file name. The database holds each image once, under its file name: such
    a pair passed here and, after the whole segmentation, failed there as "SQLite error: constraint failed" (a
    traceback and a partial run). Two flights' `flight1/f000.jpg` and `flight2/f000.jpg` are the usual cause."""
    by_file: dict[Path, int] = {}
    for i, path in keep:
        file = path.resolve()  # one file reached as `images/x.jpg` and through a spelling or sub-path of its name
        if file in by_file:
            raise InputError(f"poses {names[by_file[file]]!r} and {names[i]!r} both pair with the image {path}: "
                             "one pose per image (two flights' poses given for one folder of images?)", poses)
        by_file[file] = i
    if (shared := shared_file_name(path for _, path in keep)) is not None:
        raise InputError(f"images {shared[0]} and {shared[1]} share the file name {shared[1].name!r}, under which a "
                         "map stores each image: map each folder on its own, or rename the images apart", images)


def pose_file_beside(images: str | Path) -> Path | None:
    """A pose source lying beside or inside an image folder that `map --images` got without --poses: a
    `sosmatch synth` session holding the folder, or a poses.csv in the folder or its parent (a flight laid out as
    `flight/images/` + `flight/poses.csv`, as `batch` reads it); None when there is none. Without --poses, map makes
    poses by structure from motion (in a local frame at a nominal height, when the images carry no GPS), which a
    user who forgot --poses does not want (nu54)."""
    folder = Path(images)
    for where in (folder.parent, folder):
        if _is_synth_session(where) and where / "images" == folder:
            return where
        if (where / "poses.csv").is_file():
            return where / "poses.csv"
    return None


def warn_of_pose_file_beside(images: str | Path) -> Path | None:
    """Say in one warning line when `pose_file_beside` finds a pose source that map was not given; returns it."""
    found = pose_file_beside(images)
    if found is not None:
        log.warning("%s looks like this flight's poses: pass --poses %s to use them (without --poses, map makes "
                    "poses from the images)", found, found)
    return found


def refuse_text_model_names(image_paths: Sequence[Path]) -> None:
    """InputError naming the first image whose file name (the name the map stores it under) a COLMAP text model
    cannot hold (`colmap_model.colmap_text_name_problem`): `map --text` refuses it before any work. The map
    reported success and wrote images.txt that pycolmap read back as 40 images all named 'DJI'."""
    refuse_names_colmap_cannot_hold(image_paths, TEXT_MODEL,
                                    "drop --text (the binary model keeps any name), or rename the images")


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
        poses: a pose CSV, a COLMAP model directory (or its images.bin/.txt), an OpenSfM / OpenDroneMap
            reconstruction (reconstruction.json or the project directory), or a `sosmatch synth` session.
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
    if poses.is_dir():  # a killed `synth` (or `poses`) leaves only its staging: say so, not "a folder"
        check_finished(poses)
    if _is_synth_session(poses):
        pose_file = poses / ("poses_ekf.csv" if ekf else "poses.csv")
        pose_list, epsg = read_poses_csv(pose_file, convention)
        sources["poses"] = str(pose_file)
        sources["session"] = str(poses)  # the folder given: an output inside it is inside an input
        cams = read_cameras_txt(poses / "cameras.txt")
        cam_from_poses = one_camera(cams, poses / "cameras.txt")
        if cam_from_poses is not None:
            sources["camera"] = str(poses / "cameras.txt")  # was recorded as the pose file
        if images is None:
            images = poses / "images"
    elif is_colmap_model(poses):
        pose_list, cams, _ = read_colmap_model_poses(poses)
        sources["poses"] = str(poses)
        cam_from_poses = one_camera(cams, poses) if camera is None else None
    elif is_opensfm(poses):  # OpenDroneMap / OpenSfM: poses in the UTM grid of its reference_lla
        from ..poses import opensfm_poses

        pose_list, opensfm_cams, _, epsg, _ = opensfm_poses(poses, images)
        sources["poses"] = str(poses)
        # as a COLMAP model's: two cameras said "no camera intrinsics: give --camera", not that there were two
        cam_from_poses = one_camera(opensfm_cams, poses) if camera is None else None
    else:
        if ekf:
            raise InputError("--ekf needs a synth session directory as --poses", poses)
        pose_list, epsg = read_poses_csv(poses, convention)
        sources["poses"] = str(poses)
        beside = poses.parent / "cameras.txt"  # where `sosmatch poses-from-exif` puts the intrinsics
        if camera is None and beside.is_file():
            cam_from_poses = one_camera(read_cameras_txt(beside), beside)
            sources["camera"] = str(beside)
    if not epsg and looks_like_ecef(pose_list.centers, pose_list.rotations):
        # COLMAP's model_aligner with GPS references writes Earth-centred coordinates: metres, but z is not up,
        # so every level-frame step (keyframes' heights, the ground, the plausibility) would be wrong. The same
        # poses in their UTM zone are exact
        grid, rotations, epsg = ecef_to_grid(pose_list.centers, pose_list.rotations)
        pose_list = Poses(pose_list.names, rotations, grid)
        log.info("%s: the poses are Earth-centred (ECEF) coordinates; mapped in UTM, EPSG:%d", poses, epsg)
        sources["poses_frame"] = f"ECEF, converted to EPSG:{epsg}"
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
    files = {f.name: f for f in image_files(images)}
    # a name spelt otherwise (case, Unicode normalisation): paired when it names one file only
    by_key = {k: files[n] for k, n in unique_by_key(files).items()}
    keep = []
    missing = []
    for i, name in enumerate(pose_list.names):
        path = images / name
        if path.is_file():
            keep.append((i, path))
        elif Path(name).name in files:  # poses may carry a sub-path ("images/x.jpg"); match by file name
            keep.append((i, files[Path(name).name]))
        elif name_key(Path(name).name) in by_key:
            keep.append((i, by_key[name_key(Path(name).name)]))
        else:
            missing.append(name)
    _refuse_shared_images(keep, pose_list.names, poses, images)
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
    # the camera in these images' pixels: a calibration of the full-resolution frames rescaled to downscaled
    # copies, another size refused naming the cameras file (it named an image, deep in the run: nu50); images of
    # two sizes refused naming the odd one (every image's header is read: the first's alone decided, rev39)
    fitted = camera_for_image_files(cam, [p for _, p in keep], sources["camera"])
    if fitted != cam:  # recorded in run.json beside the file it came from
        sources["camera_rescaled"] = f"{cam.width}x{cam.height} -> {fitted.width}x{fitted.height}"
        cam = fitted
    sub = pose_list.subset([i for i, _ in keep])
    sub.names = [p.name for _, p in keep]
    # a poses.csv of `sosmatch poses`: its georegistration's doubts are the map's, as when map runs SfM itself
    doubts: list[str] = []
    wrong: list[str] = []
    source = POSE_SOURCE_GIVEN
    vertical: tuple[str, float] = ("", float("nan"))
    if sources.get("poses") == str(poses) and Path(poses).is_file():
        from ...database.session_io import poses_record_beside, record_of_own_sfm
        from ..poses.result import poses_vertical, registration_findings

        record = poses_record_beside(Path(poses))  # read once: its doubts, its vertical, and whose poses these are
        doubts, wrong = registration_findings(record)
        vertical = poses_vertical(record)
        if record_of_own_sfm(record):  # README's photo workflow: `poses`, then `map --poses`; not an import
            source = POSE_SOURCE_SFM
    inputs = in_flight_order(MapInputs([p for _, p in keep], sub, cam, epsg, sources, warnings=doubts,
                                       refusals=wrong, pose_source=source, vertical=vertical))
    if (problem := focal_against_exif(inputs)) is not None:
        log.warning("%s", problem)
        # the map's verdict too (run.json, the summary line, a batch's report): landmark heights scale with it
        inputs.warnings.append(problem)
    return inputs


def focal_against_exif(inputs: MapInputs) -> str | None:
    """A warning when the camera's focal length differs from the one the images' EXIF gives (FocalLength with
    the focal plane resolution, or FocalLengthIn35mmFilm; `image_cameras.camera_from_metadata`) by more than
    `image_cameras.EXIF_FOCAL_TOLERANCE`, naming both and the camera file; None when they agree or the EXIF has no
    focal length. A landmark's height scales with the focal length (the flying height above it is f x baseline /
    disparity), while the horizontal map and its matches stay intact. The first, middle and last images are read:
    one camera per flight."""
    from ...database.exif import read_image_metadata
    from ..image_cameras import EXIF_FOCAL_TOLERANCE, camera_from_metadata

    paths = inputs.image_paths
    if not paths:
        return None
    for k in sorted({0, len(paths) // 2, len(paths) - 1}):
        try:
            meta = read_image_metadata(paths[k])
            exif, source = camera_from_metadata(meta)
        except (InputError, OSError, ValueError):
            continue
        if exif.width != inputs.camera.width or exif.height != inputs.camera.height or exif.fx <= 0:
            continue
        change = inputs.camera.fx / exif.fx - 1.0
        if abs(change) <= EXIF_FOCAL_TOLERANCE:
            return None
        return (f"{inputs.sources.get('camera', 'the camera')}: its focal length {inputs.camera.fx:.1f} px is "
                f"{100 * change:+.0f} % off the one the images' EXIF gives ({exif.fx:.1f} px from {source}, "
                f"{paths[k].name}): landmark heights scale with it (at 100 m, {abs(change) * 100:.0f} m off); check "
                "the intrinsics (a 35 mm-equivalent or a sensor size taken for the real one?)")
    return None


def require_keyframes(inputs: MapInputs, interval_m: float) -> None:
    """Refuse (InputError naming the pose source) poses that give fewer than two keyframes: every camera centre
    within `interval_m` (keyframes.interval_m) of the first, as a hovering flight or one position copied to every
    image gives. A map needs two keyframes to triangulate anything; without this check pycolmap's own assertion
    surfaced as a traceback after the segmentation."""
    from ...plugin.keyframes import select_keyframes

    centers = inputs.poses.centers
    if len(select_keyframes(centers, interval_m)) >= 2:
        return
    spread = float(np.max(np.linalg.norm(centers - centers[0], axis=1))) if len(centers) else 0.0
    raise InputError(f"the {len(centers)} camera centres lie within {spread:.2f} m of the first, less than the "
                     f"{interval_m:g} m between keyframes (keyframes.interval_m): one keyframe, nothing to "
                     "triangulate (a hovering flight, or one position given to every image?)",
                     inputs.sources.get("poses"))


def in_flight_order(inputs: MapInputs, capture_times: Sequence[float | None] | None = None) -> MapInputs:
    """The inputs in the order the frames were taken (`plugin.keyframes.flight_order`): by the images' EXIF
    capture times when every image has one (the frames of one time along the camera path where their given order
    is not), else as given unless that order is evidently not a flight (then along the camera path). Keyframes
    and tracks follow this order: frames mapped in file-name order when the names do not follow the flight lost
    two thirds of the landmarks (tracks broken at every jump), without a word.
    `capture_times`: each image's capture time (None without one) when the caller has read its EXIF already
    (`map --images`: `read_image_priors`); else it is read here."""
    from ...database.exif import read_image_metadata

    times = list(capture_times) if capture_times is not None else []
    for path in inputs.image_paths if capture_times is None else []:
        try:
            times.append(read_image_metadata(path).capture_time_s)
        except InputError:  # an unreadable image is named where its pixels are read (the run resumes from there)
            times.append(None)
    t = None if any(x is None for x in times) else np.asarray(times, dtype=np.float64)
    order, how, split = ordered_flight(inputs.poses.centers, t)
    said = flight_order_message(how, t, split)
    if said is None:
        return inputs
    log.log(logging.WARNING if said[0] else logging.INFO, "%s", said[1])
    poses = inputs.poses.subset(order)
    # every other field as it was (the pose source's doubts and vertical: a field listed here by hand was lost)
    return dataclasses.replace(inputs, image_paths=[inputs.image_paths[i] for i in order], poses=poses)


def image_digests(inputs: MapInputs) -> list[str]:
    """sha256 of every image's contents, in the order of `inputs.image_paths` (an unreadable one: InputError)."""
    digests = []
    for p in inputs.image_paths:
        try:
            digests.append(sha256_file(p))
        except OSError as exc:
            raise InputError(f"cannot read image: {exc.strerror or exc}", p) from None
    return digests


def distinct_images(inputs: MapInputs) -> tuple[MapInputs, list[str]]:
    """(`inputs` without the copies of other images, their `image_digests`): the copies `warn_duplicate_images`
    finds are left out (the original of each picture kept), and its warnings join `inputs.warnings` (the map's
    verdict: run.json and the summary line)."""
    digests = image_digests(inputs)
    found = warn_duplicate_images(inputs.image_paths, digests, inputs.poses.centers, inputs.poses.rotations)
    if not found.warnings:
        return inputs, digests
    out = set(found.left_out)
    keep = [i for i in range(len(digests)) if i not in out]
    return (dataclasses.replace(inputs, image_paths=[inputs.image_paths[i] for i in keep],
                                poses=inputs.poses.subset(keep), warnings=[*inputs.warnings, *found.warnings]),
            [digests[i] for i in keep])


@dataclass(frozen=True)
class Duplicates:
    """What `warn_duplicate_images` found: groups of names showing one picture (the kept original first), the
    indices of the copies left out, and the warnings said."""

    copies: list[list[str]]
    left_out: list[int]
    warnings: list[str]


TURN_IN_PLACE_DEG = 1.0  # recorded attitudes further apart than this: the camera turned at the position


def warn_duplicate_images(paths: list[Path], digests: list[str], centers: np.ndarray | None = None,
                          rotations: np.ndarray | None = None) -> Duplicates:
    """Images that are one picture under several names, said in one warning: byte-identical files (a copy made
    twice), and, among images the poses put at one position (`centers`, capture order; within rounding,
    `geometry.position_groups`), those that show
    the same view (`image_rigs.same_view`: a PNG written from the JPEG beside it, a re-encoded copy). One picture
    with two poses: the pose check's pair of them has no baseline (undefined epipolar geometry) and a copy can
    replace its original as a keyframe, so each copy is left out, its original kept (`image_rigs.original_name`).
    Images at one recorded position whose views differ are named, both kept: with one recorded attitude (`rotations`
    within TURN_IN_PLACE_DEG) as a pose fault, the later one's position repeating the earlier's (a GPS updating
    slower than the camera; which of the two is wrong the images cannot say); with attitudes that differ, as a turn
    at one position (a hover turning in place: the position may be right)."""
    from ..image_rigs import original_name, same_view

    groups: dict[str, list[int]] = {}
    for i, d in enumerate(digests):
        groups.setdefault(d, []).append(i)
    same_as = {i: g[0] for g in groups.values() for i in g}  # each image -> the first of its picture
    repeated: list[tuple[int, int]] = []  # (image, the earlier image whose recorded position it repeats)
    turned: list[tuple[int, int, float]] = []  # (image, the earlier one at its position, degrees between them)
    if centers is not None:
        # one recorded position within rounding (`geometry.SAME_POSITION`): rows read from a CSV or converted from
        # EXIF or ECEF that differ by 1e-9 m are one position, as exact equality did not say
        for members in (m for m in position_groups(centers) if len(m) > 1):
            last = None  # the latest distinct picture at this position: each image is compared with it alone, so
            # a long stall reads every image twice, not every pair (rev37: 100 frames at 20 MP were ~18 min of CPU)
            for k, j in enumerate(members):
                if same_as[j] != j:
                    continue  # byte-identical to an earlier image
                if last is not None and same_view(paths[last], paths[j]):
                    same_as[j] = last
                    continue
                if last is not None:
                    turn = 0.0 if rotations is None else rotation_angle_deg(rotations[last], rotations[j])
                    if turn > TURN_IN_PLACE_DEG:  # the recorded attitudes differ: a hover turning in place, not
                        turned.append((j, last, turn))  # necessarily a wrong position (rev37)
                    else:
                        repeated.append((j, members[k - 1]))
                last = j
    pictures: dict[int, list[int]] = {}
    for i in range(len(paths)):
        pictures.setdefault(same_as[i], []).append(i)
    copies, left_out, byte_copies, views = [], [], [], []
    for members in (m for m in pictures.values() if len(m) > 1):
        kept = members[original_name([paths[i].name for i in members])]
        copies.append([paths[kept].name] + [paths[i].name for i in members if i != kept])
        left_out += [i for i in members if i != kept]
        for i in members:
            if i != kept:  # the same bytes (a copy), or the same view at one position in other bytes
                (byte_copies if digests[i] == digests[kept] else views).append(f"{paths[kept].name} = {paths[i].name}")
    warnings = []
    if byte_copies:
        warnings.append(f"{len(byte_copies)} image(s) are byte-identical copies of others: "
                        + "; ".join(byte_copies[:3]) + (" ..." if len(byte_copies) > 3 else "")
                        + ": one picture under two names; each copy is left out, its original kept; remove the copies")
    if views:
        # not said to be copies: a hovering drone's next exposure shows the same view too (rev37)
        warnings.append(f"{len(views)} image(s) show the same view as another at the same recorded position, in "
                        "other bytes (a copy in another format or edited, or a hover's repeated exposure): "
                        + "; ".join(views[:3]) + (" ..." if len(views) > 3 else "")
                        + ": each is left out, the other kept (the pair has no baseline to map from or check)")
    if repeated:
        listing = "; ".join(f"{paths[j].name} repeats {paths[i].name}'s" for j, i in repeated[:5])
        warnings.append(f"{len(repeated)} image(s) are given the recorded position of another whose view differs "
                        f"({listing}{' ...' if len(repeated) > 5 else ''}): the camera moved between them, so "
                        "one of each pair's positions is wrong (a GPS updating slower than the camera?); their pair "
                        "has no baseline to check against the images")
    if turned:
        listing = "; ".join(f"{paths[j].name} at {paths[i].name}'s, turned {deg:.0f} deg" for j, i, deg in turned[:5])
        warnings.append(f"{len(turned)} image(s) are given the recorded position of another with a different recorded "
                        f"attitude ({listing}{' ...' if len(turned) > 5 else ''}): a hover turning in place, or a GPS "
                        "updating slower than the camera; their pair has no baseline to check against the images; "
                        "both kept")
    for w in warnings:
        log.warning("%s", w)
    return Duplicates(copies, sorted(left_out), warnings)


def input_fingerprints(inputs: MapInputs, digests: list[str] | None = None) -> dict[str, str]:
    """sha256 of the images (names + contents), the poses (as used, full precision) and the camera.

    `digests`: the images' `image_digests`, when the caller has them already."""
    h_img = hashlib.sha256()
    for p, d in zip(inputs.image_paths, digests if digests is not None else image_digests(inputs)):
        h_img.update(p.name.encode() + b"\0" + d.encode() + b"\n")
    h_pose = hashlib.sha256()
    h_pose.update("\n".join(inputs.poses.names).encode())
    h_pose.update(np.ascontiguousarray(inputs.poses.rotations).tobytes())
    h_pose.update(np.ascontiguousarray(inputs.poses.centers).tobytes())
    h_pose.update(str(inputs.epsg).encode())
    c = inputs.camera
    # a pinhole camera keeps the fingerprint it had before lens models existed (sessions resume across versions)
    cam_key = (c.width, c.height, c.fx, c.fy, c.cx, c.cy) + (() if c.is_pinhole else (c.model, c.extra))
    h_cam = hashlib.sha256(repr(cam_key).encode())
    combined = hashlib.sha256((h_img.hexdigest() + h_pose.hexdigest() + h_cam.hexdigest()).encode())
    return {"images": h_img.hexdigest(), "poses": h_pose.hexdigest(), "camera": h_cam.hexdigest(),
            "inputs": combined.hexdigest()}


def input_paths(inputs: MapInputs) -> list[Path]:
    """The files and folders a map reads (for the output-is-not-an-input check)."""
    paths = {p.parent for p in inputs.image_paths}
    paths |= {Path(s) for s in inputs.sources.values() if Path(s).exists()}
    return sorted(paths)


def recorded_sources(sources: dict[str, str]) -> dict[str, str]:
    """The input sources as run.json records them: paths absolute (a relative one meant the folder the map was run
    from, and `evaluate` run from another folder read another file or none: the map's poses silently replaced by
    the truth); descriptions that are no path ("EXIF/XMP of ...") as they are."""
    return {k: str(Path(v).absolute()) if Path(v).exists() else v for k, v in sources.items()}


def sources_from_session(sources: dict[str, str], session_dir: str | Path) -> dict[str, str]:
    """The input sources that are paths, relative to the session directory: run.json records them beside the
    absolute ones, so that a project folder moved or copied elsewhere (sessions and images together) still finds
    its images (the nineteenth sweep: `changes` then ran without image evidence, a warning only, and claimed
    4 gone / 10 new where the images said 1 / 6)."""
    base = Path(session_dir).absolute()
    return {k: os.path.relpath(Path(v).absolute(), base) for k, v in sources.items() if Path(v).exists()}


def hash_json(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()
