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
compiles them ahead (`make install` runs it). Either writes a marker with the sources' digest when done.

`compile_lock()` lets one process at a time compile into the cache: numba's cache is not safe when two processes
write entries of one function at once (numba issue #4807; two pytest-xdist workers compiling on a cold cache left
an index naming another signature's machine code, and the next search segfaulted in `windowed_search`). A
`batch --workers 2` or two `sosmatch match` started together after an install without `make install` are the
users' case. Once the kernels are compiled for these sources the lock is not taken.
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
from collections.abc import Iterator
from pathlib import Path

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
_lock_depth = threading.local()  # n > 0: this thread is inside compile_lock (a flock is not re-entrant)


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
    """The directory numba caches this package's functions in (its own locator: __pycache__, NUMBA_CACHE_DIR, or
    the user-wide cache when the package is read-only)."""
    if package_dir == PACKAGE_DIR:
        try:
            from numba.core.caching import FunctionCache

            return Path(FunctionCache(_probe)._cache_path)  # numba's own choice of directory
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
    compiled them since their sources changed. Returns True when it did. The search that compiles marks them
    compiled after it (`compile_lock` says which call that is), so the next process starts without the message."""
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


@contextlib.contextmanager
def compile_lock(package_dir: Path = PACKAGE_DIR) -> Iterator[bool]:
    """Hold the package's compile lock while this process may compile kernels into the shared cache (module doc):
    a second process that needs them says so in one line, waits, then loads what the first compiled. Yields
    whether this call is the one that compiles (the kernels are not compiled for these sources, also after a wait;
    not nested in another compile_lock): the caller then `mark_compiled` when done, inside it, and it alone. No
    lock once the kernels are compiled, nor where the cache directory cannot hold one (no flock there: numba then
    compiles as before, and the call still compiles). Re-entrant within a thread (a match inside
    `tools.warm_kernels`); another thread of the process waits like another process."""
    if getattr(_lock_depth, "n", 0) or compiled_for_these_sources(package_dir):
        yield False
        return
    lock = None
    try:
        directory = cache_dir(package_dir)
        directory.mkdir(parents=True, exist_ok=True)
        lock = open(directory / COMPILE_LOCK_NAME, "a")  # noqa: SIM115 - held across the yield
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            logger.info("waiting for another sosmatch process that is compiling the search kernels (once per "
                        "install)")
            fcntl.flock(lock, fcntl.LOCK_EX)
    except OSError as error:  # no lock file, or a file system without flock (some NFS / Lustre mounts)
        logger.debug("kernel compile lock not taken: %s", error)
        if lock is not None:
            lock.close()
        lock = None
    compiling = lock is None or not compiled_for_these_sources(package_dir)  # else compiled while this one waited
    if not compiling:
        lock.close()
        lock = None
    _lock_depth.n = getattr(_lock_depth, "n", 0) + 1
    try:
        yield compiling
    finally:
        _lock_depth.n -= 1
        if lock is not None:
            lock.close()  # closing the descriptor releases the flock


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


refresh()
