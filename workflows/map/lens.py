"""The map's lens check: the camera's distortion refit on the map's own observations with the poses fixed
(pycolmap bundle adjustment), judged by `plugin.lens_check` (the method, its significance and its limits)."""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Any

import numpy as np

from ...plugin.geometry import Camera
from ...plugin.lens_check import (
    CHECKED_MODELS,
    LensCheck,
    LensNotChecked,
    jackknife_se,
    judge_lens,
    landmark_groups,
    lens_displacement_px,
    refit_camera,
)
from ...plugin.params import Params

log = logging.getLogger(__name__)
GROUPS = 8  # jackknife blocks: enough for a standard error; 2 + 2 x 8 solves in all
MAX_LANDMARKS = 500  # a larger map is checked on this many landmarks spread over it (the cost stays small)


def _solve(rec: Any, refine_lens: bool, loss_scale_px: float) -> None:
    """Bundle adjustment with every pose constant, the points free, and the lens's distortion free or constant."""
    import pycolmap

    from ..triangulation import fixed_camera_ba_options

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    for frame_id in rec.reg_frame_ids():
        config.set_constant_rig_from_world_pose(frame_id)
    if not refine_lens:
        for camera_id in rec.cameras:
            config.set_constant_cam_intrinsics(camera_id)
    options = fixed_camera_ba_options(pycolmap.LossFunctionType.HUBER, loss_scale_px, refine_poses=False)
    options.refine_extra_params = bool(refine_lens)  # the distortion only: focal length and principal point stay
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()


def _with_camera(rec: Any, camera: Camera, drop: list[int] = ()) -> Any:
    """A copy of `rec` seeing through `camera`, without the points `drop`."""
    from ...database.cameras import pycolmap_camera

    out = type(rec)(rec)
    for camera_id in list(out.cameras):
        out.cameras[camera_id] = pycolmap_camera(camera, camera_id)
    for pid in drop:
        out.delete_point3D(pid)
    return out


def _camera_of(rec: Any, like: Camera) -> Camera:
    cam = next(iter(rec.cameras.values()))
    return Camera.from_colmap(like.model, like.width, like.height, [float(p) for p in cam.params])


def _heights(rec: Any, ids: list[int]) -> np.ndarray:
    return np.array([rec.points3D[i].xyz[2] for i in ids])


def _rms(rec: Any, ids: list[int], loss_scale_px: float) -> float:
    """RMS of the reprojection residuals, each capped at the robust loss's scale x 3 (a few wild ones would
    hide the rest)."""
    err = []
    for pid in ids:
        p = rec.points3D[pid]
        for el in p.track.elements:
            im = rec.images[el.image_id]
            uv = im.project_point(p.xyz)  # through the image's own camera, as `triangulation.mean_reprojection_error`
            err.append(float(np.linalg.norm(np.asarray(uv).ravel() - im.points2D[el.point2D_idx].xy))
                       if uv is not None else np.inf)
    e = np.minimum(np.asarray(err), 3.0 * loss_scale_px)
    return float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")


def check_lens(rec: Any, camera: Camera, camera_file: str, flying_height_m: float, pixel_sigma_px: float,
               groups: int = GROUPS) -> LensCheck | None:
    """The lens check of a map's reconstruction `rec` (its points triangulated through `camera`, the poses
    fixed; it is not changed), or None when the map has too few landmarks for `groups` blocks of them or its
    camera's model is not checked (`plugin.lens_check.CHECKED_MODELS`)."""
    t0 = time.process_time()
    start = refit_camera(camera)
    if start is None:
        return None
    ids = sorted(rec.points3D)
    if len(ids) > MAX_LANDMARKS:  # evenly over the landmark order (flight order), the same on every run
        ids_keep = set(ids[i] for i in np.linspace(0, len(ids) - 1, MAX_LANDMARKS).round().astype(int))
        rec = _with_camera(rec, camera, [p for p in ids if p not in ids_keep])
        ids = sorted(ids_keep)
    if len(ids) < 2 * groups:
        return None
    loss = 2.0 * pixel_sigma_px  # the points-only refinement's Huber scale (`triangulation.refine_points_only`)

    def fit(drop: list[int]) -> tuple[Camera, Any]:
        """The lens fit with the points `drop` left out, and the reconstruction holding the rest at its optimum
        (the points where that lens triangulates them)."""
        part = _with_camera(rec, start, drop)
        _solve(part, True, loss)
        return _camera_of(part, start), part

    # both lenses' heights from the same solve (the map's own points may be placed otherwise: whole masks only)
    given = _with_camera(rec, start)
    _solve(given, False, loss)
    z0 = _heights(given, ids)
    fitted, whole = fit([])
    shift = float(np.median(_heights(whole, ids) - z0))
    block = landmark_groups(len(ids), groups)
    leave_outs = []
    for g in range(groups):
        # every landmark re-triangulated through the lens fit without block g: the scatter is the lens's, not
        # that of which landmarks the median is taken over (on the rest only, a 27-landmark map's forgotten
        # k1 -0.18, refit to -0.176, stood 4.3 standard errors out instead of 24)
        lens, _ = fit([p for p, b in zip(ids, block) if b == g])
        again = _with_camera(rec, lens)
        _solve(again, False, loss)
        leave_outs.append(float(np.median(_heights(again, ids) - z0)))
    return LensCheck(camera_file, camera, fitted, shift, jackknife_se(np.array(leave_outs)), flying_height_m,
                     lens_displacement_px(start, fitted), _rms(given, ids, loss),
                     _rms(whole, ids, loss), len(ids), time.process_time() - t0)


def lens_stage(landmarks: Any, camera: Camera, camera_file: str, flying_height_m: float, params: Params,
               kind: str = "file", poses_fit: bool = True
               ) -> tuple[LensCheck | LensNotChecked | None, list[str], list[str]]:
    """The map's lens check (`check_lens` on the triangulation's reconstruction) and its (warnings, refusals)
    by `plugin.lens_check.judge_lens` at the map's `params.quality` limits (`kind`: where the camera came from;
    `poses_fit`: the pose check found the poses fitting the images); (None, [], []) for a map without the
    landmarks to check it or with the check off (`quality.lens_check`). A check that fails keeps the map: a
    warning and a `LensNotChecked` (rev40: a refit error threw away a finished map with a traceback)."""
    rec = getattr(landmarks, "reconstruction", None)
    if not params.quality.lens_check or rec is None or not len(landmarks):
        return None, [], []
    try:
        check = check_lens(rec, camera, camera_file, flying_height_m, params.triangulation.pixel_sigma_px)
    except Exception as e:  # noqa: BLE001 -- a check, not the map: whatever the refit raises must not lose the map
        failed = LensNotChecked(camera_file, f"{type(e).__name__}: {e}"[:200])
        return failed, [failed.line()], []
    if check is None:
        log.info("the lens is not checked against the images: %s", f"{len(landmarks)} landmarks" if
                 camera.model in CHECKED_MODELS else f"a {camera.model} camera's terms are not fixed by a map")
    else:
        check = replace(check, camera_kind=kind, judged=poses_fit)
    q = params.quality
    warnings, refusals = judge_lens(check, q.lens_shift_margin, q.warn_lens_height_shift, q.max_lens_height_shift,
                                    kind, poses_fit)
    return check, warnings, refusals
