"""Where every command's output goes: one mechanism, so that nothing is ever lost.

The rules (README "Errors"; tests/test_outputs.py keeps them):
1. A command never deletes or replaces anything it did not create. An output directory is new, empty, or a
   previous output of the same command: its marker file `.sosmatch-output.json`, written by sosmatch when it
   takes the directory, names the command. An output file is new, or a file the same command wrote before
   and nobody changed since: the directory's registry `.sosmatch-files.json` lists it with its sha256
   (`database.output_files.OutputFiles`). Inside an output directory, a file the command writes (match.json) is
   replaced or removed only while it is the one the marker records under "files" (sha256, recorded when written),
   and a directory entry it publishes (a session's sparse/) only while it holds just the files the marker records
   under "entries" (`database.output_entries`): a user's file at such a name refuses the run, nothing changed.
   Every file goes through `OutputDir.publish` (or `write_file`), which records it.
2. An output is never an input, never inside an input, and never holds one (compared as resolved paths).
3. Replacing a previous *complete* output of the same command made from other inputs or settings (another
   `identity`) needs `overwrite=True` (`--overwrite`). An incomplete one (a killed or failed run) is resumed or
   restarted without it: a failed run never blocks its own retry. The same identity replaces freely: the
   outputs are deterministic, so nothing is lost.
4. One run at a time per output directory: an exclusive lock (flock on `.sosmatch-output.lock`, present while
   a run holds it; the kernel releases it when the process dies) refuses a second concurrent run. The file names
   the run's process (`database.output_lock`), so that a reader can tell a run being written now from one that
   was killed. The lock moves with the directory: a directory moved or deleted under its run stops the run in
   one line (`database.taken.OutputMoved`), and nothing is written or re-created at its old place.
5. Files are written atomically (`sosmatch.database.atomic`); the one place where a directory is replaced is
   here (`OutputDir.replace_dir`, `OutputDir.publish`), and only inside a directory the command owns.
   Temporaries of killed runs are removed by the next run.

Python:

    with open_output_dir(out, "match", identity, inputs=[a, b], overwrite=False) as out_dir:
        write_text_atomic(out_dir.path / "match.json", text)
        out_dir.finish()                       # the output is complete (until then it is resumable)

    files = OutputFiles([geojson], "export", identity, inputs=[source])   # database.output_files: single files,
    files.write(geojson, text)                                             # checked before any work

What an output directory is to its readers (the marker, `check_finished`, the identities `fingerprint` and
`sha256_file`, `check_not_input`) is `database.output_markers`; whether a run may take one (what it holds now, the
refusal of another complete output, the checks a command makes before its work) is `database.output_checks`;
this module takes the directory, writes the marker and publishes the entries.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from ..plugin.errors import InputError
from .atomic import clean_stale_temporaries, locked_temp_dir, write_bytes_atomic, write_text_atomic
from .output_checks import OURS, OVERWRITE_HINT, PreviousOutput, RecordedSettings, previous_output, refuse_another
from .output_entries import (
    adopted_files,
    check_entry_ours,
    check_file_ours,
    check_not_in_output_entry,
    entry_files,
    entry_names,
    merge_entry_records,
    recorded_entries,
    recorded_files,
)
from .output_lock import acquire_lock, release_lock
from .output_markers import (
    LOCK,
    MARKER,
    MARKER_FORMAT,
    STAGING,
    VersionedIdentity,
    check_not_input,
    output_marker,
    sha256_file,
)
from .taken import OutputMoved, Place, check_place


def _holds_files(folder: Path) -> bool:
    """True when anything but directories lies in `folder` or below (True too when it cannot be read)."""
    try:
        for root, dirs, files in os.walk(folder, onerror=_raise):
            if files or any(os.path.islink(os.path.join(root, d)) for d in dirs):
                return True
    except OSError:
        return True
    return False


def _raise(exc: OSError) -> None:
    raise exc


def _bytes_or_none(path: Path) -> bytes | None:
    """The file's bytes, None when it is absent (another error is raised: absent is what lets a restore remove it)."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None


class OutputDir:
    """An output directory taken by one run of one command (see the module doc); use `open_output_dir`."""

    def __init__(self, path: Path, command: str, identity: str, previous: PreviousOutput, lock_fd: int,
                 created: Sequence[Path] = (), same_as: Iterable[str] = (), record: str | None = None) -> None:
        self.path = path
        self.command = command
        self.identity = identity
        self.previous = previous
        self._same_as = frozenset(same_as)  # earlier versions' identities of this very output
        self._record = record  # the command's record (`legacy_record`): the settings a refusal compares
        self._lock_fd: int | None = lock_fd
        self._created = list(created)  # directories this run created, outermost first
        marker = output_marker(path)
        # what sosmatch wrote in each directory entry (kept in the marker across runs): all a replacement may delete
        self._entries = recorded_entries(marker)
        # and the files it wrote at the top (name -> sha256): all it may replace or remove there; None: an older
        # sosmatch's marker, which recorded none (`open_output_dir` takes its files as ours, as that one did)
        self._files = recorded_files(marker)
        self._complete = previous.state == "complete"
        self._place = Place(path, command)  # the directory itself: a move under the run is noticed (`taken`)
        # the marker as the run found it (read under the lock, before the run re-writes it): `restore_previous`
        self._marker_before = _bytes_or_none(path / MARKER)

    @property
    def resumed(self) -> bool:
        """True when an unfinished run of this command left the directory (its staging area may be reused)."""
        return self.previous.state == "incomplete"

    @property
    def was_complete(self) -> bool:
        """True when the directory already held this very output (same identity, or an earlier version's of it),
        complete."""
        return self.previous.state == "complete" and (self.previous.identity == self.identity
                                                      or self.previous.identity in self._same_as)

    @property
    def staging(self) -> Path:
        """OUT/.partial: where a command builds what it publishes at the end (kept across a killed run)."""
        self.check_place()
        d = self.path / STAGING
        d.mkdir(exist_ok=True)
        return d

    def staged(self, name: str) -> Path:
        """OUT/.partial/NAME, with whatever a killed run left there removed (the staging area is ours)."""
        p = self.staging / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()
        return p

    def check_place(self) -> None:
        """Raise `OutputMoved` (one line, exit 2) when the directory was moved or deleted while this run holds it:
        nothing is then written at its old place."""
        self._place.check()

    def clear_staging(self) -> None:
        """Remove the staging area (`STAGING`) and what a run built in it, in the directory this run holds."""
        self.check_place()
        shutil.rmtree(self.path / STAGING, ignore_errors=True)

    def _write_marker(self, complete: bool) -> None:
        """Write this run's marker."""
        from ..plugin import __version__

        self.check_place()
        self._complete = complete
        write_text_atomic(self.path / MARKER, json.dumps(
            {"format": MARKER_FORMAT, "command": self.command, "identity": self.identity,
             "complete": complete, "sosmatch": __version__, "entries": self._entries,
             "files": self._files if self._files is not None else {}}, indent=1) + "\n")

    def restore_previous(self) -> None:
        """For a run refused (a user error) before it wrote anything into the directory: put back the marker as the
        run found it, so that the directory is exactly as it was (a complete earlier output, also one replaced
        under `overwrite`, complete and of its own identity again; no marker where there was none). Taking the
        directory re-wrote the marker as this run's, incomplete: left so, it called the untouched earlier output
        unfinished (rev31 F3: `evaluate --overwrite --sweep-floor` refused after its search). A directory moved
        away under the run is not written (`check_place`)."""
        self.check_place()
        if self._marker_before is None:
            (self.path / MARKER).unlink(missing_ok=True)
        else:
            write_bytes_atomic(self.path / MARKER, self._marker_before)
        self._complete = self.previous.state == "complete"

    def _check_entries(self, layouts: dict[str, set[str]] | None = None) -> None:
        """Refuse (InputError naming the file) when a directory entry holds anything sosmatch did not write there.
        Without `layouts` only recorded entries are checked (when the directory is taken, before anything
        changes); with them (publishing: entry name -> the new entry's files) unrecorded ones too."""
        for name in sorted(self._entries.keys() | (layouts or {}).keys()):
            dst = self.path / name
            if not dst.is_dir() or dst.is_symlink():
                continue
            if name in self._entries:
                check_entry_ours(dst, self.command, self._entries[name])
            elif layouts is not None and name in layouts:
                check_entry_ours(dst, self.command, None, layouts[name])

    def check_files(self, names: Iterable[str]) -> None:
        """Refuse (InputError naming the file) a file at one of `names` (the files the command writes at the top
        of the directory) that the command did not write there or that was changed since (the marker's "files",
        `output_entries.check_file_ours`): checked when the directory is taken, before anything changes, and again
        by `publish` before its first rename."""
        for name in names:
            self._check_kind(name, False)
            check_file_ours(self.path / name, self.command, self._files)

    def write_file(self, name: str, data: bytes | str) -> None:
        """Write OUT/NAME (a file of the output; text as UTF-8) through the staging area and `publish`: refused when
        a file stands there that the command did not write, else written atomically and recorded."""
        self.check_files([name])  # before it is staged: a refusal leaves the directory as it was
        write_bytes_atomic(self.staged(name), data.encode("utf-8") if isinstance(data, str) else data)
        self.publish([name])

    def remove_file(self, name: str) -> None:
        """Remove OUT/NAME, a file the command wrote there (InputError, nothing removed, when it did not write it or
        it was changed since: `check_files`)."""
        if (self.path / name).exists() or (self.path / name).is_symlink():
            self.check_files([name])
            self._remove_entry(name)
            self._write_marker(self._complete)

    def _replace_entry(self, src: Path, name: str, checked: bool = False) -> None:
        """Move `src` onto OUT/NAME; an existing directory there (ours: this is our output) is swapped out
        (`checked`: its files were found ours just before, as `publish` does for all its entries at once).

        An entry of the other kind (a directory where the command writes a file, or a file where it writes a
        directory) was not made by this command and is refused."""
        dst = self.path / name
        exists = dst.exists() or dst.is_symlink()
        is_dir = src.is_dir()
        self._check_kind(name, is_dir)
        if is_dir:
            new = entry_files(src)
            if exists and not checked:  # `publish` checked every entry before replacing any; replace_dir did not
                check_entry_ours(dst, self.command, self._entries.get(name), set(new))
            # recorded before the swap (old and new files both: a run killed in between leaves no file unlisted),
            # then only the new ones
            self._entries[name] = merge_entry_records(self._entries.get(name, {}), new)
            self._write_marker(self._complete)
        if exists and is_dir:
            old, fd = locked_temp_dir(dst)
            try:
                os.replace(dst, old / name)
                os.replace(src, dst)
            finally:
                shutil.rmtree(old, ignore_errors=True)
                os.close(fd)
        else:
            os.replace(src, dst)
        if is_dir:
            self._entries[name] = new
            self._write_marker(self._complete)

    def _check_kind(self, name: str, is_dir: bool, verb: str = "replaced") -> None:
        """Refuse (InputError naming OUT/NAME) an entry of the other kind than the one the command writes there (a
        directory where it writes a file, or a file or link where it writes a directory): not this command's."""
        dst = self.path / name
        if not (dst.exists() or dst.is_symlink()):
            return
        found_dir = dst.is_dir() and not dst.is_symlink()
        if found_dir != is_dir:
            found, wanted = ("a directory", "a file") if found_dir else ("a file", "a directory")
            raise InputError(f"is {found} where `sosmatch {self.command}` writes {wanted}; not {verb} (remove it "
                             "or choose another output directory)", dst)

    def _check_targets(self, staging: Path, names: Sequence[str], optional: Sequence[str]) -> None:
        """Everything `publish` will rename or remove, checked before the first change, so that a refusal leaves
        the directory as it was (fix149: a user's directory named landmarks.csv was refused only after sparse/ and
        landmarks.sosmap had been swapped in): each target of the kind the run stages (a file that is not staged
        and is optional is removed: it must be a file), and the places a rename writes (the output directory;
        a directory entry moved aside, whose '..' changes) writable."""
        if not os.access(self.path, os.W_OK | os.X_OK):
            raise InputError("cannot write output directory: it is read-only or not writable", self.path)
        for name in names:
            src = staging / name
            if src.exists() or src.is_symlink():
                staged_dir = src.is_dir() and not src.is_symlink()
                self._check_kind(name, staged_dir)
                if not staged_dir:
                    check_file_ours(self.path / name, self.command, self._files)
            elif name in optional:
                self._check_kind(name, False, "removed")
                check_file_ours(self.path / name, self.command, self._files)
            else:  # a required output that was not staged is a bug: said before anything moved
                raise FileNotFoundError(f"{src} was not staged")
            dst = self.path / name
            if dst.is_dir() and not dst.is_symlink() and not os.access(dst, os.W_OK | os.X_OK):
                raise InputError("cannot replace this directory: it is read-only", dst)

    @contextlib.contextmanager
    def replace_dir(self, name: str) -> Iterator[Path]:
        """Yield a new, empty directory; on success it replaces OUT/NAME (a previous one is deleted)."""
        tmp, fd = locked_temp_dir(self.path / name)
        try:
            target = tmp / name
            target.mkdir()
            yield target
            self._replace_entry(target, name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            os.close(fd)

    def publish(self, names: Sequence[str], last: str | None = None, optional: Sequence[str] = ()) -> None:
        """Move the staged entries NAMES (then `last`, the record whose presence means complete) into OUT; the
        previous record is removed first, once the directory entries are checked (a refusal changes nothing).

        An `optional` name (an aid such as a picture, which may fail without losing the output) that this run
        did not stage is not published, and its previous version, ours since OUT is, is removed: what stands
        beside the record always comes from the same run."""
        self.check_place()
        staging = self.path / STAGING
        layouts = {name: set(entry_names(staging / name)) for name in names if (staging / name).is_dir()}
        try:  # every entry checked before any is replaced or removed: a refusal changes nothing
            self._check_entries(layouts)
            self._check_targets(staging, [*names, *([last] if last else [])], optional)
        except InputError:
            if self.previous.state == "complete":  # untouched: the previous output stands, complete as it was
                self.restore_previous()
            raise
        targets = [*names, *([last] if last else [])]
        files = {name: sha256_file(staging / name) for name in targets
                 if (staging / name).is_file() and not (staging / name).is_symlink()}
        # the files recorded before they are renamed (the old hash and the new both: a run killed in between leaves
        # either, and its next run must find it ours), then only the new ones: one marker write each, for them all
        self._files = merge_entry_records(self._files or {}, files)
        self._write_marker(self._complete)
        if last:
            self._remove_entry(last)  # absent while entries are swapped: what stands beside it is complete
        for name in targets:
            src = staging / name
            if name in optional and not (src.exists() or src.is_symlink()):
                self._remove_entry(name)
                continue
            self._replace_entry(src, name, checked=True)
        self._files.update(files)
        self._write_marker(self._complete)

    def _remove_entry(self, name: str) -> None:
        """Remove OUT/NAME, an entry of this command's output (a file; a directory of another kind is refused)."""
        self._check_kind(name, False, "removed")
        (self.path / name).unlink(missing_ok=True)
        if self._files is not None:
            self._files.pop(name, None)

    def settle(self, identity: str | VersionedIdentity, overwrite: bool = False,
               overwrite_flag: str = OVERWRITE_HINT, settings: RecordedSettings | None = None) -> None:
        """The output's identity when the work decided it (`match`: the rigid answer after a similarity's scale no
        dome makes), the directory taken for any of those it could be (`open_output_dir`'s `earlier`): a complete
        previous output of another identity is refused now, as `open_output_dir` refuses it (unless `overwrite`;
        the marker restored as the run found it), and the marker names `identity`. Call before writing anything.
        `settings`: the settings of that answer, which a refusal compares with the record's (`open_output_dir`)."""
        versions = identity if isinstance(identity, VersionedIdentity) else VersionedIdentity(identity)
        try:
            refuse_another(self.path, self.command, self.previous, versions, {versions.today, *versions.same_as},
                            overwrite, overwrite_flag, settings, self._record)
        except InputError:
            self.restore_previous()
            raise
        self.identity, self._same_as = versions.today, frozenset(versions.same_as)
        self._write_marker(complete=self.was_complete)

    def finish(self, keep_staging: bool = False) -> None:
        """Mark the output complete (a later run with another identity then needs overwrite)."""
        if not keep_staging:
            self.clear_staging()
        self._write_marker(complete=True)

    def close(self) -> None:
        """Release the directory (idempotent)."""
        if self._lock_fd is not None:
            release_lock(self.path / LOCK, self._lock_fd, self._place.fd)
            self._lock_fd = None
        self._place.release()

    def _discard_if_untouched(self) -> None:
        """After a failed run: remove what this run created if it wrote nothing else (a bad input then leaves
        no trace); a directory holding anything more (e.g. a resumable cache) stays."""
        if not self._created or not self._place.here():  # moved: what is at the old place is not ours
            return
        staging = self.path / STAGING
        if not _holds_files(staging):  # only empty folders (a stage's work directory made before the refusal)
            shutil.rmtree(staging, ignore_errors=True)
        try:
            left = {p.name for p in self.path.iterdir()}
        except OSError:
            return
        if left <= OURS:
            (self.path / MARKER).unlink(missing_ok=True)
            self.close()
            for d in reversed(self._created):
                with contextlib.suppress(OSError):
                    d.rmdir()

    def __enter__(self) -> OutputDir:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        # (an interrupt stays one: Ctrl-C is not the move)
        moved = isinstance(exc_type, type) and issubclass(exc_type, Exception) and not self._place.here()
        if moved:
            # whatever failed (a write by path into the vanished directory, a FileNotFoundError deep in a stage,
            # in a worker) failed because the directory went away: said as that, in one line
            error = OutputMoved(self._place.path, self.command, self._place.now())
        if exc_type is not None:
            self._discard_if_untouched()
        self.close()
        if moved:  # (also over a worker's OutputMoved, which cannot say where the directory went)
            raise error from None


def open_output_dir(
    path: str | Path,
    command: str,
    identity: str | VersionedIdentity,
    *,
    inputs: Iterable[str | Path | None] = (),
    overwrite: bool = False,
    legacy_record: str | None = None,
    overwrite_flag: str = OVERWRITE_HINT,
    earlier: Iterable[str] = (),
    before_taking: Callable[[Path], None] | None = None,
    settings: RecordedSettings | None = None,
    files: Iterable[str] = (),
) -> OutputDir:
    """Take directory `path` for one run of `command` producing the output `identity` (see the module doc).

    Refuses (InputError, nothing changed): a path that is a file or cannot be created, an input (or inside
    one, or holding one), a non-empty directory that is not this command's output, a complete output of
    another identity unless `overwrite`, and a directory another run is using. `legacy_record`: the name of
    the command's JSON record (format "sosmatch ...") that marks an output written before markers existed.
    Cleans the stale temporaries of killed runs. `overwrite_flag` is how the refusal names the command's
    option. `earlier`: the identities an earlier sosmatch gave this same output (same inputs and settings): such
    an output is no other one, and is made again under `identity`. A `VersionedIdentity` `identity` also holds the
    identities earlier sosmatch versions gave this very output (`plugin.params.identity_versions`): such a complete
    output is this one (resumed, its marker re-written under today's identity); and what a refusal says of an
    earlier version's output whose settings behave otherwise today. `before_taking(path)`: the command's own checks
    that may refuse (InputError), run under the lock before the marker changes, so that a refused run leaves a
    previous output as it was. `settings`: this run's settings as `legacy_record` keeps them; the refusal of a
    complete output of another identity names those its record keeps otherwise (`RecordedSettings`). `files`: the
    files the command writes at the top of `path`, as far as it knows them before its work: one standing there that
    it did not write, or that was changed since, is refused now, nothing changed (`OutputDir.check_files`). Returns
    the taken directory (a context manager that releases the lock).
    """
    path = Path(path)
    versions = identity if isinstance(identity, VersionedIdentity) else VersionedIdentity(identity)
    identity, same_as = versions.today, frozenset(versions.same_as)  # earlier versions' identities of this output
    check_not_input(path, list(inputs))
    check_not_in_output_entry(path)
    previous = previous_output(path, command, legacy_record)
    same = {identity, *earlier, *same_as}
    refuse_another(path, command, previous, versions, same, overwrite, overwrite_flag, settings, legacy_record)
    created = [p for p in [*reversed(path.absolute().parents), path.absolute()] if not p.exists()]
    check_place(path)  # inside another run's output (batch's maps) that was moved away: not re-created
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output directory: {exc.strerror or exc}", path) from None
    fd = acquire_lock(path / LOCK, command)
    out: OutputDir | None = None
    try:
        again = previous_output(path, command, legacy_record)  # under the lock: a run that just finished counts
        if again != previous and again.state == "complete" and again.identity not in same and not overwrite:
            raise InputError(f"output directory now holds a complete `sosmatch {command}` output made from other "
                             f"inputs or settings; use {overwrite_flag} to replace it", path)
        out = OutputDir(path, command, identity, again, fd, created, same_as, legacy_record)
        out._check_entries()  # a user's file inside e.g. sparse/ is refused now, not when the run publishes
        out.check_files(files)  # and one at a name the run writes: before a run of minutes, not after it
        if before_taking is not None:
            before_taking(path)
        if out._files is None:  # an older sosmatch's output: its files are ours, as they were to it (recorded_files)
            out._files = adopted_files(path)
        clean_stale_temporaries(path)
        if (path / STAGING).is_dir():
            clean_stale_temporaries(path / STAGING, recursive=True)
        out._write_marker(complete=out.was_complete)
    except OSError as exc:
        release_lock(path / LOCK, fd)
        if out is not None:
            out._place.release()
        raise InputError(f"cannot write output directory: {exc.strerror or exc}", path) from None
    except BaseException:
        release_lock(path / LOCK, fd)
        if out is not None:
            out._place.release()
        for d in reversed(created):  # a refused run into a new directory leaves no trace
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    return out
