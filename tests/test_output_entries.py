"""Rule 1 of `sosmatch.database.outputs` inside an output's directory entries (a session's sparse/): replacing
one removes only what sosmatch wrote there; a refused run leaves a previous output complete, as it was."""

from __future__ import annotations

import sqlite3

import pytest

from sosmatch.database.atomic import write_text_atomic
from sosmatch.database.outputs import MARKER, open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.workflows.map.output_dir import take_output_dir


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
