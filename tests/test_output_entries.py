"""Rule 1 of `sosmatch.database.outputs` inside an output's directory entries (a session's sparse/): replacing
one removes only what sosmatch wrote there; a refused run leaves a previous output complete, as it was."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from sosmatch.database.atomic import write_text_atomic
from sosmatch.database.output_markers import MARKER, sha256_file
from sosmatch.database.outputs import open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main
from sosmatch.workflows.map.output_dir import take_output_dir


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def merged(toy_sessions, tmp_path, capsys):
    """A complete `sosmatch merge` output (it publishes a sparse/ directory) and the argv that re-makes it."""
    a, b, match = toy_sessions.a.path, toy_sessions.b.path, toy_sessions.match
    out = tmp_path / "M"
    argv = ["merge", str(a), str(b), "--match", str(match), "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    return out, [*argv, "--overwrite", "--set", "association.distance_tolerance_m=3"]


def test_overwrite_never_deletes_a_users_file_inside_a_directory_entry(merged, cli_error):
    out, other = merged
    (out / "sparse" / "README.txt").write_text("notes")  # the user's, inside sosmatch's sparse/
    before = _tree(out)
    err = cli_error(*other)
    assert "README.txt" in err and "not written by `sosmatch merge`" in err
    assert _tree(out) == before  # refused before anything changed: the marker still says complete
    (out / "sparse" / "README.txt").unlink()
    model = next((out / "sparse").rglob("*.bin"))
    model.write_bytes(model.read_bytes() + b"edited")  # changed since sosmatch wrote it: not ours to delete either
    assert "changed since" in cli_error(*other)
    assert model.read_bytes().endswith(b"edited")


def test_an_entry_written_before_entries_were_recorded_is_replaced_only_when_it_holds_sosmatchs_files(
        merged, cli_error):
    out, other = merged
    marker = json.loads((out / MARKER).read_text())
    marker.pop("entries", None)  # as an older sosmatch wrote it
    (out / MARKER).write_text(json.dumps(marker))
    (out / "sparse" / "README.txt").write_text("notes")
    def kept():  # all but the marker (rewritten) and the staging area (the run's work, kept for its retry)
        return {k: v for k, v in _tree(out).items() if k != MARKER and not k.startswith(".partial")}

    before = kept()
    assert "README.txt" in cli_error(*other)  # checked when publishing, against the new sparse/'s files
    assert kept() == before  # its record (merge.json) too
    after = json.loads((out / MARKER).read_text())
    assert after["complete"] is True and after["identity"] == marker["identity"]  # the previous output stands
    (out / "sparse" / "README.txt").unlink()
    assert main(other) == 0  # only sosmatch's files there: replaced
    assert "sparse" in json.loads((out / MARKER).read_text())["entries"]


def test_an_output_inside_another_outputs_directory_entry_is_refused(merged, toy_sessions, cli_error, tmp_path):
    out, other = merged
    with pytest.raises(InputError, match="which a `sosmatch merge` run replaces"):
        open_output_dir(out / "sparse" / "m", "match", "x")
    assert "which a `sosmatch merge` run replaces" in cli_error(
        "export", "--csv", toy_sessions.a.path, "--out", out / "sparse" / "a.csv")
    assert not (out / "sparse" / "m").exists() and not (out / "sparse" / "a.csv").exists()
    assert main(other) == 0


def test_a_map_refused_for_a_locked_database_leaves_the_previous_map_complete(tmp_path):
    out = tmp_path / "MB"
    with open_output_dir(out, "map", "old map") as taken:
        sqlite3.connect(taken.staged("database.db")).close()
        write_text_atomic(taken.staged("run.json"), "{}")
        taken.publish(["database.db"], last="run.json")  # (recorded as the map's: what the new map replaces)
        taken.finish()
    before = (out / MARKER).read_text()
    holder = sqlite3.connect(out / "database.db", isolation_level=None)  # e.g. COLMAP's GUI
    holder.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(InputError, match="locked"):
            take_output_dir(out, "new map", [], overwrite=True)
    finally:
        holder.close()
    assert (out / MARKER).read_text() == before


def test_a_run_killed_between_recording_and_swapping_an_entry_resumes(merged, monkeypatch, capsys):
    """Review rev19: the record written before the swap kept only the new hash of a file in both entries, so a run
    killed before the swap left sparse/'s old files "changed since" and every later run was refused."""
    import sosmatch.database.outputs as outputs

    out, other = merged

    class Killed(BaseException):
        pass

    real = outputs.locked_temp_dir

    def kill_at_swap(path, *args, **kwargs):
        if path.name == "sparse":
            raise Killed  # after the marker recorded old + new files, before the old sparse/ moved
        return real(path, *args, **kwargs)

    # the old model differs from the one the run writes (as after a change of settings), and is on record
    marker = json.loads((out / MARKER).read_text())
    (out / "sparse" / "points3D.bin").write_bytes((out / "sparse" / "points3D.bin").read_bytes() + b"old")
    marker["entries"]["sparse"]["points3D.bin"] = sha256_file(out / "sparse" / "points3D.bin")
    (out / MARKER).write_text(json.dumps(marker))
    monkeypatch.setattr(outputs, "locked_temp_dir", kill_at_swap)
    with pytest.raises(Killed):
        main(other)
    monkeypatch.setattr(outputs, "locked_temp_dir", real)
    recorded = json.loads((out / MARKER).read_text())["entries"]["sparse"]
    assert isinstance(recorded["points3D.bin"], list) and len(recorded["points3D.bin"]) == 2  # both, while swapping
    capsys.readouterr()
    assert main(other) == 0  # resumed, not refused
    assert all(isinstance(v, str) for v in json.loads((out / MARKER).read_text())["entries"]["sparse"].values())


def test_an_older_outputs_entry_of_another_layout_is_ours_by_its_names(tmp_path):
    """Review rev19: an entry written before entries were recorded was judged by the new entry's layout only, so
    `map --text` over a binary model (or `synth` of fewer frames) was refused after all its work."""
    from sosmatch.database.output_entries import check_entry_ours

    sparse = tmp_path / "sparse"
    sparse.mkdir()
    for name in ("cameras.bin", "images.bin", "points3D.bin", "rigs.bin", "frames.bin"):
        (sparse / name).write_bytes(b"x")
    check_entry_ours(sparse, "map", None, {"cameras.txt", "images.txt", "points3D.txt"})
    (sparse / "README.txt").write_text("notes")
    with pytest.raises(InputError, match="not written by `sosmatch map`"):
        check_entry_ours(sparse, "map", None, {"cameras.txt", "images.txt", "points3D.txt"})
    images = tmp_path / "images"
    images.mkdir()
    (images / "frame_00023.jpg").write_bytes(b"x")
    check_entry_ours(images, "synth", None, {"frame_00000.jpg"})


def test_an_entry_s_files_are_recorded_in_an_order_of_their_names_not_of_the_file_system(tmp_path):
    """The marker's record of an entry lists its files in os.walk order, which is the file system's (tmpfs: newest
    first, ext4: by hash): a project re-made on another disk had other marker bytes (nu56 D7)."""
    from sosmatch.database.output_entries import entry_files

    names = [f"{c}{i}.bin" for i in range(12) for c in "zam"] + ["sub/b.txt", "sub/a.txt", "a/z.txt"]
    for name in names:  # created in an order that is not a sorted one
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_bytes(name.encode())
    assert list(entry_files(tmp_path)) == sorted(names)


@pytest.mark.parametrize("obstacle", ["landmarks.csv", "sparse"])
def test_an_entry_of_the_other_kind_is_refused_before_anything_is_published(merged, cli_error, obstacle):
    """fix149: a user's directory where the run writes a file (landmarks.csv) was refused only after sparse/ and
    landmarks.sosmap had been swapped in (and merge.json removed); likewise a file where it writes a directory.
    Every target is now checked before the first rename: the folder is as it was, and a re-run once the user
    moved the obstacle away publishes."""
    out, other = merged
    target = out / obstacle
    kept = target.with_name(obstacle + ".kept")
    target.rename(kept)  # sosmatch's own, moved aside by the user
    if obstacle == "sparse":
        target.write_text("the user's notes")  # a file where merge writes a directory
    else:
        target.mkdir()  # a directory where merge writes a file
        (target / "notes.txt").write_text("the user's notes")

    def everything():  # every file's bytes but the staging area (the run's work, kept for its retry)
        return {k: v for k, v in _tree(out).items() if not k.startswith(".partial")}

    before = everything()
    err = cli_error(*other)
    assert obstacle in err and "where `sosmatch merge` writes" in err
    assert everything() == before  # nothing swapped in, merge.json still there, the marker as it was
    assert json.loads((out / MARKER).read_text())["complete"] is True
    if target.is_dir():
        target.joinpath("notes.txt").unlink()
        target.rmdir()
    else:
        target.unlink()
    assert main(other) == 0
    assert (out / obstacle).exists() and (out / "merge.json").is_file()
    assert json.loads((out / MARKER).read_text())["complete"] is True


def test_an_interrupted_publish_refused_for_an_obstacle_still_resumes(merged, monkeypatch, cli_error, capsys):
    """A run killed while it publishes (marker incomplete, sparse/ new, merge.json gone) then refused for a user's
    directory where landmarks.csv goes leaves the half-published folder as it was; once the directory is moved
    away the same command finishes it."""
    from sosmatch.database.outputs import OutputDir

    out, other = merged

    class Killed(BaseException):
        pass

    real = OutputDir._replace_entry

    def kill_at_second(self, src, name, checked=False):
        if name == "landmarks.sosmap":
            raise Killed
        return real(self, src, name, checked)

    monkeypatch.setattr(OutputDir, "_replace_entry", kill_at_second)
    with pytest.raises(Killed):
        main(other)
    monkeypatch.setattr(OutputDir, "_replace_entry", real)
    capsys.readouterr()
    assert json.loads((out / MARKER).read_text())["complete"] is False and not (out / "merge.json").exists()
    (out / "landmarks.csv").unlink()
    (out / "landmarks.csv").mkdir()
    (out / "landmarks.csv" / "notes.txt").write_text("the user's")
    before = {k: v for k, v in _tree(out).items() if not k.startswith(".partial")}
    assert "landmarks.csv" in cli_error(*other)
    assert {k: v for k, v in _tree(out).items() if not k.startswith(".partial")} == before
    (out / "landmarks.csv" / "notes.txt").unlink()
    (out / "landmarks.csv").rmdir()
    assert main(other) == 0
    assert json.loads((out / MARKER).read_text())["complete"] is True and (out / "merge.json").is_file()
