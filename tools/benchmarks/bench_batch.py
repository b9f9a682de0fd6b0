"""The multi-session bar: a batch of 4 flights (2 seasons x 2 paths over one area), locally and on Dask.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_batch [--work bench_batch] [--workers 2] [--no-dask]
        [--toy] [--write]

Synthetic mode (default): `sosmatch synth` renders summer/winter x path 1/path 2 (path 2 shifted and flown in
reverse) over world seed 11 into WORK/flights (kept between runs), then `batch.run` maps them on their EKF poses,
matches all 6 pairs and merges the connected groups, once with local worker processes and once on a Dask
LocalCluster. Toy mode (`--toy`): the same 2 x 2 layout as toy mapped sessions (`sosmatch.tools.toy_sessions`,
no images; each session in its own rotated and shifted frame), which exercises the real association search,
the graph and merge without the image front end.

Checked and printed: pairs matched; per pair the footprint overlap, accepted or not, |S|, and the transform
error against the truth as (RMS displacement of B's landmarks in metres, rotation angle in degrees). Truth:
for synthetic flights, each session's frame is its EKF frame, so world_from_session is the rigid least-squares
fit of its EKF camera centres to the true ones (the EKF drift that remains is part of the error budget); for toy
flights it is exact. Then `colmap model_analyzer` (COLMAP 3.8) on every merged model, and whether the Dask run's
report and merged models equal the local run's. `--write` puts the table into BENCHMARKS.md between
`<!-- section:multi-session -->` and `<!-- end:multi-session -->` (one block per mode).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path

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


def synth_truth(flight: Path) -> Sim3:
    """world_from_session for a synth flight mapped on its EKF poses."""
    from ...database.poses import read_poses_csv

    truth, _ = read_poses_csv(flight / "poses.csv")
    ekf, _ = read_poses_csv(flight / "poses_ekf.csv")
    return umeyama(ekf.centers, truth.centers)


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


def evaluate(report: dict, flights: dict[str, Path], truth_fn: object, footprint_fn: object) -> list[dict]:
    """Per pair: overlap, accepted, |S|, transform error against the truth."""
    from ...database.session_io import read_session

    truths = {n: truth_fn(p) for n, p in flights.items()}
    prints = {n: footprint_fn(p) for n, p in flights.items()}
    sessions = {s["name"]: s for s in report["sessions"]}
    rows = []
    for p in report["pairs"]:
        a, b = p["a"], p["b"]
        inter = prints[a].intersection(prints[b]).area
        overlap = inter / min(prints[a].area, prints[b].area)
        row = {"pair": p["pair"], "status": p["status"], "overlap": overlap, "accepted": p.get("accepted"),
               "S": p.get("num_associations"), "err_m": None, "err_deg": None}
        if p["status"] == "done" and p.get("transform"):
            t = p["transform"]
            est = Sim3(t["rotation"], t["translation"], t["scale"])
            truth = truths[a].inverse().compose(truths[b])  # a_from_b = session_a_from_world ∘ world_from_b
            pts = read_session(sessions[b]["session"]).landmarks.positions
            row["err_m"], row["err_deg"] = transform_error(est, truth, pts)
        rows.append(row)
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
    ap.add_argument("--resume", action="store_true",
                    help="keep finished tasks of an earlier run (wall times then measure only what was redone)")
    args = ap.parse_args(argv)

    from ...workflows import batch
    from ...workflows.executors import DaskExecutor, LocalExecutor

    machine = machine_summary()
    print(machine, flush=True)
    mode = "toy" if args.toy else "synth"
    work = args.work / mode
    flights_dir = work / "flights"
    if args.toy:
        flights = toy_flights(flights_dir)
        truth_fn, footprint_fn = toy_truth, toy_footprints
    else:
        flights = synth_flights(flights_dir)
        truth_fn, footprint_fn = synth_truth, synth_footprints
    options = batch.BatchOptions(ekf=True, progress=True)
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
    rows = evaluate(report, flights, truth_fn, footprint_fn)
    matched = sum(r["status"] == "done" for r in rows)
    overlapping = [r for r in rows if r["overlap"] > 0.1]
    aligned = [r for r in overlapping if r["accepted"] and r["err_m"] is not None
               and r["err_m"] <= ERR_M and r["err_deg"] <= ERR_DEG]
    analyzer = {g["reference"]: _model_analyzer(out / "merged" / g["reference"] / "sparse")
                for g in report["groups"] if g.get("status") == "done"}
    identical = None
    if "dask" in runs:
        identical = _normalised(out) == _normalised(runs["dask"][0]) and _same_models(out, runs["dask"][0])

    lines = [
        f"Command: `.venv/bin/python -m sosmatch.tools.benchmarks.bench_batch{' --toy' if args.toy else ''} "
        f"--workers {args.workers}` ({mode} flights: 2 seasons x 2 paths, world seed {WORLD_SEED}, "
        f"{'mapped on EKF poses' if not args.toy else 'toy mapped sessions, each in its own frame'}).",
        f"Machine: {machine}.", "",
        "| pair | overlap | accepted | \\|S\\| | error m (RMS at B's landmarks) | error deg |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['pair']} | {r['overlap']:.2f} | {_fmt(r['accepted'])} | {_fmt(r['S'])} | "
                     f"{_fmt(r['err_m'])} | {_fmt(r['err_deg'])} |")
    sessions = ", ".join(f"{s['name']} {s.get('landmarks', '-')}" for s in report["sessions"])
    lines += [
        "",
        f"- Landmarks per session: {sessions}.",
        f"- Pairs matched: {matched}/6 (bar: 6). Overlapping pairs (footprint overlap > 0.1) aligned within "
        f"{ERR_M:g} m and {ERR_DEG:g} deg: {len(aligned)}/{len(overlapping)} (bar: all).",
        f"- Merged groups: {', '.join(' + '.join(g['members']) for g in report['groups'])}; "
        f"`colmap model_analyzer`: {'; '.join(f'{k}: {v}' for k, v in analyzer.items()) or 'no merged group'}.",
        f"- Wall time{' (resumed run: finished tasks reused)' if args.resume else ''}: "
        f"local ({args.workers} processes) {runs['local'][2]:.1f} s"
        + (f", Dask LocalCluster ({args.workers} workers) {runs['dask'][2]:.1f} s; Dask results identical to "
           f"local (report and merged models byte for byte): {identical}." if "dask" in runs else "."),
    ]
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_benchmarks(Path(__file__).resolve().parents[2] / "BENCHMARKS.md", mode, text)
    ok = matched == 6 and len(aligned) == len(overlapping) and all(v.startswith("ok") for v in analyzer.values())
    return 0 if ok and identical is not False else 1


if __name__ == "__main__":
    raise SystemExit(main())
