"""A full disk (or quota) seen through a C++ library. pycolmap and its SQLite report "no space left" as a
RuntimeError without an errno ("No registered database factory succeeded."), which the CLI cannot tell from a
bug (nu56 D2: a traceback, exit 1). A write probe in the same folder tells: when it fails for lack of room, the
error is the full disk's (the CLI's one line, exit 2, and the run resumes)."""

from __future__ import annotations

import errno
import functools
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

# a device or quota that is full: the user frees space and re-runs (the run resumes)
FULL_DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
_PROBE_BYTES = 64 * 1024  # a few SQLite pages: what a failed database write needed at least

F = TypeVar("F", bound=Callable[..., Any])


def no_room(folder: Path) -> int | None:
    """ENOSPC / EDQUOT when a small write in `folder` fails for lack of room, else None (room, or another error:
    not the disk's fullness)."""
    try:
        with tempfile.TemporaryFile(dir=folder) as probe:
            probe.write(b"\0" * _PROBE_BYTES)
            probe.flush()
            os.fsync(probe.fileno())  # a file system that allocates late says ENOSPC only here
    except OSError as exc:
        return exc.errno if exc.errno in FULL_DISK_ERRNOS else None
    return None


def full_disk_reported(func: F) -> F:
    """Decorator of a function whose first argument is the path of the file a C++ library writes (a COLMAP
    database): its RuntimeError becomes OSError(ENOSPC) when that file's folder has no room; otherwise it stays."""
    @functools.wraps(func)
    def wrapper(path: Path, *args: Any, **kwargs: Any) -> Any:
        try:
            return func(path, *args, **kwargs)
        except RuntimeError as exc:
            code = no_room(Path(path).parent)
            if code is None:
                raise
            raise OSError(code, os.strerror(code)) from exc  # no file name: the CLI names the command's output
    return wrapper  # type: ignore[return-value]
