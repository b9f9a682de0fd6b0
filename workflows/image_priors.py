"""What a folder of survey images says about its poses and cameras: EXIF GPS, XMP attitude, heights, capture
times and intrinsics, read once for every pose workflow (`poses-from-exif` turns them into poses, `poses`
uses them as the priors and the fallback of structure from motion).

`read_image_priors(images, ...)` returns an `ImagePriors`: per image the grid position (NaN without a fix), the
prior rotation, whether it came from attitude tags, the capture time, the height sources, and one camera per
make, model and image size. Nothing is refused here that structure from motion can live without (images
without GPS, mixed cameras, damaged tags: they are counted in the summary and warned about once);
`poses_from_exif.poses_from_images` adds the checks its own job needs.

World frame. Positions are full UTM coordinates (WGS84 / UTM, EPSG:326zz north or 327zz south, the zone of the
flight's median fix unless `epsg` is given: two flights of one site then take one zone unless the site's middle
lies on a zone boundary, where the first image's zone split them by where each started). A telemetry CSV's
positions (GPSLatitude, GPSLongitude, GPSAltitude), where its row has them, take precedence over the image's own
EXIF GPS: a file the user gives is their better positions (an autopilot's log, a PPK / RTK solution), as
OpenDroneMap's geo.txt overrides the EXIF; how far it moves them is judged
(`image_positions.telemetry_against_exif`: a warning beyond TELEMETRY_WARN_M, refused beyond TELEMETRY_REFUSE_M from
most of the plausible EXIF fixes, and refused when its rows are joined to the images a whole number of images off,
`image_positions.rows_shifted`).
Heights: the GPS altitude (metres, as the receiver reports it:
for most consumer receivers height above the ellipsoid or above mean sea level; either way one consistent
vertical datum per flight), or, where DJI XMP gives `RelativeAltitude` (barometric height above the take-off
point), the take-off altitude + RelativeAltitude. The take-off altitude is given (`takeoff_altitude_m`) or
taken from the GPS at the start of each flight (a folder of several batteries may hold several home points:
`plugin.height_drift.takeoff_altitudes`): the line of GPS altitude - RelativeAltitude over capture time
(`plugin.height_drift.fit_drift`) at the flight's first image, since a GPS altitude drifts from take-off on; that
drift against the barometer is measured and reported; a step of it (an RTK fix lost, another datum) gives the
level of one segment; every fix RTK fixed: the GPS altitude itself (`workflows.prior_heights`).
The pose CSV header says `# crs: EPSG:<code>`; float64
keeps UTM-sized coordinates to well under a millimetre, and the landmark map stores an origin + EPSG, so every
output stays georeferenced.
Rotations are expressed in the UTM grid: the heading of an image (from true north) is turned into a grid
azimuth with the local meridian convergence (1.5 degrees at the Seneca site, not negligible against attitude
errors of a degree or two).

Attitude sources, per image, first that applies:
1. DJI XMP `GimbalYawDegree/GimbalPitchDegree/GimbalRollDegree` (absolute gimbal angles; pitch -90 = nadir), or
   Parrot's `CameraYawDegree/CameraPitchDegree/CameraRollDegree` (the same convention, as OpenDroneMap reads
   them): the camera looks along the gimbal's forward axis, image x to its right (mount "gimbal").
2. senseFly XMP `Heading/PitchAngle/RollAngle`, or DJI `FlightYawDegree/FlightPitchDegree/FlightRollDegree`
   without gimbal tags, or the same angles from a telemetry CSV (`telemetry=`): the airframe attitude of a
   camera fixed to the airframe looking down; the mounting is `mount` (see `FIXED_MOUNTS`), and the sign of
   pitch and roll `pitch_sign`/`roll_sign`.
3. No attitude at all: level, nadir, heading = course over ground (EXIF GPSTrack, else the direction to the
   neighbouring images): a starting point only, logged at info level; the callers that make poses solve these
   orientations from the images (structure from motion, `poses_from_exif`'s refinement) and warn themselves.

Fixed-mount convention (checked on the Seneca flight, `tools/benchmarks/bench_real.py attitude`): the senseFly
pitch/roll/heading are taken as aerospace angles (yaw clockwise from north, pitch nose up, roll right wing down;
R_ned_from_body = Rz(heading) Ry(pitch) Rx(roll)). For 53 consecutive same-line frame pairs, ORB matches
(RANSAC-homography inliers, no telemetry used) were compared with the motion the telemetry poses predict over
the flat ground at GPS altitude - Height. Median error per pair: image top towards the nose with pitch and roll
as given 138 px; pitch or roll sign flipped 168-190 px; image x along the nose 503-527 px, along the tail
527-584 px, image top towards the tail 704-805 px; a level camera (attitude ignored) 148 px. So the mount is
"top_forward" with both signs +1 (the default), and the wrong mounts are ruled out by far; but the telemetry
attitude is noisy (the remaining 138 px at ~70 m above ground is ~11 m on the ground, i.e. ~5-7 degrees per
frame, no better explained by a height scale, a timing shift of the positions or the neighbouring rows'
attitude), so refine such poses (`pose_refinement`) with an attitude sigma of ~5 degrees.

Intrinsics: `image_cameras` (one camera per make, model and image size, from the EXIF focal length).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..database.exif import ImageMetadata, orientation_note, read_image_metadata
from ..database.geo_txt import geo_txt_hint
from ..database.images import image_files, no_images_message
from ..database.telemetry_io import read_telemetry_csv, telemetry_rows
from ..plugin.attitude import (  # noqa: F401 (re-exported: the conventions the tags are read with)
    DEFAULT_MOUNT,
    DEFAULT_PITCH_SIGN,
    DEFAULT_ROLL_SIGN,
    ENU_FROM_NED,
    FIXED_MOUNTS,
    GIMBAL_MOUNT,
    camera_rotations,
    ned_from_body,
)
from ..plugin.errors import InputError
from ..plugin.geodesy import (  # noqa: F401 (re-exported)
    METRES_PER_DEGREE,
    geographic_to_grid,
    topocentric_to_grid,
    utm_epsg,
)
from ..plugin.geometry import Camera
from ..plugin.keyframes import flight_order_message, ordered_flight
from .image_cameras import (  # noqa: F401 (re-exported: their home before image_cameras)
    EXIF_FOCAL_TOLERANCE,
    FULL_FRAME_DIAGONAL_MM,
    camera_from_metadata,
    camera_groups,
    full_frame_diagonal_px,
    make_model,
    turned_readout,
)
from .image_positions import (
    check_one_place,
    flights_of_one_place,
    median_position,
    one_vertical_datum,
    telemetry_against_exif,
    track_checks,
    xmp_against_exif,
)
from .image_rigs import one_image_per_capture, one_image_per_exposure

log = logging.getLogger(__name__)


def list_images(images: str | Path | Sequence[str | Path]) -> list[Path]:
    """A directory's image files (sorted by name), or the given list of paths."""
    if isinstance(images, (str, Path)):
        root = Path(images)
        if root.is_dir():
            paths = image_files(root)
            if not paths:
                raise InputError(no_images_message(root), root)
            return paths
        if not root.exists():
            raise InputError("image directory not found", root)
        return [root]
    if not (paths := [Path(p) for p in images]):  # an empty list was an IndexError deep inside the callers
        raise InputError("no images given: an empty list of image paths")
    return paths


def _course_from_neighbours(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """Azimuth of travel (degrees clockwise from grid north) at each image, from its neighbours with a position
    (NaN where an image has no neighbour with one)."""
    n = len(east)
    out = np.full(n, np.nan)
    ok = np.flatnonzero(np.isfinite(east) & np.isfinite(north))
    for i in range(n):
        # the nearest images with a position before and after (the image itself at the ends of the flight)
        before, after = ok[ok < i], ok[ok > i]
        here = [i] if i in ok else []
        a = before[-1] if len(before) else (here or [None])[0]
        b = after[0] if len(after) else (here or [None])[0]
        if a is not None and b is not None and a != b:
            out[i] = np.degrees(np.arctan2(east[b] - east[a], north[b] - north[a]))
    return out


# A change of the direction of travel beyond this between the legs before and after an image marks a turn. The
# legs span two images each: GPS noise turns a leg by ~sigma * sqrt(2) / length (1 m over two 7 m spacings: ~6 deg;
# world 88 at 150 m: at most 25 deg between two straight legs), a survey's line turns are 90-180 deg.
TURN_DEG = 30.0
TURN_LEG_IMAGES = 2


def turn_images(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """(N,) bool: images at a turn of the flight, where the directions of travel from TURN_LEG_IMAGES images
    before and to as many after differ by more than TURN_DEG (images without a position, and the first and last
    ones, are never marked). There the course over ground says nothing of the heading (a multirotor yaws at or
    after the corner, a fixed wing banks through it)."""
    n, k = len(east), TURN_LEG_IMAGES
    out = np.zeros(n, dtype=bool)
    ok = np.isfinite(east) & np.isfinite(north)
    for i in range(k, n - k):
        if ok[i - k] and ok[i] and ok[i + k]:
            a = np.arctan2(east[i] - east[i - k], north[i] - north[i - k])
            b = np.arctan2(east[i + k] - east[i], north[i + k] - north[i])
            out[i] = abs(np.degrees(np.angle(np.exp(1j * (b - a))))) > TURN_DEG
    return out


@dataclass
class ImagePriors:
    """Per image (in capture order: by EXIF capture time when every image has one, else by file name): what its
    metadata says (see `read_image_priors`)."""

    paths: list[Path]
    metas: list[ImageMetadata]
    epsg: int  # projected CRS of `positions` (0 when no image has a GPS fix)
    positions: np.ndarray  # (N,3) east, north, height; NaN without a GPS fix (only the height: no altitude)
    gps_altitude: np.ndarray  # (N,) as the receiver reports it (NaN without)
    relative_altitude: np.ndarray  # (N,) DJI RelativeAltitude (NaN without)
    rotations: np.ndarray  # (N,3,3) prior world_from_camera (level nadir + course where no tags say)
    attitude_kind: np.ndarray  # (N,) "gimbal" | "fixed" (airframe angles) | "course" (no attitude tags)
    times_s: np.ndarray  # (N,) capture time (DateTimeOriginal; capture order where missing)
    cameras: list[Camera]  # one per make + model + image size + focal length (`image_cameras.camera_groups`)
    camera_index: np.ndarray  # (N,) index into `cameras`
    summary: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.paths]

    @property
    def has_gps(self) -> np.ndarray:
        return np.all(np.isfinite(self.positions), axis=1)

    @property
    def times_known(self) -> bool:
        """False when `times_s` is only the capture order (no image has an EXIF capture time): no seconds."""
        return not str(self.summary.get("capture_times", "")).startswith("capture order")

    @property
    def attitude_from_tags(self) -> np.ndarray:
        return self.attitude_kind != "course"

    @property
    def heights_consistent(self) -> bool:
        """Whether the heights are one datum the block can be held to (RelativeAltitude-based, or an RTK fixed
        altitude: `prior_heights`), not a GPS altitude that may drift. Priors of an older summary: by the source."""
        return bool(self.summary.get("heights_consistent",
                                     "RelativeAltitude" in str(self.summary.get("altitude_source", ""))))


# Capture times that go back by more than a day from one image to the next by name are a camera clock reset (to
# its factory date, or a new battery's RTC), not a counter that wrapped within a flight (minutes).
CLOCK_RESET_S = 86400.0


def _capture_order(metas: list[ImageMetadata], centers: np.ndarray) -> np.ndarray | None:
    """The order the images were taken in (`plugin.keyframes.flight_order` of their capture times and `centers`,
    NaN without a fix), said in the log; None: as listed."""
    stamps = [m.capture_time_s for m in metas]
    times = None if None in stamps else np.asarray(stamps, dtype=np.float64)
    order, how, split = ordered_flight(centers, times)
    said = flight_order_message(how, times, split)
    if said is not None:
        log.log(logging.WARNING if said[0] else logging.INFO, "%s", said[1])
    if times is not None and np.ptp(times) > 0:
        # whatever the names' order (rev56 D3: listed in time order, two dates were mapped as one flight unsaid)
        flights = flights_of_one_place(times, centers, [m.path.name for m in metas])
        back = np.flatnonzero(np.diff(times) < -CLOCK_RESET_S)
        if flights is not None:  # the same ground flown again days later: no clock fault (nu58 D6)
            log.warning("%s", flights)
        elif len(back):  # the nu20 sweep: a camera clock reset to 2000-01-01 reordered the flight with no word
            k = int(back[0])
            log.warning("the capture times jump back by %.1f days from %s to %s (a camera clock reset?): the images "
                        "are ordered by them, which puts the later ones first; fix the dates if that is wrong",
                        (times[k] - times[k + 1]) / 86400.0, metas[k].path.name, metas[k + 1].path.name)
    return None if said is None else order


def _capture_times(metas: list[ImageMetadata]) -> tuple[np.ndarray, str]:
    """Capture times in seconds; images without one are placed by their order between those with one (capture
    order at one second per image when none has a time)."""
    t = np.array([m.capture_time_s if m.capture_time_s is not None else np.nan for m in metas], dtype=np.float64)
    ok = np.isfinite(t)
    idx = np.arange(len(t), dtype=np.float64)
    if ok.sum() >= 2:
        if not ok.all():
            t[~ok] = np.interp(idx[~ok], idx[ok], t[ok])
        return t - t.min(), "EXIF DateTimeOriginal" + ("" if ok.all() else " (interpolated where missing)")
    return idx, "capture order (no EXIF DateTimeOriginal)"


def check_prior_options(mount: str | np.ndarray, sensor_width_mm: float | None, epsg: int | None,
                        takeoff_altitude_m: float | None) -> None:
    """Refuse (one-line InputError) options the images' metadata cannot be read with, before any image is read.
    Before: `--epsg 4326` or an unknown code was a traceback from the pose writer or pyproj after every image was
    read; a mount name the images never needed (gimbal tags), a NaN or negative sensor width, were taken."""
    from ..database.poses import crs_problem

    if isinstance(mount, str) and mount != "gimbal" and mount not in FIXED_MOUNTS:
        raise InputError(f"unknown camera mount {mount!r} (use one of {', '.join(sorted(FIXED_MOUNTS))})")
    if sensor_width_mm is not None and not (math.isfinite(sensor_width_mm) and sensor_width_mm > 0):
        raise InputError(f"the sensor width must be a positive number of millimetres, got {sensor_width_mm!r}")
    if epsg is not None and (problem := crs_problem(int(epsg))) is not None:
        raise InputError(f"--epsg: {problem}")
    # within 100 km (as `evaluate --ground-height`): 1e9 was a traceback from the pose writer after the whole SfM run
    if takeoff_altitude_m is not None and not (math.isfinite(takeoff_altitude_m) and abs(takeoff_altitude_m) <= 1e5):
        raise InputError("the take-off altitude must be a finite number of metres (within 100 km), got "
                         f"{takeoff_altitude_m!r}")


def read_image_priors(
    images: str | Path | Sequence[str | Path],
    telemetry: str | Path | None = None,
    mount: str = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    sensor_width_mm: float | None = None,
    epsg: int | None = None,
    takeoff_altitude_m: float | None = None,
    strict_intrinsics: bool = False,
) -> ImagePriors:
    """Read every image's metadata (and `telemetry`) into `ImagePriors` (see the module doc for the frame, the
    attitude sources and the heights). Damaged or implausible tags are left out with one warning naming the
    images; an unreadable image file is an InputError."""
    from ..database.poses import crs_scale_problem
    from .prior_heights import prior_heights, relative_altitude_spikes, rtk_tags

    check_prior_options(mount, sensor_width_mm, epsg, takeoff_altitude_m)
    paths = list_images(images)
    tele = read_telemetry_csv(telemetry) if telemetry is not None else {}
    metas = [read_image_metadata(p) for p in paths]
    # one image per capture: a multispectral camera's bands share one time and position (`image_rigs`)
    keep = one_image_per_capture(metas, images if isinstance(images, (str, Path)) else paths[0].parent)
    if len(keep) < len(metas):
        paths, metas = [paths[i] for i in keep], [metas[i] for i in keep]
    # one image per exposure: an edited copy beside its original is one picture with two poses
    keep, repeated = one_image_per_exposure(metas)  # (its warning: poses.json's, as the track's)
    if len(keep) < len(metas):
        paths, metas = [paths[i] for i in keep], [metas[i] for i in keep]
    n = len(metas)
    rows = telemetry_rows(tele, [m.path.name for m in metas], telemetry, images)
    damaged = [m for m in metas if m.problems]
    if damaged:
        log.warning("%d of %d images have damaged or implausible metadata (those values left out): %s", len(damaged), n,
                    "; ".join(f"{m.path.name}: {m.problems[0]}" for m in damaged[:3])
                    + (f" ... ({len(damaged)} in all)" if len(damaged) > 3 else ""))
    lat, lon, alt = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    tele_alt = np.array([r.get("alt", np.nan) for r in rows], dtype=np.float64)
    exif_alt = np.array([m.altitude if m.altitude is not None else np.nan for m in metas], dtype=np.float64)
    alt_from_telemetry = np.zeros(n, bool)
    pos_src: Counter = Counter()
    # the images with both: their EXIF fixes, the telemetry's (lat, lon) and capture times (`telemetry_against_exif`)
    exif_ll, tele_ll, both_t = [], [], []
    for i, m in enumerate(metas):
        t = rows[i]
        if "lat" in t and "lon" in t:  # the user's file over the images' own tags (module doc)
            lat[i], lon[i] = t["lat"], t["lon"]
            alt_from_telemetry[i] = "alt" in t
            pos_src["telemetry CSV"] += 1
            if m.has_gps:
                exif_ll.append((m.latitude, m.longitude))
                tele_ll.append((t["lat"], t["lon"]))
                both_t.append(m.capture_time_s if m.capture_time_s is not None else np.nan)
        elif m.has_gps:
            lat[i], lon[i] = m.latitude, m.longitude
            # an image without an EXIF altitude keeps its telemetry altitude (a row with an altitude but no fix)
            alt_from_telemetry[i] = not np.isfinite(exif_alt[i]) and "alt" in t
            # EXIF GPS, else DJI's XMP position (an image whose EXIF GPS was stripped: `database.exif`)
            pos_src["EXIF GPS" if m.sources.get("position", "").startswith("EXIF") else m.sources["position"]] += 1
        if np.isfinite(lat[i]):
            alt[i] = tele_alt[i] if alt_from_telemetry[i] else exif_alt[i]
    tele_warnings = telemetry_against_exif(
        telemetry, np.asarray(exif_ll).reshape(-1, 2), np.asarray(tele_ll).reshape(-1, 2),
        np.asarray(both_t, np.float64))
    alt = one_vertical_datum(alt, alt_from_telemetry & np.isfinite(alt), tele_alt, exif_alt, telemetry)
    has = np.isfinite(lat)
    if telemetry is None and has.any() and (geo_txt := geo_txt_hint(paths[0].parent)) is not None:
        # OpenDroneMap would take it over the images' own GPS (an RTK/PPK solution): said, not silently skipped
        log.warning("the positions are the images' own GPS; %s", geo_txt)
    east, north, north_az = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n)
    if has.any():
        if epsg is None:
            epsg = utm_epsg(*median_position(lat[has], lon[has]))
        east[has], north[has], north_az[has] = geographic_to_grid(lat[has], lon[has], epsg)
        north_az[~has] = float(np.mean(north_az[has]))
        check_one_place(lat, lon, east, north, int(epsg), [m.path.name for m in metas], images)
        # the images whose position is their EXIF one (a telemetry file's rows take precedence)
        exif_pos = ~np.array(["lat" in r and "lon" in r for r in rows], dtype=bool)
        if (text := xmp_against_exif(metas, np.where(exif_pos, east, np.nan), north, int(epsg))) is not None:
            log.warning("%s", text)
            tele_warnings.append(text)  # the summary's warnings: poses.json records it
        # the pose reader refuses a CRS that stretches distances at the flight (Web Mercator, a polar
        # stereographic of another standard parallel): refused here, before poses are written that `map` refuses
        if (stretched := crs_scale_problem(int(epsg), np.column_stack([east[has], north[has]]))) is not None:
            raise InputError(f"--epsg: {stretched}", images)
    # capture order, not file-name order (renamed files, a wrapped counter, frames of one clock second): the
    # course over ground, the pairs of consecutive images and the poses' order all follow it
    order = _capture_order(metas, np.column_stack([east, north, np.zeros(n)]))
    if order is not None:
        paths, metas, rows = [paths[i] for i in order], [metas[i] for i in order], [rows[i] for i in order]
        lat, lon, alt, east, north, north_az, has = (a[order] for a in (lat, lon, alt, east, north, north_az, has))
    times, time_source = _capture_times(metas)

    # Heights: DJI RelativeAltitude + take-off altitude where every fixed image has it (an RTK fixed altitude over
    # it), else the GPS altitude (`prior_heights`).
    rel = np.array([v[0] if (v := m.xmp_float("RelativeAltitude")) else np.nan for m in metas])
    rel, rel_warning = relative_altitude_spikes(rel, alt, times, [m.path.name for m in metas])
    if rel_warning is not None:
        log.warning("%s", rel_warning)
        tele_warnings.append(rel_warning)  # the summary's warnings: poses.json records it
    rtk_flags, rtk_sigma = rtk_tags(metas)
    ph = prior_heights(alt, rel, has, times, [m.path.name for m in metas], rtk_flags, rtk_sigma, takeoff_altitude_m)
    for text in ph.warnings:
        log.warning("%s", text)
    heights, height_source, rel_drift, flights = ph.heights, ph.source, ph.rel_drift, ph.flights
    takeoff_altitude_m = ph.takeoff_altitude_m
    positions = np.stack([east, north, heights], 1)  # NaN height: a fix without altitude

    # Attitude, per image.
    yaw, pitch, roll = np.zeros(n), np.zeros(n), np.zeros(n)
    kind = np.empty(n, dtype=object)
    att_src: Counter = Counter()
    course = _course_from_neighbours(east, north)
    turned = np.array([turned_readout(m) for m in metas], dtype=bool)
    for i, m in enumerate(metas):
        t = rows[i]
        gimbal = [m.xmp_float(*k) for k in (("GimbalYawDegree", "CameraYawDegree"),
                                            ("GimbalPitchDegree", "CameraPitchDegree"),
                                            ("GimbalRollDegree", "CameraRollDegree"))]
        fixed = [m.xmp_float("Heading", "FlightYawDegree"), m.xmp_float("PitchAngle", "FlightPitchDegree"),
                 m.xmp_float("RollAngle", "FlightRollDegree")]
        if turned[i]:
            pass  # its tags describe the unturned camera, and which way the file was turned is not recorded
        elif all(gimbal):
            (yaw[i], _), (pitch[i], _), (roll[i], _) = gimbal  # type: ignore[misc]
            kind[i] = "gimbal"
            parrot = gimbal[0][1].startswith("Camera")  # type: ignore[index]
            att_src["XMP CameraYaw/Pitch/RollDegree (Parrot)" if parrot else "XMP GimbalYaw/Pitch/RollDegree"] += 1
        elif all(fixed):
            (yaw[i], ky), (pitch[i], kp), (roll[i], kr) = fixed  # type: ignore[misc]
            kind[i] = "fixed"
            att_src[f"XMP {ky}/{kp}/{kr}"] += 1
        elif all(k in t for k in ("yaw", "pitch", "roll")):
            yaw[i], pitch[i], roll[i] = t["yaw"], t["pitch"], t["roll"]
            kind[i] = "fixed"
            att_src["telemetry CSV"] += 1
        if kind[i] is None:
            kind[i] = "course"
            if m.gps_track_deg is not None:
                yaw[i] = m.gps_track_deg
                att_src["EXIF GPSTrack (level, nadir)"] += 1
            elif np.isfinite(course[i]):
                yaw[i] = course[i] - north_az[i]  # course is a grid azimuth; yaw is from true north
                att_src["course from neighbours (level, nadir)"] += 1
            else:
                att_src["nothing (level, nadir, heading unknown)"] += 1
    if turned.any():
        # an Orientation tag says how viewers turn the file, not how the stored pixels lie against the readout the
        # attitude tags describe (a camera writes 6 or 8 on unturned pixels): named, not applied (nu53)
        tags = sorted({m.orientation or 1 for m, t in zip(metas, turned) if t})
        if set(tags) <= {6, 8}:
            how = (f"their EXIF Orientation {'/'.join(map(str, tags))} turns them back to the readout's aspect in "
                   "viewers, a turn sosmatch does not apply (it reads the pixels as stored)")
        else:
            tagged = orientation_note([m.orientation for m, t in zip(metas, turned) if t])
            how = f"which way the pixels were turned from it is not recorded ({tagged or 'no EXIF Orientation tag'})"
        log.warning("%d of %d images are their camera's readout turned by 90 degrees (portrait files, e.g. %s): their "
                    "attitude tags describe the unturned camera and %s, so their headings are left to the images "
                    "(as for images without tags)", int(turned.sum()), n,
                    metas[int(np.flatnonzero(turned)[0])].path.name, how)
    rotations = np.empty((n, 3, 3))
    for k, m_name, ps, rs in (("gimbal", "gimbal", 1.0, 1.0), ("fixed", mount, pitch_sign, roll_sign),
                              ("course", mount, 1.0, 1.0)):
        sel = kind == k
        if sel.any():
            rotations[sel] = camera_rotations(yaw[sel], pitch[sel], roll[sel], m_name, ps, rs, north_az[sel])
    n_course = int(np.sum(kind == "course"))
    n_turns = int(np.sum(turn_images(east, north) & (kind == "course")))
    if n_course:
        # Info, not a warning: these rotations are only a starting point. Every caller that makes poses solves the
        # orientations of such images from the images (structure from motion; poses_from_exif's refinement) and
        # says so itself; a warning here would tell the user the guess is what their map is built on.
        log.info("%d of %d images have no attitude tags: their starting orientations are level, nadir and headed "
                 "along the course over ground (%d of them at turns of the flight, where the course says nothing "
                 "of the heading)", n_course, n, n_turns)

    track_warnings, track_facts = track_checks(east, north, positions[:, 2], times, time_source.startswith("EXIF"),
                                                rotations, kind != "course", [m.path.name for m in metas], lat, lon,
                                                np.array([np.nan if m.exposure_s is None else m.exposure_s
                                                          for m in metas]))
    for text in track_warnings:
        log.warning("%s", text)
    cameras, camera_index, intrinsics_sources, camera_warnings = camera_groups(metas, sensor_width_mm,
                                                                                strict_intrinsics)
    m0 = metas[0]
    summary = {
        "images": n,
        "images_with_gps": int(has.sum()),
        "epsg": int(epsg or 0),
        "crs": f"EPSG:{epsg}" if epsg else "local",
        "origin_latlon": [float(lat[has][0]), float(lon[has][0])] if has.any() else None,
        "position_sources": dict(pos_src),
        "altitude_source": height_source,
        "heights_consistent": ph.consistent,  # one datum the block can be held to (RelativeAltitude or RTK fixed)
        "gps_altitude_vs_relative_altitude": rel_drift.to_dict() if rel_drift is not None else None,
        "takeoff_altitude_m": takeoff_altitude_m if np.isfinite(rel[has]).all() and has.any() else None,
        # flights of different take-off heights (batteries from two home points), when there are several
        "flights": [{"first_image": metas[idx[0]].path.name, "images": len(idx), "takeoff_altitude_m": fit.reference,
                     "gps_altitude_vs_relative_altitude": fit.to_dict()} for idx, fit in flights]
        if len(flights) > 1 else None,
        "attitude_sources": dict(att_src),
        "images_without_attitude": n_course,  # their headings are the course over ground (a guess)
        "images_at_turns_without_attitude": n_turns,  # ... where the course says nothing of the heading
        "capture_times": time_source,
        "mount": mount,
        "pitch_sign": pitch_sign,
        "roll_sign": roll_sign,
        "meridian_convergence_deg": float(np.mean(north_az)),
        "intrinsics_source": intrinsics_sources[0],
        # those a consumer's own record must count (poses.json)
        "warnings": repeated + tele_warnings + track_warnings + camera_warnings,
        "cameras": [{"make_model": make_model(next(m for m, i in zip(metas, camera_index) if i == g)),
                     "images": int(np.sum(camera_index == g)), "width": c.width, "height": c.height,
                     "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "intrinsics_source": intrinsics_sources[g]}
                    for g, c in enumerate(cameras)],
        "make_model": make_model(m0),
        "damaged_metadata": {m.path.name: m.problems for m in damaged},
        **track_facts,
    }
    return ImagePriors(paths, metas, int(epsg or 0), positions, alt, rel, rotations, kind, times, cameras,
                       camera_index, summary)
