"""`sosmatch changes` on a match whose images agree and whose maps' georeferences disagree: refused as `merge`
refuses it (one line, exit 2, nothing written) unless --trust-images, which compares and says so in changes.json.
The fixtures are those of test_merge.py's georeference test."""

import json

import pytest

from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
from sosmatch.database.match_io import read_match
from sosmatch.plugin.multisession import Sim3
from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import lawnmower, make_world, toy_match_json, write_toy_session, yaw_transform


@pytest.fixture(scope="module")
def geo_pair(tmp_path_factory):
    """test_merge.py's pair, both maps stamped with EPSG 32617."""
    root = tmp_path_factory.mktemp("geo")
    world = make_world(260, seed=11)
    a = write_toy_session(root / "A", world, lawnmower(20, 140, 20, 140, 60, 40, 10), Sim3.identity(), seed=1)
    b = write_toy_session(
        root / "B", world, lawnmower(90, 220, 90, 220, 60, 40, 10), yaw_transform(40, (15, -8, 3)), seed=2
    )
    for s in (a, b):
        lm = read_landmark_map(s.path / "landmarks.sosmap")
        write_landmark_map(s.path / "landmarks.sosmap", LandmarkMap(lm.positions, lm.sizes, lm.origin, 32617))
    return root, a, b


def _recorded_georeference(match_json, b_path, radius_m=50.0):
    """What `match` records of maps in one EPSG (as test_merge.py's helper): how far the answer moves B from its
    georeference (`chance.median_horizontal_move` over its paired landmarks) and the radius."""
    from sosmatch.plugin.chance import median_horizontal_move

    m = read_match(match_json)
    off = median_horizontal_move(m.transform, read_landmark_map(b_path / "landmarks.sosmap").positions[
        m.associations[:, 1]])
    data = json.loads(match_json.read_text())
    data["search_mode"] = {"position_prior": f"georeference {radius_m:g} m: refused there",
                           "georeference_off_m": round(off, 2)}
    data["params"] = {"association": {"georeference_prior_m": radius_m}}
    match_json.write_text(json.dumps(data))
    return off


def test_changes_refuses_maps_whose_georeferences_disagree_unless_told_to_trust_the_images(geo_pair, tmp_path,
                                                                                          capsys):
    """The commit that made merge refuse it left `changes` comparing such a pair in silence, its changes.geojson
    placed by A's georeference, which may be the wrong one."""
    _, a, b = geo_pair
    match = toy_match_json(a, b, tmp_path / "far.json")
    off = _recorded_georeference(match, b.path)
    assert off > 50.0
    command = ["changes", str(a.path), str(b.path), "--match", str(match), "--no-plot"]
    capsys.readouterr()
    assert main([*command, "--out", str(tmp_path / "C")]) == 2
    err = capsys.readouterr().err
    said = f"images agree, georeferences disagree by {off:.0f} m: one georeference is wrong"
    assert said in err and "--trust-images" in err and "nothing compared" in err and str(match) in err
    assert err.count("\n") == 1 and not (tmp_path / "C").exists()
    assert main([*command, "--out", str(tmp_path / "T"), "--trust-images"]) == 0
    record = json.loads((tmp_path / "T" / "changes.json").read_text())
    assert any(said in w and "--trust-images" in w for w in record["warnings"])
    # within the radius the georeferences agree: compared, nothing said of them
    near = toy_match_json(a, b, tmp_path / "near.json")
    _recorded_georeference(near, b.path, radius_m=2 * off)
    assert main(["changes", str(a.path), str(b.path), "--match", str(near), "--no-plot", "--out",
                 str(tmp_path / "N")]) == 0
    record = json.loads((tmp_path / "N" / "changes.json").read_text())
    assert not any("georeferences disagree" in w for w in record["warnings"])
