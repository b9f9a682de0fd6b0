"""Maps in one georeferenced frame: the search near the georeference first (`association.georeference_prior_m`)
against the search over every alignment, on bench_seasons' maps.

    nice -n 10 .venv/bin/python -m sosmatch.tools.benchmarks.bench_georeference --maps /work/w16 \
        [--worlds 229,241] [--tag default] [--sessions summer,winter,...] [--move DX,DY,YAW] [--only same|cross]

Sessions of one synthetic world share its frame (up to each map's EKF drift of 1-2 m), as two GNSS-georeferenced
maps of one place do: every pair of one world is a positive (truth: the identity), every pair of two worlds a
negative (nothing may be accepted). Each pair is answered as `sosmatch match` answers it (the transform its maps'
pose sources choose and the derived search parameters, `workflows.match.transform_choice.answer_plan`) twice:
as maps in unrelated frames and as maps in one frame. `--move` moves B by a rigid motion (metres, degrees about
the frame's origin) first: a georeference that is that wrong.
Prints one row per pair and a summary (accepted, worst error to the truth in metres, CPU seconds).
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

from ...database.landmark_map import LandmarkMap, read_landmark_map
from ...plugin.params import Params
from ...workflows.match.transform_choice import answer_plan, plan_search
from .machine import machine_summary

SESSIONS = ("summer", "winter", "winter-x45", "winter-x90", "winter-130", "summer-130", "spring", "autumn",
            "summer-free")


def moved(points: np.ndarray, dx: float, dy: float, yaw_deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + np.array([dx, dy, 0.0])


def answer_row(a: LandmarkMap, b: LandmarkMap, points_b: np.ndarray, truth_b: np.ndarray, common: bool) -> dict:
    """One answer as `sosmatch match` gives it; its error: the horizontal RMS distance of B's landmarks moved by
    the answer from where the truth puts them."""
    # (the plan, derivation included, outside the timing as before; a photo-mapped map is searched with a
    # similarity as `match` searches it, its rigid fallback timed with it)
    plan = plan_search(Params(), False, a.sfm_poses, b.sfm_poses, a.noise, b.noise, a.positions, a.sizes, points_b,
                       b.sizes)
    t0 = time.process_time()
    ans = answer_plan(plan, a.positions, a.sizes, points_b, b.sizes, common_frame=common).answer
    cpu = time.process_time() - t0
    v = ans.verification
    err = None
    if ans.accepted:
        t = ans.transform
        err = float(np.sqrt(np.mean(np.sum(((points_b @ (t.scale * t.rotation).T + t.translation)
                                             - truth_b)[:, :2] ** 2, axis=1))))
    return {"accepted": bool(ans.accepted), "search": ans.tolerances,
            "support": 0 if v.best is None else len(v.best.associations), "runner_up": int(v.runner_up_support),
            "p": None if v.chance is None else float(v.chance.p_value), "error_m": err, "cpu_s": cpu}


def cell(g: dict) -> str:
    p = "-" if g["p"] is None else f"{g['p']:.1g}"
    err = "-" if g["error_m"] is None else f"{g['error_m']:.1f}"
    return (f"{'accepted' if g['accepted'] else 'refused'} ({g['search']}), {g['support']} / {g['runner_up']}, {p}, "
            f"{err}, {g['cpu_s']:.2f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--maps", required=True, type=Path, help="bench_seasons --work directory")
    ap.add_argument("--worlds", default="229,241")
    ap.add_argument("--tag", default="default", help="maps tag")
    ap.add_argument("--sessions", default=",".join(SESSIONS))
    ap.add_argument("--move", default="0,0,0", help="DX,DY,YAW: B's georeference that wrong")
    ap.add_argument("--only", choices=("same", "cross"))
    args = ap.parse_args(argv)
    worlds = [int(w) for w in args.worlds.split(",")]
    dx, dy, yaw = (float(v) for v in args.move.split(","))
    maps = {}
    for w, s in itertools.product(worlds, args.sessions.split(",")):
        path = args.maps / f"w{w}" / "maps" / args.tag / s / "landmarks.sosmap"
        if path.exists():
            maps[(w, s)] = read_landmark_map(path)
    print(f"# {machine_summary()}; B moved by {dx:g}, {dy:g} m, {yaw:g} deg")
    print("| A | B | unrelated frames: answer, support / runner-up, p, error m, CPU s | one frame: the same |")
    print("|---|---|---|---|")
    rows = []
    for ka, kb in itertools.combinations(sorted(maps), 2):
        same = ka[0] == kb[0]
        if args.only and (args.only == "same") != same:
            continue
        a, b = maps[ka], maps[kb]
        pb = moved(b.positions, dx, dy, yaw)
        got = [answer_row(a, b, pb, b.positions, common) for common in (False, True)]
        rows.append((same, got))
        cells = [cell(g) for g in got]
        print(f"| w{ka[0]} {ka[1]} | w{kb[0]} {kb[1]} | {cells[0]} | {cells[1]} |", flush=True)
    for same, label in ((True, "same world (positives)"), (False, "two worlds (negatives)")):
        part = [g for s, g in rows if s == same]
        if not part:
            continue
        for k, frame in enumerate(("unrelated frames", "one frame")):
            acc = [g[k] for g in part if g[k]["accepted"]]
            worst = max((g["error_m"] for g in acc), default=float("nan"))
            print(f"{label}, {frame}: {len(acc)} of {len(part)} accepted, worst error {worst:.1f} m, "
                  f"CPU {sum(g[k]['cpu_s'] for g in part):.1f} s")


if __name__ == "__main__":
    main()
