"""Benchmark `sosmatch synth`: wall and CPU time of 100-frame 640x480 sessions (the issue's bar: < 60 s on 2 cores).

    python -m sosmatch.tools.benchmarks.bench_synth [--frames 100] [--repeats 3] [--workers 2]

Each repeat renders a fresh process's session (world built from scratch: no cache carries over between
repeats, as for separate `sosmatch synth` calls). Prints a markdown table (median of the repeats) and the
machine line. CPU time (user + system of the process) is printed too: on a shared machine the wall time
depends on the load, the CPU time much less.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from .machine import machine_summary

_CHILD = """
import json, resource, sys, time
from sosmatch.workflows.synth import SynthConfig, run
cfg = SynthConfig(**json.loads(sys.argv[1]))
t = time.perf_counter()
summary = run(sys.argv[2], cfg, workers=int(sys.argv[3]))
ru = resource.getrusage(resource.RUSAGE_SELF)
summary["wall"] = time.perf_counter() - t
summary["cpu"] = ru.ru_utime + ru.ru_stime
print(json.dumps(summary))
"""


def bench_once(settings: dict, workers: int) -> dict:
    """Render one session in a fresh Python process; returns its summary with wall and CPU seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(settings), str(Path(tmp) / "S"),
                              str(workers)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seasons", default="summer,winter")
    args = parser.parse_args(argv)
    print(f"machine: {machine_summary()}")
    print("| session | frames | world build s | scene + light s | render s | total wall s | CPU s |")
    print("|---|---|---|---|---|---|---|")
    for season in args.seasons.split(","):
        settings = {"world_seed": 7, "season": season, "frames": args.frames, "session_seed": 1}
        runs = [bench_once(settings, args.workers) for _ in range(args.repeats)]

        def med(key: str, runs: list[dict] = runs) -> float:
            return statistics.median(r[key] for r in runs)

        print(f"| {season}, lawnmower, 640x480, {args.workers} threads | {args.frames} | {med('seconds_world'):.1f} "
              f"| {med('seconds_scene'):.1f} | {med('seconds_render'):.1f} | {med('wall'):.1f} | {med('cpu'):.1f} |",
              flush=True)
    print(f"machine after: {machine_summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
