"""Poses from images (`sosmatch poses`): the issue-13 bars, printed.

    python -m sosmatch.tools.benchmarks.bench_sfm synthetic --work /tmp/bench_sfm     # faults vs exact truth
    python -m sosmatch.tools.benchmarks.bench_sfm seneca --work /tmp/bench_sfm        # ../shared/data/seneca

synthetic: `sosmatch synth` flights (several worlds and paths) with a consumer drone's faults written into the
JPEGs (DJI XMP; GPS noise 1 m, a GPS altitude drifting by 50 m over the flight, a 180 degree yaw on one flight
line, barrel distortion k1 = -0.1 when the renderer supports it), then `poses` on the JPEGs alone. Figures:
camera centres and orientations against the exact poses (UTM, session.json's offset), and the landmark map made
on the SfM poses and cameras against the map made on the exact poses (mutual nearest landmarks within 2 m:
their horizontal offsets; both maps with the survey-free default preset). Bars: centres within 1 m, orientations
within 1 deg, maps within 0.5 m horizontally.

seneca: the 167 JPEGs alone (EXIF GPS; no telemetry), `poses` then `map --preset survey`; landmarks, their mean
reprojection error, CPU time of each stage and the load average (the machine is shared). Bar: >= 200 landmarks
at <= 3.5 px in <= 6 min on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

from .machine import machine_summary

# (label, synth arguments): the faults of the bar on two worlds and two paths
SYNTH_CASES = [
    ("world 7 lawnmower", ["--world-seed", "7", "--frames", "90", "--yaw-fault-lines", "1"]),
    ("world 3 lawnmower rotated", ["--world-seed", "3", "--frames", "90", "--rotate", "35", "--session-seed", "2",
                                   "--yaw-fault-lines", "2"]),
]
FAULTS = ["--geotags", "dji", "--gps-sigma", "1.0", "--gps-altitude-drift", "50"]


def _cpu() -> float:
    """CPU seconds of this process and its finished children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _timed(fn, *args, **kwargs):  # noqa: ANN001, ANN202 (a benchmark helper)
    w, c = time.perf_counter(), _cpu()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - w, _cpu() - c


def _synth_supports(flag: str) -> bool:
    from sosmatch.tools.synth.config import SynthConfig

    return any(f.name == flag for f in __import__("dataclasses").fields(SynthConfig))


def synthetic_case(label: str, args: list[str], work: Path) -> dict:
    from sosmatch.database.landmark_map import read_landmark_map
    from sosmatch.database.poses import read_poses_csv
    from sosmatch.plugin.geometry import rotation_angle_deg
    from sosmatch.plugin.params import Params
    from sosmatch.plugin.refinement import mutual_nearest
    from sosmatch.tools.cli import main as cli
    from sosmatch.workflows import map as map_wf
    from sosmatch.workflows import poses as poses_wf

    name = label.replace(" ", "_")
    session = work / name
    lens = ["--k1", "-0.1"] if _synth_supports("lens_k1") else []
    if not (session / "session.json").is_file():
        assert cli(["synth", "--out", str(session), *args, *FAULTS, *lens, "-q"]) == 0
    meta = json.loads((session / "session.json").read_text())
    offset = np.array(meta["geo"]["world_to_crs_offset"])
    truth, _ = read_poses_csv(session / "poses.csv")
    result, wall, cpu = _timed(poses_wf.run, session / "images", work / f"{name}_poses", Params(), overwrite=True)
    idx = [truth.names.index(n) for n in result.poses.names]
    err = np.linalg.norm(result.poses.centers - (truth.centers[idx] + offset), axis=1)
    rot = np.asarray(rotation_angle_deg(result.poses.rotations, truth.rotations[idx]))
    out = {"case": label, "lens": "k1 = -0.1" if lens else "pinhole (renderer without distortion)",
           "images": len(truth), "registered": len(result.poses), "poses_seconds": wall, "poses_cpu_s": cpu,
           "centre_error_median_m": float(np.median(err)), "centre_error_max_m": float(err.max()),
           "rotation_error_median_deg": float(np.median(rot)), "rotation_error_max_deg": float(rot.max()),
           "camera": result.report["cameras"], "warnings": result.warnings}
    # the maps: on exact poses and camera, and on the SfM poses and cameras (poses.csv + cameras.txt)
    exact_dir, sfm_dir = work / f"{name}_map_exact", work / f"{name}_map_sfm"
    if not (exact_dir / "run.json").is_file():
        map_wf.run(Params(), map_wf.load_inputs(None, session), exact_dir, overwrite=True, progress=False)
    inputs = map_wf.load_inputs(session / "images", work / f"{name}_poses" / "poses.csv")
    map_wf.run(Params(), inputs, sfm_dir, overwrite=True, progress=False)
    lm_exact = read_landmark_map(exact_dir / "landmarks.sosmap")
    lm_sfm = read_landmark_map(sfm_dir / "landmarks.sosmap")
    pa, pb = lm_exact.positions + offset, lm_sfm.positions
    pairs, _ = mutual_nearest(pa, None, pb, None, 2.0, 1.0)
    d = pb[pairs[:, 1]] - pa[pairs[:, 0]]
    horizontal = np.linalg.norm(d[:, :2], axis=1)
    out.update(landmarks_exact=len(pa), landmarks_sfm=len(pb), landmarks_common=int(len(pairs)),
               map_horizontal_median_m=float(np.median(horizontal)) if len(pairs) else float("nan"),
               map_horizontal_mean_offset_m=float(np.linalg.norm(d[:, :2].mean(0))) if len(pairs) else float("nan"),
               map_vertical_median_m=float(np.median(d[:, 2])) if len(pairs) else float("nan"))
    return out


def seneca(data: Path, work: Path) -> dict:
    import pycolmap

    from sosmatch.database.config_io import load_params
    from sosmatch.workflows import map as map_wf
    from sosmatch.workflows import poses as poses_wf

    params = load_params(preset="survey")
    load0 = os.getloadavg()
    result, p_wall, p_cpu = _timed(poses_wf.run, data / "images", work / "seneca_poses", params, overwrite=True)
    inputs = map_wf.load_inputs(data / "images", work / "seneca_poses" / "poses.csv")
    summary, m_wall, m_cpu = _timed(map_wf.run, params, inputs, work / "seneca_map", overwrite=True, progress=False)
    errors = np.array([p.error for p in pycolmap.Reconstruction(work / "seneca_map" / "sparse").points3D.values()])
    return {"images": len(result.poses) + len(result.unregistered), "registered": len(result.poses),
            "unregistered": result.unregistered, "sfm_points": result.report["points"],
            "sfm_reprojection_px": result.report["reprojection_px"], "camera": result.report["cameras"],
            "georegistration": {k: v for k, v in (result.report["georegistration"] or {}).items() if k != "transform"},
            "timings": result.report["timings_s"], "warnings": result.warnings,
            "landmarks": summary.num_landmarks, "mean_reprojection_px": float(errors.mean()) if len(errors) else None,
            "poses_wall_s": p_wall, "poses_cpu_s": p_cpu, "map_wall_s": m_wall, "map_cpu_s": m_cpu,
            "total_wall_s": p_wall + m_wall, "total_cpu_s": p_cpu + m_cpu,
            "load_average_before": load0, "load_average_after": os.getloadavg()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["synthetic", "seneca"])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / ".." / "shared" / "data",
                        help="the shared data folder (seneca/ inside)")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    print(machine_summary())
    if args.what == "synthetic":
        rows = [synthetic_case(label, a, args.work) for label, a in SYNTH_CASES]
        print(json.dumps(rows, indent=1))
        print("| case | lens | registered | centre error median / max (m) | orientation error median / max (deg) "
              "| common landmarks | map horizontal median (m) | bars |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            ok = (r["centre_error_max_m"] <= 1.0, r["rotation_error_max_deg"] <= 1.0,
                  r["map_horizontal_median_m"] <= 0.5)
            print(f"| {r['case']} | {r['lens']} | {r['registered']}/{r['images']} | {r['centre_error_median_m']:.2f} / "
                  f"{r['centre_error_max_m']:.2f} | {r['rotation_error_median_deg']:.2f} / "
                  f"{r['rotation_error_max_deg']:.2f} "
                  f"| {r['landmarks_common']} of {r['landmarks_exact']} | {r['map_horizontal_median_m']:.2f} | "
                  f"{'met' if all(ok) else 'NOT met ' + str(ok)} |")
    else:
        r = seneca(args.data / "seneca", args.work)
        print(json.dumps(r, indent=1))
        ok = r["landmarks"] >= 200 and (r["mean_reprojection_px"] or 99) <= 3.5
        print(f"seneca from JPEGs: {r['registered']}/{r['images']} registered, {r['landmarks']} landmarks at "
              f"{r['mean_reprojection_px']:.2f} px; poses {r['poses_cpu_s']:.0f} CPU-s "
              f"({r['poses_wall_s']:.0f} s wall), "
              f"map {r['map_cpu_s']:.0f} CPU-s ({r['map_wall_s']:.0f} s wall), total {r['total_cpu_s']:.0f} CPU-s = "
              f"{r['total_cpu_s'] / 2:.0f} s on 2 cores; load {r['load_average_before'][0]:.1f} -> "
              f"{r['load_average_after'][0]:.1f}; landmark bar {'met' if ok else 'NOT met'}")


if __name__ == "__main__":
    main()
