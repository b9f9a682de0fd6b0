"""A structural check of COLMAP binary models (cameras, rigs, frames, images, points3D .bin) before pycolmap
reads them.

pycolmap trusts every count in a binary model: a random-bytes points3D.bin claims ~10^18 points and makes it
allocate until the kernel kills the process, and a model whose images refer to a missing camera or frame fails
deep inside with `unordered_map::at`. `check_binary_model` walks each file once (struct, no allocation beyond
the file's own size), checks every count against the bytes left, every id against the records it refers to,
and that each file ends where its last record does; any defect is an InputError naming the file and the record.
Layouts: COLMAP's src/colmap/scene/reconstruction_io_binary.cc (little-endian; ids uint32, point3D ids uint64).
"""

from __future__ import annotations

import math
import mmap
import os
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path

from ..plugin.camera_models import CAMERA_MODELS
from ..plugin.errors import InputError
from .cameras import MAX_IMAGE_SIDE
from .text_input import open_without_waiting

INVALID_POINT3D_ID = 2**64 - 1
SENSOR_CAMERA, SENSOR_IMU = 0, 1
_PARAMS_OF_MODEL = {m.model_id: m.num_params for m in CAMERA_MODELS.values()}


class _Reader:
    """Sequential little-endian reads of one file that refuse to run past its end."""

    def __init__(self, data: bytes | mmap.mmap, path: Path) -> None:
        self.data, self.path, self.pos = data, path, 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def read(self, fmt: str, what: str) -> tuple:
        s = struct.calcsize("<" + fmt)
        if s > self.left():
            raise InputError(f"COLMAP model file is truncated (in {what}, byte {self.pos})", self.path)
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += s
        return values

    def count(self, fmt: str, min_record: int, what: str) -> int:
        (n,) = self.read(fmt, f"the number of {what}")
        if n * min_record > self.left():
            raise InputError(f"COLMAP model file claims {n} {what}, more than its {len(self.data)} bytes can hold "
                             "(corrupt)", self.path)
        return n

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"COLMAP model file is truncated (in {what}, byte {self.pos})", self.path)
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{what} has a name that is not UTF-8 text", self.path) from None

    def done(self) -> None:
        if self.left():
            raise InputError(f"COLMAP model file has {self.left()} bytes after its last record (corrupt)", self.path)


def _finite(values: tuple, what: str, path: Path) -> None:
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{what} holds NaN or infinite values", path)


def _unit_quaternion(q: tuple, what: str, path: Path) -> None:
    _finite(q, what, path)
    if abs(math.sqrt(sum(v * v for v in q[:4])) - 1.0) > 1e-3:
        raise InputError(f"{what} has a rotation quaternion that is not unit length", path)


def _read(path: Path) -> _Reader:
    """The file mapped into memory, not read: a model's points3D.bin and images.bin grow with the survey (GBs for
    large ones) and the walk touches each byte once, so the pages it needs come and go (bounded memory)."""
    try:
        with open_without_waiting(path) as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                raise InputError("COLMAP model file is not a regular file", path)
            if os.fstat(handle.fileno()).st_size == 0:
                return _Reader(b"", path)
            return _Reader(mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ), path)
    except OSError as exc:
        raise InputError(f"cannot read COLMAP model file: {exc.strerror or exc}", path) from None


@dataclass
class BinaryModelSummary:
    """What the check found: record counts (for messages and tests)."""

    cameras: int = 0
    images: int = 0
    points3D: int = 0
    rigs: int | None = None  # None: no rigs.bin (a COLMAP 3.x model)
    frames: int | None = None
    num_points2D: dict[int, int] = field(default_factory=dict)


def check_binary_model(model_dir: str | Path) -> BinaryModelSummary:
    """Walk the binary model in `model_dir` (see the module doc); InputError on the first defect."""
    d = Path(model_dir)
    out = BinaryModelSummary()
    cameras = _check_cameras(d / "cameras.bin")
    out.cameras = len(cameras)
    rigs: set[int] | None = None
    image_frame: dict[int, int] | None = None
    if (d / "rigs.bin").is_file() or (d / "frames.bin").is_file():
        if not ((d / "rigs.bin").is_file() and (d / "frames.bin").is_file()):
            raise InputError("COLMAP model has only one of rigs.bin and frames.bin", d)
        rigs = _check_rigs(d / "rigs.bin", cameras)
        image_frame = _check_frames(d / "frames.bin", rigs)
        out.rigs, out.frames = len(rigs), len(set(image_frame.values()))
    points2d, refs = _check_images(d / "images.bin", cameras, image_frame)
    out.images, out.num_points2D = len(points2d), points2d
    out.points3D = _check_points3d(d / "points3D.bin", points2d, refs, d / "images.bin")
    return out


def _check_cameras(path: Path) -> set[int]:
    r = _read(path)
    ids: set[int] = set()
    for k in range(r.count("Q", 4 + 4 + 16 + 8, "cameras")):
        cid, model_id, width, height = r.read("IiQQ", f"camera {k}")
        if model_id not in _PARAMS_OF_MODEL:
            raise InputError(f"camera {cid} has unknown camera model id {model_id}", path)
        params = r.read(f"{_PARAMS_OF_MODEL[model_id]}d", f"camera {cid}")
        _finite(params, f"camera {cid}", path)
        if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
            raise InputError(f"camera {cid} has an image size of {width}x{height}", path)
        if cid in ids:
            raise InputError(f"camera id {cid} appears twice", path)
        ids.add(cid)
    r.done()
    return ids


def _check_rigs(path: Path, cameras: set[int]) -> set[int]:
    r = _read(path)
    ids: set[int] = set()
    for k in range(r.count("Q", 8, "rigs")):
        rid, num_sensors = r.read("II", f"rig {k}")
        if num_sensors * 8 > r.left():
            raise InputError(f"rig {rid} claims {num_sensors} sensors, more than the file holds", path)
        for j in range(num_sensors):
            stype, sid = r.read("iI", f"rig {rid}")
            if j > 0:
                (has_pose,) = r.read("B", f"rig {rid}")
                if has_pose:
                    _unit_quaternion(r.read("7d", f"rig {rid}"), f"rig {rid} sensor pose", path)
            if stype not in (SENSOR_CAMERA, SENSOR_IMU):
                raise InputError(f"rig {rid} has a sensor of unknown type {stype}", path)
            if stype == SENSOR_CAMERA and sid not in cameras:
                raise InputError(f"rig {rid} refers to camera {sid}, which cameras.bin does not hold", path)
        if rid in ids:
            raise InputError(f"rig id {rid} appears twice", path)
        ids.add(rid)
    r.done()
    return ids


def _check_frames(path: Path, rigs: set[int]) -> dict[int, int]:
    r = _read(path)
    image_frame: dict[int, int] = {}
    frames: set[int] = set()
    for k in range(r.count("Q", 8 + 56 + 4, "frames")):
        fid, rid = r.read("II", f"frame {k}")
        _unit_quaternion(r.read("7d", f"frame {fid}"), f"frame {fid}", path)
        if rid not in rigs:
            raise InputError(f"frame {fid} refers to rig {rid}, which rigs.bin does not hold", path)
        (num_data,) = r.read("I", f"frame {fid}")
        if num_data * 16 > r.left():
            raise InputError(f"frame {fid} claims {num_data} data ids, more than the file holds", path)
        for _ in range(num_data):
            stype, _sid, data_id = r.read("iIQ", f"frame {fid}")
            if stype == SENSOR_CAMERA:
                if data_id in image_frame:
                    raise InputError(f"image {data_id} belongs to two frames", path)
                image_frame[data_id] = fid
        if fid in frames:
            raise InputError(f"frame id {fid} appears twice", path)
        frames.add(fid)
    r.done()
    return image_frame


def _check_images(path: Path, cameras: set[int], image_frame: dict[int, int] | None
                  ) -> tuple[dict[int, int], dict[tuple[int, int], int]]:
    r = _read(path)
    points2d: dict[int, int] = {}
    refs: dict[tuple[int, int], int] = {}  # (image id, point2D index) -> point3D id
    names: set[str] = set()
    for k in range(r.count("Q", 4 + 56 + 4 + 1 + 8, "images")):
        (iid,) = r.read("I", f"image {k}")
        _unit_quaternion(r.read("7d", f"image {iid}"), f"image {iid}", path)
        (cid,) = r.read("I", f"image {iid}")
        name = r.name(f"image {iid}")
        if cid not in cameras:
            raise InputError(f"image {iid} ({name}) refers to camera {cid}, which cameras.bin does not hold", path)
        if image_frame is not None and iid not in image_frame:
            raise InputError(f"image {iid} ({name}) belongs to no frame of frames.bin", path)
        if iid in points2d or name in names:
            raise InputError(f"image id {iid} or name {name!r} appears twice", path)
        n = r.count("Q", 24, f"points of image {iid}")
        for j in range(n):
            x, y, pid = r.read("ddQ", f"image {iid}")
            if not (math.isfinite(x) and math.isfinite(y)):
                raise InputError(f"image {iid} ({name}) holds a non-finite keypoint", path)
            if pid != INVALID_POINT3D_ID:
                refs[(iid, j)] = pid
        points2d[iid] = n
        names.add(name)
    r.done()
    return points2d, refs


def _check_points3d(path: Path, points2d: dict[int, int], refs: dict[tuple[int, int], int],
                    images_path: Path) -> int:
    r = _read(path)
    ids: set[int] = set()
    n = r.count("Q", 8 + 24 + 3 + 8 + 8, "points")
    for k in range(n):
        (pid,) = r.read("Q", f"point {k}")
        xyz = r.read("3d", f"point {pid}")
        r.read("3Bd", f"point {pid}")  # colour, reprojection error
        _finite(xyz, f"point {pid}", path)
        length = r.count("Q", 8, f"track elements of point {pid}")
        for _ in range(length):
            iid, idx = r.read("II", f"point {pid}")
            if idx >= points2d.get(iid, 0):
                raise InputError(f"point {pid} is observed by image {iid}, keypoint {idx}, which images.bin does "
                                 "not hold", path)
        if pid in ids or pid == INVALID_POINT3D_ID:
            raise InputError(f"point id {pid} appears twice (or is the invalid id)", path)
        ids.add(pid)
    r.done()
    missing = {p for p in refs.values() if p not in ids}
    if missing:
        raise InputError(f"images refer to {len(missing)} point(s) that points3D.bin does not hold (e.g. "
                         f"{min(missing)})", images_path)
    return n
