"""Numba's on-disk cache of the association kernels, invalidated when any kernel source changes.

numba (`cache=True`) stamps a cached function with the modification time and size of *its own* file only.
A kernel that calls kernels of another module (the search calls the graph and solve kernels) keeps its old
machine code, with the old callees inlined, after those callees change: an upgraded installation then runs
stale code or crashes in it (a segfault was seen in `windowed_search` after an update of `kernels_graph`).

`refresh()` keys the cache on the contents of every module of this package: where the cache directory's stamp
differs from the sources' digest, the package's own cache files (`MODULE.*.nbi` / `.nbc`, files numba wrote for
these modules and nothing else) are removed before any kernel loads, and the new stamp is written. The check
runs once per process, under a file lock (pytest-xdist and pool workers import concurrently).

`announce_compile()` says so, once, before a search would compile the kernels (the first match after an install
or a change of their sources: minutes of CPU, for maps that then match in seconds); `tools.warm_kernels`
compiles them ahead (`make install` runs it). Either writes a marker with the sources' digest when done, so that
the next process does not say it again.

One process at a time compiles or loads a cached kernel: numba's cache is not safe when two processes write
entries of one function at once (numba issue #4807; two pytest-xdist workers compiling on a cold cache left an
index naming another signature's machine code, and the next search segfaulted in `windowed_search`). numba does
every compile of a dispatcher, its cache look-up (`load_overload`) and its cache write (`save_overload`) inside
its in-process `global_compiler_lock`, and announces each acquisition with the event `numba:compiler_lock`. The
listener `CompileLock`, registered when this module is imported (before any kernel of the package loads), holds
an exclusive flock beside the cache from the process's outermost start of that lock to its outermost end: any
kernel, on any path (a position prior, the paper preset, `--exhaustive`, the parallel graph build, a test that
calls a kernel directly), is read, compiled and written by one process at a time, and a second process that
needs it waits, then loads what the first wrote. A warm cache costs one flock per top-level kernel a process loads
(14 for a default match, ~1 ms); a file system without flock leaves numba unlocked, as before, with a debug log.

The same listener times those spans (`kernel_seconds`): `search_clock()` is the search's clock, which stands still
while the process compiles or loads a kernel (or waits for another process compiling one), so that a search's
timings (match.json `search_seconds`) hold the search and not the one-off compile of a fresh install (minutes of
CPU: a first match recorded 151 s for a search of 0.9 s, nu54); the match records that time apart
(`kernel_compile_s`). Both are per process, not per thread: see `search_clock` for what that means for searches
that run concurrently as threads of one process.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib
import logging
import os
import pkgutil
import threading
import time
import types
from pathlib import Path
from typing import IO

from numba.core import event

logger = logging.getLogger(__name__)

PACKAGE_DIR = Path(__file__).resolve().parent
STAMP_NAME = "sosmatch-kernels.sha1"
COMPILED_NAME = "sosmatch-kernels.compiled"  # the sources' digest, once the searches' kernels are compiled
# CPU seconds per kernel compiled: a default match from an empty cache compiled 41 kernels in 61 s of CPU, the
# position-prior path 2 more in 2.5 s (BENCHMARKS.md, "The new-user sweep"); what the notice's minutes come from
COMPILE_CPU_S_PER_KERNEL = 1.5
_refreshed: set[Path] = set()
_announced: list[bool] = []
COMPILE_LOCK_NAME = "sosmatch-kernels.compile.lock"
REGISTERED_ATTR = "_sosmatch_compile_lock"  # where the process's CompileLock is kept (`install_compile_lock`)
WAIT_NOTICE_S = 2.0  # a wait on the compile lock longer than this is said (once per process)


def sources_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-1 over the names and contents of the package's modules (sorted): what the compiled code depends on."""
    digest = hashlib.sha1()
    for path in sorted(package_dir.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _probe() -> None:  # a function of this package, to ask numba where the package's kernels are cached
    pass


def cache_dir(package_dir: Path = PACKAGE_DIR) -> Path:
    """The directory numba caches the functions of `package_dir` in (its own locator: __pycache__, NUMBA_CACHE_DIR,
    or the user-wide cache when the package is read-only)."""
    try:
        from numba.core.caching import FunctionCache

        probe = _probe
        if package_dir != PACKAGE_DIR:  # the same function, as numba sees one defined in that package
            probe = types.FunctionType(_probe.__code__.replace(co_filename=str(package_dir / "__init__.py")),
                                       {"__name__": "probe"})
        return Path(FunctionCache(probe)._cache_path)  # numba's own choice of directory
    except Exception as error:  # noqa: BLE001 - any failure of a private API: fall back to numba's default
        logger.debug("numba cache locator unavailable (%s); assuming __pycache__", error)
    return package_dir / "__pycache__"


def invalidate_stale(package_dir: Path, directory: Path, digest: str) -> int:
    """Remove the package's cached kernels from `directory` unless its stamp equals `digest`; return how many
    files were removed. Only files named after the package's modules with numba's suffixes are touched."""
    stamp = directory / STAMP_NAME
    try:
        if stamp.read_text().strip() == digest:
            return 0
    except OSError:
        pass
    modules = {path.stem for path in package_dir.glob("*.py")}
    removed = 0
    for path in directory.glob("*.nb[ic]"):
        if path.name.split(".", 1)[0] in modules:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += 1
    tmp = directory / f".{STAMP_NAME}.{os.getpid()}.tmp"
    tmp.write_text(digest + "\n")
    os.replace(tmp, stamp)
    return removed


def kernels() -> dict[str, object]:
    """Every numba kernel of this package that numba caches on disk, by "module.name" (imports the modules)."""
    found: dict[str, object] = {}
    for info in pkgutil.iter_modules([str(PACKAGE_DIR)]):
        module = importlib.import_module(f"{__package__}.{info.name}")
        for name, obj in vars(module).items():
            cache = getattr(obj, "_cache", None)
            if getattr(obj, "__module__", None) == module.__name__ and hasattr(cache, "_cache_file"):
                found[f"{info.name}.{name}"] = obj
    return found


def uncompiled_kernels() -> list[str]:
    """The kernels with no entry in numba's on-disk cache ("module.name"). Not all of them compile in a search:
    kernels called only from other kernels are compiled into their callers and never get an entry of their own,
    and some paths (the parallel graph build, the exhaustive reference) run only when asked for. Empty when
    numba's cache layout cannot be read (private API)."""
    try:
        return sorted(name for name, kernel in kernels().items()
                      if not Path(kernel._cache._cache_file._index_path).is_file())  # type: ignore[attr-defined]
    except Exception as error:  # noqa: BLE001 - a private API of numba: never fail a search on it
        logger.debug("numba cache entries not checked: %s", error)
        return []


def compile_message(missing: int, total: int) -> str:
    """The one line said before `missing` of the `total` kernels compile ("up to": a search compiles only those it
    calls, a default match 43 of 66)."""
    minutes = max(1, round(COMPILE_CPU_S_PER_KERNEL * missing / 60.0))
    return (f"compiling the search kernels once for this install ({missing} of {total}, up to ~{minutes} min of "
            "CPU); later runs start at once")


def compiled_for_these_sources(package_dir: Path = PACKAGE_DIR) -> bool:
    """Whether a search (or `tools.warm_kernels`) has compiled the kernels since their sources last changed: the
    marker beside the cache holds the sources' digest."""
    try:
        return (cache_dir(package_dir) / COMPILED_NAME).read_text().strip() == sources_digest(package_dir)
    except OSError:
        return False


def mark_compiled(package_dir: Path = PACKAGE_DIR) -> None:
    """Record that the searches' kernels are compiled for the current sources (never fatal)."""
    try:
        directory = cache_dir(package_dir)
        tmp = directory / f".{COMPILED_NAME}.{os.getpid()}.tmp"
        tmp.write_text(sources_digest(package_dir) + "\n")
        os.replace(tmp, directory / COMPILED_NAME)
    except OSError as error:
        logger.debug("compiled-kernels marker not written: %s", error)


def announce_compile() -> bool:
    """Log `compile_message` (once per process) before a search that must compile the kernels first: nothing has
    compiled them since their sources changed. Returns True when it did: the caller then `mark_compiled` after its
    search, so the next process starts without the message (also for kernels no search of it compiles)."""
    if _announced:
        return False
    _announced.append(True)
    if compiled_for_these_sources():
        return False
    missing = uncompiled_kernels()
    if not missing:
        return False
    logger.info("%s (`make install` compiles them ahead)", compile_message(len(missing), len(kernels())))
    return True


class CompileLock(event.Listener):
    """Holds an exclusive flock on `path` while this process is inside numba's compiler lock (module doc).

    numba's lock is re-entrant (a kernel's compile compiles the kernels it calls) and fires its start event before
    it is taken, so another thread may start while one holds it: the count is process-wide, under a threading lock,
    and the flock is taken on its first start and let go on its last end. While the flock is held this process
    waits on no other (a waiter blocks before numba's lock, holding nothing another process needs). A path that
    cannot be locked (no flock on the file system, a read-only directory) is given up with a debug log: numba
    then compiles unlocked, as without this listener."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._guard = threading.Lock()
        self._depth = 0
        self._held: IO[str] | None = None
        self._pending: IO[str] | None = None  # the lock file opened by a wait not yet granted (`after_fork_in_child`)
        self._told = False
        # the time spent inside numba's lock (`seconds`): its own guard, as `_guard` is held through a flock wait
        self._clock = threading.Lock()
        self._spent = 0.0
        self._since: float | None = None  # perf_counter at the outermost start of the span in progress

    def on_start(self, event: object) -> None:  # noqa: ARG002 - numba's Listener interface
        with self._guard:
            if self._depth == 0:
                self._span(True)  # a wait for another process's compile is counted too
                try:
                    self._held = self._acquire()  # before counting: an interrupted wait leaves the count as it was
                except BaseException:
                    self._span(False)
                    raise
            self._depth += 1

    def on_end(self, event: object) -> None:  # noqa: ARG002 - numba's Listener interface
        with self._guard:
            if self._depth == 0:  # an end whose start came before the listener was registered
                return
            self._depth -= 1
            if self._depth == 0:
                if self._held is not None:
                    self._held.close()  # closing the descriptor releases the flock
                    self._held = None
                self._span(False)

    def _span(self, starts: bool) -> None:
        """Start or end the process's span inside numba's lock (its outermost start and end)."""
        now = time.perf_counter()
        with self._clock:
            if starts:
                self._since = now
            elif self._since is not None:
                self._spent += now - self._since
                self._since = None

    def seconds(self, now: float | None = None) -> float:
        """Seconds this process has spent inside numba's compiler lock (compiling or loading kernels, or waiting
        for another process's compile), up to `now` (perf_counter; default: now)."""
        now = time.perf_counter() if now is None else now
        with self._clock:
            return self._spent + (now - self._since if self._since is not None else 0.0)

    def _acquire(self) -> IO[str] | None:
        if self.path is None:
            return None
        lock = None
        try:
            lock = self._pending = open(self.path, "a")  # noqa: SIM115 - held until the outermost end
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                self._wait(lock)
            self._pending = None
            return lock
        except OSError as error:  # a file system without flock (some NFS / Lustre mounts), a read-only directory
            logger.debug("numba compile lock %s not taken (%s): numba compiles unlocked", self.path, error)
            self.path = None  # given up for the process: one log line, no retry per kernel
            self._release_pending(lock)
            return None
        except BaseException:  # interrupted (Ctrl-C) in or right after the wait: a file left open in the
            self._release_pending(lock)  # traceback could hold the flock, and the next compile here wait on itself
            raise

    def _release_pending(self, lock: IO[str] | None) -> None:
        self._pending = None
        if lock is not None:
            lock.close()

    def _wait(self, lock: IO[str]) -> None:
        """Wait for the flock; say so when another process keeps it a while (it is compiling: loading a cached
        kernel holds it for milliseconds)."""
        notice = threading.Timer(WAIT_NOTICE_S, self._tell)
        notice.daemon = True
        notice.start()
        try:
            fcntl.flock(lock, fcntl.LOCK_EX)
        finally:
            notice.cancel()

    def _tell(self) -> None:
        """The wait's notice: once per process at INFO (a cold cache makes a process wait once per kernel)."""
        logger.log(logging.DEBUG if self._told else logging.INFO,
                   "waiting for another process that is compiling numba kernels into the shared cache")
        self._told = True

    def after_fork_in_child(self) -> None:
        """A child forked while a thread here held the flock shares its open file (a flock belongs to the open
        file): it closes its copy, so the parent's release still lets go, and counts from zero (the holding
        thread is not in the child)."""
        for file in (self._held, self._pending):  # also a file a parent's thread is still waiting to lock: the
            if file is not None:                     # lock the parent gets later would be this child's too (rev34)
                file.close()
        self._held = self._pending = None
        self._depth = 0
        self._guard = threading.Lock()
        self._clock = threading.Lock()
        self._since = None  # a span of the parent's threads: not this process's


def install_compile_lock() -> CompileLock:
    """Register the process's `CompileLock` beside the package's cache (once, when this module is imported). Once
    per process, also when this module is loaded a second time (a reload, or run as `__main__`): a second listener
    would open the lock file again and wait, forever, on the first one's flock (a flock belongs to the open file)."""
    registered = getattr(event, REGISTERED_ATTR, None)
    if isinstance(registered, event.Listener):
        return registered  # type: ignore[return-value]
    path: Path | None = None
    try:
        directory = cache_dir()
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / COMPILE_LOCK_NAME
    except OSError as error:
        logger.debug("numba compile lock not set up: %s", error)
    lock = CompileLock(path)
    event.register("numba:compiler_lock", lock)
    os.register_at_fork(after_in_child=lock.after_fork_in_child)
    setattr(event, REGISTERED_ATTR, lock)  # on numba's module: one per process, whichever copy of this one asks
    return lock


def refresh(package_dir: Path = PACKAGE_DIR) -> None:
    """Make numba's cache of this package's kernels match their sources (once per process; never fatal: a cache
    that cannot be checked is left to numba, which then compiles where it cannot write)."""
    if package_dir in _refreshed:
        return
    _refreshed.add(package_dir)
    try:
        directory = cache_dir(package_dir)
        directory.mkdir(parents=True, exist_ok=True)
        with open(directory / f"{STAMP_NAME}.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            removed = invalidate_stale(package_dir, directory, sources_digest(package_dir))
        if removed:
            logger.debug("removed %d stale compiled kernels from %s", removed, directory)
    except OSError as error:
        logger.debug("numba cache of %s not checked: %s", package_dir, error)


def kernel_seconds() -> float:
    """Seconds this process has spent compiling or loading numba kernels (any, on any thread; `CompileLock`): per
    process, as `search_clock` (whose doc says what that means for concurrent searches)."""
    return COMPILE_LOCK.seconds()


def search_clock() -> float:
    """A clock (seconds, like `time.perf_counter`) that stands still while this process compiles or loads numba
    kernels: differences of it time a search without the one-off compile of a fresh install (module doc).

    The clock is the process's, not the calling thread's (rev46 D3): while any thread of the process is inside
    numba's compiler lock, it stands still for every thread. Searches that run concurrently as threads of one
    process (batch on a Dask scheduler whose workers run several threads, `dask worker --nthreads N`) then
    undercount: a search that compiles nothing loses the time another thread compiles (3 s of work timed 2.1 s while
    another thread compiled three kernels), and its `kernel_compile_s` (`kernel_seconds`) holds that thread's
    compile. Processes (batch's LocalExecutor, `--dask-local`: one thread per worker) are not affected, nor is one
    search, one process (`match`, `evaluate`). Kept per process because a search's own compiles are not all on its
    thread: on idle cores the windowed search computes a block's direct window pairs in a thread pool
    (`windowed_search._direct_in_threads`), whose first call compiles the kernel on a pool thread while the
    search's thread waits for it, and a per-thread clock would count that compile as search
    time. A per-thread clock would not be exact either: numba compiles under one process-wide lock, so a thread
    that needs a kernel while another compiles waits for that compile too (time its search also loses), and a
    compile holds the GIL that a pure-Python search needs."""
    now = time.perf_counter()
    return now - COMPILE_LOCK.seconds(now)


refresh()
COMPILE_LOCK = install_compile_lock()  # before any kernel of the package loads
