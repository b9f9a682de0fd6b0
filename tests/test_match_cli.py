"""`sosmatch match` end to end on small synthetic maps, and bad input."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.database.match_io import read_match
from sosmatch.plugin.association.rigid import rotation_angle_deg
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.tools.cli import main

SOSMATCH = str(Path(sys.executable).parent / "sosmatch")


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    d = tmp_path_factory.mktemp("maps")
    s = survey_map_pair(200, seed=21)
    write_landmark_map(d / "a.sosmap", LandmarkMap(s.points_a, s.sizes_a, s.points_a.mean(0).round()))
    session = d / "session_b"
    session.mkdir()
    write_landmark_map(session / "landmarks.sosmap", LandmarkMap(s.points_b, s.sizes_b, s.points_b.mean(0).round()))
    return d, s


def test_an_imprecise_answer_is_said_at_the_verdict(maps, tmp_path):
    """nu44: the summary line of an answer that may place B 58 m off read "verified: 9 associations ...", its
    warning at the far end of a long line; the verdict itself now says "verified, imprecise"."""
    from dataclasses import replace

    from sosmatch.plugin.params import Params
    from sosmatch.workflows import match

    d, _ = maps
    res = match.run(Params(), d / "a.sosmap", d / "session_b", tmp_path / "out", plot=False)
    u = res.answer.uncertainty
    assert res.accepted and not u.imprecise and ", verified: " in res.summary() and "WARNING" not in res.summary()
    # the same answer, had its predicted error exceeded its gate (as the tiles' 58.1 m against 2.81 m)
    res.answer.uncertainty = replace(u, predicted_max_m=58.1, imprecise=True)
    line = res.summary()
    assert ", verified, imprecise: " in line and "WARNING: imprecise answer" in line and "58.1 m" in line


def test_match_end_to_end(maps, tmp_path, capsys):
    d, s = maps
    out = tmp_path / "out"
    assert main(["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("match: ") and "\n" not in line and "over theta_S" in line and "verified: " in line
    doc = json.loads((out / "match.json").read_text())
    assert doc["format"] == "sosmatch match v1" and doc["num_accepted"] > 0
    # the summary prints the wall time and, beside it, the CPU time (the honest figure on a shared machine)
    wall, cpu = (float(x) for x in re.search(r"\(([0-9.]+) s, CPU ([0-9.]+) s\) -> ", line).groups())
    assert (wall, cpu) == (round(doc["seconds_total"], 2), round(doc["cpu_seconds_total"], 2)) and cpu > 0
    best = doc["hypotheses"][doc["best"]]
    assert best["accepted"] and best["size"] > doc["params"]["association"]["min_associations"]
    rot = np.array(doc["consensus"]["transform"]["rotation"])
    assert rotation_angle_deg(rot, s.rotation) < 0.5
    # the answer is verified on the full maps, and every consumer's reader returns it
    ver = doc["verification"]
    assert doc["answer"] == "verified" and ver["accepted"] and ver["support"] >= best["size"]
    assert rotation_angle_deg(np.array(ver["transform"]["rotation"]), s.rotation) < 0.5
    ap = doc["params"]["association"]
    assert doc["search_mode"].pop("searched") == {"window_factors": [ap["window_factor_a"], ap["window_factor_b"]],
                                                  **{k: ap[k] for k in ("window_length", "window_stride",
                                                                        "min_associations", "distance_tolerance_m",
                                                                        "max_size_difference", "position_prior_m")}}
    assert doc["search_mode"] == {"consistency": "gravity", "windows": "id", "solver": "bounded", "yaw_slices": 48,
                                  "position_prior_m": 0.0, "position_prior": "off", "paper": False,
                                  "tolerances": "configured",  # a .sosmap has no noise figures: one search
                                  "derived": {"tolerances": "configured", "windows": "configured"}}
    assert doc["search_seconds"] >= doc["timings"]["verify_s"] > 0
    assert doc["timings"]["kernel_compile_s"] >= 0  # kept out of search_seconds (nu54 M1)
    summary = read_match(out / "match.json")
    assert summary.accepted and summary.source == "verified" and len(summary.associations) == ver["support"]
    assert summary.consensus_accepted and len(summary.consensus_associations) == doc["consensus"]["num_associations"]
    rows = (out / "associations.csv").read_text().splitlines()
    assert rows[0].startswith("index_a,index_b") and len(rows) - 1 == ver["support"]
    truth = set(map(tuple, s.truth.tolist()))
    pairs = {(int(r.split(",")[0]), int(r.split(",")[1])) for r in rows[1:]}
    assert len(pairs - truth) <= 1
    assert (out / "match.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # determinism: the same inputs give the same hypotheses
    out2 = tmp_path / "out2"
    assert main(["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(out2), "--no-plot"]) == 0
    doc2 = json.loads((out2 / "match.json").read_text())
    assert doc2["hypotheses"] == doc["hypotheses"] and doc2["consensus"] == doc["consensus"]
    assert not (out2 / "match.png").exists()


def test_no_verify_paper_preset_and_an_ignored_prior(maps, tmp_path, caplog):
    d, s = maps
    out = tmp_path / "raw"
    assert main(["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(out), "--no-plot", "--no-verify",
                 "--preset", "paper", "--set", "association.position_prior_m=50"]) == 0
    doc = json.loads((out / "match.json").read_text())
    assert doc["answer"] == "consensus" and doc["verification"] is None
    mode = doc["search_mode"]
    assert mode["consistency"] == "distance" and mode["solver"] == "clipper" and mode["yaw_slices"] == 1
    # the maps carry no EPSG code: they are not known to share a frame, so the prior was not used
    assert mode["position_prior"].startswith("ignored") and not mode["paper"]
    assert "position prior ignored" in caplog.text
    summary = read_match(out / "match.json")
    assert summary.source == "consensus" and summary.accepted and doc["consensus"]["accepted"] is True
    assert len(summary.associations) == doc["consensus"]["num_associations"]
    # a consensus below theta_S is recorded as such and read as no answer (merge and changes refuse it)
    doc["consensus"]["accepted"] = False
    (out / "below.json").write_text(json.dumps(doc))
    assert not read_match(out / "below.json").accepted


def test_match_colmap_model_without_sizes(maps, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    d, s = maps
    model = tmp_path / "model"
    model.mkdir()
    rec = pycolmap.Reconstruction()
    small = s.points_b[:70]  # without sizes every landmark pair is putative: keep the problem small
    for p in small:
        rec.add_point3D(p, pycolmap.Track())
    rec.write(str(model))
    out = tmp_path / "out"
    assert main(["match", str(d / "a.sosmap"), str(model), "--out", str(out), "--no-plot",
                 "--set", "association.window_length=25"]) == 0
    doc = json.loads((out / "match.json").read_text())
    assert doc["map_b"]["kind"] == "colmap" and doc["map_b"]["has_sizes"] is False
    assert doc["num_accepted"] > 0


def test_bad_input_one_line_exit_2(maps, tmp_path):
    d, _ = maps
    r = subprocess.run([SOSMATCH, "match", str(tmp_path / "missing.sosmap"), str(d / "a.sosmap"), "--out",
                        str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "missing.sosmap" in r.stderr and "Traceback" not in r.stderr
    junk = tmp_path / "junk.sosmap"
    junk.write_bytes(b"not a map at all, sorry")
    assert main(["match", str(junk), str(d / "a.sosmap"), "--out", str(tmp_path / "o")]) == 2
    empty = tmp_path / "emptydir"
    empty.mkdir()
    assert main(["match", str(empty), str(d / "a.sosmap"), "--out", str(tmp_path / "o")]) == 2
    tiny = tmp_path / "tiny.sosmap"
    write_landmark_map(tiny, LandmarkMap(np.zeros((2, 3)), np.ones(2)))
    assert main(["match", str(tiny), str(d / "a.sosmap"), "--out", str(tmp_path / "o")]) == 2
    assert main(["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(tmp_path / "o"),
                 "--set", "association.transform=affine"]) == 2
    if Path("/dev/zero").exists():  # a device is neither a map file nor a folder (it was called a "directory")
        r = subprocess.run([SOSMATCH, "match", "/dev/zero", str(d / "a.sosmap"), "--out", str(tmp_path / "o")],
                           capture_output=True, text=True)
        assert r.returncode == 2 and "not a file or directory" in r.stderr and "directory holds" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_map_matched_with_itself_or_a_copy_is_refused(maps, tmp_path, capsys):
    """`match A A` reported the identity, verified by every landmark, as a success: a mistake, refused like one."""
    d, _ = maps
    out = tmp_path / "o"
    assert main(["match", str(d / "session_b"), str(d / "session_b" / "."), "--out", str(out)]) == 2
    assert "A and B are the same session: nothing to match" in capsys.readouterr().err
    copy = tmp_path / "copy.sosmap"
    copy.write_bytes((d / "a.sosmap").read_bytes())
    assert main(["match", str(d / "a.sosmap"), str(copy), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{copy}: holds the same landmark map as {d / 'a.sosmap'}" in err
    assert not out.exists()


def test_colmap_model_sizes_from_tracks(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from sosmatch.database.colmap_db import write_colmap_database
    from sosmatch.database.map_loading import load_map
    from sosmatch.plugin.geometry import Camera

    rng = np.random.default_rng(0)
    f = 800.0
    cam = Camera(1000, 800, f, f, 500.0, 400.0)
    pts = rng.uniform([-30, -30, 0], [30, 30, 10], (6, 3))
    true_size = rng.uniform(1.0, 8.0, 6)
    rot = np.diag([1.0, -1.0, -1.0])  # nadir camera
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="PINHOLE", width=1000, height=800,
                                                    params=[f, f, 500.0, 400.0]))
    keypoints = []
    for i in range(3):
        centre = np.array([5.0 * i, 0.0, 120.0])
        t = -rot @ centre
        depth = (pts @ rot.T + t)[:, 2]
        uv = (pts @ rot.T + t)[:, :2] / depth[:, None] * f + [500.0, 400.0]
        h_px = true_size * f / depth
        kp = np.zeros((6, 6), np.float32)
        kp[:, :2] = uv
        kp[:, 2], kp[:, 5] = h_px, 0.5 * h_px  # A = sqrt(Sigma), largest axis h_px
        keypoints.append(kp)
        img = pycolmap.Image(name=f"f{i}.jpg", camera_id=1, image_id=i + 1)
        img.points2D = pycolmap.Point2DList([pycolmap.Point2D(p) for p in uv.astype(np.float64)])
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(pycolmap.Rotation3d(rot), t))
    for k in range(6):
        track = pycolmap.Track()
        for i in range(3):
            track.add_element(i + 1, k)
        rec.add_point3D(pts[k], track)
    session = tmp_path / "session"
    (session / "sparse").mkdir(parents=True)
    rec.write(str(session / "sparse"))
    write_colmap_database(session / "database.db", cam, [f"f{i}.jpg" for i in range(3)], keypoints, {})
    loaded = load_map(session)
    assert loaded.kind == "colmap" and loaded.lmap.has_sizes
    assert np.allclose(loaded.lmap.positions, pts)
    assert np.allclose(loaded.lmap.sizes, true_size, rtol=1e-3)


def test_exhaustive_flag_gives_the_same_file(maps, tmp_path):
    d, _ = maps
    docs = []
    for name, extra in (("fast", ["--workers", "2"]), ("ref", ["--exhaustive"])):
        out = tmp_path / name
        assert main(["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(out), "--no-plot",
                     "--set", "association.window_length=30", *extra]) == 0
        docs.append(json.loads((out / "match.json").read_text()))
    assert docs[0]["num_accepted"] > 0
    for key in ("hypotheses", "best", "accepted", "consensus"):
        assert docs[0][key] == docs[1][key]


def test_the_first_of_two_searches_is_judged_at_its_own_theta_s(maps):
    # the first search keeps the configured windows and theta_S (map_noise.first_search_params); when it answers,
    # its hypotheses are those of that theta_S, which match.json and the evaluation must use (not the derived one)
    import dataclasses

    from sosmatch.plugin.match_answer import match_maps
    from sosmatch.plugin.params import Params

    _, s = maps
    params = Params()
    derived = dataclasses.replace(params.association, min_associations=params.association.min_associations + 3)
    first = dataclasses.replace(derived, min_associations=params.association.min_associations)
    answer = match_maps(s.points_a, s.sizes_a, s.points_b, s.sizes_b,
                        dataclasses.replace(params, association=derived), common_frame=False, first_try=first)
    assert answer.accepted and answer.tolerances == "first"
    assert answer.searched.min_associations == first.min_associations != derived.min_associations
    assert min(h.size for h in answer.search.hypotheses) <= derived.min_associations  # hypotheses of theta_S 6


def test_an_unmapped_synthetic_session_is_named_as_such(tmp_path, cli_error):
    raw = tmp_path / "raw"
    (raw / "images").mkdir(parents=True)
    (raw / "session.json").write_text("{}")
    err = cli_error("match", raw, raw, "--out", tmp_path / "m")
    assert "not mapped yet" in err and "sosmatch map --poses" in err and not (tmp_path / "m").exists()


def test_map_files_carrying_their_noise_figures_are_matched_with_derived_tolerances(maps, tmp_path, caplog):
    """Ninth sweep: a map copied out of its session was searched at the configured tolerances (its noise figures
    lived only in run.json). A map file written with its figures (`sosmatch map` writes them) carries them."""
    from sosmatch.plugin.map_noise import MapNoise

    d, s = maps
    for name, pts, sizes in (("a", s.points_a, s.sizes_a), ("b", s.points_b, s.sizes_b)):
        noise = MapNoise(ground_resolution_m=0.16, residual_m=0.95, size_log_std=0.08, landmarks=len(pts))
        write_landmark_map(tmp_path / f"{name}.sosmap", LandmarkMap(pts, sizes, pts.mean(0).round(), noise=noise))
    out = tmp_path / "out"
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(out),
                 "--no-plot"]) == 0
    doc = json.loads((out / "match.json").read_text())
    assert doc["map_noise"][0]["residual_m"] == 0.95 and doc["search_mode"]["derived"]["tolerances"] != "configured"
    assert not [r for r in caplog.records if "records no noise figures" in r.getMessage()]
    assert doc["answer"] == "verified" and doc["verification"]["accepted"]


def test_a_tolerance_set_and_replaced_by_the_derived_one_is_said_and_named_by_the_refusal(maps, tmp_path,
                                                                                          cli_error):
    """rev56 D8: `--set association.distance_tolerance_m=5` was replaced by the value derived from the maps without
    a word, and into an existing match the refusal did not name the setting (match.json kept the derived value
    both times). The run warns naming the setting and the remedy; the refusal names the value set."""
    from sosmatch.plugin.map_noise import MapNoise

    d, s = maps
    for name, pts, sizes in (("a", s.points_a, s.sizes_a), ("b", s.points_b, s.sizes_b)):
        noise = MapNoise(ground_resolution_m=0.16, residual_m=0.95, size_log_std=0.08, landmarks=len(pts))
        write_landmark_map(tmp_path / f"{name}.sosmap", LandmarkMap(pts, sizes, pts.mean(0).round(), noise=noise))
    a, b, out = tmp_path / "a.sosmap", tmp_path / "b.sosmap", tmp_path / "out"
    assert main(["match", str(a), str(b), "--out", str(out), "--no-plot", "-q"]) == 0
    doc = json.loads((out / "match.json").read_text())
    derived = doc["params"]["association"]["distance_tolerance_m"]
    assert derived != 5 and not [w for w in doc["warnings"] if "derive_from_maps" in w]  # nothing set: no word
    err = cli_error("match", a, b, "--out", out, "--no-plot", "--set", "association.distance_tolerance_m=5")
    assert "association.distance_tolerance_m set to 2.0, this run's 5" in err and f"both used {derived}" in err
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "out5"), "--no-plot", "-q",
                 "--set", "association.distance_tolerance_m=5"]) == 0
    said = json.loads((tmp_path / "out5" / "match.json").read_text())["warnings"]
    assert f"association.distance_tolerance_m=5 replaced by {derived:g} derived from the maps" in " ".join(said)
    assert "set association.derive_from_maps=false to keep yours" in " ".join(said)


def test_a_refusal_of_maps_made_at_very_different_ground_resolutions_names_them(tmp_path):
    """nu57 D2: a 150 m map against a 60 m one said "no match" with no reason, though both maps record their
    ground resolution (0.59 and 0.24 m per pixel: 2.4x, far beyond the size gate) and `evaluate` names the height
    ratio. A refusal of such maps names the resolutions; maps of one resolution are refused without that line."""
    from sosmatch.plugin.map_noise import MapNoise

    rng = np.random.default_rng(5)
    for name, gsd in (("a", 0.59), ("b", 0.24), ("c", 0.59)):
        pts = rng.uniform(0.0, 300.0, (30, 3)) * [1.0, 1.0, 0.02]
        noise = MapNoise(ground_resolution_m=gsd, residual_m=0.95, size_log_std=0.08, landmarks=len(pts))
        write_landmark_map(tmp_path / f"{name}.sosmap", LandmarkMap(pts, rng.uniform(1.0, 6.0, 30), np.zeros(3),
                                                                   noise=noise))
    docs = {}
    for b in ("b", "c"):
        out = tmp_path / f"a_{b}"
        assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / f"{b}.sosmap"), "--out", str(out),
                     "--no-plot", "-q"]) == 0
        docs[b] = json.loads((out / "match.json").read_text())
        assert not (docs[b]["verification"] or {}).get("accepted")  # no match
    said = [w for w in docs["b"]["warnings"] if "m of ground per pixel" in w]
    assert len(said) == 1 and "0.59 and 0.24 m" in said[0] and "x2.5" in said[0], docs["b"]["warnings"]
    assert not [w for w in docs["c"]["warnings"] if "m of ground per pixel" in w], docs["c"]["warnings"]


def test_a_match_without_picture_leaves_no_previous_picture_beside_it(maps, tmp_path):
    d, _ = maps
    out = tmp_path / "AB"
    argv = ["match", str(d / "a.sosmap"), str(d / "session_b"), "--out", str(out)]
    assert main(argv) == 0 and (out / "match.png").is_file()
    # the picture showed the previous run's maps: what stands beside match.json always comes from the same run
    assert main([*argv, "--overwrite", "--no-plot"]) == 0  # another identity (the plot is part of it)
    assert not (out / "match.png").exists() and (out / "match.json").is_file()


def test_a_map_too_small_to_align_is_named_by_its_file(maps, tmp_path, capsys):
    """nu27: "map A has 2 landmarks; at least 3 are needed" named neither file; the error names the one that is."""
    d, _ = maps
    tiny = tmp_path / "two_trees.sosmap"
    write_landmark_map(tiny, LandmarkMap(np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]), np.ones(2)))
    assert main(["match", str(d / "a.sosmap"), str(tiny), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{tiny}: holds 2 landmark(s); at least 3 are needed" in err
    assert not (tmp_path / "o").exists()


def test_maps_too_small_for_theta_s_say_why_there_is_no_match(tmp_path, capsys):
    """nu27: two maps of 5 trees ended in a bare "verification: no match": no window can hold more than theta_S
    associations, and the line says so."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 40, (5, 3)) * [1, 1, 0.05]
    write_landmark_map(tmp_path / "a.sosmap", LandmarkMap(pts, np.full(5, 2.0)))
    write_landmark_map(tmp_path / "b.sosmap", LandmarkMap(pts + [3.0, 1.0, 0.0], np.full(5, 2.0)))
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "o"),
                 "--no-plot"]) == 0
    out = capsys.readouterr().out
    assert "verification: no match (no candidate: no window hypothesis holds more than theta_S = 6 associations)" in out



def test_maps_whose_sizes_are_defined_differently_are_matched_with_a_warning(toy_sessions, tmp_path):
    """Sweep nu39: a map made with the paper's size estimator ("mean") reads 0.94 of a default ("nadir") map's
    sizes on common landmarks (0.81 on conifers), against a 20 % size gate, and `match` said nothing. Both maps'
    run.json record their settings: when the size-defining ones differ, match.json says so."""
    import shutil

    def session(name: str, estimator: str) -> Path:
        copy = tmp_path / name
        shutil.copytree((toy_sessions.a if name.startswith("a") else toy_sessions.b).path, copy)
        (copy / "run.json").write_text(json.dumps({"params": {"triangulation": {"size_estimator": estimator},
                                                              "segmentation": {"backend": "classical"}}}))
        return copy

    said = {}
    for case, b_estimator in (("same", "nadir"), ("other", "mean")):
        out = tmp_path / case
        assert main(["match", str(session(f"a_{case}", "nadir")), str(session(f"b_{case}", b_estimator)),
                     "--out", str(out), "--no-plot"]) == 0
        said[case] = [w for w in json.loads((out / "match.json").read_text())["warnings"]
                      if "define landmark sizes differently" in w]
    assert said["same"] == []
    assert len(said["other"]) == 1 and "'nadir' in A, 'mean' in B" in said["other"][0]
