"""Benchmark of the association stage (issue 15): one CLIPPER problem against the C++ reference, and the match on
maps of every kind (sparse, dense, without sizes, aerial, crossing flights, a season), with its scaling.

    python -m sosmatch.tools.benchmarks.bench_match                     # everything (tens of minutes)
    python -m sosmatch.tools.benchmarks.bench_match --only clipper      # or: sparse, dense, derived, nosizes, aerial,
                                                                        #     crossing, season, scaling, refusal
    python -m sosmatch.tools.benchmarks.bench_match --only scaling --max-scaling 20000 --plot docs/img/match_scaling.png
    python -m sosmatch.tools.benchmarks.bench_match --only refusal --max-refusal 3000  # maps of two places
Prints every figure (medians of repeats) with the machine line and the load. CPU times are `time.process_time` of
this one process (the search runs in one process); wall times are given beside them. Peak memory is the
VmHWM of a fresh child process that runs one match (`--memory`; `match_report.peak_rss_mb`).

The one-problem comparison with the C++ CLIPPER reference (how to build it, the protocol): `match_clipper.py`
(`--clipper-ref BUILD_DIR`).

Problems: `match_problems.py` (deterministic in their seeds; each documented there).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ...plugin.association import search_reference
from ...plugin.association.reference import differences
from ...plugin.association.synthetic import survey_map_pair
from ...plugin.map_noise import MapNoise, derived_association_params
from ...plugin.match_answer import match_maps
from ...plugin.params import Params, preset_params, with_overrides
from ...workflows.match.transform_choice import answer_plan, plan_search
from .bench_match_real import bench_evaluation, bench_naip
from .machine import machine_summary
from .match_clipper import bench_clipper
from .match_problems import aerial_maps, boulder_maps, crossing_maps, dense_maps, season_maps
from .match_report import bar, peak_rss_mb, print_bars, quality, report, timed, timed_match

BARS_S = {"sparse": 0.2, "dense": 1.0, "nosizes": 1.0, "aerial": 5.0, "season": 10.0}
AERIAL_MEMORY_BAR_MB = 500.0


# --- maps ----------------------------------------------------------------------------------------------------------


def bench_sparse(repeats: int, reference: bool) -> list[dict]:
    s = survey_map_pair(1000, seed=1)
    truth = set(map(tuple, s.truth.tolist()))
    print(f"## Two sparse survey maps, {len(s.points_a)} x {len(s.points_b)} landmarks ({len(s.truth)} shared)")
    rows = []
    for label, params in (("default", Params()), ("paper preset", preset_params("paper"))):
        ans, cpu, wall = timed_match(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params, repeats)
        rows.append(report(f"sparse 1000, {label}", ans, cpu, wall, truth, s.rotation,
                            BARS_S["sparse"] if label == "default" else None))
        if reference:
            t0 = time.process_time()
            ref = search_reference(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params.association)
            diff = differences(ans.search, ref)
            print(f"  reference (every window pair from scratch): {time.process_time() - t0:.1f} s CPU; "
                  f"same hypotheses: {not diff}")
    return rows


def bench_dense(repeats: int) -> list[dict]:
    s = dense_maps()
    truth = set(map(tuple, s.truth.tolist()))
    print(f"## Dense maps (demo density), {len(s.points_a)} x {len(s.points_b)} landmarks in "
          f"{np.ptp(s.points_a[:, 0]):.0f} m x {np.ptp(s.points_a[:, 1]):.0f} m")
    rows = []
    for label, params, reps in (("default", Params(), repeats), ("paper preset", preset_params("paper"), 1)):
        ans, cpu, wall = timed_match(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params, reps)
        rows.append(report(f"dense 600, {label}", ans, cpu, wall, truth, s.rotation,
                            BARS_S["dense"] if label == "default" else None))
    return rows


# The noise figures every mapped session carries (`map_noise.MapNoise`), at the upper end of those of bench_seasons'
# v3 maps of worlds 5, 11, 23, 42 (residual 0.82-0.97 m, size log-spread 0.07-0.095): theta_eps 2.85 m, sigma
# 1.43 m, theta_r 0.38 derived, the widest tolerances (the slowest search) those sessions get.
MAPPED_NOISE = MapNoise(ground_resolution_m=0.1, residual_m=0.95, size_log_std=0.09, landmarks=1)


def timed_default_match(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, noise: MapNoise,
                        repeats: int) -> tuple:
    """`timed_match` of what `sosmatch match` runs on two mapped sessions (`workflows.match.run`): the parameters
    derived from the maps' noise figures and geometry, the first search with the tighter tolerances, the derived
    one only when its verification refuses (`transform_choice.answer_plan`, the function `match` calls; the maps
    are of given poses: searched rigidly). The derivation is timed with the match."""
    base = Params()

    def once(a: np.ndarray, sa: np.ndarray, b: np.ndarray, sb: np.ndarray) -> object:
        return answer_plan(plan_search(base, False, False, False, noise, noise, a, sa, b, sb), a, sa, b, sb).answer

    return timed(once, pa, ha, pb, hb, repeats)


def bench_derived(repeats: int) -> list[dict]:
    """The default path on maps that carry noise figures (every mapped session; the sparse and dense cases above
    are bare arrays, so they search with the configured tolerances): the sparse and dense maps, and a sparse pair
    of another season (B's sizes re-segmented, 25 % size noise, 1 m position noise), each with `MAPPED_NOISE`."""
    s, d = survey_map_pair(1000, seed=1), dense_maps()
    season = survey_map_pair(1000, seed=4, noise_m=1.0, size_noise=0.25)
    derived = derived_association_params(Params().association, MAPPED_NOISE, MAPPED_NOISE)
    print(f"## The default path on maps with noise figures (residual {MAPPED_NOISE.residual_m} m, size log-spread "
          f"{MAPPED_NOISE.size_log_std}: theta_eps {derived.distance_tolerance_m} m, sigma "
          f"{derived.affinity_sigma_m} m, theta_r {derived.max_size_difference} derived)")
    rows = []
    for name, m, limit in (("sparse 1000", s, BARS_S["sparse"]), ("dense 600", d, BARS_S["dense"]),
                           ("sparse 1000, another season", season, BARS_S["sparse"])):
        truth = set(map(tuple, m.truth.tolist()))
        ans, cpu, wall = timed_default_match(m.points_a, m.sizes_a, m.points_b, m.sizes_b, MAPPED_NOISE, repeats)
        row = report(f"{name} with noise figures (default path)", ans, cpu, wall, truth, m.rotation, limit)
        print(f"  the step that answered: {ans.tolerances} (first: the tighter tolerances; derived: the second search)")
        row["step"] = ans.tolerances
        rows.append(row)
    return rows


def bench_nosizes(repeats: int) -> list[dict]:
    a, b, r, _, truth = boulder_maps()
    print(f"## Maps without sizes (boulder-map stand-in), {len(a)} x {len(b)} landmarks, eps 0.2 m, sigma 0.1 m")
    over = {"association.distance_tolerance_m": 0.2, "association.affinity_sigma_m": 0.1}
    rows = []
    for label, base in (("default", Params()), ("paper preset", preset_params("paper"))):
        params = with_overrides(base, over)
        ans, cpu, wall = timed_match(a, None, b, None, params, repeats if label == "default" else 1)
        rows.append(report(f"no sizes 392 x 212, {label}", ans, cpu, wall, truth, r,
                            BARS_S["nosizes"] if label == "default" else None))
    return rows


def bench_aerial(repeats: int, memory: bool) -> list[dict]:
    pa, ha, pb, hb, truth = aerial_maps()
    params = preset_params("aerial")
    print(f"## Aerial maps (NAIP stand-in), {len(pa)} x {len(pb)} landmarks, {len(truth)} common, aerial preset "
          f"(position prior {params.association.position_prior_m} m)")
    rows = []
    for label, common in (("georeferenced (prior applies)", True), ("without the prior", False)):
        if not common and params.association.position_prior_m == 0:
            continue
        ans, cpu, wall = timed_match(pa, ha, pb, hb, params, repeats if common else 1, common_frame=common)
        row = report(f"aerial {len(pa)} x {len(pb)}, {label}", ans, cpu, wall, truth, np.eye(3),
                      BARS_S["aerial"] if common else None)
        if memory:
            row["peak_mb"] = child_peak_mb("aerial", common)
            ok = bar(f"aerial stand-in {len(pa)} x {len(pb)}: <= {AERIAL_MEMORY_BAR_MB:.0f} MB peak",
                     f"{row['peak_mb']:.0f} MB", row["peak_mb"] <= AERIAL_MEMORY_BAR_MB) if common else ""
            print(f"  peak memory (fresh process, imports included): {row['peak_mb']:.0f} MB"
                  + (f" - bar {AERIAL_MEMORY_BAR_MB:.0f} MB {ok}" if common else ""))
        rows.append(row)
    return rows


def reachable_fraction(pa: np.ndarray, pb: np.ndarray, truth: set, params: object) -> float:
    """Share of the common landmarks that lie in some window pair holding more than theta_S common landmarks."""
    from ...plugin.association.windows import hilbert_order, map_windows

    oa = hilbert_order(pa) if params.windows == "spatial" else np.arange(len(pa))
    ob = hilbert_order(pb) if params.windows == "spatial" else np.arange(len(pb))
    ra, rb = np.empty(len(pa), int), np.empty(len(pb), int)
    ra[oa], rb[ob] = np.arange(len(pa)), np.arange(len(pb))
    t = np.array(sorted(truth))
    pos_a, pos_b = ra[t[:, 0]], rb[t[:, 1]]
    wa, wb = map_windows(len(pa), len(pb), params)
    reached = np.zeros(len(t), bool)
    for a0, a1 in wa:
        ina = (pos_a >= a0) & (pos_a < a1)
        if ina.sum() <= params.min_associations:
            continue
        for b0, b1 in wb:
            both = ina & (pos_b >= b0) & (pos_b < b1)
            if both.sum() > params.min_associations:
                reached |= both
    return float(reached.mean())


def bench_crossing(repeats: int) -> list[dict]:
    print("## Crossing flights: common landmarks in a window pair holding > theta_S of them, and the match")
    print("| crossing | landmarks | common | windows | reachable | answer | CPU s |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for angle in (0.0, 45.0, 90.0):
        pa, ha, pb, hb, truth, r = crossing_maps(angle)
        for windows in ("id", "spatial"):
            params = with_overrides(Params(), {"association.windows": windows})
            frac = reachable_fraction(pa, pb, truth, params.association)
            ans, cpu, wall = timed_match(pa, ha, pb, hb, params, repeats)
            print(f"| {angle:.0f} deg | {len(pa)} x {len(pb)} | {len(truth)} | {windows} | {frac:.0%} | "
                  f"{quality(ans, truth, r)} | {cpu:.3f} |")
            rows.append({"angle": angle, "windows": windows, "reachable": frac, "cpu_s": cpu,
                         "accepted": bool(ans.accepted), "associations": len(ans.associations)})
    return rows


def bench_season(repeats: int) -> list[dict]:
    pa, ha, pb, hb, truth = season_maps()
    params = with_overrides(Params(), {"association.position_prior_m": 30.0})
    print(f"## A new flight of {len(pa)} landmarks against a season map of {len(pb)} (position prior 30 m)")
    # the season map and the flight share one frame: the prior applies (timed_match assumes unrelated frames)
    ans, cpu, wall = timed_match(pa, ha, pb, hb, params, repeats, common_frame=True)
    return [report(f"season {len(pa)} x {len(pb)}, prior 30 m", ans, cpu, wall, truth, None, BARS_S["season"])]


def bench_controls(repeats: int) -> list[dict]:
    """Negative controls on synthetic maps: B mirrored (x -> -x in its own frame; a mirror image is no rigid motion
    of A, so its only "alignments" are chance sets, or the upside-down copy of a flat map), for sparse, dense and
    aerial maps (the aerial one mirrored about its tile centre under the same georeference, so the prior applies).
    Nothing may be accepted."""
    print("## Negative controls: maps against the mirror image of the other (nothing may be accepted)")
    s, d = survey_map_pair(1000, seed=1), dense_maps()
    pa, ha, pb, hb, _ = aerial_maps()
    flip = np.array([-1.0, 1.0, 1.0])
    centre = np.array([pb[:, 0].min() + pb[:, 0].max(), 0.0, 0.0])
    cases = (("sparse 1000", s.points_a, s.sizes_a, s.points_b * flip, s.sizes_b, Params(), False),
             ("dense 600", d.points_a, d.sizes_a, d.points_b * flip, d.sizes_b, Params(), False),
             ("aerial stand-in", pa, ha, centre + pb * flip, hb, preset_params("aerial"), True))
    rows = []
    for name, xa, sa, xb, sb, params, common in cases:
        ans, cpu, wall = timed_match(xa, sa, xb, sb, params, repeats, common_frame=common)
        row = report(f"control {name} vs its mirror image", ans, cpu, wall, None, None)
        bar(f"negative control {name} vs mirror image: nothing accepted",
            f"{len(ans.associations)} associations accepted" if ans.accepted else "nothing accepted", not ans.accepted)
        rows.append(row)
    return rows


def bench_scaling(sizes: list[int], plot: str | None) -> list[dict]:
    print("## Search time against map size (two sparse survey maps of n x n landmarks, half of the area shared, "
          "no prior, default parameters)")
    print("| landmarks (A x B) | window pairs | solved | accepted | consistent pairs | blocks | CPU s | wall s | "
          "peak MB (process) |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    params = Params()
    for n in sizes:
        s = survey_map_pair(n, seed=1)
        ans, cpu, wall = timed_match(s.points_a, s.sizes_a, s.points_b, s.sizes_b, params, 1)
        # the process's peak so far: sizes ascend, so it is this size's peak (a fresh process per size doubled
        # the run's time; `child_peak_mb("scaling", n)` gives it alone)
        peak = peak_rss_mb()
        t = ans.search.timings
        rows.append({"n": n, "cpu_s": cpu, "wall_s": wall, "peak_mb": peak})
        if plot:  # redrawn after every size: an interrupted run keeps the curve so far
            plot_scaling(rows, plot)
        print(f"| {len(s.points_a)} x {len(s.points_b)} | {ans.search.num_window_pairs} | {len(ans.search.hypotheses)} "
              f"| {len(ans.search.accepted)} | {int(t['consistent_pairs'])} | {int(t['blocks'])} | {cpu:.2f} | "
              f"{wall:.2f} | {peak:.0f} |")
    return rows


# noise figures of a season map merged from flights (the eleventh sweep's 788-landmark map of world 7: residual 1.31 m,
# size log-spread 0.089, 0.41 m pixels), from which the match derives theta_eps 3.9 m, theta_r 0.37
SEASON_NOISE = MapNoise(ground_resolution_m=0.41, residual_m=1.31, size_log_std=0.089, landmarks=1)
SEASON_DENSITY = 5000.0  # landmarks per km^2 of the synthetic worlds' maps (3800-7800 measured on mapped flights)


def bench_refusal(sizes: list[int]) -> list[dict]:
    """What refusing maps of two places costs as they grow to the size of a season: two survey maps of n landmarks
    of unrelated worlds (`survey_map_pair` A maps of two seeds, at the density of mapped flights) with a season
    map's noise figures, matched as `sosmatch match` matches two mapped sessions (`timed_default_match`: the
    first search, its verification, the derived search, its verification). Nothing may be accepted; the figures
    say where the time goes (each stage's own clock)."""
    print("## Refusing maps of two places, season-sized (unrelated survey maps, a season map's noise figures, "
          "the default path)")
    print("| landmarks (A x B) | window pairs | hypotheses over theta_S | CPU s | search s | of it consensus s | "
          "verification s | answer |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for n in sizes:
        a = survey_map_pair(n, seed=31, density_per_km2=SEASON_DENSITY)
        b = survey_map_pair(n, seed=32, density_per_km2=SEASON_DENSITY)
        ans, cpu, wall = timed_default_match(a.points_a, a.sizes_a, b.points_a, b.sizes_a, SEASON_NOISE, 1)
        t = ans.search.timings
        rows.append({"n": n, "cpu_s": cpu, "wall_s": wall, "search_s": ans.timings["search_s"],
                     "consensus_s": t.get("consensus_s", 0.0), "verify_s": ans.timings["verify_s"],
                     "accepted": bool(ans.accepted)})
        print(f"| {len(a.points_a)} x {len(b.points_a)} | {ans.search.num_window_pairs} | "
              f"{len(ans.search.accepted)} | {cpu:.1f} | {ans.timings['search_s']:.1f} | "
              f"{t.get('consensus_s', 0.0):.1f} | {ans.timings['verify_s']:.1f} | "
              f"{'ACCEPTED' if ans.accepted else 'refused'} ({ans.tolerances}) |")
        bar(f"maps of two places, {n} landmarks each: nothing accepted",
            "accepted" if ans.accepted else "refused", not ans.accepted)
    return rows


def plot_scaling(rows: list[dict], plot: str) -> None:
    """The scaling curve (CPU seconds and peak memory against landmarks per map), log-log, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    ns = [r["n"] for r in rows]
    ax.loglog(ns, [r["cpu_s"] for r in rows], "o-", label="match (search + verification), CPU s")
    ax2 = ax.twinx()
    ax2.loglog(ns, [r["peak_mb"] for r in rows], "s--", color="gray", label="peak memory, MB (right)")
    ax.set_xticks(ns, [str(n) for n in ns])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("landmarks per map")
    ax.set_ylabel("CPU seconds")
    ax2.set_ylabel("MB")
    ax.set_title(f"sosmatch match, no prior ({machine_summary().rsplit(', ', 1)[-1]})")
    ax.grid(True, which="both", alpha=0.3)
    lines = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    ax.legend(lines, [h.get_label() for h in lines], fontsize=8, loc="upper left")
    fig.savefig(plot, bbox_inches="tight")
    plt.close(fig)


# --- peak memory of one match in a fresh process ------------------------------------------------------------------


def child_peak_mb(case: str, arg: object) -> float:
    """Peak memory (MB, `peak_rss_mb`) of a fresh interpreter that imports sosmatch, builds the maps of `case` and
    runs one match."""
    code = f"import sys; from sosmatch.tools.benchmarks.bench_match import _child; _child({case!r}, {arg!r})"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode != 0:
        print(f"  (the memory run of {case} {arg} failed with exit code {out.returncode}: "
              f"{(out.stderr.strip().splitlines() or ['no message'])[-1]})")
        return float("nan")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["peak_mb"])


def _child(case: str, arg: object) -> None:
    if case == "aerial":
        pa, ha, pb, hb, _ = aerial_maps()
        match_maps(pa, ha, pb, hb, preset_params("aerial"), common_frame=bool(arg))
    elif case == "scaling":
        s = survey_map_pair(int(arg), seed=1)
        match_maps(s.points_a, s.sizes_a, s.points_b, s.sizes_b, Params())
    print(json.dumps({"peak_mb": peak_rss_mb()}))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parts = ["clipper", "sparse", "dense", "derived", "nosizes", "aerial", "naip", "evaluation", "controls", "crossing",
             "season", "scaling", "refusal"]
    parser.add_argument("--only", choices=parts, action="append")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--clipper-ref", default=None, help="directory holding the clipper_ref module")
    parser.add_argument("--reference", action="store_true", help="check sparse maps against the slow reference")
    parser.add_argument("--memory", action="store_true", help="peak memory of the aerial match (child process)")
    parser.add_argument("--naip", type=Path, default=Path("../shared/data/naip"), help="the two NAIP orthophotos")
    parser.add_argument("--naip-work", type=Path, default=Path("naip_work"), help="NAIP sessions and maps (reused)")
    parser.add_argument("--eval-work", type=Path, default=Path("bench_work"),
                        help="evaluation suite sessions, maps and evaluations (bench_evaluate --work; reused)")
    parser.add_argument("--eval-baseline-work", type=Path, default=None,
                        help="read ORB+RANSAC from this suite's finished evaluations (same sessions) instead")
    parser.add_argument("--max-scaling", type=int, default=20000)
    parser.add_argument("--max-refusal", type=int, default=3000, help="largest maps of the refusal part")
    parser.add_argument("--plot", default=None, help="PNG of the scaling curve (e.g. docs/img/match_scaling.png)")
    parser.add_argument("--json", default=None, help="write every figure to this JSON file")
    args = parser.parse_args(argv)
    print(machine_summary())
    results: dict = {}
    for part in args.only or parts:
        if part == "clipper":
            results[part] = bench_clipper(max(3, args.repeats), args.clipper_ref)
        elif part == "sparse":
            results[part] = bench_sparse(args.repeats, args.reference)
        elif part == "dense":
            results[part] = bench_dense(args.repeats)
        elif part == "derived":
            results[part] = bench_derived(args.repeats)
        elif part == "nosizes":
            results[part] = bench_nosizes(args.repeats)
        elif part == "aerial":
            results[part] = bench_aerial(args.repeats, args.memory)
        elif part == "naip":
            results[part] = bench_naip(args.naip, args.naip_work, args.repeats, args.memory)
        elif part == "evaluation":
            results[part] = bench_evaluation(args.eval_work, 3, args.eval_baseline_work)
        elif part == "controls":
            results[part] = bench_controls(max(1, args.repeats // 3))
        elif part == "crossing":
            results[part] = bench_crossing(max(1, args.repeats // 3))
        elif part == "season":
            results[part] = bench_season(max(1, args.repeats // 2))
        elif part == "scaling":
            ns = [n for n in (250, 500, 1000, 2000, 4000, 8000, 12000, 16000, 20000) if n <= args.max_scaling]
            results[part] = bench_scaling(ns, args.plot)
        elif part == "refusal":
            results[part] = bench_refusal([n for n in (250, 500, 1000, 2000, 3000) if n <= args.max_refusal])
        print(machine_summary())
    print_bars()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
