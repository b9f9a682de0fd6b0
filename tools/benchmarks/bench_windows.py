"""The chance model of window pairs against the search itself, and the windows it derives (issue 16).

    python -m sosmatch.tools.benchmarks.bench_windows MAP_A MAP_B [MAP_A MAP_B ...] [--lengths 50,100,200]

For every pair of mapped sessions (directories with landmarks.sosmap and run.json): the tolerances derived from
their noise, the chance model (`plugin.association.window_chance`) at each window length, the largest upright
consistent set the search finds between A and B mirrored (x -> -x in B's frame: same density, sizes and layout,
but no rigid transform explains it, so every set is chance), and the windows and theta_S `derived_search_params`
gives (`--no-search`: the model and the derived windows only, for many pairs). Prints one line per pair and
length, then the machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


def chance_rows(map_a: Path, map_b: Path, lengths: list[int], run_search: bool = True) -> list[dict]:
    from ...database.map_loading import load_map
    from ...plugin.association import search
    from ...plugin.association.window_chance import window_chance
    from ...plugin.map_noise import derived_association_params, derived_search_params
    from ...plugin.params import Params

    a, b = load_map(map_a), load_map(map_b)
    pa, ha, pb, hb = a.lmap.positions, a.lmap.sizes, b.lmap.positions.copy(), b.lmap.sizes
    tolerances = derived_association_params(Params().association, a.noise, b.noise)
    derived = derived_search_params(Params().association, a.noise, b.noise, pa, ha, pb, hb)
    pb[:, 0] *= -1.0
    rows = []
    for length in lengths:
        model = window_chance(pa, ha, pb, hb, tolerances, length)
        # theta_S 3: every window pair with a set of 4 or more is solved (chance sets of a few are everywhere)
        ap = dataclasses.replace(tolerances, window_length=length, window_stride=max(1, length // 5),
                                 min_associations=3)
        c0 = time.process_time()
        found = None
        if run_search:
            res = search(pa, ha, pb, hb, ap)
            found = max((int(h.size) for h in res.hypotheses
                         if h.transform is not None and h.tilt_deg <= ap.max_gravity_angle_deg), default=0)
        rows.append({"pair": f"{map_a} / {map_b.name}", "theta_eps": tolerances.distance_tolerance_m,
                     "length": length, "lambda": round(model.per_transform, 3), "model_largest": model.largest,
                     "search_largest": found, "cpu_s": round(time.process_time() - c0, 2),
                     "derived": (derived.params.window_length, derived.params.window_stride,
                                 derived.params.min_associations)})
    return rows


def main(argv: list[str] | None = None) -> None:
    from .machine import machine_summary

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("maps", nargs="+", type=Path, help="mapped sessions, in pairs A B")
    parser.add_argument("--lengths", default="50", help="window lengths to compare (comma-separated)")
    parser.add_argument("--no-search", action="store_true", help="the model and the derived windows only")
    args = parser.parse_args(argv)
    if len(args.maps) % 2:
        parser.error("maps come in pairs")
    lengths = [int(x) for x in args.lengths.split(",")]
    print("| pair | theta_eps m | window | lambda | largest chance set: model | search (mirrored B) | "
          "derived windows / stride / theta_S |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for map_a, map_b in zip(args.maps[::2], args.maps[1::2]):
        for r in chance_rows(map_a, map_b, lengths, run_search=not args.no_search):
            found = "-" if r["search_largest"] is None else r["search_largest"]
            print(f"| {r['pair']} | {r['theta_eps']:.2f} | {r['length']} | {r['lambda']:.2f} | {r['model_largest']} | "
                  f"{found} | {' / '.join(str(v) for v in r['derived'])} |", flush=True)
    print(machine_summary())


if __name__ == "__main__":
    main()
