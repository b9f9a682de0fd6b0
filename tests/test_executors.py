"""Executors: the same tasks give the same results locally (inline and in worker processes) and on a real
Dask LocalCluster with process workers on loopback; a failing task is captured, the others still run."""

import math
import operator
import time

import pytest

from sosmatch.workflows.executors import DaskExecutor, LocalExecutor, call_task, make_executor

pytest.importorskip("dask.distributed")

TASKS = {f"t{i}": (i, 7) for i in range(12)}
EXPECTED = {k: a * b for k, (a, b) in TASKS.items()}


@pytest.fixture(scope="module")
def dask_executor():
    ex = DaskExecutor(workers=2)  # one LocalCluster for the whole module: starting one costs seconds
    yield ex
    ex.close()


def _values(results):
    return {k: r.value for k, r in results.items()}


def test_call_task_captures_errors():
    ok = call_task("a", operator.add, (2, 3))
    bad = call_task("b", math.sqrt, (-1.0,))
    assert ok.ok and ok.value == 5 and ok.error == ""
    assert not bad.ok and bad.value is None and "ValueError" in bad.error and "Traceback" in bad.traceback


def test_local_inline_and_processes_agree():
    inline = LocalExecutor(0).run(operator.mul, TASKS, progress=False)
    with LocalExecutor(2) as ex:
        procs = ex.run(operator.mul, TASKS, progress=False)
        again = ex.run(operator.mul, {"x": (3, 4)}, progress=False)  # the pool is reused between runs
    assert list(inline) == list(TASKS) == list(procs)  # results come back in task order
    assert _values(inline) == _values(procs) == EXPECTED
    assert again["x"].value == 12


def test_dask_local_cluster_matches_local(dask_executor):
    assert dask_executor.client.scheduler_info()["workers"], "LocalCluster has no workers"
    results = dask_executor.run(operator.mul, TASKS, progress=False)
    assert list(results) == list(TASKS)
    assert _values(results) == EXPECTED
    # The tasks really ran in other processes (the worker processes of the cluster).
    pids = dask_executor.run(_getpid_task, {i: () for i in range(4)}, progress=False)
    import os

    assert all(r.ok for r in pids.values()) and os.getpid() not in {r.value for r in pids.values()}


def _getpid_task():
    import os

    return os.getpid()


def test_failures_are_per_task_on_every_executor(dask_executor):
    tasks = {"good": (4.0,), "bad": (-4.0,), "good2": (9.0,)}
    for ex in (LocalExecutor(0), dask_executor):
        res = ex.run(math.sqrt, tasks, progress=False)
        assert res["good"].ok and res["good"].value == 2.0 and res["good2"].value == 3.0
        assert not res["bad"].ok and "math domain error" in res["bad"].error


def test_make_executor_choices():
    assert isinstance(make_executor(workers=0), LocalExecutor)
    assert make_executor(workers=3).describe() == "local (3 worker processes)"
    with pytest.raises(ValueError):
        LocalExecutor(-1)


def test_dask_executor_on_an_existing_scheduler_address(dask_executor):
    """--scheduler tcp://HOST:PORT: connect to a running cluster (here the module's LocalCluster) and leave it up."""
    address = dask_executor._cluster.scheduler_address
    assert address.startswith("tcp://127.0.0.1:")
    with DaskExecutor(address=address) as ex:
        assert ex.describe() == f"dask ({address})"
        assert _values(ex.run(operator.mul, TASKS, progress=False)) == EXPECTED
    assert dask_executor.run(operator.add, {"k": (1, 2)}, progress=False)["k"].value == 3  # cluster still up


def test_pool_workers_leave_ctrl_c_to_their_parent():
    """Ctrl-C reaches every process of the group; a worker that died of it while writing its result to the pipe
    hung `map --workers 2` (the twelfth sweep) and printed tracebacks in `batch`. Workers ignore it; the parent
    stops the run at once (`stop_pool`: the running task's worker terminated, not waited for)."""
    import signal
    from concurrent.futures import wait

    from sosmatch.workflows.executors import process_pool, stop_pool

    parent = signal.getsignal(signal.SIGINT)  # SIG_IGN already when the suite runs in a background job
    with process_pool(1) as pool:
        assert pool.submit(signal.getsignal, signal.SIGINT).result() == signal.SIG_IGN
        running = pool.submit(time.sleep, 60)
        time.sleep(0.5)
        t0 = time.perf_counter()
        stop_pool(pool)
        wait([running], timeout=10)  # the pool's manager thread fails it once it sees its worker gone
        assert time.perf_counter() - t0 < 20 and running.done()
    assert signal.getsignal(signal.SIGINT) == parent  # the parent's own Ctrl-C handling is left as it was


def _slow_exit_task() -> bool:
    """Make this worker process take seconds to exit, as one that ran the search does (numba's teardown)."""
    import atexit
    import time

    atexit.register(time.sleep, 5.0)
    return True


def test_a_local_cluster_closes_without_killing_workers_that_exit_slowly(caplog):
    """nu54 M10: after a successful batch on `dask_local=True`, the close logged "Worker process still alive after
    4.0 seconds, killing" for each worker (their interpreter's exit outlasted the cluster's wait). The workers are
    given the time to end on their own."""
    with caplog.at_level("WARNING"):
        with DaskExecutor(workers=1) as ex:
            assert ex.run(_slow_exit_task, {"k": ()}, progress=False)["k"].value is True
    assert "still alive" not in caplog.text and "killing" not in caplog.text, caplog.text


def _exit_on(key: str, doomed: str) -> str:
    import os

    if key == doomed:
        os._exit(9)  # as the OOM killer: the worker process is gone
    return key


def test_a_task_whose_worker_dies_fails_alone_and_each_result_is_handed_over_as_it_arrives():
    """rev48 D1: a dead worker (BrokenProcessPool, Dask's KilledWorker) raised out of `run`, and the results that
    had arrived were lost with it (batch saved no state of a finished map). Now it fails the tasks it took down,
    the others go on, and `on_result` sees every result before `run` returns."""
    import dask

    from sosmatch.workflows.executors import WORKER_DIED

    tasks = {k: (k, "t2") for k in ("t1", "t2", "t3")}
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):  # no retries of the doomed task
        executors = [LocalExecutor(1), DaskExecutor(workers=1)]
    for ex in executors:
        seen = []
        with ex:
            res = ex.run(_exit_on, tasks, progress=False, on_result=seen.append)
        assert sorted(r.key for r in seen) == list(tasks) and list(res) == list(tasks), ex
        assert not res["t2"].ok and res["t2"].error == WORKER_DIED, ex
        # locally one task runs a worker at a time: t2 alone was taken down (Dask's worker held the others too,
        # and fails those the death took down by its own rule: `allowed-failures`)
        for key in ("t1", "t3"):
            assert res[key].value == key or isinstance(ex, DaskExecutor) and res[key].error == WORKER_DIED, ex


def _write_mib(path: str) -> int:
    with open(path, "wb") as f:
        return f.write(b"\0" * (1 << 20))


def test_a_full_disk_stops_the_run_instead_of_failing_each_task(tmp_path, small_disk):
    """A task that meets a full disk raises it (the CLI's full-disk line, exit 2) and the executor stops: before,
    each flight of a batch was reported failed with "OSError: [Errno 28]" and the batch went on, exit 1 (nu56 D6).
    Another OSError stays the task's own failure."""
    import errno

    tasks = {"a": (str(small_disk / "a"),), "b": (str(small_disk / "b"),)}
    for workers in (0, 1):
        with LocalExecutor(workers) as ex, pytest.raises(OSError) as raised:
            ex.run(_write_mib, tasks, progress=False)
        assert raised.value.errno == errno.ENOSPC
        assert workers or not (small_disk / "b").exists()  # inline: stopped at the first task, b never started
    other = LocalExecutor(0).run(_write_mib, {"x": (str(tmp_path / "missing" / "x"),)}, progress=False)
    assert not other["x"].ok and other["x"].error.startswith("FileNotFoundError")


def _full_disk_or_value(key: str, flags: str) -> str:
    """Task `a` meets a full disk, the others return their key; each leaves a flag file when it is done, `a` and
    `b` once the parent has been handed `0` (flag `handed`)."""
    import errno
    from pathlib import Path

    while key != "0" and not (Path(flags) / "handed").exists():
        time.sleep(0.05)
    (Path(flags) / key).touch()
    if key == "a":
        raise OSError(errno.ENOSPC, "No space left on device", str(Path(flags) / key))
    return key


def test_the_results_that_arrive_with_a_full_disk_are_handed_over_before_it_stops_the_run(tmp_path):
    """rev52 D6: the results of one `wait` were handed over in key order and a full disk raised at the first: a
    task that finished alongside (`b`) was never handed to `on_result`, so a batch saved no state of it and the
    re-run did it again. Every result that arrived is handed over, then the full disk is raised."""
    import errno
    from pathlib import Path

    flags = tmp_path / "flags"
    flags.mkdir()
    seen = []

    def on_result(res) -> None:
        seen.append(res.key)
        if res.key == "0":  # keep the parent busy until `a` and `b` are done: both in the next `wait`
            (flags / "handed").touch()
            while not ((flags / "a").exists() and (flags / "b").exists()):
                time.sleep(0.05)
            time.sleep(1.0)  # (their results cross the pipe)

    tasks = {k: (k, str(flags)) for k in ("0", "a", "b")}
    with LocalExecutor(3) as ex, pytest.raises(OSError) as raised:
        ex.run(_full_disk_or_value, tasks, progress=False, on_result=on_result)
    assert raised.value.errno == errno.ENOSPC and Path(raised.value.filename).name == "a"
    assert seen == ["0", "b"]


STOPPED_MID_TASK = '''
import errno, sys, time
from sosmatch.workflows.executors import LocalExecutor
from sosmatch.workflows.progress import progress_bar

def task(key):
    with progress_bar(1, key, "task", False):  # (a disabled bar, as a batch's worker makes)
        pass
    if key == "a":
        time.sleep(0.5)
        raise OSError(errno.ENOSPC, "No space left on device", key)
    time.sleep(60)

if __name__ == "__main__":
    try:
        with LocalExecutor(2) as ex:
            ex.run(task, {"a": ("a",), "b": ("b",), "c": ("c",)}, progress=False)
    except OSError as error:
        sys.exit(f"stopped: {error}")
'''


def test_workers_stopped_mid_task_leave_no_semaphore_for_the_tracker_to_report(tmp_path):
    """rev52 D3: a run stopped with its workers mid-task (a full disk, SIGTERM, a killed worker) ended with its
    one line and then Python's resource tracker's two: "There appear to be 2 leaked semaphore objects" (each
    killed worker's tqdm lock, a multiprocessing RLock). The workers make no such semaphore now."""
    import subprocess
    import sys

    script = tmp_path / "stopped.py"
    script.write_text(STOPPED_MID_TASK)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stderr.strip().startswith("stopped: [Errno 28]"), done.stderr
    assert "leaked" not in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
