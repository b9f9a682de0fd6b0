"""The output directories this process has taken, and whether each is still where it was taken.

A user may move (`mv OUT NEW`) or delete an output directory while a command writes it. The run's lock moves
with the directory (a second run on NEW is refused), but every later write by path would either fail deep in a
stage (a traceback) or, worse, re-create folders at the old place (`mkdir(parents=True)`), which a re-run then
refuses as a folder sosmatch did not create. So a taken directory is remembered by its identity (device and
inode, from a descriptor held open while it is taken): before a write creates folders at or below it, the
directory at its path must still be that one (`check_place`); otherwise the run stops with `OutputMoved`, one
line naming the new place when the kernel knows it. Only the process that took a directory checks it: the
processes a run starts (pool and Dask workers, started before or reused across runs) would hold another run's
identities (rev25: a worker reused by a second run took the first run's folder for moved), so a worker's write under
a moved directory fails as it did before, and its run reports the move from here (`OutputDir.__exit__`).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..plugin.errors import InputError


class OutputMoved(InputError):
    """The output directory of a running command was moved or deleted under it (the user's to resolve)."""

    def __init__(self, path: Path, command: str, now: Path | None = None) -> None:
        where = f" (now {now})" if now is not None else ""
        again = "" if now is not None else " (or here to start again)"
        super().__init__(f"was moved or deleted while sosmatch {command} was writing it{where}: re-run the same "
                         f"command on its new place to resume{again}", path)


class Place:
    """One taken directory: its path, the command writing it, and a descriptor of the directory itself."""

    def __init__(self, path: Path, command: str) -> None:
        self.path = Path(os.path.abspath(path))
        self.command = command
        self.fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY)
        st = os.fstat(self.fd)
        self._id = (st.st_dev, st.st_ino)
        _TAKEN[self.path] = self

    def here(self) -> bool:
        """True while the directory at the taken path is still the one taken (not moved, deleted or replaced)."""
        try:
            st = os.stat(self.path)
        except OSError:
            return False
        return (st.st_dev, st.st_ino) == self._id

    def now(self) -> Path | None:
        """Where the taken directory is now (Linux /proc; None when deleted or unknown)."""
        try:
            now = os.readlink(f"/proc/self/fd/{self.fd}")
        except OSError:
            return None
        return None if now.endswith(" (deleted)") or not now.startswith("/") else Path(now)

    def check(self) -> None:
        """Raise `OutputMoved` when the directory is no longer at its path."""
        if not self.here():
            raise OutputMoved(self.path, self.command, self.now())

    def release(self) -> None:
        """Forget the directory (idempotent)."""
        if _TAKEN.get(self.path) is self:
            del _TAKEN[self.path]
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


_TAKEN: dict[Path, Place] = {}  # this process's taken directories, by path


def check_place(path: str | Path) -> None:
    """Before creating `path` (or folders on its way): raise `OutputMoved` when a directory this process took at
    or above `path` is no longer there, so that a write never re-creates folders at a taken directory's old place."""
    p = Path(os.path.abspath(path))
    for place in list(_TAKEN.values()):
        if p == place.path or place.path in p.parents:
            place.check()


def make_dirs(path: str | Path) -> Path:
    """`mkdir -p path` for a folder at or below a taken output directory, after `check_place`: the one way a stage
    creates folders there, so that no writer re-creates a moved directory's old place (rev25: five writers each
    paired the check with their own mkdir)."""
    check_place(path)
    Path(path).mkdir(parents=True, exist_ok=True)
    return Path(path)
