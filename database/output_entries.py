"""What sosmatch wrote inside the directory entries of an output directory (e.g. a session's `sparse/`), so that
replacing an entry removes only that (rule 1 of `database.outputs`).

The output's marker `.sosmatch-output.json` keeps, under "entries", each published directory entry's files (path
relative to the entry, sha256). An entry found holding anything else (a user's README.txt, another command's
output put inside, a file changed since) is not sosmatch's to delete: the run is refused, naming that file."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from .output_markers import STAGING, output_marker, resolved_path, sha256_file


def entry_names(folder: Path) -> list[str]:
    """The relative paths of every file below `folder` (the layout of an entry a run publishes)."""
    # sorted: the marker records them in this order, and its bytes must not depend on the file system (os.walk
    # yields directory order: ext4 and tmpfs differ)
    return sorted((Path(root) / name).relative_to(folder).as_posix() for root, _, names in os.walk(folder)
                  for name in names)


def entry_files(folder: Path) -> dict[str, str]:
    """relative path -> sha256 of every file below `folder` (what a run publishes there)."""
    return {rel: sha256_file(folder / rel) for rel in entry_names(folder)}


# The files an older sosmatch (before entries were recorded) wrote in its directory entries: its COLMAP models in
# sparse/ (binary or text) and a synthetic session's frames in images/ and labels/. A re-run that writes another
# layout (`map --text` over a binary model, `synth` of fewer frames) replaces them; anything else stays foreign.
LEGACY_NAMES = {
    "sparse": re.compile(r"(cameras|images|points3D|rigs|frames)\.(bin|txt)"),
    "images": re.compile(r"frame_\d+\.(jpg|jpeg|png|tif|tiff)"),
    "labels": re.compile(r"frame_\d+\.png"),
}


def _hashes(value: Any) -> list[str] | None:
    """A recorded file's accepted sha256 values: one, or two while a run swaps the entry (None: malformed)."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return list(value)
    return None


def recorded_entries(marker: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """The marker's record of its directory entries ({} when absent or malformed: an older sosmatch wrote it)."""
    entries = (marker or {}).get("entries")
    if not isinstance(entries, dict):
        return {}
    return {name: dict(files) for name, files in entries.items()
            if isinstance(name, str) and isinstance(files, dict)
            and all(isinstance(k, str) and _hashes(v) is not None for k, v in files.items())}


def merge_entry_records(old: Mapping[str, Any], new: Mapping[str, str]) -> dict[str, Any]:
    """The record of an entry while a run swaps it: every file of the old and of the new entry, with both hashes
    where a name is in both. A run killed between this record and the swap leaves the old files, which must still
    be ours (review rev19: with the new hash alone, every later run refused `sparse/images.bin` as changed)."""
    merged: dict[str, Any] = {}
    for rel in sorted(set(old) | set(new)):
        hashes = (_hashes(old[rel]) or []) if rel in old else []
        if rel in new and new[rel] not in hashes:
            hashes.append(new[rel])
        merged[rel] = hashes[0] if len(hashes) == 1 else hashes
    return merged


def check_entry_ours(entry: Path, command: str, record: Mapping[str, str] | None,
                     layout: set[str] | None = None) -> None:
    """InputError naming the first file in directory `entry` that sosmatch did not write there: one missing from
    `record` or changed since (sha256). Without a record (an entry an older sosmatch wrote, before entries were
    recorded), a file is taken as ours when the new entry has one at the same place (`layout`) or it bears the
    name an older sosmatch gave its files there (`LEGACY_NAMES`): those are replaced, anything beside them is not."""
    try:
        for root, dirs, names in os.walk(entry, onerror=_raise):
            for name in sorted(names) + sorted(d for d in dirs if os.path.islink(os.path.join(root, d))):
                p = Path(root) / name
                rel = p.relative_to(entry).as_posix()
                if record is not None:
                    ours = rel in record and not p.is_symlink() and sha256_file(p) in (_hashes(record[rel]) or [])
                    changed = rel in record
                else:
                    legacy = LEGACY_NAMES.get(entry.name)
                    ours = not p.is_symlink() and ((layout is not None and rel in layout)
                                                   or (legacy is not None and legacy.fullmatch(rel) is not None))
                    changed = False
                if not ours:
                    why = (f"was changed since `sosmatch {command}` wrote it" if changed else
                           f"was not written by `sosmatch {command}`")
                    raise InputError(f"{why}, and a run replaces {entry.name}/ with all it holds; sosmatch never "
                                     f"deletes what it did not create: move it out of {entry} (or choose another "
                                     "output directory)", p)
    except OSError as exc:
        raise InputError(f"cannot read output directory: {exc.strerror or exc}", entry) from None


def check_not_in_output_entry(output: str | Path) -> None:
    """Refuse an output inside a directory entry of another sosmatch output (e.g. OUT/sparse/ of a session) or its
    staging area: a run of that output replaces the entry, and would then refuse because of this one."""
    out = resolved_path(output)
    for folder in out.parents:
        marker = output_marker(folder)
        if marker is None:
            continue
        inner = out.relative_to(folder).parts[0]
        if inner == STAGING or inner in recorded_entries(marker):
            raise InputError(f"output is inside {folder / inner}, which a `sosmatch {marker.get('command')}` run "
                             "replaces; write it elsewhere", output)


def _raise(exc: OSError) -> None:
    raise exc
