"""Seasons, crossing flights and altitude on several synthetic worlds (issue 16), resumable.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_seasons --work /work/data16 --worlds 11,5,23,42 \
        [--held-out 23,42] [--cases summer-winter,...] [--maps-tag T --map-set k=v ...] \
        [--eval-tag E --eval-set k=v ...] [--no-baselines] [--write]

Per world (`--world-seed`; sessions of one world share it exactly) the same sessions, with fixed session seeds:
summer (A of every summer case), winter over the same path, winter on the path rotated by 45 and by 90 degrees
(crossing flights), winter at 130 m instead of 100 m, spring and autumn over the same path, a summer free-form
flight, and summer at 80, 130 and 150 m (altitude: size agreement; winter at 130 m is also evaluated against
winter, so the altitude is measured in both seasons apart from what the season changes in the objects' look).
Every session is mapped on its EKF poses (`sosmatch map --ekf`, as the evaluation suite does) and every case
evaluated with `workflows.evaluate.run`: the paper's average F1 and recall at P >= 0.99, F1 and recall at the
matcher's own operating point (theta_S), the common landmarks of the two maps against the ground-truth objects,
their size agreement and the oracle recall (`plugin.evaluation.landmark_truth`).

Layout under `--work` (nothing is recomputed that exists; an interrupted run resumes):
    wSEED/sessions/NAME                 sosmatch synth (session.json = done)
    wSEED/maps/TAG/NAME                 sosmatch map --ekf with TAG's parameters (run.json = done)
    wSEED/baselines/CASE/evaluation.json  ORB+RANSAC and SIFT+RANSAC (independent of the maps: computed once)
    wSEED/eval/TAG/CASE/evaluation.json   ours with the maps of TAG (and the association parameters of --eval-set)
Worlds in `--held-out` are marked so in the tables: they are evaluated, never tuned on.
`--write` puts the tables between `<!-- section:seasons -->` and `<!-- end:seasons -->` of BENCHMARKS.md.
Run it with `nice -n 10`: a world is ~11 sessions (~25 s of CPU each to render, ~30 s to map).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .bench_evaluate import run_cli
from .machine import machine_summary

log = logging.getLogger(__name__)

MARKER, END_MARKER = "<!-- section:{} -->", "<!-- end:{} -->"

# Session name -> `sosmatch synth` arguments (the world seed is added). Seeds as in bench_evaluate where the
# session is the same (summer 1, winter 6, spring 4, autumn 5), so world 11 reproduces the suite's sessions.
SESSIONS: dict[str, tuple[str, ...]] = {
    "summer": ("--season", "summer", "--session-seed", "1"),
    "winter": ("--season", "winter", "--session-seed", "6"),
    "winter-x45": ("--season", "winter", "--session-seed", "7", "--rotate", "45"),
    "winter-x90": ("--season", "winter", "--session-seed", "8", "--rotate", "90"),
    "winter-130": ("--season", "winter", "--session-seed", "9", "--altitude", "130"),
    "spring": ("--season", "spring", "--session-seed", "4"),
    "autumn": ("--season", "autumn", "--session-seed", "5"),
    "summer-free": ("--season", "summer", "--session-seed", "3", "--flight", "freeform", "--flight-seed", "4"),
    "summer-80": ("--season", "summer", "--session-seed", "10", "--altitude", "80"),
    "summer-130": ("--season", "summer", "--session-seed", "11", "--altitude", "130"),
    "summer-150": ("--season", "summer", "--session-seed", "12", "--altitude", "150"),
}


@dataclass(frozen=True)
class Case:
    name: str
    a: str
    b: str
    kind: str  # "cross-season", "same-season" or "altitude"
    baselines: bool = True


# The baselines (ORB/SIFT+RANSAC over all 100 x 100 keyframe pairs, ~4 min of CPU per case) run where a bar or a
# comparison needs them: spring-autumn (average F1 >= SIFT's) and the reference summer-winter case.
CASES = (
    Case("summer-winter", "summer", "winter", "cross-season"),
    Case("summer-winter-x45", "summer", "winter-x45", "cross-season", baselines=False),
    Case("summer-winter-x90", "summer", "winter-x90", "cross-season", baselines=False),
    Case("summer-winter-130m", "summer", "winter-130", "cross-season", baselines=False),
    Case("spring-autumn", "spring", "autumn", "cross-season"),
    Case("summer-freeform", "summer", "summer-free", "same-season", baselines=False),
    Case("summer-80m", "summer", "summer-80", "altitude", baselines=False),
    Case("summer-130m", "summer", "summer-130", "altitude", baselines=False),
    Case("summer-150m", "summer", "summer-150", "altitude", baselines=False),
    Case("winter-130m", "winter", "winter-130", "altitude", baselines=False),
)
BAR_RECALL, BAR_ALTITUDE_F1, BAR_RATIO, BAR_ERROR_M = 0.8, 0.05, (0.97, 1.03), 5.0


def session_dir(work: Path, world: int, name: str) -> Path:
    """`sosmatch synth` of session `name` in world `world` unless it exists."""
    out = work / f"w{world}" / "sessions" / name
    if not (out / "session.json").exists():
        run_cli(["synth", "-q", "--world-seed", str(world), *SESSIONS[name], "--out", str(out)])
    return out


def map_dir(work: Path, world: int, name: str, tag: str, overrides: list[str], features_from: str | None) -> Path:
    """`sosmatch map --ekf` of a session with the parameters of `tag` unless the map exists. `features_from`:
    another tag whose per-keyframe cache is copied in first (reused where its segmentation parameters match)."""
    out = work / f"w{world}" / "maps" / tag / name
    if (out / "run.json").exists():
        return out
    synth = session_dir(work, world, name)
    if features_from:
        src = work / f"w{world}" / "maps" / features_from / name / ".partial" / "cache"
        if src.is_dir() and not (out / ".partial" / "cache").exists():
            shutil.copytree(src, out / ".partial" / "cache")
            # an unfinished `map` output holding that cache (resumed by the run below), not a foreign directory,
            # which `map` refuses to write into (database/outputs.py)
            from sosmatch.database.output_markers import MARKER, MARKER_FORMAT

            (out / MARKER).write_text(json.dumps({"format": MARKER_FORMAT, "command": "map", "identity": None,
                                                  "complete": False}) + "\n")
    sets = [x for kv in overrides for x in ("--set", kv)]
    run_cli(["map", "-q", "--poses", str(synth), "--ekf", "--out", str(out), "--no-progress", "--keep-cache", *sets])
    return out


def _params(overrides: list[str]):  # noqa: ANN202 (Params, imported lazily)
    from ...database.config_io import load_params, parse_override

    return load_params(None, dict(parse_override(t) for t in overrides))


def baseline_eval(work: Path, world: int, case: Case) -> dict | None:
    """ORB+RANSAC and SIFT+RANSAC of a case (they do not depend on the maps: computed once per world)."""
    if not case.baselines:
        return None
    out = work / f"w{world}" / "baselines" / case.name
    done = out / "evaluation.json"
    if not done.exists():
        from ...workflows.evaluate import run as evaluate

        a, b = session_dir(work, world, case.a), session_dir(work, world, case.b)
        evaluate(_params([]), a, b, out, methods=["orb_ransac", "sift_ransac"], case=case.name)
    return json.loads(done.read_text(encoding="utf-8"))


def ours_eval(work: Path, world: int, case: Case, maps_tag: str, map_overrides: list[str], eval_tag: str,
              eval_overrides: list[str], features_from: str | None, overlap_test: bool = True) -> dict:
    """Our evaluation of a case with the maps of `maps_tag` and the parameters `eval_overrides`."""
    out = work / f"w{world}" / "eval" / eval_tag / case.name
    done = out / "evaluation.json"
    if not done.exists():
        from ...workflows.evaluate import run as evaluate

        a, b = session_dir(work, world, case.a), session_dir(work, world, case.b)
        ma = map_dir(work, world, case.a, maps_tag, map_overrides, features_from)
        mb = map_dir(work, world, case.b, maps_tag, map_overrides, features_from)
        evaluate(_params(map_overrides + eval_overrides), a, b, out, map_a=ma, map_b=mb, methods=["sosmatch"],
                 case=case.name, repeats=1, overlap_test=overlap_test)
    return json.loads(done.read_text(encoding="utf-8"))


def case_row(ours: dict, baselines: dict | None) -> dict:
    """One table row: ours (paper metrics, operating point, truth) and the baselines' average F1."""
    row = dict(ours["rows"][0])
    truth = ours["methods"]["sosmatch"].get("landmark_truth") or {}
    row["landmarks"] = ours["methods"]["sosmatch"].get("landmarks")
    row["size_ratio_median"] = truth.get("size_ratio_median")
    row["within_gate"] = truth.get("within_size_gate")
    row["oracle_all"] = (truth.get("oracle") or {}).get("recall")
    windows = next((r for r in ours["rows"] if r["method"] == "SOS-Match, windows only"), None)
    if windows is not None:
        row["windows_average_f1"], row["windows_recall_at_p99"] = windows["average_f1"], windows["recall_at_p99"]
    ver = ours["methods"]["sosmatch"].get("verification") or {}
    row["verified_support"] = ver.get("support") if ver.get("accepted") else None
    if baselines is not None:
        for r in baselines["rows"]:
            row[r["method"]] = r["average_f1"]
    return row


def _f(value: object, fmt: str = ".3f") -> str:
    return "-" if value is None or (isinstance(value, float) and not np.isfinite(value)) else format(value, fmt)


def world_table(world: int, rows: list[dict], held_out: bool) -> str:
    head = (f"**World {world}**{' (held out: evaluated only, never tuned on)' if held_out else ''}\n\n"
            "| case | landmarks A / B | common / eligible | in size gate | size ratio B/A (median) | oracle recall "
            "(gated / all) | ours avg F1 | recall at P >= 0.99 | F1 / recall at theta_S | verified support "
            "| windows only: avg F1 / recall at P >= 0.99 | ORB F1 | SIFT F1 | worst accepted m | limited by |\n"
            "|---|---|---|---:|---:|---|---:|---:|---|---:|---|---:|---:|---:|---|")
    lines = [head]
    for r in rows:
        lm = r.get("landmarks") or ["-", "-"]
        lines.append(
            f"| {r['case']} | {lm[0]} / {lm[1]} | {r.get('common_landmarks', '-')} / {r.get('eligible_objects', '-')} "
            f"| {_f(r.get('within_gate'), '.2f')} | {_f(r.get('size_ratio_median'), '.3f')} "
            f"| {_f(r.get('oracle_recall'), '.2f')} / {_f(r.get('oracle_all'), '.2f')} | {_f(r['average_f1'])} "
            f"| {_f(r['recall_at_p99'])} | {_f(r.get('f1_at_operating'))} / {_f(r.get('recall_at_operating'))} "
            f"| {r.get('verified_support') or '-'} | {_f(r.get('windows_average_f1'))} / "
            f"{_f(r.get('windows_recall_at_p99'))} | {_f(r.get('ORB+RANSAC'))} | {_f(r.get('SIFT+RANSAC'))} "
            f"| {_f(r.get('accepted_max_error_m'), '.1f')} "
            f"| {r.get('limited_by', '-')} |")
    return "\n".join(lines) + "\n"


def kind_table(work: Path, worlds: list[int], case: Case, evaluations: list[dict]) -> str:
    """Per object kind, summed over the worlds: the eligible objects of a case, those the segmenter found in both
    maps (in > theta_n keyframes), the common landmarks, the segmented ones lost by tracking or triangulation, the
    median radius of the unsegmented ones and the median size ratio B / A of the common pairs."""
    from ...database.synth_session import load_synth_session

    agg: dict[str, dict] = {}
    for world, ev in zip(worlds, evaluations):
        truth = ev["methods"]["sosmatch"].get("landmark_truth") or {}
        if "segmented_both_by_kind" not in truth:
            return ""  # evaluated before the segmented objects were recorded
        kind_of = {int(o["id"]): str(o["kind"]) for o in load_synth_session(session_dir(work, world, case.a)).objects}
        for key, col in (("eligible_by_kind", "eligible"), ("segmented_both_by_kind", "segmented"),
                         ("common_by_kind", "common"), ("segmented_not_common_by_kind", "lost")):
            for kind, n in truth[key].items():
                agg.setdefault(kind, {}).setdefault(col, 0)
                agg[kind][col] += n
        for kind, r in zip(truth["unsegmented_kinds"], truth["unsegmented_radius_m"]):
            agg.setdefault(kind, {}).setdefault("radius", []).append(r)
        for oid, _, _, size_a, size_b in truth["common_pairs"]:
            agg.setdefault(kind_of[int(oid)], {}).setdefault("ratio", []).append(size_b / size_a)
    lines = [f"**{case.name}** ({case.a} vs {case.b}; worlds {', '.join(str(w) for w in worlds)} summed)", "",
             "| kind | eligible | segmented in both | common | segmented, not common | not segmented: median radius m "
             "| size ratio B/A of common (median) |", "|---|---:|---:|---:|---:|---:|---:|"]
    for kind, g in sorted(agg.items()):
        radius, ratio = g.get("radius", []), g.get("ratio", [])
        r_med = float(np.median(radius)) if radius else None
        lines.append(f"| {kind} | {g.get('eligible', 0)} | {g.get('segmented', 0)} | {g.get('common', 0)} "
                     f"| {g.get('lost', 0)} | {len(radius)} at {_f(r_med, '.1f')} "
                     f"| {_f(float(np.median(ratio)) if ratio else None)} |")
    return "\n".join(lines) + "\n"


def _ratio(rows: dict[str, dict], name: str) -> float | None:
    m = rows.get(name, {}).get("size_ratio_median")
    return m if m is not None and np.isfinite(m) else None


def altitude_ratio_notes(world: int, rows: dict[str, dict], ok: Callable[[bool], str]) -> list[str]:
    """The size-ratio bar (130 m against 100 m) on the same-season pairs, where only the altitude differs; the
    cross-season pair at 130 m as information, beside the same pair at equal altitude: leaf-off crowns and snowed
    roofs really look smaller in winter (BENCHMARKS, issue 16), which no size descriptor should undo, so the
    season's change is not charged to the altitude bar. Their quotient is the altitude's share across seasons."""
    notes = []
    for name in ("summer-130m", "winter-130m"):
        m = _ratio(rows, name)
        if m is not None:
            notes.append(f"w{world} {name}: median size ratio of common landmarks 130 m / 100 m {m:.3f} (bar "
                         f"{BAR_RATIO[0]}-{BAR_RATIO[1]}) - {ok(BAR_RATIO[0] <= m <= BAR_RATIO[1])}")
    cross, equal = _ratio(rows, "summer-winter-130m"), _ratio(rows, "summer-winter")
    if cross is not None:
        text = f"w{world} summer-winter-130m (information, season and altitude mixed): median size ratio {cross:.3f}"
        if equal is not None:
            text += f"; summer-winter at equal altitude {equal:.3f}, quotient {cross / equal:.3f}"
        notes.append(text)
    return notes


def check_bars(world: int, rows: dict[str, dict]) -> list[str]:
    """Issue 16's synthetic bars for one world, as sentences with the figures."""
    notes = []

    def ok(flag: bool) -> str:
        return "met" if flag else "MISSED"

    for name in ("summer-winter", "summer-winter-x45", "summer-winter-x90"):
        if name in rows:
            r = rows[name]["recall_at_p99"]
            notes.append(f"w{world} {name}: recall at P >= 0.99 {r:.3f} (bar {BAR_RECALL}) - {ok(r >= BAR_RECALL)}")
    if "spring-autumn" in rows and rows["spring-autumn"].get("SIFT+RANSAC") is not None:
        r = rows["spring-autumn"]
        notes.append(f"w{world} spring-autumn: average F1 {r['average_f1']:.3f} vs SIFT+RANSAC "
                     f"{r['SIFT+RANSAC']:.3f} - {ok(r['average_f1'] >= r['SIFT+RANSAC'])}")
    if "summer-winter" in rows and "summer-winter-130m" in rows:
        eq, alt = rows["summer-winter"], rows["summer-winter-130m"]
        for key, label in (("average_f1", "average F1"), ("recall_at_p99", "recall at P >= 0.99")):
            d = alt[key] - eq[key]
            notes.append(f"w{world} 130 m vs 100 m: {label} {alt[key]:.3f} vs {eq[key]:.3f} (difference {d:+.3f}, "
                         f"bar -{BAR_ALTITUDE_F1}) - {ok(d >= -BAR_ALTITUDE_F1)}")
    notes += altitude_ratio_notes(world, rows, ok)
    worst = [r.get("accepted_max_error_m") for r in rows.values() if r.get("accepted_max_error_m") is not None]
    if worst:
        notes.append(f"w{world}: worst accepted hypothesis {max(worst):.1f} m off the truth (bar {BAR_ERROR_M} m) - "
                     f"{ok(max(worst) <= BAR_ERROR_M)}")
    return notes


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="sessions, maps, evaluations (outside the repo)")
    parser.add_argument("--worlds", default="11,5,23,42", help="world seeds")
    parser.add_argument("--held-out", default="", help="world seeds never tuned on (marked in the tables)")
    parser.add_argument("--cases", default=",".join(c.name for c in CASES))
    parser.add_argument("--maps-tag", default="default", help="name of the mapping configuration (a directory)")
    parser.add_argument("--map-set", action="append", default=[], metavar="K=V", help="mapping parameter")
    parser.add_argument("--eval-tag", default=None, help="name of the evaluation configuration (default: maps tag)")
    parser.add_argument("--eval-set", action="append", default=[], metavar="K=V", help="association parameter")
    parser.add_argument("--features-from", default=None, help="maps tag whose per-keyframe caches to reuse")
    parser.add_argument("--no-baselines", action="store_true", help="skip ORB/SIFT (their column stays empty)")
    parser.add_argument("--no-overlap-test", action="store_true",
                        help="claims from every observer pair (the evaluation's earlier rule)")
    parser.add_argument("--write", action="store_true", help="write the tables into BENCHMARKS.md")
    parser.add_argument("--title", default="Seasons, crossing flights and altitude on several worlds (issue 16)")
    parser.add_argument("--section", default="seasons", help="name of the marked BENCHMARKS.md section to write")
    parser.add_argument("--note", action="append", default=[], help="a paragraph after the title (repeatable)")
    parser.add_argument("--by-kind", default="", metavar="CASES",
                        help="cases to tabulate per object kind (segmented, common, lost, size ratio)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    os.environ.setdefault("SOSMATCH_CACHE_DIR", str(args.work / "cache"))
    machine = machine_summary()
    print(machine)
    worlds = [int(w) for w in args.worlds.split(",") if w]
    held = {int(w) for w in args.held_out.split(",") if w}
    wanted = [c for c in CASES if c.name in args.cases.split(",")]
    eval_tag = args.eval_tag or args.maps_tag
    tables, bars = [], []
    evaluations: dict[str, list[dict]] = {}
    for world in worlds:
        rows: dict[str, dict] = {}
        for case in wanted:
            ours = ours_eval(args.work, world, case, args.maps_tag, args.map_set, eval_tag, args.eval_set,
                             args.features_from, not args.no_overlap_test)
            evaluations.setdefault(case.name, []).append(ours)
            base = None if args.no_baselines else baseline_eval(args.work, world, case)
            rows[case.name] = case_row(ours, base)
            print(f"w{world} {case.name}: " + json.dumps({k: v for k, v in rows[case.name].items()
                                                           if k not in ("case", "method")}, default=str))
        tables.append(world_table(world, list(rows.values()), world in held))
        bars += check_bars(world, rows)
    by_kind = [c for c in wanted if c.name in args.by_kind.split(",")]
    kinds = [t for t in (kind_table(args.work, worlds, c, evaluations[c.name]) for c in by_kind) if t]
    if kinds:
        tables += ["Per object kind (eligible: present in both sessions and seen in > theta_n keyframes of each; "
                   "segmented: under a segment centroid in > theta_n keyframes of both maps):", "", *kinds]
    end_load = machine_summary().rsplit("load ", 1)[-1]
    raw = list(argv if argv is not None else __import__("sys").argv[1:])
    shown = " ".join(a for i, a in enumerate(raw) if a != "--note" and (i == 0 or raw[i - 1] != "--note"))
    notes = [x for n in args.note for x in (n, "")]
    section = "\n".join([MARKER.format(args.section), f"### {args.title}", "",
                         f"Command: `python -m sosmatch.tools.benchmarks.bench_seasons {shown}`  ",
                         f"Machine: {machine} (load at the end: {end_load})", "", *notes, *tables, "Bars:",
                         *[f"- {b}" for b in bars], "", END_MARKER.format(args.section), ""])
    print(section)
    if args.write:
        from ...database.atomic import write_text_atomic
        from .bench_evaluate import replace_section

        bench = Path("BENCHMARKS.md")
        write_text_atomic(bench, replace_section(bench.read_text(encoding="utf-8"), section,
                                                  MARKER.format(args.section), END_MARKER.format(args.section)))


if __name__ == "__main__":
    main()
