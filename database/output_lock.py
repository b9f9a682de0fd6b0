"""An output directory's lock: taking and releasing it (`acquire_lock`, `release_lock`), who holds it, and
whether that run is still going.

A run that takes an output directory flocks `.sosmatch-output.lock` (`database.outputs`) and writes into it a
record of its process (`lock_record`). The lock file is removed when the run ends, normally or on an error; a
killed run leaves it behind, naming a process that no longer exists. A reader that finds an unfinished output
(`output_markers.unfinished_run`) asks the record whether the run is being written now (wait for it) or was
interrupted (re-run it): the two call for opposite actions, and re-running a command that is still going
collides with it.

The flock itself would answer, but a reader cannot ask it without taking it, and a probe at the moment a run
starts makes that run refuse ("in use"). So the record names the process as only it can be named: its pid, and
the host, the kernel's boot, the pid namespace and the process's start time, because a pid alone is no name:
after a reboot, or once the pids wrap, pid N is another process, alive. A process on another host, in another
pid namespace (a container sharing the file system), or of a record without these (an older sosmatch, a lock
file still being written) cannot be checked from here: `holder_state` then says "unknown".

The record also names the folder the lock was taken for (its resolved path, device and inode): a copy of a
directory taken while its run was writing it (cp -a, rsync of a project in use) carries the lock file along, and
its pid names a live process that writes the original, never the copy. A lock whose folder differs from the one
it is found in both by path and by (device, inode) is such a copy's ("elsewhere"); either alone is not enough: a
folder moved while its run writes keeps its inode, and one path may be another mount of the same folder.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import socket
from dataclasses import dataclass
from pathlib import Path

from ..plugin.errors import InputError
from .text_input import read_user_bytes

LOCK_FORMAT = "sosmatch output lock v1"
_LOCK_LIMIT_BYTES = 64 << 10  # a record is ~200 bytes; anything larger is not one
_OLD_RECORD = re.compile(r"^sosmatch (\S+) \(pid (\d+)\)")  # what sosmatch wrote before LOCK_FORMAT


def _read_small(path: str) -> str | None:
    try:
        with open(path, encoding="utf-8") as handle:
            return handle.read(4096)
    except (OSError, UnicodeDecodeError):
        return None


def _boot_id() -> str | None:
    text = _read_small("/proc/sys/kernel/random/boot_id")
    return text.strip() or None if text else None


def _pid_namespace() -> str | None:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return None


def _process_start(pid: int) -> tuple[str, int] | None:
    """(state letter, start time in clock ticks after boot) of process `pid` (/proc/PID/stat fields 3 and 22),
    None when it does not exist or /proc cannot tell (not Linux)."""
    text = _read_small(f"/proc/{pid}/stat")
    if not text or ")" not in text:
        return None
    fields = text[text.rindex(")") + 2:].split()  # the command name, in parentheses, may hold spaces
    try:
        return fields[0], int(fields[19])
    except (IndexError, ValueError):
        return None


@dataclass(frozen=True)
class LockHolder:
    """The process a lock file names; a field is None when the record does not say (older sosmatch, unreadable)."""

    command: str | None = None
    pid: int | None = None
    host: str | None = None
    boot_id: str | None = None
    pid_namespace: str | None = None
    started: int | None = None  # clock ticks after boot (/proc/PID/stat field 22)
    folder: str | None = None  # the resolved path of the directory the lock was taken for
    folder_id: tuple[int, int] | None = None  # its (st_dev, st_ino)

    def taken_elsewhere(self, folder: str | Path) -> bool:
        """Whether this lock was taken for another directory than `folder` (on this host), which it was found in:
        a copy of `folder` made while its run was writing. False when the record does not say."""
        if self.folder is None or self.folder_id is None or self.host != socket.gethostname():
            return False  # another host's paths and devices mean nothing here
        try:
            here = Path(folder).resolve()
            st = os.stat(here)
        except (OSError, RuntimeError):
            return False
        return str(here) != self.folder and (st.st_dev, st.st_ino) != self.folder_id

    def describe(self) -> str:
        """"sosmatch map (pid 123)", with the host when it is not this one; "another process" when unknown."""
        if self.pid is None:
            return "another process"
        text = f"sosmatch {self.command or '?'} (pid {self.pid})"
        return text if self.host in (None, socket.gethostname()) else f"{text} on host {self.host}"


def lock_record(command: str, folder: str | Path | None = None) -> str:
    """The record the run of `command` that takes a lock on directory `folder` writes into the lock file: this
    process, named so that `holder_state` can tell it from a later process with the same pid, and the folder, so
    that a copy of the directory is not taken for the one this process writes (None: not recorded)."""
    start = _process_start(os.getpid())
    record = {"format": LOCK_FORMAT, "command": command, "pid": os.getpid(), "host": socket.gethostname(),
              "boot_id": _boot_id(), "pid_namespace": _pid_namespace(), "started": start[1] if start else None}
    if folder is not None:
        real = Path(folder).resolve()
        st = os.stat(real)
        record.update({"folder": str(real), "folder_dev": st.st_dev, "folder_ino": st.st_ino})
    return json.dumps(record) + "\n"


def read_lock_holder(lock_path: str | Path) -> LockHolder | None:
    """The holder the lock file `lock_path` names; None when there is no lock file. A file that cannot be read or
    parsed (being written at this moment, damaged) is a holder of unknown fields."""
    lock_path = Path(lock_path)
    if not lock_path.exists():
        return None
    try:
        text = read_user_bytes(lock_path, "output lock", _LOCK_LIMIT_BYTES).decode("utf-8")
    except (InputError, UnicodeDecodeError):
        return LockHolder()
    if (old := _OLD_RECORD.match(text)) is not None:
        return LockHolder(old.group(1), int(old.group(2)))
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        return LockHolder()
    if not isinstance(data, dict) or data.get("format") != LOCK_FORMAT:
        return LockHolder()

    def typed(key: str, kind: type) -> object:
        value = data.get(key)
        return value if isinstance(value, kind) and not isinstance(value, bool) else None

    dev, ino = typed("folder_dev", int), typed("folder_ino", int)
    folder_id = (dev, ino) if dev is not None and ino is not None else None
    return LockHolder(typed("command", str), typed("pid", int), typed("host", str), typed("boot_id", str),
                      typed("pid_namespace", str), typed("started", int), typed("folder", str),
                      folder_id)  # type: ignore[arg-type]


def holder_state(holder: LockHolder | None) -> str:
    """Whether the run a lock file names is "running" (its very process is alive on this host), "gone" (no run
    holds the directory: no lock file, the machine has restarted since, the pid is free, or it is another, later
    process), or "unknown" (another host or pid namespace, or a record that does not name its process fully)."""
    if holder is None:  # a run creates the lock file before it marks its output unfinished, and removes it last
        return "gone"
    if holder.pid is None or holder.host is None or holder.host != socket.gethostname():
        return "unknown"
    if holder.boot_id is not None and _boot_id() is not None and holder.boot_id != _boot_id():
        return "gone"  # no process outlives a restart
    if holder.pid_namespace is None or holder.pid_namespace != _pid_namespace():
        return "unknown"  # its pid means another process here, or none
    try:
        os.kill(holder.pid, 0)
    except ProcessLookupError:
        return "gone"
    except PermissionError:  # alive, another user's
        pass
    except OSError:
        return "unknown"
    now = _process_start(holder.pid)
    if now is None or holder.started is None:
        return "unknown"  # alive, but it cannot be told from a later process with its pid
    state, started = now
    if state in ("Z", "X"):  # killed and not yet reaped by its parent: it writes nothing any more
        return "gone"
    return "running" if started == holder.started else "gone"


def acquire_lock(lock_path: Path, what: str) -> int:
    """flock `lock_path` exclusively without waiting; InputError naming the holder if another run has it.

    The lock file is removed when released (`release_lock`); a lock taken on a file that was removed
    meanwhile is not a lock, so the inode is checked after locking and the attempt repeated."""
    while True:
        try:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise InputError(f"cannot write output directory: {exc.strerror or exc}", lock_path.parent) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = (read_lock_holder(lock_path) or LockHolder()).describe()
            os.close(fd)
            raise InputError(f"output directory is in use by {holder}; wait for it to finish (or stop it)",
                             lock_path.parent) from None
        try:
            same = os.stat(lock_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, lock_record(what, lock_path.parent).encode())
    return fd


def release_lock(lock_path: Path, fd: int, dir_fd: int | None = None) -> None:
    """Remove the lock file while still holding it (a waiting run then finds the file gone and retries), then
    release it. `dir_fd`: the locked directory itself, where the file is looked up (the directory may have been
    moved: the lock moved with it); only the file this run locked is removed, never another run's."""
    name = lock_path.name if dir_fd is not None else lock_path
    try:
        st = os.stat(name, dir_fd=dir_fd)
        if (st.st_dev, st.st_ino) == (os.fstat(fd).st_dev, os.fstat(fd).st_ino):
            os.unlink(name, dir_fd=dir_fd)
    except OSError:
        pass
    os.close(fd)
