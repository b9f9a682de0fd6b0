"""The batch run: its stages (map, match, session graph + merge, report) as named calls; see the package doc."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Collection
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path
from typing import Any

from ...database.atomic import write_text_atomic
from ...database.map_loading import session_sfm_poses
from ...database.match_io import MatchSummary, answer_gate
from ...database.output_markers import check_not_input, output_command, versioned_identity
from ...database.outputs import open_output_dir
from ...database.poses import crs_problem
from ...database.segmentation_models import SegmentationModels, keyed_by_models, segmentation_models
from ...plugin.errors import InputError
from ...plugin.params import Params, mapping_params, params_to_dict
from ...plugin.params.identity import build_versions, each_version
from ..executors import Executor, LocalExecutor
from ..merge import label_problem
from .discovery import PAIR_SEP, discover_flights, flight_digest, flight_signature, images_dir, one_session_per_flight
from .graph import _after_pair_fingerprints, _graph_and_merge, _stale_outputs, of_sessions, pair_made_from
from .pairs import flight_times, pairs_chosen_by
from .report import REPORT_FILES, BatchReport, write_report
from .state import StateStore, fingerprint, run_stage
from .tasks import changes_task, map_task, pair_task

log = logging.getLogger(__name__)


@dataclass
class BatchOptions:
    """How to run a batch (parameters of the method live in Params)."""

    nearest: int | None = None  # match only the k nearest pairs (None: every pair)
    ekf: bool = False  # synth flights: map with the noisy poses_ekf.csv instead of the ground truth
    merge: bool = True
    # (without verify) consensus transforms refined on the full maps (`merge_refine.refined_answer`)
    refine: bool = False
    # Each match verifies its window hypotheses on the full maps (a stage of `sosmatch match`, settings in
    # Params.verification); off = the match's consensus as it is. BENCHMARKS.md, Multi-session, has what each
    # step does to the errors.
    verify: bool = True
    edge_tolerance_m: float = 5.0  # (ours) two accepted pairs agree if they place sessions within this distance
    changes: bool = True  # change detection of every pair in the session graph (OUT/pairs/A__B/changes/)
    # the projected CRS of the flights of photos (poses from structure from motion; None: each flight's UTM zone of
    # its median fix): flights of one site on either side of a zone edge mapped in one (`match` advises it)
    epsg: int | None = None
    progress: bool = True
    # replace complete outputs made with other parameters or options (OUT itself, and each session, pair and merged
    # model whose inputs changed); without it such a run is refused (sosmatch.database.outputs)
    overwrite: bool = False
    # the user chose `association.transform` (--set, --config, --preset): every pair is matched with it; otherwise a
    # pair holding a flight whose poses came from structure from motion is matched with a similarity, as `sosmatch
    # match` does (`workflows.match.transform_choice`)
    transform_chosen: bool = False


def _searched_transform(params: Params, options: BatchOptions, sfm_a: bool, sfm_b: bool) -> dict[str, str]:
    """{"transform": "similarity"} when `sosmatch match` will search the pair with a similarity that the flights'
    pose sources chose (`transform_choice.choose_transform`: either flight's poses came from structure from motion
    (`sfm_a`, `sfm_b`: `map_loading.session_sfm_poses`) and the user did not choose the transform), else {}: a pair's
    fingerprint then follows the transform its match uses, so a pair matched rigidly before the choice existed is
    matched again (as `match` refuses that output), while pairs of given poses, and any pair whose transform the
    user chose, keep their fingerprint and resume (rev52 D4, D5)."""
    from ..match.transform_choice import choose_transform

    choice = choose_transform(params, options.transform_chosen, sfm_a, sfm_b)
    return {} if choice.note is None else {"transform": choice.params.association.transform}


def _valid_session(done: dict[str, Any]) -> bool:
    p = Path(done.get("session", ""))
    return (p / "landmarks.sosmap").is_file() and (p / "sparse").is_dir()


def _kept_session(out_dir: Path, overwrite: bool, renewed: set[str]) -> Any:
    """`_valid_session`, and for a session the batch mapped (not an adopted one: the user's, used as it is) whose
    run.json says another sosmatch made it (`database.code_version.other_version`): kept, said once in a warning
    naming the folder, both versions and the remedy; with `overwrite` mapped again instead, its name added to
    `renewed` (its pairs, merges and comparisons are then made again too). Its identity keys the inputs and
    settings, not the code, so an upgrade resumes it: re-mapping every flight is what a resume saves, and a map of
    the same settings is usually fine, but the user should know what made it."""
    from ...database.code_version import kept_message, other_version
    from ...database.output_markers import read_json_or_none

    def kept(done: dict[str, Any]) -> bool:
        if not _valid_session(done):
            return False
        session = Path(done["session"])
        if done.get("kind") == "mapped" or (made_by := other_version(read_json_or_none(session / "run.json"))) is None:
            return True
        try:
            where = session.relative_to(out_dir).as_posix()
        except ValueError:
            where = str(session)
        if overwrite:
            log.info("%s: made by %s; mapped again with this one (--overwrite)", where, made_by)
            renewed.add(str(done.get("name", session.name)))
            return False
        log.warning("%s", kept_message(where, made_by, "maps it again"))
        return True

    return kept


def _valid_match(done: dict[str, Any]) -> bool:
    return Path(done.get("match", "")).is_file()


def _map_prints(sessions: dict[str, dict[str, Any]], names: Collection[str]) -> dict[str, str | None]:
    """Each session's landmark map as a match.json names it (`landmark_map.landmark_map_fingerprint`; None: it does
    not read, and its pairs are matched again, which says why)."""
    from ...database.landmark_map import landmark_map_fingerprint, read_landmark_map

    prints: dict[str, str | None] = {}
    for name in names:
        try:
            prints[name] = landmark_map_fingerprint(read_landmark_map(Path(sessions[name]["session"])
                                                                      / "landmarks.sosmap"))
        except InputError:
            prints[name] = None
    return prints


def _pairs_made_from(keys: Collection[str], prints: dict[str, str | None]) -> tuple[dict[str, str], Any]:
    """(`run_stage`'s `made_from` of the match stage: both maps of each pair as they are now, and its `unrecorded`
    test of a pair an earlier sosmatch saved: the maps its match.json names are those). A session mapped again
    whose pairs were not (a batch --overwrite killed between the stages) has another map than its pairs' match.json
    names: they are matched again, and the stages made of them again after them (`graph.pair_made_from`)."""
    from ...database.match_io import read_match

    made_from = {k: json.dumps([prints[n] for n in k.split(PAIR_SEP)]) for k in keys}

    def same_maps(key: str, done: dict[str, Any]) -> bool:
        try:
            m = read_match(done.get("match", ""))
        except InputError:
            return False
        return json.dumps([m.map_a.fingerprint, m.map_b.fingerprint]) == made_from[key]

    return made_from, same_maps


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
    if options.epsg is not None and (problem := crs_problem(int(options.epsg))) is not None:
        # refused as `map --epsg` and `poses --epsg` refuse it: a batch of mapped or posed flights took any code
        raise InputError(f"--epsg: {problem}")
    out_dir = Path(out_dir)
    own_executor = executor is None
    executor = executor or LocalExecutor(1)
    # an output is never inside an input directory (README "Errors"), and FLIGHTS is the batch's: OUT inside it
    # was taken and left out of discovery, and every other batch of the folder skipped it with a warning (nu59 D6)
    try:
        check_not_input(out_dir, [flights_dir])
    except InputError as exc:
        if output_command(out_dir) == "batch":  # one an earlier version took there (rev59 D3): it moves whole
            raise InputError(f"{exc.problem}; an earlier sosmatch took this batch output there: move the folder "
                             f"out of {flights_dir} and give its new place as OUT, the batch resumes there",
                             out_dir) from None
        raise
    flights = discover_flights(flights_dir)
    if options.merge:  # a flight's name labels its images in a merged model: refused now, not after the mapping
        for flight in flights:
            if (problem := label_problem(flight.name)) is not None:
                raise InputError(f"{problem}: a merged model names its images FLIGHT/name; rename the flight folder "
                                 "(or --no-merge)", flight.path)
    pdict = params_to_dict(params)
    # the segmentation's model files, by their contents, when a flight is to be segmented (`map`'s identity holds
    # them too): another model named by the environment is another batch, and maps again
    models = (segmentation_models(params.segmentation) if any(f.kind != "mapped" for f in flights)
              else SegmentationModels())
    # (the CRS only when chosen: batches run before the option keep their identity and resume)
    identity = keyed_by_models(lambda extra: versioned_identity(lambda as_dict: {
        "params": as_dict(params), "matcher": (pair_fn or pair_task).__qualname__,
        **{k: v for k, v in dataclasses.asdict(options).items()
           if k not in ("progress", "overwrite", "transform_chosen") and not (k == "epsg" and v is None)},
        **extra}, fingerprint), models)
    try:
        with open_output_dir(out_dir, "batch", identity, inputs=[f.path for f in flights],
                             overwrite=options.overwrite, legacy_record="report.json", files=REPORT_FILES) as taken:
            report = _run_batch(flights, out_dir, params, pdict, executor, options, pair_fn, models)
            report.seconds = time.perf_counter() - t0
            write_report(report, taken)
            taken.finish()
    finally:
        if own_executor:
            executor.close()
    return report


def _run_batch(flights: list, out_dir: Path, params: Params, pdict: dict[str, Any], executor: Executor,
               options: BatchOptions, pair_fn: Any, models: SegmentationModels | None = None) -> BatchReport:
    """The stages of `run` inside its taken output directory (`models`: the segmentation's model files)."""
    state = StateStore(out_dir / "state", out_dir)
    report = BatchReport(out_dir, executor=executor.describe())
    # 1-2: map
    fps, earlier, tasks, listings = {}, {}, {}, {}
    for f in flights:
        # what a flight's map depends on: its contents (not where the folder is: a moved flights folder resumes)
        # and the mapping parameters (a setting of matching or change detection does not map it again)
        listings[f.name] = contents_seen(out_dir, f)
        contents = {"kind": f.kind, "ekf": options.ekf, "contents": listings[f.name][0]}
        # an adopted session is used where it lies: its place is part of it (a copy elsewhere is another session)
        where = {"flight": str(f.path.resolve())} if f.kind == "mapped" else {}
        crs = {"epsg": options.epsg} if options.epsg is not None and f.kind == "images" else {}
        # the model files a flight is segmented with (none: a backend without any, or an adopted session, whose
        # fingerprints stay those of earlier versions)
        seg = {"models": models.identity()} if models is not None and models.identity() and f.kind != "mapped" else {}
        # each version's fingerprint (`identity_eras`): a batch of an earlier sosmatch resumes
        fixed = {**contents, **where, **crs, **seg}
        fps[f.name] = build_versions(lambda as_dict, fixed=fixed: fingerprint(
            {"map": 2, **fixed, "params": mapping_params(params, as_dict)}))
        before = {"flight": str(f.path.resolve()), **contents}  # before 88ab9e6: the folder and every setting
        earlier[f.name] = [p for p in build_versions(lambda as_dict, before=before: fingerprint(
            {**before, "params": as_dict(params)})) if p is not None]
        # the session folder is the batch's own product, as merges and comparisons are: a flight whose contents
        # changed is mapped again into it (a changed setting is refused before any work by the batch's identity)
        tasks[f.name] = (f.name, f.kind, str(f.path), str(out_dir / "sessions" / f.name), params, options.ekf,
                         True, options.epsg if f.kind == "images" else None)
    if options.epsg is not None and (own := [f.name for f in flights if f.kind != "images"]):
        log.warning("--epsg applies to flights of photos (poses from structure from motion); %s keep the CRS of "
                    "their poses or sessions", ", ".join(own))
    renewed: set[str] = set()  # sessions another sosmatch made, mapped again (--overwrite): all made of them too
    by_name = {f.name: f for f in flights}
    # what a flight mapped now was mapped from, recorded as its state is saved (an interrupted stage keeps both)
    sessions = run_stage(executor, map_task, tasks, fps, state, "map", out_dir, "map flights",
                         options.progress, _kept_session(out_dir, options.overwrite, renewed), earlier,
                         on_done=lambda name: record_contents(out_dir, by_name[name], *listings[name]))
    _session_warnings(sessions)
    # one session of each flight: two maps of one flight (other settings) would put its images twice into a model
    mapped = one_session_per_flight([f.name for f in flights if sessions[f.name]["status"] == "done"], sessions)
    report.sessions = [{"name": f.name, "kind": f.kind, **sessions[f.name]} for f in flights]

    # 3: match
    # with --nearest, each flight's neighbours in time are matched too (read only then: <= 9 EXIF headers a flight)
    times = flight_times({f.name: None if f.kind == "mapped" else images_dir(f.path) for f in flights
                          if f.name in mapped}, report.run_warnings) if options.nearest is not None else {}
    chosen_by = pairs_chosen_by(mapped, sessions, options.nearest, times)
    chosen = list(chosen_by)
    matcher = pair_fn or pair_task
    # a custom matcher (pair_fn) returns its own summary; the default one is `sosmatch match` (verified)
    verify = bool(options.verify) if matcher is pair_task else None
    pair_fps, pair_tasks = {}, {}
    # each version's association and verification sections: the same for every pair
    match_sections = build_versions(lambda as_dict: (as_dict(params.association), as_dict(params.verification)))
    # where each session's poses came from, read once (a session's map file and record; not once per pair)
    sfm = {n: session_sfm_poses(sessions[n]["session"]) for n in mapped} if matcher is pair_task else {}
    for a, b in chosen:
        key = f"{a}{PAIR_SEP}{b}"
        # what `sosmatch match` depends on (its own identity: both maps, association, verification, seed), with
        # the transform it searches with when the flights' poses chose it (`_searched_transform`)
        searched = _searched_transform(params, options, sfm[a], sfm[b]) if matcher is pair_task else {}
        pair_fps[key] = each_version(lambda fa, fb, sections, searched=searched: fingerprint(
            {"a": fa, "b": fb, "association": sections[0], "verification": sections[1], "seed": pdict["seed"],
             "matcher": matcher.__qualname__, "verify": verify, **searched}), fps[a], fps[b], match_sections)
        pair_tasks[key] = (sessions[a]["session"], sessions[b]["session"], str(out_dir / "pairs" / key), params)
        if matcher is pair_task:
            pair_tasks[key] += (verify, True, options.transform_chosen)  # the batch's own, as the sessions
    pairs_from, same_maps = _pairs_made_from(pair_tasks, _map_prints(sessions, mapped))
    pairs = run_stage(executor, matcher, pair_tasks, pair_fps, state, "match", out_dir, "match pairs",
                      options.progress, _valid_match, redo=of_sessions(pair_tasks, renewed), made_from=pairs_from,
                      unrecorded=same_maps)
    for (a, b), why in chosen_by.items():  # said in report.json: why each pair was matched (a resumed pair too)
        pairs[f"{a}{PAIR_SEP}{b}"]["chosen_by"] = why
    _match_refusals(pairs)
    matches = _read_matches(pairs)
    _georeference_warnings(pairs, matches, sessions)
    _match_warnings(pairs, matches)
    failed = [f.name for f in flights if sessions[f.name]["status"] != "done"]

    # 4: session graph (marks each pair's in_graph) and merged groups
    report.groups = _graph_and_merge(report, mapped, sessions, pairs, matches, pair_fps, state, executor, options,
                                     params, out_dir, renewed)
    # 5: what changed between the sessions of every pair the graph kept
    if options.changes:
        # where each flight's images are now: a map resumed after the flights folder moved records the old place
        images = {f.name: None if f.kind == "mapped" else images_dir(f.path) for f in flights}
        _changes(sessions, pairs, matches, pair_fps, state, executor, options, params, out_dir, images, renewed)
    report.pairs = [{"pair": key, "a": key.split(PAIR_SEP)[0], "b": key.split(PAIR_SEP)[1], **rec}
                    for key, rec in pairs.items()]
    report.pairs += [{"pair": f"{a}{PAIR_SEP}{b}", "a": a, "b": b, "status": "skipped",
                      "error": "a session failed to map"}
                     for a, b in combinations([f.name for f in flights], 2) if a in failed or b in failed]
    report.stale_outputs = _stale_outputs(out_dir, report, options.nearest, options.merge)
    return report


def _contents_path(out_dir: Path, name: str) -> Path:
    return out_dir / "state" / "contents" / f"{name}.json"


def _listing(entries: Any) -> list[list[Any]] | None:
    """A listing as JSON gives it back (lists, not tuples); None when it is not one."""
    if not isinstance(entries, list) or not all(isinstance(e, (list, tuple)) and len(e) == 3 for e in entries):
        return None
    return [list(e) for e in entries]


def contents_seen(out_dir: Path, flight: Any) -> tuple[list[list[Any]], list[list[Any]]]:
    """(the listing the flight's map fingerprint is made from, its listing now). They differ where the flight's
    files differ from those it was mapped from only in mtimes (same names and sizes: a tar, zip or FAT copy keeps
    whole seconds, `cp` without -p none) and hold the same bytes (sha256 recorded when it was mapped,
    OUT/state/contents/F.json): the map and every stage after it resume instead of mapping the flight again (the
    nu37 sweep: 40 s of CPU for 1 s; hours on real flights). Names or sizes or bytes differing: the listing now."""
    now = [list(e) for e in flight_signature(flight.path)]
    try:
        rec = json.loads(_contents_path(out_dir, flight.name).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return now, now
    if not isinstance(rec, dict) or (mapped := _listing(rec.get("listing"))) is None or mapped == now:
        return now, now
    if _listing(rec.get("same_contents")) == now:  # verified by an earlier run
        return mapped, now
    if [e[:2] for e in mapped] != [e[:2] for e in now] or not isinstance(rec.get("sha256"), str):
        return now, now
    if flight_digest(flight.path, now) != rec["sha256"]:
        return now, now
    log.info("%s: files touched since it was mapped (only their mtimes differ), same contents by sha256: its map "
             "is kept", flight.name)
    write_text_atomic(_contents_path(out_dir, flight.name), json.dumps({**rec, "same_contents": now}) + "\n")
    return mapped, now


def record_contents(out_dir: Path, flight: Any, mapped: list[list[Any]], now: list[list[Any]]) -> None:
    """After a flight is mapped: the listing its fingerprint was made from and the sha256 of its files'
    contents (`contents_seen`), unless its files changed while it was mapped."""
    if mapped != now:  # mapped again for another reason (settings) from a listing verified by content
        return  # its record (`contents_seen`) holds both listings already
    digest = flight_digest(flight.path, now)
    if digest is None or [list(e) for e in flight_signature(flight.path, warn=False)] != now:  # said once already
        _contents_path(out_dir, flight.name).unlink(missing_ok=True)
        return
    write_text_atomic(_contents_path(out_dir, flight.name), json.dumps({"listing": now, "sha256": digest}) + "\n")


def _read_matches(pairs: dict[str, dict[str, Any]]) -> dict[str, MatchSummary]:
    """Every accepted pair's match.json, read once (`match_io.read_match`) for all the stages that use it (the
    georeference warning, the alignment control, the merge), and handed to their tasks as it was parsed."""
    from ...database.match_io import read_match

    return {key: read_match(rec["match"]) for key, rec in pairs.items()
            if rec.get("status") == "done" and rec.get("accepted") and rec.get("match")}


def _match_refusals(pairs: dict[str, dict[str, Any]]) -> None:
    """Why each matched pair holds no accepted answer, in `match`'s words from its match.json
    (`match_notes.refusal_note`: best support, runner-up, chance p), as the pair's `refused` (`refused_by` "match"):
    report.md showed only the support (13 against a runner-up of 13, p ~ 1, unsaid). Read here, for a pair matched
    now and one a resumed batch reads finished alike; not a warning (most pairs of a folder of flights do not
    overlap)."""
    from ...database.match_io import parse_match, read_match_json
    from ...database.match_notes import refusal_note
    from ...plugin.errors import InputError

    for rec in pairs.values():
        if rec.get("status") != "done" or rec.get("accepted") or not rec.get("match"):
            continue
        rec.pop("match_warnings", None)
        try:
            doc = read_match_json(rec["match"])
            summary = parse_match(doc, Path(rec["match"]))
            why = refusal_note(doc, summary)
        except InputError as e:  # it was read by the match stage a moment ago: say what is wrong with it now
            why = f"its match.json cannot be read: {e}"
        else:
            if summary.warnings:  # what match warned of (CRS, noise figures), for a pair without an answer too
                rec["match_warnings"] = list(summary.warnings)
        if why:
            rec.update({"refused": why, "refused_by": "match"})


def _georeference_warnings(pairs: dict[str, dict[str, Any]], matches: dict[str, MatchSummary],
                           sessions: dict[str, dict[str, Any]]) -> None:
    """Pairs whose images agree and whose maps' georeferences do not (`match_notes.georeference_note`, from its
    match.json; measured from the sessions' maps when an older match.json records no offset): one georeference is
    wrong, so the pair is kept out of the session graph (`in_graph` false: no group, no merge, no changes) and
    said in its record (`georeference_warning`, report.json / .md) and the batch's log. match says it in its
    worker, whose log a batch does not show, and a resumed batch does not run it again (the twenty-first sweep:
    two flights 428 m apart by their georeferences merged into one EPSG without a word; the twenty-fifth: a
    flight tagged in Switzerland and its copy tagged in Fiji, 16,684 km apart, merged into one group)."""
    from ...database.landmark_map import read_landmark_map
    from ...database.match_notes import georeference_note

    for key, rec in pairs.items():
        rec.pop("georeference_warning", None)
        if key not in matches:  # not done, not accepted, or no match file
            continue
        a, b = key.split(PAIR_SEP)
        maps: tuple[Any, ...] = ()
        if matches[key].georeference_off_m is None and sessions[a].get("epsg") and sessions[b].get("epsg"):
            maps = tuple(read_landmark_map(Path(sessions[n]["session"]) / "landmarks.sosmap") for n in (a, b))
        if (note := georeference_note(matches[key], *maps)) is not None:
            rec["georeference_warning"] = (f"{b}: {note}; left out of the session graph: {a} and {b} are not "
                                           "merged into one group")
            log.warning("pair %s: %s", key, rec["georeference_warning"])


def _session_warnings(sessions: dict[str, dict[str, Any]]) -> None:
    """Repeat what `sosmatch map` warned of for each mapped session (run.json's verdict,
    `map.quality.recorded_verdict_warnings`: its poses', quality's and pose check's warnings; and its poses.json's,
    `poses.result.recorded_pose_warnings`) into its record
    (`warnings`, report.json / .md) and the batch's log, for a session mapped now (its worker's log is not the
    batch's) and one a resumed batch adopts finished (nu42: a flight whose images and EXIF contradict each other on
    the focal length, its landmarks 18 m off in height, was "ok" in report.json, said only in its run.json)."""
    from ...plugin.errors import InputError
    from ..map.quality import recorded_verdict_warnings
    from ..poses.result import recorded_pose_warnings, with_pose_warnings

    for name, rec in sessions.items():
        rec.pop("warnings", None)
        if rec.get("status") != "done":
            continue
        try:
            # its poses' own record (structure from motion inside the session): a verdict of an earlier version
            # repeats only some of them ("poses: ..."), the others (images left out or repeated) are said once here
            said = with_pose_warnings(recorded_verdict_warnings(rec["session"]),
                                      recorded_pose_warnings(Path(rec["session"]) / "poses"))
        except InputError as e:  # mapped a moment ago: say what is wrong with its records now
            said = [f"its session record cannot be read: {e}"]
        if said:
            rec["warnings"] = said
            for text in said:
                log.warning("session %s: %s", name, text)


def _match_warnings(pairs: dict[str, dict[str, Any]], matches: dict[str, MatchSummary]) -> None:
    """Repeat what `match` warned of for each accepted pair (match.json `warnings`, as `_read_matches` parsed it:
    an imprecise answer, heights on two datums, a CRS disagreement) into its record (`match_warnings`, report.json
    / .md) and the batch's log; a pair without an answer gets its own from `_match_refusals`. The georeference
    disagreement is said once, by `georeference_warning`, with what batch did about it (nu42: B__cropc's "imprecise
    answer", B moved 9.6 m vertically, was missing from report.json)."""
    for key, match in matches.items():
        rec = pairs[key]
        rec.pop("match_warnings", None)
        geo = rec.get("georeference_warning") or ""
        # match's text is "PATH_B: NOTE", batch's "B: NOTE; left out ...": the same NOTE is one warning
        said = [w for w in match.warnings if not (geo and w.partition(": ")[2] and w.partition(": ")[2] in geo)]
        if said:
            rec["match_warnings"] = said
            for text in said:
                log.warning("pair %s match: %s", key, text)


def _absolute(path: str | Path) -> str:
    return str(Path(path).resolve())


def _valid_changes(done: dict[str, Any]) -> bool:
    return Path(done.get("changes", "")).is_file()


def _changes(sessions: dict[str, dict[str, Any]], pairs: dict[str, dict[str, Any]], matches: dict[str, MatchSummary],
             pair_fps: dict[str, list[str | None]], state: StateStore, executor: Executor, options: BatchOptions,
             params: Params, out_dir: Path, images: dict[str, Path | None], renewed: Collection[str] = ()) -> None:
    """Run `changes_task` for every accepted pair in the session graph; its counts go into the pair's record. Its
    alignment control runs at the pair's match's gate, as the control stage's (`alignment_task`)."""
    tasks, fps = {}, {}
    for key, rec in pairs.items():
        if rec["status"] != "done" or not rec.get("accepted") or not rec.get("in_graph") or not rec.get("transform"):
            continue
        a, b = key.split(PAIR_SEP)
        fps[key] = _after_pair_fingerprints(pair_fps[key], rec["transform"], params)
        # absolute, as `sosmatch changes` records them (rev48 D4: changes.json held paths relative to the cwd the
        # batch was started from, where OUT is movable)
        tasks[key] = (_absolute(sessions[a]["session"]), _absolute(sessions[b]["session"]),
                      str(out_dir / "pairs" / key / "changes"), rec["transform"], params, True,
                      rec.get("answer") == "verified",  # the batch's own, as merge
                      *(None if images[n] is None else _absolute(images[n]) for n in (a, b)),
                      answer_gate(matches[key], params.association.distance_tolerance_m), _absolute(rec["match"]))
    made_from, unrecorded = pair_made_from(tasks, matches, state, pair_fps)
    done = run_stage(executor, changes_task, tasks, fps, state, "changes", out_dir, "detect changes",
                     options.progress, _valid_changes, redo=of_sessions(tasks, renewed), made_from=made_from,
                     unrecorded=unrecorded)
    for key, rec in done.items():
        pairs[key]["changes_status"] = rec["status"]
        if rec["status"] == "done":
            pairs[key].update({k: rec[k] for k in ("changes", "changes_summary")})
            _changes_record(key, pairs[key])
        else:
            pairs[key]["changes_error"] = rec.get("error", "")


def _changes_record(key: str, rec: dict[str, Any]) -> None:
    """What a pair's changes.json (`changes_io.read_changes_record`) says, into its record (report.json / .md,
    pairs.csv): its counts (`ChangeResult.counts()`, the counts `sosmatch changes` prints; read from the record,
    as of a comparison a resumed batch finds finished, whose state an earlier version may have written with other
    counts), and what it warned of (`changes_warnings`), repeated into the batch's log for a comparison run now
    (its worker's log is not the batch's) and one a resumed batch reads finished (the twenty-fourth sweep: B's
    images "show no relief", its 5 "new" claims all false, and report.json said "warnings": [])."""
    from ...database.changes_io import read_changes_record
    from ...plugin.changes import COUNT_KEYS
    from ...plugin.errors import InputError

    for k in ("changes_warnings", *COUNT_KEYS):
        rec.pop(k, None)
    try:
        record = read_changes_record(rec["changes"])
        warnings = record["warnings"]
    except InputError as e:  # the record was there a moment ago (`_valid_changes`): say what is wrong with it now
        record, warnings = {}, [f"its changes record cannot be read: {e}"]
    counts = record.get("counts")
    if isinstance(counts, dict) and all(type(counts.get(k)) is int and counts[k] >= 0 for k in COUNT_KEYS):
        rec.update({k: counts[k] for k in COUNT_KEYS})
    elif record:  # its counts are then summed with no other pair's (`BatchReport.changes_line`)
        warnings = [*warnings, f"its changes record {rec['changes']} holds no counts of "
                               f"{', '.join(COUNT_KEYS)} (an earlier version's?): its counts are not reported"]
    if warnings:
        rec["changes_warnings"] = warnings
        for text in warnings:
            log.warning("pair %s changes: %s", key, text)
