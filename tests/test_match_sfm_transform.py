"""Maps of structure-from-motion poses are matched with a similarity (`workflows.match.transform_choice`).

An SfM block of small images can be domed, scaling its landmarks by a few % about its centre (BENCHMARKS.md "Two
SfM maps of one place refused"); a map records where its poses came from (run.json `pose_source`, the .sosmap's
flag 4) and `match` fits a scale when either map is SfM-posed and the user did not choose the transform.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.landmark_map import (
    POSE_SOURCE_GIVEN,
    POSE_SOURCE_SFM,
    LandmarkMap,
    decode_landmark_map,
    encode_landmark_map,
    read_landmark_map,
    write_landmark_map,
)
from sosmatch.database.map_loading import load_map, recorded_sfm_poses
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.map_noise import MapNoise
from sosmatch.plugin.params import Params
from sosmatch.plugin.refinement import yaw_matrix
from sosmatch.workflows.match.transform_choice import MAX_DOME_SCALE, beyond_dome, choose_transform

NOISE = MapNoise(0.4, 0.35, 0.1, 274)


def _map(sfm: bool, noise: MapNoise | None = NOISE) -> LandmarkMap:
    rng = np.random.default_rng(1)
    xyz = rng.uniform(0, 100, (20, 3))
    return LandmarkMap(xyz, rng.uniform(1, 5, 20).astype(np.float32), np.array([50.0, 50.0, 0.0]), 32632, noise,
                       sfm_poses=sfm)


@pytest.mark.parametrize("noise", [NOISE, None])
def test_the_map_file_carries_the_pose_source(tmp_path: Path, noise: MapNoise | None) -> None:
    """Flag 4 round-trips (with and without the noise block); a map of given poses is written byte for byte as
    before the flag (same bytes as a map that never heard of it, flag bits 1 | 2 only)."""
    for sfm in (True, False):
        write_landmark_map(tmp_path / "m.sosmap", _map(sfm, noise))
        back = read_landmark_map(tmp_path / "m.sosmap")
        assert back.sfm_poses is sfm
        np.testing.assert_allclose(back.positions, _map(sfm, noise).positions, atol=1e-4)
    data = encode_landmark_map(_map(False, noise))
    flags = int.from_bytes(data[10:12], "little")
    assert flags == (1 | (2 if noise is not None else 0))
    sfm_data = encode_landmark_map(_map(True, noise))
    assert int.from_bytes(sfm_data[10:12], "little") == flags | 4
    assert len(sfm_data) == len(data)  # the flag has no bytes of its own


def test_an_unknown_flag_is_still_refused() -> None:
    """rev51 D5: as a map of a newer sosmatch (update), not as a damaged file."""
    import struct
    import zlib

    data = bytearray(encode_landmark_map(_map(True)))
    data[10:12] = struct.pack("<H", int.from_bytes(data[10:12], "little") | 8)
    data[-4:] = struct.pack("<I", zlib.crc32(bytes(data[:-4])))
    with pytest.raises(InputError, match="0x8 this sosmatch does not know: it was probably written by a newer "
                                         "sosmatch; update sosmatch"):
        decode_landmark_map(bytes(data), "x.sosmap")
    data[8:10] = struct.pack("<H", 3)  # a newer version too: said so, not only "unsupported"
    data[-4:] = struct.pack("<I", zlib.crc32(bytes(data[:-4])))
    with pytest.raises(InputError, match="version 3 .*newer sosmatch: update sosmatch"):
        decode_landmark_map(bytes(data), "x.sosmap")


def test_run_records_say_where_the_poses_came_from(tmp_path: Path) -> None:
    """run.json's `pose_source`; a record written before it: the text `map --images` then wrote for SfM poses, or
    a poses.csv beside the record of `sosmatch poses` (README's two steps)."""
    (tmp_path / "poses.csv").write_text("name\n")
    assert not recorded_sfm_poses({"inputs": {"poses": str(tmp_path / "poses.csv")}})
    (tmp_path / "poses.json").write_text(json.dumps({"format": "sosmatch-poses", "version": 1}))
    assert recorded_sfm_poses({"inputs": {"poses": str(tmp_path / "poses.csv")}})
    assert not recorded_sfm_poses({"inputs": {"poses": "x" * 5000 + "/poses.csv"}})
    assert recorded_sfm_poses({"pose_source": POSE_SOURCE_SFM})
    assert not recorded_sfm_poses({"pose_source": POSE_SOURCE_GIVEN,
                                   "inputs": {"poses": "structure from motion of x (SESSION_DIR/poses)"}})
    assert recorded_sfm_poses({"inputs": {"poses": "structure from motion of imgs (SESSION_DIR/poses)"}})
    assert not recorded_sfm_poses({"inputs": {"poses": "/data/flight/poses_ekf.csv"}})
    assert not recorded_sfm_poses({"inputs": "odd"}) and not recorded_sfm_poses(None)


def test_a_session_reads_its_pose_source_from_its_record(tmp_path: Path) -> None:
    """A session mapped before the flag existed (its map file without it, run.json with the SfM text) is SfM-posed
    to `load_map`; a bare copy of a flagged map file is too."""
    from sosmatch.database.landmark_map import landmark_map_fingerprint

    lmap = _map(False)
    session = tmp_path / "s"
    session.mkdir()
    write_landmark_map(session / "landmarks.sosmap", lmap)
    written = landmark_map_fingerprint(read_landmark_map(session / "landmarks.sosmap"))
    record = {"format": "sosmatch-map-run", "version": 1, "noise": NOISE.to_dict(),
              "landmarks_fingerprint": written, "verdict": {"status": "ok"},
              "inputs": {"poses": "structure from motion of imgs (SESSION_DIR/poses)"}}
    (session / "run.json").write_text(json.dumps(record))
    assert load_map(session).sfm_poses
    record["inputs"] = {"poses": "poses.csv"}
    (session / "run.json").write_text(json.dumps(record))
    assert not load_map(session).sfm_poses
    write_landmark_map(tmp_path / "bare.sosmap", _map(True))
    assert load_map(tmp_path / "bare.sosmap").sfm_poses


def test_the_transform_is_chosen_by_the_pose_sources_unless_the_user_chose_it() -> None:
    p = Params()
    assert p.association.transform == "rigid"
    for a, b in ((True, False), (False, True), (True, True)):
        got = choose_transform(p, False, a, b)
        assert got.params.association.transform == "similarity" and "structure from motion" in got.note
        assert got.params.verification == p.verification
    none = choose_transform(p, False, False, False)
    assert none.params is p and none.note is None
    assert choose_transform(p, True, True, True).params is p  # chosen: as it is
    assert beyond_dome(1.0 + MAX_DOME_SCALE / 2) is None and beyond_dome(0.96) is None
    assert "dome" in beyond_dome(1.0 + 2 * MAX_DOME_SCALE) and beyond_dome(1.0 - 2 * MAX_DOME_SCALE)


def test_chosen_settings_name_the_preset_file_and_overrides(tmp_path: Path) -> None:
    from sosmatch.database.config_io import chosen_settings
    from sosmatch.plugin.params import PRESETS

    assert chosen_settings() == set()
    assert "association.transform" in chosen_settings(overrides={"association.transform": "rigid"})
    (tmp_path / "c.toml").write_text('[association]\ntransform = "rigid"\n')
    assert chosen_settings(tmp_path / "c.toml") == {"association.transform"}
    name = sorted(PRESETS)[0]
    assert chosen_settings(preset=name) == set(PRESETS[name])


# ---- end to end: B a domed copy of A (scaled about its centre), both written as map files

@pytest.fixture(scope="module")
def survey() -> tuple[np.ndarray, np.ndarray]:
    s = survey_map_pair(150, seed=21, density_per_km2=3000.0)
    return s.points_a, s.sizes_a


def _domed(points: np.ndarray, scale: float) -> np.ndarray:
    """Re-observed (0.3 m noise), scaled about the map's centre (a dome: plan and depth), turned 20 deg, moved."""
    noisy = points + np.random.default_rng(3).normal(0.0, 0.3, points.shape)
    centre = noisy.mean(0)
    return (centre + scale * (noisy - centre)) @ yaw_matrix(np.radians(20.0)).T + np.array([30.0, 40.0, 0.0])


def _files(tmp_path: Path, pa: np.ndarray, sa: np.ndarray, pb: np.ndarray, sfm_b: bool) -> tuple[Path, Path]:
    noise = MapNoise(0.4, 0.3, 0.05, len(pa))
    write_landmark_map(tmp_path / "a.sosmap", LandmarkMap(pa, sa, pa.mean(0).round(), 0, noise))
    write_landmark_map(tmp_path / "b.sosmap", LandmarkMap(pb, sa, pb.mean(0).round(), 0, noise, sfm_poses=sfm_b))
    return tmp_path / "a.sosmap", tmp_path / "b.sosmap"


def test_a_domed_sfm_map_is_matched_with_a_similarity(survey, tmp_path: Path) -> None:
    """B scaled by 1.04 about its centre: flagged SfM, the default match fits the scale (verified, not imprecise,
    said in match.json); the same map of given poses is matched rigidly as before (its answer imprecise, no
    note). A transform the user chose is kept: `choose_transform` above."""
    from sosmatch.workflows import match

    pa, sa = survey
    pb = _domed(pa, 1.04)
    a, b = _files(tmp_path, pa, sa, pb, sfm_b=True)
    res = match.run(Params(), a, b, tmp_path / "sfm", plot=False)
    doc = json.loads((tmp_path / "sfm" / "match.json").read_text())
    assert res.accepted and doc["transform_kind"] == "similarity"
    assert abs(doc["verification"]["transform"]["scale"] - 1 / 1.04) < 0.005
    assert not doc["answer_uncertainty"]["imprecise"]
    assert "B's poses came from structure from motion" in doc["search_mode"]["transform_from_poses"]
    assert doc["params"]["association"]["transform"] == "similarity"

    a, b = _files(tmp_path, pa, sa, pb, sfm_b=False)
    given = match.run(Params(), a, b, tmp_path / "given", plot=False)
    doc = json.loads((tmp_path / "given" / "match.json").read_text())
    assert doc["transform_kind"] == "rigid" and "transform_from_poses" not in doc["search_mode"]
    assert not given.accepted or doc["answer_uncertainty"]["imprecise"]


def test_a_scale_no_dome_makes_is_not_kept(survey, tmp_path: Path) -> None:
    """B flagged SfM but scaled by 1.115 (no dome's: a focal length or GPS scale error): the similarity's answer
    (x 0.897) is not kept, the rigid match answers (as before the choice) and a warning says why, without the
    refusal's advice to match with a similarity."""
    from sosmatch.workflows import match

    pa, sa = survey
    a, b = _files(tmp_path, pa, sa, _domed(pa, 1.115), sfm_b=True)
    match.run(Params(), a, b, tmp_path / "m", plot=False)
    doc = json.loads((tmp_path / "m" / "match.json").read_text())
    assert doc["transform_kind"] == "rigid"
    assert "more than an SfM block's dome makes" in doc["search_mode"]["transform_from_poses"]
    assert any("dome makes" in w for w in doc["warnings"])
    assert not any("--set association.transform=similarity" in w for w in doc["warnings"])


def test_a_batch_pair_keeps_the_transform_the_user_chose(survey, tmp_path: Path) -> None:
    """`batch --set association.transform=rigid` (BatchOptions.transform_chosen): its pairs of SfM-posed flights
    are matched rigidly as chosen; without the choice a batch pair is matched as `sosmatch match` would."""
    from sosmatch.workflows.batch import pair_task

    pa, sa = survey
    a, b = _files(tmp_path, pa, sa, _domed(pa, 1.04), sfm_b=True)
    pair_task(str(a), str(b), str(tmp_path / "chosen"), Params(), True, False, True)
    pair_task(str(a), str(b), str(tmp_path / "free"), Params(), True, False)
    kinds = [json.loads((tmp_path / d / "match.json").read_text())["transform_kind"] for d in ("chosen", "free")]
    assert kinds == ["rigid", "similarity"]


def test_after_the_fallback_the_output_is_the_rigid_match_it_records(survey, tmp_path: Path, monkeypatch) -> None:
    """rev51 D6: when the similarity's scale is no dome's (forced here: a dome's limit of 1 % against B scaled
    by 1.03) the rigid answer is recorded, and the output is that rigid match's: re-running with the settings
    match.json records (`association.transform=rigid` chosen) into the same folder is the same output, as is the
    same command; a chosen similarity (another answer) is refused there. Its imprecise warning does not advise the
    similarity just not kept."""
    import dataclasses

    from sosmatch.workflows import match
    from sosmatch.workflows.match import transform_choice

    monkeypatch.setattr(transform_choice, "MAX_DOME_SCALE", 0.01)
    pa, sa = survey
    a, b = _files(tmp_path, pa, sa, _domed(pa, 1.03), sfm_b=True)
    out = tmp_path / "m"
    match.run(Params(), a, b, out, plot=False)
    doc = json.loads((out / "match.json").read_text())
    assert doc["transform_kind"] == "rigid" and doc["params"]["association"]["transform"] == "rigid"
    assert doc["answer_uncertainty"]["imprecise"] and any("imprecise answer" in w for w in doc["warnings"])
    assert not any("association.transform=similarity" in w for w in doc["warnings"])
    assert "association.transform=similarity" not in doc["answer_uncertainty"]["reason"]
    rigid = match.run(Params(), a, b, out, plot=False, transform_chosen=True)  # as recorded: the same output
    assert rigid.accepted and json.loads((out / "match.json").read_text())["transform_kind"] == "rigid"
    match.run(Params(), a, b, out, plot=False)  # the same command again: the same output
    similarity = dataclasses.replace(Params().association, transform="similarity")
    before = (out / "match.json").read_bytes()
    with pytest.raises(InputError, match='made with association.transform "rigid", this run\'s "similarity";'):
        match.run(dataclasses.replace(Params(), association=similarity), a, b, out, plot=False,
                  transform_chosen=True)
    assert (out / "match.json").read_bytes() == before
    assert json.loads((out / ".sosmatch-output.json").read_text())["complete"]  # left as it was


def test_a_batch_pair_is_keyed_by_the_transform_its_match_searches_with(tmp_path: Path) -> None:
    """rev52 D4 / D5: a pair of an SfM-posed flight gets "similarity" in its fingerprint unless the user chose the
    transform (a batch matched rigidly before the choice existed is matched again, as `match` refuses that
    output); pairs of given poses, and pairs whose transform was chosen (a `config dump` file names it), keep the
    fingerprint they had, so such batches resume."""
    from sosmatch.database.map_loading import session_sfm_poses
    from sosmatch.workflows.batch import BatchOptions
    from sosmatch.workflows.batch.workflow import _searched_transform

    for name, sfm in (("sfm", True), ("given", False), ("given2", False)):
        (tmp_path / name).mkdir()
        write_landmark_map(tmp_path / name / "landmarks.sosmap", _map(sfm))
    free, chosen = BatchOptions(), BatchOptions(transform_chosen=True)
    sfm, given, given2 = (session_sfm_poses(tmp_path / n) for n in ("sfm", "given", "given2"))
    assert _searched_transform(Params(), free, given, sfm) == {"transform": "similarity"}
    assert _searched_transform(Params(), chosen, given, sfm) == {}
    assert _searched_transform(Params(), free, given, given2) == {}


def test_a_rigid_match_of_an_earlier_version_is_refused_naming_the_transform(survey, tmp_path: Path) -> None:
    """An earlier sosmatch matched a photo-mapped flight rigidly; re-run now (a similarity by default) into the
    same folder, the refusal says the transform changed and why, not only "other inputs or settings"; the
    earlier output is left as it was. A setting the record does not keep otherwise is not named."""
    from sosmatch.database.output_markers import settings_differences
    from sosmatch.workflows import match

    pa, sa = survey
    a, b = _files(tmp_path, pa, sa, _domed(pa, 1.04), sfm_b=True)
    out = tmp_path / "m"
    match.run(Params(), a, b, out, plot=False, transform_chosen=True)  # as the earlier version: rigid
    before = (out / "match.json").read_bytes()
    with pytest.raises(InputError, match=r'made with association.transform "rigid", this run\'s "similarity" '
                                         r"\(map B's poses came from structure from motion"):
        match.run(Params(), a, b, out, plot=False)
    assert (out / "match.json").read_bytes() == before
    assert settings_differences({"a": {"b": 1, "c": 2}}, {"a": {"b": 1, "c": 2, "new": 3}}) is None
    many = settings_differences({"a": {"b": 1, "c": 2}, "d": 3, "e": 4}, {"a": {"b": 0, "c": 0}, "d": 0, "e": 0})
    assert many == 'made with a.b 1, this run\'s 0; a.c 2, this run\'s 0; d 3, this run\'s 0 and 1 more setting(s)'


def test_the_georeference_benchmark_answers_as_match_does(survey, tmp_path: Path) -> None:
    """Benchmarks answer a pair with the function `match` calls (`answer_plan`): a photo-mapped (domed) B is
    matched with a similarity there too (it timed only the rigid search); on maps of given poses the row is the
    one `match_maps` with the derived parameters gave before, figure for figure."""
    import dataclasses

    from sosmatch.plugin.map_noise import derived_search_params
    from sosmatch.plugin.match_answer import match_maps
    from sosmatch.tools.benchmarks.bench_georeference import answer_row

    pa, sa = survey
    pb = _domed(pa, 1.04)
    a, b = (read_landmark_map(p) for p in _files(tmp_path, pa, sa, pb, sfm_b=True))
    row = answer_row(a, b, b.positions, pa, False)
    assert row["accepted"] and row["error_m"] < 1.0, row  # the similarity: B's landmarks back on A's

    a, b = (read_landmark_map(p) for p in _files(tmp_path, pa, sa, pb, sfm_b=False))
    row = answer_row(a, b, b.positions, pa, False)
    d = derived_search_params(Params().association, a.noise, b.noise, a.positions, a.sizes, b.positions, b.sizes)
    before = match_maps(a.positions, a.sizes, b.positions, b.sizes,
                        dataclasses.replace(Params(), association=d.params), first_try=d.first_try,
                        wider_try=d.wider_try, near_try=d.near_try)
    assert row["accepted"] == before.accepted and row["search"] == before.tolerances
    assert row["support"] == (0 if before.verification.best is None else len(before.verification.best.associations))
