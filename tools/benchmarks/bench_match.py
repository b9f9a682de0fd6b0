"""Benchmark of the association stage: one CLIPPER problem, the full windowed search, and its scaling.

    python -m sosmatch.tools.benchmarks.bench_match                 # everything (a few minutes)
    python -m sosmatch.tools.benchmarks.bench_match --only clipper  # or: search, scaling
Prints the figures (median of repeats) with the machine line; `--plot PNG` writes the scaling curve.

Problems:
- clipper: 100 true associations of a rigid copy (landmarks in a 100 x 100 x 10 m box, noise 0.1 m) plus random
  wrong pairs up to m putative associations; eps 2 m, sigma 1 m; time = affinity + solve.
- search: two synthetic survey maps (`plugin/association/synthetic.py`: 300 landmarks/km^2, lawnmower id order,
  sizes 1-8 m with 10 % noise, half of the area shared, position noise 0.4 m, 10 % missing, 5 % added, arbitrary
  yaw, 2 deg tilt), default parameters; checked against the straightforward per-window-pair reference.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from ...plugin.association import affinity_graph, search, search_reference, solve
from ...plugin.association.rigid import rotation_angle_deg, rotation_from_rpy_deg
from ...plugin.association.synthetic import survey_map_pair
from ...plugin.params import AssociationParams
from .machine import machine_summary

CLIPPER_BARS_MS = {256: 5.0, 512: 15.0, 1024: 50.0, 2048: 200.0}
SEARCH_BAR_S = 2.0
SCALING_SIZES = (250, 500, 1000, 2000, 4000)


def clipper_problem(m: int, n_true: int = 100, noise: float = 0.1, seed: int = 0) -> tuple:
    """Points of A and B, m putative pairs (the first n_true rows true before shuffling), truth mask."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (n_true, 3)) * [100.0, 100.0, 10.0]
    r = rotation_from_rpy_deg(*rng.uniform(-3, 3, 2), rng.uniform(-180, 180))
    b = a @ r.T + rng.uniform(-100, 100, 3) + rng.normal(0, noise, a.shape)
    wrong = set()
    while len(wrong) < m - n_true:
        i, j = rng.integers(0, n_true, 2)
        if i != j:
            wrong.add((int(i), int(j)))
    pairs = np.concatenate([np.stack([np.arange(n_true)] * 2, 1), np.array(sorted(wrong)).reshape(-1, 2)])
    perm = rng.permutation(len(pairs))
    return a, b, pairs[perm], perm < n_true


def bench_clipper(repeats: int) -> None:
    print("## One association problem: 100 true pairs + outliers, noise 0.1 m, eps 2 m (affinity + solve)")
    print("| m | edges | affinity ms | solve ms | total ms (median) | CPU ms (median) | bar ms | true pairs selected "
          "| false pairs |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m, bar in CLIPPER_BARS_MS.items():
        a, b, pairs, is_true = clipper_problem(m)
        t_aff, t_sol, t_tot, t_cpu = [], [], [], []
        for _ in range(repeats):
            c0 = time.process_time()
            t0 = time.perf_counter()
            g = affinity_graph(a, b, pairs, eps=2.0, sigma=1.0)
            t1 = time.perf_counter()
            res = solve(g)
            t2 = time.perf_counter()
            t_cpu.append(time.process_time() - c0)
            t_aff.append(t1 - t0)
            t_sol.append(t2 - t1)
            t_tot.append(t2 - t0)
        sel = res.selected
        print(f"| {m} | {len(g.rows)} | {1e3 * statistics.median(t_aff):.1f} | {1e3 * statistics.median(t_sol):.1f} "
              f"| **{1e3 * statistics.median(t_tot):.1f}** | {1e3 * statistics.median(t_cpu):.1f} | {bar:.0f} "
              f"| {int(is_true[sel].sum())}/100 "
              f"| {int((~is_true[sel]).sum())} |")


def _maps(n: int, seed: int = 1) -> tuple:
    s = survey_map_pair(n, seed=seed)
    return s, (s.points_a, s.sizes_a, s.points_b, s.sizes_b)


def _accepted_key(res: object) -> list:
    return [(h.window_a, h.window_b, h.associations.tolist()) for h in res.hypotheses if h.accepted]


def bench_search(repeats: int, reference: bool) -> None:
    params = AssociationParams()
    s, args = _maps(1000)
    print(f"## Windowed search, two maps of {len(s.points_a)} and {len(s.points_b)} landmarks "
          f"({len(s.truth)} shared), default parameters")
    runs, cpu, res = [], [], None
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        res = search(*args, params, workers=1)
        runs.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    c = res.consensus
    truth = set(map(tuple, s.truth.tolist()))
    found = set(map(tuple, c.associations.tolist())) if c else set()
    print(f"search: median {statistics.median(runs):.2f} s over {repeats} runs (bar {SEARCH_BAR_S} s), "
          f"runs {', '.join(f'{t:.2f}' for t in runs)}; CPU median {statistics.median(cpu):.2f} s (one process)")
    print("stages (last run): " + ", ".join(f"{k} {v:.3g}" for k, v in res.timings.items()))
    print(f"window pairs {res.num_window_pairs}, solved {len(res.hypotheses)}, accepted {len(res.accepted)}; "
          f"consensus {len(found)} associations, {len(found & truth)} true, {len(found - truth)} false; "
          f"rotation error {rotation_angle_deg(c.transform.rotation, s.rotation):.3f} deg, translation error "
          f"{np.linalg.norm(c.transform.translation - s.translation):.2f} m")
    if reference:
        t0 = time.perf_counter()
        ref = search_reference(*args, params)
        t_ref = time.perf_counter() - t0
        same = _accepted_key(ref) == _accepted_key(res)
        print(f"reference (every window pair from scratch): {t_ref:.1f} s, {len(ref.accepted)} accepted; "
              f"same accepted hypotheses and associations: {same}")


def bench_scaling(repeats: int, plot: str | None, reference_up_to: int) -> None:
    params = AssociationParams()
    print("## Search time against map size (both maps about this size, half of the area shared)")
    print("| landmarks (A x B) | window pairs | solved | accepted | consistent pairs | search s (median) "
          "| CPU s | reference s |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for n in SCALING_SIZES:
        s, args = _maps(n)
        runs, cpu = [], []
        for _ in range(repeats if n <= 2000 else 1):
            c0 = time.process_time()
            t0 = time.perf_counter()
            res = search(*args, params, workers=1)
            runs.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        t_ref = None
        if n <= reference_up_to:
            t0 = time.perf_counter()
            search_reference(*args, params)
            t_ref = time.perf_counter() - t0
        med = statistics.median(runs)
        rows.append((n, med, t_ref, statistics.median(cpu)))
        print(f"| {len(s.points_a)} x {len(s.points_b)} | {res.num_window_pairs} | {len(res.hypotheses)} | "
              f"{len(res.accepted)} | {int(res.timings['consistent_pairs'])} | {med:.2f} | "
              f"{statistics.median(cpu):.2f} | "
              f"{'-' if t_ref is None else f'{t_ref:.1f}'} |")
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
        ns = [r[0] for r in rows]
        ax.loglog(ns, [r[1] for r in rows], "o-", label="search, wall time")
        ax.loglog(ns, [r[3] for r in rows], "^-", label="search, CPU time (one process)")
        ref = [(r[0], r[2]) for r in rows if r[2] is not None]
        if ref:
            ax.loglog(*zip(*ref), "s--", label="reference: every window pair from scratch")
        ax.axhline(SEARCH_BAR_S, color="gray", lw=0.8, ls=":", label=f"bar at 1000 landmarks ({SEARCH_BAR_S} s)")
        from matplotlib.ticker import NullFormatter

        ax.set_xticks(ns, [str(n) for n in ns])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("landmarks per map")
        ax.set_ylabel("seconds")
        ax.set_title(f"sosmatch match: windowed search time ({machine_summary().rsplit(', ', 1)[-1]})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.savefig(plot, bbox_inches="tight")
        plt.close(fig)
        print(f"plot: {plot}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", choices=["clipper", "search", "scaling"], action="append")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-reference", action="store_true", help="skip the slow reference check at 1000")
    parser.add_argument("--reference-up-to", type=int, default=500, help="reference timings in the scaling table")
    parser.add_argument("--plot", default=None, help="PNG of the scaling curve (e.g. docs/img/match_scaling.png)")
    args = parser.parse_args()
    parts = args.only or ["clipper", "search", "scaling"]
    print(machine_summary())
    if "clipper" in parts:
        bench_clipper(max(args.repeats, 5))
    if "search" in parts:
        bench_search(args.repeats, not args.no_reference)
    if "scaling" in parts:
        bench_scaling(max(1, args.repeats // 2), args.plot, args.reference_up_to)
    print(machine_summary())


if __name__ == "__main__":
    main()
