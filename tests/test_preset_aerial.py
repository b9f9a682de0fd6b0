"""The "aerial" preset: association of km-scale maps from coarse imagery (few common landmarks, metres of noise)."""

import json

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.plugin.association.rigid import rotation_angle_deg
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.params import PRESETS, Params, params_to_dict, preset_params
from sosmatch.tools.cli import main


def test_aerial_preset_changes_association_only():
    paper, aerial = params_to_dict(Params()), params_to_dict(preset_params("aerial"))
    changed = {(sec, k) for sec in paper if isinstance(paper[sec], dict) for k in paper[sec]
               if paper[sec][k] != aerial[sec][k]}
    assert changed and {sec for sec, _ in changed} == {"association"}
    assert len(changed) == len(PRESETS["aerial"])
    a = preset_params("aerial").association
    # the affinity keeps the paper's sigma = eps / 2; windows overlap so every stretch lies whole in one
    assert a.affinity_sigma_m == pytest.approx(a.distance_tolerance_m / 2)
    assert a.window_stride < a.window_length
    assert a.min_associations > Params().association.min_associations


@pytest.fixture(scope="module")
def coarse_maps(tmp_path_factory):
    """A sparse pair like NAIP: 40 landmarks / km^2, 3 m noise per axis, a third missing, half as many added."""
    d = tmp_path_factory.mktemp("aerial")
    s = survey_map_pair(120, seed=3, density_per_km2=40.0, noise_m=3.0, size_noise=0.15, missing=0.3, added=0.5,
                        strip_width_m=800.0)
    write_landmark_map(d / "a.sosmap", LandmarkMap(s.points_a, s.sizes_a, s.points_a.mean(0).round()))
    write_landmark_map(d / "b.sosmap", LandmarkMap(s.points_b, s.sizes_b, s.points_b.mean(0).round()))
    return d, s


def test_match_preset_aerial_uses_its_values_and_aligns_coarse_maps(coarse_maps, tmp_path):
    d, s = coarse_maps
    docs = {}
    for preset in ("paper", "aerial"):
        out = tmp_path / preset
        assert main(["match", str(d / "a.sosmap"), str(d / "b.sosmap"), "--out", str(out), "--no-plot", "-q",
                     "--preset", preset]) == 0
        docs[preset] = json.loads((out / "match.json").read_text())
    for key, value in PRESETS["aerial"].items():
        assert docs["aerial"]["params"]["association"][key.split(".", 1)[1]] == value
    # 3 m of noise per axis is far outside the paper's 2 m tolerance: nothing accepted there
    assert docs["paper"]["num_accepted"] == 0
    doc = docs["aerial"]
    assert doc["num_accepted"] > 0
    rot = np.array(doc["consensus"]["transform"]["rotation"])
    assert rotation_angle_deg(rot, s.rotation) < 1.0
    truth = set(map(tuple, s.truth.tolist()))
    pairs = set(map(tuple, np.array(doc["consensus"]["associations"]).reshape(-1, 2).tolist()))
    assert len(pairs & truth) >= 0.8 * len(pairs)
