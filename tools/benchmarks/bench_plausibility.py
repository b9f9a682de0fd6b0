"""Map plausibility against truth: false refusals on good sessions, true refusals on maps made on wrong poses.

Every case renders a synthetic session (`sosmatch synth`, cached in WORK/sessions), maps it with
`quality.refuse=false` (so that every figure is recorded) and prints the verdict `sosmatch map` would give (the
map's figures, `plugin.map_quality`, joined with the poses against the images, `workflows.pose_check`), the
figures and, where the map is in the session's frame, the median horizontal error of its landmarks against the
objects (bench_map's scoring). Maps made before the pose check existed get it computed here from their inputs
(run.json's image, pose and camera paths) with their own parameters.

Good cases (must not be refused): exact and EKF poses over several worlds, seasons, flights and heights, a lens
with distortion mapped with its true model, a 16:9 crop, a survey-like flight with the survey preset.
Bad cases (must be refused): the issue's faults without SfM, i.e. poses read from the synthetic EXIF/XMP tags
(`synth --geotags`: GPS noise, a 50 m GPS altitude drift, a 180 deg yaw fault on one line, a k1 = -0.1 lens the
EXIF camera does not model), each fault alone, a block rotated 30 deg off the vertical (what georegistration
from nearly coplanar camera centres can do), and flight lines at alternating altitude offsets.
`--mapped DIR ...` adds mapped sessions made elsewhere (Seneca, NAIP: `bench_real`) to the good cases; their
run.json verdict is read (or recomputed from sparse/ for sessions mapped before the quality stage existed).

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_plausibility --work DIR [--frames 100] [--only NAME ...]
        [--mapped SESSION ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .machine import machine_summary


@dataclass(frozen=True)
class Case:
    name: str
    good: bool
    synth: dict[str, Any]  # SynthConfig overrides
    poses: str = "exact"  # exact | ekf | exif (from the images' tags) | tilt30 | line_offsets
    preset: str = "paper"
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


W7 = {"world_seed": 7, "season": "summer"}
FAULTS = {"geotags": "dji", "geotag_altitude_drift_m": 50.0, "geotag_yaw_fault_lines": (2,)}
CASES = [
    Case("exact", True, W7),
    Case("ekf", True, W7, "ekf"),
    Case("lens k1=-0.1", True, {**W7, "lens_k1": -0.1}),
    Case("lens k1=-0.1, 16:9 crop", True, {**W7, "lens_k1": -0.1, "crop_aspect": "16:9"}, "ekf"),
    Case("winter", True, {**W7, "season": "winter", "session_seed": 3}, "ekf"),
    Case("world 11 free-form", True, {"world_seed": 11, "flight": "freeform", "flight_seed": 4}, "ekf"),
    Case("world 23 at 60 m", True, {"world_seed": 23, "altitude_m": 60.0, "line_spacing_m": 20.0}, "exact"),
    Case("world 11 at 200 m", True, {"world_seed": 11, "world_size_m": 1000.0, "altitude_m": 200.0,
                                     "line_spacing_m": 60.0, "spacing_m": 14.0, "line_length_m": 320.0}, "ekf"),
    Case("survey-like, survey preset", True, {**W7, "spacing_m": 30.0, "frames": 40, "line_length_m": 300.0,
                                              "line_spacing_m": 50.0}, "ekf", "survey"),
    Case("EXIF/XMP faults (drift 50 m, yaw line, k1 -0.1)", False, {**W7, **FAULTS, "lens_k1": -0.1}, "exif",
         note="the issue's bar: poses from the tags, no SfM"),
    Case("EXIF/XMP altitude drift 50 m", False, {**W7, "geotags": "dji", "geotag_altitude_drift_m": 50.0}, "exif"),
    Case("EXIF/XMP yaw fault on one line", False, {**W7, "geotags": "dji", "geotag_yaw_fault_lines": (2,)}, "exif"),
    Case("EXIF GPS only, drift 50 m", False, {**W7, "geotags": "exif", "geotag_altitude_drift_m": 50.0}, "exif"),
    Case("block rotated 30 deg", False, W7, "tilt30"),
    Case("lines at +-15 m altitude offsets", False, W7, "line_offsets"),
]


def _session(work: Path, case: Case, frames: int) -> Path:
    from ...workflows.synth import SynthConfig
    from ...workflows.synth import run as synth

    cfg = SynthConfig(**{"frames": frames, **case.synth})
    key = json.dumps(cfg.to_dict(), sort_keys=True)
    out = work / "sessions" / ("s" + hashlib.sha1(key.encode()).hexdigest()[:10])
    stamp = out / "config.key"
    if not (stamp.is_file() and stamp.read_text() == key):
        synth(out, cfg)
        stamp.write_text(key)
    return out


def _rotated(poses: Any, deg: float) -> Any:
    from ...plugin.geometry import Poses

    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    t = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    m = poses.centers.mean(axis=0)
    return Poses(poses.names, t @ poses.rotations, (poses.centers - m) @ t.T + m)


def _line_offsets(poses: Any, offset_m: float) -> Any:
    from ...plugin.geometry import Poses
    from ...plugin.pass_heights import flight_passes

    passes = flight_passes(poses.centers)
    centers = poses.centers.copy()
    centers[:, 2] += np.where(passes % 4 < 2, offset_m, -offset_m)
    return Poses(poses.names, poses.rotations, centers)


def _inputs(session: Path, case: Case, work: Path) -> Any:
    from ...database.poses import read_poses_csv, write_poses_csv
    from ...workflows import map as map_workflow

    if case.poses == "exif":
        from ...workflows.poses_from_exif import map_inputs_from_images

        return map_inputs_from_images(session / "images")
    if case.poses in ("exact", "ekf"):
        return map_workflow.load_inputs(None, session, ekf=case.poses == "ekf")
    poses, epsg = read_poses_csv(session / "poses.csv")
    poses = _rotated(poses, 30.0) if case.poses == "tilt30" else _line_offsets(poses, 15.0)
    path = work / "poses" / f"{session.name}_{case.poses}.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_poses_csv(path, poses, epsg)
    return map_workflow.load_inputs(session / "images", path, session / "cameras.txt")


def run_case(work: Path, case: Case, frames: int) -> dict[str, Any]:
    from ...database.config_io import load_params
    from ...workflows import map as map_workflow
    session = _session(work, case, frames)
    inputs = _inputs(session, case, work)
    out = work / "maps" / f"{session.name}_{case.poses}_{case.preset}"
    params = load_params(preset=case.preset, overrides={"quality.refuse": False})
    t = time.process_time()
    if not (out / "run.json").is_file() or "quality" not in json.loads((out / "run.json").read_text()):
        map_workflow.run(params, inputs, out, overwrite=True, progress=False)  # else: mapped by an earlier run
    cpu = time.process_time() - t
    run = json.loads((out / "run.json").read_text())
    row: dict[str, Any] = {"case": case.name, "good": case.good, "verdict": run["verdict"], "quality": run["quality"],
                           "landmarks": run["counts"]["landmarks"], "cpu_s": round(cpu, 1), "session": str(session),
                           "map": str(out), "pose_check": pose_check_of(run, inputs)}
    if case.poses != "tilt30":  # a rotated block has no meaningful horizontal error
        row["median_horizontal_m"] = horizontal_error(session, out)
    return row


def horizontal_error(session: Path, mapped: Path) -> float:
    """Median of `horizontal_errors` (NaN without a landmark on an object)."""
    err = horizontal_errors(session, mapped)
    return float(np.median(err)) if len(err) else float("nan")


def horizontal_errors(session: Path, mapped: Path) -> np.ndarray:
    """Horizontal distance of each of the map's landmarks on objects (bench_map's label vote) to the objects'
    visible-top centres, in the session's world frame (maps made from the synthetic geotags are in UTM: the
    session's `geo.world_to_crs_offset` is taken off)."""
    from ...database.landmark_map import read_landmark_map
    from ...database.synth_session import load_synth_session
    from .bench_map import landmark_objects

    synth = load_synth_session(session)
    offset = np.asarray(synth.meta.get("geo", {}).get("world_to_crs_offset", [0.0, 0.0, 0.0]), np.float64)
    lmap = read_landmark_map(mapped / "landmarks.sosmap")
    pos = lmap.positions - (offset if lmap.epsg else 0.0)
    majority, _ = landmark_objects(synth, mapped)
    objects = {int(o["id"]): o for o in synth.objects}
    return np.array([np.hypot(pos[i, 0] - objects[int(majority[i])]["x"], pos[i, 1] - objects[int(majority[i])]["y"])
                     for i in np.flatnonzero(majority > 0)], dtype=np.float64)


def figures(path: Path) -> dict[str, Any]:
    """The quality figures of a mapped session, recomputed with the current code from sparse/, landmarks.csv and
    run.json's counts (so sessions mapped by older code, or elsewhere, are judged alike)."""
    import pycolmap

    from ...database.cameras import camera_from_pycolmap
    from ...database.session_io import read_landmark_table
    from ...plugin.geometry import pixel_rays
    from ...plugin.map_quality import assess_map
    from ...plugin.params import QualityParams

    run = json.loads((path / "run.json").read_text())
    rec = pycolmap.Reconstruction(str(path / "sparse"))
    ids = sorted(rec.images)
    index = {iid: k for k, iid in enumerate(ids)}
    centers = np.array([rec.images[i].projection_center() for i in ids])
    axes = np.array([rec.images[i].cam_from_world().rotation.matrix().T[:, 2] for i in ids])
    table = read_landmark_table(path / "landmarks.csv")
    points = [rec.points3D[int(p)] for p in table.point3d_ids]
    pos = np.array([p.xyz for p in points]).reshape(-1, 3)
    errors = np.array([p.error for p in points])
    obs = [np.array([index[e.image_id] for e in p.track.elements]) for p in points]
    # the observations' world rays, as the map's own quality stage has them (`workflows.map.quality.assess`): the
    # passes' own heights of their common landmarks (`plugin.pass_heights`) need them
    camera = camera_from_pycolmap(next(iter(rec.cameras.values())))
    world_from_cam = {i: np.asarray(rec.images[i].cam_from_world().rotation.matrix()).T for i in ids}
    rays = [np.concatenate([pixel_rays(camera, np.asarray(rec.images[e.image_id].points2D[e.point2D_idx].xy)[None],
                                       world_from_cam[e.image_id]) for e in p.track.elements]) for p in points]
    q = assess_map(pos, table.sizes, errors, obs, centers, axes, run["counts"].get("tracks_long", len(pos)),
                   observation_rays=rays, pass_offset_margin=QualityParams().pass_offset_margin)
    return q.to_dict()


def pose_check_of(run: dict[str, Any], inputs: Any = None, where: Path | None = None) -> dict[str, Any] | None:
    """The map's pose check (run.json's "pose_check": verdict and figures); for a map made before the check
    existed, the check run now on `inputs` (or on the inputs run.json names) at the map's own epipolar gate
    (already scaled to the image). None when the inputs are gone."""
    from ...plugin.params import Params
    from ...workflows import map as map_workflow
    from ...workflows import pose_check

    if run.get("pose_check"):
        return run["pose_check"]
    if inputs is None:
        src = run.get("inputs") or {}
        paths = [_resolved(Path(src[k]), where) if src.get(k) else None for k in ("images", "poses", "camera")]
        if paths[2] == paths[1]:  # the intrinsics came with the poses (a synth session, a model)
            paths[2] = None
        if paths[0] is None or paths[1] is None or not all(p is None or p.exists() for p in paths):
            return None
        inputs = map_workflow.load_inputs(*paths)
    # the check's own defaults, at the gate the map tracked with (older run.json files hold keys since renamed)
    params = Params()
    t = time.process_time()
    result = pose_check.run(inputs.image_paths, inputs.poses, inputs.camera, params, refuse=False,
                            gate=float(run["params"]["tracking"]["epipolar_margin_px"]))
    return {**result.summary(), "cpu_s": round(time.process_time() - t, 1)}


def _resolved(path: Path, where: Path | None) -> Path:
    """A run.json input path; a relative one (the map was made from another working directory) is looked for
    under the map directory's ancestors."""
    if path.is_absolute() or path.exists() or where is None:
        return path
    return next((a / path for a in Path(where).resolve().parents if (a / path).exists()), path)


def mapped_row(path: Path, good: bool = True) -> dict[str, Any]:
    """A mapped session made elsewhere (Seneca, NAIP, other engineers' synthetic maps)."""
    run = json.loads((path / "run.json").read_text())
    return {"case": f"mapped: {path}", "good": good, "map": str(path), "quality": figures(path),
            "landmarks": run["counts"]["landmarks"], "pose_check": pose_check_of(run, where=path)}


def rejudge(row: dict[str, Any]) -> dict[str, Any]:
    """The verdict of a row under the current code: figures recomputed from its map (when it is still there),
    then `map_verdict.judge` with the default limits joined with the row's pose check, so the table always shows
    what `sosmatch map` would say."""
    from ...plugin.map_quality import MapQuality
    from ...plugin.map_verdict import Verdict, judge
    from ...plugin.params import Params
    from ...workflows.map.quality import joined

    quality = figures(Path(row["map"])) if Path(row.get("map", "")).is_dir() else row["quality"]
    known = {f.name for f in dataclasses.fields(MapQuality)}  # rows of older runs lack the newer figures (NaN)
    q = MapQuality(**{k: (float("nan") if quality.get(k) is None else quality[k]) for k in known})
    p = Params()
    v = judge(q, p.quality, p.association.min_associations + 1)
    pv = (row.get("pose_check") or {}).get("verdict") or {}
    v = joined(v, Verdict(list(pv.get("refusals", [])), list(pv.get("warnings", []))))
    return {**row, "quality": quality, "verdict": {"status": "ok" if v.ok else "refused", "refusals": v.refusals,
                                                   "warnings": v.warnings}}


def _fmt(v: Any, spec: str = ".2f") -> str:
    return "n/a" if v is None else format(v, spec) if isinstance(v, float) else str(v)


def _pose_cell(row: dict[str, Any]) -> str:
    f = (row.get("pose_check") or {}).get("figures")
    if not f:
        return "n/a"
    return (f"{_fmt(f['epipolar_p50_px'], '.1f')} / {_fmt(f['height_drift_m'], '+.1f')} / "
            f"{_fmt(f['height_tilt_deg'], '.1f')} / {f['reversed_pairs']}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="sessions, maps and results.json go here")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", nargs="*", help="case names (substrings) to run")
    ap.add_argument("--mapped", nargs="*", type=Path, default=[], help="more good mapped sessions to judge")
    ap.add_argument("--mapped-bad", nargs="*", type=Path, default=[],
                    help="mapped sessions known to be wrong (e.g. Seneca on its raw telemetry)")
    ap.add_argument("--report-only", action="store_true", help="re-judge and print WORK/results.json")
    args = ap.parse_args(argv)
    print(machine_summary())
    results = args.work / "results.json"
    if args.report_only:
        rows = json.loads(results.read_text())
    else:
        rows = []
        for case in CASES:
            if args.only and not any(o in case.name for o in args.only):
                continue
            rows.append(run_case(args.work, case, args.frames))
            print(f"  {case.name}: {rows[-1]['verdict']['status']}", flush=True)
            args.work.mkdir(parents=True, exist_ok=True)
            results.write_text(json.dumps(rows, indent=1, default=str) + "\n")  # after every case: resumable
    rows = [r for r in rows if not ((args.mapped or args.mapped_bad) and r["case"].startswith("mapped: "))]
    rows += [mapped_row(p) for p in args.mapped] + [mapped_row(p, good=False) for p in args.mapped_bad]
    results.write_text(json.dumps(rows, indent=1, default=str) + "\n")
    rows = [rejudge(r) for r in rows]
    for r in rows:  # scored with the current scorer where the session and map are still there
        if not r["case"].startswith("mapped: ") and "rotated" not in r["case"] and Path(r["map"]).is_dir():
            r["median_horizontal_m"] = horizontal_error(Path(r["session"]), Path(r["map"]))
    print("| case | should be | verdict | landmarks | reproj p50/p90 px | kf with lm | pass disagreement | "
          "block tilt deg | ground tilt deg | above cams | horiz. error m | poses vs images: epipolar px / "
          "drift m / tilt deg / reversed | reason |")
    print("|---|---|---|---:|---|---:|---:|---:|---:|---:|---:|---|---|")
    wrong = 0
    for r in rows:
        q, v = r["quality"], r["verdict"]
        refused = bool(v["refusals"])
        wrong += int(refused == r["good"])
        reason = "; ".join(v["refusals"] or v["warnings"])[:90]
        print(f"| {r['case']} | {'kept' if r['good'] else 'refused'} | {'refused' if refused else 'kept'} | "
              f"{r['landmarks']} | {_fmt(q['reprojection_p50_px'], '.1f')}/{_fmt(q['reprojection_p90_px'], '.1f')} | "
              f"{_fmt(q['keyframes_with_landmarks'])} | {_fmt(q['pass_disagreement'])} | "
              f"{_fmt(q['block_tilt_deg'], '.1f')} | {_fmt(q['ground_tilt_deg'], '.1f')} | "
              f"{q['landmarks_above_cameras']} | {_fmt(r.get('median_horizontal_m'))} | {_pose_cell(r)} | {reason} |")
    good = [r for r in rows if r["good"]]
    bad = [r for r in rows if not r["good"]]
    def by_poses(rows: list[dict[str, Any]]) -> int:
        return sum(any(x.startswith("poses vs images") for x in r["verdict"]["refusals"]) for r in rows)

    print(f"false refusals {sum(bool(r['verdict']['refusals']) for r in good)} of {len(good)} "
          f"({by_poses(good)} by the pose check), true refusals {sum(bool(r['verdict']['refusals']) for r in bad)} "
          f"of {len(bad)} ({by_poses(bad)} by the pose check)")
    return 0 if wrong == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
