"""Reader of synthetic session directories written by `sosmatch synth` (layout in docs/ARCHITECTURE.md).

    session = load_synth_session("S1")
    session.camera, session.poses, session.ekf_poses          # plugin.geometry Camera / Poses
    session.objects["id"], session.objects["kind"], ...      # structured numpy array (objects.csv)
    session.frames[0]["visible_object_ids"]                  # frames.json
    session.terrain.height_at(x, y)                          # terrain.npz, bilinear
    session.terrain.footprint(session.camera, r_wc, center)  # ground polygon of one image

Every missing or malformed file raises InputError naming the file (and line for CSV rows).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses, pixel_rays
from .cameras import read_cameras_txt
from .poses import read_poses_csv
from .text_input import read_user_json, read_user_npz, read_user_text

SESSION_FORMAT = "sosmatch-synth-session"
SESSION_VERSION = 1
# objects.csv: x, y, z is the centre of the object's visible top surface (the mean over its footprint seen from
# straight above, where triangulated mask centroids land); apex_z the highest point (tree tip, roof ridge, water
# level of a pond), ground_z the terrain under the object's centre, height = apex_z - ground_z (0 for ponds).
MAX_OBJECT_ID = 65535  # label images hold object ids as uint16 (0 = ground cover)
OBJECT_COLUMNS = ["id", "kind", "x", "y", "z", "radius", "height", "present", "apex_z", "ground_z"]
# Files written before apex_z / ground_z existed (z was the apex then); still read, see read_objects_csv.
LEGACY_OBJECT_COLUMNS = OBJECT_COLUMNS[:8]
OBJECT_DTYPE = np.dtype([
    ("id", "<i4"), ("kind", "U16"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
    ("radius", "<f8"), ("height", "<f8"), ("present", "?"), ("apex_z", "<f8"), ("ground_z", "<f8"),
])


@dataclass(frozen=True)
class TerrainSampler:
    """The bare-earth height field of a synthetic world (objects excluded).

    heights[r, c] is the terrain height at world (x0 + c * resolution_m, y0 + r * resolution_m): rows go
    north (+y), columns east (+x). Heights between samples are bilinear; outside the grid they are clamped to
    the border.
    """

    heights: np.ndarray
    x0: float
    y0: float
    resolution_m: float

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the sample grid."""
        rows, cols = self.heights.shape
        return (self.x0, self.y0, self.x0 + (cols - 1) * self.resolution_m, self.y0 + (rows - 1) * self.resolution_m)

    def height_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Terrain height (float64) at world x, y (any matching shapes)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        rows, cols = self.heights.shape
        fc = np.clip((x - self.x0) / self.resolution_m, 0.0, cols - 1.0)
        fr = np.clip((y - self.y0) / self.resolution_m, 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(fc).astype(np.int64), cols - 2)
        r0 = np.minimum(np.floor(fr).astype(np.int64), rows - 2)
        wc = fc - c0
        wr = fr - r0
        h = self.heights
        top = h[r0, c0] * (1 - wc) + h[r0, c0 + 1] * wc
        bottom = h[r0 + 1, c0] * (1 - wc) + h[r0 + 1, c0 + 1] * wc
        return top * (1 - wr) + bottom * wr

    def intersect_rays(self, origins: np.ndarray, directions: np.ndarray, iterations: int = 30) -> np.ndarray:
        """World points (M, 3) where rays from `origins` (M, 3) along `directions` (M, 3, pointing down) first
        meet the terrain. Marches in 0.5 m height steps below the highest sample, then bisects to < 1 mm."""
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        if np.any(d[:, 2] >= 0):
            raise ValueError("rays must point downward (negative z) to meet the terrain")
        hmax, hmin = float(self.heights.max()) + 0.01, float(self.heights.min()) - 0.01

        def above(t: np.ndarray) -> np.ndarray:
            p = o + t[:, None] * d
            return p[:, 2] - self.height_at(p[:, 0], p[:, 1])

        t_start = (hmax - o[:, 2]) / d[:, 2]  # where the ray enters the height band (above all terrain)
        t_end = (hmin - o[:, 2]) / d[:, 2]  # where it leaves it (below all terrain)
        n_steps = max(1, int(math.ceil((hmax - hmin) / 0.5)))
        frac = np.arange(n_steps + 1) / n_steps
        ts = t_start[:, None] + (t_end - t_start)[:, None] * frac[None, :]  # (M, n+1)
        p = o[:, None, :] + ts[..., None] * d[:, None, :]
        gap = p[..., 2] - self.height_at(p[..., 0], p[..., 1])
        first = np.argmax(gap <= 0, axis=1)  # gap[:, 0] > 0 and gap[:, -1] < 0 by construction
        first = np.maximum(first, 1)
        rows = np.arange(len(o))
        a, b = ts[rows, first - 1], ts[rows, first]
        for _ in range(iterations):  # bisection between the last sample above and the first below
            mid = 0.5 * (a + b)
            is_above = above(mid) > 0
            a = np.where(is_above, mid, a)
            b = np.where(is_above, b, mid)
        t = 0.5 * (a + b)
        return o + t[:, None] * d

    def footprint(self, camera: Camera, r_wc: np.ndarray, center: np.ndarray, per_side: int = 1) -> np.ndarray:
        """Ground polygon (4 per_side, 2) of one image: the rays through `per_side` points per side of the image
        border, clockwise from the corner (0,0) (per_side 1: the corners (0,0), (W,0), (W,H), (0,H); COLMAP pixel
        convention), through the lens model, intersected with the terrain, in that order."""
        from ..plugin.evaluation.footprints import border_pixels

        border = border_pixels(camera, per_side)
        rays = pixel_rays(camera, border, np.asarray(r_wc, dtype=np.float64))
        origins = np.repeat(np.asarray(center, dtype=np.float64).reshape(1, 3), len(border), axis=0)
        return self.intersect_rays(origins, rays)[:, :2]


@dataclass
class SynthSession:
    """Everything in one synthetic session directory, validated."""

    path: Path
    camera: Camera
    poses: Poses
    ekf_poses: Poses
    objects: np.ndarray  # structured array, dtype OBJECT_DTYPE (objects.csv)
    frames: list[dict[str, Any]]  # frames.json: name, visible_object_ids, footprint
    terrain: TerrainSampler
    meta: dict[str, Any] = field(default_factory=dict)  # session.json

    def image_path(self, name: str) -> Path:
        return self.path / "images" / name

    def label_path(self, name: str) -> Path:
        return self.path / "labels" / (Path(name).stem + ".png")

    def present_objects(self) -> np.ndarray:
        """The objects that exist (and render) in this session."""
        return self.objects[self.objects["present"]]


def _read_json(path: Path, expect: type) -> Any:
    if not path.exists():
        raise InputError("file not found (not a complete synthetic session?)", path)
    return read_user_json(path, "session file", expect, redo="re-run `sosmatch synth` (or `synth-from-ortho`)")


def read_objects_csv(path: str | Path) -> np.ndarray:
    """objects.csv -> structured array (OBJECT_DTYPE).

    A legacy file (the first 8 columns only, z = apex) is read with apex_z = z and ground_z = z - height."""
    path = Path(path)
    text = read_user_text(path, "objects file")
    rows = []
    header = None
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        if not row or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = [c.strip() for c in row]
            if header not in (OBJECT_COLUMNS, LEGACY_OBJECT_COLUMNS):
                raise InputError(f"header must be {','.join(OBJECT_COLUMNS)}", path, lineno)
            continue
        if len(row) != len(header):
            raise InputError(f"expected {len(header)} columns, got {len(row)}", path, lineno)
        try:
            values = (int(row[0]), row[1].strip(), *(float(v) for v in row[2:7]), int(row[7]),
                      *(float(v) for v in row[8:]))
        except ValueError:
            raise InputError("malformed object row", path, lineno) from None
        if values[7] not in (0, 1) or not all(math.isfinite(v) for v in values[2:7] + values[8:]):
            raise InputError("present must be 0 or 1 and coordinates finite", path, lineno)
        extra = values[8:] if len(values) > 8 else (values[4], values[4] - values[6])
        rows.append(values[:7] + (bool(values[7]),) + extra)
    if header is None:
        raise InputError("no header line", path)
    ids = [r[0] for r in rows]
    if len(set(ids)) != len(ids):  # objects are looked up by id: a second row silently replaced the first
        dup = next(i for i in ids if ids.count(i) > 1)
        raise InputError(f"object id {dup} is listed more than once", path)
    if ids and not all(0 < i <= MAX_OBJECT_ID for i in ids):
        raise InputError(f"object ids must be within 1..{MAX_OBJECT_ID} (label images hold them as uint16)", path)
    return np.array(rows, dtype=OBJECT_DTYPE)


def format_objects_csv(objects: np.ndarray) -> str:
    """The objects.csv text (heights and positions in metres, 3 decimals)."""
    out = io.StringIO()
    out.write(",".join(OBJECT_COLUMNS) + "\n")
    for o in objects:
        out.write(f"{int(o['id'])},{o['kind']},{o['x']:.3f},{o['y']:.3f},{o['z']:.3f},"
                  f"{o['radius']:.3f},{o['height']:.3f},{int(bool(o['present']))},{o['apex_z']:.3f},"
                  f"{o['ground_z']:.3f}\n")
    return out.getvalue()


def read_terrain_npz(path: str | Path) -> TerrainSampler:
    """terrain.npz (heights float32 2-D, x0, y0, resolution_m) -> TerrainSampler."""
    path = Path(path)
    data = read_user_npz(path, "terrain file")
    try:
        heights = np.asarray(data["heights"], dtype=np.float32)
        x0, y0, res = float(data["x0"]), float(data["y0"]), float(data["resolution_m"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"cannot read terrain (expected heights, x0, y0, resolution_m): {exc}", path) from None
    if heights.ndim != 2 or min(heights.shape) < 2 or not res > 0 or not np.all(np.isfinite(heights)):
        raise InputError("terrain heights must be a finite 2-D grid of at least 2x2 with resolution_m > 0", path)
    return TerrainSampler(heights, x0, y0, res)


def load_synth_session(path: str | Path) -> SynthSession:
    """Read and validate a synthetic session directory."""
    path = Path(path)
    if not path.is_dir():
        raise InputError("synthetic session directory not found", path)
    meta = _read_json(path / "session.json", dict)
    if meta.get("format") != SESSION_FORMAT:
        raise InputError(f"not a synthetic session (format must be {SESSION_FORMAT!r})", path / "session.json")
    if meta.get("version") != SESSION_VERSION:
        raise InputError(f"unsupported session version {meta.get('version')!r}", path / "session.json")
    cameras = read_cameras_txt(path / "cameras.txt")
    if 1 not in cameras:
        raise InputError("camera 1 missing", path / "cameras.txt")
    poses, _ = read_poses_csv(path / "poses.csv")
    ekf, _ = read_poses_csv(path / "poses_ekf.csv")
    if ekf.names != poses.names:
        raise InputError("poses_ekf.csv must list the same images as poses.csv", path / "poses_ekf.csv")
    objects = read_objects_csv(path / "objects.csv")
    frames = _read_json(path / "frames.json", list)
    if [f.get("name") if isinstance(f, dict) else None for f in frames] != poses.names:
        raise InputError("frames.json must list one entry per image of poses.csv, same order", path / "frames.json")
    for f in frames:
        if not isinstance(f.get("visible_object_ids"), list) or not isinstance(f.get("footprint"), list):
            raise InputError(f"frame {f.get('name')!r} lacks visible_object_ids or footprint", path / "frames.json")
        # ids as objects.csv holds them (the evaluation counts sightings by int(id): 'x' was a traceback, 1.5 a
        # sighting of object 1)
        if not all(isinstance(i, int) and not isinstance(i, bool) and 0 < i <= MAX_OBJECT_ID
                   for i in f["visible_object_ids"]):
            raise InputError(f"frame {f['name']!r}: visible_object_ids must be object ids (integers "
                             f"1..{MAX_OBJECT_ID})", path / "frames.json")
    terrain = read_terrain_npz(path / "terrain.npz")
    return SynthSession(path, cameras[1], poses, ekf, objects, frames, terrain, meta)


def ground_truth_crs(path: str | Path) -> tuple[int, np.ndarray] | None:
    """The CRS a synthetic session's ground truth maps to: (EPSG code, world_to_crs offset (3,)); the world frame
    of a session with geotags is its UTM grid shifted by the offset (`tools/synth/geotags.py`), an orthophoto's is
    its raster's CRS itself (offset 0), a session without geotags has none (EPSG 0). None without session.json."""
    path = Path(path)
    if not (path / "session.json").is_file():
        return None
    meta = _read_json(path / "session.json", dict)
    geo = meta.get("geo") if meta.get("source") != "orthophoto" else {"epsg": meta.get("epsg")}
    if not isinstance(geo, dict) or not geo.get("epsg"):
        return 0, np.zeros(3)
    try:
        epsg = int(geo["epsg"])
        offset = np.asarray(geo.get("world_to_crs_offset", [0.0, 0.0, 0.0]), dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputError("geo.epsg or geo.world_to_crs_offset is not a number", path / "session.json") from None
    if not np.all(np.isfinite(offset)):
        raise InputError("geo.world_to_crs_offset must be finite", path / "session.json")
    return epsg, offset


def rendered_by_synth(path: str | Path) -> bool:
    """Whether the session at PATH says (session.json's generator) it was rendered by `sosmatch synth` from a
    procedural world, which always writes its object truth (objects.csv, frames.json, labels/); False for an
    orthophoto session (no object truth), a directory without session.json (a real flight) and a session.json
    written by other means."""
    path = Path(path)
    if not (path / "session.json").is_file():
        return False
    meta = _read_json(path / "session.json", dict)
    return (meta.get("format") == SESSION_FORMAT and meta.get("source") != "orthophoto"
            and str(meta.get("generator", "")).startswith("sosmatch "))


def ground_truth_frame(path: str | Path) -> str | None:
    """What a synthetic session's ground truth (poses.csv, objects.csv, terrain.npz) is expressed in: its procedural
    world ("world seed 61, 600 m at 0.15 m") or its orthophoto's CRS ("orthophoto in EPSG:32618"); None for a
    directory without session.json (a real flight: its ground truth's frame is the user's to know).

    Two sessions can be scored against each other only in one frame: sessions of two worlds share coordinates
    but no ground, objects or object ids."""
    path = Path(path)
    if not (path / "session.json").is_file():
        return None
    meta = _read_json(path / "session.json", dict)
    if meta.get("format") != SESSION_FORMAT:
        raise InputError(f"not a synthetic session (format must be {SESSION_FORMAT!r})", path / "session.json")
    if meta.get("source") == "orthophoto":
        return f"orthophoto in EPSG:{meta.get('epsg')}"
    config = meta.get("config")
    if not isinstance(config, dict) or not all(k in config for k in ("world_seed", "world_size_m",
                                                                      "world_resolution_m")):
        raise InputError("config lacks world_seed, world_size_m or world_resolution_m", path / "session.json")
    return (f"world seed {config['world_seed']}, {config['world_size_m']:g} m at "
            f"{config['world_resolution_m']:g} m")
