"""Write one synthetic survey session (images, labels, poses, objects, footprints, terrain) to a directory.

    from sosmatch.workflows.synth import SynthConfig, run
    run("S1", SynthConfig(world_seed=7, season="summer", frames=100))
    run("S2", SynthConfig(world_seed=7, season="winter", shift_m=(20, 10), reverse=True,
                          sun_azimuth_deg=200, session_seed=3))

The session directory (docs/ARCHITECTURE.md, "Synthetic session directory") is built in OUT/.partial and
published at the end (`sosmatch.database.outputs`), so an interrupted run leaves no partial session (its
staging area is cleared by the re-run); re-running the same call produces byte-identical files. Read it back
with `sosmatch.database.synth_session.load_synth_session`.
"""

from __future__ import annotations

import json
import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..database.cameras import write_cameras_txt
from ..database.exif_write import embed_metadata
from ..database.output_markers import fingerprint
from ..database.outputs import OutputDir, open_output_dir
from ..database.poses import write_poses_csv
from ..database.synth_session import (
    OBJECT_DTYPE,
    SESSION_FORMAT,
    SESSION_VERSION,
    TerrainSampler,
    format_objects_csv,
)
from ..plugin import __version__
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..tools.synth.appearance import SEASON_LOOKS, CameraLook, encode_jpeg, finish_image, lighting
from ..tools.synth.config import SynthConfig
from ..tools.synth.flights import ekf_poses, flight_line_ids, flight_poses
from ..tools.synth.geotags import geo_frame, session_geotags
from ..tools.synth.noise import rng_for
from ..tools.synth.render import ViewOutsideWorld, render_view
from ..tools.synth.scene import Scene, build_scene, visible_top_centres
from ..tools.synth.world import EXTRA_FRACTION, World, get_world

__all__ = ["SynthConfig", "run", "session_presence", "session_poses", "session_look", "objects_table"]
log = logging.getLogger(__name__)
_T_PRESENCE, _T_LOOK, _T_FRAME = 21, 22, 23


def session_presence(world: World, config: SynthConfig) -> np.ndarray:
    """Which world objects exist in this session: each default object is removed with probability
    `changed_fraction`, each extra object added with the probability that adds as many as are removed (all of
    them once `changed_fraction` reaches the pool's share, `EXTRA_FRACTION`)."""
    rng = rng_for(_T_PRESENCE, config.world_seed, config.session_seed)
    default = np.array([o.default_present for o in world.objects], bool)
    draw = rng.random(len(default))
    p_add = min(1.0, config.changed_fraction / EXTRA_FRACTION)
    return np.where(default, draw >= config.changed_fraction, draw < p_add)


def session_poses(world: World, config: SynthConfig) -> Poses:
    """Ground-truth poses of the session's flight (centred on the world)."""
    centre = (world.config.size_m / 2.0, world.config.size_m / 2.0)
    ground = float(world.terrain_sampler.heights.mean())
    return flight_poses(config.flight_config(), centre, ground, config.session_seed, config.world_seed)


def session_look(config: SynthConfig) -> CameraLook:
    """The session's photometric settings (random parts drawn from the session seed)."""
    rng = rng_for(_T_LOOK, config.world_seed, config.session_seed)
    offset = float(rng.normal(0.0, 0.15))
    wb = 1.0 + rng.normal(0.0, 0.035, 3)
    wb = wb / wb[1]
    vignetting = float(rng.uniform(0.15, 0.35))
    ev = SEASON_LOOKS[config.season].exposure_ev + offset if config.exposure_ev is None else config.exposure_ev
    return CameraLook(ev, tuple(float(v) for v in wb), vignetting, config.blur_sigma_px, config.noise_sigma,
                      config.jpeg_quality)


def objects_table(scene: Scene) -> np.ndarray:
    """objects.csv rows (OBJECT_DTYPE) of a session's scene: the centre of the visible top surface
    (`visible_top_centres`), footprint-equivalent radius, height, presence, apex and ground heights."""
    centres = visible_top_centres(scene)
    rows = [(o.id, o.kind, *centres[o.id - 1], o.radius, o.height, bool(p), o.top_z, o.ground_z)
            for o, p in zip(scene.world.objects, scene.present)]
    return np.array(rows, dtype=OBJECT_DTYPE)


def footprint_points_per_side(camera: Camera) -> int:
    """Points per image side of a footprint: the corners of a pinhole image (its border rays meet the ground
    along straight lines), 8 per side through a lens model, whose border rays bend."""
    return 1 if camera.is_pinhole else 8


def _check_inside(world: World, camera: Camera, poses: Poses, tilted: bool = False) -> None:
    """Every image must see only the world: test the border rays at the lowest terrain height. `tilted`: the
    camera looks ahead (`camera_tilt_deg`), which the advice then names too."""
    size = world.config.size_m
    tilt = "/--camera-tilt/--altitude" if tilted else ""
    flat = TerrainSampler(np.full((2, 2), float(world.terrain.min()) - 0.5, np.float32), 0.0, 0.0, size)
    for name, r, c in zip(poses.names, poses.rotations, poses.centers):
        corners = flat.footprint(camera, r, c, footprint_points_per_side(camera))
        if corners.min() < 1.0 or corners.max() > size - 1.0:
            raise InputError(
                f"image {name} would see beyond the {size:g} m world (footprint {corners.min():.0f}.."
                f"{corners.max():.0f} m): reduce --shift/--frames/--line-length{tilt} or enlarge --world-size")


def _encode_png16(labels: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", labels.astype(np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


SESSION_FILES = ("images", "labels", "cameras.txt", "poses.csv", "poses_ekf.csv", "objects.csv", "frames.json",
                 "terrain.npz")
SESSION_RECORD = "session.json"  # published last
# the files of a session (the record last; images/ and labels/ are directory entries): a user's file at one of
# their names is refused when the folder is taken
SESSION_FILE_NAMES = (*(n for n in SESSION_FILES if n not in ("images", "labels")), SESSION_RECORD)


def run(out: str | Path, config: SynthConfig, progress: bool = False, workers: int | None = None,
        overwrite: bool = False) -> dict[str, Any]:
    """Render one session into directory `out`. Returns a summary.

    The session is built in OUT/.partial and published at the end (session.json last); `out` is taken through
    `sosmatch.database.outputs`: a session rendered with another configuration is replaced only with
    `overwrite`, anything not made by `sosmatch synth` never. `workers` threads render frames concurrently
    (default: the number of CPU cores, at most 4); the files do not depend on it."""
    config.validate()
    out = Path(out)
    with open_output_dir(out, "synth", fingerprint(config.to_dict()), overwrite=overwrite,
                         legacy_record=SESSION_RECORD, files=SESSION_FILE_NAMES) as taken:
        taken.clear_staging()  # a killed render is redone from scratch (it is deterministic)
        summary = _render(taken, out, config, progress, workers)
        taken.finish()
    return summary


def _render(taken: OutputDir, out: Path, config: SynthConfig, progress: bool, workers: int | None) -> dict[str, Any]:
    """`run` inside the taken output directory: render into its staging area, then publish."""
    t0 = time.perf_counter()
    world = get_world(config.world_config())
    t_world = time.perf_counter() - t0
    camera = config.camera()
    poses = session_poses(world, config)
    _check_inside(world, camera, poses, tilted=config.camera_tilt_deg > 0)
    if config.geotag_yaw_fault_lines:  # a line the flight does not have got no fault, and the session looked sound
        flown = sorted({int(v) for v in flight_line_ids(config.flight_config()) if v >= 0})
        if absent := sorted(set(config.geotag_yaw_fault_lines) - set(flown)):
            raise InputError(f"--yaw-fault-lines {','.join(map(str, absent))}: the flight has no such line (its "
                             f"{len(flown)} flight line(s): {', '.join(map(str, flown)) or 'none'})")
    present = session_presence(world, config)
    t1 = time.perf_counter()
    scene = build_scene(world, config.season, present)
    az, el = config.sun()
    light = lighting(scene.dsm, world.res, az, el, SEASON_LOOKS[config.season].ambient, world.terrain)
    t_scene = time.perf_counter() - t1
    look = session_look(config)
    geotags, geo = None, None
    if config.geotags:  # EXIF GPS / DJI XMP with a consumer drone's errors, drawn from the exact poses
        settings = config.geotag_settings()
        geo = geo_frame(settings, world.config.size_m)
        lines = flight_line_ids(config.flight_config())
        takeoff = float(world.terrain_sampler.height_at(*poses.centers[0, :2]))
        geotags = session_geotags(settings, geo, poses, camera, (config.width, config.height), lines, takeoff,
                                  config.spacing_m, (config.world_seed, config.session_seed))
    t2 = time.perf_counter()

    def tracked(results: Any) -> Any:
        from .progress import progress_iter

        return progress_iter(results, len(poses), f"synth {out.name}", "frame", progress)
    tmp = taken.staging
    (tmp / "images").mkdir(parents=True)
    (tmp / "labels").mkdir()

    def render_frame(i: int) -> dict[str, Any]:
        name, r_wc, centre = poses.names[i], poses.rotations[i], poses.centers[i]
        try:
            res = render_view(scene, light, camera, r_wc, centre)
        except ViewOutsideWorld as exc:
            raise InputError(f"image {name}: {exc}") from None
        rgb = finish_image(res.linear, look, rng_for(_T_FRAME, config.world_seed, config.session_seed, i))
        jpeg = encode_jpeg(rgb, look.jpeg_quality)
        (tmp / "images" / name).write_bytes(embed_metadata(jpeg, geotags[i]) if geotags else jpeg)
        (tmp / "labels" / (Path(name).stem + ".png")).write_bytes(_encode_png16(res.labels))
        visible = np.unique(res.labels)
        footprint = world.terrain_sampler.footprint(camera, r_wc, centre, footprint_points_per_side(camera))
        return {
            "name": name,
            "visible_object_ids": [int(v) for v in visible if v != 0],
            "footprint": [[round(float(x), 3), round(float(y), 3)] for x, y in footprint],
        }

    # Frames are independent (each has its own random stream), so threads render them in any order and
    # the output is the same; OpenCV and numpy release the GIL in the heavy parts.
    n_workers = max(1, min(workers if workers else (os.cpu_count() or 1), 4))
    if n_workers == 1:
        frames = list(tracked(render_frame(i) for i in range(len(poses))))
    else:
        with ThreadPoolExecutor(n_workers) as pool:
            frames = list(tracked(pool.map(render_frame, range(len(poses)))))
    t_render = time.perf_counter() - t2
    write_cameras_txt(tmp / "cameras.txt", {1: camera})
    write_poses_csv(tmp / "poses.csv", poses)
    write_poses_csv(tmp / "poses_ekf.csv", ekf_poses(poses, config.ekf_noise(), config.session_seed,
                                                     config.world_seed))
    objects = objects_table(scene)
    (tmp / "objects.csv").write_text(format_objects_csv(objects), encoding="utf-8")
    (tmp / "frames.json").write_text(json.dumps(frames, indent=1) + "\n", encoding="utf-8")
    ts = world.terrain_sampler
    with open(tmp / "terrain.npz", "wb") as f:
        np.savez_compressed(f, heights=ts.heights, x0=np.float64(ts.x0), y0=np.float64(ts.y0),
                            resolution_m=np.float64(ts.resolution_m))
    meta = {
        "format": SESSION_FORMAT,
        "version": SESSION_VERSION,
        "generator": f"sosmatch {__version__}",
        "config": config.to_dict(),
        "sun": {"azimuth_deg": az, "elevation_deg": el},
        "camera": {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
                   "cx": camera.cx, "cy": camera.cy, "hfov_deg": config.hfov_deg,
                   **({} if camera.model == "PINHOLE" and camera.height == config.height else
                      {"model": camera.model, "params": camera.params, "sensor": [config.width, config.height]})},
        "look": {"exposure_ev": look.exposure_ev, "white_balance": list(look.white_balance),
                 "vignetting": look.vignetting, "blur_sigma_px": look.blur_sigma_px,
                 "noise_sigma": look.noise_sigma, "jpeg_quality": look.jpeg_quality},
        "world": {"size_m": world.config.size_m, "resolution_m": world.res,
                  "objects": len(world.objects), "objects_present": int(present.sum())},
        "frames": len(poses),
    }
    if geo is not None:
        meta["geo"] = {**geo.to_dict(), "flight_lines": [int(v) for v in lines]}
    (tmp / SESSION_RECORD).write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    taken.publish(SESSION_FILES, last=SESSION_RECORD)
    summary = {"out": str(out), "frames": len(poses), "objects_present": int(present.sum()),
               "seconds_world": round(t_world, 2), "seconds_scene": round(t_scene, 2),
               "seconds_render": round(t_render, 2), "seconds_total": round(time.perf_counter() - t0, 2)}
    log.info("synth %s: %d frames, world %.1fs, scene %.1fs, render %.1fs", out, len(poses), t_world, t_scene,
             t_render)
    return summary
