"""Batch tasks: top-level functions with picklable arguments, run in worker processes (map, match (its verification
included), the alignment control of merge, merge, changes)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...plugin.multisession import Sim3
from ...plugin.params import Params
from .discovery import images_dir

if TYPE_CHECKING:
    from ...database.match_io import MatchSummary
    from ..merge_refine import Refinement

log = logging.getLogger(__name__)


def _session_summary(name: str, kind: str, session_dir: Path) -> dict[str, Any]:
    from ...database.colmap_model import load_reconstruction
    from ...database.session_io import georeference_sigma_m, read_session

    s = read_session(session_dir, name)
    rec = load_reconstruction(s.sparse_dir)
    centres = np.array([img.projection_center() for img in rec.images.values() if img.has_pose]).reshape(-1, 3)
    return {
        "name": name,
        "kind": kind,
        "session": str(session_dir),
        "images": int(rec.num_images()),
        "points3D": int(rec.num_points3D()),
        "landmarks": len(s.landmarks),
        "epsg": int(s.landmarks.epsg),
        # how precise its georeference is (the measured GPS noise; None: not known): a merged group keeps the
        # most precise one
        "georeference_sigma_m": georeference_sigma_m(session_dir) if s.landmarks.epsg else None,
        "center": centres.mean(0).tolist() if len(centres) else None,
    }


def map_task(name: str, kind: str, flight: str, session_dir: str, params: Params, ekf: bool,
             overwrite: bool = False, epsg: int | None = None) -> dict[str, Any]:
    """Map one flight into `session_dir` (or adopt an already mapped one) and summarise the session.

    `overwrite`: replace a complete session of other inputs or parameters there (BatchOptions.overwrite). `epsg`:
    the projected CRS of a folder of photos' poses (BatchOptions.epsg; None: the UTM zone of its median fix)."""
    from .. import map as map_workflow

    flight_path, out = Path(flight), Path(session_dir)
    if kind == "mapped":
        return _session_summary(name, kind, flight_path)
    if kind == "synth":
        inputs = map_workflow.load_inputs(None, flight_path, ekf=ekf)
    elif kind == "poses":
        cameras = flight_path / "cameras.txt"
        inputs = map_workflow.load_inputs(images_dir(flight_path), flight_path / "poses.csv",
                                          cameras if cameras.is_file() else None)
    elif kind == "opensfm":
        inputs = map_workflow.load_inputs(images_dir(flight_path), flight_path / "opensfm" / "reconstruction.json")
    elif kind == "images":  # structure from motion inside the session directory (OUT/sessions/NAME/poses)
        from ..poses import PosesFromImages

        inputs = PosesFromImages(images_dir(flight_path), params, epsg=epsg)
    else:
        raise ValueError(f"unknown flight kind {kind!r}")
    map_workflow.run(params, inputs, out, overwrite=overwrite, progress=False)
    return _session_summary(name, kind, out)


def pair_task(session_a: str, session_b: str, pair_dir: str, params: Params, verify: bool = True,
              overwrite: bool = False, transform_chosen: bool = False) -> dict[str, Any]:
    """Match two mapped sessions into pair_dir/match.json and summarise its answer.

    `sosmatch match` verifies the window hypotheses on the full maps unless `verify` is off (BatchOptions.verify);
    the summary's `accepted`, `transform` and `num_associations` are the answer's (the verified alignment's), the
    window consensus is kept as `match_accepted`, `match_transform`, `match_associations`.
    `overwrite`: replace a complete match of other maps or settings in pair_dir (BatchOptions.overwrite).
    `transform_chosen`: the user chose `association.transform` (BatchOptions.transform_chosen); else a pair with a
    flight of structure-from-motion poses is matched with a similarity, as `sosmatch match` does.
    """
    from .. import match as match_workflow

    match_workflow.run(params, session_a, session_b, pair_dir, overwrite=overwrite, verify=verify,
                       transform_chosen=transform_chosen)
    return summarise_match(Path(pair_dir) / "match.json")


def summarise_match(match_json: Path) -> dict[str, Any]:
    """The part of a match.json the batch report and the session graph need: the answer (verified unless the
    match ran without verification) and the window consensus it came from."""
    from ...database.match_io import read_match

    m = read_match(match_json)
    return {
        "match": str(match_json),
        "accepted": bool(m.accepted),
        # an answer's associations; a refused candidate's support is no association (the report printed the two
        # in one column)
        "num_associations": int(len(m.associations)) if m.accepted else 0,
        "refused_support": None if m.accepted else int(len(m.associations)),
        "num_hypotheses": int(m.num_hypotheses),
        "transform": m.transform.to_dict() if m.transform is not None and m.accepted else None,
        "answer": m.source,
        "match_accepted": bool(m.consensus_accepted),
        "match_transform": m.consensus_transform.to_dict() if m.consensus_transform is not None else None,
        "match_associations": int(len(m.consensus_associations)),
        "runner_up_support": m.runner_up_support,
    }


def alignment_task(session_a: str, session_b: str, match_json: str, transform: dict, params: Params,
                   match: MatchSummary | None = None) -> dict[str, Any]:
    """The control `sosmatch merge` applies before it merges a pair (`changes.check_alignment`: does the
    transform a_from_b bring the two maps together, by the counterpart rate of A's landmarks that B's keyframes
    saw, at the match's own gate), for a pair before it joins the session graph: `merge_sessions` does not apply
    it, and `batch --no-verify` fused an unverified consensus 680 m off into a group. `match`: match_json as
    `match_io.read_match` parsed it (batch reads each pair's once; None: read here). Returns {"refused": None}
    or {"refused": the control's one-line reason, also for an InputError of the pair's files}; anything else
    raised is no verdict on the pair and fails the task (the batch reports the pair failed)."""
    from ...database.match_io import answer_gate, read_match
    from ...database.session_io import read_session
    from ...plugin.errors import InputError
    from ..changes import check_alignment

    try:
        match = match if match is not None else read_match(match_json)
        gate = answer_gate(match, params.association.distance_tolerance_m)  # as merge: the answer's own gate
        check_alignment(read_session(session_a), read_session(session_b), Sim3.from_dict(transform), params,
                        match.source == "verified", gate, match_json, "left out of the session graph")
    except InputError as e:
        return {"refused": str(e)}
    return {"refused": None}


def merge_task(
    session_dirs: list[str],
    labels: list[str],
    transforms: list[dict],
    edges: list[tuple[int, int, str]],
    out_dir: str,
    max_fuse_distance_m: float,
    overwrite: bool = False,
    matches: list[MatchSummary] | None = None,
    refinements: list[Refinement | None] | None = None,
) -> dict[str, Any]:
    """Merge one connected group: sessions in the reference frame, landmarks fused along the tree edges
    (a, b, match.json path); writes out_dir (see `sosmatch.workflows.merge`). `matches`: each edge's match.json
    as `match_io.read_match` parsed it (batch reads each pair's once; None: read here). `refinements`: each
    edge's `merge_refine.refined_answer` under `batch --refine` (None: not refined): a refined edge fuses the pairs
    its refined transform supports (`Refinement.fuse`), as `sosmatch merge --refine` does, and merge.json's
    `refine` records each refined edge's fit."""
    from ...database.match_io import check_match_maps, read_match
    from ...database.match_notes import georeference_note
    from ...database.session_io import read_session
    from ..merge import merge_sessions
    from ..merge_refine import fused_pair

    sessions = [read_session(p, lb) for p, lb in zip(session_dirs, labels)]
    sims = [Sim3.from_dict(t) for t in transforms]
    pairs, warnings, refined = [], [], []
    # the pair's match must be about these two sessions; its answer fused at its own gate
    for k, (a, b, m) in enumerate(edges):
        match_json = Path(m)
        match = matches[k] if matches is not None else read_match(match_json)
        check_match_maps(match, sessions[a].landmarks, sessions[b].landmarks, match_json, names=(labels[a], labels[b]))
        r = refinements[k] if refinements is not None else None
        # refined: the pairs the refined transform supports (rev46 D2: the match's own fused 9 where merge --refine
        # fused 18 of the same maps); kept (`Refinement.note`): the answer's own
        pairs.append(fused_pair(a, b, match, r))
        if r is not None:
            refined.append({"pair": [labels[a], labels[b]], **r.record()})
        if (note := georeference_note(match)) is not None:  # the merged model inherits it (merge.json)
            warnings.append(f"{labels[b]}: {note}")
    res = merge_sessions(sessions, sims, pairs, out_dir, labels=labels, max_fuse_distance_m=max_fuse_distance_m,
                         record={"tree_edges": [[labels[a], labels[b], m] for a, b, m in edges],
                                 **({"refine": refined} if refined else {})},
                         inputs=[m for _, _, m in edges], overwrite=overwrite, warnings=warnings)
    return {
        "merged": out_dir, "images": res.num_images, "points3D": res.num_points3d,
        "landmarks": res.num_landmarks, "fused": res.num_fused, "rejected_associations": res.num_rejected,
        **({"warnings": warnings} if warnings else {}),
    }


# batch has no --images-a / --images-b: it reads a flight's images in its folder, a mapped session's where its
# run.json records them
BATCH_IMAGES_ADVICE = ("batch reads a mapped session's images in the directory its run.json records: put them back "
                       "there, or give batch the flight folder (images with poses) in place of the mapped session")


def changes_task(session_a: str, session_b: str, out_dir: str, transform: dict, params: Params,
                 overwrite: bool = False, verified: bool = True, images_a: str | None = None,
                 images_b: str | None = None, answer_gate_m: float | None = None,
                 match_json: str | None = None) -> dict[str, Any]:
    """Change detection of one accepted pair with its alignment a_from_b into out_dir
    (`sosmatch.workflows.changes`); returns its record and summary. `overwrite`: replace a complete changes
    output of other inputs there (BatchOptions.overwrite); `verified`: the match's answer is its verification's
    (`changes.compute` then trusts it unless its counterparts are at chance level). `images_a`, `images_b`: where
    the flights' images are now (a flights folder moved after mapping; None: where the session's run.json
    recorded them). `answer_gate_m`: the pair's match's theta_eps (`match_io.answer_gate`), the gate of the
    alignment control as in `alignment_task` (None: the configured one). `match_json`: the pair's match, which
    `changes.compute` checks and its record names as `sosmatch changes --match` does (rev48 D4: "match": "").
    The paths are recorded as given: batch gives them absolute, as the standalone command records the images."""
    from ...database.outputs import open_output_dir
    from .. import changes

    run = changes.compute(session_a, session_b, match_json, params, a_from_b=Sim3.from_dict(transform),
                          verified=verified, images_a=images_a, images_b=images_b, answer_gate_m=answer_gate_m,
                          images_advice=BATCH_IMAGES_ADVICE)
    with open_output_dir(out_dir, "changes", changes.output_identity(run, params, True),
                         inputs=[session_a, session_b], overwrite=overwrite, legacy_record="changes.json",
                         files=changes.OUTPUT_FILES) as out:
        changes.write_outputs(run, out, params)
        out.finish()
    # the counts the batch reports are read from changes.json (`workflow._changes_record`), also of a comparison a
    # resumed batch finds finished
    return {"changes": str(Path(out_dir) / "changes.json"), "changes_summary": run.summary()}
