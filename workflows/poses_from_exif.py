"""Poses and intrinsics from the images themselves: EXIF GPS + XMP attitude -> poses.csv + cameras.txt.

`poses_from_images(paths, ...)` returns an `ExifPoses` (world_from_camera poses in UTM, the EPSG code, one
pinhole camera and a summary of what was read from which tags); `run(...)` writes `poses.csv` and `cameras.txt`.
What is read, the world frame, the attitude conventions, heights and intrinsics: `workflows.image_priors`
(shared with `sosmatch poses`, which uses these poses as the priors of structure from motion). This job needs
every image to have a GPS position and all images one camera.

Images without attitude tags (EXIF GPS only): their headings would be the course over ground, a guess that is
several degrees off on the lines (GPS noise over a few metres of flight) and tens of degrees off at the turns
(world 88 at 150 m: 1-13 deg on the lines, 37-54 deg at the corners of the turns; its map's landmarks 4.0 m
(median) from their objects, 2.7 m with the orientations from tie points; BENCHMARKS.md). So their
orientations are solved from the images, as OpenDroneMap and COLMAP do with GPS-only photos: the refinement
from tie points with the GPS positions as priors (`--refine`), on whenever any image lacks attitude tags
(`orientations_from_images`); a refinement that fails is an error naming the cause, never poses of guessed
headings.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from ..database.cameras import format_cameras_txt
from ..database.exif import orientation_note
from ..database.geo_txt import geo_txt_hint
from ..database.output_files import OutputFiles
from ..database.output_markers import VersionedIdentity, fingerprint, input_identity
from ..database.poses import format_poses_csv
from ..database.xmp_sidecar import sidecars_with_gps
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..plugin.gps_track import OFF_NADIR_LIMIT_DEG, with_quantisation
from .image_cameras import FOCAL_GROUP_TOLERANCE, make_model
from .image_priors import (  # noqa: F401 (re-exported: the conventions' historical home)
    DEFAULT_MOUNT,
    DEFAULT_PITCH_SIGN,
    DEFAULT_ROLL_SIGN,
    ENU_FROM_NED,
    FIXED_MOUNTS,
    FULL_FRAME_DIAGONAL_MM,
    GIMBAL_MOUNT,
    camera_from_metadata,
    camera_rotations,
    full_frame_diagonal_px,
    geographic_to_grid,
    list_images,
    ned_from_body,
    read_image_priors,
    utm_epsg,
)

if TYPE_CHECKING:
    from ..plugin.georegistration import Vertical

log = logging.getLogger(__name__)


@dataclass
class ExifPoses:
    """Poses (world_from_camera, UTM), the EPSG code, one pinhole camera and a summary of the sources."""

    poses: Poses
    epsg: int
    camera: Camera
    summary: dict = field(default_factory=dict)
    # (N,) images without attitude tags, whose headings are the course over ground: a guess the refinement
    # replaces by what the image motion says
    headings_guessed: np.ndarray | None = None
    capture_times: list[float | None] | None = None  # (N,) EXIF capture times as read (None: the image has none)
    # every image's attitude is a stabilised gimbal's absolute angles (DJI XMP Gimbal*Degree): its tilt off the
    # vertical is what the gimbal holds, so a refinement may not tilt the cameras far from it
    gimbal_attitudes: bool = False
    orientations: list[int | None] | None = None  # (N,) EXIF Orientation tags as read (not applied)


def poses_from_images(
    images: str | Path | Sequence[str | Path],
    telemetry: str | Path | None = None,
    mount: str = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    sensor_width_mm: float | None = None,
    epsg: int | None = None,
    takeoff_altitude_m: float | None = None,
) -> ExifPoses:
    """Poses (UTM, world_from_camera) and one pinhole camera from the images' EXIF/XMP (and a telemetry CSV).

    Images without a GPS position (in EXIF or in the telemetry) raise InputError naming them; so do images of
    different sizes. The returned summary says which tags every value came from.
    """
    priors = read_image_priors(images, telemetry, mount, pitch_sign, roll_sign, sensor_width_mm, epsg,
                               takeoff_altitude_m, strict_intrinsics=True)
    metas, n = priors.metas, len(priors.metas)
    no_fix = np.flatnonzero(~np.isfinite(priors.positions[:, 0]))
    if len(no_fix):
        first = metas[int(no_fix[0])]
        hemisphere = any("hemisphere" in p for p in first.problems)
        # a rational 0/0 in its coordinates (rev38): say which, not only that the position is missing
        empty = next((p.split(" (")[0] for p in first.problems if "a rational without a value" in p), None)
        # GPS kept in sidecars by a photo editor: say where it is (nu42 D6: "50 of 50 ... no GPS", not a word
        # of the 50 .xmp files beside them)
        sidecars = sidecars_with_gps([metas[int(i)].path for i in no_fix])
        geo_txt = geo_txt_hint(first.path.parent) if telemetry is None else None  # ODM's positions file (nu58 D4)
        raise InputError(f"{len(no_fix)} of {n} images have no GPS position (EXIF GPSLatitude/GPSLongitude, DJI XMP "
                         "drone-dji:GpsLatitude/GpsLongitude"
                         + (", here without its N/S/E/W refs" if hemisphere else "")
                         + (f", here {empty}" if empty else "") + f"), e.g. {first.path.name}; "
                         + (f"{sidecars}; or " if sidecars else "") + (f"{geo_txt}; or " if geo_txt else "")
                         + "give a telemetry CSV with positions or a poses.csv", first.path)
    # the GPS positions and tags are these poses: where no aircraft flies or looks like that, they are unusable
    if priors.summary.get("gps_frozen"):
        raise InputError(f"the GPS fixes of all {n} images lie at one point (a receiver without a lock): no poses "
                         "from them; take poses from structure from motion (`sosmatch poses`) or give a pose CSV",
                         metas[0].path.parent)
    off = priors.summary.get("tags_median_off_nadir_deg")
    if off is not None and off > OFF_NADIR_LIMIT_DEG:
        raise InputError(f"the attitude tags turn the cameras {off:.0f} deg from straight down (median): not a "
                         "survey looking at the ground; tags in another pitch convention (DJI gimbal pitch -90 = "
                         "nadir; airframe tags: --mount, --pitch-sign)? Or take poses from structure from motion "
                         "(`sosmatch poses`)", metas[0].path)
    no_height = np.flatnonzero(~priors.has_gps)
    if len(no_height):
        raise InputError("image has GPS latitude/longitude but no GPSAltitude", metas[int(no_height[0])].path)
    sizes = Counter((m.width, m.height) for m in metas)
    if len(sizes) > 1:
        (w0, h0), top = sizes.most_common(1)[0]
        odd = next(m for m in metas if (m.width, m.height) != (w0, h0))
        counts = ", ".join(f"{c} {w}x{h}" for (w, h), c in sizes.most_common())
        if len(sizes) == 2 and (odd.width, odd.height) == (h0, w0):
            advice = ("portrait and landscape frames mixed: turn them to one orientation (a rotation, not a resize, "
                      "which would distort them)")
        else:
            advice = "map each camera's (or size's) images on their own, or bring them to one size"
        tied = [size for size, c in sizes.items() if c == top]
        if len(tied) > 1:
            # no size is the odd one: naming one image of either would call a full frame the odd one out (nu53:
            # 40 frames and their 40 thumbnails, a full-size frame named), so each group is named by an example
            example = {size: next(m.path.name for m in metas if (m.width, m.height) == size) for size in tied}
            groups = "; ".join(f"{top} {w}x{h}, e.g. {example[(w, h)]}" for w, h in tied)
            raise InputError(f"the folder's images are of {len(sizes)} sizes, as many of each ({groups}"
                             + (f"; and {counts} in all" if len(sizes) > len(tied) else "")
                             + f"): one camera per session; {advice}", odd.path.parent)
        raise InputError(f"image is {odd.width}x{odd.height}; the folder's images are of {len(sizes)} sizes "
                         f"({counts}): one camera per session; {advice}", odd.path)
    focals = [c.fx for c in priors.cameras]
    if len(priors.cameras) > 1 and max(focals) > (1.0 + FOCAL_GROUP_TOLERANCE) * min(focals):
        first = [m for m, i in zip(metas, priors.camera_index) if i != priors.camera_index[0]][0]
        raise InputError(f"the images are of {len(focals)} cameras of different focal lengths (fx "
                         f"{', '.join(f'{f:.0f}' for f in focals)} px: another camera, zoom or digital zoom, e.g. "
                         f"{metas[0].path.name} and {first.path.name}): one camera per session; map each on its own",
                         first.path)
    camera = priors.cameras[0]
    if len(priors.cameras) > 1:
        # cameras within the tolerance of each other: of one make and model, a zoom's settings are apart by more
        # (`image_cameras.focal_settings`), so what sets these apart is the make/model or the digital zoom. One
        # camera file is written: the images' median, not the first camera's (rev39: the first of a split spread)
        firsts = [metas[int(np.flatnonzero(priors.camera_index == g)[0])] for g in range(len(priors.cameras))]
        models = sorted({make_model(m) or "unnamed" for m in firsts})
        zooms = sorted({m.digital_zoom or 1.0 for m in firsts})
        if len(models) > 1:
            what = f"{len(models)} camera makes/models ({', '.join(models)})"
        elif len(zooms) > 1:
            what = f"{models[0]} at {len(zooms)} digital zoom ratios ({', '.join(f'x{z:g}' for z in zooms)})"
        else:
            what = f"{len(firsts)} cameras of {models[0]}"
        fx = np.array([priors.cameras[g].fx for g in priors.camera_index])
        fy = np.array([priors.cameras[g].fy for g in priors.camera_index])
        camera = replace(camera, fx=float(np.median(fx)), fy=float(np.median(fy)))
        log.warning("%s in one folder, their focal lengths within %g %% (fx %s px): one camera at the images' "
                    "median, fx %.1f px", what, 100 * FOCAL_GROUP_TOLERANCE,
                    ", ".join(f"{f:.1f}" for f in focals), camera.fx)
    if priors.cameras[0].is_pinhole:
        # one line, not a warning: the tags never carry a lens model, and most survey lenses are near-rectilinear;
        # a strong one (a barrel k1 -0.2) put the ground 3.8 m low unrefined and, refined, bent the block (26th
        # new-user sweep), where structure from motion recovered its k1 to 1 %
        log.info("the tags carry no lens model: the lens is taken as distortion-free (PINHOLE); with a distorting "
                 "(wide, fisheye, barrel) lens let structure from motion estimate it (`map --pose-source sfm`) or "
                 "give its cameras.txt (`poses-from-exif`, then `map --poses POSES.csv --camera cameras.txt`)")
    poses = Poses(priors.names, priors.rotations, priors.positions)
    return ExifPoses(poses, priors.epsg, camera, priors.summary, ~priors.attitude_from_tags,
                     [m.capture_time_s for m in metas], bool(np.all(priors.attitude_kind == "gimbal")),
                     [m.orientation for m in metas])


def run(
    images: str | Path | Sequence[str | Path],
    out: str | Path,
    telemetry: str | Path | None = None,
    mount: str = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    sensor_width_mm: float | None = None,
    epsg: int | None = None,
    cameras_out: str | Path | None = None,
    refine: bool = False,
    position_sigma_m: float = 3.0,
    attitude_sigma_deg: float = 5.0,
    refine_method: str = "colmap",
    overwrite: bool = False,
) -> ExifPoses:
    """Write `out` (pose CSV, `# crs: EPSG:<utm>`) and cameras.txt beside it (or at `cameras_out`).

    With `refine`, the EXIF poses are refined with ORB tie points between overlapping images and the EXIF poses
    as priors (`pose_refinement.refine_poses_from_images`, sigmas as given; `refine_method` "colmap" = COLMAP's
    pose-prior bundle adjustment with position priors, "scipy" = position and attitude priors) before they are
    written; the summary then holds the refinement statistics. Both files are written atomically; the return
    value carries the poses, camera and the source summary. The two files go through
    `sosmatch.database.output_files.OutputFiles`, checked before any work: an existing file is replaced only when
    this command wrote it (from other images or options: only with `overwrite`).
    """
    for name, sigma in (("position sigma", position_sigma_m), ("attitude sigma", attitude_sigma_deg)):
        if not (math.isfinite(sigma) and sigma > 0):  # the refinement's prior weights: 1 / sigma^2
            raise InputError(f"the {name} must be a positive number, got {sigma!r}")
    out = Path(out)
    cameras_path = Path(cameras_out) if cameras_out is not None else out.parent / "cameras.txt"
    sources = [Path(p) for p in ([images] if isinstance(images, (str, Path)) else images)]
    image_files = [[str(p.resolve()), *_stat(p)] for p in list_images(images)]

    def identity(tele: Any) -> str:
        return fingerprint({"images": image_files,
                            "telemetry": tele,
                            "options": [mount, pitch_sign, roll_sign, sensor_width_mm, epsg, refine, position_sigma_m,
                                        attitude_sigma_deg, refine_method]})

    # the telemetry by its content; until fix130 by its size and time (rev52 D2): such files are this output
    # (an upgrade re-writes them under today's identity rather than refusing them)
    identity = VersionedIdentity(identity(input_identity(telemetry or None)),
                                 (identity(_stat(telemetry)),) if telemetry else ())
    files = OutputFiles([out, cameras_path], "poses-from-exif", identity, inputs=[*sources, telemetry],
                        overwrite=overwrite)
    result = poses_from_images(images, telemetry, mount, pitch_sign, roll_sign, sensor_width_mm, epsg)
    guessed = orientations_from_images(result)
    if refine or guessed:
        stats = _refine(result, images, position_sigma_m, attitude_sigma_deg, refine_method, guessed)
        result.summary["refinement"] = {"method": refine_method, "position_sigma_m": position_sigma_m,
                                        "attitude_sigma_deg": attitude_sigma_deg, **stats.to_dict()}
    files.write(out, format_poses_csv(result.poses, result.epsg))
    files.write(cameras_path, format_cameras_txt({1: result.camera}))
    result.summary["poses_csv"] = str(out)
    result.summary["cameras_txt"] = str(cameras_path)
    log.info("wrote %s (%d poses, %s) and %s", out, len(result.poses), result.summary["crs"], cameras_path)
    return result


def _stat(path: str | Path) -> list[int]:
    try:
        st = Path(path).stat()
    except OSError:
        return []
    return [st.st_size, st.st_mtime_ns]


# said with the pose check's words when the tags fit the images loosely (`map.MapInputs.remedy`)
UNREFINED_REMEDY = ("the poses are the images' own tags, unrefined: `--refine` fits them to tie points between the "
                    "images first, or let structure from motion make them (`--pose-source sfm`)")


def map_inputs_from_images(
    images: str | Path,
    telemetry: str | Path | None = None,
    refine: bool = False,
    position_sigma_m: float = 3.0,
    epsg: int | None = None,
) -> object:
    """`sosmatch map --images DIR` without `--poses`: the images' EXIF/XMP (and `telemetry`) poses and camera as
    `workflows.map.MapInputs`, refined from tie points first when `refine` (see `run`). Nothing is written; the
    map's fingerprint covers the poses as used, so a re-run resumes. `epsg`: the projected CRS of the poses (None:
    the UTM zone of the flight's median fix), as `run`'s."""
    from .map import MapInputs, in_flight_order

    result = poses_from_images(images, telemetry, epsg=epsg)
    source = f"EXIF/XMP of {images}" + (f" + {telemetry}" if telemetry else "")
    guessed = orientations_from_images(result)
    if refine or guessed:
        _refine(result, images, position_sigma_m, guessed=guessed)
        source += (f", orientations of the {guessed} images without attitude tags solved from tie points" if guessed
                   else ", refined from tie points")
    remedy = "" if refine or guessed else UNREFINED_REMEDY
    # what the tags showed doubtful (rounded or jumping fixes, ...) is the map's verdict's too, not a log line only
    # (nu42: fixes rounded to 1e-4 deg, landmarks 6 m off, run.json "ok" without a warning)
    return in_flight_order(MapInputs(_image_paths(images, result.poses), result.poses, result.camera, result.epsg,
                                     {"poses": source, "camera": f"EXIF of {images}", "images": str(images)},
                                     remedy, list(result.summary.get("warnings", []))), result.capture_times)


def _image_paths(images: str | Path, poses: Poses) -> list[Path]:
    """The image files of `images` in the order of `poses`."""
    paths = {p.name: p for p in list_images(images)}
    return [paths[n] for n in poses.names]


def orientations_from_images(result: ExifPoses) -> int:
    """How many images have no attitude tags; when some lack them, says once that their orientations are solved
    from the images (the refinement runs, asked for or not) instead of taken from the course over ground."""
    guessed = int(result.summary.get("images_without_attitude", 0))
    if guessed:
        result.summary["orientations"] = "solved from tie points (GPS positions as priors)"
        log.warning("%d of %d images have no attitude tags: their orientations are solved from the images (tie "
                    "points, the GPS positions as priors; as --refine), not taken from the course over ground",
                    guessed, len(result.poses))
    return guessed


def _refine(result: ExifPoses, images: str | Path, position_sigma_m: float, attitude_sigma_deg: float = 5.0,
            method: str = "colmap", guessed: int = 0) -> object:
    """Refine `result.poses` in place from tie points between the images (`refine_poses_from_images`); returns the
    refinement statistics. `guessed`: that many images have no attitude tags, so the refinement must solve their
    orientations: its failure, or no tie points at all, is an error saying so (and pointing to structure from
    motion)."""
    from .pose_refinement import RefinementRejected, refine_poses_from_images
    from .pose_refinement.judge import GIMBAL_TILT_SIGMA_DEG

    # fixes rounded to a coarse grid are that much noisier: the prior must not hold the cameras to the grid
    # (`image_positions.coarse_fixes`)
    position_sigma_m = with_quantisation(position_sigma_m, result.summary)
    prior = result.poses
    try:
        result.poses, stats = refine_poses_from_images(_image_paths(images, result.poses), result.poses,
                                                       result.camera, position_sigma_m, attitude_sigma_deg,
                                                       method=method, unknown_headings=result.headings_guessed,
                                                       tilt_sigma_deg=(GIMBAL_TILT_SIGMA_DEG if result.gimbal_attitudes
                                                                       else None))
    except (RefinementRejected, ValueError) as error:
        note = orientation_note(result.orientations) if result.orientations else None
        if not guessed and note and isinstance(error, RefinementRejected):
            # pixels stored turned against their tags refuse as implausible turns and tilts (nu53): name the tag
            head, _, rest = error.problem.partition(": ")
            raise RefinementRejected(f"{head}: {note}; {rest}", error.path) from None
        if not guessed:
            raise
        _unsolved(result, images, guessed, str(error).split(";")[0])
    if guessed and stats.points == 0:
        _unsolved(result, images, guessed, "no tie points between the images")
    if guessed:
        # an image without a single tie-point observation keeps its prior: a guess from the course over ground
        # (seen: 4 of 40 Seneca frames, 24-26 deg off their SfM attitudes, with no word said)
        blind = [n for n, k in zip(result.poses.names, stats.observations_by_image) if k == 0]
        if blind:
            _warn(result, f"{len(blind)} of {len(result.poses)} images share no tie point with the others "
                          f"({', '.join(blind[:4])}{', ...' if len(blind) > 4 else ''}): their orientations are "
                          "guesses from the course over ground, not solved; take poses from structure from motion "
                          "(`sosmatch poses`) if they matter")
        for said in _rests_on_nadir(prior, result.poses, result.headings_guessed, result.capture_times):
            _warn(result, said)
    leave_out_unexplained(result, stats, images)
    return stats


def leave_out_unexplained(result: ExifPoses, stats: object, images: str | Path) -> list[str]:
    """Leave out of `result` (in place: its poses and per-image lists) the images whose refined poses explain less
    than half of their own tie points (`judge.unexplained_images`; `stats`: the refinement's, in the order of
    `result.poses`), with a warning naming them; returns their names. Neither the poses CSV nor a map gets such a
    pose (nu58 D2: two Seneca cameras ~140 deg off their heading and 25-34 deg tilted, 41 % / 39 % of their own
    tie points explained, written and mapped with a warning only); `map --poses` of the CSV skips them as images
    without a pose. The judge refuses the refinement where they are many (`judge_refinement`); fewer than two
    images left is the error that the orientations could not be solved."""
    from .pose_refinement.judge import unexplained_images

    odd = unexplained_images(stats.explained_share_by_image, stats.observations_by_image)
    if not len(odd):
        return []
    names = [result.poses.names[int(i)] for i in odd]
    keep = np.setdiff1d(np.arange(len(result.poses)), odd)
    if len(keep) < 2:
        _unsolved(result, images, int(result.summary.get("images_without_attitude", 0)) or len(result.poses),
                  f"the refined poses of {len(odd)} of {len(result.poses)} images explain less than half of their "
                  "own tie points")
    share = stats.explained_share_by_image
    counted = stats.observations_by_image
    listed = ", ".join(f"{result.poses.names[int(i)]} ({share[int(i)]:.0%} of {counted[int(i)]})" for i in odd[:8])
    _warn(result, f"{len(odd)} of {len(result.poses)} images left out: their refined poses explain less than half "
                  f"of their own tie points ({listed}{', ...' if len(odd) > 8 else ''}), a heading or tilt the "
                  "images contradict; take poses from structure from motion (`sosmatch poses`) if they matter")
    result.poses = result.poses.subset(keep.tolist())
    if result.headings_guessed is not None:
        result.headings_guessed = np.asarray(result.headings_guessed)[keep]
    for attr in ("capture_times", "orientations"):
        if (values := getattr(result, attr)) is not None:
            setattr(result, attr, [values[int(i)] for i in keep])
    result.summary["left_out"] = names
    return names


def _warn(result: ExifPoses, text: str | None) -> None:
    """Log `text` as a warning and keep it in the summary (a map's verdict reads it: `map_inputs_from_images`)."""
    if text is not None:
        log.warning("%s", text)
        result.summary.setdefault("warnings", []).append(text)


def _rests_on_nadir(prior: Poses, refined: Poses, guessed: np.ndarray | None,
                    capture_times: Sequence[float | None] | None = None) -> list[str]:
    """`sosmatch poses`' rule for images without attitude tags (`georegistration.nadir_tilt_warning`), asked of
    the refinement: the tilt the GPS heights fix worse than the nadir assumption (a corridor's roll about its line,
    which the position priors leave free and `level_free_roll` takes from the level nadir priors) rests on the
    camera looking straight down. The refined poses are in the world frame (their "SfM frame" is the world's); the
    GPS fixes are the prior centres; `capture_times` (in `prior`'s order; the capture order where one is missing)
    let the heights' plane tell a drift from a tilt, as in `georegister`. Then `_tilted_by_drift`."""
    from ..plugin.georegistration import nadir_tilt_warning, vertical_in_frame

    at = {name: k for k, name in enumerate(prior.names)}
    order = [at[name] for name in refined.names]
    tags = np.zeros(len(order), bool) if guessed is None else ~np.asarray(guessed, bool)[order]
    stamps = None if capture_times is None else [capture_times[k] for k in order]
    times = np.asarray(order if stamps is None or None in stamps else stamps, np.float64)
    gps = prior.centers[order]
    vert = vertical_in_frame(refined.rotations, prior.rotations[order], tags, refined.centers, gps, times=times)
    return [w for w in (nadir_tilt_warning(vert), _tilted_by_drift(vert, refined.centers, gps, times))
            if w is not None]


def _tilted_by_drift(vert: Vertical, centers: np.ndarray, gps: np.ndarray, times: np.ndarray) -> str | None:
    """What to say when the refinement tilted a block without attitude tags away from its cameras' nadir vertical
    to follow GPS heights that, against the block levelled on its cameras, change over the flight. The refinement
    holds the centres to the heights as they are (no drift term), so a drifting GPS altitude over lines flown one
    after the other tilts the whole block, cameras with it (rev56 D1: two lines, 12 m of drift, the block 7-12
    deg off and nothing said); the refined block then agrees with its own heights, so only the cameras' vertical
    (the nadir assumption's, `vert.prior_up`) against the world's tells it. None when the tilt is within the
    assumption's sigma or the levelled heights do not change."""
    from ..plugin.georegistration import MIN_HEIGHT_DRIFT_M, NADIR_ASSUMPTION_SIGMA_DEG, NADIR_SOURCE, level_rotation
    from ..plugin.height_drift import fit_drift

    if not vert.source.startswith(NADIR_SOURCE):
        return None
    tilt = math.degrees(math.acos(float(np.clip(vert.prior_up[2], -1.0, 1.0))))
    ok = np.all(np.isfinite(gps), axis=1)
    if tilt <= NADIR_ASSUMPTION_SIGMA_DEG or ok.sum() < 3:
        return None
    levelled = (centers[ok] - centers[ok].mean(0)) @ level_rotation(vert.prior_up).T
    fit = fit_drift(times[ok], gps[ok, 2] - levelled[:, 2], MIN_HEIGHT_DRIFT_M)
    if not (fit.significant or fit.kind == "step"):
        return None
    how = "jump by" if fit.kind == "step" else "drift by"
    # both readings said: the heights cannot tell a drift from a tilted mount here (the refined centres follow them)
    return (f"the refined cameras look {tilt:.1f} deg off the vertical on average, beyond the nadir assumption's +-"
            f"{NADIR_ASSUMPTION_SIGMA_DEG:g} deg, and against the block levelled on them the GPS heights {how} "
            f"{fit.change:+.1f} m over the flight: either the camera is mounted tilted (give attitude tags, "
            "--telemetry), or the GPS altitude drifts or jumps and the refinement, which takes the heights as they "
            "are, tilted the block with its cameras to follow it; `sosmatch poses` fits the drift and keeps the "
            "nadir vertical")


def _unsolved(result: ExifPoses, images: str | Path, guessed: int, why: str) -> NoReturn:
    """The one-line error when the orientations of images without attitude tags cannot come from the images."""
    raise InputError(f"{guessed} of {len(result.poses)} images have no attitude tags and their orientations could "
                     f"not be solved from tie points ({why}); give poses, or take them from structure from motion "
                     "(`sosmatch poses`, `map --pose-source sfm`)", Path(images)) from None
