"""Child processes that die with their parent.

A worker pool's children outlive a parent killed with SIGKILL (nothing runs in the parent to stop them), and
with them the multiprocessing resource tracker they keep open. Every worker sosmatch starts calls
`exit_with_parent` first (`workflows.executors.process_pool`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

PR_SET_PDEATHSIG = 1  # linux/prctl.h


def exit_with_parent(parent_pid: int, poll_s: float = 1.0) -> None:
    """Make this (worker) process die when `parent_pid` does, even by SIGKILL.

    Linux: prctl(PR_SET_PDEATHSIG, SIGKILL) has the kernel kill us when the parent exits. Elsewhere, and in
    case the parent died before the call, a daemon thread watches the parent pid and exits the process."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover (no libc prctl)
            pass
    if os.getppid() != parent_pid:  # the parent is already gone (we were re-parented)
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()




def descendants(pid: int) -> set[int]:
    """Every process started by `pid` and by its children (Linux /proc), to check that none outlives it."""
    out, todo = set(), [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except OSError:
                continue
            out.update(kids)
            todo.extend(kids)
    return out


def is_alive(pid: int) -> bool:
    """True while `pid` runs (a zombie, already dead, is not alive)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    except (OSError, IndexError):
        return False
