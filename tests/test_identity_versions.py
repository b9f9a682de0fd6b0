"""Outputs of an earlier sosmatch (before a registered setting existed) resume; a setting at another value does not."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from sosmatch.database.output_markers import MARKER, fingerprint, versioned_identity
from sosmatch.database.outputs import open_output_dir
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import ADDED, Params, params_identity, params_to_dict, with_overrides
from sosmatch.workflows.batch.state import StateStore, run_stage


def _before(d: dict, name: str, section: str = "") -> dict:
    """`d` (the params dict, or its `section` "changes." etc.) as the version before the registered setting `name`
    recorded it: without that setting and without every one registered after it (that version had none of them)."""
    d = json.loads(json.dumps(d))
    names = [a.name for a in ADDED]
    for dotted in names[names.index(name):]:
        if not dotted.startswith(section):
            continue
        *sections, key = dotted[len(section):].split(".")
        node = d
        for s in sections:
            node = node[s]
        del node[key]
    return d


def _changes_identity(params: Params) -> object:
    return versioned_identity(lambda as_dict: {"maps": ["a", "b"], "changes": as_dict(params.changes)})


def _make_output(path: Path, identity: str) -> None:
    with open_output_dir(path, "changes", identity) as out:
        (out.path / "changes.json").write_text("{}")
        out.finish()


def test_registry_names_real_settings_once():
    names = [a.name for a in ADDED]
    assert len(names) == len(set(names))
    flat = params_to_dict(Params())
    for name in names:
        node = flat
        for part in name.split("."):
            node = node[part]  # KeyError: a registered setting that is no setting


def test_neutral_setting_is_left_out_and_other_values_stay():
    d = params_identity(Params())
    assert "min_jpeg_quality" not in d["changes"] and "min_jpeg_quality" not in d["quality"]
    assert d["triangulation"]["whole_masks_only"] is True  # a default that changed behaviour stays in
    d50 = params_identity(with_overrides(Params(), {"changes.min_jpeg_quality": 50.0}))
    assert d50["changes"]["min_jpeg_quality"] == 50.0
    assert params_identity(Params().changes) == d["changes"]  # a section alone: the same rule


def test_output_of_a_version_without_the_setting_resumes(tmp_path):
    params = Params()
    # an earlier version: its changes section had no min_jpeg_quality, its identity its asdict
    old = fingerprint({"maps": ["a", "b"], "changes": _before(dataclasses.asdict(params.changes),
                                                              "changes.min_jpeg_quality", "changes.")})
    _make_output(tmp_path / "out", old)
    with open_output_dir(tmp_path / "out", "changes", _changes_identity(params)) as out:
        assert out.was_complete  # resumed, not made again
        out.finish()
    marker = json.loads((tmp_path / "out" / MARKER).read_text())
    assert marker["identity"] == _changes_identity(params).today  # re-marked under today's identity


def test_output_of_the_version_recording_every_setting_resumes(tmp_path):
    params = Params()  # sosmatch before the registry (ac8cd72): dataclasses.asdict, the settings it had all in
    recorded = _before(dataclasses.asdict(params.changes), "changes.max_motion_smear_px", "changes.")
    _make_output(tmp_path / "out", fingerprint({"maps": ["a", "b"], "changes": recorded}))
    with open_output_dir(tmp_path / "out", "changes", _changes_identity(params)) as out:
        assert out.was_complete


def test_setting_at_another_value_is_another_output(tmp_path):
    params = Params()
    old = fingerprint({"maps": ["a", "b"], "changes": _before(dataclasses.asdict(params.changes),
                                                              "changes.min_jpeg_quality", "changes.")})
    _make_output(tmp_path / "out", old)
    other = with_overrides(params, {"changes.min_jpeg_quality": 50.0})
    assert _changes_identity(other).today != _changes_identity(params).today
    with pytest.raises(InputError, match="changes.min_jpeg_quality=75.0 would accept it"):
        open_output_dir(tmp_path / "out", "changes", _changes_identity(other))


def test_refusal_names_the_set_that_resumes_only_where_one_does(tmp_path):
    def identity(params: Params, maps: tuple[str, str] = ("a", "b")) -> object:  # every section, as a map's
        return versioned_identity(lambda as_dict: {"maps": maps, "params": as_dict(params)})

    params = Params()  # today's output at the default: a user's value is refused, with the --set that resumes it
    _make_output(tmp_path / "out", identity(params).today)
    other = with_overrides(params, {"quality.min_jpeg_quality": 50.0})
    with pytest.raises(InputError, match=r"quality.min_jpeg_quality=75.0 or before it \(d1c47fd: a warning\); --set "
                                         "quality.min_jpeg_quality=75.0 would accept it"):
        open_output_dir(tmp_path / "out", "changes", identity(other))
    other_maps = identity(other, ("a", "c"))
    with pytest.raises(InputError, match="other inputs or settings") as refused:  # no setting would accept it
        open_output_dir(tmp_path / "out", "changes", other_maps)
    assert "min_jpeg_quality" not in str(refused.value)


def test_the_named_set_gives_the_neutral_value():
    from sosmatch.database.config_io import parse_override
    from sosmatch.plugin.params.identity import NO_NEUTRAL, otherwise_note

    for added in ADDED:
        if added.neutral is NO_NEUTRAL:
            continue
        flag = otherwise_note([added]).split("--set ")[1].removesuffix(" would accept it")
        params = with_overrides(Params(), dict([parse_override(flag)]))
        node = params
        for part in added.name.split("."):
            node = getattr(node, part)
        assert added.is_neutral(node), (flag, node)


def test_behaviour_change_is_refused_and_named(tmp_path):
    params = Params()  # contrast_reference's default 70 stretches hazy flights: an earlier map is another one
    seg = _before(dataclasses.asdict(params.segmentation), "segmentation.contrast_reference", "segmentation.")
    _make_output(tmp_path / "out", fingerprint({"segmentation": seg}))
    ident = versioned_identity(lambda as_dict: {"segmentation": as_dict(params.segmentation)})
    with pytest.raises(InputError, match="segmentation.contrast_reference"):
        open_output_dir(tmp_path / "out", "changes", ident)
    # set to the neutral value, the earlier output is this one
    neutral = with_overrides(params, {"segmentation.contrast_reference": 0.0})
    ident0 = versioned_identity(lambda as_dict: {"segmentation": as_dict(neutral.segmentation)})
    with open_output_dir(tmp_path / "out", "changes", ident0) as out:
        assert out.was_complete


class _NoRun:
    def run(self, fn, todo, desc="", progress=False):  # noqa: ARG002
        raise AssertionError(f"ran {sorted(todo)} again")


def test_batch_stage_of_an_earlier_version_resumes(tmp_path):
    from sosmatch.plugin.params.identity import build_versions

    params = Params()
    state = StateStore(tmp_path / "state", tmp_path)
    old = fingerprint({"changes": _before(dataclasses.asdict(params.changes), "changes.min_jpeg_quality", "changes.")})
    state.put("changes", "A__B", old, {"n": 1})
    fps = {"A__B": build_versions(lambda as_dict: fingerprint({"changes": as_dict(params.changes)}))}
    done = run_stage(_NoRun(), None, {"A__B": ()}, fps, state, "changes", tmp_path, "x", False)
    assert done["A__B"]["resumed"] and done["A__B"]["n"] == 1
    assert state.get("changes", "A__B", fps["A__B"][0]) is not None  # re-saved under today's fingerprint


def test_no_registered_setting_in_the_poses_identity():
    # workflows/poses/job.identity_of (the sfm section and the seed) builds today's identity only
    assert not [a.name for a in ADDED if a.name.startswith("sfm.") or a.name == "seed"], (
        "a registered sfm setting: build workflows/poses/job.identity_of with versioned_identity, so that poses of "
        "earlier versions resume")


def test_a_file_of_an_earlier_version_is_this_output(tmp_path):
    from sosmatch.database.output_files import OutputFiles

    # check-poses: a file written before min_jpeg_quality existed is the same output, at the behaviour of that
    # version: truncation_aware, registered later, was then off (its default is on since fix76 and changes maps)
    params = with_overrides(Params(), {"tracking.truncation_aware": False})
    old = fingerprint({"params": _before(dataclasses.asdict(params), "quality.min_jpeg_quality")})
    OutputFiles([tmp_path / "check.json"], "check-poses", old).write(tmp_path / "check.json", "{}")

    def identity(p: Params) -> object:
        return versioned_identity(lambda as_dict: {"params": as_dict(p)})

    OutputFiles([tmp_path / "check.json"], "check-poses", identity(params))  # not refused
    # the identity holds every setting: at today's defaults the file is refused, naming the --set that resumes it
    with pytest.raises(InputError, match="tracking.truncation_aware=false would accept it"):
        OutputFiles([tmp_path / "check.json"], "check-poses", identity(Params()))
    other = with_overrides(params, {"quality.min_jpeg_quality": 50.0})
    with pytest.raises(InputError, match="quality.min_jpeg_quality=75.0 would accept it"):
        OutputFiles([tmp_path / "check.json"], "check-poses", identity(other))


def test_the_note_names_the_value_an_output_was_made_with():
    """A setting registered at its default (quality.lens_check: true) is omitted from identities at that value, so
    a map refused at true and run again at false is "another output": the note said "the earlier behaviour of
    quality.lens_check ... --set quality.lens_check=true would accept it", as if true were not today's default
    (rev40). It names the value the output was made with."""
    from sosmatch.plugin.params.identity import _BY_NAME, otherwise_note

    note = otherwise_note([_BY_NAME["quality.lens_check"]])
    assert note.startswith("one made with quality.lens_check=true or before it (9eab6db"), note
    assert note.endswith("--set quality.lens_check=true would accept it"), note
