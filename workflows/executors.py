"""Where batch tasks run: local worker processes, or a Dask distributed cluster. One small interface.

    with make_executor(workers=2) as ex:                     # LocalExecutor (ProcessPoolExecutor)
    with make_executor(scheduler="tcp://host:8786") as ex:   # DaskExecutor on an existing cluster
    with make_executor(dask_local=True, workers=2) as ex:    # DaskExecutor on a LocalCluster it starts
        results = ex.run(fn, {"key": (arg1, arg2), ...}, desc="pairs")

Tasks are plain top-level functions with picklable arguments. Every task runs inside `call_task`, which catches
its exception and returns a `TaskResult` (ok or the error text and traceback): one failing flight never stops
the others (a full disk does: it is raised, see `call_task`), and no exception object has to survive pickling
between machines. `run` returns results in the order of the task dict, whatever the order of completion, so
outputs do not depend on the executor; its `on_result` sees each result as it arrives (batch saves each task's
state then: an interrupted stage keeps what finished). A worker that dies under a task (killed: most likely out
of memory) fails the tasks it took down (`worker_died`), not the run: the other tasks go on.
Worker processes are started with "spawn" (like Dask's nannies): forking a parent that already runs
OpenMP/Ceres threads (pycolmap) can deadlock. Every local worker dies with its parent (`process_pool`): a
killed batch or map leaves no worker (and so no multiprocessing resource tracker) behind.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Hashable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from ..database.full_disk import FULL_DISK_ERRNOS
from ..plugin.processes import exit_with_parent
from .progress import progress_bar

log = logging.getLogger(__name__)
# seconds a Dask worker process is given to end on its own when our LocalCluster closes (`DaskExecutor.close`)
WORKER_EXIT_S = 60.0


def _init_worker(parent_pid: int, initializer: Callable[[], None] | None) -> None:
    exit_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group: the parent stops the run (`stop_pool`: cancels what has not started,
    # kills what runs), a worker must not die of it mid-result. A worker interrupted while writing a result
    # larger than the pipe's buffer left `map --workers 2` waiting for it forever (twelfth sweep, 1 in 28 tries),
    # and `batch` printed each worker's KeyboardInterrupt traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm's first bar (a disabled one too) makes a multiprocessing RLock, a named semaphore the parent's resource
    # tracker counts; a worker `stop_pool` kills never unlinks it, and the tracker then added "There appear to be
    # 2 leaked semaphore objects" after the run's one-line message (rev52 D3). A worker's bars share no lock with
    # another process (the spawned worker's own RLock guards nothing across processes): a thread lock suffices.
    from tqdm.std import tqdm

    tqdm.set_lock(threading.RLock())
    if initializer is not None:
        initializer()


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop a pool at once, on an interruption: tasks not started are cancelled and the workers killed (their
    work is resumable: every output is written atomically). A worker ignores Ctrl-C
    (`_init_worker`), so without this an interrupted run would wait for every running task (a batch's maps)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # no public API before Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:  # SIGKILL: a worker that imported pycolmap prints glog's stack dump on SIGTERM
        proc.kill()
    for proc in procs:
        proc.join(10)


def process_pool(workers: int, initializer: Callable[[], None] | None = None) -> ProcessPoolExecutor:
    """A "spawn" ProcessPoolExecutor whose workers die with this process (then run `initializer`, a top-level
    function). Every local process pool of sosmatch is made here."""
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker,
                               initargs=(os.getpid(), initializer))


@dataclass
class TaskResult:
    """The outcome of one task: its value when ok, else the error message and traceback."""

    key: Hashable
    ok: bool
    value: Any = None
    error: str = ""
    traceback: str = ""
    seconds: float = 0.0


def call_task(key: Hashable, fn: Callable[..., Any], args: tuple) -> TaskResult:
    """Run fn(*args) and capture the outcome (this is what executes on the worker)."""
    t0 = time.perf_counter()
    try:
        value = fn(*args)
    except OSError as exc:
        if exc.errno not in FULL_DISK_ERRNOS:
            return TaskResult(key, False, None, f"{type(exc).__name__}: {exc}", traceback.format_exc(),
                              time.perf_counter() - t0)
        # A full disk is no task's failure but the run's: every further task would meet it too, and the user frees
        # space and re-runs (nu56 D6: each flight was reported failed, exit 1). A plain OSError: it crosses
        # processes and machines (errno and file name pickle), stops the executor and reaches the CLI's one line.
        raise OSError(exc.errno, exc.strerror, exc.filename) from None
    except Exception as exc:  # noqa: BLE001 (a task's failure is data, reported per task)
        return TaskResult(key, False, None, f"{type(exc).__name__}: {exc}", traceback.format_exc(),
                          time.perf_counter() - t0)
    return TaskResult(key, True, value, "", "", time.perf_counter() - t0)


# what a task taken down by the death of its worker process failed of (`worker_died`)
WORKER_DIED = ("a worker process died while it ran this task (killed: most likely out of memory; the system log, "
               "e.g. `dmesg`, says); re-run the same command to do it again (with fewer --workers if memory is short)")


def worker_died(key: Hashable, error: BaseException) -> TaskResult:
    """The failed result of a task whose worker process died under it (a broken process pool, Dask's
    KilledWorker): one line for the report, the executor's own text as its traceback (OUT/logs/)."""
    return TaskResult(key, False, None, WORKER_DIED, f"{type(error).__name__}: {error}\n")


OnResult = Callable[[TaskResult], None]


def _hand_over(finished: set[Future], running: dict[Future, Hashable],
               arrived: OnResult) -> tuple[bool, OSError | None]:
    """Hand the results of the `finished` futures (in the order of their keys) to `arrived`, taking them out of
    `running`: a task a dying worker took down (BrokenProcessPool) as failed (`worker_died`). Returns whether the
    pool broke, and the first full disk (the only error `call_task` raises), whose task hands over nothing. One
    loop for the tasks that finished and for those a broken pool took down with them, so both are said alike."""
    broken = False
    full_disk: OSError | None = None
    for fut in sorted(finished, key=lambda f: str(running[f])):
        key = running.pop(fut)
        try:
            res = fut.result()
        except BrokenProcessPool as error:  # said by the caller, as any failed task
            broken = True
            res = worker_died(key, error)
        except OSError as error:  # the run stops, after the results that arrived with it
            full_disk = full_disk or error
            continue
        arrived(res)
    return broken, full_disk


class Executor:
    """Runs a dict of independent tasks and returns {key: TaskResult} in the dict's order; `on_result` (called in
    this process) is handed each result as it arrives, so that a caller keeps what finished when the run is
    interrupted (Ctrl-C raises out of `run`)."""

    name = "executor"

    def run(
        self, fn: Callable[..., Any], tasks: dict[Hashable, tuple], desc: str = "tasks", progress: bool = True,
        on_result: OnResult | None = None,
    ) -> dict[Hashable, TaskResult]:
        raise NotImplementedError

    def close(self) -> None:
        """Release workers (idempotent)."""

    def describe(self) -> str:
        return self.name

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalExecutor(Executor):
    """Local worker processes (concurrent.futures.ProcessPoolExecutor). workers=0 runs tasks inline, in this
    process, one after the other (for debugging; exceptions are still captured per task)."""

    name = "local"

    def __init__(self, workers: int = 1) -> None:
        if workers < 0:
            raise ValueError("workers must be >= 0")
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:  # started lazily: a fully resumed batch needs no workers at all
            self._pool = process_pool(self.workers)
        return self._pool

    def run(
        self, fn: Callable[..., Any], tasks: dict[Hashable, tuple], desc: str = "tasks", progress: bool = True,
        on_result: OnResult | None = None,
    ) -> dict[Hashable, TaskResult]:
        results: dict[Hashable, TaskResult] = {}
        if not tasks:
            return results

        def arrived(res: TaskResult) -> None:
            results[res.key] = res
            if on_result is not None:
                on_result(res)
            bar.update(1)

        with progress_bar(len(tasks), desc, "task", progress) as bar:
            if self.workers == 0:
                for key, args in tasks.items():
                    arrived(call_task(key, fn, args))
            else:
                self._run_pooled(fn, tasks, arrived)
        return {key: results[key] for key in tasks}

    def _run_pooled(self, fn: Callable[..., Any], tasks: dict[Hashable, tuple], arrived: OnResult) -> None:
        """Run the tasks on the pool, at most one a worker at a time: the tasks in flight are the ones a dying
        worker takes down (a broken pool fails every task it holds), so those fail (`worker_died`) and the rest
        run on a new pool."""
        queue = list(tasks.items())[::-1]
        running: dict[Future, Hashable] = {}
        pool = self._get_pool()
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    key, args = queue.pop()
                    running[pool.submit(call_task, key, fn, args)] = key
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                broken, full_disk = _hand_over(done, running, arrived)
                if broken:  # every task still in flight was taken down with it: said as such, then a new pool
                    _, more = _hand_over(wait(running)[0], running, arrived)
                    full_disk = full_disk or more
                if full_disk is not None:
                    # every other task that finished alongside was handed over (its state saved: not redone on
                    # the re-run, rev52 D6); the full disk stops the run now
                    raise full_disk
                if broken:
                    self._pool = None
                    stop_pool(pool)
                    if queue:
                        pool = self._get_pool()
        except BaseException:  # Ctrl-C: stop now, not after every running task
            self._pool = None
            stop_pool(pool)
            raise

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def describe(self) -> str:
        return f"local ({self.workers} worker processes)" if self.workers else "local (inline)"


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster: an existing scheduler (`address`, e.g. tcp://host:8786) or, without
    one, a LocalCluster of `workers` single-threaded worker processes on loopback that this object owns."""

    name = "dask"

    def __init__(self, address: str | None = None, workers: int = 2) -> None:
        from dask.distributed import Client, LocalCluster

        self.address = address
        self._cluster = None
        if address is None:
            self._cluster = LocalCluster(
                n_workers=max(1, workers),
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
            )
            self.client = Client(self._cluster)
        else:
            try:
                self.client = Client(address)
            except (OSError, TimeoutError, ValueError) as exc:
                from ..plugin.errors import InputError

                first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise InputError(f"cannot reach the Dask scheduler {address}: {first}") from None

    def run(
        self, fn: Callable[..., Any], tasks: dict[Hashable, tuple], desc: str = "tasks", progress: bool = True,
        on_result: OnResult | None = None,
    ) -> dict[Hashable, TaskResult]:
        from dask.distributed import as_completed
        from distributed.scheduler import KilledWorker

        results: dict[Hashable, TaskResult] = {}
        if not tasks:
            return results
        # pure=False: a re-run of the same task after a fix must run again, not return a cached result.
        futures = {self.client.submit(call_task, key, fn, args, pure=False): key for key, args in tasks.items()}
        def arrived(res: TaskResult) -> None:
            results[res.key] = res
            if on_result is not None:
                on_result(res)
            bar.update(1)

        with progress_bar(len(tasks), desc, "task", progress) as bar:
            for fut in as_completed(futures):
                try:
                    res = fut.result()
                except KilledWorker as error:  # its workers died under it (Dask retried it on others first)
                    res = worker_died(futures[fut], error)
                except OSError:  # a full disk (`call_task`): the run stops, after the tasks that finished too
                    for other in futures:  # (handed over: not redone on the re-run, rev52 D6)
                        if other.status == "finished" and futures[other] not in results:
                            arrived(other.result())
                    raise
                arrived(res)
        return {key: results[key] for key in tasks}

    def close(self) -> None:
        if getattr(self, "client", None) is not None:
            self.client.close()
            self.client = None
        if self._cluster is not None:
            self._close_workers()
            self._cluster.close()
            self._cluster = None

    def _close_workers(self) -> None:
        """Let the LocalCluster's worker processes end on their own before the cluster closes. A worker that ran
        the search spends seconds in its interpreter's exit (tearing down numba's compiled kernels; 2 s at load
        12), longer than the 4 s the cluster's own close waits on a loaded machine: it then killed them and logged
        "Worker process still alive after 4.0 seconds, killing" twice after a successful batch (nu54)."""
        import asyncio

        cluster = self._cluster

        async def close_all() -> None:
            await asyncio.gather(*(worker.close(timeout=WORKER_EXIT_S) for worker in list(cluster.workers.values())),
                                 return_exceptions=True)

        try:
            cluster.sync(close_all)
        except Exception as error:  # noqa: BLE001 - the cluster's own close still ends them (killing if it must)
            log.debug("Dask workers not closed ahead of their cluster: %s", error)

    def describe(self) -> str:
        if self.address:
            return f"dask ({self.address})"
        return "dask (LocalCluster)"


def make_executor(workers: int = 1, scheduler: str | None = None, dask_local: bool = False) -> Executor:
    """The executor the command line asks for: --scheduler ADDRESS or --dask-local, else local processes."""
    if scheduler:
        return DaskExecutor(address=scheduler)
    if dask_local:
        return DaskExecutor(address=None, workers=max(1, workers))
    return LocalExecutor(workers)
