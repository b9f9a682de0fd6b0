"""`sosmatch changes` on a match whose images agree and whose maps' georeferences disagree: refused as `merge`
refuses it (one line, exit 2, nothing written) unless --trust-images, which compares and says so in changes.json.
The pair is test_merge.py's (`toy_sessions.overlapping_pair`)."""

import json

import pytest

from sosmatch.tools.cli import main
from sosmatch.tools.toy_sessions import overlapping_pair, record_georeference_offset, stamp_epsg, toy_match_json


@pytest.fixture(scope="module")
def geo_pair(tmp_path_factory):
    """test_merge.py's pair, both maps stamped with EPSG 32617 (`stamp_epsg`)."""
    root = tmp_path_factory.mktemp("geo")
    _, a, b = overlapping_pair(root)
    for s in (a, b):
        stamp_epsg(s.path, 32617)
    return root, a, b


def test_changes_refuses_maps_whose_georeferences_disagree_unless_told_to_trust_the_images(geo_pair, tmp_path,
                                                                                          capsys):
    """The commit that made merge refuse it left `changes` comparing such a pair in silence, its changes.geojson
    placed by A's georeference, which may be the wrong one."""
    _, a, b = geo_pair
    match = toy_match_json(a, b, tmp_path / "far.json")
    off = record_georeference_offset(match, b.path)
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
    record_georeference_offset(near, b.path, radius_m=2 * off)
    assert main(["changes", str(a.path), str(b.path), "--match", str(near), "--no-plot", "--out",
                 str(tmp_path / "N")]) == 0
    record = json.loads((tmp_path / "N" / "changes.json").read_text())
    assert not any("georeferences disagree" in w for w in record["warnings"])
