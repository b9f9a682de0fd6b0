"""Cameras in and out: COLMAP text cameras files (`cameras.txt`) and pycolmap cameras, any COLMAP model.

One validation (`camera_from_colmap`) serves the text reader, the pycolmap reader (cameras.bin, models) and
every writer's input: a known perspective or fisheye model (`plugin.camera_models`; the spherical EQUIRECTANGULAR
is refused), COLMAP's parameter count, finite parameters (the one not finite named), positive size and focal
lengths, a principal point on the image, a distortion that does not fold the image over (`Camera.lens_folds`).
Errors name the file, its line and the camera id. One decision (`camera_for_image_files`) fits a camera to the
images it maps: images of one size only (else the odd one is named), that of the camera or a resize of its frame
(rescaled, as COLMAP does), else refused naming the cameras file.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..plugin.camera_models import camera_model
from ..plugin.errors import InputError
from ..plugin.geometry import Camera
from .atomic import write_text_atomic
from .text_input import read_user_text

if TYPE_CHECKING:
    import pycolmap

log = logging.getLogger(__name__)

MAX_IMAGE_SIDE = 1_000_000  # pixels: no camera has a longer side


def camera_from_colmap(model: str, width: int, height: int, params: Sequence[float],
                       source: str | Path | None = None, line: int | None = None,
                       camera_id: int | None = None) -> Camera:
    """A Camera from COLMAP's model name, size and parameter list; InputError (naming `source` and `camera_id`)
    if invalid."""
    who = f"camera {camera_id}: " if camera_id is not None else ""
    try:
        spec = camera_model(model)
        p = [float(v) for v in params]
        if len(p) == spec.num_params:
            # before anything compares them: a NaN focal length read "one focal length, got fx=nan fy=nan"
            bad = next(((name, v) for name, v in zip(spec.param_names, p) if not math.isfinite(v)), None)
            if bad is not None:
                raise InputError(f"{who}the {model} parameter {bad[0]} is {bad[1]}, not a finite number", source,
                                 line)
        camera = Camera.from_colmap(model, width, height, p)
    except ValueError as exc:
        raise InputError(f"{who}{exc}", source, line) from None
    if camera.width <= 0 or camera.height <= 0 or camera.fx <= 0 or camera.fy <= 0:
        raise InputError(f"{who}camera size and focal length must be positive", source, line)
    if max(camera.width, camera.height) > MAX_IMAGE_SIDE:
        raise InputError(f"{who}camera size {camera.width}x{camera.height} is beyond {MAX_IMAGE_SIDE} pixels", source,
                         line)
    if not (0.0 <= camera.cx <= camera.width and 0.0 <= camera.cy <= camera.height):
        # COLMAP takes any principal point, but a calibration's lies on its image (a crop's far off the centre,
        # still on it): outside, the run failed later blaming the GPS, the mounting or the distortion (nu50)
        raise InputError(f"{who}the principal point ({camera.cx:g}, {camera.cy:g}) lies outside the "
                         f"{camera.width}x{camera.height} image (COLMAP pixels span 0..{camera.width}, "
                         f"0..{camera.height}): parameters of another image size, or in another order?", source, line)
    if camera.lens_folds():  # no pixel-to-ray map exists: mapping would fail deep inside (a LinAlgError)
        raise InputError(f"{who}the {camera.model} distortion {list(camera.extra)} folds the image over (pixels "
                         f"inside the {camera.width}x{camera.height} sensor do not lift to one ray each): a wrong "
                         "sign or scale of the distortion parameters?", source, line)
    return camera


# How far (a share of the side) a principal point may lie from its frame's centre for the frame to be taken as the
# full frame of the images at another resolution: real lenses' lie within a few per cent of it; a file whose size
# was edited without its parameters (640x480 around a 320x240 calibration) has its pp 25 % off (nu50)
RESCALE_MAX_PP_OFFSET = 0.10


def _resize_of(w0: int, h0: int, width: int, height: int) -> bool:
    """Whether `width` x `height` is `w0` x `h0` resized: a scale s with |w0 s - width| <= 1 and |h0 s - height|
    <= 1 (each side rounded or floored on its own; a crop of a pixel row more is not)."""
    return max((width - 1) / w0, (height - 1) / h0) <= min((width + 1) / w0, (height + 1) / h0)


def camera_for_images(camera: Camera, width: int, height: int, source: str | Path | None,
                      what: str = "the camera") -> Camera:
    """`camera` in pixels of the `width` x `height` images it is to map: itself when the sizes agree; rescaled
    (`Camera.resized`, as COLMAP's `Camera::Rescale`; one warning line) when the images are a resize of its frame,
    the same aspect within each side's rounding to whole pixels, and its principal point near the frame's centre
    (`RESCALE_MAX_PP_OFFSET`): a calibration of the full-resolution images, the images downscaled. Otherwise an
    InputError naming `source` (the cameras file) and `what`: a crop, or a frame turned by 90 degrees, whose
    principal point no scale gives. Given the images' files, `camera_for_image_files` decides their size and
    calls this."""
    w0, h0 = camera.width, camera.height
    if (width, height) == (w0, h0):
        return camera
    if not _resize_of(w0, h0, width, height):
        turned = " (turned by 90 degrees against it)" if _resize_of(h0, w0, width, height) else ""
        raise InputError(f"{what} is {w0}x{h0} but the images are {width}x{height}{turned}: another aspect ratio, "
                         "so neither these images' calibration nor theirs at another resolution (that is rescaled); "
                         "cropped from the calibrated frame? A crop moves the principal point by an unknown amount: "
                         "give the calibration of these images", source)
    off = max(abs(camera.cx / w0 - 0.5), abs(camera.cy / h0 - 0.5))
    if off > RESCALE_MAX_PP_OFFSET:
        raise InputError(f"{what} is {w0}x{h0} with its principal point ({camera.cx:g}, {camera.cy:g}) "
                         f"{100 * off:.0f} % of the frame off its centre, and the images are {width}x{height}: not "
                         "taken for a calibration of these images at another resolution (its size edited without "
                         "its parameters? a crop's calibration?); give the calibration of these images", source)
    log.warning("%s: %s is %dx%d, the images %dx%d: taken as its calibration of the images at another resolution "
                "and rescaled x%.4g (focal length, principal point; the distortion coefficients stay)", source, what,
                w0, h0, width, height, width / w0)
    return camera.resized(width, height)


def camera_for_image_files(camera: Camera, paths: Sequence[str | Path], source: str | Path | None,
                           what: str = "the camera") -> Camera:
    """`camera` fitted (`camera_for_images`) to the size that all of `paths` share, read from every image's header
    (`database.images.image_size`: no decoding, well under a millisecond an image). Images of more than one size
    are an InputError naming the first odd one (against the size most of them have; on a tie, the camera's, else
    the first image's) before any rescale: a camera fitted to the first image's size refused every image that
    matched the cameras file when only the first was odd (rev39). Unreadable images are left out, to be named
    where their pixels are read (the pose check, the keyframes); with none readable `camera` is returned as it
    is. The one decision for every camera met with images (`map`, `check-poses`, an OpenSfM project's cameras)."""
    from .images import image_size

    sizes: dict[Path, tuple[int, int]] = {}
    for p in paths:
        try:
            sizes[Path(p)] = image_size(p)
        except InputError:
            continue
    if not sizes:
        return camera
    counts = Counter(sizes.values())
    if len(counts) == 1:
        return camera_for_images(camera, *next(iter(counts)), source, what)
    own = (camera.width, camera.height)
    top = max(counts.values())
    # most images' size; on a tie the camera's (the calibration the user gave), else the first image's (dicts
    # keep order, so the answer does not depend on a set's order)
    tied = [s for s in dict.fromkeys(sizes.values()) if counts[s] == top]
    usual = own if own in tied else tied[0]
    odd = [p for p, s in sizes.items() if s != usual]
    first = sizes[odd[0]]
    fmt = "{0}x{1}".format
    as_camera = f" (the size of {what} in {source})" if usual == own else ""
    theirs = f" (the size of {what} in {source})" if first == own else ""
    more = ""
    if len(odd) > 1:
        listed = ", ".join(f"{p.name} {fmt(*sizes[p])}" for p in odd[1:9])
        more = f"; {len(odd) - 1} more odd: {listed}" + (" ..." if len(odd) > 9 else "")
    raise InputError(f"image is {fmt(*first)}{theirs} but {counts[usual]} of the {len(sizes)} images are "
                     f"{fmt(*usual)}{as_camera}{more}: a map is made from one camera's images at one size (a "
                     "thumbnail or a re-export among them?); remove or resize the odd image(s)", odd[0])


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
        cameras[cam_id] = camera_from_colmap(model, width, height, params, path, lineno, cam_id)
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
    return camera_from_colmap(model, int(cam.width), int(cam.height), [float(v) for v in cam.params], source,
                              camera_id=int(cam.camera_id))


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
