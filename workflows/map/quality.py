"""The map's quality stages: the poses against the images (`workflows.pose_check`, before anything is mapped),
then the map's figures (`plugin.map_quality.assess_map`), verdict (`plugin.map_verdict.judge`) and the picture.

A refused map is still written (so that its picture and run.json can be looked at) but run.json records the
verdict, `sosmatch map` ends with a one-line error and a non-zero exit, and the readers of mapped sessions
(`database.session_io.check_session_usable`: match, merge, batch, export) refuse it.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...database.atomic import atomic_path
from ...plugin.errors import InputError
from ...plugin.geometry import Camera, Poses, pixel_rays
from ...plugin.image_quality import FlightImages
from ...plugin.map_quality import MapQuality, assess_map, isolated_cameras
from ...plugin.map_verdict import Verdict, judge
from ...plugin.params import QualityParams, survey_preset_remedy

if TYPE_CHECKING:
    from ...database.images import Levels

log = logging.getLogger(__name__)
FIGURE = "quality.png"


class MapRefused(InputError):
    """The map was made but its geometry is implausible or it is empty: the inputs (poses, camera) are wrong."""


def pose_check_stage(inputs: Any, params: Any, record: Path, gps: Any = None, white: Levels | int | None = None) -> Any:
    """The poses of `inputs` (MapInputs) checked against its images (`workflows.pose_check.run`, figures written
    to `record`), or None when `pose_check.enabled` is off (`record` then says so, so that no stale figures of
    an earlier run stand beside the map). Never raises on a refusal: its verdict joins the map's (`joined`), so a
    map on poses that contradict the images is refused like an implausible one. `gps`: the comparison with the
    images' GPS already made (`workflow.gps_precheck`); `white`: the flight's white level."""
    from .. import pose_check

    if not params.pose_check.enabled:
        pose_check.write_disabled(record)
        return None

    # `params` are the map's, already scaled to the image (`plugin.params.for_image`): its gate as it is
    return pose_check.run(inputs.image_paths, inputs.poses, inputs.camera, params, record, refuse=False,
                          sources=inputs.sources, gate=params.tracking.epipolar_margin_px, epsg=inputs.epsg,
                          gps=gps, white=white, remedy=inputs.remedy)


def joined(*verdicts: Verdict | None) -> Verdict:
    """One verdict with the refusals and warnings of all (None: a stage that did not run)."""
    out = Verdict()
    for v in verdicts:
        if v is not None:
            out.refusals.extend(v.refusals)
            out.warnings.extend(v.warnings)
    return out


def assess(landmarks: Any, poses: Poses, long_tracks: int, camera: Camera | None = None,
           keypoints: list[np.ndarray] | None = None, limits: QualityParams | None = None) -> MapQuality:
    """The quality figures of triangulated `landmarks` (workflows.triangulation.Landmarks) on keyframe `poses`;
    with the `camera` and the keyframes' `keypoints` (COLMAP pixels, indexed by the observations' mask index) the
    passes' own heights of their common landmarks too (`plugin.pass_heights`)."""
    rays = None
    if camera is not None and keypoints is not None and len(landmarks.observations):
        # one lens call for every observation (per landmark it took 4.7 s on 20k landmarks: rev21), then split
        obs = landmarks.observations
        uv = np.array([keypoints[k][m, :2] for o in obs for k, m in o], np.float64).reshape(-1, 2)
        frames = np.concatenate([o[:, 0] for o in obs]).astype(np.int64)
        world = _world_rays(pixel_rays(camera, uv, np.eye(3)), poses.rotations[frames])
        rays = np.split(world, np.cumsum([len(o) for o in obs])[:-1])
    margin = (limits or QualityParams()).pass_offset_margin
    return assess_map(landmarks.positions, landmarks.sizes_m, landmarks.errors_px,
                      [o[:, 0] for o in landmarks.observations], poses.centers, poses.rotations[:, :, 2],
                      long_tracks, observation_rays=rays, pass_offset_margin=margin)


def _world_rays(cam_rays: np.ndarray, r_wc: np.ndarray) -> np.ndarray:
    """(n, 3) camera-frame rays turned into the world by each observation's (n, 3, 3) world-from-camera rotation."""
    return np.einsum("nij,nj->ni", r_wc, cam_rays)


def quality_stage(
    landmarks: Any, poses: Poses, camera: Camera, image_paths: list[Path], keypoints: list[np.ndarray],
    long_tracks: int, limits: QualityParams, figure: Path | None, title: str = "", min_landmarks: int = 1,
    images_flying_height_m: float = float("nan"), white: Levels | int | None = None, poses_fit: str = "",
    images: FlightImages | None = None, contrast: str = "", min_observations: int = 0,
    views_per_pass: float = float("nan"), params: Any = None, vertical: tuple[str, float] = ("", float("nan")),
) -> tuple[MapQuality, Verdict]:
    """Figures, verdict and (when `figure` is a path) the picture, written atomically. Warnings are logged.
    `images_flying_height_m`: the pose check's (`plugin.map_verdict.judge`); `white`: the flight's white level
    for the picture (`database.flight_levels.flight_white_level`); `poses_fit`, `images`: the pose check's phrase
    when it found the poses fitting, and the keyframes' image figures (`judge`); `contrast`: the flight's low contrast
    as a cause (`FlightContrast.cause`); `min_observations`: the map's theta_n (`judge`); `views_per_pass` (the
    flight's, `plugin.motion.views_per_pass`) and the map's `params`: whether to name the survey preset
    (`plugin.params.survey_preset_remedy`). `vertical`: what the poses' vertical rests on and its sigma
    (`MapInputs.vertical`), recorded with the figures and weighed against the ground's tilt (`judge`)."""
    quality = replace(assess(landmarks, poses, long_tracks, camera, keypoints, limits),
                      vertical_source=vertical[0], vertical_sigma_deg=float(vertical[1]))
    spacing = float(np.median(np.linalg.norm(np.diff(poses.centers, axis=0), axis=1))) if len(poses) > 1 else np.nan
    remedy = survey_preset_remedy(params, views_per_pass, spacing, quality.flying_height_m) if params else ""
    verdict = judge(quality, limits, min_landmarks, images_flying_height_m, poses_fit, images, contrast,
                    min_observations, remedy)
    alone = isolated_cameras(poses.centers, quality.flying_height_m, 0.5 * float(np.hypot(camera.width, camera.height)),
                             float(camera.fx))
    if len(alone):
        names = ", ".join(poses.names[i] for i in alone[:5]) + (", ..." if len(alone) > 5 else "")
        verdict.warnings.append(f"{len(alone)} of {len(poses)} keyframes share no ground with any other (their "
                                f"nearest neighbour lies beyond one image's footprint): wrong positions in the pose "
                                f"file? ({names})")
    for warning in verdict.warnings:
        log.warning("%s: %s", title or "map", warning)
    if figure is not None:
        from .figure import draw_map_figure

        try:
            with atomic_path(figure) as tmp:
                draw_map_figure(tmp, landmarks.positions, landmarks.sizes_m, landmarks.observations, keypoints,
                                poses, camera, image_paths, quality, verdict, title, white)
        except Exception as exc:  # the picture is a help, never a reason to lose the map
            log.warning("could not draw %s: %s", figure, exc)
    return quality, verdict


def verdict_record(verdict: Verdict, enforced: bool) -> dict[str, Any]:
    """run.json's "verdict": status ok / refused / accepted despite refusals (quality.refuse off)."""
    status = "ok" if verdict.ok else ("refused" if enforced else "accepted_despite_refusals")
    return {"status": status, "refusals": list(verdict.refusals), "warnings": list(verdict.warnings)}


def recorded_verdict_warnings(map_dir: str | Path) -> list[str]:
    """What `sosmatch map` warned of in MAP_DIR (run.json's "verdict", written by `verdict_record`): its warnings
    (the poses' among them, "poses: ..."), and each refusal of a map accepted despite them (quality.refuse off),
    for the stages that report on a mapped session (batch). [] for a directory without a record or a verdict (a
    merged model, an older session). InputError naming run.json when the record does not read or its verdict is
    not what `verdict_record` writes (edited by hand)."""
    from ...database.session_io import read_map_record

    verdict = (read_map_record(map_dir) or {}).get("verdict")
    if verdict is None:
        return []
    if not isinstance(verdict, dict) or not all(
            isinstance(v, list) and all(isinstance(t, str) for t in v)
            for v in (verdict.get("warnings", []), verdict.get("refusals", []))):
        raise InputError("session record's verdict is not an object with lists of texts (`warnings`, `refusals`)",
                         Path(map_dir) / "run.json")
    said = list(verdict.get("warnings", []))
    if verdict.get("status") == "accepted_despite_refusals":
        said += [f"accepted although {r} (quality.refuse is off)" for r in verdict.get("refusals", [])]
    return said


def raise_if_refused(verdict: Verdict, limits: QualityParams, out_dir: Path, remedy: str = "") -> None:
    """MapRefused (one line, naming the session) when the verdict refuses the map and refusal is on; `remedy`
    (`MapSummary.remedy`) is said with it."""
    if verdict.ok:
        return
    if not limits.refuse:
        log.warning("%s: accepted although %s (quality.refuse is off)", out_dir, "; ".join(verdict.refusals))
        return
    then = f"; {remedy}" if remedy else ""
    raise MapRefused(f"map refused: {'; '.join(verdict.refusals)}{then} (see {FIGURE} and run.json)", out_dir)
