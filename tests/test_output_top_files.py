"""Rule 1 of `sosmatch.database.outputs` for the files at the top of an output directory (match.json, a merge's
landmarks.csv): a re-run, also with --overwrite, replaces or removes only what the command wrote there and nobody
changed since (the marker's "files"); a user's file at such a name refuses it in one line, nothing changed."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from sosmatch.database.output_markers import MARKER
from sosmatch.database.outputs import open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main


def _tree(root: Path) -> dict[str, bytes]:
    """Every file below root with its bytes, and every folder (a refused run changes neither)."""
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else b"<dir>" for p in sorted(root.rglob("*"))}


def _publish(out: Path, identity: str, files: dict[str, str], optional: tuple[str, ...] = ("picture.png",)) -> None:
    with open_output_dir(out, "map", identity, overwrite=True) as taken:
        for name, text in files.items():
            taken.staged(name).write_text(text)
        taken.publish(["data.bin", *optional], last="run.json", optional=optional)
        taken.finish()


def test_a_users_file_where_an_optional_output_was_skipped_is_neither_replaced_nor_removed(tmp_path):
    """(a) the earlier run skipped the optional picture.png; the user's picture.png put there since is not sosmatch's:
    a run that makes the picture, one that skips it again (which removes an earlier run's), and a run that names it
    when taking the folder are all refused, naming it, and nothing in the folder changes."""
    out = tmp_path / "out"
    _publish(out, "first", {"data.bin": "data", "run.json": "record"})
    (out / "picture.png").write_text("the user's picture")
    before = _tree(out)
    with pytest.raises(InputError, match="not written by `sosmatch map`"):
        open_output_dir(out, "map", "second", overwrite=True, files=["data.bin", "picture.png", "run.json"])
    assert _tree(out) == before
    for files in ({"data.bin": "new", "picture.png": "new picture", "run.json": "new"},
                  {"data.bin": "new", "run.json": "new"}):
        with pytest.raises(InputError, match="not written by `sosmatch map`") as err:
            _publish(out, "second", files)
        # (beside the run's own staging area, which it keeps for its retry, as a run refused for another cause)
        left = {k: v for k, v in _tree(out).items() if not k.startswith(".partial")}
        assert err.value.path == out / "picture.png" and left == before
    (out / "picture.png").unlink()  # moved away: the run goes on
    _publish(out, "second", {"data.bin": "new", "picture.png": "new picture", "run.json": "new"})
    assert (out / "picture.png").read_text() == "new picture"


def test_a_file_sosmatch_wrote_and_the_user_replaced_is_refused_and_kept(toy_sessions, tmp_path, capsys, cli_error):
    """(b) the user's own landmarks.csv where `sosmatch merge` wrote one: refused, not kept as a backup (a backup is
    a name the user did not choose, and beside it the output would stand as complete with the user's edit lost
    from sight), by the same merge and under --overwrite alike; the same bytes again are ours (a copy back)."""
    a, b, match = toy_sessions.a.path, toy_sessions.b.path, toy_sessions.match
    out = tmp_path / "M"
    argv = ["merge", a, b, "--match", match, "--out", out]
    assert main([str(x) for x in argv]) == 0
    ours = (out / "landmarks.csv").read_bytes()
    (out / "landmarks.csv").write_text("my own landmarks\n")
    before = _tree(out)
    for extra in ((), ("--overwrite", "--set", "association.distance_tolerance_m=3")):
        err = cli_error(*argv, *extra)
        assert "landmarks.csv: was changed since `sosmatch merge` wrote it" in err and "move it out of" in err
        assert _tree(out) == before
    (out / "landmarks.csv").write_bytes(ours)
    capsys.readouterr()
    assert main([str(x) for x in argv]) == 0


def test_a_users_folder_at_a_name_sosmatch_writes_a_file_is_refused_before_anything_changes(tmp_path):
    """(c) a folder where the command writes (or removes) a file: refused when the folder is taken, and by
    `write_file`, nothing changed."""
    out = tmp_path / "out"
    with open_output_dir(out, "segment", "first") as taken:
        taken.write_file("summary.csv", "a\n")
        taken.finish()
    (out / "x.jpg.json").mkdir()
    (out / "x.jpg.json" / "mine.txt").write_text("mine")
    before = _tree(out)
    with pytest.raises(InputError, match="is a directory where `sosmatch segment` writes a file"):
        open_output_dir(out, "segment", "first", files=["summary.csv", "x.jpg.json"])
    assert _tree(out) == before
    with open_output_dir(out, "segment", "first") as taken:
        with pytest.raises(InputError, match="is a directory where `sosmatch segment` writes a file"):
            taken.write_file("x.jpg.json", "{}\n")
    assert _tree(out) == before


def test_an_older_sosmatchs_output_is_re_made_as_before_and_recorded_from_then_on(tmp_path):
    """A marker without "files" (an older sosmatch's) records none: its files are taken as ours, as that sosmatch
    took them (else no output made before the upgrade could be re-made), and recorded by the run, so that a file
    the user puts there after is told apart."""
    out = tmp_path / "out"
    _publish(out, "first", {"data.bin": "data", "picture.png": "picture", "run.json": "record"})
    marker = json.loads((out / MARKER).read_text())
    del marker["files"]
    (out / MARKER).write_text(json.dumps(marker))
    (out / "data.bin").write_text("data the older run wrote, then changed: not told apart")
    with open_output_dir(out, "map", "first", files=["data.bin", "picture.png", "run.json"]) as taken:
        assert taken.was_complete
    recorded = json.loads((out / MARKER).read_text())["files"]
    assert sorted(recorded) == ["data.bin", "picture.png", "run.json"]
    _publish(out, "second", {"data.bin": "new", "run.json": "new"})  # replaced and removed, as before
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "data.bin", "run.json"]
    (out / "picture.png").write_text("the user's, after the upgrade")
    with pytest.raises(InputError, match="not written by"):
        _publish(out, "third", {"data.bin": "3", "run.json": "3"})


def test_a_run_killed_between_recording_and_renaming_its_files_resumes(tmp_path, monkeypatch):
    """The marker records a file's new hash beside the old before the rename: whichever bytes a killed run left,
    its next run finds them ours."""
    out = tmp_path / "out"
    _publish(out, "first", {"data.bin": "data", "run.json": "record"}, optional=())
    real = os.replace

    def killed(src, dst, *args, **kwargs):
        if Path(dst).name == "run.json":
            raise KeyboardInterrupt
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        _publish(out, "second", {"data.bin": "new data", "run.json": "new record"}, optional=())
    monkeypatch.setattr(os, "replace", real)
    assert (out / "data.bin").read_text() == "new data" and not (out / "run.json").exists()
    _publish(out, "second", {"data.bin": "new data", "run.json": "new record"}, optional=())
    assert (out / "run.json").read_text() == "new record"
    assert all(isinstance(h, str) for h in json.loads((out / MARKER).read_text())["files"].values())


def test_changes_refuses_a_users_file_where_it_wrote_no_geojson_before_its_work(toy_sessions, tmp_path, capsys,
                                                                              cli_error):
    """(a) by the command line: the toy maps are not georeferenced, so `changes` writes no changes.geojson, and a
    re-run removes one an earlier run left; the user's changes.geojson is neither removed (--no-plot, --overwrite)
    nor kept beside a new run's tables, and the refusal comes before the comparison, nothing changed."""
    a, b, match = toy_sessions.a.path, toy_sessions.b.path, toy_sessions.match
    out = tmp_path / "C"
    argv = ["changes", a, b, "--match", match, "--out", out]
    assert main([str(x) for x in argv]) == 0 and not (out / "changes.geojson").exists()
    (out / "changes.geojson").write_text('{"type": "FeatureCollection", "features": []}\n')
    before = _tree(out)
    for extra in ((), ("--overwrite", "--no-plot")):
        assert "changes.geojson: was not written by `sosmatch changes`" in cli_error(*argv, *extra)
        assert _tree(out) == before
