"""What the safety checks of issue 14 cost and what they prevent (BENCHMARKS.md, "Robustness").

    python -m sosmatch.tools.benchmarks.bench_safety [--objects 3000]

1. A points3D.bin of random bytes: pycolmap alone, in a child process limited to 4 GiB of address space, against
   `colmap_model.load_reconstruction` (the structural walk first): outcome, CPU seconds, peak RSS.
2. `colmap_binary.check_binary_model` on a valid toy model of --objects points: CPU time per MB of model.
3. `outputs.open_output_dir` + `finish` (marker, lock, checks): CPU time per call.
4. A parent holding a batch executor's 2 busy workers is killed with SIGKILL: how long until every process it
   started (the workers and the multiprocessing resource tracker) is gone.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from ...plugin.processes import descendants, is_alive
from .machine import machine_summary

CHILD = textwrap.dedent("""
    import resource, sys, time
    limit = int(sys.argv[3])
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    t0 = time.process_time()
    try:
        if sys.argv[1] == "pycolmap":
            import numpy, pycolmap
            pycolmap.Reconstruction(sys.argv[2])
        else:
            from sosmatch.database.colmap_model import load_reconstruction
            load_reconstruction(sys.argv[2])
        outcome = "read"
    except MemoryError:
        outcome = "MemoryError"
    except Exception as exc:
        outcome = type(exc).__name__ + ": " + str(exc).splitlines()[0][:90]
    print(outcome, round(time.process_time() - t0, 2), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")


def _child(kind: str, model: Path, limit: int) -> str:
    proc = subprocess.run([sys.executable, "-c", CHILD, kind, str(model), str(limit)], capture_output=True, text=True)
    if proc.returncode != 0:
        return f"killed (exit {proc.returncode}): {proc.stderr.strip().splitlines()[-1][:90] if proc.stderr else ''}"
    outcome, cpu, rss = proc.stdout.rsplit(" ", 2)
    return f"{outcome} | {cpu} s CPU | peak RSS {int(rss) / 1024:.0f} MB"


POOL = textwrap.dedent("""
    import time
    from sosmatch.workflows.executors import LocalExecutor
    pool = LocalExecutor(2)._get_pool()
    futures = [pool.submit(time.sleep, 600) for _ in range(2)]
    time.sleep(1.0)
    print("ready", flush=True)
    time.sleep(600)
""")


def _orphans_after_kill() -> str:
    import signal

    parent = subprocess.Popen([sys.executable, "-c", POOL], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              text=True)
    parent.stdout.readline()
    started = descendants(parent.pid)
    t0 = time.monotonic()
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    while any(is_alive(p) for p in started) and time.monotonic() - t0 < 30:
        time.sleep(0.005)
    left = [p for p in started if is_alive(p)]
    return f"{len(started)} processes, {len(left)} left after {time.monotonic() - t0:.3f} s"


def main(argv: list[str] | None = None) -> None:
    from ...database.colmap_binary import check_binary_model
    from ...database.outputs import open_output_dir
    from ...plugin.multisession import Sim3
    from ..toy_sessions import lawnmower, make_world, write_toy_session

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=3000)
    args = ap.parse_args(argv)
    print(machine_summary())
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        extent = float(np.sqrt(args.objects / 300.0) * 240.0)
        toy = write_toy_session(root / "S", make_world(args.objects, extent, seed=1),
                                lawnmower(20, extent - 20, 20, extent - 20, 60, 40, 10), Sim3.identity(), seed=1)
        model = toy.path / "sparse"
        bad = root / "bad"
        shutil.copytree(model, bad)
        size = (bad / "points3D.bin").stat().st_size
        (bad / "points3D.bin").write_bytes(np.random.default_rng(0).bytes(size))
        limit = 4 * 2**30
        print(f"1. random points3D.bin ({size} bytes), 4 GiB address-space limit")
        print(f"   pycolmap.Reconstruction alone: {_child('pycolmap', bad, limit)}")
        print(f"   load_reconstruction:          {_child('sosmatch', bad, limit)}")
        mb = sum(p.stat().st_size for p in model.iterdir()) / 2**20
        t0 = time.process_time()
        runs = 0
        while time.process_time() - t0 < 2.0:
            summary = check_binary_model(model)
            runs += 1
        per = (time.process_time() - t0) / runs
        print(f"2. check_binary_model: {summary.images} images, {summary.points3D} points, {mb:.2f} MB: "
              f"{per * 1000:.1f} ms CPU ({per / mb:.2f} s per MB)")
        t0 = time.process_time()
        for k in range(200):
            with open_output_dir(root / f"o{k}", "bench", "x") as out:
                out.finish()
        print(f"3. open_output_dir + finish: {(time.process_time() - t0) / 200 * 1000:.2f} ms CPU per output")
    print(f"4. SIGKILL of a parent with 2 busy workers: {'; '.join(_orphans_after_kill() for _ in range(3))}")
    print(f"peak RSS of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
