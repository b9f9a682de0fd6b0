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
from .output_entries import check_not_in_output_entry
from .output_markers import VersionedIdentity, check_not_input, read_json_or_none, resolved_path, sha256_file
from .outputs import OVERWRITE_HINT, check_writable_place

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
        ours = (isinstance(entry, dict) and entry.get("command") == self.command and not path.is_symlink()
                and entry.get("sha256") == _sha256_or_none(path))
        if not ours:
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
            with atomic_path(path) as tmp:
                tmp.write_bytes(payload)
            files = registry.get("files") if isinstance(registry.get("files"), dict) else {}
            files[path.name] = {"command": self.command, "identity": self.identity,
                                "sha256": hashlib.sha256(payload).hexdigest()}
            write_text_atomic(path.parent / FILES_REGISTRY,
                              json.dumps({"format": FILES_FORMAT, "files": files}, indent=1, sort_keys=True) + "\n")
        except OSError as exc:
            raise InputError(f"cannot write output: {exc.strerror or exc}", path) from None
        finally:
            os.close(fd)


def _sha256_or_none(path: Path) -> str | None:
    try:
        return sha256_file(path)
    except OSError:
        return None
