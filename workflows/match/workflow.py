"""`run`: load both maps, compute the match's answer, warn about it, and write match.json, associations.csv and
match.png (the package docstring says what each holds)."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Collection
from pathlib import Path

import numpy as np

from ...database.atomic import write_bytes_atomic, write_text_atomic
from ...database.landmark_map import check_two_maps, crs_disagreement, georeference_offset_m
from ...database.map_loading import load_map, size_definition_disagreement
from ...database.match_io import parse_match
from ...database.output_checks import RecordedSettings
from ...database.output_markers import VersionedIdentity, versioned_identity
from ...database.outputs import open_output_dir
from ...plugin.answer_uncertainty import refused_scale_note, without_similarity_advice
from ...plugin.association.hypotheses import MIN_LANDMARKS_TO_ALIGN
from ...plugin.errors import InputError
from ...plugin.map_noise import DERIVED_TOLERANCES, replaced_settings, resolution_gap
from ...plugin.params import Params
from .answer_warnings import (
    _georeference_warning,
    _height_datum_warning,
    _takeoff_height_warning,
    _tilt_warning,
)
from .figure import alignment_png
from .record import associations_csv, match_to_json, params_record
from .result import MatchResult
from .transform_choice import Search, answer_plan, plan_search

# the package's name, as before the split: the command's warnings still read "sosmatch.workflows.match: ..."
log = logging.getLogger(__package__)
# the files a match writes, match.json (its presence = done) last: a user's file at one of their names is refused
# when the folder is taken, before the search
MATCH_FILES = ("associations.csv", "match.png", "match.json")


def run(params: Params, a: str | Path, b: str | Path, out_dir: str | Path, workers: int | None = None,
        exhaustive: bool = False, plot: bool = True, overwrite: bool = False,
        verify: bool | None = None, transform_chosen: bool = False, chosen: Collection[str] = ()) -> MatchResult:
    """Match map `b` against map `a` and write match.json, associations.csv and match.png into `out_dir`.

    a, b: session directories, .sosmap files or COLMAP models. workers: unused (the search runs in one process).
    exhaustive: use the straightforward reference search (every window pair from scratch; slow, same result).
    verify: verify the search's hypotheses on the full maps (default `params.verification.enabled`); off, the
    answer is the window consensus. A position prior (`association.position_prior_m`) is used only when both maps
    are georeferenced in one EPSG. transform_chosen: the user chose `association.transform` (--set, --config,
    --preset); else a map whose poses came from structure from motion is searched with a similarity
    (`transform_choice`). overwrite: replace a complete match of other maps or settings in `out_dir` (see
    `sosmatch.database.outputs` for what is never replaced). chosen: the settings the user chose (dotted names,
    `config_io.chosen_settings`): those among the tolerances the maps' derivation replaced are warned about
    (`map_noise.replaced_settings`). Raises InputError for unreadable or unusable maps.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    out_dir = Path(out_dir)
    map_a, map_b = load_map(a), load_map(b)
    la, lb = map_a.lmap, map_b.lmap
    prints = check_two_maps(a, b, la, lb, "match")
    for m in (map_a, map_b):
        # named here, at the edge: the search's own check knows the map only as "A" or "B" (nu27)
        if len(m.lmap) < MIN_LANDMARKS_TO_ALIGN:
            raise InputError(f"holds {len(m.lmap)} landmark(s); at least {MIN_LANDMARKS_TO_ALIGN} are needed to "
                             "match it with another map (a rigid transform needs 3 points)", m.path)
    said: list[str] = []  # every warning, logged and recorded in match.json `warnings`

    def warn(text: str | None) -> None:
        if text is not None:
            log.warning("%s", text)
            said.append(text)

    warn(crs_disagreement(la, lb))
    warn(size_definition_disagreement(map_a.size_definition, map_b.size_definition))
    if verify is not None:
        params = dataclasses.replace(params, verification=dataclasses.replace(params.verification, enabled=verify))
    # the searches: the transform the maps' pose sources choose (unless the user chose it), each with tolerances
    # from the maps' own noise and windows from their geometry when `association.derive_from_maps` (recorded in
    # match.json's params and search_mode "derived"), searched first with the tighter of the derived and the
    # configured tolerances (`match_answer`, module doc)
    plan = plan_search(params, transform_chosen, map_a.sfm_poses, map_b.sfm_poses, map_a.noise, map_b.noise,
                       la.positions, la.sizes, lb.positions, lb.sizes)
    if plan.note is not None:
        log.info("%s", plan.note)
    if params.association.derive_from_maps:
        for name, m in (("A", map_a), ("B", map_b)):
            if m.noise is None:
                warn(f"map {name} ({m.path}) records no noise figures (a COLMAP model, or a .sosmap written before "
                     "map files carried them): the configured tolerances are used, not ones derived from the "
                     "maps; give its mapped session directory to derive them")

    def identity_of(search: Search) -> VersionedIdentity:
        """The output's identity: the maps and the parameters of the search its answer was made with."""
        p, d = search.params, search.derivation
        return versioned_identity(lambda as_dict: {
            "a": prints[0], "b": prints[1], "association": as_dict(p.association),
            "first_try": None if d.first_try is None else as_dict(d.first_try),
            # only when there is one: outputs of maps that get no wider search keep their identity
            **({} if d.wider_try is None else {"wider_try": as_dict(d.wider_try)}),
            **({} if d.near_try is None else {"near_try": as_dict(d.near_try)}),
            "verification": as_dict(p.verification), "seed": p.seed, "exhaustive": exhaustive, "plot": plot})

    # why this run's transform is what it is: named when an earlier output in the folder was made with another
    # (an upgrade's rigid match of a photo-mapped flight is refused with the reason, not bare)
    sfm_maps = " and ".join(n for n, m in (("A", map_a), ("B", map_b)) if m.sfm_poses)
    why = {} if plan.note is None else {"association.transform": (
        f"map {sfm_maps}'s poses came from structure from motion: a similarity is searched unless "
        "association.transform is set")}
    # the tolerances given, which the maps' derivation replaces: match.json keeps them in search_mode.derived
    # (`map_noise.derived_search_params`), so a refusal names a change of them (rev56 D8)
    configured = params.association
    given = {f"association.{name}": getattr(configured, name) for name in DERIVED_TOLERANCES}
    if plan.first.derivation.record["tolerances"] != "configured":  # this run's values are the derived ones
        why |= {name: "association.derive_from_maps replaces it by the value derived from the maps" for name in given}

    def settings_of(search: Search) -> RecordedSettings:
        """The search's settings as match.json records them, for a refusal to compare with the record's."""
        return RecordedSettings(params_record(search.params), why, given,
                                ("search_mode", "derived", "tolerances", "configured"))

    # the answer decides which search made it (the rigid one after a similarity's scale no dome makes): the
    # directory is taken for either, and settled on the one that answered before anything is written (rev51 D6:
    # the identity was the similarity's while match.json recorded the rigid params the answer was made with)
    fallback = None if plan.fallback is None else identity_of(plan.fallback)
    with open_output_dir(out_dir, "match", identity_of(plan.first), inputs=[a, b], overwrite=overwrite,
                         legacy_record="match.json",
                         earlier=() if fallback is None else (fallback.today, *fallback.same_as),
                         settings=settings_of(plan.first), files=MATCH_FILES) as out:
        common = la.epsg == lb.epsg != 0
        if params.association.position_prior_m > 0 and not common:
            warn(f"position prior ignored: the maps are not georeferenced in one EPSG (A: {la.epsg}, B: {lb.epsg})")
        planned = answer_plan(plan, la.positions, la.sizes, lb.positions, lb.sizes, common_frame=common,
                              exhaustive=exhaustive)
        out.settle(identity_of(planned.search), overwrite, settings=settings_of(planned.search))
        ans, params, derivation = planned.answer, planned.search.params, planned.search.derivation
        warn(replaced_settings(configured, params.association, chosen))
        if planned.beyond is not None:
            warn(f"{b}: {planned.beyond}")
            if ans.uncertainty is not None:  # nor does it advise the similarity just not kept (rev51 D6)
                ans.uncertainty = without_similarity_advice(ans.uncertainty)
        if ans.accepted and not common and ans.transform is not None:
            # two EPSG codes: where each puts B on the ground (`georeference_offset_m`; None without both codes),
            # judged by the rule of one EPSG: a wrong label is a wrong georeference, one site in two zones is not
            ans.georeference_off_m = georeference_offset_m(la, lb, ans.transform, ans.associations)
        geo_warning = _georeference_warning(ans, b, params.association.georeference_prior_m) if ans.accepted else None
        warn(geo_warning)
        if common and ans.accepted:
            warn(_height_datum_warning(ans, lb.positions, b))
            warn(_takeoff_height_warning(ans, lb.positions, a, b))
        warn(_tilt_warning(ans, a, b))
        if ans.accepted and ans.uncertainty is not None and ans.uncertainty.imprecise:
            warn(f"{b}: {ans.uncertainty.warning()}; merge and changes inherit that error")
        ver = ans.verification
        if not ans.accepted and ver is not None and ver.best is not None and planned.note is None:
            # a refusal that a scale explains says so: a rigid search of two domed SfM maps was refused bare (nu54);
            # not after the maps' SfM poses chose a similarity (tried already, or its scale was no dome's)
            note = refused_scale_note(la.positions, lb.positions, ver.best.transform, ver.best.associations)
            warn(None if note is None else f"{b}: {note}")
        if not ans.accepted:  # a refusal names a cause both maps record: resolutions too different (nu57 D2)
            warn(resolution_gap(map_a.noise, map_b.noise, params.association.max_size_difference))
        # a refused answer names no associations (match.json's verification keeps what was tried)
        result = MatchResult(out_dir, map_a, map_b, ans.search,
                             ans.associations if ans.accepted else np.zeros((0, 2), np.int64),
                             ans.transform if ans.accepted else None, 0.0, ans)
        result.georeferences_disagree = geo_warning is not None
        result.min_ratio = params.verification.min_ratio
        result.seconds, result.cpu_seconds = time.perf_counter() - t0, time.process_time() - cpu0
        doc = match_to_json(result, params)
        doc["search_mode"]["derived"] = derivation.record
        if planned.note is not None:  # only then: a match of maps of given poses keeps its bytes
            doc["search_mode"]["transform_from_poses"] = planned.note
        doc["seconds_total"] = result.seconds
        doc["cpu_seconds_total"] = result.cpu_seconds
        doc["warnings"] = said
        parse_match(doc, out_dir / "match.json")  # the reader's validation: never write what it would refuse
        write_text_atomic(out.staged("associations.csv"), associations_csv(result))
        if plot:
            write_bytes_atomic(out.staged("match.png"), alignment_png(result))
        write_text_atomic(out.staged("match.json"), json.dumps(doc, indent=1) + "\n")
        # not plotted: a previous run's picture (of other maps, perhaps) is removed, not left beside this match.json;
        # match.json last: its presence = done
        out.publish(MATCH_FILES[:-1], last=MATCH_FILES[-1], optional=("match.png",))
        out.finish()
    return result
