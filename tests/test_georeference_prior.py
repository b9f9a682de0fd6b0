"""Maps georeferenced in one EPSG are searched near their georeference first (`association.georeference_prior_m`).

The two maps in tests/data are `sosmatch map --ekf` outputs of the synthetic world 229 (the spring session and a
winter session flown across it at 90 degrees; both in the world's frame, as two GNSS-georeferenced maps are):
85 winter landmarks, 21-23 of them on objects of the spring map."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.chance import within_prior
from sosmatch.plugin.map_noise import derived_search_params
from sosmatch.plugin.match_answer import MatchAnswer, match_maps
from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.params import Params, preset_params, with_overrides
from sosmatch.plugin.refinement import yaw_matrix
from sosmatch.plugin.verification import verify_alignments
from sosmatch.tools.cli import main

DATA = Path(__file__).parent / "data"


def _maps() -> tuple[LandmarkMap, LandmarkMap]:
    return read_landmark_map(DATA / "w229_spring.sosmap"), read_landmark_map(DATA / "w229_winter_x90.sosmap")


def _moved(points: np.ndarray, dx: float, dy: float, yaw_deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + np.array([dx, dy, 0.0])


def _match(a: LandmarkMap, points_b: np.ndarray, sizes_b: np.ndarray, common: bool,
           params: Params | None = None) -> MatchAnswer:
    """As `sosmatch match` does: the derived search parameters, then the answer."""
    params = params or Params()
    d = derived_search_params(params.association, a.noise, a.noise, a.positions, a.sizes, points_b, sizes_b)
    return match_maps(a.positions, a.sizes, points_b, sizes_b, dataclasses.replace(params, association=d.params),
                      common_frame=common, first_try=d.first_try, wider_try=d.wider_try)


def _offset_m(ans: MatchAnswer, points_b: np.ndarray, truth_b: np.ndarray) -> float:
    t = ans.transform
    moved = points_b @ (t.scale * t.rotation).T + t.translation
    return float(np.sqrt(np.mean(np.sum((moved - truth_b)[:, :2] ** 2, axis=1))))


def test_a_crossing_flight_refused_among_all_alignments_is_found_near_the_georeference():
    a, b = _maps()
    everywhere = _match(a, b.positions, b.sizes, common=False)
    # among every alignment of the two maps chance reaches the true support too often (p ~0.09)
    assert not everywhere.accepted and everywhere.tolerances == "derived"
    near = _match(a, b.positions, b.sizes, common=True)
    assert near.accepted and near.tolerances == "georeference" and near.prior == "georeference 50 m"
    assert near.searched.position_prior_m == 50.0
    assert near.verification.chance.p_value < 1e-3 < everywhere.verification.chance.p_value
    assert _offset_m(near, b.positions, b.positions) < 5.0
    # the search is local: window pairs far apart hold no putative association and are not solved
    assert len(near.search.hypotheses) < len(everywhere.search.hypotheses)


def test_a_georeference_off_by_more_than_the_radius_costs_a_search_not_the_answer():
    a, b = _maps()
    everywhere = _match(a, b.positions, b.sizes, common=False)
    far = _moved(b.positions, 150.0, -90.0, 0.0)
    ans = _match(a, far, b.sizes, common=True)
    assert ans.prior == "georeference 50 m refused: searched everywhere"
    assert ans.tolerances == everywhere.tolerances and ans.searched.position_prior_m == 0.0
    assert ans.accepted == everywhere.accepted
    assert ans.verification.support == everywhere.verification.support
    # within the radius it is found near the georeference, at its true place
    near = _moved(b.positions, 30.0, -25.0, 3.0)
    ans = _match(a, near, b.sizes, common=True)
    assert ans.accepted and ans.tolerances == "georeference" and _offset_m(ans, near, b.positions) < 5.0


def test_an_answer_beyond_the_prior_is_not_one_of_its_chance_test():
    # a shift and a turn that cancel near their fixed point leave landmarks there within the prior, so a search
    # with the prior finds alignments beyond it; its chance test measured only alignments within it
    b = _maps()[1].positions
    c = b.mean(axis=0)
    assert within_prior(Sim3(np.eye(3), np.array([30.0, -30.0, 5.0])), b, 50.0, 3.0)
    assert not within_prior(Sim3(np.eye(3), np.array([60.0, 0.0, 0.0])), b, 50.0, 3.0)
    turn = yaw_matrix(np.radians(90.0))  # about B's centre: the centre stays, the landmarks move ~100 m
    assert not within_prior(Sim3(turn, c - turn @ c), b, 50.0, 3.0)
    assert within_prior(Sim3(turn, c - turn @ c), b, 0.0, 3.0)  # no prior: anything
    ans = verify_alignments(b, None, b + np.array([80.0, 0.0, 0.0]), None,
                            [(Sim3(np.eye(3), np.array([-80.0, 0.0, 0.0])), np.arange(len(b)))], 3.0, 0.3, 6,
                            prior_m=50.0, chance_starts=64)
    assert ans.beyond_prior and not ans.accepted and ans.support == len(b)
    ans = verify_alignments(b, None, b + np.array([20.0, 0.0, 0.0]), None,
                            [(Sim3(np.eye(3), np.array([-20.0, 0.0, 0.0])), np.arange(len(b)))], 3.0, 0.3, 6,
                            prior_m=50.0, chance_starts=64)
    assert ans.accepted and not ans.beyond_prior


@pytest.mark.parametrize("seed", [1, 2])
def test_maps_of_other_places_in_one_frame_are_refused_near_the_georeference(seed):
    a, _ = _maps()
    other = survey_map_pair(300, seed=seed, density_per_km2=1500.0, noise_m=0.9, size_noise=0.3)
    pb = other.points_b - other.points_b.mean(axis=0) + a.positions.mean(axis=0)  # laid over A's ground
    ans = _match(a, pb, other.sizes_b, common=True)
    assert not ans.accepted and ans.prior == "georeference 50 m refused: searched everywhere"


def test_no_search_near_the_georeference_without_one_frame_a_hard_prior_or_the_verification():
    a, b = _maps()
    assert _match(a, b.positions, b.sizes, common=False).prior == "off"
    hard = with_overrides(Params(), {"association.position_prior_m": 50.0})
    ans = _match(a, b.positions, b.sizes, common=True, params=hard)
    assert ans.prior == "applied" and ans.tolerances != "georeference"
    off = with_overrides(Params(), {"verification.enabled": False})
    ans = _match(a, b.positions, b.sizes, common=True, params=off)
    assert ans.prior == "off" and ans.source == "consensus"
    paper = preset_params("paper")
    assert paper.association.georeference_prior_m == 0.0
    assert _match(a, b.positions, b.sizes, common=True, params=paper).prior == "off"


def test_match_says_it_searched_near_the_georeference(tmp_path, capsys):
    a, b = _maps()
    for name, m in (("a", a), ("b", b)):
        write_landmark_map(tmp_path / f"{name}.sosmap", dataclasses.replace(m, epsg=32617))
    out = tmp_path / "m"
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(out),
                 "--no-plot"]) == 0
    assert "verified within 50 m of the georeference: " in capsys.readouterr().out
    mode = json.loads((out / "match.json").read_text())["search_mode"]
    assert mode["position_prior"] == "georeference 50 m" and mode["tolerances"] == "georeference"
    assert mode["searched"]["position_prior_m"] == 50.0 and not mode["paper"]
