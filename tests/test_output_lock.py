"""An unfinished output is told as being written now (wait) or interrupted (re-run it), from the process its lock
file names: a user who starts `batch` while a `map` is still running is not told to re-run the map, which would
collide with it. A pid alone is no proof (pids are reused), and a process elsewhere cannot be checked from here."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from sosmatch.database.output_lock import lock_record
from sosmatch.database.output_markers import LOCK, MARKER, check_finished, unfinished_run
from sosmatch.plugin.errors import InputError
from sosmatch.workflows.batch import discover_flights

HOLDER = textwrap.dedent("""
    import sys
    from sosmatch.database.outputs import open_output_dir
    with open_output_dir(sys.argv[1], "map", "x"):
        print("held", flush=True)
        sys.stdin.read()
""")


def _refusal(folder: Path) -> str:
    with pytest.raises(InputError) as refused:
        check_finished(folder)
    return str(refused.value)


def _unfinished(folder: Path, lock: str | None) -> Path:
    """`folder` as a `map` run into it leaves it: an incomplete marker, and the lock file `lock` (None: none)."""
    folder.mkdir(parents=True)
    (folder / MARKER).write_text(json.dumps({"format": "sosmatch output v1", "command": "map", "identity": "x",
                                             "complete": False}))
    if lock is not None:
        (folder / LOCK).write_text(lock)
    return folder


def test_a_run_being_written_now_is_told_from_a_killed_one(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    flight = tmp_path / "flights" / "f1"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(flight)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        run = unfinished_run(flight)
        assert run is not None and run.state == "running"
        err = _refusal(flight)
        assert f"has not finished (being written now by pid {holder.pid}): wait for it to finish" in err
        assert "re-run" not in err
        with caplog.at_level(logging.WARNING), pytest.raises(InputError, match="no flights found"):
            discover_flights(tmp_path / "flights")
        assert f"being written now by pid {holder.pid}); not a flight: wait for it to finish, then run batch " \
               "again" in caplog.text
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (flight / LOCK).is_file()  # a killed run leaves its lock file, naming a process that is gone
    err = _refusal(flight)
    assert "has not finished (interrupted; no process writes it any more): re-run the same command" in err
    caplog.clear()
    with caplog.at_level(logging.WARNING), pytest.raises(InputError, match="no flights found"):
        discover_flights(tmp_path / "flights")
    assert "(interrupted; no process writes it any more); not a flight: re-run it" in caplog.text


def test_a_dead_pid_and_a_reused_pid_are_interrupted(tmp_path: Path) -> None:
    made = subprocess.run([sys.executable, "-c", "from sosmatch.database.output_lock import lock_record\n"
                           "print(lock_record('map'), end='')"], capture_output=True, text=True, check=True)
    dead = json.loads(made.stdout)["pid"]
    with pytest.raises(ProcessLookupError):  # the process that wrote it has exited (and was reaped)
        os.kill(dead, 0)
    assert unfinished_run(_unfinished(tmp_path / "dead", made.stdout)).state == "interrupted"  # type: ignore[union-attr]
    # a live process with the pid, started at another time: the pid was reused, the writer is gone
    reused = json.loads(lock_record("map"))
    assert reused["started"] is not None  # Linux: /proc tells the start time
    live = _unfinished(tmp_path / "live", json.dumps(reused))
    assert unfinished_run(live).state == "running"  # type: ignore[union-attr]
    reused["started"] -= 1
    folder = _unfinished(tmp_path / "reused", json.dumps(reused))
    assert unfinished_run(folder).state == "interrupted"  # type: ignore[union-attr]
    assert "interrupted; no process writes it any more" in _refusal(folder)
    # no lock file at all: a run creates it before marking its output unfinished and removes it when it ends
    assert unfinished_run(_unfinished(tmp_path / "nolock", None)).state == "interrupted"  # type: ignore[union-attr]


def test_a_holder_that_cannot_be_checked_from_here_is_interrupted_or_still_running(tmp_path: Path) -> None:
    elsewhere = {**json.loads(lock_record("map")), "host": "another-host"}
    cases = {"other host": json.dumps(elsewhere),
             "other pid namespace": json.dumps({**json.loads(lock_record("map")), "pid_namespace": "pid:[1]"}),
             "older sosmatch": f"sosmatch map (pid {os.getpid()})\n",  # the text before the record named its host
             "unreadable": "\x00\x01 not a record",
             "being written": ""}
    for name, lock in cases.items():
        folder = _unfinished(tmp_path / name.replace(" ", "_"), lock)
        assert unfinished_run(folder).state == "unknown", name  # type: ignore[union-attr]
        err = _refusal(folder)
        assert "has not finished (interrupted, or still running" in err, err
        assert "once it is not running any more, re-run the same command" in err, err
    assert f"still running as sosmatch map (pid {os.getpid()}) on host another-host)" in \
        _refusal(tmp_path / "other_host")


def test_a_copy_made_while_a_run_writes_is_not_taken_for_the_live_run(tmp_path: Path) -> None:
    """The lock file of a directory copied mid-run (cp -a, rsync) names a live process, which writes the
    original: the copy will never finish by waiting. A folder moved while its run writes is still that run's, and
    a second run into the very folder is still refused by the flock."""
    from sosmatch.database.outputs import open_output_dir

    flight = tmp_path / "flights" / "f1"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(flight)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        copy = tmp_path / "copy" / "f1"
        shutil.copytree(flight, copy)
        run = unfinished_run(copy)
        assert run is not None and run.state == "interrupted" and run.copied
        err = _refusal(copy)
        assert f"(copied while sosmatch map (pid {holder.pid}) was writing {flight.resolve()}; its lock file came " \
               "along, but no process writes this copy): re-run the same command" in err, err
        assert "being written now" not in err
        with pytest.raises(InputError, match=f"in use by sosmatch map \\(pid {holder.pid}\\)"):
            with open_output_dir(flight, "map", "x"):  # two runs into one folder still exclude each other
                pass
        moved = tmp_path / "moved"
        flight.parent.rename(moved)  # same inode: the run writes it wherever it is now
        run = unfinished_run(moved / "f1")
        assert run is not None and run.state == "running" and not run.copied
        with open_output_dir(copy, "map", "x"):  # the copy's stale lock does not keep a re-run out
            pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
