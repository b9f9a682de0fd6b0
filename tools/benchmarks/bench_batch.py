"""The multi-session bar: a batch of 4 flights (2 seasons x 2 paths over one area), locally and on Dask.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_batch [--work bench_batch] [--workers 2] [--no-dask]
        [--toy] [--poses ekf|exact] [--write]

Synthetic mode (default): `sosmatch synth` renders summer/winter x path 1/path 2 (path 2 shifted and flown in
reverse) over world seed 11 into WORK/flights (kept between runs), then `batch.run` maps them on their EKF poses,
matches all 6 pairs and merges the connected groups, once with local worker processes and once on a Dask
LocalCluster. Toy mode (`--toy`): the same 2 x 2 layout as toy mapped sessions (`sosmatch.tools.toy_sessions`,
no images; each session in its own rotated and shifted frame), which exercises the real association search,
the graph and merge without the image front end.

Checked and printed: pairs matched; per pair the footprint overlap, the match's own decision and the error of
its consensus transform, then the verified alignment (`sosmatch match`'s verification stage,
`plugin.verification.verify_search`: every window hypothesis refined on the full maps, the best supported one
wins): accepted or not, its support (mutual nearest
neighbours) and the runner-up's, and its error against the truth as (RMS displacement at the overlap in metres,
rotation angle in degrees) and in the 4 degrees of freedom of gravity-aligned maps (horizontal RMS displacement,
yaw difference). Truth: for synthetic flights, each session's frame is its EKF frame, which no rigid transform
maps onto the world (drift and attitude error bend it by 1-2 m, mostly in height); the truth of a pair is the
rigid fit of B's to A's EKF-frame images of a 4 m ground grid (`ekf_frame_points`: what a perfect front end would
triangulate), over the points both sessions see in >= 6 frames; its residual is printed as the "truth fit RMS".
With `--poses exact` the flights are mapped on their exact poses, every map is a rigid image of the world and the truth
is exact (the identity; `OUT` is WORK/synth-exact, the rendered flights are shared). For toy flights the truth is
exact. Then `colmap model_analyzer` (COLMAP 3.8) on every merged model, and whether
the Dask run's report and merged models equal the local run's. `--write` puts the table into BENCHMARKS.md
between `<!-- section:multi-session -->` and `<!-- end:multi-session -->` (one block per mode).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from ...plugin.multisession import Sim3, transform_error, umeyama
from .machine import machine_summary

WORLD_SEED = 11
MARKER, END_MARKER = "<!-- section:multi-session -->", "<!-- end:multi-session -->"
ERR_M, ERR_DEG = 1.0, 1.0
FLIGHTS = {  # name: (season, path 2?)
    "summer-p1": ("summer", False),
    "summer-p2": ("summer", True),
    "winter-p1": ("winter", False),
    "winter-p2": ("winter", True),
}


# --- inputs ------------------------------------------------------------------------------------------------------


def synth_flights(root: Path) -> dict[str, Path]:
    """Render the four synthetic flights unless they exist."""
    from ...workflows.synth import SynthConfig
    from ...workflows.synth import run as synth

    out = {}
    for k, (name, (season, path2)) in enumerate(FLIGHTS.items()):
        d = root / name
        if not (d / "session.json").exists():
            cfg = SynthConfig(world_seed=WORLD_SEED, season=season, session_seed=k + 1,
                              shift_m=(30.0, 20.0) if path2 else (0.0, 0.0), reverse=path2)
            t = time.perf_counter()
            synth(d, cfg)
            print(f"synth {name}: {time.perf_counter() - t:.1f} s", flush=True)
        out[name] = d
    return out


MIN_VIEWS = 6  # as landmarks: tracks with more than theta_n = 5 observations (fewer: too short a baseline)
GRID_M = 4.0  # spacing of the ground points the truth is fitted on


def ekf_frame_points(flight: Path, points: np.ndarray) -> np.ndarray:
    """Where a perfect front end would map world `points` (N,3) in the session's (EKF) frame; NaN rows for
    points seen (inside the image, in front of the camera) in fewer than MIN_VIEWS frames.

    Each point is projected into every frame with the TRUE pose, the pixel's ray is re-cast from the EKF pose,
    and the rays are intersected (least-squares midpoint). The result holds exactly the session's pose errors
    (drift, attitude error at the 100 m lever arm, the depth error of short baselines) and none of
    segmentation's or tracking's noise or bias.
    """
    from ...database.synth_session import load_synth_session
    from ...plugin.geometry import project

    s = load_synth_session(flight)
    cam = s.camera
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a, b = np.zeros((len(pts), 3, 3)), np.zeros((len(pts), 3))
    views = np.zeros(len(pts), np.int64)
    for f in range(len(s.poses)):
        r, c = s.poses.rotations[f], s.poses.centers[f]
        uv, depth = project(cam, r, c, pts)
        vis = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
        u = ((pts[vis] - c) @ r) @ s.ekf_poses.rotations[f].T  # same camera-frame direction, EKF attitude
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        proj = np.eye(3)[None] - u[:, :, None] * u[:, None, :]  # (I - u u^T): squared distance to the ray
        a[vis] += proj
        b[vis] += proj @ s.ekf_poses.centers[f]
        views[vis] += 1
    out = np.full((len(pts), 3), np.nan)
    ok = views >= MIN_VIEWS
    out[ok] = np.linalg.solve(a[ok], b[ok][:, :, None])[:, :, 0]
    return out


def ground_grid(flights: dict[str, Path]) -> np.ndarray:
    """Terrain points every GRID_M metres over the flights' footprints (bare earth, world frame)."""
    from ...database.synth_session import load_synth_session

    first = load_synth_session(next(iter(flights.values())))
    corners = np.vstack([np.asarray(f["footprint"]) for p in flights.values()
                         for f in json.loads((p / "frames.json").read_text()) if f.get("footprint")])
    lo, hi = corners.min(0), corners.max(0)
    x, y = np.meshgrid(np.arange(lo[0], hi[0], GRID_M), np.arange(lo[1], hi[1], GRID_M))
    x, y = x.ravel(), y.ravel()
    return np.column_stack([x, y, first.terrain.height_at(x, y)])


def synth_pair_truth(ekf_a: np.ndarray, ekf_b: np.ndarray) -> tuple[Sim3, np.ndarray, float]:
    """The true a_from_b of two sessions mapped on EKF poses, the points to measure errors at, and the fit RMS.

    Neither session's frame is a rigid image of the world (EKF drift and attitude error bend each map by
    ~1-2 m, mostly in height), so "the" true transform is a definition. Here: the rigid least-squares fit of
    B's EKF-frame ground points to A's (`ekf_frame_points` on one grid) over every point both sessions saw,
    i.e. the best rigid alignment of the two maps a perfect front end would produce, where they overlap.
    Returns (a_from_b, those points in B's frame, RMS residual of the fit = the bend no rigid transform removes).
    """
    ok = np.isfinite(ekf_a[:, 0]) & np.isfinite(ekf_b[:, 0])
    pa, pb = ekf_a[ok], ekf_b[ok]
    truth = umeyama(pb, pa)
    rms = float(np.sqrt(np.mean(np.sum((truth.apply(pb) - pa) ** 2, axis=1))))
    return truth, pb, rms


def synth_footprints(flight: Path) -> object:
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    frames = json.loads((flight / "frames.json").read_text())
    return unary_union([Polygon(f["footprint"]) for f in frames if f.get("footprint")])


def toy_flights(root: Path) -> dict[str, Path]:
    from ..toy_sessions import lawnmower, make_world, write_toy_session, yaw_transform

    world = make_world(600, extent_m=400, seed=WORLD_SEED)
    out = {}
    for k, name in enumerate(FLIGHTS):
        path2 = FLIGHTS[name][1]
        x0 = 130.0 if path2 else 40.0
        frame = yaw_transform(37.0 * k, (10.0 * k, -7.0 * k, 0.5 * k))
        write_toy_session(root / name, world, lawnmower(x0, x0 + 200, 60, 300, 60, 40, 8), frame, seed=100 + k)
        out[name] = root / name
    return out


def toy_truth(flight: Path) -> Sim3:
    from ..toy_sessions import load_toy_session

    return load_toy_session(flight).session_from_world.inverse()


def toy_footprints(flight: Path) -> object:
    """Ground footprints of a toy flight (nadir camera over z = 0), from poses.csv in the session frame."""
    from shapely.geometry import box
    from shapely.ops import unary_union

    from ...database.poses import read_poses_csv
    from ..toy_sessions import TOY_CAMERA

    poses, _ = read_poses_csv(flight / "poses.csv")
    world = toy_truth(flight).apply(poses.centers)
    hw = world[:, 2] * TOY_CAMERA.width / 2 / TOY_CAMERA.fx
    hh = world[:, 2] * TOY_CAMERA.height / 2 / TOY_CAMERA.fy
    return unary_union([box(x - w, y - h, x + w, y + h) for (x, y, _), w, h in zip(world, hw, hh)])


# --- checks ------------------------------------------------------------------------------------------------------


def _normalised(out: Path) -> dict:
    data = json.loads((out / "report.json").read_text().replace(str(out), "OUT"))
    for key in ("executor", "seconds"):
        data.pop(key)
    for item in data["sessions"] + data["pairs"] + data["groups"]:
        item.pop("seconds", None)
        item.pop("resumed", None)
    return data


def _same_models(out_a: Path, out_b: Path) -> bool:
    for merged in sorted((out_a / "merged").glob("*")):
        other = out_b / "merged" / merged.name
        for name in ("landmarks.sosmap", "landmarks.csv", "sparse/points3D.bin", "sparse/images.bin"):
            if not (other / name).exists() or (merged / name).read_bytes() != (other / name).read_bytes():
                return False
    return True


def _model_analyzer(sparse: Path) -> str:
    colmap = shutil.which("colmap")
    if colmap is None:
        return "colmap not installed"
    res = subprocess.run([colmap, "model_analyzer", "--path", str(sparse)], capture_output=True, text=True,
                         timeout=300)
    if res.returncode != 0:
        return f"FAILED ({res.stderr.strip().splitlines()[-1] if res.stderr.strip() else res.returncode})"
    stats = dict(line.split(":", 1) for line in res.stdout.splitlines() if ":" in line)
    return f"ok ({stats['Registered images'].strip()} images, {stats['Points'].strip()} points)"


def _errors(est: Sim3, truth: Sim3, pts: np.ndarray) -> tuple[float, float, float, float, float]:
    """(RMS displacement m, rotation deg, horizontal RMS displacement m, yaw difference deg, mean vertical
    displacement m) at `pts`."""
    from ...plugin.association.rigid import roll_pitch_yaw_deg

    err_m, err_deg = transform_error(est, truth, pts)
    d = est.apply(pts) - truth.apply(pts)
    yaw = roll_pitch_yaw_deg(est.rotation)[2] - roll_pitch_yaw_deg(truth.rotation)[2]
    return (err_m, err_deg, float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))),
            abs((yaw + 180.0) % 360.0 - 180.0), float(np.mean(d[:, 2])))


def evaluate(report: dict, flights: dict[str, Path], pair_truth: object, footprint_fn: object) -> list[dict]:
    """Per pair: overlap, accepted, support, the final transform's error against the truth (and the match's
    consensus transform's, before verification)."""
    prints = {n: footprint_fn(p) for n, p in flights.items()}
    rows = []
    for p in report["pairs"]:
        a, b = p["a"], p["b"]
        inter = prints[a].intersection(prints[b]).area
        overlap = inter / min(prints[a].area, prints[b].area)
        truth, pts, fit_rms = pair_truth(a, b)
        row = {"pair": p["pair"], "status": p["status"], "overlap": overlap, "accepted": p.get("accepted"),
               "S": p.get("num_associations"), "err": None, "before": None, "fit_rms": fit_rms,
               "match_accepted": p.get("match_accepted", p.get("accepted")), "runner_up": p.get("runner_up_support")}
        if p["status"] == "done" and p.get("transform"):
            row["err"] = _errors(Sim3.from_dict(p["transform"]), truth, pts)
        before = p.get("match_transform", p.get("transform") if "match_transform" not in p else None)
        if p["status"] == "done" and before:
            row["before"] = _errors(Sim3.from_dict(before), truth, pts)
        rows.append(row)
    return rows


def step_errors(report: dict, pair_truth: object) -> list[str]:
    """Table rows: what each refinement step does to the match's consensus transform, per pair (errors as in the
    main table: m / deg, then horizontal m / yaw deg). Steps: the consensus (one group of agreeing windows);
    `merge_pairs.refine_transform` (one 6-DOF refit on the consensus' associations within theta_eps);
    `refine_alignment` 6-DOF and 4-DOF (iterated mutual nearest neighbours on the full maps, size-gated, Huber)."""
    from ...database.match_io import read_match
    from ...database.session_io import read_session
    from ...plugin.params import Params
    from ...plugin.refinement import refine_alignment
    from ...workflows.merge_pairs import refine_transform

    ap = Params().association
    sessions = {s["name"]: s["session"] for s in report["sessions"]}
    rows = []
    for p in report["pairs"]:
        if p["status"] != "done" or not p.get("match_transform"):
            continue
        truth, pts, _ = pair_truth(p["a"], p["b"])
        a, b = read_session(sessions[p["a"]]), read_session(sessions[p["b"]])
        m = read_match(p["match"])
        la, lb = a.landmarks, b.landmarks
        one, _ = refine_transform(a, b, m.associations, m.transform, False, ap.distance_tolerance_m)
        steps = [m.transform, one] + [
            refine_alignment(la.positions, la.sizes, lb.positions, lb.sizes, m.transform, ap.distance_tolerance_m,
                             ap.max_size_difference, dof=dof).transform for dof in (6, 4)]
        cells = [f"{e[0]:.2f} / {e[1]:.2f} ({e[2]:.2f} / {e[3]:.2f})" for e in (_errors(t, truth, pts) for t in steps)]
        rows.append(f"| {p['pair']} | {p['match_associations']} | " + " | ".join(cells) + " |")
    return rows


def write_benchmarks(path: Path, mode: str, text: str) -> None:
    """Put `text` into BENCHMARKS.md inside the multi-session section, in this mode's own block (toy and synth
    results live side by side; re-running one mode replaces only its block)."""
    doc = path.read_text()
    begin, end = f"<!-- multi-session:{mode} -->", f"<!-- end multi-session:{mode} -->"
    block = f"{begin}\n### Batch of 4 {mode} flights\n\n{text}\n{end}"
    if begin in doc and end in doc:
        doc = doc[: doc.index(begin)] + block + doc[doc.index(end) + len(end):]
    elif END_MARKER in doc:
        doc = doc.replace(END_MARKER, f"{block}\n{END_MARKER}")
    else:
        doc = doc.replace(MARKER, f"{MARKER}\n## Multi-session: merge and batch\n\n{block}\n{END_MARKER}")
    path.write_text(doc)


def _fmt(v: object, nd: int = 2) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=Path("bench_batch"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--toy", action="store_true", help="toy mapped sessions instead of rendered flights")
    ap.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    ap.add_argument("--poses", choices=["ekf", "exact"], default="ekf",
                    help="synth flights: map on the noisy EKF poses (default) or on the exact poses, where every "
                         "map is a rigid image of the world and the truth is exact")
    ap.add_argument("--resume", action="store_true",
                    help="keep finished tasks of an earlier run (wall times then measure only what was redone)")
    args = ap.parse_args(argv)

    from ...workflows import batch
    from ...workflows.executors import DaskExecutor, LocalExecutor

    machine = machine_summary()
    print(machine, flush=True)
    mode = "toy" if args.toy else "synth" if args.poses == "ekf" else "synth-exact"
    work = args.work / mode
    flights_dir = args.work / ("toy" if args.toy else "synth") / "flights"  # exact and EKF runs share the flights
    if args.toy:
        flights = toy_flights(flights_dir)
        footprint_fn = toy_footprints

        def pair_truth(a: str, b: str) -> tuple[Sim3, np.ndarray, float]:
            from ...database.session_io import read_session

            pts = read_session(flights[b]).landmarks.positions
            return toy_truth(flights[a]).inverse().compose(toy_truth(flights[b])), pts, 0.0
    else:
        flights = synth_flights(flights_dir)
        footprint_fn = synth_footprints
        grid = ground_grid(flights)
        ekf = {n: ekf_frame_points(p, grid) for n, p in flights.items()}

        def pair_truth(a: str, b: str) -> tuple[Sim3, np.ndarray, float]:
            if args.poses == "exact":  # both maps are in the world frame: the truth is the identity
                seen = np.isfinite(ekf[a][:, 0]) & np.isfinite(ekf[b][:, 0])
                return Sim3.identity(), grid[seen], 0.0
            return synth_pair_truth(ekf[a], ekf[b])
    options = batch.BatchOptions(ekf=args.poses == "ekf", progress=True)
    runs = {}
    for name in ("local",) + (() if args.no_dask else ("dask",)):
        out = work / f"out_{name}"
        if not args.resume:
            shutil.rmtree(out, ignore_errors=True)  # a bench measures a full run, not a resumed one
        t = time.perf_counter()
        ex = LocalExecutor(args.workers) if name == "local" else DaskExecutor(workers=args.workers)
        with ex:
            rep = batch.run(flights_dir, out, executor=ex, options=options)
        runs[name] = (out, rep, time.perf_counter() - t)
        print(f"{name}: {runs[name][2]:.1f} s, ok={rep.ok}, failures={rep.failures}", flush=True)

    out, rep, _ = runs["local"]
    report = json.loads((out / "report.json").read_text())
    rows = evaluate(report, flights, pair_truth, footprint_fn)
    matched = sum(r["status"] == "done" for r in rows)
    overlapping = [r for r in rows if r["overlap"] > 0.1]
    aligned = [r for r in overlapping if r["accepted"] and r["err"] is not None
               and r["err"][0] <= ERR_M and r["err"][1] <= ERR_DEG]
    aligned4 = [r for r in overlapping if r["accepted"] and r["err"] is not None
                and r["err"][2] <= ERR_M and r["err"][3] <= ERR_DEG]
    analyzer = {g["reference"]: _model_analyzer(out / "merged" / g["reference"] / "sparse")
                for g in report["groups"] if g.get("status") == "done"}
    identical = None
    if "dask" in runs:
        identical = _normalised(out) == _normalised(runs["dask"][0]) and _same_models(out, runs["dask"][0])

    lines = [
        f"Command: `.venv/bin/python -m sosmatch.tools.benchmarks.bench_batch{' --toy' if args.toy else ''}"
        f"{' --poses exact' if args.poses == 'exact' and not args.toy else ''} "
        f"--workers {args.workers}` ({mode} flights: 2 seasons x 2 paths, world seed {WORLD_SEED}, "
        f"{'toy mapped sessions, each in its own frame' if args.toy else f'mapped on {args.poses.upper()} poses'}).",
        f"Machine: {machine}.", "",
        "| pair | overlap | truth fit RMS m | match: accepted, error m / deg | verified: accepted, support "
        "(runner-up) | error m / deg (RMS at the overlap) | horizontal m / yaw deg | mean vertical offset m |",
        "|---|---|---|---|---|---|---|---|",
    ]
    def pair_cell(e: tuple | None, k: int) -> str:
        return "-" if e is None else f"{e[k]:.2f} / {e[k + 1]:.2f}"

    for r in rows:
        lines.append(f"| {r['pair']} | {r['overlap']:.2f} | {r['fit_rms']:.2f} | {_fmt(r['match_accepted'])}, "
                     f"{pair_cell(r['before'], 0)} | {_fmt(r['accepted'])}, {_fmt(r['S'])} ({_fmt(r['runner_up'])}) "
                     f"| {pair_cell(r['err'], 0)} | {pair_cell(r['err'], 2)} | "
                     f"{'-' if r['err'] is None else format(r['err'][4], '.2f')} |")
    sessions = ", ".join(f"{s['name']} {s.get('landmarks', '-')}" for s in report["sessions"])
    lines += [
        "",
        f"- Landmarks per session: {sessions}.",
        f"- Pairs matched: {matched}/6 (bar: 6). Overlapping pairs (footprint overlap > 0.1) accepted and aligned "
        f"within {ERR_M:g} m and {ERR_DEG:g} deg: {len(aligned)}/{len(overlapping)} (bar: all); in the "
        f"horizontal and yaw (the 4 degrees of freedom of gravity-aligned maps): {len(aligned4)}/{len(overlapping)}.",
        f"- Merged groups: {', '.join(' + '.join(g['members']) for g in report['groups'])}; "
        f"`colmap model_analyzer`: {'; '.join(f'{k}: {v}' for k, v in analyzer.items()) or 'no merged group'}.",
        f"- Wall time{' (resumed run: finished tasks reused)' if args.resume else ''}: "
        f"local ({args.workers} processes) {runs['local'][2]:.1f} s"
        + (f", Dask LocalCluster ({args.workers} workers) {runs['dask'][2]:.1f} s; Dask results identical to "
           f"local (report and merged models byte for byte): {identical}." if "dask" in runs else "."),
    ]
    steps = step_errors(report, pair_truth)
    if steps:
        lines += [
            "", "Each refinement step applied to the match's consensus transform (error m / deg, in brackets "
            "horizontal m / yaw deg; right only where the consensus was right):", "",
            "| pair | consensus \\|S\\| | consensus | one 6-DOF refit (merge_pairs.refine_transform) | "
            "full-map ICP 6-DOF | full-map ICP 4-DOF |", "|---|---|---|---|---|---|", *steps,
        ]
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_benchmarks(Path(__file__).resolve().parents[2] / "BENCHMARKS.md", mode, text)
    ok = matched == 6 and len(aligned) == len(overlapping) and all(v.startswith("ok") for v in analyzer.values())
    return 0 if ok and identical is not False else 1


if __name__ == "__main__":
    raise SystemExit(main())
