"""Benchmark `sosmatch synth`: wall and CPU time of 100-frame 640x480 sessions (the issue's bar: < 60 s on 2 cores).

    python -m sosmatch.tools.benchmarks.bench_synth [--frames 100] [--repeats 3] [--workers 2]

Each run renders a session in a fresh process, as separate `sosmatch synth` calls do, with a private world
cache (tools/synth/world_cache.py): per season one "cold" run on an empty cache (the world and the season's
albedo are built and written to the cache: the first call for a world seed) and `--repeats` "warm" runs that
load them (every later call). Prints a markdown table (median of the warm repeats) and the machine line. CPU
time (user + system of the process) is printed too: on a shared machine the wall time depends on the load,
the CPU time much less.
"""

from __future__ import annotations

import argparse
import json
import os
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


def bench_once(settings: dict, workers: int, cache_dir: str | Path) -> dict:
    """Render one session in a fresh Python process with world cache `cache_dir`; returns its summary with
    wall and CPU seconds."""
    env = {**os.environ, "SOSMATCH_CACHE_DIR": str(cache_dir)}
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(settings), str(Path(tmp) / "S"),
                              str(workers)], capture_output=True, text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seasons", default="summer,winter")
    args = parser.parse_args(argv)
    print(f"machine: {machine_summary()}")
    print("| session | world cache | frames | world s | scene + light s | render s | total wall s | CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for season in args.seasons.split(","):
        settings = {"world_seed": 7, "season": season, "frames": args.frames, "session_seed": 1}
        with tempfile.TemporaryDirectory() as cache:
            cold = [bench_once(settings, args.workers, cache)]
            warm = [bench_once(settings, args.workers, cache) for _ in range(args.repeats)]
        for label, runs in (("cold (1 run)", cold), (f"warm (median of {args.repeats})", warm)):

            def med(key: str, runs: list[dict] = runs) -> float:
                return statistics.median(r[key] for r in runs)

            print(f"| {season}, lawnmower, 640x480, {args.workers} threads | {label} | {args.frames} "
                  f"| {med('seconds_world'):.1f} | {med('seconds_scene'):.1f} | {med('seconds_render'):.1f} "
                  f"| {med('wall'):.1f} | {med('cpu'):.1f} |", flush=True)
    print(f"machine after: {machine_summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
