"""Real-data checks (the NAIP checks are in `real_naip.py`, the Seneca ones in `real_seneca.py`).

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

from ...database.telemetry_io import read_telemetry_csv
from ...plugin.geometry import Camera
from ...workflows import poses_from_exif as pfe
from .machine import machine_summary
from .real_naip import evaluation_cases, naip_check  # noqa: F401 (evaluation_cases: bench_evaluate's real-data hook)
from .real_seneca import seneca_cross_session, seneca_end_to_end


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
    tele = read_telemetry_csv(seneca / "telemetry.csv")
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
        for k, v in seneca_cross_session(args.seneca, args.work, args.work / "refined" / "poses.csv").items():
            print(f"cross-session {k}: {v}")
        return
    if args.check == "seneca-cross":
        for k, v in seneca_cross_session(args.seneca, args.work, args.work / "refined" / "poses.csv").items():
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
