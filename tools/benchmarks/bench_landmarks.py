"""What a landmark's size depends on, and which objects become landmarks in each season (issue 16), with the truth.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_landmarks sizes SESSION [SESSION ...] [--frames 25]
    .venv/bin/python -m sosmatch.tools.benchmarks.bench_landmarks funnel MAPPED_SESSION SYNTH_SESSION [...]

`sizes`: for every ground-truth object seen whole in `--frames` frames spread over each synthetic session (labels
of >= 30 px not touching the border), the size descriptor sqrt(lambda_max) and the extent across the relief
direction (sqrt(v^T Sigma v), v perpendicular to the image direction from the nadir point to the object) of its
rendered region (labels) and of the best-matching classical mask (IoU >= 0.5), in metres on the object's visible
top (x depth / f) and relative to R / 2 (the sqrt(lambda_max) of its footprint disc), by kind and off-nadir angle;
plus the mask / label ratio of sqrt(lambda_max) (what segmentation, working resolution, blur and boundary pixels
add) and the share of objects found.

`funnel`: for every object eligible in a mapped synthetic session (present, >= 30 px in >= theta_n + 1 keyframes),
by kind: in how many of its keyframes a mask centroid falls on it (segmented), its longest track (re-run from the
map's per-keyframe cache, `sosmatch map --keep-cache`), how many have a track longer than theta_n, and how many
are a landmark (majority object of a landmark's observed centroids). It says at which stage an object is lost.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .machine import machine_summary

KINDS = ("deciduous", "conifer", "bush", "boulder", "building", "pond")
ANGLES = ((0, 8), (8, 16), (16, 24), (24, 40))


def _labels(path: Path) -> np.ndarray:
    import cv2

    lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if lab is None:
        raise FileNotFoundError(path)
    return lab.astype(np.int64)


def _across_relief(cov: np.ndarray, centroid: np.ndarray, nadir: np.ndarray) -> float:
    u = centroid - nadir
    n = float(np.linalg.norm(u))
    u = u / n if n > 1e-6 else np.array([1.0, 0.0])
    v = np.array([-u[1], u[0]])
    return float(np.sqrt(max(v @ cov @ v, 0.0)))


def size_rows(session: Path, frames: int) -> list[dict]:
    """One row per (frame, object seen whole): kind, R, off-nadir angle, label and mask sizes (module doc)."""
    from ...database.images import read_image
    from ...database.synth_session import load_synth_session
    from ...plugin.geometry import project
    from ...plugin.mask_features import covariance_size, mask_moments
    from ...plugin.params import Params
    from ...plugin.segmentation import MaskSet, get_backend, mask_iou_matrix

    s = load_synth_session(session)
    seg = Params().segmentation
    backend = get_backend(seg.backend, seg)
    objects = {int(o["id"]): o for o in s.objects}
    rows = []
    for i in np.linspace(0, len(s.poses) - 1, frames).astype(int):
        name = s.poses.names[i]
        lab = _labels(s.label_path(name))
        gt = MaskSet.from_labels(np.where(lab > 0, lab, -1))
        masks = backend(read_image(s.image_path(name)))
        if len(gt) == 0 or len(masks) == 0:
            continue
        iou = mask_iou_matrix(gt, masks)
        g_area, g_cent, g_cov = mask_moments(gt)
        _, m_cent, m_cov = mask_moments(masks)
        g_h, m_h = covariance_size(g_cov), covariance_size(m_cov)
        center, r_wc = s.poses.centers[i], s.poses.rotations[i]
        nadir = project(s.camera, r_wc, center, center[None] - [0.0, 0.0, 100.0])[0][0]
        border = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])).tolist())
        for k, oid in enumerate(sorted(int(v) for v in np.unique(lab) if v > 0)):
            if oid in border or g_area[k] < 30:
                continue
            o = objects[oid]
            top = np.array([o["x"], o["y"], o["z"]])
            depth = float((r_wc.T @ (top - center))[2])
            scale = depth / s.camera.fx / (float(o["radius"]) / 2.0)
            j = int(np.argmax(iou[k]))
            found = bool(iou[k, j] >= 0.5)
            rows.append({
                "kind": str(o["kind"]), "angle": float(np.degrees(np.arctan2(np.hypot(*(top[:2] - center[:2])),
                                                                              center[2] - top[2]))),
                "label_max": float(g_h[k]) * scale, "label_across": _across_relief(g_cov[k], g_cent[k], nadir) * scale,
                "found": found, "mask_over_label": float(m_h[j] / g_h[k]) if found else float("nan"),
                "mask_max": float(m_h[j]) * scale if found else float("nan"),
                "mask_across": _across_relief(m_cov[j], m_cent[j], nadir) * scale if found else float("nan"),
            })
    return rows


def sizes_table(rows: list[dict], title: str) -> str:
    lines = [f"**{title}** (sizes x R/2, medians; mask columns over masks with IoU >= 0.5)", "",
             "| kind | off-nadir deg | n | label sqrt(lambda_max) | label across relief | mask sqrt(lambda_max) "
             "| mask across relief | mask / label | found |", "|---|---|---:|---:|---:|---:|---:|---:|---:|"]

    def med(values: list[float]) -> str:
        v = [x for x in values if np.isfinite(x)]
        return f"{np.median(v):.2f}" if v else "-"

    for kind in KINDS:
        for lo, hi in ANGLES:
            sel = [r for r in rows if r["kind"] == kind and lo <= r["angle"] < hi]
            if len(sel) < 3:
                continue
            lines.append(f"| {kind} | {lo}-{hi} | {len(sel)} | {med([r['label_max'] for r in sel])} "
                         f"| {med([r['label_across'] for r in sel])} | {med([r['mask_max'] for r in sel])} "
                         f"| {med([r['mask_across'] for r in sel])} | {med([r['mask_over_label'] for r in sel])} "
                         f"| {np.mean([r['found'] for r in sel]):.2f} |")
    return "\n".join(lines) + "\n"


def funnel(mapped: Path, session: Path) -> dict[str, dict]:
    """Per kind: eligible objects, median share of their keyframes segmented, median longest track, tracks
    longer than theta_n, landmarks (module doc)."""
    from ...database.evaluation_io import landmark_observed_objects
    from ...database.poses import read_poses_csv
    from ...database.synth_session import load_synth_session
    from ...plugin.evaluation.landmark_truth import majority_objects
    from ...plugin.mask_features import MaskFeatures
    from ...plugin.params import params_from_dict
    from ...plugin.tracking import track_masks

    s = load_synth_session(session)
    run = json.loads((mapped / "run.json").read_text(encoding="utf-8"))
    params = params_from_dict(run["params"])
    names = run["keyframes"]
    cache = sorted((mapped / ".partial" / "cache").glob("*.npz"))
    if len(cache) != len(names):
        raise SystemExit(f"{mapped}: needs the per-keyframe cache (map with --keep-cache)")
    feats, motion = [], []
    for path in cache:
        with np.load(path) as data:
            feats.append(MaskFeatures.from_npz_dict({k[5:]: data[k] for k in data.files if k.startswith("feat_")}))
            motion.append((float(data["motion"][0]), float(data["motion"][1])))
    source = Path(str(run.get("inputs", {}).get("poses", "")))
    poses, _ = read_poses_csv(source if source.suffix == ".csv" and source.is_file() else session / "poses.csv")
    row = {n: i for i, n in enumerate(poses.names)}
    tracking = track_masks(feats, s.camera, poses.subset([row[n] for n in names]), motion, params.tracking)
    visible: dict[int, int] = {}
    segmented: dict[int, set] = {}
    on_object = []
    for k, (name, f) in enumerate(zip(names, feats)):
        lab = _labels(s.label_path(name))
        ids, counts = np.unique(lab, return_counts=True)
        for oid, c in zip(ids, counts):
            if oid > 0 and c >= 30:
                visible[int(oid)] = visible.get(int(oid), 0) + 1
        c = np.clip(np.floor(f.centroids).astype(int), 0, [lab.shape[1] - 1, lab.shape[0] - 1])
        obj = lab[c[:, 1], c[:, 0]] if len(c) else np.zeros(0, np.int64)
        on_object.append(obj)
        for oid in set(obj.tolist()) - {0}:
            segmented.setdefault(oid, set()).add(k)
    longest: dict[int, int] = {}
    for t in range(tracking.num_tracks):
        kf, mk = tracking.observations(t)
        ids = np.array([on_object[a][b] for a, b in zip(kf, mk)])
        values, counts = np.unique(ids, return_counts=True)
        oid = int(values[np.argmax(counts)])
        if oid > 0:
            longest[oid] = max(longest.get(oid, 0), len(kf))
    landmarks = set(majority_objects(landmark_observed_objects(mapped, session / "labels")).object_ids.tolist())
    theta_n = params.triangulation.min_observations
    kinds = {int(o["id"]): str(o["kind"]) for o in s.objects}
    eligible = [int(o) for o in s.present_objects()["id"] if visible.get(int(o), 0) > theta_n]
    out = {}
    for kind in KINDS:
        objs = [o for o in eligible if kinds[o] == kind]
        if objs:
            out[kind] = {"eligible": len(objs),
                         "segmented_share": float(np.median([len(segmented.get(o, ())) / visible[o] for o in objs])),
                         "longest_track": float(np.median([longest.get(o, 0) for o in objs])),
                         "tracks_over_theta_n": sum(longest.get(o, 0) > theta_n for o in objs),
                         "landmarks": sum(o in landmarks for o in objs)}
    return out


def funnel_table(rows: dict[str, dict[str, dict]]) -> str:
    lines = ["| map | kind | eligible | keyframes segmented (median share) | longest track (median) "
             "| track > theta_n | landmark |", "|---|---|---:|---:|---:|---:|---:|"]
    for name, kinds in rows.items():
        for kind, r in kinds.items():
            lines.append(f"| {name} | {kind} | {r['eligible']} | {r['segmented_share']:.2f} | {r['longest_track']:.0f} "
                         f"| {r['tracks_over_theta_n']} | {r['landmarks']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("sizes")
    p.add_argument("sessions", type=Path, nargs="+")
    p.add_argument("--frames", type=int, default=25)
    p = sub.add_parser("funnel")
    p.add_argument("pairs", type=Path, nargs="+", help="MAPPED_SESSION SYNTH_SESSION, repeated")
    args = parser.parse_args(argv)
    print(machine_summary())
    if args.what == "sizes":
        for session in args.sessions:
            print(sizes_table(size_rows(session, args.frames), str(session)))
    else:
        if len(args.pairs) % 2:
            raise SystemExit("funnel takes MAPPED_SESSION SYNTH_SESSION pairs")
        rows = {str(m): funnel(m, s) for m, s in zip(args.pairs[0::2], args.pairs[1::2])}
        print(funnel_table(rows))


if __name__ == "__main__":
    main()
