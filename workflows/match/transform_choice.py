"""Which transform `match` searches two maps with, from where their poses came from.

A map whose poses came from sosmatch's structure from motion (`sosmatch poses`, `map --images`: run.json
`pose_source`, the map file's flag 4) may be domed: on small images the bundle adjustment determines the lens's k1
poorly, the cameras stay on their GPS priors and the error goes into the rotations, which lean away from (or
toward) the block's centre in proportion to the distance from it; every landmark is then scaled about the centre
by 1-5 % in plan and depth (BENCHMARKS.md "Two SfM maps of one place refused"). Two such maps, or one and a map of
given poses, differ by that scale, which a rigid transform with noise tolerances cannot absorb: nu54's two
photo-mapped flights were refused, two other pairs verified "imprecise". So when either map is SfM-posed and the
user did not choose `association.transform`, the search and verification fit a similarity (the verification's
chance placements fit a scale too, so chance is judged with the same freedom), and the answer is kept only when
its scale is one a dome can make (`MAX_DOME_SCALE`); beyond it, the rigid match is the answer, as before. Maps of
given poses (EKF, telemetry, synth, EXIF tags) are matched rigidly as before, byte for byte.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...plugin.map_noise import DerivedSearch, MapNoise, derived_search_params
from ...plugin.params import Params

if TYPE_CHECKING:
    from ...plugin.match_answer import MatchAnswer

# how far from 1 the scale between two SfM maps may be and still be called a dome's: measured 0.959-1.041 between
# two domed 320x240 blocks (each 0.97-1.05 against the truth, dome coefficients a x 100 m up to 0.05); two blocks
# domed oppositely at that limit differ by ~10 %. A larger scale is not a dome: a scale error of the GPS or the
# focal length, which the map's own checks report (pose_check's GPS lengths, the height above take-off)
MAX_DOME_SCALE = 0.10


@dataclass(frozen=True)
class TransformChoice:
    """The parameters to search with and, when the maps' pose source chose a similarity, what to say of it."""

    params: Params
    note: str | None = None  # None: the transform is the configured one


def choose_transform(params: Params, chosen: bool, sfm_a: bool, sfm_b: bool) -> TransformChoice:
    """`params` with `association.transform` "similarity" when either map's poses came from structure from motion
    (`sfm_a`, `sfm_b`: `LoadedMap.sfm_poses`), the configured transform is "rigid" and the user did not choose it
    (`chosen`: set by --set, --config or --preset); otherwise `params` as they are (module doc)."""
    if chosen or params.association.transform != "rigid" or not (sfm_a or sfm_b):
        return TransformChoice(params)
    which = "A's and B's" if sfm_a and sfm_b else "A's" if sfm_a else "B's"
    note = (f"searched with a similarity (association.transform \"similarity\"): {which} poses came from structure "
            "from motion, whose block can be domed, scaled by a few % about its centre; a scale beyond "
            f"{MAX_DOME_SCALE:.0%} is not kept (`--set association.transform=rigid` to match rigidly)")
    association = dataclasses.replace(params.association, transform="similarity")
    return TransformChoice(dataclasses.replace(params, association=association), note)


def beyond_dome(scale: float) -> str | None:
    """What to say when a similarity answer's `scale` (B into A) is more than a dome makes (`MAX_DOME_SCALE`),
    else None."""
    if abs(scale - 1.0) <= MAX_DOME_SCALE:
        return None
    return (f"the similarity's answer scales B by x {scale:.4f}, more than an SfM block's dome makes "
            f"(within {MAX_DOME_SCALE:.0%}): not kept; the rigid match answers")


@dataclass(frozen=True)
class Search:
    """One search of two maps: its parameters with the association derived from the maps
    (`plugin.map_noise.derived_search_params`), and that derivation (its first, wider and near tries)."""

    params: Params
    derivation: DerivedSearch


@dataclass(frozen=True)
class SearchPlan:
    """What `match` searches two maps with: `first`, the chosen transform's search; `note`, why a similarity
    (None: the configured transform); `fallback`, the configured (rigid) search that answers when the similarity's
    scale is no dome's (None without a similarity chosen by the maps' pose sources)."""

    first: Search
    note: str | None = None
    fallback: Search | None = None


@dataclass(frozen=True)
class PlannedAnswer:
    """The answer of a `SearchPlan` and the search it was made with (`search`: its params are the answer's, what
    match.json records and the output's identity holds); `note`: match.json's `search_mode.transform_from_poses`;
    `beyond`: why the similarity's answer was not kept (the fallback answered), else None."""

    search: Search
    answer: MatchAnswer
    note: str | None = None
    beyond: str | None = None


def plan_search(params: Params, chosen: bool, sfm_a: bool, sfm_b: bool, noise_a: MapNoise | None,
                noise_b: MapNoise | None, points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                sizes_b: np.ndarray | None) -> SearchPlan:
    """The searches `match` (and `evaluate`, which scores what `match` does) runs on two maps: the transform
    `choose_transform` chooses, each search's association derived from the maps' noise and geometry."""

    def derived(given: Params) -> Search:
        derivation = derived_search_params(given.association, noise_a, noise_b, points_a, sizes_a, points_b, sizes_b)
        return Search(dataclasses.replace(given, association=derivation.params), derivation)

    choice = choose_transform(params, chosen, sfm_a, sfm_b)
    if choice.note is None:
        return SearchPlan(derived(params))
    return SearchPlan(derived(choice.params), choice.note, derived(params))


def answer_plan(plan: SearchPlan, points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                sizes_b: np.ndarray | None, common_frame: bool = False, exhaustive: bool = False) -> PlannedAnswer:
    """Search and verify (`plugin.match_answer.match_maps`) as `plan` says: its first search; when the maps'
    pose sources chose a similarity and its accepted answer's scale is no dome's (`beyond_dome`), the rigid
    search answers instead, as it did before the choice. One function for `match` and `evaluate`."""
    from ...plugin.match_answer import match_maps

    def run(search: Search) -> MatchAnswer:
        d = search.derivation
        return match_maps(points_a, sizes_a, points_b, sizes_b, search.params, common_frame=common_frame,
                          exhaustive=exhaustive, first_try=d.first_try, wider_try=d.wider_try, near_try=d.near_try)

    ans = run(plan.first)
    if plan.fallback is not None and ans.accepted and ans.transform is not None:
        beyond = beyond_dome(float(ans.transform.scale))
        if beyond is not None:  # no dome's scale: the rigid match answers
            return PlannedAnswer(plan.fallback, run(plan.fallback), f"{plan.note}; {beyond}", beyond)
    return PlannedAnswer(plan.first, ans, plan.note)
