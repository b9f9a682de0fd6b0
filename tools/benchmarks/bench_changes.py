"""Change detection against the synthetic world's truth: precision and recall of gone / new per object kind and
size, false changes per hectare, same-season and cross-season pairs, at several `synth --changed` levels.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_changes --work DIR [--worlds 7,11,23,31]
        [--changed 0.04,0.10,0.25] [--frames 100] [--figure FILE.png] [--example FILE.png]
        [--set changes.KEY=VALUE ...]   (an ablation: the same pairs with other change-detection parameters)

Per world seed and change level, three sessions of one world (kept in WORK between runs): A summer (session seed
1), B summer on another path (shifted 20, 10 m, sun from 200 deg: shadows moved; seed 2) and W winter (shifted
-10, 15 m, flown in reverse; seed 3), each mapped on its EKF poses. Pairs A-B (same season) and A-W (cross season)
are matched as `batch` does, into WORK/.../pairs/A{B,W} (`workflows.batch.tasks.pair_task`: `sosmatch match`,
whose answer is the window hypotheses verified on the full maps, read back with `match_io.read_match`), and
`workflows.changes.compute` classifies every landmark. Scoring: `tools.benchmarks.change_truth` (objects of
radius >= 2 m seen by both sessions' keyframes >= 6 times; per-object claims; false changes per hectare of the
common area; claims outside the other session's true observed area).

Printed: one table row per season kind and change level (pooled over worlds), then per kind and size bin
(pooled), then a sweep of `changes.min_confidence` with the precision and recall each leaves, and the machine.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...plugin.params import Params
from .change_truth import SIZE_BINS, Score, object_truth, observed_truth_area, score_pair
from .machine import machine_summary

SESSIONS = {  # tag: (season, session seed, shift, reverse, sun azimuth)
    "A": ("summer", 1, (0.0, 0.0), False, None),
    "B": ("summer", 2, (20.0, 10.0), False, 200.0),
    "W": ("winter", 3, (-10.0, 15.0), True, None),
}
PAIRS = {"B": "same season", "W": "cross season"}
SWEEP = (0.0, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95)


def prepare(work: Path, world: int, changed: float, frames: int) -> Path:
    """Synthesise, map (EKF poses) and match + verify the pairs of one world and change level (skips done work)."""
    from ...workflows.batch.tasks import pair_task
    from ...workflows.map import load_inputs
    from ...workflows.map import run as map_run
    from ...workflows.synth import SynthConfig
    from ...workflows.synth import run as synth_run

    root = work / f"w{world}_c{changed:.2f}"
    for tag, (season, seed, shift, reverse, sun) in SESSIONS.items():
        if not (root / tag / "session.json").exists():
            synth_run(root / tag, SynthConfig(world_seed=world, season=season, session_seed=seed, shift_m=shift,
                                              reverse=reverse, sun_azimuth_deg=sun, changed_fraction=changed,
                                              frames=frames))
        if not (root / f"m{tag}" / "run.json").exists():
            map_run(Params(), load_inputs(None, root / tag, ekf=True), root / f"m{tag}", progress=False)
    for tag in PAIRS:
        if not (root / "pairs" / f"A{tag}" / "match.json").exists():
            pair_task(str(root / "mA"), str(root / f"m{tag}"), str(root / "pairs" / f"A{tag}"), Params(), verify=True)
    return root


@dataclass
class PairResult:
    world: int
    changed: float
    kind: str
    cpu_s: float
    summary: str
    scores: dict[float, Score]


def evaluate(root: Path, world: int, changed: float, tag: str, sweep: tuple[float, ...],
             params: Params | None = None) -> PairResult | None:
    """Classify the pair A-`tag` with its verified alignment and score it at every min-confidence of `sweep`;
    None when the pair was not aligned."""
    from ...database.match_io import read_match
    from ...database.synth_session import load_synth_session
    from ...workflows.changes import compute
    from .bench_map import landmark_objects

    alignment = read_match(root / "pairs" / f"A{tag}" / "match.json")  # the match's verified answer
    if not alignment.accepted:
        return None  # nothing to compare: reported as a pair that was not aligned
    t = time.process_time()
    run = compute(root / "mA", root / f"m{tag}", None, params or Params(), a_from_b=alignment.transform)
    cpu = time.process_time() - t
    sa, sb = load_synth_session(root / "A"), load_synth_session(root / tag)
    kfa = json.loads((root / "mA" / "run.json").read_text())["keyframes"]
    kfb = json.loads((root / f"m{tag}" / "run.json").read_text())["keyframes"]
    truth = object_truth(sa, sb, kfa, kfb)
    oa, ob = landmark_objects(sa, root / "mA")[0], landmark_objects(sb, root / f"m{tag}")[0]
    area_a, area_b = observed_truth_area(sa, kfa), observed_truth_area(sb, kfb)
    scores = {c: score_pair(run.result, truth, oa, ob, area_a, area_b, min_confidence=c) for c in sweep}
    return PairResult(world, changed, PAIRS[tag], cpu, run.summary(), scores)


def _bar(score: Score, change: str) -> tuple[float, int, float, int, float, int]:
    """(precision, claims, recall, removed/added, recall over mapped, mapped) over radius >= 2 m."""
    def pooled(fn: object, **kw: object) -> tuple[float, int]:
        vals = [fn(change, size=name, **kw) for lo, _, name in SIZE_BINS if lo >= 2.0]
        n = sum(k for _, k in vals)
        return (sum(v * k for v, k in vals if k) / n if n else float("nan")), n
    p, n_p = pooled(score.precision)
    r, n_r = pooled(score.recall)
    rm, n_m = pooled(score.recall, mapped=True)
    return p, n_p, r, n_r, rm, n_m


def _cell(v: float, n: int) -> str:
    return f"{v:.2f} ({n})" if n else "- (0)"


def report(results: list[PairResult], sweep: tuple[float, ...]) -> str:
    lines = ["| pairs | --changed | gone P (claims) | gone R (removed) | gone R of mapped | new P | new R | "
             "new R of mapped | false changes / ha | outside | CPU s / pair |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple[str, float], list[PairResult]] = {}
    for r in results:
        groups.setdefault((r.kind, r.changed), []).append(r)
    for (kind, changed), rs in sorted(groups.items()):
        pool = Score()
        for r in rs:
            pool.add(r.scores[0.0])
        g, nw = _bar(pool, "gone"), _bar(pool, "new")
        lines.append(f"| {kind} ({len(rs)}) | {changed:.2f} | {_cell(g[0], g[1])} | {_cell(g[2], g[3])} | "
                     f"{_cell(g[4], g[5])} | {_cell(nw[0], nw[1])} | {_cell(nw[2], nw[3])} | {_cell(nw[4], nw[5])} | "
                     f"{pool.false_per_ha():.2f} | {pool.outside} | {np.mean([r.cpu_s for r in rs]):.2f} |")
    lines += ["", "Per kind and size (all change levels pooled; P = precision (claims), R = recall (changed "
              "objects)):", "", "| pairs | change | kind / size | P | R | R of mapped |", "|---|---|---|---|---|---|"]
    for kind in PAIRS.values():
        pool = Score()
        for r in results:
            if r.kind == kind:
                pool.add(r.scores[0.0])
        kinds = sorted({k for (_, k, _) in list(pool.truth) + list(pool.claimed)})
        for change in ("gone", "new"):
            for obj in kinds:
                p, r_ = pool.precision(change, kind=obj), pool.recall(change, kind=obj)
                rm = pool.recall(change, kind=obj, mapped=True)
                lines.append(f"| {kind} | {change} | {obj} | {_cell(*p)} | {_cell(*r_)} | {_cell(*rm)} |")
            for _, _, name in SIZE_BINS:
                p, r_ = pool.precision(change, size=name), pool.recall(change, size=name)
                rm = pool.recall(change, size=name, mapped=True)
                lines.append(f"| {kind} | {change} | radius {name} | {_cell(*p)} | {_cell(*r_)} | {_cell(*rm)} |")
        fk = ", ".join(f"{k} {v / pool.common_ha:.2f}" for k, v in sorted(pool.false_by_kind.items()))
        lines.append(f"| {kind} | false changes / ha by kind | {fk} | | | |")
    lines += ["", "min-confidence sweep (radius >= 2 m, all change levels pooled):", "",
              "| pairs | min confidence | gone P | gone R | new P | new R | false changes / ha |",
              "|---|---|---|---|---|---|---|"]
    for kind in PAIRS.values():
        for c in sweep:
            pool = Score()
            for r in results:
                if r.kind == kind:
                    pool.add(r.scores[c])
            g, nw = _bar(pool, "gone"), _bar(pool, "new")
            lines.append(f"| {kind} | {c:.2f} | {_cell(g[0], g[1])} | {_cell(g[2], g[3])} | {_cell(nw[0], nw[1])} | "
                         f"{_cell(nw[2], nw[3])} | {pool.false_per_ha():.2f} |")
    return "\n".join(lines)


def figure(results: list[PairResult], sweep: tuple[float, ...], path: Path) -> None:
    """Precision and recall of gone + new (radius >= 2 m) against the min-confidence, per season kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=100, sharey=True)
    for ax, kind in zip(axes, PAIRS.values()):
        for change, colour in (("gone", "#d62728"), ("new", "#2ca02c")):
            ps, rs = [], []
            for c in sweep:
                pool = Score()
                for r in results:
                    if r.kind == kind:
                        pool.add(r.scores[c])
                b = _bar(pool, change)
                ps.append(b[0])
                rs.append(b[2])
            ax.plot(sweep, ps, "-o", c=colour, label=f"{change}: precision")
            ax.plot(sweep, rs, "--s", c=colour, label=f"{change}: recall", alpha=0.7)
        ax.axhline(0.9, c="k", lw=0.5, ls=":")
        ax.set_title(f"{kind} ({sum(r.kind == kind for r in results)} pairs)")
        ax.set_xlabel("--min-confidence")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("objects of radius >= 2 m")
    axes[0].legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--worlds", default="7,11,23,31")
    ap.add_argument("--changed", default="0.04,0.10,0.25")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--figure", type=Path, help="write the min-confidence figure here")
    ap.add_argument("--example", type=Path, help="write the first same-season pair's changes.png here")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="parameter override for change detection (repeatable)")
    args = ap.parse_args(argv)
    from ...database.config_io import parse_override
    from ...plugin.params import with_overrides

    params = with_overrides(Params(), dict(parse_override(t) for t in args.overrides))
    if args.overrides:
        print(f"parameters: {', '.join(args.overrides)}")
    worlds = [int(w) for w in args.worlds.split(",")]
    levels = [float(c) for c in args.changed.split(",")]
    results: list[PairResult] = []
    for world in worlds:
        for changed in levels:
            root = prepare(args.work, world, changed, args.frames)
            for tag in PAIRS:
                res = evaluate(root, world, changed, tag, SWEEP, params)
                if res is None:
                    print(f"world {world} changed {changed:.2f} {PAIRS[tag]}: not aligned (no accepted alignment), "
                          "not scored", flush=True)
                    continue
                results.append(res)
                print(f"world {world} changed {changed:.2f} {res.kind}: {res.summary} ({res.cpu_s:.2f} s CPU)",
                      flush=True)
    print()
    print(report(results, SWEEP))
    if args.figure:
        figure(results, SWEEP, args.figure)
    if args.example:
        from ...database.atomic import write_bytes_atomic
        from ...workflows.changes import changes_png, compute

        root = args.work / f"w{worlds[0]}_c{levels[-1]:.2f}"
        run = compute(root / "mA", root / "mB", root / "pairs" / "AB" / "match.json")
        write_bytes_atomic(args.example, changes_png(run.result, f"world {worlds[0]}, --changed {levels[-1]:.2f}, "
                                                                 f"summer vs summer: {run.summary()}"))
    print(f"\nmachine: {machine_summary()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
