"""Negative and positive pairs for the match's verification: maps of DIFFERENT synthetic worlds (they share no
object: nothing may be accepted) and maps of one world (every one must keep its verified answer), resumable.

    nice -n 10 .venv/bin/python -m sosmatch.tools.benchmarks.bench_negatives --maps /work/data16 \
        [--work /tmp/bench_negatives] [--worlds 5,11,23,42] [--tag v3] [--only cross|same] [--set k=v ...] [--cost]
        [--suite BENCH_WORK/maps] [--no-pairs] [--null PAIRS --null-starts M]

The maps are bench_seasons' (`MAPS/wSEED/maps/TAG/SESSION`, mapped sessions with run.json, so `match` derives its
tolerances from their noise as a user's run would). Each pair is matched with `workflows.match.run` and default
parameters (plus `--set`); its row goes to `WORK/rows/A--B.json` (an existing row is not recomputed: an
interrupted run resumes; `--fresh` recomputes). Truth: sessions of one world share its frame, so the true A_from_B
is the identity up to each map's EKF drift (`workflows.evaluate.error_to_identity`, at the centroid of the
answer's B landmarks); pairs of different worlds have no true alignment. The chance model's CPU per pair is
measured by running it again (`plugin.verification.winner_chance`: the uniform placements and the rows; process
time); `--cost` also measures it
side by side on the search benchmark's dense, sparse and aerial maps (`chance_cost`). `--null` calibrates the
chance model itself (`null_calibration`): unrelated random maps, the best of M random refinements offered as the
winner; its tail q says how often one chance alignment reaches that support, so M q is (about) the probability
that the best of M does, and over many pairs it must not fall below x more often than a fraction x of the time.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import time
from pathlib import Path

from .machine import machine_summary

SAME_WORLD = [("summer", "winter"), ("summer", "winter-x45"), ("summer", "winter-x90"), ("summer", "winter-130"),
              ("summer", "summer-130"), ("summer", "summer-free"), ("spring", "autumn")]
# pairs of sessions of two different worlds: the seasons (sparse winter, dense spring/summer), crossing flights
# and altitudes, so the chance level ranges from ~1 to ~13 pairs
CROSS_WORLD = [("summer", "winter"), ("spring", "spring"), ("summer", "summer"), ("summer-130", "winter-x90")]


def pairs(worlds: list[int], only: str | None) -> list[tuple[str, str, bool]]:
    """(A, B, same world) as 'wN/SESSION'."""
    out = []
    if only in (None, "same"):
        out += [(f"w{w}/{a}", f"w{w}/{b}", True) for w in worlds for a, b in SAME_WORLD]
    if only in (None, "cross"):
        out += [(f"w{wa}/{a}", f"w{wb}/{b}", False) for wa, wb in itertools.combinations(worlds, 2)
                for a, b in CROSS_WORLD]
    return out


def map_path(maps: Path, tag: str, name: str) -> Path:
    world, session = name.split("/")
    return maps / world / "maps" / tag / session


def run_pair(maps: Path, tag: str, work: Path, a: str, b: str, same: bool, overrides: list[str]) -> dict:
    from ...database.config_io import parse_override
    from ...database.landmark_map import read_landmark_map
    from ...plugin.params import Params, with_overrides
    from ...plugin.verification import winner_chance
    from ...workflows.evaluate import error_to_identity
    from ...workflows.match import run

    params = with_overrides(Params(), dict(parse_override(o) for o in overrides))
    out = work / "matches" / f"{a.replace('/', '_')}--{b.replace('/', '_')}"
    pa_dir, pb_dir = map_path(maps, tag, a), map_path(maps, tag, b)
    t0 = time.process_time()
    res = run(params, pa_dir, pb_dir, out, plot=False, overwrite=True)
    cpu = time.process_time() - t0
    doc = json.loads((out / "match.json").read_text())
    ver = doc.get("verification") or {}
    chance = ver.get("chance") or {}
    row = {"a": a, "b": b, "same_world": same, "accepted": bool(res.accepted), "support": ver.get("support"),
           "support_dof": ver.get("support_dof"), "runner_up": ver.get("runner_up_support"),
           "chance_mean": chance.get("mean"), "chance_var": chance.get("variance"), "trials": chance.get("trials"),
           "p_value": chance.get("p_value"), "tolerances": doc["search_mode"].get("tolerances"),
           "gate_m": ver.get("method", {}).get("gate_m"), "match_cpu_s": cpu, "verify_wall_s": doc["timings"].get(
               "verify_s"), "error_m": None, "yaw_deg": None}
    ans = res.answer
    if ans is not None and ans.verification is not None and ans.verification.best is not None:
        lb = read_landmark_map(pb_dir / "landmarks.sosmap")
        best = ans.verification.best
        if same:
            err = error_to_identity(best.transform, lb.positions[best.associations[:, 1]])
            row.update(error_m=err["error_m"], yaw_deg=err["yaw_deg"])
        # the chance model's CPU: the part of the verification it adds (its placements refined again, and the
        # rows laid on rows when those are judged)
        la = read_landmark_map(pa_dir / "landmarks.sosmap")
        vp, ap = params.verification, doc["params"]["association"]
        t1 = time.process_time()
        winner_chance(la.positions, la.sizes, lb.positions, lb.sizes, best.transform,
                          lb.positions[best.associations[:, 1]], ans.verification.support, ap["distance_tolerance_m"],
                          vp.max_size_difference, vp.chance_starts, vp.false_alarm, ap["position_prior_m"], vp.dof,
                          vp.z_weight)
        row["chance_cpu_s"] = time.process_time() - t1
        row["chance_samples"] = chance.get("samples")
    return row


def chance_cost(repeats: int = 3) -> str:
    """The chance model's CPU on the search benchmark's maps (`bench_match`: dense 600-landmark, sparse
    1000-landmark, aerial stand-in with its position prior): `match_maps` with and without it
    (`verification.chance_starts` 0), side by side, median process time of `repeats`."""
    import statistics

    from ...plugin.association.synthetic import survey_map_pair
    from ...plugin.match_answer import match_maps
    from ...plugin.params import Params, preset_params, with_overrides
    from .match_problems import aerial_maps, dense_maps

    dense, sparse = dense_maps(), survey_map_pair(1000, seed=3)
    pa, ha, pb, hb, _ = aerial_maps()
    cases = [("dense 600", dense.points_a, dense.sizes_a, dense.points_b, dense.sizes_b, Params()),
             ("sparse 1000", sparse.points_a, sparse.sizes_a, sparse.points_b, sparse.sizes_b, Params()),
             ("aerial stand-in, prior 50 m", pa, ha, pb, hb, preset_params("aerial"))]
    lines = ["| maps | match CPU s without the chance model | with it | added | chance samples | p-value | N_eff |",
             "|---|---|---|---|---|---|---|"]
    for name, a, sa, b, sb, params in cases:
        match_maps(a, sa, b, sb, params)  # compiled kernels warm
        cpu: dict[int, list[float]] = {0: [], params.verification.chance_starts: []}
        ans = None
        for _ in range(repeats):
            for starts in cpu:
                p = with_overrides(params, {"verification.chance_starts": starts})
                t0 = time.process_time()
                ans = match_maps(a, sa, b, sb, p)
                cpu[starts].append(time.process_time() - t0)
        off, on = (statistics.median(v) for v in cpu.values())
        c = ans.verification.chance
        lines.append(f"| {name} | {off:.3f} | {on:.3f} | {on - off:+.3f} | {c.samples} | {c.p_value:.1e} | "
                     f"{c.trials:.1e} |")
    return "\n".join(lines)


SUITE_CASES = {"summer-20min": ("season_summer_session-seed_1", "season_summer_session-seed_2_sun-azimuth_160_sun-"
                                                                  "elevation_56"),
               "viewpoint": ("season_summer_session-seed_1", "season_summer_session-seed_3_shift_12x12_reverse"),
               "spring-autumn": ("season_spring_session-seed_4", "season_autumn_session-seed_5"),
               "summer-winter": ("season_summer_session-seed_1", "season_winter_session-seed_6")}


def suite_answers(maps: Path, work: Path) -> str:
    """The evaluation suite's answers with and without the chance model (`bench_evaluate`'s maps in `maps`, as
    `bench_evaluate --work W` leaves them in W/maps). The evaluation's figures depend on the verification only
    through its answer (winner, associations, and `clear`) and on which search ran (a refused first search runs
    the derived one): when these are equal, so are the figures."""
    from ...plugin.params import Params, with_overrides
    from ...workflows.match import run

    lines = ["| case | without the chance model: answer, support, tolerances | with it | p-value | same answer |",
             "|---|---|---|---|---|"]
    for case, (a, b) in SUITE_CASES.items():
        if not ((maps / a / "run.json").exists() and (maps / b / "run.json").exists()):
            lines.append(f"| {case} | no maps | | | |")
            continue
        got = []
        for starts in (0, Params().verification.chance_starts):
            res = run(with_overrides(Params(), {"verification.chance_starts": starts}), maps / a, maps / b,
                      work / "suite" / f"{case}_{starts}", plot=False, overwrite=True)
            v = res.answer.verification
            got.append((res.accepted, v.support, res.answer.tolerances, v.chance,
                        res.associations.tolist()))
        (acc0, s0, t0, _, as0), (acc1, s1, t1, c1, as1) = got
        lines.append(f"| {case} | {'verified' if acc0 else 'refused'}, {s0}, {t0} | "
                     f"{'verified' if acc1 else 'refused'}, {s1}, {t1} | {c1.p_value:.1e} | "
                     f"{'yes' if (acc0, s0, t0, as0) == (acc1, s1, t1, as1) else '**no**'} |")
    return "\n".join(lines)


def _null_field(rng: object, n: int, span: float, clustered: bool) -> tuple:
    """n landmarks over span x span m: uniform, or in groves (a Thomas process: centres uniform, 8 m spread)."""
    import numpy as np

    if clustered:
        centres = rng.uniform(0, span, (max(3, n // 12), 2))
        xy = centres[rng.integers(len(centres), size=n)] + rng.normal(0, 8.0, (n, 2))
    else:
        xy = rng.uniform(0, span, (n, 2))
    return np.column_stack([xy, rng.normal(0, 0.5, n)]), rng.lognormal(1.0, 0.5, n)


def null_pair(seed: int, starts: int) -> tuple:
    """Null pair `seed` of `null_calibration`: (a, sizes_a, b, sizes_b, gate_m, best), `best` the refined
    alignment with the most pairs among `starts` random placements (deterministic)."""
    import numpy as np

    from ...plugin.multisession import Sim3
    from ...plugin.refinement import refine_alignment, yaw_matrix

    rng = np.random.default_rng(1000 + seed)
    clustered = seed % 2 == 1
    a, sa = _null_field(rng, int(rng.integers(150, 400)), 250.0, clustered)
    b, sb = _null_field(rng, int(rng.integers(50, 200)), 200.0, clustered)
    gate = float(rng.uniform(2.0, 4.0))
    best = None
    for _ in range(starts):
        turn = yaw_matrix(rng.uniform(0, 2 * np.pi))
        target = np.r_[rng.uniform(0, 250, 2), 0.0]
        aligned = refine_alignment(a, sa, b, sb, Sim3(turn, target - turn @ b.mean(0)), gate, 0.4)
        if best is None or len(aligned.associations) > len(best.associations):
            best = aligned
    return a, sa, b, sb, gate, best


def null_calibration(pairs_n: int, starts: int) -> str:
    """The chance model on pairs of unrelated maps (150-400 x 50-200 landmarks, uniform or in groves, gates
    2-4 m, sizes with the verification's gate 0.4): the best of `starts` random refinements is offered to
    `verify_alignments` as the winner. Prints, per pair, the support, p and starts x q (q: the model's tail at
    that support), then how many pairs were accepted and how many have starts x q below 0.01 / 0.05 / 0.2 (a
    calibrated tail: about that fraction of the pairs, fewer when the starts converge to shared optima)."""
    import numpy as np

    from ...plugin.verification import verify_alignments

    lines, mq, accepted = [], [], 0
    for seed in range(pairs_n):
        a, sa, b, sb, gate, best = null_pair(seed, starts)
        clustered = seed % 2 == 1
        v = verify_alignments(a, sa, b, sb, [(best.transform, best.associations[:, 1])], gate, 0.4, 6)
        accepted += int(v.accepted)
        mq.append(starts * v.chance.tail if v.chance else float("inf"))
        lines.append(f"null {seed}: {'groves' if clustered else 'uniform'} {len(a)} x {len(b)}, gate {gate:.1f} m: "
                     f"support {v.support}, runner-up {v.runner_up_support}, p {v.chance.p_value if v.chance else '-'}"
                     f", starts x q {mq[-1]:.3g}, accepted {v.accepted}")
    arr = np.asarray(mq)
    lines.append(f"null calibration: {pairs_n} pairs, best of {starts} starts: accepted {accepted}; starts x q below "
                 + ", ".join(f"{x}: {int(np.sum(arr < x))}" for x in (0.01, 0.05, 0.2)))
    return "\n".join(lines)


def _f(x: object, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def table(rows: list[dict]) -> str:
    lines = ["| A | B | world | answer | support | runner-up | chance mean / var | N_eff | p-value | error vs truth "
             "| match CPU s (chance part) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        verdict = "verified" if r["accepted"] else "refused"
        if r["accepted"] != r["same_world"]:
            verdict = f"**{verdict}: WRONG**"
        err = "-" if r["error_m"] is None else f"{r['error_m']:.1f} m, {r['yaw_deg']:.1f} deg"
        lines.append(
            f"| {r['a']} | {r['b']} | {'same' if r['same_world'] else 'different'} | {verdict} ({r['tolerances']}) | "
            f"{_f(r['support'], 'd')} | {_f(r['runner_up'], 'd')} | {_f(r['chance_mean'], '.1f')} / "
            f"{_f(r['chance_var'], '.1f')} | {_f(r['trials'], '.1e')} | {_f(r['p_value'], '.1e')} | {err} | "
            f"{r['match_cpu_s']:.2f} ({_f(r.get('chance_cpu_s'), '.3f')}) |")
    cross = [r for r in rows if not r["same_world"]]
    same = [r for r in rows if r["same_world"]]
    lines.append("")
    lines.append(f"different worlds: {sum(r['accepted'] for r in cross)} of {len(cross)} accepted; same world: "
                 f"{sum(r['accepted'] for r in same)} of {len(same)} verified")
    errs = [r["error_m"] for r in same if r["accepted"] and r["error_m"] is not None]
    if errs:
        lines.append(f"verified same-world answers: error vs truth {min(errs):.1f}-{max(errs):.1f} m")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", type=Path, default=Path("/work/data16"))
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_negatives"))
    ap.add_argument("--tag", default="v3")
    ap.add_argument("--worlds", default="5,11,23,42")
    ap.add_argument("--only", choices=("cross", "same"))
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--cost", action="store_true", help="also the chance model's CPU on bench_match's maps")
    ap.add_argument("--suite", type=Path, help="also the evaluation suite's answers with and without the chance "
                    "model (bench_evaluate's maps directory)")
    ap.add_argument("--no-pairs", action="store_true", help="skip the world pairs (with --cost / --suite)")
    ap.add_argument("--null", type=int, default=0, help="also calibrate the chance model on this many pairs of "
                    "unrelated random maps")
    ap.add_argument("--null-starts", type=int, default=3000, help="random refinements per --null pair")
    args = ap.parse_args(argv)
    worlds = [int(w) for w in args.worlds.split(",")]
    (args.work / "rows").mkdir(parents=True, exist_ok=True)
    print(machine_summary(), flush=True)
    rows = []
    for a, b, same in ([] if args.no_pairs else pairs(worlds, args.only)):
        if not (map_path(args.maps, args.tag, a).exists() and map_path(args.maps, args.tag, b).exists()):
            print(f"skip {a} vs {b}: no maps", flush=True)
            continue
        path = args.work / "rows" / f"{a.replace('/', '_')}--{b.replace('/', '_')}.json"
        if path.exists() and not args.fresh:
            row = json.loads(path.read_text())
        else:
            row = run_pair(args.maps, args.tag, args.work, a, b, same, args.overrides)
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(row))
            os.replace(tmp, path)
        print(f"{a} vs {b}: {'same' if same else 'different'} accepted={row['accepted']} support={row['support']} "
              f"runner-up={row['runner_up']} chance {row['chance_mean']} p={row['p_value']} "
              f"error={row['error_m']}", flush=True)
        rows.append(row)
    if rows:
        print(table(rows))
    if args.suite:
        print(suite_answers(args.suite, args.work))
    if args.cost:
        print(chance_cost())
    if args.null:
        print(null_calibration(args.null, args.null_starts), flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
