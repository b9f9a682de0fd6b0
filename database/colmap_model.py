"""COLMAP models in and out: poses and intrinsics from a model, the session's sparse/ model and landmarks.ply.

Reading accepts a model directory (or its images.bin / images.txt / cameras.* file). Binary or complete models
go through `pycolmap.Reconstruction`; a text model with only cameras.txt + images.txt (no points3D.txt, as
pose exports often are) is parsed here with the same validation as the pose CSV (file and line in every error).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses, quat_to_rotmat
from .atomic import atomic_path, write_bytes_atomic
from .cameras import camera_from_pycolmap, distinct_cameras, read_cameras_txt
from .colmap_binary import check_binary_model
from .poses import UNIT_QUAT_TOLERANCE
from .text_input import bounded_lines, open_without_waiting

if TYPE_CHECKING:
    import pycolmap

MODEL_FILES = ("cameras", "images", "points3D")


def model_dir_of(path: str | Path) -> Path:
    """The model directory of a path that is a model directory or one of its files."""
    path = Path(path)
    if path.is_file() and path.stem in ("cameras", "images", "points3D", "rigs", "frames"):
        return path.parent
    return path


def is_colmap_model(path: str | Path) -> bool:
    """True if `path` is (a file of) a COLMAP model directory holding images.bin or images.txt."""
    d = model_dir_of(path)
    return d.is_dir() and ((d / "images.bin").is_file() or (d / "images.txt").is_file())


def _looks_like_image_line(parts: list[str]) -> bool:
    """IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME: an int, seven numbers, an int, a name."""
    if len(parts) < 10:
        return False
    try:
        int(parts[0]), int(parts[8]), [float(v) for v in parts[1:8]]
    except ValueError:
        return False
    return True


def _points2d_problem(line: str) -> str | None:
    """Why the line right after an image line cannot be its POINTS2D line (X Y POINT3D_ID triples; empty or
    white space: none), or None. COLMAP reads that line as the POINTS2D line whatever it holds, so one missing (an
    export with one line per image) made every second image line the POINTS2D line of the one before."""
    parts = line.split()
    # an image line has 10 fields (more only for a name with spaces, which COLMAP cuts at the first): no
    # POINTS2D line has that many unless it ends with an integer POINT3D_ID, where an image line ends with its name
    if _looks_like_image_line(parts) and (len(parts) % 3 or not parts[-1].lstrip("-").isdigit()):
        return "images.txt needs a POINTS2D line (empty is fine) after every image line; this is an image line"
    if parts and parts[0].startswith("#"):  # COLMAP fails on it; skipping it made the next image line the POINTS2D
        return "a comment where the image line before needs its POINTS2D line (empty is fine)"
    if len(parts) % 3:
        return f"a POINTS2D line holds X Y POINT3D_ID triples, this one {len(parts)} fields"
    return None


def _read_images_txt(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, list[int]]:
    """Parse images.txt -> names, quaternions (w,x,y,z) cam_from_world, translations, camera ids."""
    names: list[str] = []
    quats: list[list[float]] = []
    trans: list[list[float]] = []
    cam_ids: list[int] = []
    seen: set[str] = set()
    expect_pose = True
    try:
        handle = io.TextIOWrapper(open_without_waiting(path), encoding="utf-8-sig")  # a BOM is not text
    except OSError as exc:
        raise InputError(f"cannot read images file: {exc.strerror or exc}", path) from None
    # line by line: the POINTS2D lines make images.txt as large as the survey's tie points
    with handle:
        for lineno, line in bounded_lines(handle, path, "images file"):
            if not expect_pose:  # the POINTS2D line that follows every pose line (may be empty), as COLMAP reads it
                if (problem := _points2d_problem(line)) is not None:
                    raise InputError(problem, path, lineno)
                expect_pose = True
                continue
            if line.startswith("#"):
                continue
            parts = line.split()
            if not parts:
                continue
            if len(parts) < 10:
                raise InputError(f"expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {len(parts)} fields",
                                 path, lineno)
            try:
                values = [float(v) for v in parts[1:8]]
                cam_id = int(parts[8])
            except ValueError:
                raise InputError(f"non-numeric pose value in {parts[1:9]}", path, lineno) from None
            if not all(math.isfinite(v) for v in values):
                raise InputError("NaN or infinite pose value", path, lineno)
            norm = math.sqrt(sum(v * v for v in values[:4]))
            if abs(norm - 1.0) > UNIT_QUAT_TOLERANCE:
                raise InputError(f"quaternion is not unit length (norm {norm:.6f})", path, lineno)
            name = " ".join(parts[9:])
            if name in seen:
                raise InputError(f"duplicate image name {name!r}", path, lineno)
            seen.add(name)
            names.append(name)
            quats.append(values[:4])
            trans.append(values[4:])
            cam_ids.append(cam_id)
            expect_pose = False
    return names, np.array(quats).reshape(-1, 4), np.array(trans).reshape(-1, 3), cam_ids


def _pycolmap_problem(exc: Exception) -> str:
    """pycolmap's error in words a user can act on (its own text, e.g. `unordered_map::at`, kept in brackets)."""
    text = str(exc).strip().splitlines()
    first = text[-1] if text else type(exc).__name__
    if "unordered_map" in first:
        return f"an id in one file refers to a record missing from another (pycolmap: {first})"
    return f"pycolmap: {first}"


_TEXT_COUNT = re.compile(r"^#\s*Number of [A-Za-z0-9 ]+:\s*(\d+)")


def _check_text_model_file(path: Path, lines_per_record: int) -> None:
    """A COLMAP text file that is complete: it ends with a line end and holds as many records as its
    `# Number of ...: N` header says (COLMAP writes one; a file without it is not counted). pycolmap reads a file
    cut inside a line as far as it goes: a points3D.txt truncated at 700 bytes gave 4 of 42 landmarks and a
    'no match' with exit 0."""
    declared, records = None, 0
    points2d_due = False  # images.txt: the line after an image line is its POINTS2D line, even when empty
    last = ""
    try:
        handle = io.TextIOWrapper(open_without_waiting(path), encoding="utf-8-sig")  # a BOM is not text
    except OSError as exc:
        raise InputError(f"cannot read {path.name}: {exc.strerror or exc}", path) from None
    with handle:
        for lineno, line in bounded_lines(handle, path, path.name):
            if points2d_due:
                if (problem := _points2d_problem(line)) is not None:
                    raise InputError(problem, path, lineno)
                points2d_due = False
                records += 1
                continue
            if line.startswith("#"):
                if declared is None and (m := _TEXT_COUNT.match(line)):
                    declared = int(m.group(1))
                continue
            # where a record is due COLMAP skips blank and white-space lines (a model with blank lines between its
            # records was refused as truncated)
            if line.strip():
                records += 1
                points2d_due = lines_per_record > 1
    with open(path, "rb") as raw:
        if raw.seek(0, 2):
            raw.seek(-1, 2)
            last = raw.read(1).decode("latin-1")
    if last not in ("", "\n"):
        raise InputError("file ends inside a line: truncated (an interrupted copy?)", path)
    if points2d_due:  # pycolmap drops that last image without a word
        raise InputError("file ends with an image line without its POINTS2D line: truncated (an interrupted copy?)",
                         path)
    if declared is not None and records != declared * lines_per_record:
        found = records // lines_per_record
        raise InputError(f"file says it holds {declared} records but holds {found}: truncated or edited", path)


def load_reconstruction(model_dir: str | Path) -> pycolmap.Reconstruction:
    """The one way sosmatch opens a COLMAP model directory (binary or text).

    A binary model is first walked by `colmap_binary.check_binary_model` (counts against file sizes, ids
    against the records they refer to), so pycolmap never allocates beyond the files' size nor fails inside;
    whatever pycolmap still refuses is an InputError naming the directory."""
    import pycolmap

    d = Path(model_dir)
    if not d.is_dir():
        raise InputError("COLMAP model directory not found", d)
    if all((d / f"{n}.bin").is_file() for n in MODEL_FILES):  # pycolmap reads the binary files when present
        check_binary_model(d)
    elif not all((d / f"{n}.txt").is_file() for n in MODEL_FILES):
        raise InputError("incomplete COLMAP model: need cameras, images and points3D (.bin or .txt)", d)
    else:
        for name in MODEL_FILES:
            _check_text_model_file(d / f"{name}.txt", 2 if name == "images" else 1)
    try:
        return pycolmap.Reconstruction(str(d))
    except Exception as exc:  # noqa: BLE001 (pycolmap raises plain RuntimeError / ValueError / IndexError)
        raise InputError(f"cannot read COLMAP model: {_pycolmap_problem(exc)}", d) from None


def read_colmap_model_poses(path: str | Path) -> tuple[Poses, dict[int, Camera], dict[str, int]]:
    """Poses and cameras of a COLMAP model.

    Returns (Poses in world_from_camera form, sorted by image name; {camera_id: Camera}; {image name:
    camera_id}). Only registered images with a pose are returned.
    """
    d = model_dir_of(path)
    if not is_colmap_model(d):
        raise InputError("not a COLMAP model directory (no images.bin or images.txt)", d)
    complete = all((d / f"{n}.bin").is_file() for n in MODEL_FILES) or all(
        (d / f"{n}.txt").is_file() for n in MODEL_FILES
    )
    if not complete and (d / "images.txt").is_file() and (d / "cameras.txt").is_file():
        names, quats, trans, cam_ids = _read_images_txt(d / "images.txt")
        cameras = read_cameras_txt(d / "cameras.txt")
        missing = sorted(set(cam_ids) - set(cameras))
        if missing:
            raise InputError(f"images refer to camera id(s) {missing} missing from cameras.txt", d / "images.txt")
        r_cw = quat_to_rotmat(quats) if len(quats) else np.zeros((0, 3, 3))
        order = np.argsort(names, kind="stable")
        poses = Poses.from_cam_from_world([names[i] for i in order], r_cw[order], trans[order])
        return poses, cameras, dict(zip(names, cam_ids))
    if not complete:
        raise InputError("incomplete COLMAP model: need cameras, images and points3D (.bin or .txt), or "
                         "cameras.txt + images.txt", d)
    rec = load_reconstruction(d)
    cameras = {int(cid): camera_from_pycolmap(cam, d) for cid, cam in rec.cameras.items()}
    items = sorted(((img.name, iid) for iid, img in rec.images.items() if img.has_pose), key=lambda t: t[0])
    names, r_list, t_list, cam_of = [], [], [], {}
    for name, iid in items:
        img = rec.images[iid]
        pose = img.cam_from_world()
        r = np.asarray(pose.rotation.matrix(), dtype=np.float64)
        t = np.asarray(pose.translation, dtype=np.float64)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
            raise InputError(f"NaN or infinite pose value for image {name!r}", d)
        names.append(name)
        r_list.append(r)
        t_list.append(t)
        cam_of[name] = int(img.camera_id)
    poses = Poses.from_cam_from_world(names, np.array(r_list).reshape(-1, 3, 3), np.array(t_list).reshape(-1, 3))
    return poses, cameras, cam_of


def read_camera_file(path: str | Path) -> Camera:
    """The one camera of a cameras.txt / cameras.bin file or a COLMAP model directory."""
    path = Path(path)
    if path.is_dir() or path.suffix == ".bin":
        d = path if path.is_dir() else path.parent
        if (d / "cameras.txt").is_file() and not (d / "cameras.bin").is_file():
            cameras = read_cameras_txt(d / "cameras.txt")
        else:
            _, cameras, _ = read_colmap_model_poses(d)
    else:
        cameras = read_cameras_txt(path)
    # copies of one camera, one per image (COLMAP's and hloc's default), are that camera
    distinct = distinct_cameras(list(cameras.values()))
    if len(distinct) != 1:
        raise InputError(f"expected one camera, found {len(distinct)} different ones among {len(cameras)} "
                         f"(ids {sorted(cameras)[:8]}{' ...' if len(cameras) > 8 else ''})", path)
    return distinct[0]


# COLMAP's text files that hold image names between blanks, and what a name with a blank does there
TEXT_MODEL = ("a COLMAP text model (images.txt ends a name at its first blank; the model would read back with wrong "
              "names)")
PAIR_LIST = ("COLMAP's list of image pairs to match (pairs.txt ends a name at its first blank: COLMAP finds no such "
             "image and matches no pair)")


def colmap_text_name_problem(names: Sequence[str], listing: str) -> tuple[int, str] | None:
    """(index, why) of the first image name that `listing` (TEXT_MODEL, PAIR_LIST) cannot hold, or None when it
    holds them all: COLMAP reads a name there up to its first blank. pycolmap read a text model of `DJI 00000.jpg`
    ... back as 40 images all named 'DJI' (and `changes` then found none of them in the database); matching a
    pair list of them matched nothing. The binary model and the database keep any name."""
    for i, name in enumerate(names):
        if any(c.isspace() for c in name):
            return i, f"image name {name!r} holds white space, which {listing} cannot hold"
    return None


def refuse_names_colmap_cannot_hold(image_paths: Sequence[Path], listing: str, remedy: str) -> None:
    """InputError naming the first image whose file name `listing` (TEXT_MODEL, PAIR_LIST) cannot hold
    (`colmap_text_name_problem`), with `remedy`: the commands that would write such a file refuse it before any
    work."""
    if (problem := colmap_text_name_problem([Path(p).name for p in image_paths], listing)) is not None:
        raise InputError(f"{problem[1]}: {remedy}", image_paths[problem[0]])


def write_model(rec: pycolmap.Reconstruction, out_dir: str | Path, text: bool = False) -> None:
    """Write a pycolmap Reconstruction atomically as a COLMAP model directory (binary, or text if asked).
    ValueError for a text model of names it cannot hold (`colmap_text_name_problem`: callers refuse them first)."""
    names = [im.name for im in rec.images.values()]
    if text and (problem := colmap_text_name_problem(names, TEXT_MODEL)) is not None:
        raise ValueError(problem[1])
    with atomic_path(out_dir) as tmp:
        tmp.mkdir(parents=True)
        if text:
            rec.write_text(str(tmp))
        else:
            rec.write_binary(str(tmp))


def encode_ply(points_local: np.ndarray, sizes: np.ndarray, origin: np.ndarray, epsg: int = 0) -> bytes:
    """Binary little-endian PLY of landmarks: float32 x, y, z (relative to `origin`), float32 size_m.

    The origin and CRS are recorded as header comments so the world coordinates can be restored exactly.
    """
    pts = np.asarray(points_local, dtype=np.float64).reshape(-1, 3)
    sizes = np.asarray(sizes, dtype=np.float64).reshape(-1)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment sosmatch landmarks; world = vertex + origin\n"
        f"comment origin {float(origin[0])!r} {float(origin[1])!r} {float(origin[2])!r}\n"
        f"comment crs {f'EPSG:{epsg}' if epsg else 'local'}\n"
        f"element vertex {len(pts)}\n"
        "property float x\nproperty float y\nproperty float z\nproperty float size_m\nend_header\n"
    )
    rec = np.zeros(len(pts), dtype=[("xyz", "<f4", (3,)), ("size", "<f4")])
    rec["xyz"] = pts
    rec["size"] = sizes
    return header.encode("ascii") + rec.tobytes()


def write_ply(path: str | Path, points_local: np.ndarray, sizes: np.ndarray, origin: np.ndarray,
              epsg: int = 0) -> None:
    """Write `encode_ply(...)` atomically."""
    write_bytes_atomic(path, encode_ply(points_local, sizes, origin, epsg))
