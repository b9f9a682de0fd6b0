"""Maps whose vertical axes differ (frames not both gravity-aligned: SLAM / VIO local frames, a COLMAP model not
registered to gravity) by 10-22 deg, inside the search's gravity check: the level verification kept only the pairs
near the centroid and was "verified" metres off (rev42: roll 18 deg, 34 of 140 pairs, 15.9 m at the far end). The
free 6-DOF fit is the answer when the heights show the tilt and it pairs clearly more landmarks."""

import json

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.plugin.association.rigid import rotation_from_rpy_deg
from sosmatch.tools.cli import main

TRUTH_T = np.array([40.0, -25.0, 3.0])


def _pair(tmp_path, roll_deg):
    """rev42's construction: A 200 random landmarks over 300 x 300 m; B its landmarks 60..199 moved by the truth
    x_A = R x_B + T (yaw 37 deg, roll `roll_deg`) with 0.3 m noise. Returns the paths, B's points and R."""
    rng = np.random.default_rng(1)
    pa = np.column_stack([rng.uniform(0, 300, 200), rng.uniform(0, 300, 200), rng.normal(0, 1.5, 200)])
    sa = rng.lognormal(0.5, 0.5, 200)
    rng = np.random.default_rng(5)
    rot = rotation_from_rpy_deg(roll_deg, 0, 37)
    idx = np.arange(60, 200)
    pb = (pa[idx] - TRUTH_T) @ rot + rng.normal(0, 0.3, (len(idx), 3))
    sb = sa[idx] * rng.lognormal(0, 0.05, len(idx))
    paths = []
    for name, p, s in (("a", pa, sa), ("b", pb, sb)):
        write_landmark_map(tmp_path / f"{name}.sosmap", LandmarkMap(p, s.astype(np.float32), np.zeros(3), 0))
        paths.append(str(tmp_path / f"{name}.sosmap"))
    return paths, pb, rot


def _match(tmp_path, roll_deg):
    paths, pb, rot = _pair(tmp_path, roll_deg)
    assert main(["match", *paths, "--out", str(tmp_path / "m"), "--no-plot", "-q"]) == 0
    doc = json.loads((tmp_path / "m" / "match.json").read_text())
    t = doc["verification"]["transform"]
    moved = pb @ np.array(t["rotation"]).T + np.array(t["translation"])
    err = np.linalg.norm(moved - (pb @ rot.T + TRUTH_T), axis=1)
    return doc, err


@pytest.mark.parametrize("roll_deg", [10.0, 14.0, 18.0])
def test_maps_tilted_against_each_other_get_the_free_fit_and_a_warning(tmp_path, roll_deg):
    doc, err = _match(tmp_path, roll_deg)
    ver = doc["verification"]
    assert ver["accepted"] and ver["support"] >= 135  # the level fit kept 139 / 80 / 34 of 140
    assert err.max() < doc["params"]["association"]["distance_tolerance_m"]  # within the gate (was 2.4 / 6.4 / 15.9 m)
    said = [w for w in doc["warnings"] if "vertical axes differ by" in w]
    assert len(said) == 1 and "not both gravity-aligned" in said[0]
    tilt = float(said[0].split("differ by ")[1].split(" deg")[0])
    assert abs(tilt - roll_deg) < 1.0
    # the rivals and chance judged the answer given: its pairs are the support they were compared with
    assert ver["support_dof"] == ver["support"] and ver["chance"]["p_value"] <= ver["chance"]["false_alarm"]


def test_level_maps_keep_the_level_fit_and_no_warning(tmp_path):
    doc, err = _match(tmp_path, 0.0)
    ver = doc["verification"]
    assert ver["accepted"] and ver["support"] == 140 and err.max() < 0.5
    assert not [w for w in doc["warnings"] if "vertical axes" in w]
    assert ver["support_dof"] == 140  # the level search's own support: the free fit was not taken


def test_a_tilted_answer_meets_the_chance_a_level_one_does(tmp_path):
    """Chance placed B level while the answer was tilted: the local chance refinements never reached a 14 deg tilt,
    so the free fit's extra freedom counted as less chance, not more (rev43: two unrelated rows, 5 m apart along
    each, B rolled 14 deg: chance p 1.7e-75 and only the ratio test refusing, where the level pair's p is 1.0).
    Chance now judges B turned by the answer's tilt: the same p tilted or level."""
    ra, rb = np.random.default_rng(31), np.random.default_rng(32)
    pa = np.column_stack([np.arange(100) * 5.0, ra.normal(0, 0.2, 100), ra.normal(0, 0.2, 100)])
    pb = np.column_stack([np.arange(70) * 5.0, rb.normal(0, 0.2, 70), rb.normal(0, 0.2, 70)])
    pb = pb @ rotation_from_rpy_deg(0, 0, 37).T + np.array([7.0, -3.0, 1.0])
    sa, sb = ra.lognormal(0.5, 0.5, 100), rb.lognormal(0.5, 0.5, 70)
    write_landmark_map(tmp_path / "a.sosmap", LandmarkMap(pa, sa.astype(np.float32), np.zeros(3), 0))
    chance = {}
    for roll in (0.0, 14.0):
        c = pb.mean(axis=0)
        b = tmp_path / f"b{roll:.0f}.sosmap"
        write_landmark_map(b, LandmarkMap((pb - c) @ rotation_from_rpy_deg(roll, 0, 0).T + c, sb.astype(np.float32),
                                          np.zeros(3), 0))
        out = tmp_path / f"m{roll:.0f}"
        assert main(["match", str(tmp_path / "a.sosmap"), str(b), "--out", str(out), "--no-plot", "-q"]) == 0
        ver = json.loads((out / "match.json").read_text())["verification"]
        assert not ver["accepted"]
        chance[roll] = ver["chance"]["p_value"]
    assert chance[14.0] > 0.5 and chance[0.0] > 0.5, chance  # level: p 1.0; tilted, placed level: 1.7e-75
