"""Batch stage 1, discovery: which sub-folders of FLIGHTS_DIR are flights, and of what kind (see the package doc)."""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...database.images import image_files
from ...database.output_markers import hash_file_into, output_command, unfinished_run
from ...plugin.errors import InputError

log = logging.getLogger(__name__)

PAIR_SEP = "__"


@dataclass(frozen=True)
class Flight:
    """One flight folder and how it will be mapped."""

    name: str
    path: Path
    kind: str  # "mapped" | "synth" | "poses" | "opensfm" | "images"


def images_dir(folder: Path) -> Path | None:
    for cand in (folder / "images", folder):
        if cand.is_dir() and image_files(cand):
            return cand
    return None


def classify_flight(folder: Path) -> str | None:
    """The kind of a flight folder (see the module doc), or None when it is not a flight."""
    if (folder / "sparse").is_dir() and all((folder / f).is_file() for f in ("landmarks.sosmap", "landmarks.csv")):
        return "mapped"
    if (folder / "session.json").is_file() and (folder / "poses.csv").is_file():
        return "synth"
    if images_dir(folder) is None:
        return None
    if (folder / "poses.csv").is_file():
        return "poses"
    return "opensfm" if (folder / "opensfm" / "reconstruction.json").is_file() else "images"


def flight_signature(folder: Path, warn: bool = True) -> list[tuple[str, int, int]]:
    """(relative path, size, mtime in ns) of every file under a flight folder, sorted: what the map stage's
    fingerprint knows of the flight's contents, so that re-running a batch redoes a flight whose images, poses or
    mapped session changed (and every pair, merge and comparison of it) instead of resuming stale results. A
    listing, not a digest: re-reading every image on every re-run would cost what the skip saves; a listing that
    differs only in mtimes (a tar, zip or FAT copy, `cp` without -p) is checked by content (`flight_digest`,
    `workflow.contents_seen`) before the flight is mapped again.

    Links are followed, as the map stage follows them: a flight's `images/` is often a link to where the photos
    lie (rev58 D1: `Path.rglob` does not enter a linked folder, so the listing held no image and a flight whose
    photos were replaced resumed its old map); a linked file counts with its target's size and mtime. A link back
    to a folder it lies in is left out with a warning (it would list the folder without end; `warn` False: not
    said again by a second listing of one run)."""
    entries = []
    for path in sorted(_files_under(folder, folder, frozenset({os.path.realpath(folder)}), warn)):
        try:
            st = path.stat()
        except OSError:
            continue  # gone since it was listed: the map stage reports what it cannot read
        entries.append((path.relative_to(folder).as_posix(), st.st_size, st.st_mtime_ns))
    return entries


def _files_under(folder: Path, top: Path, above: frozenset[str], warn: bool = True) -> Iterator[Path]:
    """Every regular file under `folder`, through links (a dangling one is left out: the map stage reports what
    it cannot read); `above`: the real paths of the folders it lies in, a link to one of which is a loop (skipped,
    said)."""
    try:
        children = list(folder.iterdir())
    except OSError:
        return  # unreadable: the map stage reports what it cannot read
    for child in children:
        if not child.is_dir():  # is_dir and is_file follow links
            if child.is_file():
                yield child
            continue
        real = os.path.realpath(child)
        if real in above:
            if warn:
                log.warning("%s: a link to %s, a folder it lies in (a loop); what is under it is not part of flight "
                            "%s", child, real, top)
            continue
        yield from _files_under(child, top, above | {real}, warn)


def flight_digest(folder: Path, listing: list) -> str | None:
    """sha256 over the relative path, size and bytes of every file of `listing` (`flight_signature`) under
    `folder`, in its order; None when one of them no longer reads or its size changed."""
    h = hashlib.sha256()
    for rel, size, _ in listing:
        h.update(f"{rel}\0{size}\0".encode())
        try:
            n = hash_file_into(h, folder / rel)
        except OSError:
            return None
        if n != size:
            return None
    return h.hexdigest()


NOT_FLIGHTS = (".", "_")  # folder names that are never flights: hidden ones, and those put aside with "_"
# outputs of the sosmatch commands whose folders are never flights (those of synth, poses and map are)
NOT_FLIGHT_OUTPUTS = ("batch", "match", "merge", "changes", "evaluate", "demo", "segment")


# what each kind of flight folder is, in words (`discover_flights`' refusal of a flight given as the flights folder)
KIND_NAMES = {"mapped": "a mapped session", "synth": "a `sosmatch synth` session", "poses": "images with poses.csv",
              "opensfm": "images with an OpenSfM reconstruction", "images": "a folder of photos in images/"}


def _itself_a_flight(root: Path) -> str | None:
    """The kind of flight `root` itself is (`classify_flight`), or None. Photos loose in it with no pose file are
    no flight of their own here: a folder of flights may hold a stray picture beside the flight folders."""
    kind = classify_flight(root)
    return None if kind == "images" and images_dir(root) == root else kind


def discover_flights(flights_dir: str | Path) -> list[Flight]:
    """Flights in the sub-folders of `flights_dir`, sorted by name; hidden folders are skipped (the batch's own
    output is never among them: `run` refuses it there)."""
    root = Path(flights_dir)
    if not root.is_dir():
        raise InputError("flights directory not found", root)
    if (kind := _itself_a_flight(root)) is not None:
        # its images/ (and a synth session's labels/) would be taken for flights of photos, mapped by structure
        # from motion in a made-up frame beside the poses the folder holds (rev48 D2)
        raise InputError(f"is itself a flight ({KIND_NAMES[kind]}); give the folder that holds the flights, one "
                         "sub-folder each", root)
    flights: list[Flight] = []
    seen: dict[Path, str] = {}  # resolved folder -> the flight name it is mapped as
    for link in sorted(p for p in root.iterdir() if p.is_symlink() and not p.exists()):
        if not link.name.startswith(NOT_FLIGHTS):  # a flight moved or unmounted: say so, do not drop it silently
            log.warning("%s: a link to %s, which does not exist; not a flight of this batch", link,
                        os.readlink(link))
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        if folder.name.startswith(NOT_FLIGHTS):
            continue
        try:  # names go into JSON state, reports and pair names: they must be text
            folder.name.encode("utf-8")
        except UnicodeEncodeError:
            raise InputError(f"flight folder name {folder.name!r} is not valid UTF-8; rename the folder",
                             root) from None
        if PAIR_SEP in folder.name:
            raise InputError(f"flight folder names may not contain {PAIR_SEP!r} (used for pair names)", folder)
        made_by = output_command(folder)
        if made_by in NOT_FLIGHT_OUTPUTS:  # e.g. an earlier batch's output kept beside the flights
            log.warning("%s: an output of `sosmatch %s`, not a flight; skipped", folder, made_by)
            continue
        real = folder.resolve()
        if real in seen:  # two links (or a link and the folder) to one flight: mapping it twice would also
            # "match" it with itself and merge it twice
            log.warning("%s: the same folder as flight %s (%s); mapped once, as %s", folder, seen[real], real,
                        seen[real])
            continue
        kind = classify_flight(folder)
        if kind is None:
            if (unfinished := unfinished_run(folder)) is not None:  # e.g. a killed `synth`: only its staging
                todo = ("wait for it to finish, then run batch again" if unfinished.state == "running" else
                        "re-run it" if unfinished.state == "interrupted" else "re-run it once it is not running")
                log.warning("%s: a `sosmatch %s` run into it has not finished (%s); not a flight: %s", folder,
                            unfinished.command, unfinished.status(), todo)
            elif (folder / "poses.csv").is_file():
                log.warning("%s: a pose file but no images (looked in %s/images and %s itself); not a flight",
                            folder, folder, folder)
            else:
                log.info("%s: no images, pose file or mapped session; not a flight", folder)
            continue
        seen[real] = folder.name
        flights.append(Flight(folder.name, folder, kind))
    if not flights:
        raise InputError("no flights found (one folder per flight: images with poses.csv, geotagged images, "
                         "a synth session or a mapped session)", root)
    return flights


def one_session_per_flight(mapped: list[str], sessions: dict[str, dict[str, Any]]) -> list[str]:
    """The mapped flights (names, in order) less those that are a flight an earlier one is (`merge_pairs`'
    `walk_flights`, merge's walk: the same landmark map, image folder or images by content), each of those
    left out of matching and merging with a warning in its record (`warnings`, `same_flight_as`) and the log:
    rev33, two maps of one flight made with different settings in one flights folder were matched (234
    associations) and merged with every photo twice, and batch said "ok". What merge says of two flights that share
    image names, one known by its names only (an older merge.json), batch says too (the record's `warnings`, the
    log), and keeps both."""
    from ...database.session_io import read_session
    from ..merge_pairs import session_flights, walk_flights

    def flights_of() -> Iterator[tuple[str, list[dict[str, Any]]]]:
        for name in mapped:
            try:
                yield name, session_flights(read_session(sessions[name]["session"]))
            except InputError as e:  # said where the session is read for its match; nothing to compare it by here
                log.debug("%s: its flights cannot be read: %s", name, e)
                yield name, []  # no flights: kept, and held against none

    def say(name: str, text: str) -> None:
        log.warning("session %s: %s", name, text)
        sessions[name]["warnings"] = [*sessions[name].get("warnings", []), text]

    kept: list[str] = []
    for check in walk_flights(flights_of()):
        name = check.holder
        for note in check.notes:
            say(name, note)
        if check.repeat is None:
            kept.append(name)
            continue
        say(name, f"the same flight as {check.repeat[0]} ({check.repeat[1]}): left out of matching and merging (its "
            "images would be in the merged model twice); keep one map of each flight in the flights folder")
        sessions[name]["same_flight_as"] = check.repeat[0]
    return kept
