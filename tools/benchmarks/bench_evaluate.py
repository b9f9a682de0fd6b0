"""The evaluation suite: the paper's Table I and precision-recall figure on standard synthetic cases.

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_evaluate [--work bench_work] [--cases summer-20min,...]
        [--no-write] [--methods sosmatch,orb_ransac,sift_ransac] [--real]

Per case (fixed seeds, so every run builds the same sessions): `sosmatch synth` both sessions, `sosmatch map`
both (on the EKF-noisy poses, as a vehicle would), then `workflows.evaluate.run` (ground truth from the exact
poses and the terrain, our windowed search, ORB+RANSAC and SIFT+RANSAC). Finished steps are reused when their
outputs exist (a session with session.json, a map with run.json), so an interrupted run resumes. The results go
into BENCHMARKS.md between `<!-- section:evaluate -->` and `<!-- end:evaluate -->`, with the PR plots and map
overlays copied to docs/img/eval_<case>_{pr,overlay}.png, and the bars of issue 6 checked with the numbers.

Real data hook: when ../shared/data (or --data) exists and --real is given, the cases returned by
`sosmatch.tools.benchmarks.bench_real.evaluation_cases(data_root, work_dir)` are evaluated too (if that function
exists; it is the real-data issue's to define). Each case is a dict with keys case, session_a, session_b,
map_a, map_b and optionally dem, ground_height.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

from .machine import machine_summary

log = logging.getLogger(__name__)

WORLD_SEED = 11
MARKER, END_MARKER = "<!-- section:evaluate -->", "<!-- end:evaluate -->"
CROSS_SEASON = ("spring-autumn", "summer-winter")


@dataclass(frozen=True)
class Case:
    """A session pair: `sosmatch synth` arguments of A and B (the world seed is added by the suite)."""

    name: str
    title: str
    synth_a: tuple[str, ...]
    synth_b: tuple[str, ...]


# Session arguments (default flight: 100 frames, a lawnmower of 160 m lines 30 m apart at 100 m, a frame every
# 7 m, so every frame is a 2 m keyframe). A and B of one case share the world (WORLD_SEED); the session seed
# differs, so camera noise, changed objects and EKF drift differ as on two real flights. 20 minutes later near
# noon moves the summer sun by ~10 degrees of azimuth and ~1 degree of elevation.
_SUMMER = ("--season", "summer", "--session-seed", "1")
CASES = (
    Case("summer-20min", "Summer vs summer 20 min later (shadows moved)", _SUMMER,
         ("--season", "summer", "--session-seed", "2", "--sun-azimuth", "160", "--sun-elevation", "56")),
    Case("viewpoint", "Summer vs summer, shifted and reversed path (viewpoint change)", _SUMMER,
         ("--season", "summer", "--session-seed", "3", "--shift", "12,12", "--reverse")),
    Case("spring-autumn", "Spring vs autumn", ("--season", "spring", "--session-seed", "4"),
         ("--season", "autumn", "--session-seed", "5")),
    Case("summer-winter", "Summer vs winter", _SUMMER, ("--season", "winter", "--session-seed", "6")),
)


def run_cli(args: list[str]) -> None:
    """`sosmatch ARGS` in this process; a non-zero exit is an error (a benchmark step that failed)."""
    from ..cli import main

    log.info("sosmatch %s", " ".join(args))
    code = main(args)
    logging.getLogger("sosmatch").setLevel(logging.INFO)  # the CLI's -q lowered it for the whole process
    if code != 0:
        raise RuntimeError(f"`sosmatch {' '.join(args)}` failed with exit code {code}")


def _slug(args: tuple[str, ...]) -> str:
    """A directory name for a session's arguments: equal arguments, equal session."""
    return "_".join(a.lstrip("-").replace(",", "x") for a in args)


def synth_session(args: tuple[str, ...], out: Path) -> Path:
    """`sosmatch synth` unless the session already exists."""
    if not (out / "session.json").exists():
        run_cli(["synth", "-q", "--world-seed", str(WORLD_SEED), *args, "--out", str(out)])
    return out


def map_session(synth_dir: Path, out: Path, extra: tuple[str, ...] = ()) -> Path:
    """`sosmatch map` of a synthetic session on its EKF poses unless the map already exists."""
    if not (out / "run.json").exists():
        run_cli(["map", "-q", "--poses", str(synth_dir), "--ekf", "--out", str(out), "--no-progress", *extra])
    return out


def _own_search(methods: list[str], repeats: int) -> int | None:
    """`repeats` where evaluate runs a search of its own (the sosmatch method), else None: evaluate refuses timing
    repeats of a search that does not run."""
    return repeats if "sosmatch" in methods else None


def run_case(case: Case, work: Path, methods: list[str], repeats: int = 3, reuse: bool = False) -> dict:
    """Build, map and evaluate one case; returns the evaluation dict (with `reuse`, a finished one is read)."""
    from ...plugin.params import Params
    from ...workflows.evaluate import run as evaluate

    done = work / case.name / "eval" / "evaluation.json"
    if reuse and done.exists():
        return json.loads(done.read_text(encoding="utf-8"))

    # Sessions (and their maps) are shared between cases with the same arguments (the summer reference).
    a = synth_session(case.synth_a, work / "sessions" / _slug(case.synth_a))
    b = synth_session(case.synth_b, work / "sessions" / _slug(case.synth_b))
    map_a = map_b = None
    if "sosmatch" in methods:
        map_a = map_session(a, work / "maps" / _slug(case.synth_a))
        map_b = map_session(b, work / "maps" / _slug(case.synth_b))
    return evaluate(Params(), a, b, work / case.name / "eval", map_a=map_a, map_b=map_b, methods=methods,
                    case=case.name, repeats=_own_search(methods, repeats))


def real_cases(data_root: Path, work: Path) -> list[dict]:
    """Real-data cases from the real-data issue's hook (empty if it defines none)."""
    try:
        from . import bench_real
    except ImportError:
        return []
    hook = getattr(bench_real, "evaluation_cases", None)
    if hook is None:
        log.warning("bench_real.evaluation_cases is not defined yet: no real-data cases")
        return []
    return list(hook(data_root, work))


def check_bars(evaluation: dict) -> list[str]:
    """The bars for one case (issue 6: search 10x, map 100x, cross-season F1; issue 15: search 46x), as sentences
    with the numbers (empty when a method is missing)."""
    rows = {r["method"]: r for r in evaluation["rows"]}
    ours, orb, sift = rows.get("SOS-Match (ours)"), rows.get("ORB+RANSAC"), rows.get("SIFT+RANSAC")
    notes = []
    if ours is None or orb is None:
        return notes
    case = evaluation["case"]
    speed = orb["search_s"] / max(ours["search_s"], 1e-9)
    size = orb["map_mb"] / max(ours["map_mb"], 1e-12)
    notes.append(f"{case}: search {speed:.0f}x shorter than ORB+RANSAC ({ours['search_s']:.3g} s vs "
                 f"{orb['search_s']:.3g} s) - bar 10x {'met' if speed >= 10 else 'MISSED'}, bar 46x (issue 15) "
                 f"{'met' if speed >= 46 else 'MISSED'}; map {size:.0f}x smaller "
                 f"({ours['map_mb'] * 1e3:.3g} kB vs {orb['map_mb']:.3g} MB) - bar 100x "
                 f"{'met' if size >= 100 else 'MISSED'}.")
    if case in CROSS_SEASON:
        best = max(r["average_f1"] for r in (orb, sift) if r is not None)
        ok = ours["average_f1"] >= best
        notes.append(f"{case}: average F1 {ours['average_f1']:.3f} vs best baseline {best:.3f} - bar "
                     f"{'met' if ok else 'MISSED'}.")
    return notes


def _runs(evaluations: list[dict]) -> str:
    counts = sorted({len(e["methods"]["sosmatch"].get("search_seconds_runs") or [])
                     for e in evaluations if "sosmatch" in e.get("methods", {})})
    return "/".join(str(c) for c in counts) or "0"


def section_text(evaluations: list[dict], machine: str, command: str, notes: list[str] | None = None,
                 img_prefix: str = "docs/img/eval_") -> str:
    """The BENCHMARKS.md section: machine, command, one table, the bars, the figures."""
    from ...workflows.evaluate import format_table

    rows = [r for e in evaluations for r in e["rows"]]
    lines = [MARKER, "## Evaluation: Table I and precision-recall (issue 6)", "",
             f"Command: `{command}`  ", f"Machine: {machine}", "",
             "Protocol: README section *Evaluate*. Search time: ours = median of "
             f"{_runs(evaluations)} runs of the match's answer (windowed search + verification on the full maps, "
             "one process); baselines = matching + RANSAC of all keyframe pairs (one thread per core), feature "
             "extraction excluded. Map size: mean of the two sessions.", "",
             format_table(rows)]
    for note in notes or []:
        lines += [note, ""]
    for e in evaluations:
        p = e["protocol"]
        lines.append(f"- {e['case']}: {e['keyframes'][0]} x {e['keyframes'][1]} keyframes, {p['positive_pairs']} "
                     f"pairs with IoU > {p['tp_iou']}, {p['negative_pairs']} with IoU < {p['fp_iou']}.")
    notes = [n for e in evaluations for n in check_bars(e)]
    if notes:
        lines += ["", "Bars:"] + [f"- {n}" for n in notes]
    lines.append("")
    for e in evaluations:
        lines.append(f"![{e['case']} precision-recall]({img_prefix}{e['case']}_pr.png) "
                     f"![{e['case']} overlay]({img_prefix}{e['case']}_overlay.png)")
    lines += ["", END_MARKER, ""]
    return "\n".join(lines)


def replace_section(text: str, section: str, marker: str = MARKER, end_marker: str = END_MARKER) -> str:
    """Put `section` in place of `marker` (or of a previous section between the two markers; default: the
    evaluate section of BENCHMARKS.md), or append it when the text has no such marker."""
    if marker not in text:
        return text.rstrip("\n") + "\n\n" + section
    start = text.index(marker)
    end = text.find(end_marker, start)
    end = start + len(marker) + 1 if end < 0 else end + len(end_marker) + 1
    return text[:start] + section + text[end:]


def main(argv: list[str] | None = None) -> None:
    from ...database.atomic import write_text_atomic

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("bench_work"), help="sessions, maps and evaluations")
    parser.add_argument("--cases", default=",".join(c.name for c in CASES))
    parser.add_argument("--methods", default="sosmatch,orb_ransac,sift_ransac")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats of our search (median)")
    parser.add_argument("--real", action="store_true", help="also run the real-data cases (needs --data)")
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--reuse", action="store_true", help="read finished evaluations instead of re-running them")
    parser.add_argument("--note", action="append", default=[], help="a paragraph for the section (repeatable)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md and docs/img alone")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    machine = machine_summary()
    print(machine)
    methods = [m for m in args.methods.split(",") if m]
    wanted = args.cases.split(",")
    evaluations = []
    for case in CASES:
        if case.name in wanted:
            evaluations.append(run_case(case, args.work, methods, args.repeats, args.reuse))
            print(json.dumps(evaluations[-1]["rows"], indent=1))
    if args.real and args.data.exists():
        from ...plugin.params import Params
        from ...workflows.evaluate import run as evaluate

        for rc in real_cases(args.data, args.work / "real"):
            evaluations.append(evaluate(Params(), rc["session_a"], rc["session_b"], args.work / "real" / rc["case"],
                                        map_a=rc.get("map_a"), map_b=rc.get("map_b"), methods=methods,
                                        case=rc["case"], dem=rc.get("dem"), ground_height=rc.get("ground_height", 0.0),
                                        repeats=_own_search(methods, args.repeats)))
    import sys

    shown, skip = [], False
    for a in sys.argv[1:] if argv is None else argv:  # the notes are printed as paragraphs, not in the command
        if skip or a == "--note":
            skip = not skip
            continue
        shown.append(a)
    command = "python -m sosmatch.tools.benchmarks.bench_evaluate " + " ".join(shown)
    end_load = machine_summary().rsplit("load ", 1)[-1]
    section = section_text(evaluations, f"{machine} (load at the end: {end_load})", command.strip(), args.note)
    print(section)
    if args.no_write:
        return
    img = Path("docs/img")
    img.mkdir(parents=True, exist_ok=True)
    for e in evaluations:
        out = Path(e["out_dir"])
        for kind in ("pr", "overlay"):
            if (out / f"{kind}.png").exists():
                shutil.copyfile(out / f"{kind}.png", img / f"eval_{e['case']}_{kind}.png")
    bench = Path("BENCHMARKS.md")
    write_text_atomic(bench, replace_section(bench.read_text(encoding="utf-8"), section))


if __name__ == "__main__":
    main()
