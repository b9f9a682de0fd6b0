"""May this run take that output directory? What `database.outputs` checks before anything changes.

What the directory holds for a command (`previous_output`: new, an unfinished or a complete output of it, or
refused as not its own), the refusal of a complete output of another identity unless overwrite
(`refuse_another`, naming the settings its record keeps otherwise: `RecordedSettings`), and the checks a command
makes before its work, changing nothing (`check_output_dir`, `check_writable_place`). The rules are
`database.outputs`'.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from .output_entries import check_file_ours, check_not_in_output_entry, recorded_files
from .output_markers import (
    LOCK,
    MARKER,
    MARKER_FORMAT,
    VersionedIdentity,
    check_not_input,
    output_marker,
    read_json_or_none,
    settings_differences,
)

# how a refusal names the option that replaces another output: the same refusal reaches the command line
# (`--overwrite`) and Python callers of the workflows (`overwrite=True`)
OVERWRITE_HINT = "--overwrite (overwrite=True in Python)"

OURS = {MARKER, LOCK}  # present in a directory that is otherwise empty: still empty


@dataclass(frozen=True)
class RecordedSettings:
    """This run's settings as the command's record (`legacy_record`) keeps them under "params" (`now`), and why
    some of them are what they are (`why`: dotted name -> reason, e.g. a transform the maps chose): the refusal of
    a complete output then names the settings it was made with that differ (`settings_differences`), not only
    "other inputs or settings" (an upgrade whose defaults changed was refused without saying so)."""

    now: dict[str, Any]
    why: dict[str, str] = field(default_factory=dict)
    # settings this run was given and replaced by others (match's tolerances derived from the maps: `now` holds
    # the values used): dotted name -> the value given, and the keys down to where the record keeps the values
    # given by their last name (rev56 D8: a change of a replaced setting was refused without naming it)
    given: dict[str, Any] = field(default_factory=dict)
    given_at: tuple[str, ...] = ()


@dataclass(frozen=True)
class PreviousOutput:
    """What an output directory held when a run took it."""

    state: str  # "new" (absent or empty), "incomplete" (ours, unfinished), "complete" (ours, finished)
    identity: str | None = None  # the identity of the complete output (None: unknown, from an older sosmatch)


def previous_output(path: Path, command: str, legacy_record: str | None) -> PreviousOutput:
    """Classify `path` for `command` without changing anything; InputError when it is not ours to write."""
    if not path.exists():
        return PreviousOutput("new")
    if not path.is_dir():
        raise InputError("output path exists and is not a directory", path)
    marker = read_json_or_none(path / MARKER)
    if marker is None:
        try:
            names = sorted(p.name for p in path.iterdir() if p.name not in OURS)
        except OSError as exc:
            raise InputError(f"cannot read output directory: {exc.strerror or exc}", path) from None
        if not names:
            return PreviousOutput("new")
        if legacy_record is not None:
            record = read_json_or_none(path / legacy_record)
            if record and str(record.get("format", "")).startswith("sosmatch"):
                return PreviousOutput("complete", None)  # written before markers existed: complete, identity unknown
        raise InputError(f"output directory is not empty and is not a `sosmatch {command}` output ({names[0]}, ...);"
                         " sosmatch never replaces what it did not create: choose a new or empty directory", path)
    if marker.get("format") != MARKER_FORMAT or not isinstance(marker.get("command"), str):
        raise InputError(f"unreadable output marker {MARKER}; choose a new or empty directory", path)
    if marker["command"] != command:
        raise InputError(f"output directory holds a `sosmatch {marker['command']}` output; `sosmatch {command}` "
                         "never replaces it: choose a new or empty directory", path)
    if marker.get("complete"):
        return PreviousOutput("complete", marker.get("identity"))
    return PreviousOutput("incomplete", marker.get("identity"))


def refuse_another(path: Path, command: str, previous: Any, versions: VersionedIdentity, same: set[str],
                    overwrite: bool, overwrite_flag: str, settings: RecordedSettings | None = None,
                    record: str | None = None) -> None:
    """InputError when `path` holds a complete output of an identity not in `same`, unless `overwrite`; it names
    the settings `record` (the command's record in `path`) keeps otherwise than `settings` when it can."""
    if previous.state == "complete" and previous.identity not in same and not overwrite:
        # identities of earlier versions' same outputs are in `same_as` (nu36): what is left is another output,
        # or one of a version that behaved otherwise: said, so that nobody hunts for a changed input
        what = versions.refusal_note(previous.identity) or _recorded_difference(path, record, settings) or (
            "an output made from other inputs or settings, or by another version of sosmatch")
        raise InputError(f"output directory holds a complete `sosmatch {command}` output: {what}; use "
                         f"{overwrite_flag} to replace it (or choose another directory)", path)


def _recorded_difference(path: Path, record: str | None, settings: RecordedSettings | None) -> str | None:
    """The settings the record `path/record` keeps otherwise than `settings` (`settings_differences`), else None."""
    if record is None or settings is None:
        return None
    kept = read_json_or_none(path / record) or {}
    given: Any = kept
    for key in settings.given_at:
        given = given.get(key) if isinstance(given, dict) else None
    kept_given = {name: given[name.rsplit(".", 1)[-1]] for name in settings.given
                  if isinstance(given, dict) and name.rsplit(".", 1)[-1] in given}
    return settings_differences(kept.get("params"), settings.now, settings.why,
                                given=(kept_given, settings.given))


def check_output_dir(path: str | Path, command: str, *, inputs: Iterable[str | Path | None] = (),
                     legacy_record: str | None = None, identity: str | VersionedIdentity | None = None,
                     overwrite: bool = False, overwrite_flag: str = OVERWRITE_HINT, files: Iterable[str] = ()) -> None:
    """What `open_output_dir` refuses whatever the run produces, checked before any work and changing nothing:
    an input (or inside one, or holding one), a path that is a file, a non-empty directory that is not this
    command's output, or a new directory that cannot be made (a file or a read-only folder on its way). A command
    whose output identity is known only after its work (`sosmatch changes`) calls this first, so a bad `--out`
    is refused at once; `open_output_dir` still decides (overwrite, the lock) when the work is done. `identity`:
    the output's, when the command can know it before its work: a complete output of another one is refused
    now too (unless `overwrite`), as `open_output_dir` would refuse it after the work; and a file at one of `files`
    (those the command writes there) that it did not write, or that was changed since (`OutputDir.check_files`)."""
    path = Path(path)
    check_not_input(path, list(inputs))
    check_not_in_output_entry(path)
    previous = previous_output(path, command, legacy_record)
    if identity is not None:
        versions = identity if isinstance(identity, VersionedIdentity) else VersionedIdentity(identity)
        refuse_another(path, command, previous, versions, {versions.today, *versions.same_as}, overwrite,
                        overwrite_flag)
    record = recorded_files(output_marker(path))
    for name in files:
        check_file_ours(path / name, command, record)
    if previous.state == "new" and not path.exists():
        check_writable_place(path)


def check_writable_place(path: Path) -> None:
    """The folder that will hold `path` (its nearest existing ancestor, when it is still to be made) is a directory
    this process may write: checked before any work, so that a run of minutes does not end on "cannot write
    output: File exists" (a file where a folder of the path should be) or a read-only file system."""
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"cannot write output: {folder} is a file, not a folder", path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"cannot write output: {folder} is read-only or not writable", path)
