"""Output files of commands that write single files (export, poses-from-exif, check-poses): rule 1 of
`database.outputs` for files. A file is new, or one the same command wrote before and nobody changed since: the
directory's registry `.sosmatch-files.json` lists each with its command, identity and sha256."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from .atomic import atomic_path, write_text_atomic
from .output_checks import OVERWRITE_HINT, check_writable_place
from .output_entries import check_not_in_output_entry
from .output_markers import VersionedIdentity, check_not_input, read_json_or_none, resolved_path, sha256_file

FILES_REGISTRY = ".sosmatch-files.json"
FILES_LOCK = ".sosmatch-files.lock"
FILES_FORMAT = "sosmatch output files v1"


class OutputFiles:
    """Output files of one run of one command (see the module doc, rule 1): checked when made, before any work,
    and again when each is written."""

    def __init__(self, paths: Iterable[str | Path], command: str, identity: str | VersionedIdentity, *,
                 inputs: Iterable[str | Path | None] = (), overwrite: bool = False) -> None:
        self.paths = [Path(p) for p in paths]
        self.command = command
        # a VersionedIdentity: a file an earlier sosmatch wrote of the same inputs and settings is this output
        self.versions = identity if isinstance(identity, VersionedIdentity) else VersionedIdentity(identity)
        self.identity = self.versions.today
        self.inputs = list(inputs)
        self.overwrite = overwrite
        if len({resolved_path(p) for p in self.paths}) != len(self.paths):
            raise InputError("the same file is given for two outputs", self.paths[0])
        for p in self.paths:
            self._check(p, read_json_or_none(p.parent / FILES_REGISTRY) or {})

    def _check(self, path: Path, registry: Mapping[str, Any]) -> None:
        if path.name in (FILES_REGISTRY, FILES_LOCK):  # the run writes them itself: an output there would be lost
            raise InputError(f"output file name {path.name} is the record sosmatch keeps of the files it writes in "
                             "that folder; choose another name", path)
        check_not_input(path, self.inputs)
        check_not_in_output_entry(path)
        if path.is_dir():
            raise InputError("output path is a directory; give a file name", path)
        check_writable_place(path)
        if not (path.exists() or path.is_symlink()):
            return
        entry = (registry.get("files") or {}).get(path.name) if isinstance(registry.get("files"), dict) else None
        entry = None if path.is_symlink() else _matching_record(entry, self.command, _sha256_or_none(path))
        if entry is None:
            raise InputError(f"output file exists and was not written by `sosmatch {self.command}` (or was changed "
                             "since); sosmatch never replaces what it did not create: remove it or choose another "
                             "name", path)
        previous = entry.get("identity")
        if previous != self.identity and previous not in self.versions.same_as and not self.overwrite:
            note = self.versions.refusal_note(previous)
            what = f": {note}" if note else " made from other inputs or settings"
            raise InputError(f"output file holds a `sosmatch {self.command}` output{what}; use {OVERWRITE_HINT} "
                             "to replace it", path)

    def write(self, path: str | Path, data: bytes | str) -> None:
        """Write one of the output files atomically and record it in its directory's registry."""
        path = Path(path)
        if path not in self.paths:
            raise ValueError(f"{path} is not one of this run's output files")
        payload = data.encode("utf-8") if isinstance(data, str) else data
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path.parent / FILES_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise InputError(f"cannot write output: {exc.strerror or exc}", path) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # short: other writers of this directory wait
            registry = read_json_or_none(path.parent / FILES_REGISTRY) or {}
            self._check(path, registry)
            files = registry.get("files") if isinstance(registry.get("files"), dict) else {}
            record = {"command": self.command, "identity": self.identity,
                      "sha256": hashlib.sha256(payload).hexdigest()}
            # The registry must know the new file before it is in place, and keep knowing the old one until it
            # is: a failure at any step (a full disk, a kill) then leaves a file the re-run recognises as its own.
            # So: new bytes to a temporary; the record as "pending" beside the old one; rename; the final record.
            with atomic_path(path) as tmp:
                tmp.write_bytes(payload)
                old = files.get(path.name)
                kept = {k: v for k, v in old.items() if k != "pending"} if isinstance(old, dict) else {}
                _write_registry(path.parent, {**files, path.name: {**kept, "pending": record}})
            files[path.name] = record
            _write_registry(path.parent, files)
        except OSError as exc:
            raise InputError(f"cannot write output: {exc.strerror or exc}", path) from None
        finally:
            os.close(fd)


def _write_registry(folder: Path, files: Mapping[str, Any]) -> None:
    write_text_atomic(folder / FILES_REGISTRY,
                      json.dumps({"format": FILES_FORMAT, "files": files}, indent=1, sort_keys=True) + "\n")


def _matching_record(entry: Any, command: str, sha256: str | None) -> dict[str, Any] | None:
    """The registry record (the entry, or the write it had pending when interrupted) of `command` whose sha256
    is the file's; None when the file is not one `command` wrote."""
    if not isinstance(entry, dict) or sha256 is None:
        return None
    for record in (entry, entry.get("pending")):
        if isinstance(record, dict) and record.get("command") == command and record.get("sha256") == sha256:
            return record
    return None


def _sha256_or_none(path: Path) -> str | None:
    try:
        return sha256_file(path)
    except OSError:
        return None
