"""numba's cache of compiled kernels follows changes of *called* kernels in other modules (kernel_cache)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
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
    assert list((package / "__pycache__").glob("caller.*.nbc")), "numba cached the caller"
    _write_package(tmp_path, increment=2)  # only the callee's module changes
    assert _call(tmp_path) == 30  # numba alone would load the caller with the old callee inlined: 20
    stamp = (package / "__pycache__" / kernel_cache.STAMP_NAME).read_text().strip()
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


def test_a_process_compiling_into_the_cache_holds_the_others_until_it_is_done(tmp_path, monkeypatch, caplog):
    """Two processes compiling into numba's cache at once can leave entries that segfault on load (numba #4807:
    two xdist workers on a cold cache). While another process holds the compile lock, a search that must compile
    says so and waits for it: the child writes `released` before it lets go, so the lock's holder here always
    finds it. Compiled meanwhile (here: once released), the waiter does not keep the lock (rev32 K4: N workers
    then waited for N - 1 whole matches). Re-entrant in one thread (warm_kernels runs match_maps inside it)."""
    import logging
    import time

    released = tmp_path / "released"
    compiled = [False]
    monkeypatch.setattr(kernel_cache, "compiled_for_these_sources", lambda package_dir=None: compiled[0])
    monkeypatch.setattr(kernel_cache, "cache_dir", lambda package_dir=None: tmp_path)
    ready = tmp_path / "ready"
    child = _hold_the_lock(tmp_path, ready, released)
    try:
        while not ready.exists() and child.poll() is None:
            time.sleep(0.01)
        assert ready.exists()
        with caplog.at_level(logging.INFO, logger=kernel_cache.__name__), kernel_cache.compile_lock() as holding:
            assert released.exists() and holding
            with kernel_cache.compile_lock() as inner:  # re-entrant: no deadlock on its own lock
                assert not inner
        assert "waiting for another sosmatch process" in caplog.text
    finally:
        child.wait(timeout=60)
    assert child.returncode == 0
    # compiled by the process waited for: the waiter goes on without the lock
    released.unlink()
    ready.unlink()
    child = _hold_the_lock(tmp_path, ready, released)
    try:
        while not ready.exists() and child.poll() is None:
            time.sleep(0.01)
        monkeypatch.setattr(kernel_cache, "compiled_for_these_sources",
                            lambda package_dir=None: compiled[0] or released.exists())
        with kernel_cache.compile_lock() as holding:
            assert released.exists() and not holding
    finally:
        child.wait(timeout=60)


def _hold_the_lock(tmp_path: Path, ready: Path, released: Path) -> subprocess.Popen:
    """A child process that takes the compile lock in `tmp_path`, touches `ready`, holds it a second, then touches
    `released` before it exits (and so lets go)."""
    return subprocess.Popen([sys.executable, "-c", (
        "import fcntl, pathlib, time\n"
        f"lock = open({str(tmp_path / kernel_cache.COMPILE_LOCK_NAME)!r}, 'a')\n"
        "fcntl.flock(lock, fcntl.LOCK_EX)\n"
        f"pathlib.Path({str(ready)!r}).touch()\n"
        "time.sleep(1.0)\n"
        f"pathlib.Path({str(released)!r}).touch()\n")])
