"""OpenSfM / OpenDroneMap reconstructions (`opensfm/reconstruction.json`): poses and cameras, read and validated.

Format (OpenSfM's doc/source/geometry.rst and io.py): a JSON list of reconstructions, each with
- `cameras`: {camera id: {projection_type, width, height, focal | focal_x + focal_y, c_x, c_y, k1, k2, ...}},
  in *normalised image coordinates*: origin at the image centre, the larger image side = 1, so pixels (COLMAP
  convention, top-left pixel centre at 0.5) are u = max(w, h) x_n + w / 2;
- `shots`: {image name: {rotation (angle-axis), translation, camera, ...}}: x_cam = R(rotation) x_world +
  translation, camera axes x right, y down, z forward (OpenCV's);
- `points`: {id: {coordinates, color}};
- optionally `reference_lla` {latitude, longitude, altitude}: the origin of the topocentric world frame (x east,
  y north, z up) when GPS was used; OpenDroneMap keeps it in `opensfm/reference_lla.json` beside.

Camera models map onto COLMAP's exactly: perspective (f, k1, k2 about the centre) = RADIAL, simple_radial =
SIMPLE_RADIAL (or OPENCV with unequal focal lengths), radial = RADIAL (or OPENCV), brown = OPENCV (FULL_OPENCV
when k3 is not 0; OpenSfM's tangential terms are OpenCV's), fisheye (d = 1 + k1 theta^2 + k2 theta^4) =
RADIAL_FISHEYE. Other projections (spherical, dual, fisheye62, fisheye_opencv) are refused by name.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from .cameras import camera_from_colmap
from .text_input import read_user_json

log = logging.getLogger(__name__)

# ODM's name for the topocentric reconstruction once reconstruction.json is georeferenced (see find_reconstruction)
TOPOCENTRIC = "reconstruction.topocentric.json"
SUPPORTED = ("perspective", "simple_radial", "radial", "brown", "fisheye")


@dataclass
class OpenSfmReconstruction:
    """The largest reconstruction of a reconstruction.json: poses in its world frame, cameras in pixels."""

    path: Path
    poses: Poses  # world_from_camera, sorted by name
    cameras: dict[str, Camera]  # by OpenSfM camera id
    camera_of_shot: dict[str, str]
    points: np.ndarray  # (M,3) world
    reference_lla: tuple[float, float, float] | None  # latitude, longitude, altitude of the world origin
    other_reconstructions: list[int] = field(default_factory=list)  # shot counts of the smaller ones


def find_reconstruction(path: str | Path) -> Path:
    """The topocentric reconstruction of a reconstruction.json or of an OpenDroneMap / OpenSfM project directory.

    OpenDroneMap >= 2 (stages/run_opensfm.py), once georeferenced, runs OpenSfM's `export_geocoords
    --reconstruction --offset-x/-y` and moves the result over opensfm/reconstruction.json: UTM minus the offset of
    odm_georeferencing/coords.txt, absolute heights. The topocentric original, the one reference_lla.json
    describes, stays beside as reconstruction.topocentric.json: that one is read. A reconstruction.json of a
    georeferenced ODM project without it cannot be told apart from a topocentric one by its content (ODM puts
    reference_lla at the same offset, so the two differ by the meridian convergence), so it is refused rather
    than guessed."""
    path = Path(path)
    if path.is_dir():
        for cand in (path / "opensfm" / "reconstruction.json", path / "reconstruction.json"):
            if cand.is_file():
                path = cand
                break
        else:
            topo = path / "opensfm" / TOPOCENTRIC
            if topo.is_file():
                return topo
            raise InputError("no opensfm/reconstruction.json in the project directory", path)
    elif not path.is_file():
        raise InputError("OpenSfM reconstruction not found", path)
    if path.name != "reconstruction.json":
        return path  # named explicitly (reconstruction.topocentric.json, a copy): taken as given
    topo = path.with_name(TOPOCENTRIC)
    if topo.is_file():
        log.info("%s is OpenDroneMap's georeferenced copy (offset UTM): reading the topocentric %s beside it",
                 path, topo.name)
        return topo
    coords = next((d / "odm_georeferencing" / "coords.txt" for d in (path.parent.parent, path.parent)
                   if (d / "odm_georeferencing" / "coords.txt").is_file()), None)
    if coords is not None:
        raise InputError(f"the project is georeferenced ({coords}) but {TOPOCENTRIC} is missing beside this file: "
                         "OpenDroneMap rewrites reconstruction.json in offset UTM, so its frame is unknown; put "
                         f"the project's {TOPOCENTRIC} back beside it", path)
    return path


def is_opensfm(path: str | Path) -> bool:
    """True for a reconstruction.json file or a project directory holding one (no parsing)."""
    path = Path(path)
    if path.is_dir():
        return any((path / sub).is_file() for sub in ("opensfm/reconstruction.json", f"opensfm/{TOPOCENTRIC}",
                                                       "reconstruction.json"))
    return path.is_file() and path.suffix.lower() == ".json" and path.name.startswith("reconstruction")


def _number(d: dict, key: str, where: str, path: Path, default: float | None = None) -> float:
    value = d.get(key, default)
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{where}: '{key}' must be a number, got {value!r}", path) from None
    if not math.isfinite(number):
        raise InputError(f"{where}: '{key}' is not finite", path)
    return number


def camera_from_opensfm(cam: dict, where: str, path: Path) -> Camera:
    """One OpenSfM camera (normalised coordinates) as a pixel Camera of COLMAP's equivalent model."""
    kind = str(cam.get("projection_type", "perspective"))
    if kind not in SUPPORTED:
        raise InputError(f"{where}: projection_type {kind!r} is not supported (use one of {', '.join(SUPPORTED)})",
                         path)
    w, h = int(_number(cam, "width", where, path)), int(_number(cam, "height", where, path))
    if w <= 0 or h <= 0:
        raise InputError(f"{where}: width and height must be positive", path)
    scale = float(max(w, h))
    num = lambda key, default=None: _number(cam, key, where, path, default)  # noqa: E731
    if kind in ("perspective", "fisheye"):
        fx = fy = num("focal") * scale
        cx, cy = w / 2.0, h / 2.0
    else:
        fx, fy = num("focal_x") * scale, num("focal_y") * scale
        cx, cy = w / 2.0 + num("c_x", 0.0) * scale, h / 2.0 + num("c_y", 0.0) * scale
    k1, k2 = num("k1", 0.0), num("k2", 0.0)
    if kind == "fisheye":
        model, params = "RADIAL_FISHEYE", [fx, cx, cy, k1, k2]
    elif kind == "brown":
        p1, p2, k3 = num("p1", 0.0), num("p2", 0.0), num("k3", 0.0)
        if k3 == 0.0:
            model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
        else:
            model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    elif fx == fy and kind == "simple_radial":
        model, params = "SIMPLE_RADIAL", [fx, cx, cy, k1]
    elif fx == fy:  # perspective, radial
        model, params = "RADIAL", [fx, cx, cy, k1, k2]
    else:
        model, params = "OPENCV", [fx, fy, cx, cy, k1, k2 if kind != "simple_radial" else 0.0, 0.0, 0.0]
    return camera_from_colmap(model, w, h, params, path)


def _rotation(rotvec: list) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix()


def read_opensfm_reconstruction(path: str | Path) -> OpenSfmReconstruction:
    """The largest reconstruction of an OpenSfM reconstruction.json (or a project directory); every defect is an
    InputError naming the file and the shot or camera."""
    path = find_reconstruction(path)
    data = read_user_json(path, "OpenSfM reconstruction", (list, dict))
    if isinstance(data, dict):
        data = [data]
    recs = [r for r in data if isinstance(r, dict) and isinstance(r.get("shots"), dict)] if isinstance(data, list) \
        else []
    if not recs:
        raise InputError("no reconstruction with shots in the file (an OpenSfM reconstruction.json is a list of "
                         "{cameras, shots, points})", path)
    recs.sort(key=lambda r: -len(r["shots"]))
    rec = recs[0]
    cams_json = rec.get("cameras")
    if not isinstance(cams_json, dict) or not cams_json:
        raise InputError("the reconstruction has no cameras", path)
    cameras = {str(k): camera_from_opensfm(v, f"camera {k!r}", path) for k, v in cams_json.items()
               if isinstance(v, dict)}
    names, rots, centers, cam_of = [], [], [], {}
    for name in sorted(rec["shots"]):
        shot = rec["shots"][name]
        where = f"shot {name!r}"
        try:
            r_cw = _rotation(shot["rotation"])
            t = np.asarray(shot["translation"], dtype=np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{where}: needs 'rotation' (3 numbers, angle-axis) and 'translation' (3)", path) \
                from None
        if not np.all(np.isfinite(t)) or not np.all(np.isfinite(r_cw)):
            raise InputError(f"{where}: rotation or translation is not finite", path)
        cam_id = str(shot.get("camera", ""))
        if cam_id not in cameras:
            raise InputError(f"{where}: camera {cam_id!r} is not among the reconstruction's cameras", path)
        names.append(str(name))
        rots.append(r_cw.T)
        centers.append(-r_cw.T @ t)
        cam_of[str(name)] = cam_id
    pts = [p.get("coordinates") for p in (rec.get("points") or {}).values() if isinstance(p, dict)]
    points = np.array([c for c in pts if isinstance(c, list) and len(c) == 3], dtype=np.float64).reshape(-1, 3)
    ref = rec.get("reference_lla")
    beside = path.parent / "reference_lla.json"
    if not isinstance(ref, dict) and beside.is_file():
        ref = read_user_json(beside, "OpenSfM reference_lla.json")
    lla = None
    if isinstance(ref, dict):
        lla = tuple(_number(ref, k, "reference_lla", path) for k in ("latitude", "longitude", "altitude"))
    return OpenSfmReconstruction(path, Poses(names, np.array(rots).reshape(-1, 3, 3),
                                             np.array(centers).reshape(-1, 3)),
                                 cameras, cam_of, points, lla,  # type: ignore[arg-type]
                                 [len(r["shots"]) for r in recs[1:]])
