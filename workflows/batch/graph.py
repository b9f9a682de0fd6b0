"""Batch stage 4, the session graph: the accepted pairs' alignments controlled (`alignment_task`), the ones
that contradict the others left out, each connected group brought into one reference frame and merged; and the
outputs of earlier runs that this one no longer uses (see the package doc)."""

from __future__ import annotations

import json
import logging
from collections.abc import Collection, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...database.match_io import MatchSummary
from ...database.session_io import MERGE_RECORD
from ...plugin.multisession import Edge, Sim3, connected_groups, consistent_edges, spanning_transforms
from ...plugin.params import Params
from ...plugin.params.identity import build_versions, each_version
from ..executors import Executor
from .discovery import PAIR_SEP
from .report import BatchReport
from .state import StateStore, fingerprint, run_stage
from .tasks import alignment_task, merge_task

if TYPE_CHECKING:
    from ..merge_refine import Refinement
    from .workflow import BatchOptions

log = logging.getLogger(__name__)

# why an accepted pair is left out of the session graph (`consistent_edges`), as its record's `left_out` says it
CONTRADICTED = "contradicts the other accepted pairs linking its groups; left out of the session graph"
UNCORROBORATED = ("imprecise answer, uncorroborated: kept apart (no other accepted pair agrees with it); "
                  "`sosmatch merge` it by hand if you trust it")


def _valid_merge(done: dict[str, Any]) -> bool:
    return (Path(done.get("merged", "")) / MERGE_RECORD).is_file()


def _stale_outputs(out_dir: Path, report: BatchReport, nearest: int | None = None, merging: bool = True) -> list[str]:
    """The batch's outputs (OUT/sessions/F, OUT/pairs/A__B, OUT/merged/R) that this run neither made nor read: of
    flights removed from the flights folder since an earlier run, pairs --nearest does not choose, or a group whose
    reference changed. They are left in place (a user may still want them) but named, each with its cause as this
    run knows it (`_stale_cause`), so that nobody reads them as part of this batch and nobody has to guess why
    (nu40: merged/f1 left by a reference that moved, and the warning guessed at flights removed or --nearest).
    `merging`: whether this run merges its groups (off: --no-merge)."""
    current = {"sessions": {s["name"] for s in report.sessions}, "pairs": {p["pair"] for p in report.pairs},
               "merged": {g["reference"] for g in report.groups if g.get("status") not in ("single", "not merged")}}
    stale = []
    for folder, names in current.items():
        if (out_dir / folder).is_dir():
            stale += [f"{folder}/{p.name}" for p in sorted((out_dir / folder).iterdir())
                      if p.is_dir() and p.name not in names]
    if stale:
        causes = [f"{name} ({_stale_cause(name, report, nearest, merging)})" for name in stale]
        log.warning("%d output(s) in %s belong to no flight, pair or group of this run: %s%s; left in place, not "
                    "part of this report", len(stale), out_dir, "; ".join(causes[:6]),
                    " ..." if len(causes) > 6 else "")
    return stale


def _stale_cause(name: str, report: BatchReport, nearest: int | None, merging: bool = True) -> str:
    """Why an output folder `name` (sessions/F, pairs/A__B, merged/R) is not part of this run (`merging` off:
    --no-merge, which merges no group)."""
    folder, item = name.split("/", 1)
    status = {s["name"]: s.get("status") for s in report.sessions}
    gone = [f for f in (item.split(PAIR_SEP) if folder == "pairs" else [item]) if f not in status]
    if gone:
        return f"flight {', '.join(gone)} is no longer in the flights folder"
    if folder == "pairs":
        return f"--nearest {nearest} does not choose this pair" if nearest is not None else "not matched by this run"
    if folder == "merged":
        if not merging:  # rev48 D3: the group was said to be "merged as R now"
            return "made by an earlier run; --no-merge: this run merges no group"
        for g in report.groups:
            if item in g.get("reference_was", []):
                return g["reference_note"]
        if status[item] != "done":
            return f"{item} did not map in this run"
        if any(g["members"] == [item] for g in report.groups):
            return f"{item} is linked to no other session in this run (no accepted pair in the session graph)"
        now = next((g["reference"] for g in report.groups if item in g["members"]), None)
        return f"made by an earlier run, whose reference {item} was; its group is merged as {now} now"
    return "not a session of this run"


def previous_references(out_dir: Path) -> list[str]:
    """The references of the merged groups of the batch's previous run (its report.json), to keep (see
    `spanning_transforms`' `keep`); none when there is no readable report (a first run)."""
    try:
        doc = json.loads((out_dir / "report.json").read_text(encoding="utf-8"))
        groups = doc.get("groups", []) if isinstance(doc, dict) else []
        return [str(g["reference"]) for g in groups if isinstance(g, dict) and isinstance(g.get("reference"), str)
                and g.get("status") not in ("single", "not merged") and len(g.get("members") or []) > 1]
    except (OSError, ValueError):
        return []


def _reference_note(names: list[str], members: list[int], ref: int, before: list[int],
                    georeferenced: set[int], noise: dict[int, float]) -> str:
    """Why a group's reference is not the one (or not each of those) of the previous run in it: `before`."""
    parts = []
    for old in before:
        if old == ref:
            continue
        if ref in before:  # two earlier groups joined: one reference stays
            why = (f"its group and {names[ref]}'s were joined by an accepted pair; {names[ref]}, the "
                   "more strongly linked of the earlier references, stays the reference")
        elif ref in georeferenced and old not in georeferenced:
            why = f"{names[ref]} is georeferenced and {names[old]} is not: the merged model keeps the georeference"
        elif old in noise and ref in noise and noise[ref] < noise[old] or ref in noise and old not in noise:
            why = (f"{names[ref]}'s georeference is measured more precise ({noise[ref]:.2f} m against "
                   f"{'unknown' if old not in noise else f'{noise[old]:.2f} m'})")
        else:
            why = f"{names[old]} is no longer eligible (`spanning_transforms`)"
        parts.append(f"the reference moved from {names[old]} to {names[ref]}: {why}")
    return "; ".join(parts)


def _graph_and_merge(
    report: BatchReport, names: list[str], sessions: dict[str, dict[str, Any]], pairs: dict[str, dict[str, Any]],
    matches: dict[str, MatchSummary], pair_fps: dict[str, list[str | None]], state: StateStore, executor: Executor,
    options: BatchOptions, params: Params, out_dir: Path, renewed: Collection[str] = (),
) -> list[dict[str, Any]]:
    index = {n: i for i, n in enumerate(names)}
    sims, refined = {}, {}
    for key, rec in pairs.items():
        if rec["status"] != "done" or not rec["accepted"] or rec["transform"] is None:
            continue
        if rec.get("georeference_warning"):  # images agree, georeferences do not: kept apart (no control either)
            continue
        a, b = key.split(PAIR_SEP)
        rec.pop("refine", None)
        if options.refine and rec.get("answer") != "verified":
            refined[key] = _refine_pair(rec, sessions[a]["session"], sessions[b]["session"], matches[key], params)
        sims[key] = Sim3.from_dict(rec["transform"])
    _control_alignments(sims, sessions, pairs, matches, pair_fps, state, executor, options, params, out_dir, renewed)
    edges, edge_keys = [], {}
    for key, sim in sims.items():
        if pairs[key]["status"] != "done" or not pairs[key]["accepted"]:  # refused by merge's control, or it failed
            continue
        a, b = key.split(PAIR_SEP)
        edge = Edge(index[a], index[b], sim, float(pairs[key]["num_associations"]), matches[key].imprecise)
        edges.append(edge)
        edge_keys[(edge.a, edge.b)] = key
    # Accepted pairs that contradict the others are dropped before the graph is used (see consistent_edges).
    probes = [np.asarray(sessions[n].get("center") or [0.0, 0.0, 0.0]) for n in names]
    edges, dropped, alone = consistent_edges(len(names), edges, probes, options.edge_tolerance_m)
    for rec in pairs.values():
        rec.pop("left_out", None)
        if rec["status"] == "done" and rec["accepted"]:
            rec["in_graph"] = not rec.get("georeference_warning")
    for why, left in ((CONTRADICTED, dropped), (UNCORROBORATED, alone)):
        for e in left:  # out of the graph, and why: the pair's `left_out`, a warning of the report
            key = edge_keys[(e.a, e.b)]
            pairs[key].update({"in_graph": False, "left_out": why})
            log.warning("pair %s: %s", key, why)
    groups = []
    merge_tasks, merge_fps = {}, {}
    georeferenced = {index[n] for n in names if sessions[n].get("epsg")}  # a merged group keeps a georeference
    # ... the most precise one (the measured GPS noise of each session's georeference, where known)
    noise = {index[n]: float(sessions[n]["georeference_sigma_m"]) for n in names
             if isinstance(sessions[n].get("georeference_sigma_m"), (int, float))}
    # the previous run's references stay where they can, so the merged model keeps its frame and folder as flights
    # are added (a moved reference is said, with its cause: `_reference_note`)
    kept = {index[n] for n in previous_references(out_dir) if n in index}
    for members in connected_groups(len(names), edges):
        ref, ref_from, tree = spanning_transforms(members, edges, georeferenced, noise, keep=kept)
        order = [ref] + [m for m in members if m != ref]
        group = {
            "reference": names[ref],
            "reference_georeference_sigma_m": noise.get(ref),
            "members": [names[m] for m in order],
            "tree": [edge_keys[(e.a, e.b)] for e in tree],
            "reference_from_session": {names[m]: ref_from[m].to_dict() for m in order},
        }
        if len(members) > 1 and (before := [m for m in members if m in kept and m != ref]):
            group["reference_was"] = [names[m] for m in before]
            group["reference_note"] = _reference_note(names, members, ref, [m for m in members if m in kept],
                                                      georeferenced, noise)
            log.warning("group of %s: %s", names[ref], group["reference_note"])
        groups.append(group)
        if len(members) < 2 or not options.merge:
            group["status"] = "single" if len(members) < 2 else "not merged"
            continue
        pos = {m: k for k, m in enumerate(order)}
        # each tree edge's answer a merge fuses: the pair's match.json (its verified alignment, unless unverified)
        tree_edges = [(pos[e.a], pos[e.b], pairs[edge_keys[(e.a, e.b)]]["match"]) for e in tree]
        key = names[ref]
        group_fp = {"members": [names[m] for m in order], "transforms": [ref_from[m].to_dict() for m in order],
                    "eps": params.association.distance_tolerance_m}  # contents: in the pair fps
        # --refine: each refined tree edge's fused pairs (rev46 D2: until then a refined group fused the match's own
        # associations, 9 where merge --refine fused 18); a group with one has another fingerprint than the same
        # group merged before, so an earlier batch's merge of it is made again; a group without one keeps its own
        edge_refines = [refined.get(edge_keys[(e.a, e.b)]) for e in tree]
        if any(r is not None for r in edge_refines):
            group_fp["refine"] = [None if r is None else _refine_print(r) for r in edge_refines]
        merge_fps[key] = each_version(lambda *prints, g=group_fp: fingerprint({**g, "pairs": list(prints)}),
                                      *[pair_fps[edge_keys[(e.a, e.b)]] for e in tree])
        merge_tasks[key] = (
            [sessions[names[m]]["session"] for m in order], [names[m] for m in order],
            [ref_from[m].to_dict() for m in order], tree_edges, str(out_dir / "merged" / key),
            # the group's merged model is this batch's own product of its sessions and pairs: when a flight was
            # added, removed or changed it is remade, as everything else that changed (a changed setting is
            # refused before any work by the batch's own identity unless --overwrite)
            params.association.distance_tolerance_m, True, [matches[edge_keys[(e.a, e.b)]] for e in tree],
            edge_refines,
        )
    # a group with a session mapped again by this version (`batch.workflow._kept_session`) is merged again
    remerge = {key for key, task in merge_tasks.items() if set(task[1]) & set(renewed)}
    # ... and one of another match of its tree's pairs (their maps and answers, `pair_made_from`)
    tree_keys = {g["reference"]: list(g["tree"]) for g in groups if g["reference"] in merge_tasks}
    each_pair, pair_unrecorded = pair_made_from({k for keys in tree_keys.values() for k in keys}, matches, state,
                                                pair_fps)
    merged = run_stage(executor, merge_task, merge_tasks, merge_fps, state, "merge", out_dir, "merge groups",
                       options.progress, _valid_merge, redo=remerge,
                       made_from={key: fingerprint([each_pair[k] for k in keys]) for key, keys in tree_keys.items()},
                       unrecorded=lambda key, done: all(pair_unrecorded(k, done) for k in tree_keys[key]))
    for group in groups:
        if group["reference"] in merged:
            group.update(merged[group["reference"]])
    return groups


def pair_made_from(keys: Iterable[str], matches: dict[str, MatchSummary], state: StateStore,
                   pair_fps: dict[str, list[str | None]]) -> tuple[dict[str, str], Any]:
    """`run_stage`'s `made_from` of a stage on accepted pairs (the control, the changes): each pair's match as it is
    now (`match_io.match_content`: its maps and its answer), and its `unrecorded` test of a state an earlier
    sosmatch saved: kept while the pair's own state is one too (made before any match was matched again for its
    maps, `workflow._pairs_made_from`); a pair matched since (it names its maps) is newer than it."""
    from ...database.match_io import match_content

    return ({k: match_content(matches[k]) for k in keys},
            lambda key, done: not state.names_its_inputs("match", key, pair_fps[key][0]))


def of_sessions(keys: Iterable[str], renewed: Collection[str]) -> set[str]:
    """The pair keys (A__B) of `keys` with a session in `renewed` (mapped again by this version,
    `batch.workflow._kept_session`): made again after it."""
    return {k for k in keys if set(k.split(PAIR_SEP)) & set(renewed)}


def _control_alignments(sims: dict[str, Sim3], sessions: dict[str, dict[str, Any]], pairs: dict[str, dict[str, Any]],
                        matches: dict[str, MatchSummary], pair_fps: dict[str, list[str | None]], state: StateStore,
                        executor: Executor, options: BatchOptions, params: Params, out_dir: Path,
                        renewed: Collection[str] = ()) -> None:
    """`sosmatch merge`'s control of every accepted pair's alignment (`alignment_task`), before the pair can join
    the session graph: a pair it refuses (its verdict, or an InputError: a file of the pair's that cannot be read)
    is recorded as refused (`accepted` false, its associations as `refused_support`, `refused`: the reason,
    `refused_by` "control") and said in the log and the report's warnings; it is no edge, no merge, no changes.
    A control that raises anything else (a bug, an ImportError of code changed under the run, a MemoryError) has
    said nothing of the pair: the pair failed (`status` "failed", `error`, traceback in OUT/logs/), as a failed
    match, counted in the report's failures and the exit code, and not saved as finished, so a re-run controls it
    again (nu26: 14 of 21 pairs "refused" by an ImportError, nothing merged, "ok", exit 0)."""
    tasks, fps = {}, {}
    for key, sim in sims.items():
        a, b = key.split(PAIR_SEP)
        transform = sim.to_dict()
        fps[key] = _after_pair_fingerprints(pair_fps[key], transform, params)
        tasks[key] = (sessions[a]["session"], sessions[b]["session"], str(pairs[key]["match"]), transform, params,
                      matches[key])
    made_from, unrecorded = pair_made_from(tasks, matches, state, pair_fps)
    done = run_stage(executor, alignment_task, tasks, fps, state, "control", out_dir, "control alignments",
                     options.progress, redo=of_sessions(tasks, renewed), made_from=made_from, unrecorded=unrecorded)
    for key, res in done.items():
        rec = pairs[key]
        rec.pop("refused", None), rec.pop("refused_by", None)
        if res["status"] != "done":  # `record_result` logged it and wrote its traceback
            rec.update({"status": "failed", "error": f"its alignment control failed: {res.get('error')}",
                        "accepted": False, "num_associations": 0, "transform": None})
        elif why := res.get("refused"):
            rec.update({"accepted": False, "refused": why, "refused_by": "control",
                        "refused_support": rec.get("num_associations"), "num_associations": 0, "transform": None})
            log.warning("pair %s refused: %s", key, why)


def _after_pair_fingerprints(pair: list[str | None], transform: dict[str, Any], params: Params) -> list[str | None]:
    """Each version's fingerprint of a stage on an accepted pair (its control, its changes): the pair's, the
    transform, the changes section and theta_eps."""
    return each_version(lambda fp, changes: fingerprint(
        {"pair": fp, "transform": transform, "changes": changes, "eps": params.association.distance_tolerance_m}),
        pair, build_versions(lambda as_dict: as_dict(params.changes)))


def _refine_pair(rec: dict[str, Any], session_a: str, session_b: str, m: MatchSummary,
                 params: Params) -> Refinement:
    """`--refine`: the pair's unverified answer refined on the full maps as `sosmatch merge --refine` refines it
    (`merge_refine.refined_answer`), into the pair's record: its `transform` is then the refined one, which the
    graph, the control, the merge, the changes and the report all read (rev33: the graph and the merge used a
    refit, the changes and the report the consensus, 0.5 m apart), and `refine` says what the fit used. Returns
    the refinement, whose pairs (`Refinement.fuse`) the group's merge fuses, as merge --refine does."""
    from ...database.session_io import read_session
    from ..merge_refine import refined_answer

    got = refined_answer(read_session(session_a).landmarks, read_session(session_b).landmarks, m, params)
    rec["refine"] = got.record()
    rec["transform"] = got.transform.to_dict()
    return got


def _refine_print(r: Refinement) -> dict[str, Any]:
    """A refined tree edge in its group's merge fingerprint: what the fit used and the pairs it fuses."""
    return {**r.record(), "fuse": None if r.fuse is None else r.fuse.identity()}
