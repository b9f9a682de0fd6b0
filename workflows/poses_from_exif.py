"""Poses and intrinsics from the images themselves: EXIF GPS + XMP attitude -> poses.csv + cameras.txt.

`poses_from_images(paths, ...)` returns an `ExifPoses` (world_from_camera poses in UTM, the EPSG code, one
pinhole camera and a summary of what was read from which tags); `run(...)` writes `poses.csv` and `cameras.txt`.

World frame. Positions are full UTM coordinates (WGS84 / UTM, EPSG:326zz north or 327zz south, the zone of the
first image unless `epsg` is given), z = the GPS altitude (metres, as the receiver reports it: for most
consumer receivers height above the ellipsoid or above mean sea level; either way one consistent vertical
datum per flight). The pose CSV header says `# crs: EPSG:<code>`; float64 keeps UTM-sized coordinates to well
under a millimetre, and the landmark map stores an origin + EPSG, so every output stays georeferenced.
Rotations are expressed in the UTM grid: the heading of an image (from true north) is turned into a grid
azimuth with the local meridian convergence (1.5 degrees at the Seneca site, not negligible against attitude
errors of a degree or two).

Attitude sources, per image, first that applies:
1. DJI XMP `GimbalYawDegree/GimbalPitchDegree/GimbalRollDegree` (absolute gimbal angles; pitch -90 = nadir):
   the camera looks along the gimbal's forward axis, image x to its right (mount "gimbal").
2. senseFly XMP `Heading/PitchAngle/RollAngle`, or DJI `FlightYawDegree/FlightPitchDegree/FlightRollDegree`
   without gimbal tags, or the same angles from a telemetry CSV (`telemetry=`): the airframe attitude of a
   camera fixed to the airframe looking down; the mounting is `mount` (see `FIXED_MOUNTS`), and the sign of
   pitch and roll `pitch_sign`/`roll_sign`.
3. No attitude at all: level, nadir, heading = course over ground (EXIF GPSTrack, else the direction to the
   neighbouring images); a warning says how many images this affected.

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

Intrinsics: fx = FocalLength [mm] * FocalPlaneXResolution [px/mm] * (file width / ExifImageWidth): EXIF
describes the sensor readout, and images are often downscaled afterwards (Seneca: 4000x3000 -> 1200x900).
Without a focal-plane resolution, `sensor_width_mm` (fx = f / sensor width * file width) or the 35 mm
equivalent focal length (scaled by the image diagonal) are used. The principal point is the image centre.
"""

from __future__ import annotations

import csv
import logging
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..database.cameras import format_cameras_txt
from ..database.exif import ImageMetadata, read_image_metadata
from ..database.outputs import OutputFiles, fingerprint
from ..database.poses import format_poses_csv
from ..database.text_input import read_user_text
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

# Camera axes (x right, y down, z forward) expressed in the airframe's forward-right-down (FRD) axes, as the
# columns of R_body_from_cam. A downward camera has z = body down; the mounts differ in where the image top is.
FIXED_MOUNTS: dict[str, np.ndarray] = {
    # image top towards the nose, image x along the right wing
    "top_forward": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    # image x towards the nose (image top towards the left wing)
    "right_forward": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    # image top towards the tail
    "top_backward": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    # image x towards the tail (image top towards the right wing)
    "left_forward": np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]),
}
# A gimbal camera looks along its forward axis: x = right, y = down, z = forward.
GIMBAL_MOUNT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# Chosen by the Seneca flow check (tools/benchmarks/bench_real.py, BENCHMARKS.md real-data section).
DEFAULT_MOUNT = "top_forward"
DEFAULT_PITCH_SIGN = 1.0
DEFAULT_ROLL_SIGN = 1.0
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def ned_from_body(yaw_deg: np.ndarray, pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """(N,3,3) aerospace rotations Rz(yaw) Ry(pitch) Rx(roll): yaw clockwise from north, pitch nose up."""
    y, p, r = (np.radians(np.asarray(a, dtype=np.float64)).reshape(-1) for a in (yaw_deg, pitch_deg, roll_deg))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    one, zero = np.ones_like(y), np.zeros_like(y)
    rz = np.stack([np.stack([cy, -sy, zero], -1), np.stack([sy, cy, zero], -1), np.stack([zero, zero, one], -1)], -2)
    ry = np.stack([np.stack([cp, zero, sp], -1), np.stack([zero, one, zero], -1), np.stack([-sp, zero, cp], -1)], -2)
    rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cr, -sr], -1), np.stack([zero, sr, cr], -1)], -2)
    return rz @ ry @ rx


def camera_rotations(
    yaw_deg: np.ndarray,
    pitch_deg: np.ndarray,
    roll_deg: np.ndarray,
    mount: str | np.ndarray = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    grid_azimuth_of_north_deg: np.ndarray | float = 0.0,
) -> np.ndarray:
    """world_from_camera rotations (N,3,3) in an east-north-up grid frame from aerospace body angles.

    `mount` is a name in FIXED_MOUNTS, "gimbal", or a 3x3 R_body_from_cam. `grid_azimuth_of_north_deg` is the
    azimuth of true north in the grid (clockwise from grid north), added to the yaw (meridian convergence).
    """
    if isinstance(mount, str):
        if mount == "gimbal":
            m = GIMBAL_MOUNT
        elif mount in FIXED_MOUNTS:
            m = FIXED_MOUNTS[mount]
        else:
            raise InputError(f"unknown camera mount {mount!r} (use gimbal or one of {sorted(FIXED_MOUNTS)})")
    else:
        m = np.asarray(mount, dtype=np.float64)
    yaw = np.asarray(yaw_deg, dtype=np.float64) + np.asarray(grid_azimuth_of_north_deg, dtype=np.float64)
    r = ned_from_body(yaw, pitch_sign * np.asarray(pitch_deg, float), roll_sign * np.asarray(roll_deg, float))
    return ENU_FROM_NED @ r @ m


def utm_epsg(latitude: float, longitude: float) -> int:
    """EPSG code of the WGS84 / UTM zone containing a point (326zz north, 327zz south)."""
    zone = int(math.floor((longitude + 180.0) / 6.0)) % 60 + 1
    return (32600 if latitude >= 0 else 32700) + zone


def geographic_to_grid(lat: np.ndarray, lon: np.ndarray, epsg: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """WGS84 degrees -> (easting, northing, azimuth of true north in the grid in degrees) for a projected CRS."""
    from pyproj import Transformer

    tf = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    e, n = tf.transform(lon, lat)
    # Meridian convergence measured, not looked up: the grid direction of a 1e-4 degree step north.
    e2, n2 = tf.transform(lon, lat + 1e-4)
    north_az = np.degrees(np.arctan2(np.asarray(e2) - e, np.asarray(n2) - n))
    return np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64), north_az


@dataclass
class ExifPoses:
    """Poses (world_from_camera, UTM), the EPSG code, one pinhole camera and a summary of the sources."""

    poses: Poses
    epsg: int
    camera: Camera
    summary: dict = field(default_factory=dict)


def list_images(images: str | Path | Sequence[str | Path]) -> list[Path]:
    """A directory's image files (sorted by name), or the given list of paths."""
    if isinstance(images, (str, Path)):
        root = Path(images)
        if root.is_dir():
            paths = sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not paths:
                raise InputError("no images (.jpg/.tif/.png) in directory", root)
            return paths
        if not root.exists():
            raise InputError("image directory not found", root)
        return [root]
    return [Path(p) for p in images]


_TELEMETRY_KEYS = {
    "name": ("filename", "name", "image", "image_name", "file"),
    "yaw": ("heading", "yaw", "yaw_deg", "flightyawdegree"),
    "pitch": ("pitchangle", "pitch", "pitch_deg", "flightpitchdegree"),
    "roll": ("rollangle", "roll", "roll_deg", "flightrolldegree"),
    "lat": ("gpslatitude", "latitude", "lat"),
    "lon": ("gpslongitude", "longitude", "lon"),
    "alt": ("gpsaltitude", "altitude", "alt"),
}


def read_telemetry_csv(path: str | Path) -> dict[str, dict[str, float]]:
    """Per image name: yaw/pitch/roll (and lat/lon/alt where present) from a telemetry CSV (header names as in
    Seneca's telemetry.csv: FileName, Heading, PitchAngle, RollAngle, GPSLatitude, ...; case-insensitive)."""
    path = Path(path)
    text = read_user_text(path, "telemetry file")
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError("empty telemetry file", path)
    header = [h.strip().lower() for h in rows[0]]
    col = {key: next((header.index(a) for a in aliases if a in header), None)
           for key, aliases in _TELEMETRY_KEYS.items()}
    if col["name"] is None:
        raise InputError(f"telemetry header needs an image name column (one of {_TELEMETRY_KEYS['name']})", path, 1)
    out: dict[str, dict[str, float]] = {}
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        values: dict[str, float] = {}
        for key, idx in col.items():
            if key == "name" or idx is None or idx >= len(row) or not row[idx].strip():
                continue
            try:
                values[key] = float(row[idx])
            except ValueError:
                raise InputError(f"non-numeric {header[idx]} value {row[idx]!r}", path, lineno) from None
        out[row[col["name"]].strip()] = values
    return out


def camera_from_metadata(meta: ImageMetadata, sensor_width_mm: float | None = None) -> tuple[Camera, str]:
    """Pinhole intrinsics of one image from its EXIF, scaled to the file's actual size, and the source used."""
    w, h = meta.width, meta.height
    if meta.focal_mm and sensor_width_mm:
        fx = meta.focal_mm / sensor_width_mm * w
        return Camera(w, h, fx, fx, w / 2.0, h / 2.0), "FocalLength + given sensor width"
    if meta.focal_mm and meta.focal_plane_px_per_mm:
        ref_w, ref_h = meta.exif_size if meta.exif_size else (w, h)
        if meta.exif_size and abs(ref_w / ref_h - w / h) > 0.01:
            log.warning("%s: EXIF size %dx%d and file %dx%d differ in aspect (cropped?): scaling by width",
                        meta.path.name, ref_w, ref_h, w, h)
        scale = w / ref_w
        fx = meta.focal_mm * meta.focal_plane_px_per_mm[0] * scale
        fy = meta.focal_mm * meta.focal_plane_px_per_mm[1] * scale
        return Camera(w, h, fx, fy, w / 2.0, h / 2.0), "FocalLength + FocalPlaneX/YResolution (scaled to file size)"
    if meta.focal_35mm:
        fx = meta.focal_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(w, h)
        return Camera(w, h, fx, fx, w / 2.0, h / 2.0), "FocalLengthIn35mmFilm (diagonal)"
    raise InputError("no usable focal length in EXIF (FocalLength with FocalPlaneXResolution, or "
                     "FocalLengthIn35mmFilm); give the sensor width (--sensor-width-mm) or a cameras.txt", meta.path)


def _course_from_neighbours(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """Azimuth of travel (degrees clockwise from grid north) at each image, from its neighbours."""
    n = len(east)
    if n < 2:
        return np.zeros(n)
    nxt = np.r_[np.arange(1, n), n - 1]
    prv = np.r_[0, np.arange(0, n - 1)]
    return np.degrees(np.arctan2(east[nxt] - east[prv], north[nxt] - north[prv]))


def poses_from_images(
    images: str | Path | Sequence[str | Path],
    telemetry: str | Path | None = None,
    mount: str = DEFAULT_MOUNT,
    pitch_sign: float = DEFAULT_PITCH_SIGN,
    roll_sign: float = DEFAULT_ROLL_SIGN,
    sensor_width_mm: float | None = None,
    epsg: int | None = None,
) -> ExifPoses:
    """Poses (UTM, world_from_camera) and one pinhole camera from the images' EXIF/XMP (and a telemetry CSV).

    Images without a GPS position (in EXIF or in the telemetry) raise InputError naming them; so do images of
    different sizes. The returned summary says which tags every value came from.
    """
    paths = list_images(images)
    tele = read_telemetry_csv(telemetry) if telemetry is not None else {}
    metas = [read_image_metadata(p) for p in paths]
    n = len(metas)
    lat, lon, alt = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    pos_src: Counter = Counter()
    for i, m in enumerate(metas):
        t = tele.get(m.path.name, {})
        if m.has_gps:
            lat[i], lon[i] = m.latitude, m.longitude
            pos_src["EXIF GPS"] += 1
        elif "lat" in t and "lon" in t:
            lat[i], lon[i] = t["lat"], t["lon"]
            pos_src["telemetry CSV"] += 1
        alt[i] = m.altitude if m.altitude is not None else t.get("alt", np.nan)
    missing = [metas[i].path.name for i in np.flatnonzero(~np.isfinite(lat))]
    if missing:
        raise InputError(f"{len(missing)} of {n} images have no GPS position (EXIF GPSLatitude/GPSLongitude), "
                         f"e.g. {missing[0]}; give a telemetry CSV with positions or a poses.csv",
                         metas[np.flatnonzero(~np.isfinite(lat))[0]].path)
    if np.any(~np.isfinite(alt)):
        bad = metas[int(np.flatnonzero(~np.isfinite(alt))[0])].path
        raise InputError("image has GPS latitude/longitude but no GPSAltitude", bad)
    if epsg is None:
        epsg = utm_epsg(float(lat[0]), float(lon[0]))
    east, north, north_az = geographic_to_grid(lat, lon, epsg)

    # Attitude, per image.
    yaw, pitch, roll = np.zeros(n), np.zeros(n), np.zeros(n)
    kind = np.empty(n, dtype=object)
    att_src: Counter = Counter()
    course = _course_from_neighbours(east, north)
    for i, m in enumerate(metas):
        t = tele.get(m.path.name, {})
        gimbal = [m.xmp_float(k) for k in ("GimbalYawDegree", "GimbalPitchDegree", "GimbalRollDegree")]
        fixed = [m.xmp_float("Heading", "FlightYawDegree"), m.xmp_float("PitchAngle", "FlightPitchDegree"),
                 m.xmp_float("RollAngle", "FlightRollDegree")]
        if all(gimbal):
            (yaw[i], _), (pitch[i], _), (roll[i], _) = gimbal  # type: ignore[misc]
            kind[i] = "gimbal"
            att_src["XMP GimbalYaw/Pitch/RollDegree"] += 1
        elif all(fixed):
            (yaw[i], ky), (pitch[i], kp), (roll[i], kr) = fixed  # type: ignore[misc]
            kind[i] = "fixed"
            att_src[f"XMP {ky}/{kp}/{kr}"] += 1
        elif all(k in t for k in ("yaw", "pitch", "roll")):
            yaw[i], pitch[i], roll[i] = t["yaw"], t["pitch"], t["roll"]
            kind[i] = "fixed"
            att_src["telemetry CSV"] += 1
        else:
            kind[i] = "course"
            if m.gps_track_deg is not None:
                yaw[i] = m.gps_track_deg
                att_src["EXIF GPSTrack (level, nadir)"] += 1
            else:
                yaw[i] = course[i] - north_az[i]  # course is a grid azimuth; yaw is from true north
                att_src["course from neighbours (level, nadir)"] += 1
    rotations = np.empty((n, 3, 3))
    for k, m_name, ps, rs in (("gimbal", "gimbal", 1.0, 1.0), ("fixed", mount, pitch_sign, roll_sign),
                              ("course", mount, 1.0, 1.0)):
        sel = kind == k
        if sel.any():
            rotations[sel] = camera_rotations(yaw[sel], pitch[sel], roll[sel], m_name, ps, rs, north_az[sel])
    n_course = int(np.sum(kind == "course"))
    if n_course:
        log.warning("%d of %d images have no attitude tags: assumed level and nadir, heading = course", n_course, n)

    # Intrinsics: one camera; every image must have the same size.
    sizes = Counter((m.width, m.height) for m in metas)
    if len(sizes) > 1:
        (w0, h0), _ = sizes.most_common(1)[0]
        odd = next(m for m in metas if (m.width, m.height) != (w0, h0))
        raise InputError(f"image is {odd.width}x{odd.height} but most are {w0}x{h0}: one camera per session, "
                         "resize the images to one size", odd.path)
    cams = [camera_from_metadata(m, sensor_width_mm) for m in metas]
    fxs = np.array([c.fx for c, _ in cams])
    fys = np.array([c.fy for c, _ in cams])
    if fxs.max() > 1.01 * fxs.min():
        log.warning("focal lengths differ between images (%.1f..%.1f px): using the median", fxs.min(), fxs.max())
    c0 = cams[0][0]
    camera = Camera(c0.width, c0.height, float(np.median(fxs)), float(np.median(fys)), c0.cx, c0.cy)
    centers = np.stack([east, north, alt], 1)
    poses = Poses([m.path.name for m in metas], rotations, centers)
    summary = {
        "images": n,
        "epsg": int(epsg),
        "crs": f"EPSG:{epsg}",
        "origin_latlon": [float(lat[0]), float(lon[0])],
        "position_sources": dict(pos_src),
        "altitude_source": "EXIF GPSAltitude" if all(m.altitude is not None for m in metas) else "EXIF/telemetry",
        "attitude_sources": dict(att_src),
        "mount": mount,
        "pitch_sign": pitch_sign,
        "roll_sign": roll_sign,
        "meridian_convergence_deg": float(np.mean(north_az)),
        "intrinsics_source": cams[0][1],
        "camera": {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
                   "cx": camera.cx, "cy": camera.cy},
        "make_model": metas[0].model if metas[0].model.startswith(metas[0].make)
        else f"{metas[0].make} {metas[0].model}".strip(),
    }
    return ExifPoses(poses, int(epsg), camera, summary)


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
    `sosmatch.database.outputs.OutputFiles`, checked before any work: an existing file is replaced only when
    this command wrote it (from other images or options: only with `overwrite`).
    """
    out = Path(out)
    cameras_path = Path(cameras_out) if cameras_out is not None else out.parent / "cameras.txt"
    sources = [Path(p) for p in ([images] if isinstance(images, (str, Path)) else images)]
    identity = fingerprint({"images": [[str(p.resolve()), *_stat(p)] for p in list_images(images)],
                            "telemetry": _stat(telemetry) if telemetry else None,
                            "options": [mount, pitch_sign, roll_sign, sensor_width_mm, epsg, refine, position_sigma_m,
                                        attitude_sigma_deg, refine_method]})
    files = OutputFiles([out, cameras_path], "poses-from-exif", identity, inputs=[*sources, telemetry],
                        overwrite=overwrite)
    result = poses_from_images(images, telemetry, mount, pitch_sign, roll_sign, sensor_width_mm, epsg)
    if refine:
        stats = _refine(result, images, position_sigma_m, attitude_sigma_deg, refine_method)
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


def map_inputs_from_images(
    images: str | Path,
    telemetry: str | Path | None = None,
    refine: bool = False,
    position_sigma_m: float = 3.0,
) -> object:
    """`sosmatch map --images DIR` without `--poses`: the images' EXIF/XMP (and `telemetry`) poses and camera as
    `workflows.map.MapInputs`, refined from tie points first when `refine` (see `run`). Nothing is written; the
    map's fingerprint covers the poses as used, so a re-run resumes."""
    from .map import MapInputs

    result = poses_from_images(images, telemetry)
    source = f"EXIF/XMP of {images}" + (f" + {telemetry}" if telemetry else "")
    if refine:
        _refine(result, images, position_sigma_m)
        source += ", refined from tie points"
    return MapInputs(_image_paths(images, result.poses), result.poses, result.camera, result.epsg,
                     {"poses": source, "camera": f"EXIF of {images}", "images": str(images)})


def _image_paths(images: str | Path, poses: Poses) -> list[Path]:
    """The image files of `images` in the order of `poses`."""
    paths = {p.name: p for p in list_images(images)}
    return [paths[n] for n in poses.names]


def _refine(result: ExifPoses, images: str | Path, position_sigma_m: float, attitude_sigma_deg: float = 5.0,
            method: str = "colmap") -> object:
    """Refine `result.poses` in place from tie points between the images (`refine_poses_from_images`); returns the
    refinement statistics."""
    from .pose_refinement import refine_poses_from_images

    result.poses, stats = refine_poses_from_images(_image_paths(images, result.poses), result.poses, result.camera,
                                                   position_sigma_m, attitude_sigma_deg, method=method)
    return stats
