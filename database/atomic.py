"""Atomic output: write to a temporary sibling, then rename, so a killed run never leaves half a file.

The temporary sibling is a directory `.NAME.XXXXXXXX.tmp` beside the target. It holds the new file (or new
directory) and a lock file that its writer holds (flock) until the rename. A killed writer's lock dies with
it, so the next atomic write of the same target removes the stale sibling: a re-run cleans what a killed run
left, and a live writer's temporary is never touched.

Nothing here deletes or replaces a directory: a target that exists as a directory is refused
(`TargetIsDirectory`). Replacing a directory is a decision about ownership, taken in one place,
`sosmatch.database.outputs` (only entries of an output directory the command owns are replaced).
"""

from __future__ import annotations

import contextlib
import fcntl
import glob
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..plugin.errors import InputError
from .taken import check_place

TMP_SUFFIX = ".tmp"
TMP_LOCK = ".sosmatch-tmp.lock"  # inside a temporary: held by its live writer


class TargetIsDirectory(InputError, FileExistsError):
    """An atomic file write would have replaced a directory (never done; see the module doc)."""


def temp_siblings(path: Path) -> list[Path]:
    """The temporaries an atomic write of `path` may have left beside it (`.NAME.*.tmp`)."""
    return [Path(p) for p in glob.glob(os.path.join(glob.escape(str(path.parent)), f".{glob.escape(path.name)}.*"
                                                    + TMP_SUFFIX))]


def remove_if_stale(tmp_dir: Path) -> bool:
    """Remove a temporary of an atomic write whose writer is gone (its lock is free); True if removed.

    A directory without our lock file is removed only when empty (a writer killed between creating it and
    its lock); anything else without the lock is not ours to delete and stays.
    """
    try:
        fd = os.open(tmp_dir / TMP_LOCK, os.O_RDWR)
    except FileNotFoundError:
        try:
            tmp_dir.rmdir()
            return True
        except OSError:
            return False
    except OSError:
        return False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False  # its writer is alive
        shutil.rmtree(tmp_dir, ignore_errors=True)
        return True
    finally:
        os.close(fd)


def clean_stale_temporaries(directory: Path, recursive: bool = False) -> int:
    """Remove stale temporaries (`.*.tmp` with a free lock) in `directory` (and below); returns how many."""
    removed = 0
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return 0
    for entry in entries:
        if not entry.is_dir(follow_symlinks=False):
            continue
        if entry.name.startswith(".") and entry.name.endswith(TMP_SUFFIX):
            removed += remove_if_stale(Path(entry.path))
        elif recursive:
            removed += clean_stale_temporaries(Path(entry.path), recursive=True)
    return removed


def locked_temp_dir(path: Path) -> tuple[Path, int]:
    """A new `.NAME.XXXXXXXX.tmp` directory beside `path` and the fd of its held lock."""
    for _ in range(5):
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent))
        try:
            fd = os.open(tmp / TMP_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:  # a cleaner took the still-empty directory for a killed writer's: retry
            continue
        fcntl.flock(fd, fcntl.LOCK_EX)
        return tmp, fd
    raise OSError(f"cannot create a temporary directory beside {path}")


@contextlib.contextmanager
def atomic_path(path: str | Path, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is renamed onto `path`, on error removed.

    The caller creates a file, or a directory, at the yielded path. A file replaces an existing file; a
    directory may only be created (an existing directory target raises `TargetIsDirectory`, as does a file
    write onto a directory). Stale temporaries of earlier, killed writes of `path` are removed first. The
    folders on the way to `path` are created, unless `make_parents` is False (the folder must then exist).
    """
    path = Path(path)
    # never re-create a taken output directory that was moved away under its run (`database.taken`)
    check_place(path.parent)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    for stale in temp_siblings(path):
        remove_if_stale(stale)
    tmp, fd = locked_temp_dir(path)
    target = tmp / path.name
    try:
        yield target
        if path.is_dir() and not path.is_symlink():
            raise TargetIsDirectory("exists and is a directory; not replaced", path)
        if target.is_dir() and (path.exists() or path.is_symlink()):
            raise TargetIsDirectory("exists; a directory is never written over it", path)
        os.replace(target, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        os.close(fd)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))
