"""The map's output directory, taken through the shared output mechanism (`sosmatch.database.outputs`).

Everything is built in SESSION_DIR/.partial (the staging area, which also holds the per-keyframe cache) and
published at the end, run.json last. An unfinished run (killed, or failed on a bad input) is resumed by the
next one whatever its inputs: the cache entries that are still valid are reused, the others recomputed.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ...database.colmap_db import check_database_writable
from ...database.output_markers import VersionedIdentity, read_settings_identity
from ...database.outputs import OutputDir, open_output_dir
from ...database.segmentation_models import SegmentationModels, keyed_by_models
from ...plugin.params import MAP_READS, Params

COMMAND = "map"
RECORD = "run.json"  # written last: the run's record (parameters, fingerprints, counts)
PARTIAL = ".partial"
POSE_CHECK = "pose_check.json"  # the poses against the images (`workflows.pose_check`); absent when disabled
OUTPUTS = ("database.db", "sparse", "landmarks.sosmap", "landmarks.ply", "landmarks.csv", "quality.png", POSE_CHECK)
# the files among them and the record: a user's file at one of their names is refused when the folder is taken
FILES = (*(name for name in OUTPUTS if name != "sparse"), RECORD)


def take_output_dir(out_dir: str | Path, identity: str | VersionedIdentity, inputs: Iterable[Path],
                    overwrite: bool) -> OutputDir:
    """Take SESSION_DIR for this run (see `open_output_dir` for what is refused); also refuses a database that
    another process (e.g. COLMAP's GUI) has locked, before the directory is taken: a refused run leaves a previous
    map complete, as it was."""
    return open_output_dir(out_dir, COMMAND, identity, inputs=inputs, overwrite=overwrite, legacy_record=RECORD,
                           before_taking=lambda path: check_database_writable(path / "database.db"), files=FILES)


def map_identity(inputs: Any, params: Params, text_model: bool, masks: str,
                 models: SegmentationModels | None = None) -> VersionedIdentity:
    """A map's identity: its inputs (`inputs`: their fingerprint, or the identity of the source its poses are made
    from), the parameters a map depends on (`plugin.params.MAP_READS`, `mapping_params`: no setting of matching or
    change detection), the sparse model's format, where the masks come from and the contents of the segmentation
    backend's model files (`models`, `database.segmentation_models.keyed_by_models`: its settings may be empty, the
    environment naming the files, or name a file since replaced). Without model files (`classical`) the identity is
    that of earlier versions; a map an earlier version made with model files is another map (which model made it is
    not known).

    Until fix51 it held every parameter, so a map re-run with another later-stage setting was refused, and a
    later-stage setting registered with a non-neutral default (`plugin.params.identity.ADDED`) refused every
    earlier map (rev24). Such a map is this one when made with the later settings given now, or at their defaults
    (those its version lacked at their neutral values, `settings_at_rest`): those identities, in every earlier
    version, are among its own (`same_as`); a refusal names a registered mapping setting that behaves otherwise
    here, as before (`database.output_markers.read_settings_identity`)."""
    return keyed_by_models(lambda extra: read_settings_identity(
        lambda settings: {"inputs": inputs, "params": settings, "text_model": text_model, "masks": masks, **extra},
        params, MAP_READS), models or SegmentationModels())
