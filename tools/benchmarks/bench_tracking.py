"""Tracking parameter sweep: epipolar margin `theta_a` x max track age `theta_t`, with exact and EKF poses.

On a synthetic session (`sosmatch synth`): keyframes by travel (theta_T) on the ground-truth poses (so both pose
sets see the same keyframes), masks either from the ground-truth label images (`--masks gt`: one mask per visible
object, the tracker's own errors only) or from a segmentation backend (`--masks classical`), described by the real
front end (`describe_masks`: centroids, sizes, RootSIFT), image motion from `image_motion_stats`. The mask
description and motion statistics are computed once; then every (poses, theta_a, theta_t) runs the tracker.

Measured per run, with the object id of a mask = the label at its centroid pixel (0 = background: every such
observation counts as an object of its own):
- purity: observation-weighted share of the majority id in tracks with >= 2 observations (background 0 is an id,
  as in bench_map); object-only purity: the same over observations whose centroid is on an object, i.e. only
  object-to-object confusions (with classical masks most impurity is a segment whose centroid slides between an
  object and the ground around it);
- pure tracks: share of tracks with more than theta_n = 5 observations whose observations all hit one id;
- mean length of tracks with >= 2 observations;
- tracked: fraction of the objects seen in >= 6 keyframes that own a track with more than theta_n = 5
  observations (the ones that can become landmarks);
- tracks/object: landmark-eligible tracks per tracked object (> 1 means fragmentation into duplicates);
- time of the tracker alone (median of --repeats).

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_tracking SESSION [--frames 100] [--masks gt]
"""

from __future__ import annotations

import argparse
import itertools
import pickle
import time
from pathlib import Path

import numpy as np

from ...plugin.params import SegmentationParams, TrackingParams
from .machine import machine_summary


def _load_labels(path: Path) -> np.ndarray:
    import cv2

    lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if lab is None:
        raise FileNotFoundError(path)
    return lab.astype(np.int64)


def prepare(session: Path, frames: int, masks: str, seg: SegmentationParams) -> dict:
    """Keyframes, per-keyframe MaskFeatures + object id per mask, motion stats, camera and both pose sets."""
    from ...database.cameras import read_cameras_txt
    from ...database.images import read_image
    from ...database.poses import read_poses_csv
    from ...plugin.keyframes import select_keyframes
    from ...plugin.mask_features import describe_masks, to_gray_u8
    from ...plugin.motion import image_motion_stats
    from ...plugin.segmentation import MaskSet, get_backend

    camera = next(iter(read_cameras_txt(session / "cameras.txt").values()))
    exact, _ = read_poses_csv(session / "poses.csv")
    ekf, _ = read_poses_csv(session / "poses_ekf.csv")
    n = min(frames, len(exact)) if frames > 0 else len(exact)
    keys = select_keyframes(exact.centers[:n], 2.0)
    backend = get_backend(masks, seg) if masks != "gt" else None
    feats, objs, motion, grays = [], [], [(0.0, 0.0)], []
    t0 = time.perf_counter()
    for k in keys:
        name = exact.names[k]
        image = read_image(session / "images" / name)
        labels = _load_labels(session / "labels" / (Path(name).stem + ".png"))
        mset = MaskSet.from_labels(np.where(labels > 0, labels, -1)) if backend is None else backend(image)
        f = describe_masks(image, mset, seg)
        col = np.clip(np.floor(f.centroids[:, 0]).astype(int), 0, labels.shape[1] - 1)
        row = np.clip(np.floor(f.centroids[:, 1]).astype(int), 0, labels.shape[0] - 1)
        feats.append(f)
        objs.append(labels[row, col])
        grays.append(to_gray_u8(image))
        if len(grays) > 1:
            motion.append(image_motion_stats(grays[-2], grays[-1]))
            grays.pop(0)
    frames_json = session / "frames.json"
    visible = None
    if frames_json.exists():
        import json

        info = json.loads(frames_json.read_text())
        info = info["frames"] if isinstance(info, dict) else info
        by_name = {f["name"]: np.asarray(f.get("visible_object_ids", []), np.int64) for f in info}
        visible = [by_name.get(exact.names[k], np.zeros(0, np.int64)) for k in keys]
    ekf_names = {nm: i for i, nm in enumerate(ekf.names)}
    ekf_idx = [ekf_names[exact.names[k]] for k in keys]
    return {
        "camera": camera, "exact": exact.subset(keys), "ekf": ekf.subset(ekf_idx), "features": feats,
        "objects": objs, "visible": visible, "motion": motion, "prep_s": time.perf_counter() - t0,
        "keyframes": len(keys),
    }


def prepare_toy(seed: int, frames: int, attitude_deg: float = 0.5, position_m: float = 0.5) -> dict:
    """A geometric stand-in for a synthetic session (no images): 600 objects with relief on a lawnmower survey at
    100 m (two legs joined by a turn), centroids projected with 3 px noise, sizes radius * f / depth with 5 %
    noise, SIFT sets as noisy re-detections of per-object random descriptors, 15 clutter masks per keyframe.
    EKF poses: white attitude noise (`attitude_deg` per axis) plus a random-walk position drift (`position_m`
    per 100 m)."""
    from ...plugin.geometry import Camera, Poses, project
    from ...plugin.mask_features import MaskFeatures

    rng = np.random.default_rng(seed)
    cam = Camera(1200, 900, 1000.0, 1000.0, 600.0, 450.0)
    n_obj = 600
    centres = np.column_stack([rng.uniform(-60, 220, n_obj), rng.uniform(-60, 120, n_obj), rng.uniform(0, 8, n_obj)])
    radii = rng.uniform(0.7, 4.0, n_obj)
    words = rng.standard_normal((n_obj, 24, 128))
    leg = frames // 2
    xs = np.concatenate([np.arange(leg) * 2.0, (leg - 1) * 2.0 - np.arange(frames - leg) * 2.0])
    ys = np.concatenate([np.zeros(leg), np.full(frames - leg, 60.0)])
    yaw = np.concatenate([np.zeros(leg), np.full(frames - leg, np.pi)])
    nadir = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])

    def rz(a: float) -> np.ndarray:
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])

    def small_rot(v: np.ndarray) -> np.ndarray:
        import cv2
        return cv2.Rodrigues(v.reshape(3, 1))[0]

    rots = np.stack([rz(a) @ nadir @ small_rot(rng.normal(0, np.radians(1.0), 3)) for a in yaw])  # true jitter
    centers = np.column_stack([xs, ys, 100.0 + rng.normal(0, 0.5, frames)])
    exact = Poses([f"kf{i}" for i in range(frames)], rots, centers)
    drift = np.cumsum(rng.normal(0, position_m * np.sqrt(2.0 / 100.0), (frames, 3)), axis=0)
    ekf_rots = np.stack([r @ small_rot(rng.normal(0, np.radians(attitude_deg), 3)) for r in rots])
    ekf = Poses(exact.names, ekf_rots, centers + drift + rng.normal(0, 0.05, (frames, 3)))
    feats, objs = [], []
    for t in range(frames):
        uv, depth = project(cam, rots[t], centers[t], centres)
        vis = np.flatnonzero((uv[:, 0] > 10) & (uv[:, 0] < cam.width - 10) & (uv[:, 1] > 10)
                            & (uv[:, 1] < cam.height - 10) & (depth > 0) & (rng.random(n_obj) < 0.9))
        xy = np.concatenate([uv[vis] + rng.normal(0, 3.0, (len(vis), 2)),
                             rng.uniform([0, 0], [cam.width, cam.height], (15, 2))])
        size = np.concatenate([radii[vis] * cam.fx / depth[vis] * (1 + rng.normal(0, 0.05, len(vis))),
                               rng.uniform(5, 40, 15)])
        descs = [words[o, rng.choice(24, 12, replace=False)] + rng.normal(0, 0.35, (12, 128)) for o in vis]
        descs += [rng.standard_normal((8, 128)) for _ in range(15)]
        desc = np.concatenate(descs).astype(np.float32)
        desc /= np.linalg.norm(desc, axis=1, keepdims=True)
        owner = np.repeat(np.arange(len(descs)), [len(d) for d in descs]).astype(np.int32)
        k = len(xy)
        cov = np.zeros((k, 2, 2))
        cov[:, 0, 0] = cov[:, 1, 1] = size**2
        feats.append(MaskFeatures(xy, cov, size, np.ones(k, np.int64), np.ones(k, np.float32),
                                  xy[owner].astype(np.float32), desc, owner))
        objs.append(np.concatenate([vis + 1, np.zeros(15, np.int64)]))
    # image motion as a feature tracker would see it: displacements of ground points seen in both keyframes
    ground = np.column_stack([rng.uniform(-60, 220, 3000), rng.uniform(-60, 120, 3000), rng.uniform(0, 8, 3000)])
    motion = [(0.0, 0.0)]
    for t in range(1, frames):
        a, da = project(cam, rots[t - 1], centers[t - 1], ground)
        b, db = project(cam, rots[t], centers[t], ground)
        ok = ((a >= 0) & (a < [cam.width, cam.height]) & (b >= 0) & (b < [cam.width, cam.height])).all(1)
        ok &= (da > 0) & (db > 0)
        mag = np.linalg.norm(b[ok] - a[ok], axis=1)
        motion.append((float(mag.mean()), float(mag.std())) if ok.sum() >= 8 else (0.0, 100.0))
    return {"camera": cam, "exact": exact, "ekf": ekf, "features": feats, "objects": objs, "visible": None,
            "motion": motion,
            "prep_s": 0.0, "keyframes": frames}


def evaluate(result: object, objects: list[np.ndarray], visible: list[np.ndarray] | None = None,
             min_seen: int = 6, theta_n: int = 5) -> dict:
    """Purity, track length, landmark-eligible objects and duplicates of one tracking result.

    `objects[t][k]`: object id under the centroid of mask k of keyframe t (0 = background, an id like any other,
    as in bench_map). `visible[t]`: ids visible in keyframe t (frames.json); without it, the centroid ids.
    """
    tid = np.concatenate(result.track_ids)
    obj = np.concatenate(objects).astype(np.int64)
    lengths = np.bincount(tid, minlength=result.num_tracks)
    multi = lengths[tid] >= 2
    pairs, counts = np.unique(np.stack([tid[multi], obj[multi]], 1), axis=0, return_counts=True)
    major: dict[int, tuple[int, int]] = {}
    distinct = np.zeros(result.num_tracks, np.int64)
    for (t, o), c in zip(pairs.tolist(), counts.tolist()):
        distinct[t] += 1
        if c > major.get(t, (0, 0))[1]:
            major[t] = (o, c)
    # object-to-object confusions only: the same, over observations whose centroid is on an object
    on = multi & (obj > 0)
    p2, c2 = np.unique(np.stack([tid[on], obj[on]], 1), axis=0, return_counts=True)
    best: dict[int, int] = {}
    for (t, _), c in zip(p2.tolist(), c2.tolist()):
        best[t] = max(best.get(t, 0), c)
    long_tracks = np.flatnonzero(lengths > theta_n)
    if visible is None:
        visible = [np.unique(o[o > 0]) for o in objects]
    ids, seen = np.unique(np.concatenate([np.asarray(v, np.int64) for v in visible] + [np.zeros(0, np.int64)]),
                          return_counts=True)
    well = set(ids[(seen >= min_seen) & (ids > 0)].tolist())
    owners: dict[int, int] = {}
    for t in long_tracks.tolist():
        o = major[t][0]
        if o in well:
            owners[o] = owners.get(o, 0) + 1
    return {
        "purity": sum(c for _, c in major.values()) / max(int(multi.sum()), 1),
        "purity_obj": sum(best.values()) / max(int(on.sum()), 1),
        "pure_long": float(np.mean(distinct[long_tracks] == 1)) if len(long_tracks) else float("nan"),
        "mean_len": float(lengths[lengths >= 2].mean()) if (lengths >= 2).any() else 0.0,
        "tracked": len(owners) / max(len(well), 1),
        "dup": float(np.mean(list(owners.values()))) if owners else 0.0,
        "well_seen": len(well),
        "long_tracks": len(long_tracks),
    }


def true_pair_gates(data: dict, pose_set: str, params: TrackingParams) -> dict:
    """Gate statistics of the TRUE links: consecutive keyframes, objects with exactly one mask in each.

    Returns percentiles (50, 95, 99) of the epipolar distance (px) and the motion z-score, and the fraction of
    true links each gate would cut at `params`: the evidence for choosing theta_a against pose noise.
    """
    from ...plugin.epipolar import epipolar_distances
    from ...plugin.mask_scores import desc_index, feature_scores, size_scores
    from ...plugin.tracking import gap_motion

    feats, objs, cam, poses = data["features"], data["objects"], data["camera"], data[pose_set]
    epi, mot, qs, qf = [], [], [], []
    for t in range(1, len(feats)):
        a, b = objs[t - 1], objs[t]
        ids, ca = np.unique(a[a > 0], return_counts=True)
        idb, cb = np.unique(b[b > 0], return_counts=True)
        common = np.intersect1d(ids[ca == 1], idb[cb == 1])
        if len(common) == 0:
            continue
        i = np.array([np.flatnonzero(a == o)[0] for o in common])
        j = np.array([np.flatnonzero(b == o)[0] for o in common])
        xs, xt = feats[t - 1].centroids[i], feats[t].centroids[j]
        epi.append(np.diag(epipolar_distances(cam, poses, t - 1, t, xs, xt)))
        mu, sigma = gap_motion(data["motion"], t - 1, t, params.centroid_sigma_px)
        mot.append(np.abs(np.linalg.norm(xs - xt, axis=1) - mu) / sigma)
        qs.append(np.diag(size_scores(feats[t - 1].sizes[i], feats[t].sizes[j], params.size_tolerance)))
        qf.append(feature_scores(desc_index(feats[t - 1]), desc_index(feats[t]), i, j, params.sift_ratio))
    epi, mot, qs, qf = (np.concatenate(x) if x else np.zeros(0) for x in (epi, mot, qs, qf))
    q = np.sqrt(qs * qf)
    return {
        "links": len(epi),
        "epi_pct": np.percentile(epi, [50, 95, 99]) if len(epi) else np.full(3, np.nan),
        "motion_pct": np.percentile(mot, [50, 95, 99]) if len(mot) else np.full(3, np.nan),
        "cut_epipolar": float(np.mean(epi > params.epipolar_margin_px)) if len(epi) else np.nan,
        "cut_motion": float(np.mean(mot >= params.motion_gate_sigmas)) if len(mot) else np.nan,
        "cut_size": float(np.mean(qs == 0)) if len(qs) else np.nan,
        "cut_score": float(np.mean(q < params.min_score)) if len(q) else np.nan,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("session", type=Path, nargs="?", help="synthetic session directory (omit with --toy)")
    ap.add_argument("--toy", type=int, default=None, metavar="SEED", help="geometric stand-in world (no images)")
    ap.add_argument("--frames", type=int, default=100, help="first N frames of the session (0 = all)")
    ap.add_argument("--masks", default="gt", help="'gt' (label images) or a segmentation backend name")
    ap.add_argument("--margins", default="4,8,12,16,24,32", help="theta_a values (px)")
    ap.add_argument("--ages", default="1,2,3,5", help="theta_t values (keyframes)")
    ap.add_argument("--poses", default="exact,ekf")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cache", type=Path, help="pickle of the prepared front end (written if missing, else read)")
    args = ap.parse_args(argv)

    from ...plugin.tracking import track_masks

    print(machine_summary())
    if args.toy is not None:
        data = prepare_toy(args.toy, args.frames or 100)
        args.masks = "toy"
    elif args.cache is not None and args.cache.exists():
        data = pickle.loads(args.cache.read_bytes())
    else:
        data = prepare(args.session, args.frames, args.masks, SegmentationParams())
        if args.cache is not None:
            args.cache.write_bytes(pickle.dumps(data))
    mus = np.array(data["motion"][1:])
    print(f"session {args.session}: {data['keyframes']} keyframes, masks={args.masks}, "
          f"{sum(len(f) for f in data['features'])} masks, mu_p median {np.median(mus[:, 0]):.1f} px, "
          f"sigma_p median {np.median(mus[:, 1]):.2f} px; preparation {data['prep_s']:.1f} s")
    for pose_set in args.poses.split(","):
        g = true_pair_gates(data, pose_set, TrackingParams())
        print(f"true links ({pose_set} poses, {g['links']}): epipolar px p50/p95/p99 "
              f"{'/'.join(f'{x:.1f}' for x in g['epi_pct'])}, motion z p50/p95/p99 "
              f"{'/'.join(f'{x:.2f}' for x in g['motion_pct'])}; cut at defaults by epipolar "
              f"{g['cut_epipolar']:.3f}, motion {g['cut_motion']:.3f}, size {g['cut_size']:.3f}, "
              f"score (size or SIFT) {g['cut_score']:.3f}")
    print("| poses | theta_a px | theta_t | purity (obs.) | object-only purity | pure tracks >5 obs | mean track len | "
          "objects >=6 kf with a track >5 obs | tracks/object | tracker s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for pose_set, margin, age in itertools.product(
        args.poses.split(","), [float(x) for x in args.margins.split(",")], [int(x) for x in args.ages.split(",")]
    ):
        params = TrackingParams(epipolar_margin_px=margin, max_track_age_keyframes=age)
        times = []
        for _ in range(max(1, args.repeats)):
            t0 = time.perf_counter()
            res = track_masks(data["features"], data["camera"], data[pose_set], data["motion"], params)
            times.append(time.perf_counter() - t0)
        m = evaluate(res, data["objects"], data.get("visible"))
        print(f"| {pose_set} | {margin:g} | {age} | {m['purity']:.3f} | {m['purity_obj']:.4f} | {m['pure_long']:.3f} | "
              f"{m['mean_len']:.1f} | "
              f"{m['tracked']:.2f} (of {m['well_seen']}) | {m['dup']:.2f} | {np.median(times):.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
