"""Batch tasks: top-level functions with picklable arguments, run in worker processes (map, match + verify,
merge, changes)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ...database.atomic import write_text_atomic
from ...plugin.errors import InputError
from ...plugin.multisession import (
    Sim3,
    verify_alignments,
)
from ...plugin.params import Params
from .discovery import images_dir

log = logging.getLogger(__name__)


def _session_summary(name: str, kind: str, session_dir: Path) -> dict[str, Any]:
    from ...database.colmap_model import load_reconstruction
    from ...database.session_io import read_session

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
        "center": centres.mean(0).tolist() if len(centres) else None,
    }


def map_task(name: str, kind: str, flight: str, session_dir: str, params: Params, ekf: bool,
             overwrite: bool = False) -> dict[str, Any]:
    """Map one flight into `session_dir` (or adopt an already mapped one) and summarise the session.

    `overwrite`: replace a complete session of other inputs or parameters there (BatchOptions.overwrite)."""
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

        inputs = PosesFromImages(images_dir(flight_path), params)
    else:
        raise ValueError(f"unknown flight kind {kind!r}")
    map_workflow.run(params, inputs, out, overwrite=overwrite, progress=False)
    return _session_summary(name, kind, out)


def pair_task(session_a: str, session_b: str, pair_dir: str, params: Params,
              verify: dict[str, Any] | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Match two mapped sessions into pair_dir/match.json and summarise the chosen hypothesis.

    With `verify` (keyword arguments of `verify_pair`; batch passes them unless BatchOptions.verify is off),
    every window hypothesis is then checked and refined on the full maps, the result is written to
    pair_dir/alignment.json, and the summary's `accepted`, `transform` and `num_associations` are the verified
    alignment's (the match's own are kept as `match_accepted`, `match_transform`, `match_associations`).
    `overwrite`: replace a complete match of other maps or settings in pair_dir (BatchOptions.overwrite).
    """
    from .. import match as match_workflow

    # workers=1: the task already runs in a worker process; nested pools would oversubscribe the cores
    res = match_workflow.run(params, session_a, session_b, pair_dir, workers=1, overwrite=overwrite)
    summary = summarise_match(Path(pair_dir) / "match.json")
    if verify is None:
        return summary
    cands = [(h.transform, h.associations[:, 1]) for h in sorted(res.search.hypotheses, key=lambda h: -h.size)
             if h.transform is not None and h.tilt_deg <= params.association.max_gravity_angle_deg]
    return {**summary, **verify_pair(res.map_a.lmap, res.map_b.lmap, cands, Path(pair_dir), params, **verify)}


def verify_pair(map_a: Any, map_b: Any, candidates: list[tuple[Any, np.ndarray]], pair_dir: Path,
                params: Params, dof: int = 4, min_ratio: float = 1.2, z_weight: float = 0.5,
                max_candidates: int = 400, final_dof: int | None = 6) -> dict[str, Any]:
    """Verify a pair's window hypotheses on the full landmark maps (`plugin.multisession.verify_alignments`:
    mutual nearest neighbours within theta_eps that pass the size gate theta_r, ICP-refined with `dof` 4 =
    yaw + translation, the winner finally refitted with `final_dof` 6 on its pairs), write
    pair_dir/alignment.json and return the summary fields it overrides.

    `max_candidates` bounds the work on dense same-season maps (the largest hypotheses are tried first).
    """
    from ...database.match_io import read_match

    a_p, b_p = np.asarray(map_a.positions, np.float64), np.asarray(map_b.positions, np.float64)
    ap = params.association
    sims = [(Sim3(t.rotation, t.translation, t.scale), idx) for t, idx in candidates[:max_candidates]]
    v = verify_alignments(a_p, map_a.sizes, b_p, map_b.sizes, sims, ap.distance_tolerance_m, ap.max_size_difference,
                          ap.min_associations, min_ratio=min_ratio, dof=dof, z_weight=z_weight, final_dof=final_dof)
    match = read_match(pair_dir / "match.json")
    out = {
        "match_accepted": bool(match.accepted),
        "match_transform": match.transform.to_dict() if match.transform is not None else None,
        "match_associations": int(len(match.associations)),
        "accepted": bool(v.accepted),
        "transform": v.best.transform.to_dict() if v.best is not None else None,
        "num_associations": int(len(v.best.associations)) if v.best is not None else 0,
        "runner_up_support": int(v.runner_up_support),
        "alignment": str(pair_dir / "alignment.json"),
    }
    doc = {
        "format": "sosmatch alignment v1",
        "method": {"dof": dof, "final_dof": final_dof, "gate_m": ap.distance_tolerance_m,
                   "max_size_difference": ap.max_size_difference, "min_support": ap.min_associations,
                   "min_ratio": min_ratio, "z_weight": z_weight,
                   "candidates": len(sims), "refined": v.num_refined},
        "accepted": out["accepted"], "transform": out["transform"],
        "support": out["num_associations"], "runner_up_support": out["runner_up_support"],
        "rms_m": v.best.rms_m if v.best is not None and np.isfinite(v.best.rms_m) else None,
        "associations": v.best.associations.tolist() if v.best is not None else [],
        "match_transform": out["match_transform"],
    }
    write_text_atomic(pair_dir / "alignment.json", json.dumps(doc, indent=1) + "\n")
    return out


def read_associations(path: str | Path) -> np.ndarray:
    """(K,2) landmark associations of a pair: alignment.json's (verified) or match.json's."""
    from ...database.match_io import parse_associations, read_match

    path = Path(path)
    if path.name == "alignment.json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise InputError(f"cannot read alignment file: {exc}", path) from None
        if not isinstance(data, dict):
            raise InputError("alignment file must hold a JSON object", path)
        return parse_associations(data.get("associations"), "associations", path)
    return read_match(path).associations


def summarise_match(match_json: Path) -> dict[str, Any]:
    """The part of a match.json the batch report and the session graph need."""
    from ...database.match_io import read_match

    m = read_match(match_json)
    return {
        "match": str(match_json),
        "accepted": bool(m.accepted),
        "num_associations": int(len(m.associations)),
        "num_hypotheses": int(m.num_hypotheses),
        "transform": m.transform.to_dict() if m.transform is not None else None,
    }


def merge_task(
    session_dirs: list[str],
    labels: list[str],
    transforms: list[dict],
    edges: list[tuple[int, int, str]],
    out_dir: str,
    max_fuse_distance_m: float,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Merge one connected group: sessions in the reference frame, landmarks fused along the tree edges
    (a, b, alignment.json or match.json path); writes out_dir (see `sosmatch.workflows.merge`)."""
    from ...database.match_io import check_match_maps, read_match
    from ...database.session_io import read_session
    from ..merge import merge_sessions

    sessions = [read_session(p, lb) for p, lb in zip(session_dirs, labels)]
    sims = [Sim3.from_dict(t) for t in transforms]
    for a, b, m in edges:  # the pair's match (beside its alignment) must be about these two sessions
        match_json = Path(m).parent / "match.json"
        check_match_maps(read_match(match_json), sessions[a].landmarks, sessions[b].landmarks, match_json,
                         names=(labels[a], labels[b]))
    pairs = [(a, b, read_associations(m)) for a, b, m in edges]
    res = merge_sessions(sessions, sims, pairs, out_dir, labels=labels, max_fuse_distance_m=max_fuse_distance_m,
                         record={"tree_edges": [[labels[a], labels[b], m] for a, b, m in edges]},
                         inputs=[m for _, _, m in edges], overwrite=overwrite)
    return {
        "merged": out_dir, "images": res.num_images, "points3D": res.num_points3d,
        "landmarks": res.num_landmarks, "fused": res.num_fused, "rejected_associations": res.num_rejected,
    }


def changes_task(session_a: str, session_b: str, out_dir: str, transform: dict, params: Params,
                 overwrite: bool = False) -> dict[str, Any]:
    """Change detection of one accepted pair with its (verified) alignment a_from_b into out_dir
    (`sosmatch.workflows.changes`); returns the counts for the report. `overwrite`: replace a complete changes
    output of other inputs there (BatchOptions.overwrite)."""
    from ...database.outputs import open_output_dir
    from .. import changes

    run = changes.compute(session_a, session_b, None, params, a_from_b=Sim3.from_dict(transform))
    with open_output_dir(out_dir, "changes", changes.output_identity(run, params, True),
                         inputs=[session_a, session_b], overwrite=overwrite, legacy_record="changes.json") as out:
        changes.write_outputs(run, out.path, params)
        out.finish()
    counts = run.result.counts()
    return {"changes": str(Path(out_dir) / "changes.json"), "gone": counts["gone"], "new": counts["new"],
            "kept": counts["kept_a"], "unseen": counts["unseen_a"] + counts["unseen_b"],
            "changes_summary": run.summary()}
