"""Timing and reporting shared by the sections of the association benchmark (`bench_match.py`): one match timed
in CPU and wall seconds, its answer scored against the truth, and every bar of issue 15 collected with its figure
(printed together at the end of the run)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from ...plugin.association.rigid import rotation_angle_deg
from ...plugin.match_answer import match_maps
from ...plugin.params import Params

BARS: list[tuple[str, str, bool]] = []  # (bar, measured figure, met) of this run, in the order measured


def peak_rss_mb() -> float:
    """Peak resident memory of this process (MB): the VmHWM of /proc/self/status where there is one. Not
    ru_maxrss: Linux keeps that across execve, so a child spawned by a large parent reports the parent's size."""
    try:
        for line in open("/proc/self/status", encoding="ascii"):
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bar(name: str, figure: str, met: bool) -> str:
    """Record a bar of issue 15 with its figure; returns "met" / "MISSED" for the line that shows it."""
    BARS.append((name, figure, bool(met)))
    return "met" if met else "MISSED"


def print_bars() -> None:
    """Every bar measured in this run, with its figure."""
    if not BARS:
        return
    print("## Bars of issue 15 measured in this run")
    print("| bar | measured | |")
    print("|---|---|---|")
    for name, figure, met in BARS:
        print(f"| {name} | {figure} | {'met' if met else '**MISSED**'} |")


def timed(run: Callable[..., object], pa: np.ndarray, ha: np.ndarray | None, pb: np.ndarray, hb: np.ndarray | None,
          repeats: int) -> tuple:
    """`run(pa, ha, pb, hb)` timed after a small warm-up call that compiles the kernels: (its answer, median CPU s,
    median wall s)."""
    n = min(60, len(pa), len(pb))
    run(pa[:n], None if ha is None else ha[:n], pb[:n], None if hb is None else hb[:n])  # compile
    cpu, wall, ans = [], [], None
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        ans = run(pa, ha, pb, hb)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return ans, statistics.median(cpu), statistics.median(wall)


def timed_match(pa: np.ndarray, ha: np.ndarray | None, pb: np.ndarray, hb: np.ndarray | None, params: Params,
                 repeats: int, common_frame: bool = False) -> tuple:
    """The match's answer (search + verification), timed: (answer, median CPU s, median wall s)."""
    return timed(lambda a, sa, b, sb: match_maps(a, sa, b, sb, params, common_frame=common_frame),
                 pa, ha, pb, hb, repeats)


def quality(ans: object, truth: set | None, rotation: np.ndarray | None) -> str:
    if not ans.accepted:
        return "no match"
    found = set(map(tuple, ans.associations.tolist()))
    out = f"{len(found)} associations"
    if truth is not None:
        out += f" ({len(found & truth)} true, {len(found - truth)} false)"
    if rotation is not None:
        out += f", rotation error {rotation_angle_deg(ans.transform.rotation, rotation):.3f} deg"
    return out


def report(name: str, ans: object, cpu: float, wall: float, truth: set | None, rotation: np.ndarray | None,
           limit_s: float | None = None) -> dict:
    """Print one match's figures; with `limit_s`, record its time bar (met only by an accepted answer in time)."""
    s = ans.search
    t = s.timings
    verdict = ""
    if limit_s is not None:
        ok = bar(f"{name}: <= {limit_s:g} s CPU", f"{cpu:.3f} s CPU ({quality(ans, truth, rotation)})",
                 cpu <= limit_s and ans.accepted)
        verdict = f" - bar {limit_s:g} s {ok}"
    print(f"{name}: **{cpu:.3f} s CPU** (wall {wall:.3f} s; search {ans.timings['search_s']:.3f} s + verification "
          f"{ans.timings['verify_s']:.3f} s wall){verdict}; window pairs {s.num_window_pairs}, solved "
          f"{len(s.hypotheses)}, accepted {len(s.accepted)}, consistent pairs {int(t.get('consistent_pairs', 0))}, "
          f"incidences {int(t.get('incidences', 0))}; answer ({ans.source}): {quality(ans, truth, rotation)}")
    return {"case": name, "cpu_s": cpu, "wall_s": wall, "search_wall_s": ans.timings["search_s"],
            "verify_wall_s": ans.timings["verify_s"], "window_pairs": s.num_window_pairs,
            "solved": len(s.hypotheses), "accepted": bool(ans.accepted), "associations": len(ans.associations)}
