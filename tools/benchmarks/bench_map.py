"""Benchmark of `sosmatch map` on a synthetic session (`sosmatch synth`), with exact and with EKF poses.

Runs the real command line (`sosmatch map`, a subprocess, timed as a whole: imports, segmentation, tracking,
database, triangulation, outputs) on the first `--frames` frames and scores the result against the session's
ground truth:
- object of a landmark: the object id under each observed centroid in labels/ (uint16 per pixel, 0 =
  background), majority vote; observations are read back from the sparse/ model (keypoints = mask centroids);
- position error: landmark against its object's visible-top centre (objects.csv x, y, z), median horizontal
  and median vertical, over landmarks whose majority id is an object;
- purity: fraction of landmark tracks whose observations all hit one id (background counts as an id);
- coverage: of the objects visible in >= 6 keyframes (frames.json), the fraction that became a landmark;
- map bytes per landmark (landmarks.sosmap size / count, header included) and the run's wall and CPU time.
- pipeline error: the same medians against the object's *centroid point*, the least-squares intersection of the
  rays through the object's ground-truth label centroids in the keyframes (masks >= 30 px that do not touch the
  image border, exact poses). A mask centroid of a tall object is not its top: in a perspective view the visible
  region of a tree or a building spans from its top down its side, so its centroid triangulates well below the
  top (measured on the synth sessions: about -h/2 to -h). The centroid point is what a perfect segmenter +
  tracker + triangulator would return, so the distance to it is the error the pipeline adds.

With `--gt-masks` the back end (tracking, database, triangulation) is also run in-process on the ground-truth
label masks instead of the segmentation backend: what the mapping stage does with perfect segments.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_map SESSION [--frames 100] [--repeats 1] [--out DIR]
        [--gt-masks]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .machine import machine_summary

MIN_KEYFRAMES_SEEN = 6


def _labels(path: Path) -> np.ndarray:
    import cv2

    lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if lab is None:
        raise FileNotFoundError(path)
    return lab


def centroid_points(synth: object, names: list[str], label_cache: dict[str, np.ndarray]) -> dict[int, np.ndarray]:
    """Object id -> least-squares intersection of the rays through its label centroids in the frames `names`."""
    from ...plugin.geometry import pixel_rays

    index = {n: i for i, n in enumerate(synth.poses.names)}
    normal: dict[int, np.ndarray] = {}
    rhs: dict[int, np.ndarray] = {}
    count: dict[int, int] = {}
    for name in names:
        if name not in label_cache:
            label_cache[name] = _labels(synth.label_path(name))
        lab = label_cache[name].astype(np.int64)
        h, w = lab.shape
        ids, inv, cnt = np.unique(lab.ravel(), return_inverse=True, return_counts=True)
        rows, cols = np.indices(lab.shape)
        sx = np.bincount(inv, cols.ravel())
        sy = np.bincount(inv, rows.ravel())
        border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        i = index[name]
        center, r_wc = synth.poses.centers[i], synth.poses.rotations[i]
        for k, oid in enumerate(ids):
            if oid == 0 or cnt[k] < 30 or oid in border:
                continue
            uv = np.array([[sx[k] / cnt[k] + 0.5, sy[k] / cnt[k] + 0.5]])
            d = pixel_rays(synth.camera, uv, r_wc)[0]
            d /= np.linalg.norm(d)
            proj = np.eye(3) - np.outer(d, d)
            normal[int(oid)] = normal.get(int(oid), 0) + proj
            rhs[int(oid)] = rhs.get(int(oid), 0) + proj @ center
            count[int(oid)] = count.get(int(oid), 0) + 1
    return {oid: np.linalg.solve(normal[oid], rhs[oid]) for oid in normal if count[oid] >= 3}


def landmark_objects(synth: object, mapped: Path, label_cache: dict[str, np.ndarray] | None = None,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The object of each landmark of a mapped synthetic session: the object id under each observed centroid in
    labels/ (0 = background), majority vote over the track read back from sparse/. Returns ((N,) ids, (N,) bool
    purity: all observations on one id)."""
    import pycolmap

    from ...database.session_io import read_landmark_point_ids

    pids = read_landmark_point_ids(mapped / "landmarks.csv")
    rec = pycolmap.Reconstruction(str(mapped / "sparse"))
    tracks = []
    for pid in pids:
        obs = []
        for el in rec.points3D[int(pid)].track.elements:
            image = rec.images[el.image_id]
            obs.append((image.name, *np.asarray(image.points2D[el.point2D_idx].xy, dtype=np.float64)))
        tracks.append(obs)
    return track_objects(synth, tracks, label_cache)


def track_objects(synth: object, tracks: list[list[tuple[str, float, float]]],
                  label_cache: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The object of each track of observations (image name, u, v in COLMAP pixels): the object id under each
    observation in labels/ (0 = background), majority vote. Returns ((N,) ids, (N,) bool purity)."""
    label_cache = {} if label_cache is None else label_cache
    majority, pure = [], []
    for obs in tracks:
        ids = []
        for name, u, v in obs:
            if name not in label_cache:
                label_cache[name] = _labels(synth.label_path(name))
            lab = label_cache[name]
            col = int(np.clip(np.floor(u), 0, lab.shape[1] - 1))  # COLMAP: pixel i spans [i, i + 1)
            row = int(np.clip(np.floor(v), 0, lab.shape[0] - 1))
            ids.append(int(lab[row, col]))
        values, counts = np.unique(ids, return_counts=True)
        majority.append(int(values[np.argmax(counts)]))
        pure.append(len(values) == 1)
    return np.array(majority, dtype=np.int64), np.array(pure, dtype=bool)


def score_session(session_dir: Path, mapped: Path) -> dict[str, float]:
    """Ground-truth figures of a mapped session (see the module docstring)."""

    from ...database.landmark_map import read_landmark_map
    from ...database.synth_session import load_synth_session

    synth = load_synth_session(session_dir)
    lmap = read_landmark_map(mapped / "landmarks.sosmap")
    run = json.loads((mapped / "run.json").read_text())
    objects = {int(o["id"]): o for o in synth.objects}
    label_cache: dict[str, np.ndarray] = {}
    majority_arr, pure = landmark_objects(synth, mapped, label_cache)
    on_object = np.flatnonzero(majority_arr > 0)
    err_h, err_v = [], []
    for i in on_object:
        o = objects[int(majority_arr[i])]
        d = lmap.positions[i] - np.array([o["x"], o["y"], o["z"]])
        err_h.append(float(np.hypot(d[0], d[1])))
        err_v.append(float(abs(d[2])))
    refs = centroid_points(synth, run["keyframes"], label_cache)
    pipe_h, pipe_v = [], []
    for i in on_object:
        ref = refs.get(int(majority_arr[i]))
        if ref is not None:
            d = lmap.positions[i] - ref
            pipe_h.append(float(np.hypot(d[0], d[1])))
            pipe_v.append(float(abs(d[2])))
    keyframes = set(run["keyframes"])
    seen: dict[int, int] = {}
    for frame in synth.frames:
        if frame["name"] in keyframes:
            for oid in frame["visible_object_ids"]:
                seen[int(oid)] = seen.get(int(oid), 0) + 1
    eligible = {oid for oid, n in seen.items() if n >= MIN_KEYFRAMES_SEEN}
    mapped_objects = set(majority_arr[on_object].tolist())
    size = (mapped / "landmarks.sosmap").stat().st_size
    return {
        "keyframes": len(keyframes),
        "landmarks": len(lmap),
        "on_object": len(on_object),
        "median_h_m": float(np.median(err_h)) if err_h else float("nan"),
        "median_v_m": float(np.median(err_v)) if err_v else float("nan"),
        "pipe_h_m": float(np.median(pipe_h)) if pipe_h else float("nan"),
        "pipe_v_m": float(np.median(pipe_v)) if pipe_v else float("nan"),
        "purity": float(np.mean(pure)) if len(pure) else float("nan"),
        "coverage": len(eligible & mapped_objects) / len(eligible) if eligible else float("nan"),
        "eligible_objects": len(eligible),
        "bytes_per_landmark": size / len(lmap) if len(lmap) else float("nan"),
    }


class LabelMasks:
    """`masks_for` of the map workflow: the session's label image as masks (one per object id, no background)."""

    def __init__(self, session: Path) -> None:
        self.labels = Path(session) / "labels"

    def __call__(self, name: str, image: np.ndarray) -> object:
        from ...plugin.segmentation import MaskSet

        lab = _labels(self.labels / (Path(name).stem + ".png")).astype(np.int64)
        return MaskSet.from_labels(np.where(lab > 0, lab, -1))


def run_map_gt_masks(session: Path, frames: int, ekf: bool, out: Path) -> tuple[float, float]:
    """The map workflow in-process with ground-truth masks; returns (wall s, CPU s of this process)."""
    from ...plugin.params import Params
    from ...workflows import map as map_workflow

    with tempfile.TemporaryDirectory(prefix="bench-map-") as tmp:
        poses = _pose_subset(session, frames, ekf, Path(tmp))
        shutil.rmtree(out, ignore_errors=True)
        inputs = map_workflow.load_inputs(session / "images", poses, session / "cameras.txt")
        t, c = time.perf_counter(), time.process_time()
        summary = map_workflow.run(Params(), inputs, out, progress=False, masks_for=LabelMasks(session))
        seconds, cpu = time.perf_counter() - t, time.process_time() - c
    print("   ", summary.line(), f"(wall {seconds:.1f} s, CPU {cpu:.1f} s)")
    return seconds, cpu


def _pose_subset(session: Path, frames: int, ekf: bool, work: Path) -> Path:
    """A pose CSV holding the first `frames` rows of the session's (EKF) poses."""
    src = session / ("poses_ekf.csv" if ekf else "poses.csv")
    out_lines, rows = [], 0
    for line in src.read_text().splitlines():
        is_row = line and not line.startswith("#") and not line.startswith("name,")
        if is_row:
            if rows >= frames:
                continue
            rows += 1
        out_lines.append(line)
    path = work / ("poses_ekf.csv" if ekf else "poses.csv")
    path.write_text("\n".join(out_lines) + "\n")
    return path


def run_map(session: Path, frames: int, ekf: bool, out: Path, extra: list[str]) -> tuple[float, float]:
    """Run `sosmatch map` on the first `frames` frames; returns (wall seconds, CPU seconds user + system).

    CPU time is reported because the wall time on a shared machine mostly measures the other processes."""
    with tempfile.TemporaryDirectory(prefix="bench-map-") as tmp:
        poses = _pose_subset(session, frames, ekf, Path(tmp))
        shutil.rmtree(out, ignore_errors=True)
        cmd = [sys.executable, "-m", "sosmatch.tools.cli", "map", "-q", "--no-progress",
               "--images", str(session / "images"), "--poses", str(poses),
               "--camera", str(session / "cameras.txt"), "--out", str(out), *extra]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        seconds = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise SystemExit(f"sosmatch map failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    print("   ", proc.stdout.strip(), f"(wall {seconds:.1f} s, CPU {cpu:.1f} s)")
    return seconds, cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("session", type=Path, help="a `sosmatch synth` session directory")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=1, help="runs per pose set; the median time is reported")
    ap.add_argument("--out", type=Path, help="keep the mapped sessions here (default: a temporary directory)")
    ap.add_argument("--gt-masks", action="store_true", help="also run with ground-truth label masks")
    ap.add_argument("--score-only", action="store_true", help="score the sessions already mapped in --out")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="passed to sosmatch map")
    ap.add_argument("--poses", choices=("both", "exact", "ekf"), default="both", help="pose sets to run")
    args = ap.parse_args(argv)
    extra = [a for o in args.overrides for a in ("--set", o)]
    print(machine_summary())
    print(f"session {args.session}, first {args.frames} frames")
    header = ("| poses | keyframes | landmarks (on objects) | median horiz. / vert. error to visible top m | "
              "median horiz. / vert. error to centroid point m | purity | objects seen in >= 6 kf mapped | "
              "bytes/landmark | run s wall / CPU |")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-map-out-") as tmp:
        root = args.out or Path(tmp)
        variants = [(False, False), (True, False)] + ([(False, True), (True, True)] if args.gt_masks else [])
        if args.poses != "both":
            variants = [v for v in variants if v[0] == (args.poses == "ekf")]
        for ekf, gt in variants:
            out = root / (("map_ekf" if ekf else "map_exact") + ("_gtmasks" if gt else ""))
            if args.score_only:
                times = [(json.loads((out / "run.json").read_text())["timings_s"]["total"], float("nan"))]
            else:
                times = [run_map_gt_masks(args.session, args.frames, ekf, out) if gt
                         else run_map(args.session, args.frames, ekf, out, extra) for _ in range(args.repeats)]
            s = score_session(args.session, out)
            rows.append(
                f"| {'EKF' if ekf else 'exact'}{', GT masks' if gt else ''} | {s['keyframes']} | "
                f"{s['landmarks']} ({s['on_object']}) | "
                f"{s['median_h_m']:.2f} / {s['median_v_m']:.2f} | {s['pipe_h_m']:.2f} / {s['pipe_v_m']:.2f} | "
                f"{s['purity']:.3f} | {s['coverage']:.2f} of {s['eligible_objects']} | "
                f"{s['bytes_per_landmark']:.1f} | {statistics.median(t[0] for t in times):.1f} / "
                f"{statistics.median(t[1] for t in times):.1f} |"
            )
    print(header)
    print("|" + "---|" * 9)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
