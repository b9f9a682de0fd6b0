"""What a merge fuses and from which flights (`workflows.merge`, and batch's merge stage): the landmark pairs of
each session pair and the test they must pass after alignment (`FusePair`, `filter_associations`), and the flights
a session holds, so that no flight is merged twice (`session_flights`, `same_flight`; `walk_flights`, the one walk
of merge's `distinct_flights` and batch's `one_session_per_flight`; of an older merge.json, `older_merged_flights`),
with the
fingerprint a merge of a session depends on (`session_fingerprint`)."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..database.landmark_map import landmark_map_fingerprint
from ..database.output_markers import fingerprint, sha256_file
from ..database.session_io import MERGE_RECORD, SessionFiles, is_merged_session
from ..database.text_input import read_user_json
from ..plugin.errors import InputError
from ..plugin.multisession import Sim3, one_to_one, umeyama
from ..plugin.refinement import pairing_distance


class FusePair(NamedTuple):
    """Landmark associations of sessions a and b to fuse, and the test they passed against their alignment: the
    match's own gate (`MatchSummary.gate_m`, `gate_z_weight`; `pairing_distance`). A verified match pairs
    landmarks within the theta_eps derived from the maps (2.7 m on 100 m flights) with heights at half weight;
    re-judging them at the configured 2 m in 3D left 16 of 35 verified summer-winter associations unfused.
    gate_m None: `max_fuse_distance_m` of the merge, in 3D."""

    a: int
    b: int
    associations: np.ndarray
    gate_m: float | None = None
    z_weight: float = 1.0

    def identity(self) -> list[Any]:
        """The pair as a merge's identity holds it: its sessions, its associations by their digest, its gate."""
        digest = hashlib.sha256(np.ascontiguousarray(self.associations, dtype="<i8").tobytes()).hexdigest()
        return [self.a, self.b, digest, self.gate_m, self.z_weight]


def match_fuse_pair(a: int, b: int, match: Any) -> FusePair:
    """The FusePair of a match's answer (a `database.match_io.MatchSummary`) between sessions a and b."""
    return FusePair(a, b, match.associations, match.gate_m, match.gate_z_weight)


def filter_associations(
    sessions: list[SessionFiles], transforms: list[Sim3], pairs: Sequence[FusePair | tuple[int, int, np.ndarray]],
    max_dist: float
) -> tuple[list[tuple[int, int, np.ndarray]], int]:
    """Keep, of each pair's associations, a one-to-one set (`one_to_one`, nearest first, in that order) whose two
    landmarks pass their pair's gate (`FusePair`; plain (a, b, associations): within max_dist in 3D) and have 3D
    points; returns (kept pairs, number of associations left out).

    The distance is measured in the frame of the pair's session a, whose metres the gate is in (the match paired
    them there); in the reference frame a similarity transform's scale multiplied it (rev33: 138 / 52 / 21 of 138
    fused at reference scale 1 / 2 / 3). One-to-one: an unverified match (a window consensus) may pair one
    landmark with several, and grouping them all chained landmarks no association links (rev33: 5.7 m apart under
    a 2.95 m gate)."""
    kept, rejected = [], 0
    for pair in pairs:
        a, b, assoc, gate, z_weight = FusePair(*pair)
        gate = max_dist if gate is None else gate
        assoc = np.asarray(assoc, dtype=np.int64).reshape(-1, 2)
        na, nb = len(sessions[a].landmarks), len(sessions[b].landmarks)
        valid = (assoc[:, 0] < na) & (assoc[:, 1] < nb)
        if not np.all(valid):
            raise InputError(
                f"associations refer to landmarks beyond the maps ({na} in {sessions[a].name}, "
                f"{nb} in {sessions[b].name}); was match.json computed on these sessions?"
            )
        a_from_b = transforms[a].inverse().compose(transforms[b])
        pa = sessions[a].landmarks.positions[assoc[:, 0]]
        pb = a_from_b.apply(sessions[b].landmarks.positions[assoc[:, 1]])
        dist = pairing_distance(pa, pb, z_weight)
        ok = dist <= gate
        ok &= (sessions[a].point3d_ids[assoc[:, 0]] >= 0) & (sessions[b].point3d_ids[assoc[:, 1]] >= 0)
        taken = one_to_one(assoc, dist, ok)
        rejected += len(assoc) - len(taken)
        kept.append((a, b, assoc[taken]))
    return kept, rejected


# a flight's images in merge.json by the first 16 hex digits of their sha256 (64 bits: no two photos share them
# by chance), so that a season's merge of many flights stays small
IMAGE_DIGEST_CHARS = 16


def flight_maps(session: SessionFiles) -> list[str]:
    """The landmark maps (content fingerprints) of the flights a session holds (`session_flights`' `map`)."""
    return maps_of(session_flights(session))


def maps_of(flights: Iterable[dict[str, Any]]) -> list[str]:
    """The landmark maps of `flights` (`session_flights`), sorted and each once: merge.json's `flight_maps`."""
    return sorted({f["map"] for f in flights})


def session_flights(session: SessionFiles, _seen: frozenset[Path] = frozenset()) -> list[dict[str, Any]]:
    """The flights a session holds, each as what identifies it: `map`, its landmark map (content fingerprint);
    `images`, the digest of its image folder (names and contents: run.json `fingerprints.images`, the same for two
    maps of one folder made with different settings, wherever the project lies) or None; `keyframes`, the content
    digests of the images in its model (run.json `keyframe_images`, first `IMAGE_DIGEST_CHARS` hex digits,
    sorted: images, not names, so that two flights' DJI_0001.JPG are two photos); `names`, the names of those
    images (or, for a flight of an older merge.json, the names they are among: `name_overlap`). A flight without
    run.json (an older sosmatch): its map only. A merged session's as its merge.json records them
    (`flights`); of an older sosmatch, which recorded no images, as `older_merged_flights` recovers them.
    InputError naming merge.json or run.json when it is unreadable, or merge.json when a merged session
    (`session_io.is_merged_session`: its output marker) has lost it: a merged session taken for one flight would let a
    flight it holds be merged into it again."""
    record = session.path / MERGE_RECORD
    if not record.is_file() and is_merged_session(session.path):
        # its marker says `sosmatch merge` wrote it: taken for one flight, a flight it holds would be merged into
        # it again (rev45 D9: 40 photos twice, exit 0); its flights are in merge.json alone
        raise InputError("a merged session (its output marker says `sosmatch merge` wrote it) without its merge.json: "
                         "damaged or copied in part; re-run `sosmatch merge` to make it again", record)
    if record.is_file():
        merged = read_user_json(record, "merge record", redo="re-run `sosmatch merge`")
        flights = merged.get("flights")
        if isinstance(flights, list) and flights and all(isinstance(f, dict) and isinstance(f.get("map"), str)
                                                         for f in flights):
            return [{"map": f["map"], "images": f.get("images") if isinstance(f.get("images"), str) else None,
                     "keyframes": sorted(str(k) for k in f.get("keyframes") or []),
                     "names": sorted(str(n) for n in f.get("names") or [])} for f in flights]
        return older_merged_flights(session, merged, _seen | {session.path.resolve()})
    run = session.record.get() or {}  # run.json as `read_session` read it
    images = (run.get("fingerprints") or {}).get("images") if isinstance(run.get("fingerprints"), dict) else None
    keyframes = run.get("keyframe_images") if isinstance(run.get("keyframe_images"), dict) else {}
    return [{"map": landmark_map_fingerprint(session.landmarks), "images": images if isinstance(images, str) else None,
             "keyframes": sorted({str(d)[:IMAGE_DIGEST_CHARS] for d in keyframes.values()}),
             "names": sorted(str(n) for n in keyframes)}]


def _model_names(session: SessionFiles) -> list[str]:
    """The names of the images in a session's model (a merged model's: `label/name`, its session's label first)."""
    from ..database.colmap_model import load_reconstruction

    return [img.name for img in load_reconstruction(session.sparse_dir).images.values()]


def older_merged_flights(session: SessionFiles, merged: dict[str, Any], seen: frozenset[Path]
                         ) -> list[dict[str, Any]]:
    """The flights of a merged session whose merge.json (an older sosmatch: `flight_maps` at most) records no
    images (rev34): each input session merge.json names (`sessions`, as given then: relative to the working
    directory, or beside the merged session) that is still the flight merged (its landmark maps are among
    `flight_maps`) by its own record (`session_flights`: images by content); the others by their maps and the
    names of their images in the merged model (`label/name`), which alone never refuse a flight (two flights'
    DJI_0001.JPG are two photos) but warn (`name_overlap`). A merge.json without `flight_maps` (older still) cannot
    tell an input that was mapped again since from the one merged: its flights are the merged map only."""
    recorded = merged.get("flight_maps")
    maps = set(recorded) if isinstance(recorded, list) and all(isinstance(f, str) for f in recorded) else set()
    paths, labels = merged.get("sessions"), merged.get("labels")
    inputs = list(zip(paths, labels)) if (isinstance(paths, list) and isinstance(labels, list)
                                          and len(paths) == len(labels)) else []
    found: list[dict[str, Any]] = []
    unknown: list[str] = []
    for path, label in inputs:
        flights = _still_merged(session, str(path), maps - {f["map"] for f in found}, seen) if maps else None
        if flights is None:
            unknown.append(str(label))
        else:
            found += flights
    left = sorted(maps - {f["map"] for f in found}) or ([] if maps else [landmark_map_fingerprint(session.landmarks)])
    labelled = [name.partition("/") for name in _model_names(session)]
    names = sorted({name for label, _, name in labelled if not inputs or label in unknown})
    return found + [{"map": m, "images": None, "keyframes": [], "names": names} for m in left]


def _still_merged(merged: SessionFiles, path: str, maps: set[str], seen: frozenset[Path]
                  ) -> list[dict[str, Any]] | None:
    """The flights (`session_flights`) of the input session `path` of the merged session `merged` when it is
    found (as recorded, or by its folder's name beside `merged`) and still holds what was merged (every landmark
    map among `maps`, those of the inputs not found yet: two inputs of one folder name are not one found twice);
    None otherwise (moved, deleted or mapped again since)."""
    from ..database.session_io import read_session

    for candidate in (Path(path), merged.path.parent / Path(path).name):
        try:
            if not candidate.is_dir() or candidate.resolve() in seen:
                continue
            flights = session_flights(read_session(candidate), seen)
        except (InputError, OSError):
            continue
        if flights and all(f["map"] in maps for f in flights):
            return flights
    return None


def same_flight(f: dict[str, Any], g: dict[str, Any]) -> str | None:
    """Why two flights (`session_flights`) are one: the same landmark map, the same image folder, or images in
    common (by content); None when nothing says so."""
    if f["map"] == g["map"]:
        return "the same landmark map"
    if f["images"] is not None and f["images"] == g["images"]:
        return "the same images"
    common = len(set(f["keyframes"]) & set(g["keyframes"]))
    if common:
        return f"{common} of its images, by content"
    return None


def name_overlap(f: dict[str, Any], g: dict[str, Any]) -> int:
    """How many image names two flights (`session_flights`) share when one of them has no record of its images'
    contents (an older merge.json's: `older_merged_flights`), so that names are all that might tell they are one;
    0 when both have one (their contents decide: `same_flight`)."""
    if (f["keyframes"] or f["images"]) and (g["keyframes"] or g["images"]):
        return 0
    return len(set(f["names"]) & set(g["names"]))


def repeated_flight(flights: Sequence[dict[str, Any]], held: Sequence[tuple[dict[str, Any], Any]]
                    ) -> tuple[Any, str] | None:
    """(holder, why) when one of `flights` (`session_flights`) is a flight of `held` ((flight, holder) each, e.g.
    the sessions taken before: `same_flight`), else None."""
    for f in flights:
        for g, holder in held:
            if (why := same_flight(f, g)) is not None:
                return holder, why
    return None


class FlightCheck(NamedTuple):
    """One session's flights against those of the sessions before it (`walk_flights`)."""

    holder: Any  # the session, as the caller names it (merge: its path; batch: its flight's name)
    flights: list[dict[str, Any]]  # its flights (`session_flights`)
    repeat: tuple[Any, str] | None  # (holder, why) of an earlier session holding one of them (`repeated_flight`)
    notes: list[str]  # image names shared with an earlier session's flight known by its names only (`name_overlap`)


def walk_flights(sessions: Iterable[tuple[Any, Sequence[dict[str, Any]]]]) -> Iterator[FlightCheck]:
    """Each of `sessions` ((holder, its flights: `session_flights`), in order) checked against the flights of the
    ones before it that repeated none (`FlightCheck`): the one walk of merge (`distinct_flights`: a repeat is
    refused) and batch (`batch.discovery.one_session_per_flight`: a repeat is left out, said), whose names-only
    notes both say. A repeat's flights are not held (batch leaves it out); it gets no notes (it is not taken)."""
    held: list[tuple[dict[str, Any], Any]] = []
    for holder, flights in sessions:
        if (repeat := repeated_flight(flights, held)) is not None:
            yield FlightCheck(holder, list(flights), repeat, [])
            continue
        notes = [f"{holder} and {other} hold flights with {n} image names in common, and an older sosmatch's "
                 "merge.json records no images of one (nor is its session found as merged: moved, deleted or "
                 "mapped again): names alone do not tell a photo; if it is one flight mapped twice, its images are "
                 "in the model twice"
                 for f in flights for g, other in held if (n := name_overlap(f, g))][:1]
        held += [(f, holder) for f in flights]
        yield FlightCheck(holder, list(flights), None, notes)


def distinct_flights(sessions: Sequence[SessionFiles]) -> tuple[list[dict[str, Any]], list[str]]:
    """The flights of all `sessions` (`session_flights`), as merge.json records them (`flights`), and a warning
    for each flight that shares image names with one of whose images no record holds the contents (`name_overlap`:
    an older merge.json; names alone do not refuse). InputError when one flight is in two of them
    (`repeated_flight`; its images would be in the model twice): the eleventh sweep, a flight merged into a season
    map that already held it; rev33, two maps of one flight made with different settings (other landmarks, the
    same photos), merged with every photo twice, exit 0. The walk is batch's too (`walk_flights`)."""
    flights: list[dict[str, Any]] = []
    notes: list[str] = []
    for check in walk_flights((s.path, session_flights(s)) for s in sessions):
        if check.repeat is not None:
            raise InputError(f"holds a flight that {check.repeat[0]} holds already ({check.repeat[1]}): merging it "
                             "again would put its images into the model twice", check.holder)
        flights += check.flights
        notes += check.notes
    return flights, notes


def session_fingerprint(session: SessionFiles) -> str:
    """What a merge of `session` depends on: its landmarks (content fingerprint), landmark table and model."""
    files = sorted(p for p in session.sparse_dir.iterdir() if p.is_file())
    return fingerprint({"landmarks": landmark_map_fingerprint(session.landmarks),
                        "point3d_ids": hashlib.sha256(np.ascontiguousarray(session.point3d_ids, "<i8")).hexdigest(),
                        "sparse": {p.name: sha256_file(p) for p in files}})


def refine_transform(
    a: SessionFiles, b: SessionFiles, associations: np.ndarray, initial: Sim3, with_scale: bool, gate_m: float
) -> tuple[Sim3, int]:
    """Re-estimate a_from_b by least squares on every association that `initial` already explains within gate_m:
    one refit, not what `merge --refine` / `batch --refine` do (`merge_refine.refined_answer`); kept as the baseline the
    batch benchmark's refinement table and a test compare that refinement with.

    Returns (transform, number of associations used); keeps `initial` when fewer than 3 survive the gate.
    """
    assoc = np.asarray(associations, dtype=np.int64).reshape(-1, 2)
    pa = a.landmarks.positions[assoc[:, 0]]
    pb = b.landmarks.positions[assoc[:, 1]]
    inliers = np.linalg.norm(initial.apply(pb) - pa, axis=1) <= gate_m
    if np.count_nonzero(inliers) < 3:
        return initial, 0
    try:
        return umeyama(pb[inliers], pa[inliers], with_scale=with_scale), int(np.count_nonzero(inliers))
    except ValueError:  # collinear inliers: the initial transform is all we have
        return initial, 0
