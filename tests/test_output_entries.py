"""Rule 1 of `sosmatch.database.outputs` inside an output's directory entries (a session's sparse/): replacing
one removes only what sosmatch wrote there; a refused run leaves a previous output complete, as it was."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from sosmatch.database.atomic import write_text_atomic
from sosmatch.database.outputs import MARKER, open_output_dir
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
        sqlite3.connect(out / "database.db").close()
        write_text_atomic(out / "run.json", "{}")
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
