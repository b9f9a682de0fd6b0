"""What a merge fuses and from which flights (`workflows.merge`, and batch's merge stage): the landmark pairs of
each session pair and the test they must pass after alignment (`FusePair`, `filter_associations`), and the flights
a session holds, so that no flight is merged twice (`session_flights`, `same_flight`, `distinct_flights`), with the
fingerprint a merge of a session depends on (`session_fingerprint`)."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..database.landmark_map import landmark_map_fingerprint
from ..database.output_markers import fingerprint, sha256_file
from ..database.session_io import MERGE_RECORD, SessionFiles, read_map_record
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
    return sorted({f["map"] for f in session_flights(session)})


def session_flights(session: SessionFiles) -> list[dict[str, Any]]:
    """The flights a session holds, each as what identifies it: `map`, its landmark map (content fingerprint);
    `images`, the digest of its image folder (names and contents: run.json `fingerprints.images`, the same for two
    maps of one folder made with different settings, wherever the project lies) or None; `keyframes`, the content
    digests of the images in its model (run.json `keyframe_images`, first `IMAGE_DIGEST_CHARS` hex digits,
    sorted: images, not names, so that two flights' DJI_0001.JPG are two photos). A flight without run.json (an
    older sosmatch): its map only. A merged session's as its merge.json records them (`flights`; of an older
    sosmatch `flight_maps`, maps only). InputError naming merge.json or run.json when it is unreadable: a merged
    session taken for one flight would let a flight it holds be merged into it again."""
    record = session.path / MERGE_RECORD
    if record.is_file():
        merged = read_user_json(record, "merge record", redo="re-run `sosmatch merge`")
        flights = merged.get("flights")
        if isinstance(flights, list) and flights and all(isinstance(f, dict) and isinstance(f.get("map"), str)
                                                         for f in flights):
            return [{"map": f["map"], "images": f.get("images") if isinstance(f.get("images"), str) else None,
                     "keyframes": sorted(str(k) for k in f.get("keyframes") or [])} for f in flights]
        recorded = merged.get("flight_maps")
        if isinstance(recorded, list) and recorded and all(isinstance(f, str) for f in recorded):
            return [{"map": f, "images": None, "keyframes": []} for f in sorted(set(recorded))]
    run = read_map_record(session.path) or {}
    images = (run.get("fingerprints") or {}).get("images") if isinstance(run.get("fingerprints"), dict) else None
    keyframes = run.get("keyframe_images") if isinstance(run.get("keyframe_images"), dict) else {}
    return [{"map": landmark_map_fingerprint(session.landmarks), "images": images if isinstance(images, str) else None,
             "keyframes": sorted({str(d)[:IMAGE_DIGEST_CHARS] for d in keyframes.values()})}]


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


def repeated_flight(flights: Sequence[dict[str, Any]], held: Sequence[tuple[dict[str, Any], Any]]
                    ) -> tuple[Any, str] | None:
    """(holder, why) when one of `flights` (`session_flights`) is a flight of `held` ((flight, holder) each, e.g.
    the sessions taken before: `same_flight`), else None."""
    for f in flights:
        for g, holder in held:
            if (why := same_flight(f, g)) is not None:
                return holder, why
    return None


def distinct_flights(sessions: Sequence[SessionFiles]) -> list[dict[str, Any]]:
    """The flights of all `sessions` (`session_flights`), as merge.json records them (`flights`); InputError when
    one flight is in two of them (`repeated_flight`; its images would be in the model twice): the eleventh sweep, a
    flight merged into a season map that already held it; rev33, two maps of one flight made with different
    settings (other landmarks, the same photos), merged with every photo twice, exit 0."""
    held: list[tuple[dict[str, Any], Path]] = []
    for s in sessions:
        flights = session_flights(s)
        if (repeat := repeated_flight(flights, held)) is not None:
            raise InputError(f"holds a flight that {repeat[0]} holds already ({repeat[1]}): merging it again would "
                             "put its images into the model twice", s.path)
        held += [(f, s.path) for f in flights]
    return [f for f, _ in held]


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
    one refit, not what `merge --refine` / `batch --refine` do (`merge.refined_answer`); kept as the baseline the
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
