"""What sosmatch wrote in an output directory: inside its directory entries (e.g. a session's `sparse/`) and as its
files (match.json), so that replacing one replaces only that (rule 1 of `database.outputs`).

The output's marker `.sosmatch-output.json` keeps, under "entries", each published directory entry's files (path
relative to the entry, sha256), and under "files" each file the command wrote at the top of the directory (name ->
sha256; two while a run replaces it). An entry found holding anything else (a user's README.txt, another command's
output put inside, a file changed since), or a file at a name the command writes that it did not write there (an
optional output an earlier run skipped, then the user's) or that was changed since, is not sosmatch's to replace
or delete: the run is refused, naming that file. A marker without "files" (an older sosmatch's) is read as before
files were recorded: see `recorded_files`."""

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


def recorded_files(marker: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The marker's record of the files the command wrote at the top of its directory (name -> sha256, or a list of
    two while a run replaces one), {} for a malformed one; None when the marker keeps none (an older sosmatch wrote
    it, or there is no marker: an output made before markers existed), see `check_file_ours`."""
    files = (marker or {}).get("files")
    if files is None:
        return None
    if not isinstance(files, dict):
        return {}
    return {name: value for name, value in files.items() if isinstance(name, str) and _hashes(value) is not None}


def check_file_ours(path: Path, command: str, record: Mapping[str, Any] | None) -> None:
    """InputError naming `path`, a name at the top of an output directory that the command writes or removes, when
    something stands there that the command did not write (not in `record`, a link or a directory: sosmatch
    writes neither there) or that was changed since (sha256). `record` None (an older sosmatch's marker, which
    recorded no files): whatever file stands there is taken as ours, as that sosmatch took it: its files are not
    told from a user's, and refusing them would refuse every re-run of every output made before the upgrade;
    the run then records them (`database.outputs.open_output_dir`), and from there on they are told apart."""
    if not (path.exists() or path.is_symlink()):
        return
    if path.is_dir() and not path.is_symlink():
        return  # of the other kind: `OutputDir._check_kind` names it as such
    if record is None and not path.is_symlink():
        return
    recorded = record is not None and path.name in record and not path.is_symlink()
    try:
        ours = recorded and sha256_file(path) in (_hashes(record[path.name]) or [])
    except OSError as exc:
        raise InputError(f"cannot read output file: {exc.strerror or exc}", path) from None
    if not ours:
        why = (f"was changed since `sosmatch {command}` wrote it" if recorded else
               f"was not written by `sosmatch {command}`")
        raise InputError(f"{why}, and a run of it replaces or removes {path.name}; sosmatch never replaces what it "
                         f"did not create: move it out of {path.parent} (or choose another output directory)", path)


def adopted_files(folder: Path) -> dict[str, str]:
    """name -> sha256 of every file at the top of `folder` (hidden ones, the marker's and the lock's, left out): an
    output an older sosmatch made, whose files are taken as ours as that sosmatch took them (`check_file_ours`)."""
    try:
        names = sorted(p.name for p in folder.iterdir()
                       if not p.name.startswith(".") and p.is_file() and not p.is_symlink())
        return {name: sha256_file(folder / name) for name in names}
    except OSError as exc:
        raise InputError(f"cannot read output directory: {exc.strerror or exc}", folder) from None


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
