"""Pose files: the project's pose CSV (read with validation, written atomically).

Format (docs/ARCHITECTURE.md):
    # sosmatch poses v1
    # convention: world_from_camera        (or camera_from_world)
    # crs: local                            (or EPSG:<code>)
    name,x,y,z,qw,qx,qy,qz
Comment lines start with '#'; `key: value` comments set the convention and CRS. Every defect raises
InputError naming the file and line.
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

QUAT_COLUMNS = ["name", "x", "y", "z", "qw", "qx", "qy", "qz"]
CONVENTIONS = ("world_from_camera", "camera_from_world")
UNIT_QUAT_TOLERANCE = 1e-3


def _parse_crs(text: str, path: Path, line: int) -> int:
    text = text.strip()
    if text.lower() == "local":
        return 0
    if text.upper().startswith("EPSG:") and text[5:].isdigit():
        return int(text[5:])
    raise InputError(f"crs must be 'local' or 'EPSG:<code>', got {text!r}", path, line)


def read_poses_csv(path: str | Path, convention: str | None = None) -> tuple[Poses, int]:
    """Read a pose CSV -> (Poses with world_from_camera rotations and centres, EPSG code or 0).

    `convention` overrides the file's `# convention:` comment (a flag wins over the header).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("pose file not found", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read pose file: {exc}", path) from None
    file_convention, epsg = "world_from_camera", 0
    header: list[str] | None = None
    names: list[str] = []
    rows: list[list[float]] = []
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
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
            if header != QUAT_COLUMNS:
                raise InputError(f"header must be {','.join(QUAT_COLUMNS)}, got {','.join(header)}", path, lineno)
            continue
        if len(row) != len(QUAT_COLUMNS):
            raise InputError(f"expected {len(QUAT_COLUMNS)} columns, got {len(row)}", path, lineno)
        try:
            values = [float(v) for v in row[1:]]
        except ValueError:
            raise InputError(f"non-numeric pose value in {row[1:]}", path, lineno) from None
        if not all(math.isfinite(v) for v in values):
            raise InputError("NaN or infinite pose value", path, lineno)
        norm = math.sqrt(sum(v * v for v in values[3:]))
        if abs(norm - 1.0) > UNIT_QUAT_TOLERANCE:
            raise InputError(f"quaternion is not unit length (norm {norm:.6f})", path, lineno)
        name = row[0].strip()
        if name in names:
            raise InputError(f"duplicate image name {name!r}", path, lineno)
        names.append(name)
        rows.append(values)
    if header is None:
        raise InputError("no header line (expected " + ",".join(QUAT_COLUMNS) + ")", path)
    if convention is not None:
        file_convention = convention
    data = np.array(rows, dtype=np.float64).reshape(-1, 7)
    rot = quat_to_rotmat(data[:, 3:]) if len(data) else np.zeros((0, 3, 3))
    if file_convention == "world_from_camera":
        return Poses(names, rot, data[:, :3]), epsg
    return Poses.from_cam_from_world(names, rot, data[:, :3]), epsg


def format_poses_csv(poses: Poses, epsg: int = 0) -> str:
    """The pose CSV text (world_from_camera), full float precision."""
    out = io.StringIO()
    out.write("# sosmatch poses v1\n# convention: world_from_camera\n")
    out.write(f"# crs: {f'EPSG:{epsg}' if epsg else 'local'}\n")
    out.write(",".join(QUAT_COLUMNS) + "\n")
    quats = rotmat_to_quat(poses.rotations) if len(poses) else np.zeros((0, 4))
    for name, c, q in zip(poses.names, poses.centers, quats):
        out.write(name + "," + ",".join(repr(float(v)) for v in (*c, *q)) + "\n")
    return out.getvalue()


def write_poses_csv(path: str | Path, poses: Poses, epsg: int = 0) -> None:
    write_text_atomic(path, format_poses_csv(poses, epsg))
