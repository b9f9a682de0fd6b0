"""The map's output directory, taken through the shared output mechanism (`sosmatch.database.outputs`).

Everything is built in SESSION_DIR/.partial (the staging area, which also holds the per-keyframe cache) and
published at the end, run.json last. An unfinished run (killed, or failed on a bad input) is resumed by the
next one whatever its inputs: the cache entries that are still valid are reused, the others recomputed.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from ...database.colmap_db import check_database_writable
from ...database.output_markers import VersionedIdentity
from ...database.outputs import OutputDir, open_output_dir

COMMAND = "map"
RECORD = "run.json"  # written last: the run's record (parameters, fingerprints, counts)
PARTIAL = ".partial"
POSE_CHECK = "pose_check.json"  # the poses against the images (`workflows.pose_check`); absent when disabled
OUTPUTS = ("database.db", "sparse", "landmarks.sosmap", "landmarks.ply", "landmarks.csv", "quality.png", POSE_CHECK)


def take_output_dir(out_dir: str | Path, identity: str | VersionedIdentity, inputs: Iterable[Path],
                    overwrite: bool) -> OutputDir:
    """Take SESSION_DIR for this run (see `open_output_dir` for what is refused); also refuses a database that
    another process (e.g. COLMAP's GUI) has locked, before the directory is taken: a refused run leaves a previous
    map complete, as it was."""
    return open_output_dir(out_dir, COMMAND, identity, inputs=inputs, overwrite=overwrite, legacy_record=RECORD,
                           before_taking=lambda path: check_database_writable(path / "database.db"))
