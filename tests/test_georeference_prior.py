"""Maps georeferenced in one EPSG are searched near their georeference first (`association.georeference_prior_m`).

The two maps in tests/data are `sosmatch map --ekf` outputs of the synthetic world 229 (the spring session and a
winter session flown across it at 90 degrees; both in the world's frame, as two GNSS-georeferenced maps are):
85 winter landmarks, 21-23 of them on objects of the spring map."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.chance import chance_placements, within_prior
from sosmatch.plugin.map_noise import derived_search_params
from sosmatch.plugin.match_answer import MatchAnswer, match_maps, reconcile_near
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


def _match(a: LandmarkMap, b: LandmarkMap, points_b: np.ndarray, common: bool,
           params: Params | None = None) -> MatchAnswer:
    """As `sosmatch match` does: the derived search parameters, then the answer (B's landmarks at `points_b`)."""
    params = params or Params()
    d = derived_search_params(params.association, a.noise, b.noise, a.positions, a.sizes, points_b, b.sizes)
    return match_maps(a.positions, a.sizes, points_b, b.sizes, dataclasses.replace(params, association=d.params),
                      common_frame=common, first_try=d.first_try, wider_try=d.wider_try, near_try=d.near_try)


# These maps' crossing flight is a pair at the chance test's border: with the default false alarm (0.01) it is
# now verified among all alignments (support 23 against a runner-up of 10, p 0.003, 3 m from the truth; it was
# refused at p 0.09 by a negative binomial with one 1/k for every mean, BENCHMARKS.md "the chance test's tail").
# The search near the georeference is tested where the whole-map search refuses it: at a false alarm of 1e-3.
STRICT = with_overrides(Params(), {"verification.false_alarm": 1e-3})


def _offset_m(ans: MatchAnswer, points_b: np.ndarray, truth_b: np.ndarray) -> float:
    t = ans.transform
    moved = points_b @ (t.scale * t.rotation).T + t.translation
    return float(np.sqrt(np.mean(np.sum((moved - truth_b)[:, :2] ** 2, axis=1))))


def test_a_crossing_flight_refused_among_all_alignments_is_found_near_the_georeference():
    a, b = _maps()
    everywhere = _match(a, b, b.positions, common=False, params=STRICT)
    # among every alignment of the two maps chance reaches the true support too often (p ~0.02 > 1e-3)
    assert not everywhere.accepted and everywhere.tolerances == "derived"
    near = _match(a, b, b.positions, common=True, params=STRICT)
    assert near.accepted and near.tolerances == "georeference"
    assert near.prior == "georeference 50 m: answered there, nothing accepted everywhere"
    assert near.searched.position_prior_m == 50.0
    assert near.verification.chance.p_value < 1e-3 < everywhere.verification.chance.p_value
    assert _offset_m(near, b.positions, b.positions) < 5.0
    # the search is local: window pairs far apart hold no putative association and are not solved
    assert len(near.search.hypotheses) < len(everywhere.search.hypotheses)


def test_the_crossing_flight_is_verified_among_all_alignments_at_the_default_false_alarm():
    # chance supports whose spread grows with their mean (NB1): refused at p 0.09 before (STRICT above)
    a, b = _maps()
    ans = _match(a, b, b.positions, common=False)
    assert ans.accepted and ans.verification.chance.p_value < 0.01
    assert _offset_m(ans, b.positions, b.positions) < 5.0


def test_a_georeference_off_by_more_than_the_radius_costs_a_search_not_the_answer():
    a, b = _maps()
    everywhere = _match(a, b, b.positions, common=False)
    far = _moved(b.positions, 150.0, -90.0, 0.0)
    ans = _match(a, b, far, common=True)
    assert ans.prior == "georeference 50 m: refused there"
    assert ans.tolerances == everywhere.tolerances and ans.searched.position_prior_m == 0.0
    assert ans.accepted == everywhere.accepted
    assert ans.verification.support == everywhere.verification.support
    # within the radius it is found near the georeference, at its true place
    near = _moved(b.positions, 30.0, -25.0, 3.0)
    ans = _match(a, b, near, common=True)
    assert ans.accepted and _offset_m(ans, near, b.positions) < 5.0
    assert ans.prior in ("georeference 50 m: answered there, nothing accepted everywhere",
                         "georeference 50 m: the same answer as everywhere")


def test_a_partial_alignment_near_a_wrong_georeference_is_overruled_by_the_true_one_elsewhere():
    # world 241, autumn against summer at 130 m, B's georeference 80 m off: near it the search finds 32 pairs
    # of a partial alignment 53 m from the truth that its chance test passes (p 6e-4); over every placement the
    # true alignment holds 91
    a, b = read_landmark_map(DATA / "w241_autumn.sosmap"), read_landmark_map(DATA / "w241_summer_130.sosmap")
    moved = _moved(b.positions, 80.0, 0.0, 0.0)
    ans = _match(a, b, moved, common=True)
    assert ans.accepted and ans.tolerances != "georeference" and _offset_m(ans, moved, b.positions) < 5.0
    assert ans.prior == "georeference 50 m: overruled by the alignment found everywhere"
    assert 70 <= ans.georeference_off_m <= 90
    # with the georeference right, both searches give one answer
    ans = _match(a, b, b.positions, common=True)
    assert ans.accepted and ans.prior == "georeference 50 m: the same answer as everywhere"
    assert ans.georeference_off_m is not None and ans.georeference_off_m < 5.0


def test_the_answer_near_the_georeference_needs_more_pairs_than_any_alignment_elsewhere():
    a, b = _maps()
    ans = _match(a, b, b.positions, common=True, params=STRICT)
    near, everywhere = ans.verification, _match(a, b, b.positions, common=False, params=STRICT).verification
    assert reconcile_near(50.0, near, everywhere, b.positions, 3.0)[1]
    elsewhere = dataclasses.replace(everywhere, best=dataclasses.replace(
        near.best, transform=Sim3(np.eye(3), np.array([200.0, 0.0, 0.0])),
        associations=np.zeros((len(near.best.associations), 2), np.int64)))
    said, used = reconcile_near(50.0, near, elsewhere, b.positions, 3.0)
    assert not used and said.startswith("georeference 50 m: not answered, an alignment elsewhere holds as many")
    refused_near = dataclasses.replace(near, accepted=False)
    assert reconcile_near(50.0, refused_near, everywhere, b.positions, 3.0) == ("georeference 50 m: refused there",
                                                                               False)


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
    ans = _match(a, LandmarkMap(pb, other.sizes_b, pb.mean(axis=0).round()), pb, common=True)
    assert not ans.accepted and ans.prior.startswith("georeference 50 m: ")


def test_no_search_near_the_georeference_without_one_frame_a_hard_prior_or_the_verification():
    a, b = _maps()
    assert _match(a, b, b.positions, common=False).prior == "off"
    hard = with_overrides(Params(), {"association.position_prior_m": 50.0})
    ans = _match(a, b, b.positions, common=True, params=hard)
    assert ans.prior == "applied" and ans.tolerances != "georeference"
    off = with_overrides(Params(), {"verification.enabled": False})
    ans = _match(a, b, b.positions, common=True, params=off)
    assert ans.prior == "off" and ans.source == "consensus"
    paper = preset_params("paper")
    assert paper.association.georeference_prior_m == 0.0
    assert _match(a, b, b.positions, common=True, params=paper).prior == "off"


def test_the_search_near_the_georeference_takes_its_own_theta_s():
    a, b = _maps()
    params = Params()
    near_try = dataclasses.replace(params.association, min_associations=4)
    ans = match_maps(a.positions, a.sizes, b.positions, b.sizes, params, common_frame=True, near_try=near_try)
    assert ans.tolerances == "georeference" and ans.searched.min_associations == 4
    assert ans.searched.position_prior_m == 50.0
    assert min(h.size for h in ans.search.hypotheses) <= 5 < params.association.min_associations + 1


def test_match_says_it_searched_near_the_georeference(tmp_path, capsys):
    a, b = _maps()
    for name, m in (("a", a), ("b", b)):
        write_landmark_map(tmp_path / f"{name}.sosmap", dataclasses.replace(m, epsg=32617))
    out = tmp_path / "m"
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(out),
                 "--no-plot", "--set", "verification.false_alarm=0.001"]) == 0
    assert "verified within 50 m (horizontally) of the georeference: " in capsys.readouterr().out
    mode = json.loads((out / "match.json").read_text())["search_mode"]
    assert mode["position_prior"] == "georeference 50 m: answered there, nothing accepted everywhere"
    assert mode["tolerances"] == "georeference"
    assert mode["searched"]["position_prior_m"] == 50.0 and not mode["paper"]


def test_heights_on_another_datum_change_neither_the_chance_nor_the_answer(tmp_path, caplog):
    # heights above take-off in one map, above sea level in the other: the search and the prior are horizontal,
    # and the chance placements put B at A's heights (before, they kept B 420 m off and measured no chance: p 1e-24)
    a, b = _maps()
    low = b.positions + np.array([0.0, 0.0, -420.0])
    same, moved = _match(a, b, b.positions, common=True, params=STRICT), _match(a, b, low, common=True, params=STRICT)
    assert moved.accepted and moved.tolerances == same.tolerances == "georeference"
    assert moved.verification.chance.p_value == pytest.approx(same.verification.chance.p_value, rel=0.05)
    placements = chance_placements(a.positions, low, 32, prior_m=50.0)
    assert all(abs(t.apply(low).mean(axis=0)[2] - a.positions[:, 2].mean()) < 1e-6 for t in placements)
    # and `match` says the heights are on two datums
    write_landmark_map(tmp_path / "a.sosmap", dataclasses.replace(a, epsg=32617))
    write_landmark_map(tmp_path / "b.sosmap", dataclasses.replace(b, epsg=32617, positions=low,
                                                                  origin=np.asarray(b.origin) - [0, 0, 420.0]))
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "m"),
                 "--no-plot"]) == 0
    assert re.search(r"lie 4[12]\d m below those of A", caplog.text) and "not on one datum" in caplog.text


def test_match_names_georeferences_that_disagree_whichever_search_answered(tmp_path, caplog):
    """B's georeference 200 m off (a shifted origin, another datum): the search near it finds nothing, the search
    everywhere finds the true alignment, and `match` says the two georeferences disagree (before, only an answer
    near the georeference that the search everywhere overruled was named; this one passed in silence)."""
    a, b = read_landmark_map(DATA / "w241_autumn.sosmap"), read_landmark_map(DATA / "w241_summer_130.sosmap")
    moved = _moved(b.positions, 200.0, 0.0, 0.0)
    write_landmark_map(tmp_path / "a.sosmap", dataclasses.replace(a, epsg=32617))
    write_landmark_map(tmp_path / "b.sosmap", dataclasses.replace(b, epsg=32617, positions=moved,
                                                                  origin=np.asarray(b.origin) + [200.0, 0, 0]))
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "m"),
                 "--no-plot"]) == 0
    said = re.search(r"b\.sosmap: images agree, georeferences disagree by (\d+) m: one georeference is wrong",
                     caplog.text)
    assert said and 190 <= int(said.group(1)) <= 210
    assert any(said.group(0) in w for w in json.loads((tmp_path / "m" / "match.json").read_text())["warnings"])
    mode = json.loads((tmp_path / "m" / "match.json").read_text())["search_mode"]
    assert mode["georeference_off_m"] == pytest.approx(int(said.group(1)), abs=0.5)
    caplog.clear()  # the same maps where they belong: nothing to say
    write_landmark_map(tmp_path / "b2.sosmap", dataclasses.replace(b, epsg=32617))
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b2.sosmap"), "--out", str(tmp_path / "m2"),
                 "--no-plot"]) == 0
    assert "georeferences disagree" not in caplog.text


def _w241() -> tuple[LandmarkMap, LandmarkMap]:
    """Two maps the search everywhere aligns (no prior needed)."""
    return read_landmark_map(DATA / "w241_autumn.sosmap"), read_landmark_map(DATA / "w241_summer_130.sosmap")


def _placed(lmap: LandmarkMap, east: float, north: float, epsg: int) -> LandmarkMap:
    """`lmap` moved by (east, north) in the grid of `epsg` (its origin with it: the file stores offsets)."""
    shift = np.array([east, north, 0.0])
    return dataclasses.replace(lmap, epsg=epsg, positions=np.asarray(lmap.positions) + shift,
                               origin=np.asarray(lmap.origin) + shift)


def test_maps_in_two_epsg_codes_are_named(tmp_path, caplog, capsys):
    """The thirteenth sweep: a map labelled with the wrong UTM hemisphere (32732 for 32632) matched its partner with
    a near-identity transform and nothing said the labels differ. The twenty-fifth: a Swiss flight and its copy
    tagged in Fiji (16,684 km) were said to be in two codes on stderr only, and merged by batch. Where each code
    puts B on the ground is measured (`landmark_map.georeference_offset_m`: here the same numbers at 47 N and
    43 S, ~10,000 km) and judged by the rule of one EPSG: match.json records it (`search_mode.georeference_off_m`,
    `warnings`) and the command's line says it."""
    a, b = _w241()
    write_landmark_map(tmp_path / "a.sosmap", _placed(a, 430000.0, 5200000.0, 32632))
    write_landmark_map(tmp_path / "b.sosmap", _placed(b, 430000.0, 5200000.0, 32732))
    capsys.readouterr()
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "m"),
                 "--no-plot"]) == 0
    assert "A is georeferenced in EPSG:32632 (WGS 84 / UTM zone 32N), B in EPSG:32732 (WGS 84 / UTM zone 32S)" \
        in caplog.text and "one label is wrong" in caplog.text
    doc = json.loads((tmp_path / "m" / "match.json").read_text())
    assert doc["search_mode"]["position_prior"] == "off" and doc["verification"]["accepted"]
    assert 9.9e6 < doc["search_mode"]["georeference_off_m"] < 10.1e6
    said = re.compile(r"images agree, georeferences disagree by (9,9|10,0)\d\d km: one georeference is wrong")
    assert said.search(caplog.text) and any(said.search(w) for w in doc["warnings"])
    assert said.search(capsys.readouterr().out)  # the command's own line, not only the log


def test_one_site_in_two_utm_zones_is_matched_without_a_georeference_disagreement(tmp_path, caplog):
    """Flights of one site on either side of a UTM zone edge, each in its own zone: the answer holds the change of
    projection, and where each code puts B on the ground agrees with the answer (centimetres), so match records
    the offset and says no disagreement (the rule that refuses a wrong label leaves two right ones alone)."""
    from pyproj import Transformer

    a, b = _w241()
    east, north = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(6.0, 47.0)
    map_a = _placed(a, east - 300.0, north - 300.0, 32631)
    in31 = _placed(b, east - 300.0, north - 300.0, 32631)
    x, y = Transformer.from_crs("EPSG:32631", "EPSG:32632", always_xy=True).transform(
        np.asarray(in31.positions)[:, 0], np.asarray(in31.positions)[:, 1])
    placed = np.column_stack([x, y, np.asarray(in31.positions)[:, 2]])
    map_b = dataclasses.replace(b, epsg=32632, positions=placed, origin=np.round(placed.mean(0)))
    write_landmark_map(tmp_path / "a.sosmap", map_a)
    write_landmark_map(tmp_path / "b.sosmap", map_b)
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "m"),
                 "--no-plot"]) == 0
    doc = json.loads((tmp_path / "m" / "match.json").read_text())
    assert doc["verification"]["accepted"] and doc["search_mode"]["georeference_off_m"] < 5.0
    assert "one site in two projections" in caplog.text and "georeferences disagree" not in caplog.text
    assert not any("georeferences disagree" in w for w in doc["warnings"])


def test_one_site_in_two_utm_zones_is_not_called_a_wrong_label():
    """A site on the boundary of UTM zones 31 and 32: each flight takes the zone of its first image, so two flights
    of one site can be mapped in two zones. Both labels are right; `match` said "one label is wrong" (nu15 of
    this session's sweep). Where each code puts its map on the ground tells the cases apart."""
    from pyproj import Transformer

    from sosmatch.database.landmark_map import crs_disagreement

    a, b = _maps()
    lon, lat = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(6.0, 47.0)
    in31 = np.asarray(b.positions) + [lon - 150.0, lat - 150.0, 0.0]
    x, y = Transformer.from_crs("EPSG:32631", "EPSG:32632", always_xy=True).transform(in31[:, 0], in31[:, 1])
    map_a = dataclasses.replace(a, epsg=32631, positions=np.asarray(a.positions) + [lon - 150.0, lat - 150.0, 0.0])
    map_b = dataclasses.replace(b, epsg=32632, positions=np.column_stack([x, y, in31[:, 2]]))
    said = crs_disagreement(map_a, map_b)
    assert "one site in two projections" in said and "--epsg 32631" in said and "label is wrong" not in said
    wrong = crs_disagreement(map_a, dataclasses.replace(map_b, epsg=32732))  # the same numbers, southern zone
    assert "one label is wrong" in wrong and "km apart" in wrong
    assert crs_disagreement(map_a, dataclasses.replace(map_b, epsg=32631)) is None
    assert "(UTM zones 31N and 32N: a site on a zone boundary?)" in said and "(WGS 84 / UTM zone 31N)" in said
    # nu34 D7: a national grid against UTM was asked "(the two UTM zones of a zone boundary?)": said by what they are
    lv = Transformer.from_crs("EPSG:32631", "EPSG:2056", always_xy=True).transform(in31[:, 0], in31[:, 1])
    said = crs_disagreement(dataclasses.replace(map_b, epsg=2056, positions=np.column_stack([*lv, in31[:, 2]])), map_b)
    assert "one site in two projections (maps made in different CRSs)" in said and "UTM zones" not in said
    assert "EPSG:2056 (CH1903+ / LV95)" in said and "EPSG:32632 (WGS 84 / UTM zone 32N)" in said
    # rev23: one zone in two datums (WGS 84 and ETRS89, within a metre in Europe) is no zone boundary
    said = crs_disagreement(dataclasses.replace(map_b, epsg=25832), map_b)
    assert "(UTM zone 32N in two datums)" in said and "zone boundary" not in said


def test_evaluate_does_not_count_a_winner_beyond_the_prior():
    # the diff review: evaluate took `clear` alone, so an answer the match refused as beyond its prior was scored
    from sosmatch.workflows.evaluate.sosmatch_method import _clear_in_file

    doc = {"clear": True, "beyond_prior": True}
    assert not _clear_in_file(doc, 30, 5, Params())
    assert _clear_in_file({"clear": True, "beyond_prior": False}, 30, 5, Params())
    assert _clear_in_file({"clear": True}, 30, 5, Params())  # files written before the field
