"""numba's cache of compiled kernels follows changes of *called* kernels in other modules (kernel_cache)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from sosmatch.plugin.association import kernel_cache


def _write_package(root: Path, increment: int) -> Path:
    package = root / "kpkg"
    package.mkdir(exist_ok=True)
    (package / "__init__.py").write_text(textwrap.dedent("""
        from pathlib import Path
        from sosmatch.plugin.association.kernel_cache import refresh
        refresh(Path(__file__).resolve().parent)
    """))
    (package / "callee.py").write_text(textwrap.dedent(f"""
        from numba import njit
        @njit(cache=True)
        def g(x):
            return x + {increment}
    """))
    (package / "caller.py").write_text(textwrap.dedent("""
        from numba import njit
        from .callee import g
        @njit(cache=True)
        def f(x):
            return g(x) * 10
    """))
    return package


def _call(root: Path) -> int:
    out = subprocess.run([sys.executable, "-c", "from kpkg.caller import f; print(f(1))"], cwd=root,
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


def test_a_changed_callee_recompiles_its_cached_caller(tmp_path: Path) -> None:
    package = _write_package(tmp_path, increment=1)
    assert _call(tmp_path) == 20
    assert list(kernel_cache.cache_dir(package).glob("caller.*.nbc")), "numba cached the caller"
    _write_package(tmp_path, increment=2)  # only the callee's module changes
    assert _call(tmp_path) == 30  # numba alone would load the caller with the old callee inlined: 20
    stamp = (kernel_cache.cache_dir(package) / kernel_cache.STAMP_NAME).read_text().strip()
    assert stamp == kernel_cache.sources_digest(package)


def test_invalidation_touches_only_the_package_cache_files(tmp_path: Path) -> None:
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "mod.py").write_text("x = 1\n")
    cache = tmp_path / "cache"
    cache.mkdir()
    ours = [cache / "mod.f-3.py311.nbi", cache / "mod.f-3.py311.1.nbc"]
    foreign = [cache / "other.f-3.py311.nbi", cache / "mod.cpython-311.pyc", cache / "notes.txt"]
    for path in ours + foreign:
        path.write_text("")
    digest = kernel_cache.sources_digest(package)
    assert kernel_cache.invalidate_stale(package, cache, digest) == 2
    assert not any(path.exists() for path in ours)
    assert all(path.exists() for path in foreign)
    for path in ours:
        path.write_text("")
    assert kernel_cache.invalidate_stale(package, cache, digest) == 0  # stamp matches: nothing removed
    assert all(path.exists() for path in ours)
    (package / "mod.py").write_text("x = 2\n")
    assert kernel_cache.invalidate_stale(package, cache, kernel_cache.sources_digest(package)) == 2


def test_the_association_package_is_stamped() -> None:
    directory = kernel_cache.cache_dir()
    assert (directory / kernel_cache.STAMP_NAME).read_text().strip() == kernel_cache.sources_digest()


def test_a_search_that_must_compile_says_so_once(tmp_path: Path) -> None:
    """An empty cache (a fresh install): one line says the kernels are compiled once, before the first search;
    a kernel compiled since is no longer counted; once a search has compiled them, no process says it again."""
    script = textwrap.dedent("""
        import logging, sys
        import numpy as np
        logging.basicConfig(level=logging.INFO, stream=sys.stdout, format="%(message)s")
        from sosmatch.plugin.association import kernel_cache
        from sosmatch.plugin.association.kernels_csr import sym_csr
        kernel_cache.announce_compile()
        kernel_cache.announce_compile()  # once per process
        sym_csr(3, np.array([0, 1]), np.array([1, 2]), np.array([1.0, 1.0]))
        kernel_cache._announced.clear()
        kernel_cache.announce_compile()
        kernel_cache.mark_compiled()  # what the search that compiles does when it is done
        kernel_cache._announced.clear()
        print("after the search:", kernel_cache.announce_compile(), kernel_cache.compiled_for_these_sources())
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=env)
    lines = [line for line in out.stdout.splitlines() if line.startswith("compiling the search kernels")]
    total = len(kernel_cache.kernels())
    assert total > 20 and len(lines) == 2, out.stdout + out.stderr
    assert f"({total} of {total}, up to ~" in lines[0] and "later runs start at once" in lines[0]
    assert f"({total - 2} of {total}, up to ~" in lines[1]  # sym_csr and the _sym_csr it calls are cached now
    # kernels that never get an entry of their own (callees, paths of their own) do not repeat the message
    assert "after the search: False True" in out.stdout


def test_warm_kernels_help_prints_usage_without_compiling(capsys, monkeypatch) -> None:
    """`python -m sosmatch.tools.warm_kernels --help` ran the warm-up (minutes of CPU on a cold cache; nu45)."""
    import pytest

    import sosmatch.tools.warm_kernels as warm

    def must_not_run() -> tuple[int, int, float]:
        raise AssertionError("--help compiled the kernels")

    monkeypatch.setattr(warm, "warm_kernels", must_not_run)
    monkeypatch.setattr(warm.kernel_cache, "compiled_for_these_sources", lambda: False)
    with pytest.raises(SystemExit) as done:
        warm.main(["--help"])
    assert done.value.code == 0 and "usage:" in capsys.readouterr().out


def test_any_compile_waits_while_another_process_holds_the_compile_lock(tmp_path: Path) -> None:
    """Two processes compiling into numba's cache at once can leave entries that segfault on load (numba #4807: two
    xdist workers on a cold cache). Every compile or cache load of any kernel, not only the searches' (here a
    throwaway one, on two threads at once, calling another), takes the lock beside the cache: while another
    process holds it the compile waits. The holder touches `released` before it lets go, so the compile always
    finds it, and says once that it waits; afterwards this process holds nothing (the threads' nested starts and
    ends are counted)."""
    (tmp_path / "throwaway.py").write_text(textwrap.dedent("""
        from numba import njit
        @njit(cache=True)
        def g(x):
            return x + 1
        @njit(cache=True)
        def f(x):
            return g(x) * 2
    """))
    script = textwrap.dedent(f"""
        import fcntl, logging, pathlib, sys, threading, time
        from sosmatch.plugin.association import kernel_cache
        logging.basicConfig(level=logging.INFO, format="%(message)s")
        kernel_cache.WAIT_NOTICE_S = 0.2  # the holder keeps the lock 1.5 s: the wait is said, once
        tmp = pathlib.Path({str(tmp_path)!r})
        sys.path.insert(0, str(tmp))
        import throwaway
        path = kernel_cache.cache_dir() / kernel_cache.COMPILE_LOCK_NAME
        (tmp / "path").write_text(str(path))
        while not (tmp / "ready").exists():
            time.sleep(0.01)
        threads = [threading.Thread(target=throwaway.f, args=(value,)) for value in (1, 1.0)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        print("compiled after the release:", (tmp / "released").exists())
        with open(path, "a") as probe:
            fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)  # BlockingIOError if still held here
        print("lock free:", throwaway.f(2), throwaway.f(2.5))
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    compiler = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    holder = None
    try:
        while not (tmp_path / "path").exists() and compiler.poll() is None:
            time.sleep(0.01)
        holder = _hold_the_lock(Path((tmp_path / "path").read_text()), tmp_path / "ready", tmp_path / "released")
        out, err = compiler.communicate(timeout=120)
    finally:
        compiler.kill()
        if holder is not None:
            holder.wait(timeout=60)
    assert "compiled after the release: True" in out and "lock free: 6 7.0" in out, out + err
    assert err.count("waiting for another process that is compiling numba kernels") == 1, err


def test_a_child_forked_while_the_lock_is_held_does_not_keep_it(tmp_path: Path) -> None:
    """A flock belongs to the open file, which a forked child shares: a pool worker forked while a thread here held
    the lock would hold it for as long as it lives, and a later compile here would wait for that worker, which
    waits for this process. The child lets go of its copy."""
    script = textwrap.dedent("""
        import fcntl, os
        from sosmatch.plugin.association import kernel_cache
        lock = kernel_cache.COMPILE_LOCK
        lock.on_start(None)  # as numba's compiler lock announces itself: the flock is held from here
        read, write = os.pipe()
        started, running = os.pipe()
        child = os.fork()
        if child == 0:
            os.write(running, b"x")  # after the fork's hooks ran
            os.read(read, 1)  # a worker that lives on
            os._exit(0)
        os.read(started, 1)
        lock.on_end(None)
        try:
            with open(lock.path, "a") as probe:
                fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
            print("lock free")
        finally:
            os.write(write, b"x")
            os.waitpid(child, 0)
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "lock free", out.stdout + out.stderr


def test_a_child_forked_while_a_thread_waits_for_the_lock_does_not_keep_it(tmp_path: Path) -> None:
    """A thread here waits for the lock (another process holds it) when the process forks: the child shares the
    file being waited on, so the lock the parent gets later would be the child's too, held for as long as it lives
    (rev34). The child closes that file as well; the parent's release then frees the lock."""
    script = textwrap.dedent("""
        import fcntl, os, subprocess, sys, threading, time
        from sosmatch.plugin.association import kernel_cache
        lock = kernel_cache.COMPILE_LOCK
        holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'a'); "
                                   "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(1.5)",
                                   str(lock.path)], stdout=subprocess.PIPE, text=True)
        holder.stdout.readline()
        waiting = threading.Thread(target=lock.on_start, args=(None,))
        waiting.start()
        while lock._pending is None:  # the thread has opened the lock file and waits on it
            time.sleep(0.01)
        read, write = os.pipe()
        child = os.fork()
        if child == 0:
            os.read(read, 1)  # a worker that lives on
            os._exit(0)
        waiting.join()
        lock.on_end(None)
        try:
            with open(lock.path, "a") as probe:
                fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
            print("lock free")
        except BlockingIOError:
            print("held by the child")
        finally:
            os.write(write, b"x")
            os.waitpid(child, 0)
            holder.wait()
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "lock free", out.stdout + out.stderr


def test_the_module_loaded_twice_keeps_one_listener(tmp_path: Path) -> None:
    """A second copy of this module (a reload, or run as `__main__`) must not register a second listener: it would
    open the lock file again and, inside numba's next compile, wait forever for the first listener's flock. The
    child compiles a throwaway cached kernel after a reload; a timeout is the deadlock."""
    script = textwrap.dedent("""
        import importlib
        from numba.core import event
        from sosmatch.plugin.association import kernel_cache
        first = kernel_cache.COMPILE_LOCK
        importlib.reload(kernel_cache)
        assert kernel_cache.COMPILE_LOCK is first
        from numba import njit
        @njit(cache=True)
        def twice(x):
            return 2 * x
        print(twice(21), len(event._registered["numba:compiler_lock"]))
    """)
    script_path = tmp_path / "twice.py"  # a file, so that numba can cache the throwaway kernel beside it
    script_path.write_text(script)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    out = subprocess.run([sys.executable, str(script_path)], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["42", "1"], out.stdout + out.stderr


def test_a_lock_that_cannot_be_taken_leaves_numba_unlocked(tmp_path: Path, caplog) -> None:
    """Where the lock file cannot be opened or locked (a read-only directory, a file system without flock), numba
    compiles as it would without the lock: one debug line, no error, no retry per kernel."""
    import logging

    lock = kernel_cache.CompileLock(tmp_path / "missing" / kernel_cache.COMPILE_LOCK_NAME)
    with caplog.at_level(logging.DEBUG, logger=kernel_cache.__name__):
        for _ in range(2):
            lock.on_start(None)
            lock.on_start(None)  # nested
            lock.on_end(None)
            lock.on_end(None)
    assert lock.path is None and caplog.text.count("numba compiles unlocked") == 1


def _hold_the_lock(path: Path, ready: Path, released: Path) -> subprocess.Popen:
    """A child process that takes the compile lock `path`, touches `ready`, holds it 1.5 s, then touches `released`
    before it exits (and so lets go)."""
    return subprocess.Popen([sys.executable, "-c", (
        "import fcntl, pathlib, time\n"
        f"lock = open({str(path)!r}, 'a')\n"
        "fcntl.flock(lock, fcntl.LOCK_EX)\n"
        f"pathlib.Path({str(ready)!r}).touch()\n"
        "time.sleep(1.5)\n"
        f"pathlib.Path({str(released)!r}).touch()\n")])
