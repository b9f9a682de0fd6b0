"""Derived association tolerances and search time, side by side in one process on the same maps.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_derive --seasons-work /work/data16 --maps-tag v3 \
        --worlds 5,11,23,42 [--cases summer-winter,spring-autumn,...] [--suite-work SUITE_WORK] [--evaluate]

Per session pair, the match's answer (`plugin.match_answer.match_maps`: search + verification) three ways: with
the configured tolerances (`association.derive_from_maps` off), with the derived ones in one search (as main ran
them from 9411800 on), and in two steps (the default: the tighter tolerances first, the derived ones only when
the first answer is refused). Each is timed in CPU seconds of this process (`time.process_time`; the compiled
kernels are warmed up first) with its derived values, consistent pairs, associations, the step that answered and
the answer's median displacement of B's matched landmarks (the synthetic maps share the world frame, so a true
answer is near the identity, up to the maps' EKF drift). With `--evaluate` (synthetic sessions), the evaluation's
average F1 and recall at P >= 0.99 (`workflows.evaluate.run`) of the configured and the default (two-step) match.

Maps are reused, never made: bench_seasons' `WORK/wSEED/maps/TAG/NAME` (cases as in bench_seasons) and
bench_evaluate's `SUITE_WORK/maps/NAME` (its cases).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from .machine import machine_summary

SEASON_CASES = {"summer-winter": ("summer", "winter"), "summer-winter-130m": ("summer", "winter-130"),
                "summer-winter-x90": ("summer", "winter-x90"), "spring-autumn": ("spring", "autumn"),
                "summer-freeform": ("summer", "summer-free"), "summer-130m": ("summer", "summer-130")}


def pairs(args: argparse.Namespace) -> list[tuple[str, Path, Path, Path, Path]]:
    """(case, session A, session B, map A, map B) of every wanted pair whose maps exist."""
    from .bench_evaluate import CASES, _slug

    out = []
    if args.suite_work:
        w = Path(args.suite_work)
        for c in CASES:
            a, b = _slug(c.synth_a), _slug(c.synth_b)
            out.append((f"suite/{c.name}", w / "sessions" / a, w / "sessions" / b, w / "maps" / a, w / "maps" / b))
    if args.seasons_work:
        for world in (int(x) for x in args.worlds.split(",") if x):
            d = Path(args.seasons_work) / f"w{world}"
            for case in args.cases.split(","):
                a, b = SEASON_CASES[case]
                out.append((f"w{world}/{case}", d / "sessions" / a, d / "sessions" / b, d / "maps" / args.maps_tag / a,
                            d / "maps" / args.maps_tag / b))
    return [p for p in out if (p[3] / "run.json").exists() and (p[4] / "run.json").exists()]


def displacement_m(answer: object, points_b: np.ndarray) -> float | None:
    """Median distance by which the answer moves B's matched landmarks (None without an answer)."""
    if not answer.accepted or len(answer.associations) == 0:
        return None
    m = np.asarray(answer.transform.to_matrix())
    q = points_b[answer.associations[:, 1]]
    return float(np.median(np.linalg.norm(q @ m[:3, :3].T + m[:3, 3] - q, axis=1)))


def bench_pair(map_a: Path, map_b: Path) -> dict:
    from ...database.map_loading import read_map_noise
    from ...plugin.map_noise import derived_search_params
    from ...plugin.match_answer import match_maps
    from ...plugin.params import Params
    from ...workflows.evaluate.ground_truth import _map_arrays

    pa, ha, _, _ = _map_arrays(map_a)
    pb, hb, _, _ = _map_arrays(map_b)
    params = Params()
    configured = dataclasses.replace(params.association, derive_from_maps=False)
    derivation = derived_search_params(params.association, read_map_noise(map_a), read_map_noise(map_b), pa, ha,
                                       pb, hb)
    derived, first = derivation.params, derivation.first_try
    row = {"landmarks": [len(pa), len(pb)], "theta_eps": derived.distance_tolerance_m,
           "sigma": derived.affinity_sigma_m, "theta_r": derived.max_size_difference}
    for name, ap, first_try in (("configured", configured, None), ("derived", derived, None),
                                ("two-step", derived, first)):
        c0 = time.process_time()
        ans = match_maps(pa, ha, pb, hb, dataclasses.replace(params, association=ap), first_try=first_try)
        row[name] = {"cpu_s": round(time.process_time() - c0, 3), "associations": int(len(ans.associations)),
                     "accepted": bool(ans.accepted), "step": ans.tolerances,
                     "consistent_pairs": int(ans.search.timings.get("consistent_pairs", 0)),
                     "displacement_m": displacement_m(ans, pb)}
    return row


def evaluate_pair(case: str, session_a: Path, session_b: Path, map_a: Path, map_b: Path, out: Path) -> dict:
    """Average F1 and recall at P >= 0.99 with the configured tolerances and with the default match."""
    from ...plugin.params import Params
    from ...workflows.evaluate import run as evaluate

    got = {}
    for name, derive in (("configured", False), ("two-step", True)):
        p = Params()
        p = dataclasses.replace(p, association=dataclasses.replace(p.association, derive_from_maps=derive))
        e = evaluate(p, session_a, session_b, out / case / name, map_a=map_a, map_b=map_b, methods=["sosmatch"],
                     case=case, repeats=1, overwrite=True)
        r = e["rows"][0]
        got[name] = {"average_f1": r["average_f1"], "recall_at_p99": r["recall_at_p99"]}
    return got


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seasons-work", default=None, help="bench_seasons' --work")
    parser.add_argument("--maps-tag", default="v3", help="bench_seasons' maps tag")
    parser.add_argument("--worlds", default="5,11,23,42")
    parser.add_argument("--cases", default=",".join(SEASON_CASES))
    parser.add_argument("--suite-work", default=None, help="bench_evaluate's --work")
    parser.add_argument("--evaluate", action="store_true", help="also the evaluation's F1 / recall (slower)")
    parser.add_argument("--eval-out", type=Path, default=Path("bench_derive_eval"))
    args = parser.parse_args(argv)
    from ...plugin.match_answer import match_maps
    from ...plugin.params import Params
    from ...workflows.evaluate.ground_truth import _map_arrays

    print(machine_summary(), flush=True)
    todo = pairs(args)
    if not todo:
        raise SystemExit("no mapped session pairs found (see --seasons-work / --suite-work)")
    pa, ha, _, _ = _map_arrays(todo[0][3])
    match_maps(pa, ha, pa, ha, Params())  # warm-up: the compiled kernels load on their first call
    for case, sa, sb, ma, mb in todo:
        row = {"case": case, **bench_pair(ma, mb)}
        if args.evaluate:
            row["evaluation"] = evaluate_pair(case, sa, sb, ma, mb, args.eval_out)
        print(json.dumps(row), flush=True)
    print(machine_summary(), flush=True)


if __name__ == "__main__":
    main()
