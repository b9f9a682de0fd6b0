"""Seneca checks of `bench_real seneca` / `seneca-cross`: the real flight end to end from its JPEGs, and its two
headings mapped alone and matched (the truth is the identity); helpers to count and draw common landmarks."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def seneca_end_to_end(seneca: Path, work: Path) -> dict:
    """Seneca from the folder of JPEGs: poses from EXIF + telemetry, pose refinement (COLMAP pose-prior BA on ORB
    tie points), then `sosmatch map` with the telemetry poses and
    with the refined poses (paper defaults and the "survey" preset). Returns the figures."""
    import json

    import pycolmap

    from sosmatch.database.config_io import load_params
    from sosmatch.workflows import map as map_wf
    from sosmatch.workflows import poses_from_exif

    work.mkdir(parents=True, exist_ok=True)
    out: dict = {}
    t = time.perf_counter()
    poses_from_exif.run(seneca / "images", work / "poses.csv", telemetry=seneca / "telemetry.csv")
    out["exif_seconds"] = time.perf_counter() - t
    t = time.perf_counter()
    # its own folder: the refinement writes its own cameras.txt beside its poses (refined intrinsics), and an
    # output of another command's inputs is never replaced
    (work / "refined").mkdir(exist_ok=True)
    res = poses_from_exif.run(seneca / "images", work / "refined" / "poses.csv", telemetry=seneca / "telemetry.csv",
                              refine=True)
    out["refine_seconds"] = time.perf_counter() - t
    out["refinement"] = res.summary["refinement"]
    from sosmatch.workflows.map.quality import MapRefused

    for label, poses_dir, preset in [("telemetry, paper defaults", work, "paper"),
                                     ("refined, paper defaults", work / "refined", "paper"),
                                     ("telemetry, survey preset", work, "survey"),
                                     ("refined, survey preset", work / "refined", "survey")]:
        session = work / ("map_" + label.replace(", ", "_").replace(" ", "_"))
        inputs = map_wf.load_inputs(seneca / "images", poses_dir / "poses.csv", poses_dir / "cameras.txt")
        t = time.perf_counter()
        try:
            map_wf.run(load_params(preset=preset), inputs, session, overwrite=True, progress=False)
        except MapRefused as refused:  # published all the same (run.json says why): its figures are reported
            out[label + " (refused)"] = str(refused)
        wall = time.perf_counter() - t
        run = json.loads((session / "run.json").read_text())
        errors = np.array([p.error for p in pycolmap.Reconstruction(session / "sparse").points3D.values()])
        out[label] = {"landmarks": run["counts"]["landmarks"],
                      "tracks_long": run["counts"]["tracks_long"], "masks": run["counts"]["masks"],
                      "mean_reprojection_px": float(errors.mean()) if len(errors) else float("nan"),
                      "map_bytes": run["counts"]["map_bytes"], "seconds": wall}
    draw_landmarks(work / "map_refined_survey_preset", seneca / "images", ["IMG_0468.jpg", "IMG_0530.jpg",
                   "IMG_0605.jpg"], work / "seneca_landmarks.jpg")
    return out


def seneca_cross_session(seneca: Path, work: Path, poses_csv: Path) -> dict:
    """A cross-session test inside the Seneca flight: the frames flown north-east-wards (course over ground 0-150
    degrees: the ~55 degree lines and the cross lines) against those flown south-west-wards (150-360: the ~237
    degree lines), each mapped on its own with the "survey" preset from `poses_csv` (one frame for both, so the
    true transform is the identity), then `sosmatch match`. The course comes from consecutive GPS positions: the
    telemetry heading is off by a crab angle of up to tens of degrees.

    Also reported, against the known identity: `common_within_4m` / `_5m`, landmark pairs that are mutual nearest
    neighbours horizontally within 4 / 5 m (`common_landmarks`), and per half `off_ground`, landmarks more than
    20 m above or below the north-east map's median height (the ground; it is flat here to a few metres).
    The association settings stay the survey preset's: no setting tried separated the right alignment from
    chance (issue 7, BENCHMARKS.md "Seneca cross-session inside the flight"): the halves share at most 9-10
    mutually consistent landmarks (theta_eps 3-4 m, theta_r 0.4, 2-view landmarks allowed), while the densest
    set CLIPPER finds in the true pair is a flipped one of 9-10, and the negative controls (the south-west half
    mirrored; disjoint along-track halves) give upright wrong sets of 5-10 under the same settings."""
    from sosmatch.database.config_io import load_params
    from sosmatch.database.poses import read_poses_csv, write_poses_csv
    from sosmatch.plugin.geometry import rotation_angle_deg
    from sosmatch.workflows import map as map_wf
    from sosmatch.workflows import match as match_wf
    from sosmatch.workflows.map.quality import MapRefused

    poses, epsg = read_poses_csv(poses_csv)
    step = np.gradient(poses.centers[:, :2], axis=0)  # images in capture order (file names)
    course = np.degrees(np.arctan2(step[:, 0], step[:, 1])) % 360.0
    out: dict = {}
    sessions = []
    for label, lo, hi in [("course_0-150", 0.0, 150.0), ("course_150-360", 150.0, 360.0)]:
        keep = [i for i in range(len(poses)) if lo <= course[i] < hi]
        subset_csv = work / f"poses_{label}.csv"
        write_poses_csv(subset_csv, poses.subset(keep), epsg)
        inputs = map_wf.load_inputs(seneca / "images", subset_csv, poses_csv.parent / "cameras.txt")
        session = work / f"map_{label}"
        try:
            summary = map_wf.run(load_params(preset="survey"), inputs, session, overwrite=True, progress=False)
        except MapRefused as refused:  # a half the map's quality check refuses is a result, not a crash
            out[label] = {"frames": len(keep), "refused": str(refused)}
            continue
        out[label] = {"frames": len(keep), "landmarks": summary.num_landmarks}
        sessions.append(session)
    if len(sessions) < 2:
        return out
    t = time.perf_counter()
    res = match_wf.run(load_params(preset="survey"), sessions[0], sessions[1], work / "match_headings", plot=True)
    out["match_seconds"] = time.perf_counter() - t
    out["accepted"] = res.transform is not None
    if res.transform is not None:
        out["translation_error_m"] = float(np.linalg.norm(res.transform.translation))
        out["rotation_error_deg"] = float(rotation_angle_deg(res.transform.rotation, np.eye(3)))
        pa = res.map_a.lmap.positions[res.associations[:, 0]]
        pb = res.map_b.lmap.positions[res.associations[:, 1]]
        d = np.linalg.norm(pa[:, :2] - pb[:, :2], axis=1)
        out["associations"] = len(d)
        out["associations_within_5m"] = int(np.sum(d < 5.0))
    pos_a, pos_b = res.map_a.lmap.positions, res.map_b.lmap.positions
    for radius in (4.0, 5.0):
        out[f"common_within_{radius:.0f}m"] = len(common_landmarks(pos_a, pos_b, radius))
    ground = float(np.median(pos_a[:, 2]))
    for label, pos in (("course_0-150", pos_a), ("course_150-360", pos_b)):
        out[label]["off_ground"] = int(np.sum(np.abs(pos[:, 2] - ground) > 20.0))
    return out


def common_landmarks(pos_a: np.ndarray, pos_b: np.ndarray, radius_m: float) -> np.ndarray:
    """(K, 2) index pairs (A, B) of landmarks that are each other's nearest neighbour in the ground plane (x, y)
    and less than `radius_m` apart there: the landmarks two maps share when their true transform is the identity.
    Heights are left out because 3-view landmarks can be tens of metres off in height (BENCHMARKS.md)."""
    from ...plugin.refinement import mutual_nearest

    return mutual_nearest(pos_a, None, pos_b, None, radius_m, np.inf, z_weight=0.0)[0]


def draw_landmarks(session: Path, images_dir: Path, names: list[str], out: Path, width: int = 600) -> None:
    """A figure: the named images of a mapped session, side by side, each landmark observation drawn as a circle of
    the landmark's metric size at its observed centroid (yellow) with a line to where the landmark reprojects (red
    dot), as `sosmatch map` draws its keyframes (`workflows.map.figure.draw_keyframe`)."""
    import cv2
    import pycolmap

    from sosmatch.database.cameras import camera_from_pycolmap
    from sosmatch.database.images import read_image
    from sosmatch.database.session_io import read_landmark_table
    from sosmatch.workflows.map.figure import draw_keyframe

    rec = pycolmap.Reconstruction(str(session / "sparse"))
    by_name = {im.name: im for im in rec.images.values()}
    table = read_landmark_table(session / "landmarks.csv")
    sizes = dict(zip(table.point3d_ids.tolist(), table.sizes.tolist()))
    tiles = []
    for name in names:
        image = by_name.get(name)
        if image is None or not (images_dir / name).is_file():
            continue
        seen = [p for p in image.points2D if p.has_point3D() and p.point3D_id in rec.points3D]
        pose = image.cam_from_world()
        r_wc = np.asarray(pose.rotation.matrix()).T
        drawn = draw_keyframe(read_image(images_dir / name), camera_from_pycolmap(image.camera), r_wc,
                              -r_wc @ np.asarray(pose.translation),
                              np.array([p.xy for p in seen]).reshape(-1, 2),
                              np.array([rec.points3D[p.point3D_id].xyz for p in seen]).reshape(-1, 3),
                              np.array([sizes.get(p.point3D_id, 1.0) for p in seen]))
        scale = width / drawn.shape[1]
        tiles.append(cv2.resize(drawn, (width, int(round(drawn.shape[0] * scale))), interpolation=cv2.INTER_AREA))
    if tiles:
        cv2.imwrite(str(out), cv2.cvtColor(np.hstack(tiles), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
