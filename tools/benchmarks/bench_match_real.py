"""Sections of the association benchmark (`bench_match.py`) on mapped sessions: the evaluation suite (our match
against ORB+RANSAC, and the accuracy that must not fall) and the real NAIP pair with its negative controls.

Both build what they need with the other benchmarks' functions and reuse it when it exists (an interrupted run
resumes): the evaluation cases with `bench_evaluate.run_case` (sessions, maps and evaluations under --eval-work),
the NAIP sessions and maps with `real_naip.naip_sessions` (under --naip-work; the orthophotos of --naip).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from .match_report import bar, report, timed_match

EVAL_RATIO_BAR = 46.0  # ORB+RANSAC time / ours, every case (issue 15)
# The evaluation suite's accuracy before issue 15 (BENCHMARKS.md, run of 2026-11-22, and the same figures on
# 2026-12-01 with the maps used here): average F1 and recall at P >= 0.99 per case, which must not fall.
EVAL_BEFORE = {"summer-20min": (0.999, 1.000), "viewpoint": (0.996, 0.997), "spring-autumn": (0.817, 0.744),
               "summer-winter": (0.843, 0.782)}
NAIP_LIMIT_S, NAIP_MEMORY_MB = 5.0, 500.0
NAIP_WRONG_M, NAIP_WRONG_DEG = 15.0, 2.0  # an answer this far from the identity (the truth) is wrong


def bench_evaluation(work: Path, repeats: int, baseline_work: Path | None = None) -> list[dict]:
    """The evaluation suite (`bench_evaluate`): ours and ORB+RANSAC, side by side in one run per case, or with
    `baseline_work` ORB+RANSAC read from that suite's finished evaluations of the same sessions (its time depends
    on the images only: a map change needs no new baseline run)."""
    from .bench_evaluate import CASES, run_case

    source = f"ORB+RANSAC from {baseline_work}" if baseline_work else "side by side"
    print(f"## Evaluation suite (`bench_evaluate`, work {work}; {source}): our match against ORB+RANSAC, accuracy")
    print("| case | ours s (match's answer, median) | ORB+RANSAC s | ratio (bar 46x) | average F1 (before) | "
          "recall at P >= 0.99 (before) |")
    print("|---|---|---|---|---|---|")
    rows = []
    for case in CASES:
        if baseline_work is None:
            ev = run_case(case, work, ["sosmatch", "orb_ransac"], repeats, reuse=True)
            rows_b = ev["rows"]
        else:
            ev = run_case(case, work, ["sosmatch"], repeats, reuse=True)
            rows_b = run_case(case, baseline_work, ["sosmatch", "orb_ransac"], repeats, reuse=True)["rows"]
        ours = {r["method"]: r for r in ev["rows"]}["SOS-Match (ours)"]
        orb = {r["method"]: r for r in rows_b}.get("ORB+RANSAC")
        f1_0, rec_0 = EVAL_BEFORE[case.name]
        f1, rec = ours["average_f1"], ours["recall_at_p99"]
        ratio = orb["search_s"] / max(ours["search_s"], 1e-9) if orb else float("nan")
        ok = bar(f"evaluation {case.name}: >= {EVAL_RATIO_BAR:.0f}x faster than ORB+RANSAC",
                 f"{ratio:.0f}x ({ours['search_s']:.3g} s vs {orb['search_s']:.3g} s)" if orb else "no ORB run",
                 bool(orb) and ratio >= EVAL_RATIO_BAR)
        acc = bar(f"evaluation {case.name}: average F1 and recall at P >= 0.99 not below before",
                  f"F1 {f1:.3f} (before {f1_0:.3f}), recall {rec:.3f} (before {rec_0:.3f})",
                  round(f1, 3) >= f1_0 and round(rec, 3) >= rec_0)
        print(f"| {case.name} | {ours['search_s']:.3g} | {orb['search_s'] if orb else float('nan'):.3g} | "
              f"**{ratio:.0f}x** ({ok}) | {f1:.3f} ({f1_0:.3f}; {acc}) | {rec:.3f} ({rec_0:.3f}) |")
        rows.append({"case": case.name, "ours_s": ours["search_s"], "orb_s": orb["search_s"] if orb else None,
                     "ratio": ratio, "average_f1": f1, "recall_at_p99": rec})
    return rows


def _identity_error(ans: object, centre: np.ndarray) -> tuple[float, float]:
    """Displacement (m) of `centre` by the answer's transform and its rotation angle (deg): the truth of two
    georeferenced orthophotos of one tile is the identity."""
    from ...plugin.association.rigid import rotation_angle_deg

    t = ans.transform
    return float(np.linalg.norm(t.apply(centre[None])[0] - centre)), rotation_angle_deg(t.rotation, np.eye(3))


def naip_maps(naip: Path, work: Path) -> dict[str, tuple[Path, Path]]:
    """The mapped NAIP sessions: both dates, and the negative controls (opposite halves of the two dates, the two
    halves of one date, one date against the other mirrored), rendered and mapped as `bench_real naip --hfov 90
    --frame-spacing 75` does (BENCHMARKS.md, "NAIP 2009 vs 2015 matched")."""
    from .real_naip import half_orthophoto, mirrored_orthophoto, naip_sessions

    extra = ["--hfov", "90", "--frame-spacing", "75"]
    maps: list[str] = []
    (_, a), (_, b) = naip_sessions(naip, work, extra, maps)[0]
    old, new = sorted(naip.glob("*.tif"))
    halves = {(t, side): half_orthophoto(t, side, work / "control" / f"{t.stem}{side}.tif")
              for t in (old, new) for side in ("west", "east")}
    out = {"2015 into 2009": (a, b), "2009 into 2015": (b, a)}
    for x, y in (((old, "west"), (new, "east")), ((old, "east"), (new, "west")), ((old, "west"), (old, "east"))):
        (_, ma), (_, mb) = naip_sessions(naip, work, extra, maps, tifs=[halves[x], halves[y]])[0]
        out[f"control: {x[1]} {x[0].stem[-8:-4]} vs {y[1]} {y[0].stem[-8:-4]}"] = (ma, mb)
    mirror = mirrored_orthophoto(new, work / "control" / f"{new.stem}mirrored.tif")
    (_, ma), (_, mb) = naip_sessions(naip, work, extra, maps, tifs=[old, mirror])[0]
    out["control: 2009 vs 2015 mirrored"] = (ma, mb)
    return out


def bench_naip(naip: Path, work: Path, repeats: int, memory: bool) -> list[dict]:
    """The real NAIP pair (aerial preset; georeferenced in one EPSG, so the position prior applies), both orders,
    and the negative controls, which must accept nothing."""
    from ...database.landmark_map import read_landmark_map
    from ...plugin.params import preset_params

    if not naip.is_dir() or len(list(naip.glob("*.tif"))) != 2:
        print(f"## NAIP: {naip} holds no two orthophotos: skipped")
        return []
    params = preset_params("aerial")
    print(f"## NAIP 2009 / 2015 (real orthophotos of one tile, rendered and mapped; work {work}), matched with the "
          "aerial preset; the truth is the identity; the controls must accept nothing")
    rows = []
    for label, (map_a, map_b) in naip_maps(naip, work).items():
        la = read_landmark_map(map_a / "landmarks.sosmap")
        lb = read_landmark_map(map_b / "landmarks.sosmap")
        control = label.startswith("control")
        # with the prior (both maps are in one EPSG), then without it (as for maps that are not georeferenced):
        # the controls must be refused by the search itself, not only by the prior
        for common in (la.epsg == lb.epsg != 0, False):
            how = "prior" if common else "no prior"
            ans, cpu, wall = timed_match(la.positions, la.sizes, lb.positions, lb.sizes, params,
                                         repeats if common else 1, common)
            row = report(f"NAIP {label}, {len(la)} x {len(lb)}, {how}", ans, cpu, wall, None, None,
                         None if control or not common else NAIP_LIMIT_S)
            if ans.accepted:
                row["error_m"], row["error_deg"] = _identity_error(ans, lb.positions.mean(axis=0))
            wrong = ans.accepted and (control or row["error_m"] > NAIP_WRONG_M or row["error_deg"] > NAIP_WRONG_DEG)
            if control:
                bar(f"negative control NAIP {label.removeprefix('control: ')}, {how}: nothing accepted",
                    "accepted (wrong)" if ans.accepted else "nothing accepted", not ans.accepted)
            else:
                bar(f"NAIP {label}, {how}: accepted, within {NAIP_WRONG_M:g} m and {NAIP_WRONG_DEG:g} deg of the "
                    "truth", f"{len(ans.associations)} associations, {row['error_m']:.1f} m, {row['error_deg']:.2f} "
                    "deg" if ans.accepted else "no match", ans.accepted and not wrong)
            print(f"  prior {ans.prior}; " + (f"error {row['error_m']:.1f} m, {row['error_deg']:.2f} deg "
                                              f"({'WRONG' if wrong else 'right'})" if ans.accepted else "no match"))
            if memory and common and not control:
                row["peak_mb"] = naip_peak_mb(map_a, map_b)
                ok = bar(f"NAIP {label}: <= {NAIP_MEMORY_MB:.0f} MB peak", f"{row['peak_mb']:.0f} MB",
                         row["peak_mb"] <= NAIP_MEMORY_MB)
                print(f"  peak memory (fresh process, imports included): {row['peak_mb']:.0f} MB - bar {ok}")
            rows.append({"label": label, "prior": common, **row})
    return rows


def naip_peak_mb(map_a: Path, map_b: Path) -> float:
    """Peak memory (MB, `peak_rss_mb`) of a fresh interpreter that reads both maps and runs one match (aerial
    preset)."""
    code = ("import json; from sosmatch.database.landmark_map import read_landmark_map as r; "
            "from sosmatch.tools.benchmarks.match_report import peak_rss_mb; "
            "from sosmatch.plugin.match_answer import match_maps; from sosmatch.plugin.params import preset_params; "
            f"a = r({str(map_a / 'landmarks.sosmap')!r}); b = r({str(map_b / 'landmarks.sosmap')!r}); "
            "match_maps(a.positions, a.sizes, b.positions, b.sizes, preset_params('aerial'), "
            "common_frame=a.epsg == b.epsg != 0); "
            "print(json.dumps({'peak_mb': peak_rss_mb()}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["peak_mb"])
