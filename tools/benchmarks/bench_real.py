"""Real-data checks.

`attitude` (default): which body-to-camera convention makes the Seneca telemetry predict how image content
actually moves between consecutive frames.
`refine SESSION --poses poses.csv`: pose refinement with priors on a mapped real session (e.g. Seneca mapped
from `sosmatch poses-from-exif` poses): reprojection error of the landmarks before/after, how far poses moved.
`naip`: two sessions rendered from the NAIP 2009 and 2015 orthophotos along one path, mapped and matched in both
orders; scored against the exact shared ground truth (the true A_from_B transform is the identity); negative
control: maps of opposite halves of the area must accept nothing. Rendering options after the known ones go to
`synth-from-ortho`; the shipped setting (BENCHMARKS.md, "Real data"):
    bench_real naip --work DIR --hfov 90 --frame-spacing 75 --preset aerial
`seneca --work DIR`: Seneca end to end from the folder of JPEGs (poses from EXIF + telemetry, pose refinement,
`sosmatch map` with telemetry and refined poses under the paper
defaults and the "survey" preset), then `seneca-cross`: the ~55 degree flight lines against the ~237 degree
ones, each mapped alone with the refined poses and matched (true transform: the identity).

For each pair of consecutive frames on one flight line, ORB features are matched and filtered by a RANSAC
homography (image evidence only, no telemetry). For each candidate convention (mount x sign of pitch x sign of
roll, plus a level-camera baseline), every inlier of frame 1 is back-projected through the telemetry pose onto
the flat ground (z = GPS altitude - Height, averaged over the pair) and projected into frame 2; the error is
the distance to where the feature was actually seen. A wrong sign of a 10-degree roll moves the prediction by
~25 m on the ground (~300 px at 70 m); metre-level GPS error is ~12 px per metre.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_real attitude [--seneca /work/shared/data/seneca]
    .venv/bin/python -m sosmatch.tools.benchmarks.bench_real refine SESSION --poses poses.csv
    .venv/bin/python -m sosmatch.tools.benchmarks.bench_real naip --work DIR [--naip /work/shared/data/naip]
        [--preset P] [--map-preset P] [--map-set K=V] [--one-order] [--no-control] [synth-from-ortho options]
    .venv/bin/python -m sosmatch.tools.benchmarks.bench_real seneca --work DIR [--seneca /work/shared/data/seneca]
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

from ...plugin.geometry import Camera
from ...workflows import poses_from_exif as pfe
from .machine import machine_summary


def _pairs(centers: np.ndarray, yaw: np.ndarray, max_step_m: float = 45.0, max_turn_deg: float = 15.0) -> list:
    out = []
    for i in range(len(centers) - 1):
        step = np.linalg.norm(centers[i + 1, :2] - centers[i, :2])
        turn = abs((yaw[i + 1] - yaw[i] + 180.0) % 360.0 - 180.0)
        if 3.0 < step < max_step_m and turn < max_turn_deg:
            out.append((i, i + 1))
    return out


def _matches(img1: np.ndarray, img2: np.ndarray, orb: object) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    k1, d1 = orb.detectAndCompute(img1, None)
    k2, d2 = orb.detectAndCompute(img2, None)
    if d1 is None or d2 is None or len(k1) < 20 or len(k2) < 20:
        return np.zeros((0, 2)), np.zeros((0, 2))
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d1, d2, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
    if len(good) < 20:
        return np.zeros((0, 2)), np.zeros((0, 2))
    p1 = np.float32([k1[m.queryIdx].pt for m in good]) + 0.5  # COLMAP pixel convention
    p2 = np.float32([k2[m.trainIdx].pt for m in good]) + 0.5
    _, inl = cv2.findHomography(p1, p2, cv2.RANSAC, 4.0)
    if inl is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    inl = inl.ravel().astype(bool)
    return p1[inl].astype(np.float64), p2[inl].astype(np.float64)


def predict_flow(camera: Camera, r1: np.ndarray, c1: np.ndarray, r2: np.ndarray, c2: np.ndarray,
                 ground_z: float, uv1: np.ndarray) -> np.ndarray:
    """Pixels of frame 2 predicted for pixels uv1 of frame 1 over the plane z = ground_z (world_from_camera)."""
    d = np.stack([(uv1[:, 0] - camera.cx) / camera.fx, (uv1[:, 1] - camera.cy) / camera.fy, np.ones(len(uv1))], 1)
    rays = d @ r1.T
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (ground_z - c1[2]) / rays[:, 2]
    ground = c1 + lam[:, None] * rays
    p = (ground - c2) @ r2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy], 1)


def attitude_check(seneca: Path, max_pairs: int = 60, extra_poses: Path | None = None) -> dict:
    import cv2

    images = seneca / "images"
    tele = pfe.read_telemetry_csv(seneca / "telemetry.csv")
    height = _column(seneca / "telemetry.csv", "Height")
    base = pfe.poses_from_images(images, telemetry=seneca / "telemetry.csv")
    names = base.poses.names
    cam = base.camera
    centers = base.poses.centers
    yaw = np.array([tele[n]["yaw"] for n in names])
    pitch = np.array([tele[n]["pitch"] for n in names])
    roll = np.array([tele[n]["roll"] for n in names])
    lat_lon = base.summary["origin_latlon"]
    _, _, north_az = pfe.geographic_to_grid(np.array([lat_lon[0]]), np.array([lat_lon[1]]), base.epsg)
    ground = centers[:, 2] - np.array([height[n] for n in names])
    pairs = _pairs(centers, yaw)
    step = max(1, len(pairs) // max_pairs)
    pairs = pairs[::step][:max_pairs]
    orb = cv2.ORB_create(3000)
    obs = []
    t0 = time.perf_counter()
    for i, j in pairs:
        g1 = cv2.imread(str(images / names[i]), cv2.IMREAD_GRAYSCALE)
        g2 = cv2.imread(str(images / names[j]), cv2.IMREAD_GRAYSCALE)
        p1, p2 = _matches(g1, g2, orb)
        if len(p1) >= 30:
            obs.append((i, j, p1, p2))
    t_match = time.perf_counter() - t0
    candidates = [(m, ps, rs) for m, ps, rs in itertools.product(pfe.FIXED_MOUNTS, (1.0, -1.0), (1.0, -1.0))]
    results = {}
    for mount, ps, rs in candidates + [("level", 1.0, 1.0)]:
        if mount == "level":
            rot = pfe.camera_rotations(yaw, 0 * pitch, 0 * roll, results_best_mount(results), 1, 1, north_az)
        else:
            rot = pfe.camera_rotations(yaw, pitch, roll, mount, ps, rs, north_az)
        per_pair, shifts = [], []
        for i, j, p1, p2 in obs:
            pred = predict_flow(cam, rot[i], centers[i], rot[j], centers[j], 0.5 * (ground[i] + ground[j]), p1)
            res = p2 - pred
            per_pair.append(float(np.median(np.linalg.norm(res, axis=1))))
            shifts.append(float(np.median(np.linalg.norm(res - np.median(res, 0), axis=1))))
        key = f"{mount} pitch{'+' if ps > 0 else '-'} roll{'+' if rs > 0 else '-'}" if mount != "level" else \
            "level camera (pitch=roll=0), best mount"
        results[key] = {"per_pair": per_pair, "median_px": float(np.median(per_pair)),
                        "p90_px": float(np.percentile(per_pair, 90)),
                        "median_px_after_shift": float(np.median(shifts)), "mount": mount, "pitch_sign": ps,
                        "roll_sign": rs}
    if extra_poses is not None:  # e.g. refined poses: the same flow test, one more row
        from ...database.poses import read_poses_csv

        ext, _ = read_poses_csv(extra_poses)
        idx = [ext.names.index(n) for n in names]
        rot_e, cen_e = ext.rotations[idx], ext.centers[idx]
        per_pair = []
        for i, j, p1, p2 in obs:
            g = 0.5 * (ground[i] + ground[j]) + 0.5 * ((cen_e[i, 2] - centers[i, 2]) + (cen_e[j, 2] - centers[j, 2]))
            pred = predict_flow(cam, rot_e[i], cen_e[i], rot_e[j], cen_e[j], g, p1)
            per_pair.append(float(np.median(np.linalg.norm(p2 - pred, axis=1))))
        extra = {"per_pair": per_pair, "median_px": float(np.median(per_pair)),
                 "p90_px": float(np.percentile(per_pair, 90)), "median_px_after_shift": float("nan"),
                 "mount": "file", "pitch_sign": 1.0, "roll_sign": 1.0}
    table = np.array([r["per_pair"] for r in results.values()])
    best = np.argmin(table[:-1], axis=0)  # the level baseline does not compete for wins
    for k, r in enumerate(results.values()):
        r["pairs_won"] = int(np.sum(best == k)) if k < len(table) - 1 else 0
    if extra_poses is not None:
        extra["pairs_won"] = 0
        results[f"poses from {extra_poses.name}"] = extra
    return {"pairs": len(obs), "match_seconds": t_match, "results": results,
            "median_inliers": float(np.median([len(o[2]) for o in obs])) if obs else 0.0,
            "median_speed_px": float(np.median([np.median(np.linalg.norm(o[3] - o[2], axis=1)) for o in obs]))}


def results_best_mount(results: dict) -> str:
    if not results:
        return pfe.DEFAULT_MOUNT
    best = min(results.values(), key=lambda r: r["median_px"])
    return best["mount"]


def _column(path: Path, column: str) -> dict[str, float]:
    import csv

    with open(path, encoding="utf-8") as f:
        return {row["FileName"]: float(row[column]) for row in csv.DictReader(f)}


def refine_check(session: Path, poses_csv: Path, position_sigma_m: float, attitude_sigma_deg: float,
                 pixel_sigma_px: float, out: Path | None = None) -> dict:
    """Refine a mapped session's model with pose priors; report errors before/after (model written to `out`)."""
    import pycolmap

    from ...database.poses import read_poses_csv
    from ...workflows.pose_refinement import refine_poses_with_priors

    rec = pycolmap.Reconstruction(str(session / "sparse"))
    rec.update_point_3d_errors()
    before = np.array([p.error for p in rec.points3D.values()])
    priors, _ = read_poses_csv(poses_csv)
    stats = refine_poses_with_priors(rec, priors, position_sigma_m, attitude_sigma_deg, pixel_sigma_px)
    after = np.array([p.error for p in rec.points3D.values()])
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        rec.write_binary(str(out))
    return {"stats": stats.to_dict(), "point_error_median_before_px": float(np.median(before)),
            "point_error_median_after_px": float(np.median(after))}


def naip_sessions(naip: Path, work: Path, extra_args: list[str], map_args: list[str] | None = None,
                  tifs: list[Path] | None = None) -> tuple[list[tuple[Path, Path]], dict]:
    """Render both NAIP dates (or the given `tifs`) along one path (`synth-from-ortho`, extra_args passed on) and
    map them (`sosmatch map`, map_args passed on, e.g. ["--preset", "aerial"]); existing sessions and maps in
    `work` are reused. Returns [(session, mapped session)] in the order of `tifs` (default: file-name order, oldest
    first), and the timings."""
    from ..cli import main as cli

    tifs = sorted(naip.glob("*.tif")) if tifs is None else list(tifs)
    if len(tifs) != 2:
        raise SystemExit(f"expected two GeoTIFFs in {naip}")
    times = {}
    sessions = []
    for tif in tifs:
        name = tif.stem.rsplit("_", 1)[-1]
        sess, mapped = work / f"naip_{name}", work / f"naip_{name}_map"
        t0 = time.perf_counter()
        if not (sess / "session.json").exists():
            assert cli(["synth-from-ortho", str(tif), "--out", str(sess), "--max-tilt", "3", *extra_args]) == 0
        times[f"render_{name}_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        if not (mapped / "run.json").exists():
            assert cli(["map", "--poses", str(sess), "--out", str(mapped), "--no-progress", *(map_args or [])]) == 0
        times[f"map_{name}_s"] = time.perf_counter() - t0
        sessions.append((sess, mapped))
    return sessions, times


def half_orthophoto(tif: Path, side: str, out: Path) -> Path:
    """The west or east half (`side`) of `tif`, georeferenced, written once to `out`: a negative control of
    `naip_check`. Two halves share no ground, so a match between maps of opposite halves must accept nothing."""
    import rasterio
    from rasterio.windows import Window

    if not out.exists():
        with rasterio.open(tif) as src:
            half = src.width // 2
            win = Window(0, 0, half, src.height) if side == "west" else \
                Window(half, 0, src.width - half, src.height)
            profile = src.profile.copy()
            profile.update(width=win.width, height=win.height, transform=src.window_transform(win))
            data = src.read(window=win)
        _write_raster(out, data, profile)
    return out


def mirrored_orthophoto(tif: Path, out: Path) -> Path:
    """`tif` flipped east-west under the same georeference, written once to `out`: the full-size negative control
    of `naip_check` (same ponds, sizes and density as the real date, at mirrored places). A mirrored flat map is
    the original turned upside down, so that set is rejected only by the gravity gate (theta_alpha); what the
    control tests is that no upright chance set is accepted."""
    import rasterio

    if not out.exists():
        with rasterio.open(tif) as src:
            data, profile = src.read()[:, :, ::-1], src.profile
        _write_raster(out, data, profile)
    return out


def _write_raster(out: Path, data: np.ndarray, profile: dict) -> None:
    """Write a GeoTIFF atomically (a temporary sibling, then rename): a killed run leaves no half raster that the
    next run would take as done."""
    import rasterio

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".tmp.tif")
    with rasterio.open(tmp, "w", **profile) as dst:
        dst.write(data)
    tmp.replace(out)


def evaluation_cases(data_root: Path, work: Path) -> list[dict]:
    """Real-data cases for `bench_evaluate --real`: NAIP 2009 vs 2015 rendered along one path (frames every 75 m)
    and mapped; the sessions carry exact poses, footprints and a flat terrain at z = 0, so the paper's evaluation
    (footprint IoU ground truth, PR curves against ORB/SIFT + RANSAC) runs unchanged."""
    naip = Path(data_root) / "naip"
    if not naip.is_dir():
        return []
    (a, map_a), (b, map_b) = naip_sessions(naip, Path(work), ["--frame-spacing", "75"])[0]
    return [{"case": "naip-2009-2015", "session_a": a, "session_b": b, "map_a": map_a, "map_b": map_b,
             "ground_height": 0.0}]


def _identity_error(transform: dict, centre: np.ndarray) -> tuple[float, float]:
    """How far a match.json transform (A_from_B) is from the identity: displacement of `centre` (m), angle (deg)."""
    from ...plugin.geometry import rotation_angle_deg
    from ...plugin.multisession import Sim3

    sim = Sim3.from_dict(transform)
    return float(np.linalg.norm(sim.apply(centre) - centre)), rotation_angle_deg(sim.rotation, np.eye(3))


def _score_match(map_a: Path, map_b: Path, match_dir: Path) -> dict:
    """Accepted count and, if a hypothesis was accepted, its error against the identity (see `naip_check`)."""
    import json

    from ...database.landmark_map import read_landmark_map

    a = read_landmark_map(map_a / "landmarks.sosmap")
    b = read_landmark_map(map_b / "landmarks.sosmap")
    from ...database.match_io import read_match

    result = json.loads((match_dir / "match.json").read_text())
    answer = read_match(match_dir / "match.json")  # what every consumer uses: the verified alignment
    out = {"landmarks": [len(a), len(b)], "window_pairs_solved": result.get("num_solved"),
           "accepted": result.get("num_accepted"), "match_s": result.get("seconds_total"),
           "search_s": result.get("search_seconds"), "search_mode": result.get("search_mode"),
           "answer": answer.source, "answer_accepted": bool(answer.accepted),
           "answer_support": len(answer.associations) if answer.accepted else 0,
           "runner_up_support": answer.runner_up_support}
    # the margin to theta_S: the largest upright (tilt <= theta_alpha) hypothesis that is wrong, i.e. off the
    # identity by more than the bar (15 m at B's landmark centroid or 2 degrees); every one is, for the controls
    centre = b.positions.mean(axis=0)
    max_tilt = result["params"]["association"]["max_gravity_angle_deg"]
    wrong = [0]
    for h in result["hypotheses"]:
        if h.get("transform") and h.get("tilt_deg") is not None and h["tilt_deg"] <= max_tilt:
            err_m, err_deg = _identity_error(h["transform"], centre)
            if err_m > 15.0 or err_deg > 2.0:
                wrong.append(h["size"])
    out["largest_wrong_upright_hypothesis"] = max(wrong)
    out["largest_right_hypothesis"] = max([h["size"] for h in result["hypotheses"] if h.get("transform")
                                           and h.get("tilt_deg") is not None and h["tilt_deg"] <= max_tilt
                                           and max(_identity_error(h["transform"], centre)[0] / 15.0,
                                                   _identity_error(h["transform"], centre)[1] / 2.0) <= 1.0],
                                          default=0)
    out["association"] = {k: result["params"]["association"].get(k) for k in
                          ("distance_tolerance_m", "affinity_sigma_m", "max_size_difference", "window_length",
                           "window_stride", "min_associations", "derive_from_maps")}
    out["verified"] = _verified(match_dir, centre)
    best = result.get("consensus") or (result["hypotheses"][result["best"]] if result.get("best") is not None
                                       else None)
    if answer.accepted:
        out["answer_error_m"], out["answer_error_deg"] = _identity_error(answer.transform.to_dict(), centre)
    if best:
        out["transform_error_m"], out["transform_error_deg"] = _identity_error(best["transform"], centre)
        assoc = np.array(best["associations"]).reshape(-1, 2)
        d = np.linalg.norm(a.positions[assoc[:, 0], :2] - b.positions[assoc[:, 1], :2], axis=1)
        out["associations"] = len(assoc)
        out["associations_within_10m"] = int(np.sum(d < 10.0))
        out["association_distance_median_m"] = float(np.median(d)) if len(d) else float("nan")
    return out


def _verified(match_dir: Path, centre: np.ndarray) -> dict:
    """The match's answer as `sosmatch match` verified it on the full maps (match.json "verification", the one
    verification `batch` and `evaluate` read too): its support, the best rival's, whether it was accepted, its
    error to the identity."""
    from ...database.match_io import read_match, read_match_json
    from ...plugin.geometry import rotation_angle_deg

    ver = read_match_json(match_dir / "match.json").get("verification")
    if not ver:
        return {"support": 0, "runner_up_support": 0, "accepted": False}
    out = {"support": int(ver.get("support", 0)), "runner_up_support": int(ver.get("runner_up_support", 0)),
           "accepted": bool(ver.get("accepted"))}
    t = read_match(match_dir / "match.json").transform
    if t is not None:
        out.update(error_m=float(np.linalg.norm(t.apply(centre[None])[0] - centre)),
                   error_deg=float(rotation_angle_deg(t.rotation, np.eye(3))))
    return out


def draw_naip_match(tif: Path, map_a: Path, map_b: Path, match_dir: Path, out: Path, width: int = 934) -> None:
    """A figure: both maps' landmarks on the orthophoto `tif` (A red, B cyan, circles of the landmarks' metric
    size), the accepted consensus' associations as yellow lines from A's landmark to B's, B's landmarks moved
    by the accepted transform (the truth is the identity, so a line's length is the pair's disagreement)."""
    import json

    import cv2
    import rasterio

    from ...database.landmark_map import read_landmark_map
    from ...plugin.multisession import Sim3

    with rasterio.open(tif) as src:
        rgb = np.moveaxis(src.read([1, 2, 3]), 0, -1)
        inverse, gsd = ~src.transform, abs(src.transform.a)
    img = np.ascontiguousarray(rgb[:, :, ::-1])
    scale = width / img.shape[1]
    img = cv2.resize(img, (width, int(round(img.shape[0] * scale))), interpolation=cv2.INTER_AREA)

    def pixels(xy: np.ndarray) -> np.ndarray:
        cols, rows = inverse * (xy[:, 0], xy[:, 1])
        return np.round(np.column_stack([cols, rows]) * scale).astype(int)

    a = read_landmark_map(map_a / "landmarks.sosmap")
    b = read_landmark_map(map_b / "landmarks.sosmap")
    result = json.loads((match_dir / "match.json").read_text())
    best = result.get("consensus")
    pb = Sim3.from_dict(best["transform"]).apply(b.positions) if best else b.positions
    for pos, sizes, colour in ((a.positions, a.sizes, (0, 0, 255)), (pb, b.sizes, (255, 255, 0))):
        for (u, v), size in zip(pixels(pos), sizes):
            cv2.circle(img, (int(u), int(v)), max(2, int(round(size / gsd * scale))), colour, 1, cv2.LINE_AA)
    if best:
        assoc = np.array(best["associations"]).reshape(-1, 2)
        for (ua, va), (ub, vb) in zip(pixels(a.positions[assoc[:, 0]]), pixels(pb[assoc[:, 1]])):
            cv2.line(img, (int(ua), int(va)), (int(ub), int(vb)), (0, 255, 255), 3, cv2.LINE_AA)
            cv2.circle(img, (int(ua), int(va)), 9, (0, 255, 255), 2, cv2.LINE_AA)
    labels = [f"A: {len(a)} landmarks (red); B: {len(b)} (cyan), moved by the accepted transform",
              f"{0 if not best else len(best['associations'])} consensus associations (yellow)"]
    cv2.rectangle(img, (0, 0), (600, 48), (0, 0, 0), -1)
    for row, label in enumerate(labels):
        cv2.putText(img, label, (8, 18 + 20 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), img, [cv2.IMWRITE_JPEG_QUALITY, 85])


def naip_check(naip: Path, work: Path, extra_args: list[str], preset: str = "paper",
               map_args: list[str] | None = None, both_orders: bool = True, control: bool = True,
               match_sets: list[str] | None = None) -> dict:
    """Render both NAIP dates along one path, map both (`map_args`), match (parameters: `preset`); score against
    the identity ground truth. The transform is in world (UTM) coordinates, so its error is taken where the data
    is: the displacement of B's landmark centroid, and the rotation angle. `both_orders`: also match 2009 into
    2015. `control`: the negative control, maps of the west half of one date against the east half of the other
    (`half_orthophoto`; rendered and mapped alike), both ways round, and of 2009's two halves: they share no
    ground, so nothing may be accepted; and 2009 against the 2015 orthophoto mirrored (`mirrored_orthophoto`).
    Each match reports the largest upright (tilt <= theta_alpha) hypothesis: the margin to theta_S, and the
    match's window hypotheses verified on the full maps as `batch` and `evaluate` do (`_verified`): the verified
    alignment's support, its rival's, and its error. `preset` "none": the defaults; `match_sets`: `--set` of the
    match (e.g. association.derive_from_maps=true: tolerances from the maps' own noise, plugin.map_noise)."""
    from ..cli import main as cli

    sessions, times = naip_sessions(naip, work, extra_args, map_args)
    out: dict = {"preset": preset, **times}
    runs = [("2015_into_2009", sessions[0][1], sessions[1][1])]
    if both_orders:
        runs.append(("2009_into_2015", sessions[1][1], sessions[0][1]))
    if control:
        old, new = sorted(naip.glob("*.tif"))
        halves = {(t, side): half_orthophoto(t, side, work / "control" / f"{t.stem}{side}.tif")
                  for t in (old, new) for side in ("west", "east")}
        for a, b in (((old, "west"), (new, "east")), ((old, "east"), (new, "west")), ((old, "west"), (old, "east"))):
            ctrl, ctrl_times = naip_sessions(naip, work, extra_args, map_args, tifs=[halves[a], halves[b]])
            out.update({f"control_{k}": v for k, v in ctrl_times.items()})
            runs.append((f"control_{a[1]}{a[0].stem[-8:-4]}_{b[1]}{b[0].stem[-8:-4]}", ctrl[0][1], ctrl[1][1]))
        mirror = mirrored_orthophoto(new, work / "control" / f"{new.stem}mirrored.tif")
        ctrl, ctrl_times = naip_sessions(naip, work, extra_args, map_args, tifs=[old, mirror])
        out.update({f"control_{k}": v for k, v in ctrl_times.items() if "mirrored" in k})
        runs.append(("control_2009_mirrored2015", ctrl[0][1], ctrl[1][1]))
    for label, map_a, map_b in runs:
        tag = preset + "".join(f"_{kv.split('.')[-1]}" for kv in match_sets or [])
        match_dir = work / f"naip_match_{tag}_{label}"
        flags = ([] if preset == "none" else ["--preset", preset])
        flags += [x for kv in match_sets or [] for x in ("--set", kv)]
        assert cli(["match", str(map_a), str(map_b), "--out", str(match_dir), "--no-plot", *flags]) == 0
        out[label] = _score_match(map_a, map_b, match_dir)
    tag = preset + "".join(f"_{kv.split('.')[-1]}" for kv in match_sets or [])
    draw_naip_match(sorted(naip.glob("*.tif"))[0], sessions[0][1], sessions[1][1],
                    work / f"naip_match_{tag}_2015_into_2009", work / "naip_match.jpg")
    out["figure"] = str(work / "naip_match.jpg")
    return out


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
    res = poses_from_exif.run(seneca / "images", work / "poses_refined.csv", telemetry=seneca / "telemetry.csv",
                              refine=True)
    out["refine_seconds"] = time.perf_counter() - t
    out["refinement"] = res.summary["refinement"]
    for label, poses_csv, preset in [("telemetry, paper defaults", "poses.csv", "paper"),
                                     ("refined, paper defaults", "poses_refined.csv", "paper"),
                                     ("telemetry, survey preset", "poses.csv", "survey"),
                                     ("refined, survey preset", "poses_refined.csv", "survey")]:
        session = work / ("map_" + label.replace(", ", "_").replace(" ", "_"))
        inputs = map_wf.load_inputs(seneca / "images", work / poses_csv, work / "cameras.txt")
        t = time.perf_counter()
        summary = map_wf.run(load_params(preset=preset), inputs, session, overwrite=True, progress=False)
        wall = time.perf_counter() - t
        run = json.loads((session / "run.json").read_text())
        errors = np.array([p.error for p in pycolmap.Reconstruction(session / "sparse").points3D.values()])
        out[label] = {"landmarks": summary.num_landmarks,
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

    poses, epsg = read_poses_csv(poses_csv)
    step = np.gradient(poses.centers[:, :2], axis=0)  # images in capture order (file names)
    course = np.degrees(np.arctan2(step[:, 0], step[:, 1])) % 360.0
    out: dict = {}
    sessions = []
    for label, lo, hi in [("course_0-150", 0.0, 150.0), ("course_150-360", 150.0, 360.0)]:
        keep = [i for i in range(len(poses)) if lo <= course[i] < hi]
        subset_csv = work / f"poses_{label}.csv"
        write_poses_csv(subset_csv, poses.subset(keep), epsg)
        inputs = map_wf.load_inputs(seneca / "images", subset_csv, work / "cameras.txt")
        session = work / f"map_{label}"
        summary = map_wf.run(load_params(preset="survey"), inputs, session, overwrite=True, progress=False)
        out[label] = {"frames": len(keep), "landmarks": summary.num_landmarks}
        sessions.append(session)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("check", nargs="?", default="attitude",
                        choices=["attitude", "refine", "naip", "seneca", "seneca-cross"])
    parser.add_argument("session", nargs="?", type=Path, help="refine: the mapped session")
    parser.add_argument("--seneca", type=Path, default=Path("/work/shared/data/seneca"))
    parser.add_argument("--pairs", type=int, default=60)
    parser.add_argument("--poses", type=Path, help="refine: the prior poses (pose CSV)")
    parser.add_argument("--position-sigma", type=float, default=3.0)
    parser.add_argument("--attitude-sigma", type=float, default=5.0)
    parser.add_argument("--pixel-sigma", type=float, default=3.0)
    parser.add_argument("--out", type=Path, help="refine: write the refined model here")
    parser.add_argument("--naip", type=Path, default=Path("/work/shared/data/naip"))
    parser.add_argument("--preset", default="paper", help="naip: parameter preset of the match (none: defaults)")
    parser.add_argument("--match-set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="naip: override of `sosmatch match` (repeatable), e.g. association.derive_from_maps=true")
    parser.add_argument("--map-preset", help="naip: parameter preset of `sosmatch map` (default: the defaults)")
    parser.add_argument("--map-set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="naip: override of `sosmatch map` (repeatable)")
    parser.add_argument("--one-order", action="store_true", help="naip: match 2015 into 2009 only")
    parser.add_argument("--no-control", action="store_true", help="naip: skip the negative control (opposite halves)")
    parser.add_argument("--work", type=Path, default=Path("naip_work"))
    args, extra = parser.parse_known_args()
    print(machine_summary())
    if args.check == "refine":
        if args.session is None or args.poses is None:
            parser.error("refine needs SESSION and --poses")
        r = refine_check(args.session, args.poses, args.position_sigma, args.attitude_sigma, args.pixel_sigma,
                         args.out)
        st = r["stats"]
        print(f"{st['images']} images, {st['points']} points, {st['observations']} observations; sigmas: position "
              f"{args.position_sigma} m, attitude {args.attitude_sigma} deg, pixel {args.pixel_sigma} px")
        print(f"reprojection RMSE {st['reprojection_rmse_before_px']:.2f} -> {st['reprojection_rmse_after_px']:.2f}"
              f" px, median {st['reprojection_median_before_px']:.2f} -> {st['reprojection_median_after_px']:.2f} px;"
              f" point error median {r['point_error_median_before_px']:.2f} -> {r['point_error_median_after_px']:.2f}"
              f" px; poses moved {st['position_change_mean_m']:.2f} m (max {st['position_change_max_m']:.2f}),"
              f" {st['rotation_change_mean_deg']:.2f} deg (max {st['rotation_change_max_deg']:.2f});"
              f" {st['iterations']} evaluations, {st['seconds']:.1f} s")
        return
    if args.check == "seneca":
        for k, v in seneca_end_to_end(args.seneca, args.work).items():
            print(f"{k}: {v}")
        for k, v in seneca_cross_session(args.seneca, args.work, args.work / "poses_refined.csv").items():
            print(f"cross-session {k}: {v}")
        return
    if args.check == "seneca-cross":
        for k, v in seneca_cross_session(args.seneca, args.work, args.work / "poses_refined.csv").items():
            print(f"cross-session {k}: {v}")
        return
    if args.check == "naip":
        map_args = (["--preset", args.map_preset] if args.map_preset else []) + \
            [x for kv in args.map_set for x in ("--set", kv)]
        r = naip_check(args.naip, args.work, extra, args.preset, map_args, not args.one_order, not args.no_control,
                       args.match_set)
        for k, v in r.items():
            print(f"{k}: {v}")
        return
    out = attitude_check(args.seneca, args.pairs, args.poses)
    print(f"{out['pairs']} consecutive same-line pairs, median {out['median_inliers']:.0f} ORB inliers, "
          f"median image motion {out['median_speed_px']:.0f} px, matching {out['match_seconds']:.1f} s")
    print("| convention | median error px | p90 px | median after removing the pair's mean shift px | pairs best |")
    print("|---|---|---|---|---|")
    for key, r in sorted(out["results"].items(), key=lambda kv: kv[1]["median_px"]):
        print(f"| {key} | {r['median_px']:.1f} | {r['p90_px']:.1f} | {r['median_px_after_shift']:.1f} "
              f"| {r['pairs_won']} |")


if __name__ == "__main__":
    main()
