"""Change detection against the synthetic world's truth: precision and recall of gone / new (with counts and 95 %
intervals), per object kind and size, the precision of every claimed landmark, false changes per hectare, the
calibration of the confidence, same-season and cross-season pairs at several `synth --changed` levels.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_changes --work DIR [--worlds 7,11,23,31]
        [--changed 0.04,0.10] [--frames 100] [--figure FILE.png] [--example FILE.png]
        [--set changes.KEY=VALUE ...]   (an ablation: the same pairs with other change-detection parameters)
        [--cached]   (score only the pairs already matched in WORK: nothing is rendered, mapped or matched)
        [--failures]   (every false claim, missed change and claim on no object at the default confidence, with its
                        mechanism: `change_failures`)

Per world seed and change level, four sessions of one world (kept in WORK between runs): A summer (session seed
1), B summer on another path (shifted 20, 10 m, sun from 200 deg: shadows moved; seed 2), C summer on a third path
(shifted -15, -20 m, flown in reverse, sun from 120 deg; seed 4) and W winter (shifted -10, 15 m, flown in
reverse; seed 3), each mapped on its EKF poses. Every session draws its own removed and added objects (`synth
--changed` of the world's defaults), so each pair has its own changes. Same-season pairs A-B, A-C, B-C and
cross-season pairs A-W, B-W, C-W are matched and verified as `batch` does, into WORK/.../pairs/XY
(`workflows.batch.tasks.pair_task`: `sosmatch match`, whose answer is the window hypotheses verified on the full
maps, read back with `match_io.read_match`), and `workflows.changes.compute` classifies every landmark.
Scoring: `tools.benchmarks.change_truth` (objects of radius >= 2 m seen by both sessions' keyframes >= 6 times;
per-object claims, those on objects a session never mapped included (`unmapped_track_objects`: the majority label
under the track); every claimed landmark; false changes per hectare of the common area; claims outside the other
session's true observed area). `--set changes.unmapped_objects=false` scores landmarks only (the code before
that stage, identical tables).

Precision is also given with the claims on no object (ground texture, shadows: landmarks of radius >= 2 m whose
observations lie on the ground) counted as false claims (`P with ground`): what changes.csv says of things of
that size. The bar's precision counts only claims on the world's objects.

Statistics: the pairs of one world are not independent (the change levels of a world remove nested sets of the
same objects, and its pairs share sessions), so the 95 % intervals are percentile intervals of a bootstrap that
resamples whole worlds (2000 draws, fixed seed); counts are given as right / claimed and found / changed.

Printed: the bar table per season kind and change level (pooled over worlds), per kind and size, a sweep of
`changes.min_confidence`, the calibration of the confidence (claimed landmarks per confidence bin and the share
that is right), and the machine.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...plugin.params import Params
from .change_failures import Failure, classify_failures, failure_table
from .change_truth import SIZE_BINS, Score, object_truth, observed_truth_area, score_pair
from .machine import machine_summary

SESSIONS = {  # tag: (season, session seed, shift, reverse, sun azimuth)
    "A": ("summer", 1, (0.0, 0.0), False, None),
    "B": ("summer", 2, (20.0, 10.0), False, 200.0),
    "C": ("summer", 4, (-15.0, -20.0), True, 120.0),
    "W": ("winter", 3, (-10.0, 15.0), True, None),
}
SAME, CROSS = "same season", "cross season"
PAIRS = (("A", "B", SAME), ("A", "C", SAME), ("B", "C", SAME), ("A", "W", CROSS), ("B", "W", CROSS),
         ("C", "W", CROSS))
KINDS = (SAME, CROSS)
SWEEP = (0.0, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99)
CALIBRATION_BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0001)
BOOTSTRAP_DRAWS = 2000


def prepare(work: Path, world: int, changed: float, frames: int,
            pairs: Sequence[tuple[str, str, str]] = PAIRS) -> Path:
    """Synthesise, map (EKF poses) and match + verify the pairs of one world and change level (skips done work)."""
    from ...workflows.batch.tasks import pair_task
    from ...workflows.map import load_inputs
    from ...workflows.map import run as map_run
    from ...workflows.synth import SynthConfig
    from ...workflows.synth import run as synth_run

    root = work / f"w{world}_c{changed:.2f}"
    for tag in sorted({t for a, b, _ in pairs for t in (a, b)}):
        season, seed, shift, reverse, sun = SESSIONS[tag]
        if not (root / tag / "session.json").exists():
            synth_run(root / tag, SynthConfig(world_seed=world, season=season, session_seed=seed, shift_m=shift,
                                              reverse=reverse, sun_azimuth_deg=sun, changed_fraction=changed,
                                              frames=frames))
        if not (root / f"m{tag}" / "run.json").exists():
            map_run(Params(), load_inputs(None, root / tag, ekf=True), root / f"m{tag}", progress=False)
    for a, b, _ in pairs:
        if not (root / "pairs" / f"{a}{b}" / "match.json").exists():
            pair_task(str(root / f"m{a}"), str(root / f"m{b}"), str(root / "pairs" / f"{a}{b}"), Params(), verify=True)
    return root


@dataclass
class PairResult:
    world: int
    changed: float
    pair: str  # "AB": session tags
    kind: str  # SAME or CROSS
    cpu_s: float
    summary: str
    scores: dict[float, Score]
    failures: list[Failure]  # at the default min-confidence


def evaluate(root: Path, world: int, changed: float, a: str, b: str, kind: str, sweep: Sequence[float],
             params: Params | None = None, default: float = 0.8) -> PairResult | None:
    """Classify the pair a-b with its verified alignment and score it at every min-confidence of `sweep` (its
    failures at `default`); None when the pair was not aligned."""
    from ...database.match_io import read_match
    from ...database.synth_session import load_synth_session
    from ...workflows.changes import compute
    from .bench_map import landmark_objects

    alignment = read_match(root / "pairs" / f"{a}{b}" / "match.json")  # the match's verified answer
    if not alignment.accepted:
        return None  # nothing to compare: reported as a pair that was not aligned
    t = time.process_time()
    run = compute(root / f"m{a}", root / f"m{b}", None, params or Params(), a_from_b=alignment.transform,
                  images_a=root / a / "images", images_b=root / b / "images")
    cpu = time.process_time() - t
    sa, sb = load_synth_session(root / a), load_synth_session(root / b)
    kfa = json.loads((root / f"m{a}" / "run.json").read_text())["keyframes"]
    kfb = json.loads((root / f"m{b}" / "run.json").read_text())["keyframes"]
    truth = object_truth(sa, sb, kfa, kfb)
    oa, ob = landmark_objects(sa, root / f"m{a}")[0], landmark_objects(sb, root / f"m{b}")[0]
    ua = unmapped_track_objects(sa, root / f"m{a}", run.result.unmapped_a)
    ub = unmapped_track_objects(sb, root / f"m{b}", run.result.unmapped_b)
    area_a, area_b = observed_truth_area(sa, kfa), observed_truth_area(sb, kfb)
    scores = {c: score_pair(run.result, truth, oa, ob, area_a, area_b, min_confidence=c, unmapped_objects_a=ua,
                            unmapped_objects_b=ub) for c in sweep}
    failures = classify_failures(run.result, truth, oa, ob, default, ua, ub)
    return PairResult(world, changed, a + b, kind, cpu, run.summary(), scores, failures)


def unmapped_track_objects(synth: object, mapped: Path, unmapped: object) -> np.ndarray:
    """The object of each object a session never mapped (`ChangeResult.unmapped_a/b`): majority label under the
    observations of its track (keypoints of the session's database)."""
    from ...database.session_io import read_session, read_session_observations
    from .bench_map import track_objects

    if not len(unmapped.tracks):  # type: ignore[attr-defined]
        return np.zeros(0, np.int64)
    obs = read_session_observations(read_session(mapped), with_tracks=False)
    tracks = [[(obs.poses.names[k], *obs.segments[k].centroids[i]) for k, i in t]  # type: ignore[index]
              for t in unmapped.tracks]  # type: ignore[attr-defined]
    return track_objects(synth, tracks)[0]


# --- statistics -----------------------------------------------------------------------------------------------


def pool(results: Sequence[PairResult], confidence: float = 0.0) -> Score:
    out = Score()
    for r in results:
        out.add(r.scores[confidence])
    return out


def world_bootstrap(results: Sequence[PairResult], ratio: Callable[[Score], tuple[int, int]],
                    confidence: float = 0.0, draws: int = BOOTSTRAP_DRAWS, seed: int = 0) -> tuple[float, float]:
    """95 % percentile interval of a pooled ratio (numerator, denominator of `ratio`) over bootstrap samples of
    whole worlds (their pairs and change levels together)."""
    by_world: dict[int, list[int]] = {}
    for k, r in enumerate(results):
        by_world.setdefault(r.world, []).append(k)
    parts = np.array([ratio(pool([results[k] for k in ks], confidence)) for ks in by_world.values()], dtype=float)
    if not len(parts) or parts[:, 1].sum() == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(parts), (draws, len(parts)))
    num, den = parts[pick, 0].sum(1), parts[pick, 1].sum(1)
    vals = num[den > 0] / den[den > 0]
    return float(np.quantile(vals, 0.025)), float(np.quantile(vals, 0.975))


def _precision(change: str, with_ground: bool = False) -> Callable[[Score], tuple[int, int]]:
    return lambda s: s.scope_counts(change, with_ground=with_ground)[:2]


def _recall(change: str) -> Callable[[Score], tuple[int, int]]:
    return lambda s: s.scope_counts(change)[2:]


def _landmarks(s: Score) -> tuple[int, int]:
    return sum(ok for _, ok in s.landmark_claims), len(s.landmark_claims)


def _ratio_cell(results: Sequence[PairResult], fn: Callable[[Score], tuple[int, int]], confidence: float = 0.0,
                interval: bool = True) -> str:
    num, den = fn(pool(results, confidence))
    if not den:
        return "- (0)"
    text = f"{num / den:.2f} ({num}/{den})"
    if interval:
        lo, hi = world_bootstrap(results, fn, confidence)
        text += f" [{lo:.2f}-{hi:.2f}]"
    return text


def _cell(v: tuple[float, int]) -> str:
    return f"{v[0]:.2f} ({v[1]})" if v[1] else "- (0)"


def report(results: list[PairResult], sweep: Sequence[float], default: float = 0.0) -> str:
    """The tables; the bar table and the per-kind table at the `default` min-confidence (the parameters')."""
    worlds = sorted({r.world for r in results})
    lines = [f"worlds {', '.join(map(str, worlds))}; min-confidence {default:.2f}; radius >= 2 m, both saw >= 6 "
             "times; value (right/claimed or found/changed) [95 % interval, worlds resampled]", "",
             "| pairs | --changed | gone P | gone R | new P | new R | gone P with ground | new P with ground | "
             "all claimed landmarks P | false changes / ha | outside | CPU s / pair |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    levels = sorted({r.changed for r in results})
    for kind in KINDS:
        for changed in [*levels, None]:
            rs = [r for r in results if r.kind == kind and (changed is None or r.changed == changed)]
            if not rs:
                continue
            s = pool(rs, default)
            name = f"**{kind}, all**" if changed is None else kind
            lines.append(f"| {name} ({len(rs)}) | {'all' if changed is None else f'{changed:.2f}'} | "
                         f"{_ratio_cell(rs, _precision('gone'), default)} | "
                         f"{_ratio_cell(rs, _recall('gone'), default)} | "
                         f"{_ratio_cell(rs, _precision('new'), default)} | "
                         f"{_ratio_cell(rs, _recall('new'), default)} | "
                         f"{_ratio_cell(rs, _precision('gone', True), default, False)} | "
                         f"{_ratio_cell(rs, _precision('new', True), default, False)} | "
                         f"{_ratio_cell(rs, _landmarks, default)} | {s.false_per_ha():.2f} | {s.outside} | "
                         f"{np.mean([r.cpu_s for r in rs]):.2f} |")
    lines += ["", "Per kind and size (all change levels pooled; P = precision (claims), R = recall (changed "
              "objects)):", "", "| pairs | change | kind / size | P | R | R of mapped |", "|---|---|---|---|---|---|"]
    for kind in KINDS:
        s = pool([r for r in results if r.kind == kind], default)
        if not s.pairs:
            continue
        kinds = sorted({k for (_, k, _) in list(s.truth) + list(s.claimed)})
        for change in ("gone", "new"):
            for obj in kinds:
                lines.append(f"| {kind} | {change} | {obj} | {_cell(s.precision(change, kind=obj))} | "
                             f"{_cell(s.recall(change, kind=obj))} | "
                             f"{_cell(s.recall(change, kind=obj, mapped=True))} |")
            for _, _, name in SIZE_BINS:
                lines.append(f"| {kind} | {change} | radius {name} | {_cell(s.precision(change, size=name))} | "
                             f"{_cell(s.recall(change, size=name))} | "
                             f"{_cell(s.recall(change, size=name, mapped=True))} |")
        fk = ", ".join(f"{k} {v / s.common_ha:.2f}" for k, v in sorted(s.false_by_kind.items()))
        lines.append(f"| {kind} | false changes / ha by kind | {fk} | | | |")
    lines += ["", "min-confidence sweep (radius >= 2 m, all change levels pooled):", "",
              "| pairs | min confidence | gone P | gone R | new P | new R | all claimed landmarks P | "
              "false changes / ha |", "|---|---|---|---|---|---|---|---|"]
    for kind in KINDS:
        rs = [r for r in results if r.kind == kind]
        if not rs:
            continue
        for c in sweep:
            lines.append(f"| {kind} | {c:.2f} | {_ratio_cell(rs, _precision('gone'), c)} | "
                         f"{_ratio_cell(rs, _recall('gone'), c)} | {_ratio_cell(rs, _precision('new'), c)} | "
                         f"{_ratio_cell(rs, _recall('new'), c)} | {_ratio_cell(rs, _landmarks, c, False)} | "
                         f"{pool(rs, c).false_per_ha():.2f} |")
    lines += ["", "Calibration: every gone / new landmark (any size, ground texture included) by its confidence, and "
              "the share whose object truly changed:", "", "| pairs | " +
              " | ".join(f"{lo:.2f}-{min(hi, 1.0):.2f}" for lo, hi in zip(CALIBRATION_BINS, CALIBRATION_BINS[1:]))
              + " |", "|---|" + "---|" * (len(CALIBRATION_BINS) - 1)]
    for kind in KINDS:
        claims = np.array(pool([r for r in results if r.kind == kind]).landmark_claims, dtype=float).reshape(-1, 2)
        cells = []
        for lo, hi in zip(CALIBRATION_BINS, CALIBRATION_BINS[1:]):
            m = (claims[:, 0] >= lo) & (claims[:, 0] < hi)
            cells.append(f"{claims[m, 1].mean():.2f} ({int(m.sum())})" if m.any() else "- (0)")
        lines.append(f"| {kind} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(results: list[PairResult], sweep: Sequence[float], path: Path) -> None:
    """Precision and recall of gone + new (radius >= 2 m) against the min-confidence, per season kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=100, sharey=True)
    for ax, kind in zip(axes, KINDS):
        rs = [r for r in results if r.kind == kind]
        for change, colour in (("gone", "#d62728"), ("new", "#2ca02c")):
            ps, rc = [], []
            for c in sweep:
                good, claims, found, truth = pool(rs, c).scope_counts(change)
                ps.append(good / claims if claims else np.nan)
                rc.append(found / truth if truth else np.nan)
            ax.plot(sweep, ps, "-o", c=colour, label=f"{change}: precision")
            ax.plot(sweep, rc, "--s", c=colour, label=f"{change}: recall", alpha=0.7)
        ax.axhline(0.9, c="k", lw=0.5, ls=":")
        ax.axhline(0.8, c="k", lw=0.5, ls=":")
        ax.set_title(f"{kind} ({len(rs)} pairs)")
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
    ap.add_argument("--changed", default="0.04,0.10")
    ap.add_argument("--pairs", default=",".join(a + b for a, b, _ in PAIRS),
                    help="session pairs to run, e.g. AB,AW (default all six)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--figure", type=Path, help="write the min-confidence figure here")
    ap.add_argument("--example", type=Path, help="write the first same-season pair's changes.png here")
    ap.add_argument("--cached", action="store_true",
                    help="score only the pairs already matched in WORK (render, map and match nothing)")
    ap.add_argument("--failures", action="store_true",
                    help="print every failure's mechanism at the default min-confidence (change_failures)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="parameter override for change detection (repeatable)")
    args = ap.parse_args(argv)
    from ...database.config_io import parse_override
    from ...plugin.params import with_overrides

    params = with_overrides(Params(), dict(parse_override(t) for t in args.overrides))
    default = params.changes.min_confidence  # the bar table's; every claim is kept for the sweep below it
    sweep = sorted({*SWEEP, default})
    params = with_overrides(params, {"changes.min_confidence": 0.0})
    if args.overrides:
        print(f"parameters: {', '.join(args.overrides)}")
    worlds = [int(w) for w in args.worlds.split(",")]
    levels = [float(c) for c in args.changed.split(",")]
    wanted = set(args.pairs.split(","))
    pairs = [p for p in PAIRS if p[0] + p[1] in wanted]
    results: list[PairResult] = []
    for world in worlds:
        for changed in levels:
            root = (args.work / f"w{world}_c{changed:.2f}" if args.cached
                    else prepare(args.work, world, changed, args.frames, pairs))
            for a, b, kind in pairs:
                if args.cached and not (root / "pairs" / f"{a}{b}" / "match.json").is_file():
                    print(f"world {world} changed {changed:.2f} {a}-{b} ({kind}): not in WORK, not scored", flush=True)
                    continue
                res = evaluate(root, world, changed, a, b, kind, sweep, params, default)
                if res is None:
                    print(f"world {world} changed {changed:.2f} {a}-{b} ({kind}): not aligned (no accepted "
                          "alignment), not scored", flush=True)
                    continue
                results.append(res)
                print(f"world {world} changed {changed:.2f} {a}-{b} ({kind}): {res.summary} ({res.cpu_s:.2f} s "
                      "CPU)", flush=True)
    print()
    print(report(results, sweep, default))
    if args.failures:
        for kind in KINDS:
            found = [f for r in results if r.kind == kind for f in r.failures]
            if found:
                print(f"\nFailures, {kind} (min-confidence {default:.2f}; objects of radius >= 2 m both saw >= 6 "
                      f"times, claims on no object of radius >= 2 m):\n")
                print(failure_table(found))
    if args.figure:
        figure(results, sweep, args.figure)
    if args.example:
        from ...database.atomic import write_bytes_atomic
        from ...workflows.changes import changes_png, compute

        a, b, _ = pairs[0]
        root = args.work / f"w{worlds[0]}_c{levels[-1]:.2f}"
        run = compute(root / f"m{a}", root / f"m{b}", root / "pairs" / f"{a}{b}" / "match.json",
                      with_overrides(params, {"changes.min_confidence": default}))
        write_bytes_atomic(args.example, changes_png(run.result, f"world {worlds[0]}, --changed {levels[-1]:.2f}, "
                                                                 f"{a} vs {b}: {run.summary()}"))
    print(f"\nmachine: {machine_summary()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
