"""Cameras in and out: COLMAP text cameras files (`cameras.txt`) and pycolmap cameras, any COLMAP model.

One validation (`camera_from_colmap`) serves the text reader, the pycolmap reader (cameras.bin, models) and
every writer's input: a known perspective or fisheye model (`plugin.camera_models`; the spherical EQUIRECTANGULAR
is refused), COLMAP's parameter count, positive size and focal lengths, finite parameters, a distortion that does
not fold the image over (`Camera.lens_folds`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..plugin.errors import InputError
from ..plugin.geometry import Camera
from .atomic import write_text_atomic
from .text_input import read_user_text

if TYPE_CHECKING:
    import pycolmap

MAX_IMAGE_SIDE = 1_000_000  # pixels: no camera has a longer side


def camera_from_colmap(model: str, width: int, height: int, params: Sequence[float],
                       source: str | Path | None = None, line: int | None = None) -> Camera:
    """A Camera from COLMAP's model name, size and parameter list; InputError (naming `source`) if invalid."""
    try:
        camera = Camera.from_colmap(model, width, height, params)
    except ValueError as exc:
        raise InputError(str(exc), source, line) from None
    if camera.width <= 0 or camera.height <= 0 or camera.fx <= 0 or camera.fy <= 0:
        raise InputError("camera size and focal length must be positive", source, line)
    if max(camera.width, camera.height) > MAX_IMAGE_SIDE:
        raise InputError(f"camera size {camera.width}x{camera.height} is beyond {MAX_IMAGE_SIDE} pixels", source, line)
    if not all(math.isfinite(p) for p in camera.params):
        raise InputError("NaN or infinite camera parameter", source, line)
    if camera.lens_folds():  # no pixel-to-ray map exists: mapping would fail deep inside (a LinAlgError)
        raise InputError(f"the {camera.model} distortion {list(camera.extra)} folds the image over (pixels inside "
                         f"the {camera.width}x{camera.height} sensor do not lift to one ray each): a wrong sign or "
                         "scale of the distortion parameters?", source, line)
    return camera


def read_cameras_txt(path: str | Path) -> dict[int, Camera]:
    """Cameras of a COLMAP cameras.txt: {camera_id: Camera}, any perspective or fisheye COLMAP model."""
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
        if cam_id in cameras:
            raise InputError(f"duplicate camera id {cam_id}", path, lineno)
        if not 0 <= cam_id < 2**32:
            raise InputError(f"camera id {cam_id} is not a COLMAP camera id (0..2^32-1)", path, lineno)
        cameras[cam_id] = camera_from_colmap(model, width, height, params, path, lineno)
    if not cameras:
        raise InputError("no camera in file", path)
    return cameras


def format_cameras_txt(cameras: dict[int, Camera]) -> str:
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(cameras)}"]
    for cam_id, c in sorted(cameras.items()):
        lines.append(f"{cam_id} {c.model} {c.width} {c.height} " + " ".join(repr(p) for p in c.params))
    return "\n".join(lines) + "\n"


def write_cameras_txt(path: str | Path, cameras: dict[int, Camera]) -> None:
    write_text_atomic(path, format_cameras_txt(cameras))


def pycolmap_camera(camera: Camera, camera_id: int = 1) -> pycolmap.Camera:
    """The pycolmap Camera of the same model and parameters (for databases and reconstructions)."""
    import pycolmap

    return pycolmap.Camera(camera_id=int(camera_id), model=camera.model, width=int(camera.width),
                           height=int(camera.height), params=camera.params)


def camera_from_pycolmap(cam: pycolmap.Camera, source: str | Path | None = None) -> Camera:
    """A Camera from a pycolmap Camera (cameras.bin, a model), validated like a cameras.txt line."""
    model = cam.model.name if hasattr(cam.model, "name") else str(cam.model)
    return camera_from_colmap(model, int(cam.width), int(cam.height), [float(v) for v in cam.params], source)


# parameters equal within this relative difference are one camera: COLMAP and hloc write one camera per image
# unless told to share them, each a copy of the same intrinsics, and a float round trip (text, binary, another
# tool's JSON) may change the last digit; a real second camera differs by far more (a focal 0.1 % apart is ~1e-3)
SAME_CAMERA_REL_TOL = 1e-9


def same_camera(a: Camera, b: Camera, rel_tol: float = SAME_CAMERA_REL_TOL) -> bool:
    """Whether two cameras are one: the same model and size, and parameters equal within `rel_tol`."""
    return (a.model == b.model and a.width == b.width and a.height == b.height
            and all(math.isclose(p, q, rel_tol=rel_tol, abs_tol=1e-12) for p, q in zip(a.params, b.params)))


def distinct_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    """The cameras that differ (`same_camera`), in the order first met."""
    distinct: list[Camera] = []
    for cam in cameras:
        if not any(same_camera(cam, d) for d in distinct):
            distinct.append(cam)
    return distinct


def one_camera(cameras: dict, source: str | Path | None) -> Camera | None:
    """The one camera of `cameras` (None when empty): copies of one camera (one per image, as COLMAP's and hloc's
    default writes them) are that camera. InputError naming `source` when they really differ (images of two sizes,
    two drones): a map is made from one camera's images."""
    distinct = distinct_cameras(list(cameras.values()))
    if len(distinct) > 1:
        sizes = sorted({f"{c.width}x{c.height}" for c in distinct})
        raise InputError(f"holds {len(distinct)} different cameras (of {len(cameras)}; sizes {', '.join(sizes)}): a "
                         "map is made from one camera's images: map each camera's images on their own, or give "
                         "--camera when one camera took them all", source)
    return distinct[0] if distinct else None
