"""A map's identity holds what a map depends on (`mapping_params`), not the settings of the stages after it; maps
whose identity held every setting (sosmatch before fix51) resume (rev24)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from sosmatch.database.output_markers import fingerprint, versioned_identity
from sosmatch.database.segmentation_models import SegmentationModels
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import ADDED, Params, with_overrides
from sosmatch.plugin.params import identity as registry
from sosmatch.workflows.map.output_dir import map_identity, take_output_dir

INPUTS = "inputs-fingerprint"


def _full_identity(params: Params) -> str:
    """The identity sosmatch gave a map until fix51: every setting (`params_identity`)."""
    return versioned_identity(lambda as_dict: {"inputs": INPUTS, "params": as_dict(params), "text_model": False,
                                               "masks": "backend"}).today


def _made(path: Path, identity: object) -> Path:
    with take_output_dir(path, identity, [], False) as out:
        out.write_file("run.json", "{}")  # through the folder, as `map` writes it: recorded as the map's own
        out.finish()
    return path


def _resumes(path: Path, params: Params) -> bool:
    with take_output_dir(path, map_identity(INPUTS, params, False, "backend"), [], False) as out:
        return out.was_complete


def test_map_of_the_full_parameters_resumes(tmp_path):
    out = _made(tmp_path / "map", _full_identity(Params()))
    assert _resumes(out, Params())


@pytest.mark.parametrize("later", [{"changes.min_confidence": 0.9}, {"association.distance_tolerance_m": 3.0},
                                   {"verification.min_ratio": 1.5}])
def test_another_later_stage_setting_is_the_same_map(tmp_path, later):
    changed = with_overrides(Params(), later)
    assert _resumes(_made(tmp_path / "new", map_identity(INPUTS, Params(), False, "backend")), changed)
    assert _resumes(_made(tmp_path / "old", _full_identity(Params())), changed)  # one of before fix51
    assert _resumes(_made(tmp_path / "old_set", _full_identity(changed)), changed)  # made with that --set


def test_the_figure_of_a_later_section_a_map_uses_is_another_map(tmp_path):
    out = _made(tmp_path / "map", _full_identity(Params()))
    with pytest.raises(InputError, match="other inputs or settings"):
        _resumes(out, with_overrides(Params(), {"association.min_associations": 8}))


def test_later_setting_registered_at_a_non_neutral_default_refuses_no_map(tmp_path, monkeypatch):
    # a later-stage setting added with a default that changes its stage's results (rev24: untested_object_rate):
    # a map made before it, at its version's behaviour (the neutral value), is this map
    params = Params()
    before = dataclasses.asdict(params)
    del before["changes"]["min_confidence"]
    out = _made(tmp_path / "map", fingerprint({"inputs": INPUTS, "params": before, "text_model": False,
                                               "masks": "backend"}))
    added = registry.Added("changes.min_confidence", "test", 1.0, "claims below it are dropped")
    monkeypatch.setattr(registry, "ADDED", (*ADDED, added))
    assert _resumes(out, params)


def test_map_before_a_registered_mapping_setting_is_still_refused_with_its_note(tmp_path):
    params = Params()  # whole_masks_only is True by default: a map made before it located landmarks otherwise
    before = json.loads(json.dumps(dataclasses.asdict(params)))
    names = [a.name for a in ADDED]
    for dotted in names[names.index("triangulation.whole_masks_only"):]:
        section, key = dotted.split(".")
        del before[section][key]
    out = _made(tmp_path / "map", fingerprint({"inputs": INPUTS, "params": before, "text_model": False,
                                               "masks": "backend"}))
    with pytest.raises(InputError, match="triangulation.whole_masks_only"):
        _resumes(out, params)


def test_map_made_with_truncation_aware_off_is_refused_with_the_set_that_resumes_it(tmp_path):
    # truncation_aware went on by default (fix76) and changes a map: a map made with it off (its default before,
    # the registered neutral value) is not today's map, and the refusal names the --set that resumes it as made
    off = with_overrides(Params(), {"tracking.truncation_aware": False})
    assert Params().tracking.truncation_aware
    out = _made(tmp_path / "map", map_identity(INPUTS, off, False, "backend").today)
    with pytest.raises(InputError, match="--set tracking.truncation_aware=false would accept it"):
        _resumes(out, Params())
    assert _resumes(out, off)


def test_a_map_of_other_model_files_or_of_unknown_ones_is_another_map(tmp_path):
    """The segmentation backend's model files are part of a map's identity (their sha256, whatever setting or
    environment variable named them): a map made with other files, or by a version that did not record them, is
    not resumed as this one; a backend without model files keeps the identity it had."""
    sam = with_overrides(Params(), {"segmentation.backend": "sam-onnx"})
    x, y = (SegmentationModels(sha256={"sam_encoder": e * 64, "sam_decoder": "d" * 64}) for e in "xy")
    made = _made(tmp_path / "x", map_identity(INPUTS, sam, False, "backend", x))
    with take_output_dir(made, map_identity(INPUTS, sam, False, "backend", x), [], False) as out:
        assert out.was_complete
    for name, earlier, said in (("y", map_identity(INPUTS, sam, False, "backend", y), "other inputs or settings"),
                                ("unknown", map_identity(INPUTS, sam, False, "backend"), "which model made it")):
        out = _made(tmp_path / name, earlier)
        with pytest.raises(InputError, match=said), \
                take_output_dir(out, map_identity(INPUTS, sam, False, "backend", x), [], False):
            pass
    assert (map_identity(INPUTS, Params(), False, "backend", SegmentationModels())
            == map_identity(INPUTS, Params(), False, "backend"))
