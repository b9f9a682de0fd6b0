"""What a sosmatch output directory is, as every reader and writer of one sees it (`database.outputs` takes and
writes them; its module doc has the rules).

An output directory holds the marker `.sosmatch-output.json` (format `MARKER_FORMAT`: the command, the output's
identity, whether the run finished, the files of its directory entries ("entries": entry -> path -> sha256) and
the files it wrote at the top ("files": name -> sha256, a list of two while a run replaces one)), written by the
command that took it. "files" came later within the same format: a marker without it (an older sosmatch's) is
read as recording none, whose files are then taken as ours (`output_entries.recorded_files`); an older sosmatch
ignores it (and re-writes the marker without it: then read so again).
Here: the marker's names and reading (`output_marker`, `output_command`, `unfinished_run`: with the lock file,
`database.output_lock`, whether it is being written now or was interrupted), the check every reader of a
sosmatch output makes before using it (`check_finished`, `check_input_finished`: a run into it that has not
finished may leave an earlier run's files beside its own), the identities (`fingerprint` of the inputs and
settings, `sha256_file`) and how outputs and inputs may lie (`resolved_path`, `check_not_input`). Nothing here
writes.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from .output_lock import LockHolder, holder_state, read_lock_holder
from .text_input import read_user_json

MARKER = ".sosmatch-output.json"
LOCK = ".sosmatch-output.lock"
STAGING = ".partial"
MARKER_FORMAT = "sosmatch output v1"


def fingerprint(obj: Any) -> str:
    """sha256 of the canonical JSON of `obj` (keys sorted; other objects by str): an output's identity."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


@dataclass(frozen=True)
class VersionedIdentity:
    """An output's identity (`today`), the identities earlier sosmatch versions gave the same output (`same_as`),
    and those they gave it with today's settings where some behave otherwise in them (`otherwise`: identity ->
    what a refusal says of such an output, `plugin.params.identity.otherwise_note`)."""

    today: str
    same_as: tuple[str, ...] = ()
    otherwise: tuple[tuple[str, str], ...] = ()

    def refusal_note(self, previous: str | None) -> str:
        """What the refusal of the output `previous` (its identity) adds: "" unless an earlier version made it."""
        return dict(self.otherwise).get(previous or "", "")

    def accepting(self, earlier: VersionedIdentity) -> VersionedIdentity:
        """This identity, also taking the output that `earlier` (the same inputs named as an earlier sosmatch
        named them, e.g. by their paths) identifies, in any of its versions, as this one."""
        same = tuple(i for i in (*self.same_as, earlier.today, *earlier.same_as) if i != self.today)
        return VersionedIdentity(self.today, same, (*self.otherwise, *earlier.otherwise))


def versioned_identity(build: Callable[[Callable[[Any], dict[str, Any]]], Any],
                       digest: Callable[[Any], str] = fingerprint) -> VersionedIdentity:
    """The identity of `build(as_dict)` (its Params and sections given as `as_dict(section)`), today's and
    earlier versions' (`plugin.params.identity_versions`), each as `digest` (default `fingerprint`)."""
    from ..plugin.params.identity import identity_versions

    v = identity_versions(build)
    return VersionedIdentity(digest(v.today), tuple(digest(o) for o in v.earlier),
                             tuple((digest(o), note) for o, note in v.otherwise))


def read_settings_identity(envelope: Callable[[dict[str, Any]], Any], params: Any,
                           read: tuple[str, ...]) -> VersionedIdentity:
    """The identity `envelope(settings)` of an output of a command that reads only the settings `read` of `params`
    (`settings`: those settings' identity dict, `plugin.params.read_params`), so that a setting it does not read
    neither refuses nor changes its outputs. Also taken as this output: one the command made while its identity
    held every setting (`envelope(every setting's dict)`), made with `params` as given, or with the settings it
    does not read at their defaults, those registered later at the neutral values of the versions before them
    (`plugin.params.identity.settings_at_rest`), in any version. A refusal's note (of an output made with other
    behaviour of a registered setting) is kept only for an identity no such form accepts: else it could name a
    setting the command does not read."""
    from ..plugin.params import read_params
    from ..plugin.params.identity import settings_at_rest

    def build(as_settings: Callable[[Callable[[Any], dict[str, Any]]], dict[str, Any]]) -> Callable:
        return lambda as_dict: envelope(as_settings(as_dict))

    identity = versioned_identity(build(lambda as_dict: read_params(params, read, as_dict)))
    for form in [*settings_at_rest(params, read), params]:
        identity = identity.accepting(versioned_identity(build(lambda as_dict, form=form: as_dict(form))))
    same = tuple(dict.fromkeys(i for i in identity.same_as if i != identity.today))
    notes = tuple((i, note) for i, note in identity.otherwise if i not in same and i != identity.today)
    return VersionedIdentity(identity.today, same, notes)


def _flat(settings: Any, prefix: str = "") -> dict[str, Any]:
    """A nested settings dict as dotted names -> JSON values ("association.transform" -> "rigid")."""
    if not isinstance(settings, dict):
        return {prefix: settings}
    flat: dict[str, Any] = {}
    for key, value in settings.items():
        flat.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def settings_differences(recorded: Any, now: dict[str, Any], why: dict[str, str] | None = None,
                         shown: int = 3, given: tuple[dict[str, Any], dict[str, Any]] = ({}, {})) -> str | None:
    """What the refusal of a complete output says of the settings its record keeps (`recorded`, the record's
    "params") against this run's (`now`, as the record would keep them): 'made with association.transform "rigid";
    this run's is "similarity" (WHY)', up to `shown` settings, `why` a reason by dotted name; None when the record
    keeps no settings or the same ones (then the inputs differ, or the version). A setting only one of them names
    (added or retired since) is no difference: an earlier version's output holds no value for it. `given`: the
    values given (dotted name -> value: the record's, this run's) of settings the command replaced by others
    (`output_checks.RecordedSettings.given`), said as 'set to' where the values used agree."""
    if not isinstance(recorded, dict) or not recorded:
        return None
    before, after = _flat(recorded), _flat(json.loads(json.dumps(now, default=str)))
    changed = [k for k in sorted(before.keys() & after.keys()) if before[k] != after[k]]
    kept_given, now_given = given
    set_to = [k for k in sorted(kept_given.keys() & now_given.keys())
              if kept_given[k] != now_given[k] and k not in changed]
    if not changed and not set_to:
        return None
    said = []
    for key in changed[:shown]:
        reason = (why or {}).get(key)
        said.append(f"{key} {json.dumps(before[key])}, this run's {json.dumps(after[key])}"
                    + (f" ({reason})" if reason else ""))
    for key in set_to[:max(0, shown - len(said))]:
        used = f"; both used {json.dumps(after[key])}" if key in after else ""
        said.append(f"{key} set to {json.dumps(kept_given[key])}, this run's {json.dumps(now_given[key])} "
                    f"({(why or {}).get(key, 'replaced')}{used})")
    changed = changed + set_to
    more = f" and {len(changed) - shown} more setting(s)" if len(changed) > shown else ""
    return "made with " + "; ".join(said) + more


def hash_file_into(h: Any, path: str | Path) -> int:
    """Feed the bytes of `path` to the hash `h` in 1 MiB chunks (bounded memory on a file of any size); the
    number of bytes read. OSError when it does not read."""
    n = 0
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
            n += len(chunk)
    return n


def sha256_file(path: str | Path) -> str:
    """sha256 of a file's contents, streamed (every content digest of sosmatch: images, inputs, flights)."""
    h = hashlib.sha256()
    hash_file_into(h, path)
    return h.hexdigest()


def content_fingerprint(path: str | Path) -> str:
    """What a file or folder holds, not where it lies: sha256 of a file, or of a folder's files (by their path
    inside it and their sha256; hidden entries, e.g. an output's marker, lock and staging area, left out). For an
    output's identity, so that a project moved or copied whole names the same inputs (nu37 D1)."""
    path = Path(path)
    if not path.is_dir():
        return sha256_file(path) if path.is_file() else f"missing:{path.name}"
    files = {}
    for root, dirs, names in os.walk(path):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in names:
            if not name.startswith("."):
                f = Path(root) / name
                files[f.relative_to(path).as_posix()] = sha256_file(f) if f.is_file() else "not a file"
    return fingerprint(files)


def input_identity(path: str | Path | None) -> str | None:
    """An optional input file (a telemetry CSV) as an output's identity knows it: its content
    (`content_fingerprint`), not its path or time (rev49 D4: keyed by its path, an edited telemetry gave back the
    result of the old one); None without one."""
    return None if path is None else content_fingerprint(path)


def resolved_path(path: str | Path) -> Path:
    return Path(os.path.realpath(os.path.expanduser(str(path))))


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_not_input(output: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Refuse an output that is an input, lies inside an input directory or holds an input (resolved paths)."""
    out = resolved_path(output)
    for inp in inputs:
        if inp is None:
            continue
        src = resolved_path(inp)
        if out == src:
            raise InputError("output is also an input; write it elsewhere", output)
        if src.is_dir() and _inside(out, src):
            raise InputError(f"output is inside the input {inp}; write it elsewhere", output)
        if _inside(src, out):
            raise InputError(f"output would hold the input {inp}; write it elsewhere", output)


def read_json_or_none(path: Path) -> dict[str, Any] | None:
    """A marker or registry file: None when missing, {} when unreadable (then nothing it would allow is allowed)."""
    if not path.exists():
        return None
    try:
        return read_user_json(path, "output record")
    except InputError:
        return {}


def output_marker(path: str | Path) -> dict[str, Any] | None:
    """Directory `path`'s output marker when it is one sosmatch wrote (its format), else None."""
    marker = read_json_or_none(Path(path) / MARKER)
    return marker if marker is not None and marker.get("format") == MARKER_FORMAT else None


def output_command(path: str | Path) -> str | None:
    """The sosmatch command whose output directory `path` is (its marker), else None."""
    command = (output_marker(path) or {}).get("command")
    return command if isinstance(command, str) else None


@dataclass(frozen=True)
class UnfinishedRun:
    """A run into an output directory that has not finished (its marker says incomplete)."""

    command: str  # "?" when the marker does not say
    state: str  # "running" (being written now), "interrupted" (killed or failed), "unknown" (output_lock)
    holder: LockHolder | None  # the process the lock file names (None: no lock file)
    copied: bool = False  # interrupted because the lock was taken for another folder: this one is a copy

    def status(self) -> str:
        """What became of it, for a message: "being written now by pid 12", "interrupted; ...", ..."""
        if self.state == "running" and self.holder is not None:
            return f"being written now by pid {self.holder.pid}"
        if self.copied and self.holder is not None:
            return (f"copied while {self.holder.describe()} was writing {self.holder.folder}; its lock file came "
                    "along, but no process writes this copy")
        if self.state == "interrupted":
            return "interrupted; no process writes it any more"
        where = "" if self.holder is None or self.holder.pid is None else f" as {self.holder.describe()}"
        return f"interrupted, or still running{where}"


def unfinished_run(path: str | Path) -> UnfinishedRun | None:
    """The run into directory `path` that has not finished (its marker says incomplete), and whether it is being
    written now (`output_lock.holder_state`), else None. What such a directory holds may be an earlier run's,
    made from other inputs."""
    path = Path(path)
    marker = output_marker(path)
    if marker is None or marker.get("complete") is not False:
        return None
    holder = read_lock_holder(path / LOCK)
    if holder is None and (output_marker(path) or {}).get("complete") is not False:
        return None  # finished between the two reads: a run removes its lock file after marking it complete
    command = marker.get("command")
    command = command if isinstance(command, str) else "?"
    if holder is not None and holder.taken_elsewhere(path):  # whatever its pid does, it does not write here
        return UnfinishedRun(command, "interrupted", holder, copied=True)
    state = {"running": "running", "gone": "interrupted"}.get(holder_state(holder), "unknown")
    return UnfinishedRun(command, state, holder)


def check_input_finished(path: str | Path) -> None:
    """`check_finished` of the sosmatch output that holds the input `path`: the nearest of `path` (a directory)
    and its parents, up to three levels (a model's points3D.bin in sparse/0 of a merged model), with an output
    marker. Only that output decides: a finished session inside a folder of the user's is not refused for the
    folder's sake."""
    real = resolved_path(path)
    for folder in ([real] if real.is_dir() else []) + list(real.parents)[:3]:
        if output_marker(folder) is not None:
            check_finished(folder, None if folder == real else path)
            return


def check_finished(path: str | Path, named: str | Path | None = None) -> None:
    """InputError (naming `named`, default `path`) when a run of sosmatch into directory `path` has not finished:
    what it holds may be an earlier run's beside its unfinished successor (a killed `match --overwrite` leaves
    the new associations.csv beside the old match.json). The error says whether to wait (being written now) or
    to re-run it (interrupted; `unfinished_run`). Every reader of an input that a sosmatch command wrote asks
    this of the directory that holds it."""
    if (run := unfinished_run(path)) is not None:
        where = "this directory" if named is None else f"its directory {Path(path)}"
        todo = ("wait for it to finish before using it" if run.state == "running" else
                "re-run the same command to finish it before using it" if run.state == "interrupted" else
                "once it is not running any more, re-run the same command to finish it before using it")
        raise InputError(f"a `sosmatch {run.command}` run into {where} has not finished ({run.status()}): {todo}",
                         path if named is None else named)
