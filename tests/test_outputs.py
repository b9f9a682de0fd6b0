"""Nothing lost, ever: the shared output mechanism (`sosmatch.database.outputs`) and every command through it.

Each test is one rule of README "Errors": no command deletes or replaces what it did not create, an output is
never an input, a complete output of other inputs needs --overwrite, an unfinished one never blocks its retry,
one run at a time per output directory, killed runs leave nothing that the next run does not clean.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.atomic import TMP_LOCK, atomic_path, write_text_atomic
from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.database.output_files import OutputFiles
from sosmatch.database.output_markers import MARKER
from sosmatch.database.outputs import open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.processes import descendants, is_alive
from sosmatch.tools.cli import main

SOSMATCH = str(Path(sys.executable).parent / "sosmatch")


def _tree(root: Path) -> dict[str, bytes]:
    """Every file below root with its bytes (what a refused command must leave untouched)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def toy(toy_sessions):
    return toy_sessions.root, toy_sessions.a.path, toy_sessions.b.path, toy_sessions.match


# --- rule 1: never delete or replace what the command did not create -------------------------------------------


def test_export_never_replaces_its_input_or_a_directory(toy, tmp_path, capsys, cli_error):
    root, a, _, _ = toy
    before = _tree(a)
    assert "is also an input" in cli_error("export", "--csv", a, "--out", a)
    assert "inside the input" in cli_error("export", "--csv", a, "--out", a / "landmarks.csv")
    other = tmp_path / "d"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert "is a directory" in cli_error("export", "--ply", a, "--out", other)
    assert _tree(a) == before and _tree(other) == {"keep.txt": b"mine"}


def test_export_replaces_only_its_own_unchanged_files(toy, tmp_path, capsys, cli_error):
    _, a, b, _ = toy
    out = tmp_path / "l.csv"
    out.write_text("somebody else's table\n")
    for extra in ((), ("--overwrite",)):
        assert "not written by `sosmatch export`" in cli_error("export", "--csv", a, "--out", out,
                                                                     *extra)
    assert out.read_text() == "somebody else's table\n"
    out.unlink()
    assert main(["export", "--csv", str(a), "--out", str(out)]) == 0
    first = out.read_bytes()
    assert main(["export", "--csv", str(a), "--out", str(out)]) == 0  # the same export again: replaced freely
    assert out.read_bytes() == first
    capsys.readouterr()
    assert "--overwrite" in cli_error("export", "--csv", b, "--out", out)  # another map
    assert main(["export", "--csv", str(b), "--out", str(out), "--overwrite"]) == 0 and out.read_bytes() != first
    out.write_text(out.read_text() + "# my note\n")  # edited by the user: no longer ours to replace
    assert "changed since" in cli_error("export", "--csv", a, "--out", out, "--overwrite")


def test_merge_never_writes_into_an_input_or_another_commands_output(toy, tmp_path, capsys, cli_error):
    root, a, b, match = toy
    before = _tree(a)
    assert "also an input" in cli_error("merge", a, b, "--match", match, "--out", a)
    assert "inside the input" in cli_error("merge", a, b, "--match", match, "--out", a / "merged")
    mapped = tmp_path / "mapped"
    with open_output_dir(mapped, "map", "some map") as taken:  # a `sosmatch map` session
        write_text_atomic(mapped / "run.json", "{}")
        taken.finish()
    assert "holds a `sosmatch map` output" in cli_error("merge", a, b, "--match", match, "--out",
                                                              mapped, "--overwrite")
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"jpeg")
    assert "never replaces what it did not create" in cli_error("merge", a, b, "--match", match,
                                                                      "--out", foreign, "--overwrite")
    assert _tree(a) == before and _tree(foreign) == {"holiday.jpg": b"jpeg"}
    assert (mapped / "run.json").read_text() == "{}"


def test_a_directory_entry_of_the_other_kind_is_not_replaced(toy, tmp_path, capsys, cli_error):
    _, a, b, match = toy
    out = tmp_path / "M"
    assert main(["merge", str(a), str(b), "--match", str(match), "--out", str(out)]) == 0
    (out / "landmarks.csv").unlink()
    (out / "landmarks.csv").mkdir()  # a user's folder where merge writes a file
    (out / "landmarks.csv" / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert "is a directory where `sosmatch merge` writes a file" in cli_error(
        "merge", a, b, "--match", match, "--out", out)
    assert (out / "landmarks.csv" / "notes.txt").read_text() == "mine"


# --- rule 3: a complete output of other inputs needs --overwrite; the same one is re-made freely ----------------


def test_complete_output_of_other_inputs_needs_overwrite(toy, tmp_path, capsys, cli_error):
    _, a, b, match = toy
    out = tmp_path / "M"
    assert main(["merge", str(a), str(b), "--match", str(match), "--out", str(out)]) == 0
    first = _tree(out)
    assert main(["merge", str(a), str(b), "--match", str(match), "--out", str(out)]) == 0  # same inputs: fine
    capsys.readouterr()
    err = cli_error("merge", a, b, "--match", match, "--out", out, "--set",
                          "association.distance_tolerance_m=3")
    assert "use --overwrite" in err
    assert _tree(out).keys() == first.keys() and (out / "landmarks.sosmap").read_bytes() == first[
        "landmarks.sosmap"]
    assert main(["merge", str(a), str(b), "--match", str(match), "--out", str(out), "--overwrite", "--set",
                 "association.distance_tolerance_m=3"]) == 0


def test_unfinished_output_is_resumed_without_overwrite(tmp_path):
    out = tmp_path / "o"
    with pytest.raises(RuntimeError):
        with open_output_dir(out, "match", "first settings") as taken:
            write_text_atomic(out / "associations.csv", "half\n")
            raise RuntimeError("killed")
    assert json.loads((out / MARKER).read_text())["complete"] is False
    with open_output_dir(out, "match", "other settings") as taken:  # no overwrite needed: nothing was complete
        assert taken.resumed
        taken.finish()
    with pytest.raises(InputError, match=r"use --overwrite \(overwrite=True in Python\)"):  # CLI and Python
        open_output_dir(out, "match", "third settings")


def test_a_run_refused_before_writing_restores_the_marker_it_found(tmp_path):
    """rev31 F3: taking a directory re-writes its marker as the run's, incomplete; a run then refused for a user
    error (`evaluate --overwrite --sweep-floor` above the theta_S its search derives) left an earlier complete
    output called unfinished. `restore_previous` puts back the marker as found: byte for byte, or none."""
    out = tmp_path / "o"
    with open_output_dir(out, "evaluate", "earlier settings") as taken:
        write_text_atomic(out / "evaluation.json", "{}\n")
        taken.finish()
    before = (out / MARKER).read_bytes()
    with pytest.raises(InputError, match="refused"):
        with open_output_dir(out, "evaluate", "other settings", overwrite=True) as taken:
            assert not json.loads((out / MARKER).read_text())["complete"]  # taken: this run's, unfinished
            taken.restore_previous()
            raise InputError("refused")
    assert (out / MARKER).read_bytes() == before and sorted(p.name for p in out.iterdir()) == [MARKER,
                                                                                           "evaluation.json"]
    with open_output_dir(out, "evaluate", "earlier settings") as taken:  # the earlier output, complete as it was
        assert taken.was_complete
    new = tmp_path / "n" / "o"
    with pytest.raises(InputError):
        with open_output_dir(new, "evaluate", "x") as taken:
            taken.restore_previous()  # no marker before: none after, and the new folders go as before
            raise InputError("refused")
    assert not (tmp_path / "n").exists()


def test_a_failed_run_that_wrote_nothing_leaves_nothing(tmp_path):
    out = tmp_path / "a" / "b"
    with pytest.raises(InputError):
        with open_output_dir(out, "match", "x"):
            raise InputError("bad input")
    assert not (tmp_path / "a").exists()


def test_a_failed_run_that_made_only_empty_folders_leaves_nothing(tmp_path):
    out = tmp_path / "a"  # `map --images` of 2 photos left OUT/.partial/poses_work/ and an unfinished marker
    with pytest.raises(InputError):
        with open_output_dir(out, "map", "x") as taken:
            (taken.staging / "poses_work" / "sub").mkdir(parents=True)
            raise InputError("bad input")
    assert not out.exists()
    with pytest.raises(InputError):  # a staging area holding a file (a resumable cache) stays
        with open_output_dir(out, "map", "x") as taken:
            (taken.staging / "work").mkdir(parents=True)
            (taken.staging / "work" / "cache.npz").write_bytes(b"1")
            raise InputError("bad input")
    assert (out / ".partial" / "work" / "cache.npz").is_file()


# --- rule 4: one run at a time ------------------------------------------------------------------------------------

HOLDER = textwrap.dedent("""
    import sys
    from sosmatch.database.outputs import open_output_dir
    with open_output_dir(sys.argv[1], "merge", "x"):
        print("held", flush=True)
        sys.stdin.read()
""")


def test_second_concurrent_run_is_refused_and_a_killed_holder_releases(toy, tmp_path, capsys, cli_error):
    _, a, b, match = toy
    out = tmp_path / "merged"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        err = cli_error("merge", a, b, "--match", match, "--out", out)
        assert f"in use by sosmatch merge (pid {holder.pid})" in err
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert main(["merge", str(a), str(b), "--match", str(match), "--out", str(out)]) == 0  # the kernel released it


# --- rule 5: killed writers' temporaries are cleaned by the next write ------------------------------------------


def test_stale_temporaries_are_cleaned_and_live_ones_kept(tmp_path):
    import fcntl

    target = tmp_path / "x.json"
    stale, live = tmp_path / ".x.json.dead.tmp", tmp_path / ".x.json.live.tmp"
    for d in (stale, live):
        d.mkdir()
        (d / TMP_LOCK).touch()
        (d / "x.json").write_text("half")
    fd = os.open(live / TMP_LOCK, os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a writer still at work
    try:
        foreign = tmp_path / ".x.json.mine.tmp"
        foreign.mkdir()
        (foreign / "data").write_text("not a sosmatch temporary")
        write_text_atomic(target, "{}")
        assert not stale.exists() and live.exists() and (foreign / "data").exists()
    finally:
        os.close(fd)
    with pytest.raises(InputError, match="is a directory"):
        with atomic_path(tmp_path) as tmp:
            tmp.write_text("never over a directory")


def test_killed_synth_leaves_nothing_the_rerun_does_not_clean(tmp_path, monkeypatch):
    monkeypatch.setenv("SOSMATCH_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "s"
    args = [SOSMATCH, "synth", "--out", str(out), "--frames", "40", "--world-size", "240", "--line-length", "60",
            "--width", "160", "--height", "120", "-q"]
    proc = subprocess.Popen(args, env={**os.environ, "SOSMATCH_CACHE_DIR": str(tmp_path / "cache")})
    deadline = time.monotonic() + 120
    while not any((out / ".partial" / "images").glob("*.jpg")) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (out / ".partial").exists()  # killed while rendering
    assert subprocess.run(args, capture_output=True).returncode == 0
    left = [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp") or p.name == ".partial"]
    assert not left, left
    assert (out / "session.json").is_file() and len(list((out / "images").glob("*.jpg"))) == 40


# --- outputs that are files where directories go, or cannot be made (one-line errors) ---------------------------


def test_output_path_that_is_a_file_or_cannot_be_made(toy, tmp_path, capsys, cli_error):
    _, a, b, match = toy
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for out, problem, checked_first in ((blocker, "not a directory", "not a directory"),
                                        (blocker / "sub", "cannot create output directory", "is a file, not a folder")):
        cli_error("match", a, b, "--out", out)
        # merge checks its --out before any work, as changes does (rev45 D4): it names the file in the way
        assert checked_first in cli_error("merge", a, b, "--match", match, "--out", out)
        assert problem in cli_error("synth", "--out", out, "--frames", "2")
        assert problem in cli_error("batch", a.parent, "--out", out)
    assert blocker.read_text() == "x"


def test_output_files_check_everything_before_any_work(tmp_path):
    taken = tmp_path / "cameras.txt"
    taken.write_text("a user's cameras\n")
    with pytest.raises(InputError, match="not written by"):
        OutputFiles([tmp_path / "poses.csv", taken], "poses-from-exif", "id")
    with pytest.raises(InputError, match="same file"):
        OutputFiles([tmp_path / "p.csv", tmp_path / "." / "p.csv"], "export", "id")
    assert not (tmp_path / "poses.csv").exists()


def test_an_output_file_named_as_the_folder_s_registry_of_outputs_is_refused(toy, tmp_path, cli_error):
    """`export --out DIR/.sosmatch-files.json` said it wrote the CSV, which the registry then wrote over; with
    `.sosmatch-files.lock` it blamed the lock it had just made and left the new folder behind (rev45 D3)."""
    _, a, _, _ = toy
    for name in (".sosmatch-files.json", ".sosmatch-files.lock"):
        out = tmp_path / "new" / name
        assert f"output file name {name} is the record sosmatch keeps" in cli_error("export", "--csv", a, "--out",
                                                                                     out)
        assert not (tmp_path / "new").exists()


def test_an_output_file_below_a_file_is_refused_before_any_work(toy, tmp_path, cli_error):
    """`--out afile/x.csv` where `afile` is a file: poses-from-exif did its whole refinement (14 s on 10 Seneca
    frames) and then said "cannot write output: File exists". The place is checked with the file, before any
    work (a read-only file system likewise; not testable as root, whom permission bits do not stop)."""
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    with pytest.raises(InputError, match="is a file, not a folder"):
        OutputFiles([blocker / "sub" / "poses.csv"], "poses-from-exif", "id")
    _, a, _, _ = toy
    assert "is a file, not a folder" in cli_error("export", "--csv", a, "--out", blocker / "x.csv")
    assert blocker.read_text() == "x"


def test_map_output_marker_and_identity(tmp_path):
    lmap = LandmarkMap(np.zeros((3, 3)), np.ones(3))
    out = tmp_path / "o"
    with open_output_dir(out, "export-test", "id1") as taken:
        write_landmark_map(out / "m.sosmap", lmap)
        taken.finish()
    marker = json.loads((out / MARKER).read_text())
    assert marker["command"] == "export-test" and marker["identity"] == "id1" and marker["complete"] is True
    assert not (out / ".sosmatch-output.lock").exists()  # released and removed


# --- killed parents leave no workers ----------------------------------------------------------------------------

POOLS = {
    # the batch's executor (and map --workers, which uses the same `process_pool`)
    "batch executor": textwrap.dedent("""
        import time
        from sosmatch.workflows.executors import LocalExecutor
        ex = LocalExecutor(2)
        pool = ex._get_pool()
        futs = [pool.submit(time.sleep, 600) for _ in range(2)]
        time.sleep(1.0)
        print("ready", flush=True)
        time.sleep(600)
    """),
}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("kind", sorted(POOLS))
def test_workers_die_with_a_killed_parent(kind):
    parent = subprocess.Popen([sys.executable, "-c", POOLS[kind]], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout.readline().strip() == "ready"
        workers = descendants(parent.pid)
        assert len(workers) >= 2  # the workers (and, with spawn, the resource tracker)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.monotonic() + 10
    while any(is_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in workers if is_alive(p)]


def test_check_poses_never_writes_over_an_input_or_a_foreign_file(tmp_path, cli_error):
    """`check-poses --out` was a plain atomic write: `--out S/poses.csv` replaced the pose file it checked."""
    from sosmatch.tools.cli import main

    session = tmp_path / "S"
    assert main(["synth", "--out", str(session), "--frames", "3", "--width", "160", "--height", "120",
                 "--world-size", "200", "-q"]) == 0
    poses = (session / "poses.csv").read_bytes()
    assert "output is also an input" in cli_error("check-poses", "--poses", session, "--out", session / "poses.csv")
    assert "inside the input" in cli_error("check-poses", "--images", session / "images", "--poses",
                                           session / "poses.csv", "--camera", session / "cameras.txt",
                                           "--out", session / "images" / "check.json")
    (tmp_path / "notes.json").write_text("mine")
    assert "not written by `sosmatch check-poses`" in cli_error("check-poses", "--poses", session, "--out",
                                                                tmp_path / "notes.json")
    assert (session / "poses.csv").read_bytes() == poses and (tmp_path / "notes.json").read_text() == "mine"
    assert not (session / "images" / "check.json").exists()


def test_an_optional_output_not_staged_removes_its_earlier_version(tmp_path):
    out = tmp_path / "out"
    with open_output_dir(out, "map", "first") as taken:
        for name in ("data.bin", "picture.png", "run.json"):
            taken.staged(name).write_text(name)
        taken.publish(["data.bin", "picture.png"], last="run.json", optional=["picture.png"])
        taken.finish()
    assert (out / "picture.png").read_text() == "picture.png"
    with open_output_dir(out, "map", "second", overwrite=True) as taken:
        taken.staged("data.bin").write_text("new data")
        taken.staged("run.json").write_text("new record")
        taken.publish(["data.bin", "picture.png"], last="run.json", optional=["picture.png"])
        taken.finish()
    assert not (out / "picture.png").exists() and (out / "data.bin").read_text() == "new data"
    with open_output_dir(out, "map", "third", overwrite=True) as taken:
        taken.staged("run.json").write_text("record")
        with pytest.raises(FileNotFoundError):  # a required output that was not staged is a bug, not skipped
            taken.publish(["data.bin"], last="run.json", optional=["picture.png"])


def test_a_full_disk_mid_run_is_one_line_and_the_run_resumes(tmp_path, capsys):
    """No space left on device while writing (an SD card, a quota): before, a 40-line OSError traceback (map,
    synth, segment, merge; exit 1). Now one line naming the output, exit 2, and the same command finishes once
    there is room. Needs a small tmpfs (root): skipped where one cannot be mounted."""
    import subprocess

    from sosmatch.plugin.geometry import Camera
    from sosmatch.tools.cli import main
    from sosmatch.tools.toy_sessions import render_disc_flight

    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    root = tmp_path / "flight"
    render_disc_flight(root, Camera(160, 120, 120.0, 120.0, 80.0, 60.0), frames=4)
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        assert main(["segment", str(root / "images"), "--out", str(disk / "S")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1] == (f"sosmatch segment: error: {disk / 'S'}: No space left on device: free some space, then "
                           "re-run the same command to resume")
        assert not any("Traceback" in line for line in err)
        subprocess.run(["mount", "-o", "remount,size=8m", str(disk)], check=True)
        assert main(["segment", str(root / "images"), "--out", str(disk / "S")]) == 0
        assert len(list((disk / "S").glob("*.png"))) == 4
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_a_taken_folder_moved_under_its_run_is_said_in_one_line_and_not_re_created(tmp_path):
    """A write that fails because the folder went away (a pool worker's, by path) is reported as the move; no write
    re-creates the old place; a folder the user makes there afterwards, and the lock of a run in it, are not ours."""
    out, moved = tmp_path / "out", tmp_path / "moved"
    with pytest.raises(InputError, match=f"^{out}: was moved or deleted while sosmatch match was writing it "
                                         rf"\(now {moved}\): re-run the same command on its new place"):
        with open_output_dir(out, "match", "x") as taken:
            (taken.staging / "cache").mkdir()
            out.rename(moved)
            (out / ".partial" / "cache" / "e.npz").write_bytes(b"")  # FileNotFoundError: as a worker's write
    assert not out.exists() and sorted(p.name for p in moved.iterdir()) == [".partial", MARKER]
    with open_output_dir(moved, "match", "x") as taken:
        moved.rename(out)
        for write in (lambda: write_text_atomic(moved / ".partial" / "cache" / "e.txt", "x"),
                      lambda: taken.staging, lambda: taken.finish()):
            with pytest.raises(InputError, match="was moved or deleted"):
                write()
        assert not moved.exists()
    with open_output_dir(out, "match", "x") as taken:
        out.rename(moved)
        out.mkdir()  # the user's new folder at the old place, and another run's lock and marker in it
        (out / ".sosmatch-output.lock").write_text("another run")
        (out / MARKER).write_text("another run")
        with pytest.raises(InputError, match="was moved or deleted"):
            with taken:
                raise OSError("any failure")
    assert (out / ".sosmatch-output.lock").read_text() == (out / MARKER).read_text() == "another run"
    assert not (moved / ".sosmatch-output.lock").exists()  # this run's own lock, where it went, released


def test_a_taken_folder_deleted_under_its_run_is_said_and_not_re_created(tmp_path):
    import shutil

    out = tmp_path / "out"
    with pytest.raises(InputError, match="was moved or deleted while sosmatch match was writing it: re-run the same "
                                         r"command on its new place to resume \(or here to start again\)"):
        with open_output_dir(out, "match", "x") as taken:
            (taken.staging / "cache").mkdir()
            shutil.rmtree(out)
            write_text_atomic(out / ".partial" / "cache" / "e.txt", "x")
    assert not out.exists()
    with pytest.raises(KeyboardInterrupt):  # an interrupt stays one (exit 130), moved or not
        with open_output_dir(out, "match", "x"):
            out.rename(tmp_path / "moved")
            raise KeyboardInterrupt


def _check_place_in_worker(path: str) -> str:
    from sosmatch.database.taken import check_place

    check_place(path)
    return "ok"


def test_a_worker_reused_by_a_later_run_does_not_take_its_folder_for_moved(tmp_path):
    """rev25: the taken folders went to worker processes through the environment, read once when the worker
    started; a LocalExecutor reused by a second run (the Python API) kept the first run's folder identity, and
    the second run into a new folder at that path was stopped as "moved". Only the taking process checks now."""
    from sosmatch.workflows.executors import LocalExecutor

    out = tmp_path / "out"
    out.mkdir()
    executor = LocalExecutor(1)
    try:
        with open_output_dir(out, "batch", "first") as taken:
            first = executor.run(_check_place_in_worker, {"a": (str(out / "maps" / "x"),)}, progress=False)
            taken.finish()
        out.rename(tmp_path / "out.old")  # put aside, and a new batch started at the same path
        out.mkdir()
        second = executor.run(_check_place_in_worker, {"a": (str(out / "maps" / "x"),)}, progress=False)
    finally:
        executor.close()
    assert [getattr(r["a"], "value", r["a"]) for r in (first, second)] == ["ok", "ok"]
