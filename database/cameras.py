"""COLMAP text cameras files (`cameras.txt`): read one pinhole camera, write one."""

from __future__ import annotations

from pathlib import Path

from ..plugin.errors import InputError
from ..plugin.geometry import Camera
from .atomic import write_text_atomic
from .text_input import read_user_text


def read_cameras_txt(path: str | Path) -> dict[int, Camera]:
    """Cameras of a COLMAP cameras.txt (PINHOLE and SIMPLE_PINHOLE; distortion models are refused)."""
    path = Path(path)
    lines = read_user_text(path, "cameras file").splitlines()
    cameras: dict[int, Camera] = {}
    for lineno, line in enumerate(lines, start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            cam_id, model, width, height = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = [float(p) for p in parts[4:]]
        except (ValueError, IndexError):
            raise InputError("malformed camera line", path, lineno) from None
        if model == "PINHOLE" and len(params) == 4:
            fx, fy, cx, cy = params
        elif model == "SIMPLE_PINHOLE" and len(params) == 3:
            fx, cx, cy = params
            fy = fx
        else:
            raise InputError(f"camera model {model} with {len(params)} parameters is not supported "
                             "(use PINHOLE or SIMPLE_PINHOLE on undistorted images)", path, lineno)
        if width <= 0 or height <= 0 or fx <= 0 or fy <= 0:
            raise InputError("camera size and focal length must be positive", path, lineno)
        cameras[cam_id] = Camera(width, height, fx, fy, cx, cy)
    if not cameras:
        raise InputError("no camera in file", path)
    return cameras


def format_cameras_txt(cameras: dict[int, Camera]) -> str:
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(cameras)}"]
    for cam_id, c in sorted(cameras.items()):
        lines.append(f"{cam_id} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}")
    return "\n".join(lines) + "\n"


def write_cameras_txt(path: str | Path, cameras: dict[int, Camera]) -> None:
    write_text_atomic(path, format_cameras_txt(cameras))
