"""`sosmatch batch FLIGHTS_DIR --out OUT`: map every flight, match session pairs, merge connected groups.

Stages, each a set of independent tasks run by an executor (`sosmatch.workflows.executors`: local worker
processes, or a Dask cluster):
1. discovery: one sub-folder of FLIGHTS_DIR per flight (`discover_flights`), recognised as
   - "mapped": already a mapped session (sparse/, landmarks.sosmap, landmarks.csv): used as it is;
   - "synth": a `sosmatch synth` session (session.json, poses.csv, images/, cameras.txt);
   - "poses": images (in images/ or the folder itself) with a pose file poses.csv (and cameras.txt);
   - "exif": geotagged images and no pose file: poses and intrinsics come from EXIF
     (`sosmatch.workflows.poses_from_exif`).
2. map: each flight -> OUT/sessions/NAME (`sosmatch.workflows.map`);
3. match: every pair of mapped sessions, or with `nearest=k` only pairs where one session is among the k
   nearest of the other (by mean camera position; needs all sessions in one frame: same EPSG code, or the
   same local frame) -> OUT/pairs/A__B/match.json; then (BatchOptions.verify, on by default) every window
   hypothesis is checked on the FULL maps and the best supported one is refined there (`verify_pair`: size-gated
   mutual nearest neighbours within theta_eps, iterated 4-DOF fit) -> OUT/pairs/A__B/alignment.json, whose
   decision, transform and associations the graph and the merge use. Why: across seasons one window pair's |S|
   is no larger for a true hypothesis than for chance ones, and one window's 8-20 inliers give a noisy rotation;
   see BENCHMARKS.md, Multi-session;
4. session graph: sessions are nodes, accepted pairs are edges carrying a_from_b and |S|; accepted pairs
   that contradict others linking the same groups are left out (`plugin.multisession.consistent_edges`); each connected
   group is brought into the frame of its best-connected session along a maximum spanning tree
   (`sosmatch.plugin.multisession.spanning_transforms`) and merged (`sosmatch.workflows.merge.merge_sessions`)
   -> OUT/merged/REFERENCE/;
5. report: OUT/report.json, OUT/report.md (a table per session and per pair), OUT/session_graph.png.

Resume: every finished task writes OUT/state/STAGE/KEY.json atomically, holding a fingerprint of its inputs
(flight, parameters, upstream fingerprints) and its result (paths relative to OUT, so a moved OUT resumes).
A re-run skips tasks whose state matches and whose outputs still exist, so an interrupted batch continues
where it stopped; changing parameters redoes what they affect. A failing task is reported with its error
(traceback in OUT/logs/), the tasks that need its output are reported as skipped, and every other task goes
on. `BatchReport.ok` (and the command's exit code) says whether anything failed.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import time
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import write_text_atomic
from ..plugin.errors import InputError
from ..plugin.multisession import (
    Edge,
    Sim3,
    connected_groups,
    consistent_edges,
    nearest_pairs,
    spanning_transforms,
    verify_alignments,
)
from ..plugin.params import Params, params_to_dict
from .executors import Executor, LocalExecutor, TaskResult

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
STATE_VERSION = 2  # 2: paths relative to OUT
PAIR_SEP = "__"


# --- discovery ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Flight:
    """One flight folder and how it will be mapped."""

    name: str
    path: Path
    kind: str  # "mapped" | "synth" | "poses" | "exif"


def _images_dir(folder: Path) -> Path | None:
    for cand in (folder / "images", folder):
        if cand.is_dir() and any(f.suffix.lower() in IMAGE_EXTENSIONS for f in cand.iterdir() if f.is_file()):
            return cand
    return None


def classify_flight(folder: Path) -> str | None:
    """The kind of a flight folder (see the module doc), or None when it is not a flight."""
    if (folder / "sparse").is_dir() and all((folder / f).is_file() for f in ("landmarks.sosmap", "landmarks.csv")):
        return "mapped"
    if (folder / "session.json").is_file() and (folder / "poses.csv").is_file():
        return "synth"
    if _images_dir(folder) is None:
        return None
    return "poses" if (folder / "poses.csv").is_file() else "exif"


def discover_flights(flights_dir: str | Path, exclude: tuple[Path, ...] = ()) -> list[Flight]:
    """Flights in the sub-folders of `flights_dir`, sorted by name; hidden folders and `exclude` are skipped."""
    root = Path(flights_dir)
    if not root.is_dir():
        raise InputError("flights directory not found", root)
    excluded = {p.resolve() for p in exclude}
    flights = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        if folder.name.startswith((".", "_")) or folder.resolve() in excluded:
            continue
        if PAIR_SEP in folder.name:
            raise InputError(f"flight folder names may not contain {PAIR_SEP!r} (used for pair names)", folder)
        kind = classify_flight(folder)
        if kind is None:
            log.info("%s: no images, pose file or mapped session; not a flight", folder)
            continue
        flights.append(Flight(folder.name, folder, kind))
    if not flights:
        raise InputError("no flights found (one folder per flight: images with poses.csv, geotagged images, "
                         "a synth session or a mapped session)", root)
    return flights


# --- tasks (top-level functions with picklable arguments: they run in worker processes) -------------------------


def _session_summary(name: str, kind: str, session_dir: Path) -> dict[str, Any]:
    import pycolmap

    from ..database.session_io import read_session

    s = read_session(session_dir, name)
    rec = pycolmap.Reconstruction(str(s.sparse_dir))
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


def map_task(name: str, kind: str, flight: str, session_dir: str, params: Params, ekf: bool) -> dict[str, Any]:
    """Map one flight into `session_dir` (or adopt an already mapped one) and summarise the session."""
    from . import map as map_workflow

    flight_path, out = Path(flight), Path(session_dir)
    if kind == "mapped":
        return _session_summary(name, kind, flight_path)
    if kind == "synth":
        inputs = map_workflow.load_inputs(None, flight_path, ekf=ekf)
    elif kind == "poses":
        cameras = flight_path / "cameras.txt"
        inputs = map_workflow.load_inputs(_images_dir(flight_path), flight_path / "poses.csv",
                                          cameras if cameras.is_file() else None)
    elif kind == "exif":
        from . import poses_from_exif

        images = _images_dir(flight_path)
        exif_dir = out.parent / f".{name}.exif"
        poses_from_exif.run(images, exif_dir / "poses.csv")
        inputs = map_workflow.load_inputs(images, exif_dir / "poses.csv", exif_dir / "cameras.txt")
    else:
        raise ValueError(f"unknown flight kind {kind!r}")
    map_workflow.run(params, inputs, out, overwrite=True, progress=False)
    return _session_summary(name, kind, out)


def pair_task(session_a: str, session_b: str, pair_dir: str, params: Params,
              verify: dict[str, Any] | None = None) -> dict[str, Any]:
    """Match two mapped sessions into pair_dir/match.json and summarise the chosen hypothesis.

    With `verify` (keyword arguments of `verify_pair`; batch passes them unless BatchOptions.verify is off),
    every window hypothesis is then checked and refined on the full maps, the result is written to
    pair_dir/alignment.json, and the summary's `accepted`, `transform` and `num_associations` are the verified
    alignment's (the match's own are kept as `match_accepted`, `match_transform`, `match_associations`).
    """
    from . import match as match_workflow

    # workers=1: the task already runs in a worker process; nested pools would oversubscribe the cores
    res = match_workflow.run(params, session_a, session_b, pair_dir, workers=1)
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
    from ..database.match_io import read_match

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
    from ..database.match_io import read_match

    path = Path(path)
    if path.name == "alignment.json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            return np.asarray(data["associations"], dtype=np.int64).reshape(-1, 2)
        except (OSError, KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise InputError(f"cannot read alignment file: {exc}", path) from None
    return read_match(path).associations


def summarise_match(match_json: Path) -> dict[str, Any]:
    """The part of a match.json the batch report and the session graph need."""
    from ..database.match_io import read_match

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
) -> dict[str, Any]:
    """Merge one connected group: sessions in the reference frame, landmarks fused along the tree edges
    (a, b, alignment.json or match.json path); writes out_dir (see `sosmatch.workflows.merge`)."""
    from ..database.session_io import read_session
    from .merge import merge_sessions, write_merge_record

    sessions = [read_session(p, lb) for p, lb in zip(session_dirs, labels)]
    sims = [Sim3.from_dict(t) for t in transforms]
    pairs = [(a, b, read_associations(m)) for a, b, m in edges]
    res = merge_sessions(sessions, sims, pairs, out_dir, labels=labels, max_fuse_distance_m=max_fuse_distance_m)
    write_merge_record(res, {"tree_edges": [[labels[a], labels[b], m] for a, b, m in edges]})
    return {
        "merged": out_dir, "images": res.num_images, "points3D": res.num_points3d,
        "landmarks": res.num_landmarks, "fused": res.num_fused, "rejected_associations": res.num_rejected,
    }


# --- state (resume) ----------------------------------------------------------------------------------------------


def _fingerprint(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


PATH_KEYS = ("session", "match", "alignment", "merged")  # result fields that hold paths


class StateStore:
    """OUT/state/STAGE/KEY.json: the fingerprint and result of every finished task, written atomically.

    Paths inside OUT are stored relative to OUT (`base`), so a moved or copied OUT directory still resumes;
    paths outside it (an already mapped flight adopted as it is) stay as they are.
    """

    def __init__(self, root: Path, base: Path | None = None) -> None:
        self.root = root
        self.base = base if base is not None else root.parent

    def _relative(self, result: dict[str, Any]) -> dict[str, Any]:
        out = dict(result)
        base = self.base.resolve()
        for key in PATH_KEYS:
            if isinstance(out.get(key), str):
                try:
                    out[key] = Path(out[key]).resolve().relative_to(base).as_posix()
                except ValueError:
                    pass  # outside OUT: keep it absolute
        return out

    def _absolute(self, result: dict[str, Any]) -> dict[str, Any]:
        out = dict(result)
        for key in PATH_KEYS:
            if isinstance(out.get(key), str) and not Path(out[key]).is_absolute():
                out[key] = str(self.base / out[key])
        return out

    def _path(self, stage: str, key: str) -> Path:
        return self.root / stage / f"{key}.json"

    def get(self, stage: str, key: str, fingerprint: str) -> dict[str, Any] | None:
        path = self._path(stage, key)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return None
        if data.get("version") != STATE_VERSION or data.get("fingerprint") != fingerprint:
            return None
        result = data.get("result")
        return self._absolute(result) if isinstance(result, dict) else None

    def put(self, stage: str, key: str, fingerprint: str, result: dict[str, Any]) -> None:
        data = {"version": STATE_VERSION, "fingerprint": fingerprint, "result": self._relative(result)}
        write_text_atomic(self._path(stage, key), json.dumps(data, indent=1, sort_keys=True) + "\n")


# --- the batch ----------------------------------------------------------------------------------------------------


@dataclass
class BatchOptions:
    """How to run a batch (parameters of the method live in Params)."""

    nearest: int | None = None  # match only the k nearest pairs (None: every pair)
    ekf: bool = False  # synth flights: map with the noisy poses_ekf.csv instead of the ground truth
    merge: bool = True
    refine: bool = False  # (legacy, without verify) consensus transforms re-fitted on their own associations
    # Verify every pair's window hypotheses on the full maps and refine the winner (`verify_pair`); off = the
    # match's consensus as it is. BENCHMARKS.md, Multi-session, has what each step does to the errors.
    verify: bool = True
    verify_dof: int = 4  # 4: yaw + translation (gravity-aligned maps); 6: rigid
    verify_final_dof: int | None = 6  # the winner refitted 6-DOF on its pairs (None: keep the verify_dof fit)
    verify_min_ratio: float = 1.2  # (ours) the winner's support over the best disagreeing alignment's
    edge_tolerance_m: float = 5.0  # (ours) two accepted pairs agree if they place sessions within this distance
    progress: bool = True


@dataclass
class BatchReport:
    """Everything the batch did; also written as OUT/report.json (and .md)."""

    out_dir: Path
    sessions: list[dict[str, Any]] = field(default_factory=list)
    pairs: list[dict[str, Any]] = field(default_factory=list)
    groups: list[dict[str, Any]] = field(default_factory=list)
    executor: str = ""
    seconds: float = 0.0

    @property
    def failures(self) -> list[str]:
        items = [("session", s["name"], s) for s in self.sessions] + [("pair", p["pair"], p) for p in self.pairs]
        items += [("group", g["reference"], g) for g in self.groups]
        return [f"{kind} {name}: {x.get('error', '')}" for kind, name, x in items if x["status"] == "failed"]

    @property
    def ok(self) -> bool:
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "sosmatch batch report v1",
            "ok": self.ok,
            "failures": self.failures,
            "executor": self.executor,
            "seconds": round(self.seconds, 3),
            "sessions": self.sessions,
            "pairs": self.pairs,
            "groups": self.groups,
        }


def _record(result: TaskResult, log_dir: Path, stage: str, key: str) -> dict[str, Any]:
    if result.ok:
        return {"status": "done", "seconds": round(result.seconds, 3), **result.value}
    write_text_atomic(log_dir / f"{stage}-{key}.log", result.traceback or result.error)
    log.warning("%s %s failed: %s", stage, key, result.error)
    return {"status": "failed", "error": result.error.splitlines()[0] if result.error else "failed",
            "seconds": round(result.seconds, 3)}


def _run_stage(
    executor: Executor, fn: Any, tasks: dict[str, tuple], fingerprints: dict[str, str], state: StateStore,
    stage: str, out_dir: Path, desc: str, progress: bool, still_valid: Any = None,
) -> dict[str, dict[str, Any]]:
    """Skip tasks whose state matches, run the rest, save the state of those that succeed."""
    records: dict[str, dict[str, Any]] = {}
    todo = {}
    for key, args in tasks.items():
        done = state.get(stage, key, fingerprints[key])
        if done is not None and (still_valid is None or still_valid(done)):
            records[key] = {**done, "status": "done", "resumed": True}
        else:
            todo[key] = args
    if todo:
        results = executor.run(fn, todo, desc=desc, progress=progress)
        for key, res in results.items():
            rec = _record(res, out_dir / "logs", stage, key)
            if res.ok:
                state.put(stage, key, fingerprints[key], {k: v for k, v in rec.items() if k != "status"})
            records[key] = rec
    return {key: records[key] for key in tasks}


def _valid_session(done: dict[str, Any]) -> bool:
    p = Path(done.get("session", ""))
    return (p / "landmarks.sosmap").is_file() and (p / "sparse").is_dir()


def _valid_match(done: dict[str, Any]) -> bool:
    return Path(done.get("match", "")).is_file() and ("alignment" not in done or Path(done["alignment"]).is_file())


def _associations_file(rec: dict[str, Any]) -> str:
    """The file whose associations a merge fuses: the verified alignment's, else the match's."""
    return rec.get("alignment") or rec["match"]


def _valid_merge(done: dict[str, Any]) -> bool:
    return (Path(done.get("merged", "")) / "merge.json").is_file()


def _choose_pairs(names: list[str], sessions: dict[str, dict[str, Any]], nearest: int | None) -> list[tuple[str, str]]:
    all_pairs = list(combinations(names, 2))
    if nearest is None:
        return all_pairs
    centres = [sessions[n].get("center") for n in names]
    epsgs = {sessions[n].get("epsg") for n in names}
    if any(c is None for c in centres) or len(epsgs) > 1:
        log.warning("--nearest needs every session's position in one frame; matching all %d pairs", len(all_pairs))
        return all_pairs
    return [(names[i], names[j]) for i, j in nearest_pairs(np.asarray(centres), nearest)]


def run(
    flights_dir: str | Path,
    out_dir: str | Path,
    params: Params | None = None,
    executor: Executor | None = None,
    options: BatchOptions | None = None,
    pair_fn: Any = None,
) -> BatchReport:
    """Run (or resume) a batch; see the module doc. Returns the report (also written under out_dir).

    `pair_fn` replaces the matching task (default `pair_task`); it must be a top-level function with the same
    signature, e.g. `sosmatch.tools.toy_sessions.oracle_pair_task` to test the later stages on toy sessions.
    """
    t0 = time.perf_counter()
    params = params or Params()
    options = options or BatchOptions()
    out_dir = Path(out_dir)
    own_executor = executor is None
    executor = executor or LocalExecutor(1)
    flights = discover_flights(flights_dir, exclude=(out_dir,))
    out_dir.mkdir(parents=True, exist_ok=True)
    state = StateStore(out_dir / "state", out_dir)
    pdict = params_to_dict(params)
    report = BatchReport(out_dir, executor=executor.describe())
    try:
        # 1-2: map
        fps, tasks = {}, {}
        for f in flights:
            fps[f.name] = _fingerprint({"flight": str(f.path.resolve()), "kind": f.kind, "params": pdict,
                                        "ekf": options.ekf})
            tasks[f.name] = (f.name, f.kind, str(f.path), str(out_dir / "sessions" / f.name), params, options.ekf)
        sessions = _run_stage(executor, map_task, tasks, fps, state, "map", out_dir, "map flights",
                              options.progress, _valid_session)
        report.sessions = [{"name": f.name, "kind": f.kind, **sessions[f.name]} for f in flights]
        mapped = [f.name for f in flights if sessions[f.name]["status"] == "done"]

        # 3: match
        chosen = _choose_pairs(mapped, sessions, options.nearest)
        matcher = pair_fn or pair_task
        # a custom matcher (pair_fn) returns its own summary; only the default one verifies
        verify = ({"dof": options.verify_dof, "min_ratio": options.verify_min_ratio,
                   "final_dof": options.verify_final_dof}
                  if options.verify and matcher is pair_task else None)
        pair_fps, pair_tasks = {}, {}
        for a, b in chosen:
            key = f"{a}{PAIR_SEP}{b}"
            pair_fps[key] = _fingerprint({"a": fps[a], "b": fps[b], "association": pdict["association"],
                                          "seed": pdict["seed"], "matcher": matcher.__qualname__,
                                          "verify": verify})
            pair_tasks[key] = (sessions[a]["session"], sessions[b]["session"], str(out_dir / "pairs" / key), params)
            if verify is not None:
                pair_tasks[key] += (verify,)
        pairs = _run_stage(executor, matcher, pair_tasks, pair_fps, state, "match", out_dir, "match pairs",
                           options.progress, _valid_match)
        failed = [f.name for f in flights if sessions[f.name]["status"] != "done"]

        # 4: session graph (marks each pair's in_graph) and merged groups
        report.groups = _graph_and_merge(report, mapped, sessions, pairs, pair_fps, state, executor, options,
                                         params, out_dir)
        report.pairs = [{"pair": key, "a": key.split(PAIR_SEP)[0], "b": key.split(PAIR_SEP)[1], **rec}
                        for key, rec in pairs.items()]
        report.pairs += [{"pair": f"{a}{PAIR_SEP}{b}", "a": a, "b": b, "status": "skipped",
                          "error": "a session failed to map"}
                         for a, b in combinations([f.name for f in flights], 2) if a in failed or b in failed]
    finally:
        if own_executor:
            executor.close()
    report.seconds = time.perf_counter() - t0
    write_report(report)
    return report


def _graph_and_merge(
    report: BatchReport, names: list[str], sessions: dict[str, dict[str, Any]], pairs: dict[str, dict[str, Any]],
    pair_fps: dict[str, str], state: StateStore, executor: Executor, options: BatchOptions, params: Params,
    out_dir: Path,
) -> list[dict[str, Any]]:
    index = {n: i for i, n in enumerate(names)}
    edges, edge_keys = [], {}
    for key, rec in pairs.items():
        if rec["status"] != "done" or not rec["accepted"] or rec["transform"] is None:
            continue
        a, b = key.split(PAIR_SEP)
        sim = Sim3.from_dict(rec["transform"])
        if options.refine and "alignment" not in rec:
            sim = _refined(sessions[a]["session"], sessions[b]["session"], rec["match"], sim, params)
        edge = Edge(index[a], index[b], sim, float(rec["num_associations"]))
        edges.append(edge)
        edge_keys[(edge.a, edge.b)] = key
    # Accepted pairs that contradict the others are dropped before the graph is used (see consistent_edges).
    probes = [np.asarray(sessions[n].get("center") or [0.0, 0.0, 0.0]) for n in names]
    edges, dropped = consistent_edges(len(names), edges, probes, options.edge_tolerance_m)
    for rec in pairs.values():
        if rec["status"] == "done" and rec["accepted"]:
            rec["in_graph"] = True
    for e in dropped:
        pairs[edge_keys[(e.a, e.b)]]["in_graph"] = False
        log.warning("pair %s contradicts the other accepted pairs; left out of the session graph",
                    edge_keys[(e.a, e.b)])
    groups = []
    merge_tasks, merge_fps = {}, {}
    for members in connected_groups(len(names), edges):
        ref, ref_from, tree = spanning_transforms(members, edges)
        order = [ref] + [m for m in members if m != ref]
        group = {
            "reference": names[ref],
            "members": [names[m] for m in order],
            "tree": [edge_keys[(e.a, e.b)] for e in tree],
            "reference_from_session": {names[m]: ref_from[m].to_dict() for m in order},
        }
        groups.append(group)
        if len(members) < 2 or not options.merge:
            group["status"] = "single" if len(members) < 2 else "not merged"
            continue
        pos = {m: k for k, m in enumerate(order)}
        tree_edges = [(pos[e.a], pos[e.b], _associations_file(pairs[edge_keys[(e.a, e.b)]])) for e in tree]
        key = names[ref]
        merge_fps[key] = _fingerprint({"members": [names[m] for m in order],  # contents: in the pair fps
                                       "pairs": [pair_fps[edge_keys[(e.a, e.b)]] for e in tree],
                                       "transforms": [ref_from[m].to_dict() for m in order],
                                       "eps": params.association.distance_tolerance_m})
        merge_tasks[key] = (
            [sessions[names[m]]["session"] for m in order], [names[m] for m in order],
            [ref_from[m].to_dict() for m in order], tree_edges, str(out_dir / "merged" / key),
            params.association.distance_tolerance_m,
        )
    merged = _run_stage(executor, merge_task, merge_tasks, merge_fps, state, "merge", out_dir, "merge groups",
                        options.progress, _valid_merge)
    for group in groups:
        if group["reference"] in merged:
            group.update(merged[group["reference"]])
    return groups


def _refined(session_a: str, session_b: str, match_json: str, sim: Sim3, params: Params) -> Sim3:
    from ..database.match_io import read_match
    from ..database.session_io import read_session
    from .merge import refine_transform

    m = read_match(match_json)
    refined, _ = refine_transform(read_session(session_a), read_session(session_b), m.associations, sim,
                                  params.association.transform == "similarity", params.association.distance_tolerance_m)
    return refined


# --- report ------------------------------------------------------------------------------------------------------


def _table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return "" if v is None else str(v).replace("|", "/")

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def _pair_rows(report: BatchReport) -> list[dict[str, Any]]:
    rows = []
    for p in report.pairs:
        row = dict(p)
        t = p.get("transform")
        if t:
            rot = np.asarray(t["rotation"])
            row["yaw_deg"] = round(float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))), 3)
            row["shift_m"] = round(float(np.linalg.norm(t["translation"])), 3)
            row["scale"] = round(float(t["scale"]), 5)
        rows.append(row)
    return rows


SESSION_COLUMNS = ["name", "kind", "status", "images", "points3D", "landmarks", "seconds", "error"]
PAIR_COLUMNS = ["pair", "status", "accepted", "in_graph", "num_associations", "yaw_deg", "shift_m", "scale", "seconds",
                "error"]
GROUP_COLUMNS = ["reference", "members", "status", "images", "points3D", "landmarks", "fused", "merged", "error"]


def write_report(report: BatchReport) -> None:
    """OUT/report.json, OUT/report.md, OUT/sessions.csv, OUT/pairs.csv and OUT/session_graph.png."""
    out = report.out_dir
    write_text_atomic(out / "report.json", json.dumps(report.to_dict(), indent=2) + "\n")
    pair_rows = _pair_rows(report)
    groups = [{**g, "members": " ".join(g["members"])} for g in report.groups]
    status = "ok" if report.ok else f"{len(report.failures)} failure(s)"
    md = [
        "# sosmatch batch report", "",
        f"{len(report.sessions)} sessions, {len(report.pairs)} pairs, {len(report.groups)} groups; {status}; "
        f"executor: {report.executor}; {report.seconds:.1f} s", "",
        "## Sessions", "", _table(report.sessions, SESSION_COLUMNS), "",
        "## Pairs", "", "(transform a_from_b: yaw about z, length of the translation, scale)", "",
        _table(pair_rows, PAIR_COLUMNS), "",
        "## Groups (merged models)", "", _table(groups, GROUP_COLUMNS), "",
        "![session graph](session_graph.png)", "",
    ]
    write_text_atomic(out / "report.md", "\n".join(md))
    tables = (("sessions.csv", report.sessions, SESSION_COLUMNS), ("pairs.csv", pair_rows, PAIR_COLUMNS))
    for name, rows, cols in tables:
        buf = io.StringIO()
        w = csv.DictWriter(buf, cols, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out / name, buf.getvalue())
    plot_session_graph(report, out / "session_graph.png")


def plot_session_graph(report: BatchReport, path: Path) -> None:
    """Sessions at their mean camera position (or on a circle), accepted pairs as solid lines labelled |S|,
    rejected pairs dashed, failed pairs dotted red; colour = merged group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..database.atomic import atomic_path

    names = [s["name"] for s in report.sessions]
    n = len(names)
    centres = [s.get("center") for s in report.sessions]
    same_frame = len({s.get("epsg") for s in report.sessions}) == 1
    if n and same_frame and all(c is not None for c in centres):
        xy = np.asarray(centres)[:, :2]
        if n > 1 and np.ptp(xy, axis=0).max() < 1e-6:
            xy = None
    else:
        xy = None
    if xy is None:
        ang = 2 * np.pi * np.arange(n) / max(n, 1)
        xy = np.stack([np.cos(ang), np.sin(ang)], 1)
    pos = {nm: xy[i] for i, nm in enumerate(names)}
    group_of = {m: k for k, g in enumerate(report.groups) for m in g["members"]}
    fig, ax = plt.subplots(figsize=(6, 5))
    for p in report.pairs:
        if p["a"] not in pos or p["b"] not in pos:
            continue
        (x0, y0), (x1, y1) = pos[p["a"]], pos[p["b"]]
        if p["status"] == "done" and p.get("accepted") and p.get("in_graph") is False:
            ax.plot([x0, x1], [y0, y1], "-.", color="tab:orange", lw=1.5, zorder=1)
        elif p["status"] == "done" and p.get("accepted"):
            ax.plot([x0, x1], [y0, y1], "-", color="tab:green", lw=2, zorder=1)
            ax.annotate(str(p.get("num_associations", "")), ((x0 + x1) / 2, (y0 + y1) / 2), fontsize=8,
                        ha="center", color="tab:green")
        elif p["status"] == "done":
            ax.plot([x0, x1], [y0, y1], "--", color="0.6", lw=1, zorder=0)
        else:
            ax.plot([x0, x1], [y0, y1], ":", color="tab:red", lw=1, zorder=0)
    cmap = plt.get_cmap("tab10")
    for s in report.sessions:
        x, y = pos[s["name"]]
        color = "tab:red" if s["status"] != "done" else cmap(group_of.get(s["name"], 0) % 10)
        ax.scatter([x], [y], s=200, color=color, zorder=2, edgecolors="k")
        ax.annotate(s["name"], (x, y), textcoords="offset points", xytext=(8, 8), fontsize=9)
    ax.set_title("session graph: accepted (solid, |S|), contradicted (orange), rejected (dashed), failed (dotted)",
                 fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.margins(0.2)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
