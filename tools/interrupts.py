"""How a CLI run that is stopped from outside ends: Ctrl-C (SIGINT) and SIGTERM (`kill PID`, a scheduler's stop)
both stop it through the interrupt path (every `finally`, `stop_pool`, the lock's release) and end it with one
line and exit 130 / 143.

Two things stood in the way (nu56 D3, D5). pycolmap's `__init__` turns anything that stops the import of its C++
core, a Ctrl-C included, into "Cannot import the C++ backend ... pip install pycolmap", and commands import
pycolmap lazily, mid-run; `interruption` finds the interrupt in the exception's chain. And pycolmap's glog, when
the core loads, installs its own SIGTERM handler (a 30-line "*** Aborted at ..." stack dump): `stop_as_interrupt`
installs a Python handler at start and installs it again each time pycolmap's core has been loaded.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import importlib.machinery
import signal
import sys
import threading
from collections.abc import Iterator
from types import FrameType, ModuleType
from typing import Any

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM
_GLOG_MODULE = "pycolmap._core"  # loading it installs glog's failure signal handler


class Terminated(KeyboardInterrupt):
    """A SIGTERM, raised in the main thread: a KeyboardInterrupt, so everything that cleans up after a Ctrl-C
    (stopping worker pools, releasing locks, removing temporaries) does so after a SIGTERM too."""


def interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM that `exc` is, or that caused it (its `__cause__` / `__context__` chain: pycolmap's
    import error raised while handling one); None when it has nothing to do with one."""
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        current = todo.pop()
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, KeyboardInterrupt):
            return current
        todo += [current.__cause__, current.__context__]
    return None


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated()


class _ReinstallAfterGlog(importlib.abc.MetaPathFinder):
    """Finds nothing itself: wraps the loader of pycolmap's core so that the SIGTERM handler is installed again
    right after glog replaced it."""

    def find_spec(self, name: str, path: Any,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if name != _GLOG_MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _LoaderThenHandler(spec.loader)
        return spec


class _LoaderThenHandler(importlib.abc.Loader):
    def __init__(self, loader: Any) -> None:
        self._loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        try:
            return self._loader.create_module(spec)
        finally:
            signal.signal(signal.SIGTERM, _raise_terminated)

    def exec_module(self, module: ModuleType) -> None:
        try:
            self._loader.exec_module(module)
        finally:
            signal.signal(signal.SIGTERM, _raise_terminated)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loader, name)


@contextlib.contextmanager
def stop_as_interrupt() -> Iterator[None]:
    """While inside: a SIGTERM raises `Terminated` in the main thread, also after pycolmap has loaded (see the
    module doc). Outside the main thread (the CLI called from a thread) signals cannot be handled: nothing done."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    finder = _ReinstallAfterGlog()
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        with contextlib.suppress(ValueError):
            sys.meta_path.remove(finder)
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
