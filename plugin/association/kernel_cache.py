"""Numba's on-disk cache of the association kernels, invalidated when any kernel source changes.

numba (`cache=True`) stamps a cached function with the modification time and size of *its own* file only.
A kernel that calls kernels of another module (the search calls the graph and solve kernels) keeps its old
machine code, with the old callees inlined, after those callees change: an upgraded installation then runs
stale code or crashes in it (a segfault was seen in `windowed_search` after an update of `kernels_graph`).

`refresh()` keys the cache on the contents of every module of this package: where the cache directory's stamp
differs from the sources' digest, the package's own cache files (`MODULE.*.nbi` / `.nbc`, files numba wrote for
these modules and nothing else) are removed before any kernel loads, and the new stamp is written. The check
runs once per process, under a file lock (pytest-xdist and pool workers import concurrently).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
from pathlib import Path

logger = logging.getLogger(__name__)

PACKAGE_DIR = Path(__file__).resolve().parent
STAMP_NAME = "sosmatch-kernels.sha1"
_refreshed: set[Path] = set()


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
