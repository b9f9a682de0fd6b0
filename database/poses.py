"""Pose files: the project's pose CSV (read with validation, written atomically).

Format (docs/ARCHITECTURE.md):
    # sosmatch poses v1
    # convention: world_from_camera        (or camera_from_world)
    # crs: local                            (or EPSG:<code>)
    name,x,y,z,qw,qx,qy,qz              (or name,x,y,z,yaw_deg,pitch_deg,roll_deg)
Comment lines start with '#'; `key: value` comments set the convention and CRS. Every defect raises
InputError naming the file and line.

Yaw/pitch/roll (`ypr_to_rotmat`): aerospace angles of the camera body in degrees, as drone gimbals report
them. Body axes x forward (the optical axis), y right, z down; the angles rotate a local-level NED frame
(north, east, down) into the body, intrinsic Z-Y-X: yaw clockwise from north, pitch positive nose up
(-90 = looking straight down, image top towards the yaw heading), roll positive right side down. The world
frame stays ENU (x east, y north, z up). In a projected CRS (`# crs: EPSG:<code>`) the yaw is from true north,
as gimbals and autopilots report it, and is turned into the grid by the meridian convergence at each camera
(1.5 deg at the Seneca site: read as a grid azimuth it cost the map four fifths of its landmarks); in a local
frame north is the frame's +y. With `convention: camera_from_world` the matrix from the angles is taken as the
camera_from_world rotation, exactly as a quaternion would be (and the yaw as given: the camera's heading is not
known before the inversion).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Poses, quat_to_rotmat, rotmat_to_quat
from .atomic import write_text_atomic
from .landmark_map import EPSG_RANGE, MAX_WORLD_COORD_M
from .text_input import read_user_text

QUAT_COLUMNS = ["name", "x", "y", "z", "qw", "qx", "qy", "qz"]
YPR_COLUMNS = ["name", "x", "y", "z", "yaw_deg", "pitch_deg", "roll_deg"]
# ENU world from NED (swap x/y, flip z) and aerospace body (x fwd, y right, z down) from OpenCV camera axes.
_ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_BODY_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
CONVENTIONS = ("world_from_camera", "camera_from_world")
UNIT_QUAT_TOLERANCE = 1e-3
MAX_NAME_CHARS = 4096


def _parse_crs(text: str, path: Path, line: int) -> int:
    text = text.strip()
    if text.lower() == "local":
        return 0
    if text.upper().startswith("EPSG:") and text[5:].isdigit() and len(text) <= 16:
        epsg = int(text[5:])
        problem = crs_problem(epsg)
        if problem is None:
            return epsg
        raise InputError(problem, path, line)
    raise InputError(f"crs must be 'local' or 'EPSG:<code>', got {text[:40]!r}", path, line)


def crs_problem(epsg: int) -> str | None:
    """Why `epsg` cannot be the frame of poses (metres), or None: unknown, or not a projected CRS."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    if not EPSG_RANGE[0] <= epsg <= EPSG_RANGE[1]:
        return f"EPSG code {epsg} is not an EPSG code ({EPSG_RANGE[0]}..{EPSG_RANGE[1]})"
    try:
        crs = CRS.from_epsg(epsg)
    except CRSError:
        return f"unknown EPSG code {epsg}"
    if not crs.is_projected:
        return f"EPSG:{epsg} ({crs.name}) is not a projected CRS in metres; poses need one (or a local frame)"
    unit = crs.axis_info[0].unit_name if crs.axis_info else "metre"
    if unit not in ("metre", "meter"):
        return f"EPSG:{epsg} ({crs.name}) measures in {unit}; poses need a projected CRS in metres (or a local frame)"
    return None


# A map is metric in all three axes only where its CRS keeps distances: UTM stays within 0.1 % of true inside its
# zone; Web Mercator (EPSG:3857, a GIS export's favourite) stretches them by 1 / cos(latitude), 1.47 at 47 deg,
# and the landmarks came out 48 m below the ground with sizes x1.46 (the thirteenth sweep)
MAX_CRS_SCALE_ERROR = 0.01


def crs_scale_problem(epsg: int, centers: np.ndarray) -> str | None:
    """Why EPSG:`epsg` cannot hold a metric map at these camera centres, or None: its scale factor there departs
    from 1 by more than MAX_CRS_SCALE_ERROR (distances stretched, heights not)."""
    from pyproj import CRS, Proj, Transformer

    from ..plugin.geodesy import utm_epsg

    crs = CRS.from_epsg(epsg)
    x, y = np.asarray(centers, np.float64)[:, :2].mean(axis=0)
    lon, lat = Transformer.from_crs(crs, CRS.from_epsg(4326), always_xy=True).transform(x, y)
    if not (np.isfinite(lon) and np.isfinite(lat)):
        return None  # outside the CRS's area: `check_within_crs_area` says so where it matters
    factors = Proj(crs).get_factors(lon, lat)
    scale = max(factors.meridional_scale, factors.parallel_scale, key=lambda k: abs(k - 1.0))
    if not np.isfinite(scale) or abs(scale - 1.0) <= MAX_CRS_SCALE_ERROR:
        return None
    good = utm_epsg(lat, lon)
    return (f"EPSG:{epsg} ({crs.name}) stretches distances by {scale:.3f} at the camera centres (lat {lat:.2f}, "
            f"lon {lon:.2f}) and heights not: the map would not be metric; give the poses in a CRS that keeps "
            f"distances there, e.g. {CRS.from_epsg(good).name} (EPSG:{good})")


def name_problem(name: str) -> str | None:
    """Why `name` cannot be an image name of a pose file (reader and writer alike), or None."""
    if not name:
        return "empty image name"
    if name != name.strip() or name.startswith("#"):
        return f"image name {name[:40]!r} starts or ends with blanks or starts with '#'"
    if len(name) > MAX_NAME_CHARS or any(c in name for c in "\n\r\0"):
        return f"image name {name[:40]!r}... is longer than {MAX_NAME_CHARS} characters or holds a line break"
    return None


def _values_problem(values: list[float], ypr: bool) -> str | None:
    """Why a row's numbers are not a pose (reader), or None."""
    if not all(math.isfinite(v) for v in values):
        return "NaN or infinite pose value"
    if max(abs(v) for v in values[:3]) > MAX_WORLD_COORD_M:
        return f"pose position beyond {MAX_WORLD_COORD_M:g} m (not a coordinate on Earth)"
    if ypr:
        if max(abs(v) for v in values[3:]) > 720.0:
            return "yaw, pitch or roll beyond 720 degrees"
        return None
    norm = math.sqrt(sum(v * v for v in values[3:]))
    if abs(norm - 1.0) > UNIT_QUAT_TOLERANCE:
        return f"quaternion is not unit length (norm {norm:.6f})"
    return None


def ypr_to_rotmat(yaw_deg: np.ndarray, pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """(N,) aerospace yaw, pitch, roll of the camera body in degrees -> (N,3,3) world_from_camera (ENU world)."""
    y, p, r = (np.radians(np.asarray(a, dtype=np.float64)).reshape(-1) for a in (yaw_deg, pitch_deg, roll_deg))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    # ned_from_body = Rz(yaw) Ry(pitch) Rx(roll), written out to stay vectorised.
    ned_from_body = np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)
    return _ENU_FROM_NED @ ned_from_body @ _BODY_FROM_CAM


def rotmat_to_ypr(rotations: np.ndarray) -> np.ndarray:
    """(N,3,3) world_from_camera -> (N,3) yaw, pitch, roll in degrees (inverse of `ypr_to_rotmat`)."""
    ned_from_body = _ENU_FROM_NED.T @ np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3) @ _BODY_FROM_CAM.T
    yaw = np.arctan2(ned_from_body[:, 1, 0], ned_from_body[:, 0, 0])
    pitch = np.arcsin(np.clip(-ned_from_body[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(ned_from_body[:, 2, 1], ned_from_body[:, 2, 2])
    return np.degrees(np.stack([yaw, pitch, roll], 1))


def read_poses_csv(path: str | Path, convention: str | None = None) -> tuple[Poses, int]:
    """Read a pose CSV -> (Poses with world_from_camera rotations and centres, EPSG code or 0).

    `convention` overrides the file's `# convention:` comment (a flag wins over the header).
    """
    path = Path(path)
    text = read_user_text(path, "pose file")
    file_convention, epsg = "world_from_camera", 0
    header: list[str] | None = None
    names: list[str] = []
    seen: set[str] = set()
    rows: list[list[float]] = []
    # universal newlines: a table saved on an old Mac (or as Excel's "CSV (Macintosh)") ends its lines with a bare
    # CR, which csv refuses unless the text is read in universal-newline mode
    reader = csv.reader(io.StringIO(text, newline=None))
    lineno = 0
    while True:
        try:
            row = next(reader)
        except StopIteration:
            break
        except csv.Error as exc:  # e.g. a field of more than 131072 characters, a NUL byte
            raise InputError(f"not a pose CSV: {exc}", path, reader.line_num) from None
        lineno = reader.line_num
        if not row or not "".join(row).strip():
            continue
        if row[0].lstrip().startswith("#"):
            comment = ",".join(row).lstrip()[1:].strip()
            key, _, value = comment.partition(":")
            if key.strip().lower() == "convention":
                file_convention = value.strip().lower()
                if file_convention not in CONVENTIONS:
                    raise InputError(f"unknown convention {value.strip()!r} (use one of {CONVENTIONS})", path, lineno)
            elif key.strip().lower() == "crs":
                epsg = _parse_crs(value, path, lineno)
            continue
        if header is None:
            header = [c.strip().lower() for c in row]
            if header not in (QUAT_COLUMNS, YPR_COLUMNS):
                raise InputError(f"header must be {','.join(QUAT_COLUMNS)} or {','.join(YPR_COLUMNS)}, "
                                 f"got {','.join(header)}", path, lineno)
            continue
        if len(row) != len(header):
            raise InputError(f"expected {len(header)} columns, got {len(row)}", path, lineno)
        try:
            values = [float(v) for v in row[1:]]
        except ValueError:
            raise InputError(f"non-numeric pose value in {_short(row[1:])}", path, lineno) from None
        problem = name_problem(row[0].strip()) or _values_problem(values, header == YPR_COLUMNS)
        if problem is not None:
            raise InputError(problem, path, lineno)
        name = row[0].strip()
        if name in seen:
            raise InputError(f"duplicate image name {name!r}", path, lineno)
        seen.add(name)
        names.append(name)
        rows.append(values)
    if header is None:
        raise InputError("no header line (expected " + ",".join(QUAT_COLUMNS) + ")", path)
    if not rows:
        raise InputError("pose file holds no poses (only its header)", path)
    if convention is not None:
        file_convention = convention
    data = np.array(rows, dtype=np.float64).reshape(-1, len(header) - 1)
    # camera centres given as lon / lat degrees are named as such before anything reads them as metres (the
    # true-north conversion below, the CRS's area); camera_from_world translations are checked as centres below
    centres_given = file_convention == "world_from_camera"
    degrees = _look_like_degrees(data[:, :3], epsg) if centres_given else None
    if degrees:
        raise InputError(degrees, path)
    if not len(data):
        rot = np.zeros((0, 3, 3))
    elif header == QUAT_COLUMNS:
        rot = quat_to_rotmat(data[:, 3:])
    else:
        yaw = data[:, 3]
        if epsg and centres_given:  # true north -> grid (see the module doc)
            from ..plugin.geodesy import grid_north_azimuth
            from .geojson import check_within_crs_area

            # beyond the CRS's area its grid has no meaningful north (pyproj extrapolates a 90 deg convergence)
            check_within_crs_area(epsg, data[:, :2], path, "the camera centres")
            convergence = grid_north_azimuth(data[:, 0], data[:, 1], epsg)
            if not np.all(np.isfinite(convergence)):
                raise InputError(f"camera positions outside the area of EPSG:{epsg} (no true north there)", path)
            yaw = yaw + convergence
        rot = ypr_to_rotmat(yaw, data[:, 4], data[:, 5])
    poses = Poses(names, rot, data[:, :3]) if centres_given else Poses.from_cam_from_world(names, rot, data[:, :3])
    if np.abs(poses.centers).max() > MAX_WORLD_COORD_M:  # camera_from_world translations far from the origin
        raise InputError(f"camera centres beyond {MAX_WORLD_COORD_M:g} m (not a coordinate on Earth)", path)
    degrees = None if centres_given else _look_like_degrees(poses.centers, epsg)
    if degrees:
        raise InputError(degrees, path)
    stretched = crs_scale_problem(epsg, poses.centers) if epsg else None
    if stretched:
        raise InputError(stretched, path)
    return poses, epsg


def _look_like_degrees(centers: np.ndarray, epsg: int = 0) -> str | None:
    """Why the x, y of these camera centres look like longitude / latitude in degrees, or None: several cameras
    all within 0.5 of one another horizontally, at x within +-180 and y within +-90. A flight spans metres at
    least; in degrees it spans thousandths (a GPS log pasted as x, y gave 'wrong relative rotations' before)."""
    xy = np.asarray(centers, dtype=np.float64)[:, :2]
    if len(xy) < 3 or np.ptp(xy, axis=0).max() >= 0.5:
        return None
    if np.all(np.abs(xy[:, 0]) <= 180.0) and np.all(np.abs(xy[:, 1]) <= 90.0):
        frame = f"EPSG:{epsg}'s metres" if epsg else ("metres, in a projected CRS (`# crs: EPSG:<code>`, e.g. UTM) "
                                                        "or a local frame")
        return (f"the camera x, y look like longitude / latitude in degrees (x {xy[0, 0]:.6f}, y {xy[0, 1]:.6f}; "
                f"all {len(xy)} within {np.ptp(xy, axis=0).max():.4f} of each other): poses need {frame}; "
                "`sosmatch poses-from-exif` turns GPS into UTM")
    return None


def _short(values: list[str]) -> str:
    text = repr(values)
    return text if len(text) <= 80 else text[:77] + "..."


def format_poses_csv(poses: Poses, epsg: int = 0) -> str:
    """The pose CSV text (world_from_camera), full float precision.

    Raises ValueError for poses the reader would refuse (the same checks: names, positions, CRS)."""
    if not len(poses):
        raise ValueError("no poses to write")
    if epsg and crs_problem(int(epsg)):
        raise ValueError(crs_problem(int(epsg)))
    if len(set(poses.names)) != len(poses.names):
        raise ValueError("duplicate image names")
    quats = rotmat_to_quat(poses.rotations)
    out = io.StringIO()
    out.write("# sosmatch poses v1\n# convention: world_from_camera\n")
    out.write(f"# crs: {f'EPSG:{epsg}' if epsg else 'local'}\n")
    out.write(",".join(QUAT_COLUMNS) + "\n")
    writer = csv.writer(out, lineterminator="\n")
    for name, c, q in zip(poses.names, poses.centers, quats):
        values = [float(v) for v in (*c, *q)]
        problem = name_problem(name) or _values_problem(values, ypr=False)
        if problem is not None:
            raise ValueError(f"{name[:40]!r}: {problem}")
        writer.writerow([name, *(repr(v) for v in values)])
    return out.getvalue()


def write_poses_csv(path: str | Path, poses: Poses, epsg: int = 0) -> None:
    write_text_atomic(path, format_poses_csv(poses, epsg))
