"""Maps from images with EXIF GPS but no attitude tags, scored against the synthetic truth.

For each (session, mapped session) pair: the verdict and its warnings (run.json), the landmarks, the horizontal
error of the landmarks on objects (median and 90th percentile; `bench_plausibility.horizontal_errors`, the
sweep's figure), and the keyframe poses the map was made on against the true poses (rotation error median / max,
position error median; maps made from the synthetic geotags are in UTM, the session's offset is taken off).
Map the sessions first, e.g.

    sosmatch synth --out F88 --world-seed 88 --season spring --frames 70 --altitude 150 --changed 0.2 \\
        --geotags exif
    sosmatch map --images F88/images --pose-source exif --out F88m
    .venv/bin/python -m sosmatch.tools.benchmarks.bench_exif_attitude F88:F88m [SESSION:MAPPED ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from .bench_plausibility import horizontal_errors
from .machine import machine_summary


def map_pose_errors(session: Path, mapped: Path) -> dict[str, float]:
    """The mapped keyframes' poses (sparse/) against the session's true poses."""
    import pycolmap

    from ...database.poses import read_poses_csv
    from ...plugin.geometry import rotation_angle_deg

    truth, _ = read_poses_csv(session / "poses.csv")
    meta = json.loads((session / "session.json").read_text())
    offset = np.asarray(meta.get("geo", {}).get("world_to_crs_offset", [0.0, 0.0, 0.0]), np.float64)
    run = json.loads((mapped / "run.json").read_text())
    index = {n: i for i, n in enumerate(truth.names)}
    rec = pycolmap.Reconstruction(str(mapped / "sparse"))
    rot, pos = [], []
    for image in rec.images.values():
        cfw = image.cam_from_world()
        r_cw = np.asarray(cfw.rotation.matrix())
        k = index[image.name]
        rot.append(rotation_angle_deg(r_cw.T, truth.rotations[k]))
        centre = -r_cw.T @ np.asarray(cfw.translation)  # sparse/ holds the poses in the map's CRS, as given
        pos.append(float(np.linalg.norm(centre - (truth.centers[k] + (offset if run.get("epsg") else 0.0)))))
    return {"rotation_median_deg": float(np.median(rot)), "rotation_max_deg": float(np.max(rot)),
            "position_median_m": float(np.median(pos))}


def score(session: Path, mapped: Path) -> dict[str, Any]:
    run = json.loads((mapped / "run.json").read_text())
    err = horizontal_errors(session, mapped)
    return {"session": session.name, "map": mapped.name, "status": run["verdict"]["status"],
            "warnings": run["verdict"]["warnings"], "refusals": run["verdict"]["refusals"],
            "landmarks": int(run["counts"].get("landmarks", 0)), "on_objects": len(err),
            "median_h_m": float(np.median(err)) if len(err) else float("nan"),
            "p90_h_m": float(np.percentile(err, 90)) if len(err) else float("nan"),
            "poses": run["inputs"].get("poses", ""), **map_pose_errors(session, mapped)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pairs", nargs="+", help="SESSION:MAPPED (a synth session and a map of its images)")
    args = ap.parse_args(argv)
    print(machine_summary())
    print("| session | map | verdict | warnings | landmarks (on objects) | horizontal error median / p90 m | "
          "keyframe rotation error median / max deg | position median m |")
    print("|---|---|---|---|---|---|---|---|")
    for pair in args.pairs:
        session, mapped = (Path(p) for p in pair.split(":", 1))
        r = score(session, mapped)
        print(f"| {r['session']} | {r['map']} | {r['status']} | {len(r['warnings'])} | {r['landmarks']} "
              f"({r['on_objects']}) | {r['median_h_m']:.2f} / {r['p90_h_m']:.2f} | {r['rotation_median_deg']:.2f} / "
              f"{r['rotation_max_deg']:.1f} | {r['position_median_m']:.2f} |")
        for w in r["warnings"] + r["refusals"]:
            print(f"  - {w}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
