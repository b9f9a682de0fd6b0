"""End to end: two planar sessions rendered from one orthophoto, perfect-but-noisy landmark maps, the
evaluate workflow and CLI (ground truth, in-process search, claims, both baselines, table, plots)."""

import json

import cv2
import numpy as np
import pytest

from sosmatch.database.cameras import write_cameras_txt
from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.database.poses import write_poses_csv
from sosmatch.plugin.geometry import Camera, Poses, project
from sosmatch.plugin.params import Params
from sosmatch.tools.cli import main
from sosmatch.workflows.evaluate import run

CAM = Camera(200, 150, 110.0, 110.0, 100.0, 75.0)
ORTHO_RES = 0.5  # m per ortho pixel; ortho pixel (col, row) is world (col * res, row * res)


def _ortho(seed=7, size=700):
    rng = np.random.default_rng(seed)
    img = np.full((size, size, 3), 90, np.uint8)
    for _ in range(2500):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        color = tuple(int(v) for v in rng.integers(0, 255, 3))
        if rng.random() < 0.5:
            cv2.circle(img, c, int(rng.integers(2, 9)), color, -1)
        else:
            cv2.rectangle(img, c, tuple(int(v) for v in np.array(c) + rng.integers(-12, 12, 2)), color, -1)
    return img


def _session(root, name, ortho, xs, y, reverse, landmarks, sizes, seed):
    d = root / name
    (d / "images").mkdir(parents=True)
    rot = np.diag([-1.0, 1.0, -1.0]) if reverse else np.diag([1.0, -1.0, -1.0])
    xs = xs[::-1] if reverse else xs
    names = [f"frame_{i:05d}.jpg" for i in range(len(xs))]
    centers = np.stack([xs, np.full(len(xs), y), np.full(len(xs), 60.0)], 1)
    poses = Poses(names, np.repeat(rot[None], len(xs), 0), centers)
    write_poses_csv(d / "poses.csv", poses)
    write_cameras_txt(d / "cameras.txt", {1: CAM})
    world_from_ortho = np.array([[ORTHO_RES, 0, 0], [0, ORTHO_RES, 0], [0, 0, 1.0]])
    r_cw, t_cw = poses.cam_from_world()
    seen = []
    for k, n in enumerate(names):
        h = CAM.K @ np.column_stack([r_cw[k][:, 0], r_cw[k][:, 1], t_cw[k]]) @ world_from_ortho
        cv2.imwrite(str(d / "images" / n), cv2.warpPerspective(ortho, h, (CAM.width, CAM.height)))
        uv, depth = project(CAM, rot, centers[k], landmarks)
        seen.append((uv[:, 0] > 5) & (uv[:, 0] < CAM.width - 5) & (uv[:, 1] > 5) & (uv[:, 1] < CAM.height - 5))
    seen = np.array(seen)  # (frames, landmarks)
    keep = np.flatnonzero(seen.sum(0) >= 6)
    keep = keep[np.argsort(seen[:, keep].argmax(0), kind="stable")]  # by first sighting, like track ids
    rng = np.random.default_rng(seed)
    pos = landmarks[keep] + rng.normal(0, 0.15, (len(keep), 3))
    size = sizes[keep] * (1 + rng.normal(0, 0.03, len(keep)))
    write_landmark_map(d / "landmarks.sosmap", LandmarkMap(pos, size))
    lines = ["index,point3d_id,x,y,z,size_m,num_observations,image_names"]
    for i, lm in enumerate(keep):
        obs = [names[f] for f in np.flatnonzero(seen[:, lm])]
        lines.append(f"{i},{i + 1},{pos[i, 0]},{pos[i, 1]},{pos[i, 2]},{size[i]},{len(obs)},{' '.join(obs)}")
    (d / "landmarks.csv").write_text("\n".join(lines) + "\n")
    return d


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    rng = np.random.default_rng(0)
    ortho = _ortho()
    landmarks = np.column_stack([rng.uniform(20, 330, 120), rng.uniform(60, 200, 120), np.zeros(120)])
    sizes = rng.uniform(1.0, 6.0, 120)
    xs = np.arange(60.0, 290.0, 11.0)
    a = _session(root, "A", ortho, xs, 120.0, False, landmarks, sizes, 1)
    b = _session(root, "B", ortho, xs + 3.0, 135.0, True, landmarks, sizes, 2)  # shifted and reversed
    ev = run(Params(), a, b, root / "out", case="planar", repeats=1)
    return root, a, b, ev


def test_workflow_writes_table_plots_and_sane_scores(sessions):
    root, a, b, ev = sessions
    out = root / "out"
    for f in ("evaluation.md", "evaluation.json", "pr.png", "overlay.png"):
        assert (out / f).stat().st_size > 0
    rows = {r["method"]: r for r in ev["rows"]}
    assert set(rows) == {"SOS-Match (ours)", "SOS-Match, windows only", "ORB+RANSAC", "SIFT+RANSAC"}
    assert ev["protocol"]["positive_pairs"] > 30 and ev["protocol"]["negative_pairs"] > 30
    ours = ev["methods"]["sosmatch"]
    assert ours["accepted_hypotheses"] >= 1
    # Correct landmark associations: the claimed pairs really overlap, so precision is high and recall real.
    assert rows["SOS-Match (ours)"]["recall_reached"] > 0.5
    assert rows["SOS-Match (ours)"]["average_f1"] > 0.4
    # Same day, textured, planar: the feature baselines match too.
    assert rows["ORB+RANSAC"]["recall_reached"] > 0.3
    assert rows["SOS-Match (ours)"]["map_mb"] < rows["ORB+RANSAC"]["map_mb"] / 20
    # the operating point (theta_S as configured) sits on the curve, and the accepted hypotheses are right
    ours_row = rows["SOS-Match (ours)"]
    assert 0 < ours_row["recall_at_operating"] <= ours_row["recall_reached"]
    assert ours_row["precision_at_operating"] >= 0.99 and ours_row["operating_theta_S"] == 6
    assert ours_row["accepted_max_error_m"] < 1.0
    assert ours["landmark_truth"] is None  # no object ground truth in these sessions: nothing to count
    # the full-map verification finds the true alignment and vouches for at least what the windows do
    ver = ours["verification"]
    assert ver["accepted"] and ver["error_m"] < 1.0 and ver["support"] > 6
    assert ours_row["recall_at_operating"] >= rows["SOS-Match, windows only"]["recall_at_operating"]
    data = json.loads((out / "evaluation.json").read_text())
    assert data["rows"] == json.loads(json.dumps(ev["rows"]))
    assert "| planar | SOS-Match (ours) |" in (out / "evaluation.md").read_text()
    # the search time leaves out the kernel compile, which is recorded apart, and the table says so (nu54 M1)
    assert ours["kernel_compile_seconds"] >= 0 and "without the one-off compile" in (out / "evaluation.md").read_text()


def test_workflow_is_deterministic_and_cli_reports_user_errors(sessions, capsys):
    root, a, b, ev = sessions
    again = run(Params(), a, b, root / "d1", methods=["sosmatch", "orb_ransac"], repeats=1)
    for m in ("sosmatch", "orb_ransac"):
        assert again["methods"][m]["curve"] == ev["methods"][m]["curve"]
    code = main(["evaluate", str(a), str(root / "nowhere"), "--out", str(root / "d3"), "--methods", "sosmatch"])
    assert code == 2 and "pose file not found" in capsys.readouterr().err
    code = main(["evaluate", str(a), str(b), "--out", str(root / "d4"), "--methods", "sosmatch", "--repeats", "1",
                 "--max-observers", "3"])
    assert code == 0 and "SOS-Match (ours)" in capsys.readouterr().out


def test_maps_or_match_of_the_other_session_are_refused(sessions, tmp_path, capsys):
    """Issue 14: evaluate with the maps given in swapped order, or with a match of the maps in the other order,
    is a one-line error, not a silently wrong table (both sessions have the same image names)."""
    import hashlib
    import shutil

    from sosmatch.workflows import match as match_workflow

    root, a0, b0, _ = sessions
    a, b = tmp_path / "A", tmp_path / "B"
    for src, dst in ((a0, a), (b0, b)):
        shutil.copytree(src, dst)
        digests = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((dst / "images").iterdir())}
        (dst / "run.json").write_text(json.dumps({"keyframe_images": digests}))  # as `sosmatch map` records it
    args = ["evaluate", str(a), str(b), "--methods", "sosmatch"]
    assert main([*args, "--repeats", "1", "--map-a", str(b), "--map-b", str(a), "--out", str(tmp_path / "e1")]) == 2
    err = capsys.readouterr().err
    assert "other images" in err and len(err.strip().splitlines()) == 1 and not (tmp_path / "e1").exists()
    match_workflow.run(Params(), b, a, tmp_path / "ba", workers=1, plot=False)  # B first
    assert main([*args, "--match", str(tmp_path / "ba"), "--out", str(tmp_path / "e2")]) == 2  # (no --repeats)
    assert "in the other order" in capsys.readouterr().err


def test_sessions_of_two_worlds_are_refused(sessions, tmp_path, cli_error):
    """New-user sweep: two `sosmatch synth` sessions of different world seeds share coordinates but no ground, so
    their footprints 'overlap' by coordinates alone; evaluate scored such a pair (exit 0, a table of nonsense)."""
    import shutil

    root, a0, b0, _ = sessions
    a, b = tmp_path / "A", tmp_path / "B"
    for src, dst, seed in ((a0, a, 61), (b0, b, 77)):
        shutil.copytree(src, dst)
        config = {"world_seed": seed, "world_size_m": 600.0, "world_resolution_m": 0.15}
        (dst / "session.json").write_text(json.dumps({"format": "sosmatch-synth-session", "version": 1,
                                                      "config": config}))
    args = ["evaluate", a, b, "--methods", "sosmatch", "--repeats", "1"]
    err = cli_error(*args, "--out", tmp_path / "e1")
    assert "B/session.json" in err and "world seed 77" in err and not (tmp_path / "e1").exists()
    (b / "session.json").write_text((a / "session.json").read_text())  # one world: scored as before
    assert main([str(x) for x in (*args, "--out", tmp_path / "e2")]) == 0


def test_a_synth_session_missing_its_object_truth_is_refused(sessions, tmp_path, cli_error):
    """rev55 D2: a `sosmatch synth` session (session.json says so) without objects.csv was scored with its object
    columns silently '-', as if it had no object truth; `synth` always writes it, so the session is incomplete.
    The fixture's sessions (no session.json: real flights) are scored without object truth as before."""
    import shutil

    root, a0, b0, _ = sessions
    a, b = tmp_path / "A", tmp_path / "B"
    config = {"world_seed": 61, "world_size_m": 600.0, "world_resolution_m": 0.15}
    for src, dst in ((a0, a), (b0, b)):
        shutil.copytree(src, dst)
        (dst / "session.json").write_text(json.dumps({"format": "sosmatch-synth-session", "version": 1,
                                                      "generator": "sosmatch 0.1.0", "config": config}))
    err = cli_error("evaluate", a, b, "--methods", "sosmatch", "--repeats", "1", "--out", tmp_path / "e")
    assert "A/objects.csv: file not found" in err and "sosmatch synth" in err and not (tmp_path / "e").exists()


def test_a_pair_without_positive_keyframe_pairs_is_refused(sessions, tmp_path, cli_error):
    """New-user sweep: flights at 80 m and 150 m have no keyframe pair of IoU > 1/3 (IoU is at most the ratio of
    the footprints' areas), so recall and F1 are undefined; evaluate reported 0.000 with exit 0 for a right
    alignment. B flown 3.5x higher here."""
    import shutil

    from sosmatch.database.poses import read_poses_csv

    root, a, b0, _ = sessions
    b = tmp_path / "B"
    shutil.copytree(b0, b)
    poses, _ = read_poses_csv(b / "poses.csv")
    poses.centers[:, 2] *= 3.5
    write_poses_csv(b / "poses.csv", poses)
    err = cli_error("evaluate", a, b, "--methods", "sosmatch", "--repeats", "1", "--out", tmp_path / "e")
    assert "IoU > 0.333" in err and "largest 0.0" in err and not (tmp_path / "e").exists()
    assert "mostly by the heights" in err and "IoU cannot exceed 0.0" in err


def test_a_pair_of_other_lenses_is_refused_for_its_fields_of_view(sessions, tmp_path, cli_error):
    """The twenty-sixth sweep: a wide-angle flight (84 deg across, 80 m) against a zoom (30 deg, 120 m) was refused
    as flights that "differ this much in height"; the footprints' areas differ by the lenses, and the refusal says
    so with both figures. B here has A's heights and a 3.5x longer lens."""
    import shutil

    root, a, b0, _ = sessions
    b = tmp_path / "B"
    shutil.copytree(b0, b)
    write_cameras_txt(b / "cameras.txt", {1: Camera(200, 150, 3.5 * CAM.fx, 3.5 * CAM.fy, CAM.cx, CAM.cy)})
    err = cli_error("evaluate", a, b, "--methods", "sosmatch", "--repeats", "1", "--out", tmp_path / "e")
    assert "IoU > 0.333" in err and "mostly by the fields of view (85 and 29 deg across" in err
    assert "differ this much in height" not in err and not (tmp_path / "e").exists()


def test_flights_that_do_not_overlap_are_told_so(sessions, tmp_path, cli_error):
    """Footprints of one size far apart: not their sizes, their places."""
    import shutil

    from sosmatch.database.poses import read_poses_csv

    root, a, b0, _ = sessions
    b = tmp_path / "B"
    shutil.copytree(b0, b)
    poses, _ = read_poses_csv(b / "poses.csv")
    poses.centers[:, 1] += 2000.0
    write_poses_csv(b / "poses.csv", poses)
    err = cli_error("evaluate", a, b, "--methods", "sosmatch", "--repeats", "1", "--out", tmp_path / "e")
    assert "largest 0.00" in err and "the flights do not overlap enough" in err and not (tmp_path / "e").exists()


def test_a_refused_verification_claims_nothing(sessions, tmp_path):
    """When the verification refuses (here forced: a rival ratio no alignment reaches), `sosmatch match` answers
    "no match", so the matcher's row claims nothing and accepts no hypothesis; the window hypotheses stay in the
    windows-only row (the paper's protocol). Before, the matcher's row silently became the windows-only row: world
    97's crossing flight read recall 0.454 and a worst accepted hypothesis 21 m off for a refused match."""
    import dataclasses

    _, a, b, _ = sessions
    p = Params()
    strict = dataclasses.replace(p, verification=dataclasses.replace(p.verification, min_ratio=1000.0))
    ev = run(strict, a, b, tmp_path / "out", case="refused", repeats=1, methods=["sosmatch"])
    rows = {r["method"]: r for r in ev["rows"]}
    ours, windows = rows["SOS-Match (ours)"], rows["SOS-Match, windows only"]
    assert not ev["methods"]["sosmatch"]["verification"]["clear_winner"]
    assert ours["recall_reached"] == 0.0 and ours["recall_at_p99"] == 0.0 and ours["accepted_max_error_m"] is None
    assert ev["methods"]["sosmatch"]["claimed_pairs"] == 0
    assert windows["recall_reached"] > 0.5 and windows["accepted_max_error_m"] is not None


def test_a_map_georeferenced_in_the_sessions_crs_is_scored_in_the_world_frame(sessions, tmp_path):
    """Fourth sweep (multi-session): a map built from a synthetic session's DJI / EXIF geotags lives in UTM (the
    world shifted by session.json's world_to_crs_offset). Evaluated against a local map of another session, its
    right alignment was scored 5.2e6 m off with recall 0 and exit 0 (world 131); the offset is now taken off."""
    import shutil

    from sosmatch.database.landmark_map import read_landmark_map
    from sosmatch.plugin.errors import InputError

    root, a, b, ev = sessions
    offset = np.array([423675.0, 5205349.0, 420.0])
    world = {"world_seed": 1, "world_size_m": 600.0, "world_resolution_m": 0.15}
    for src, geo in ((a, None), (b, {"epsg": 32632, "world_to_crs_offset": offset.tolist()})):
        dst = tmp_path / src.name
        shutil.copytree(src, dst)
        meta = {"format": "sosmatch-synth-session", "version": 1, "config": world}
        if geo:
            meta["geo"] = geo
            lm = read_landmark_map(src / "landmarks.sosmap")
            write_landmark_map(dst / "landmarks.sosmap", LandmarkMap(lm.positions + offset, lm.sizes, offset, 32632))
            lines = (src / "landmarks.csv").read_text().splitlines()
            out = [lines[0]]
            for line in lines[1:]:
                f = line.split(",")
                f[2:5] = [repr(float(v) + float(o)) for v, o in zip(f[2:5], offset)]
                out.append(",".join(f))
            (dst / "landmarks.csv").write_text("\n".join(out) + "\n")
        (dst / "session.json").write_text(json.dumps(meta))
    geo = run(Params(), tmp_path / "A", tmp_path / "B", tmp_path / "out", case="geo", repeats=1, methods=["sosmatch"])
    plain = {r["method"]: r for r in ev["rows"]}["SOS-Match (ours)"]
    row = {r["method"]: r for r in geo["rows"]}["SOS-Match (ours)"]
    ver = geo["methods"]["sosmatch"]["verification"]
    assert ver["accepted"] and ver["error_m"] < 1.0
    assert row["recall_reached"] == pytest.approx(plain["recall_reached"], abs=0.05)
    assert row["average_f1"] == pytest.approx(plain["average_f1"], abs=0.05)
    # a map in another CRS than the session's truth cannot be related to it: one line naming the map
    (tmp_path / "B" / "session.json").write_text(json.dumps({"format": "sosmatch-synth-session", "version": 1,
                                                             "config": world}))
    with pytest.raises(InputError, match="EPSG:32632 but the ground truth"):
        run(Params(), tmp_path / "A", tmp_path / "B", tmp_path / "out2", case="geo", repeats=1, methods=["sosmatch"])


def test_the_map_s_own_poses_do_not_depend_on_the_folder_evaluate_runs_in(sessions, tmp_path, monkeypatch):
    """run.json names the pose file a map was built on; `evaluate` scores the map at those poses (a synthetic
    session's EKF poses). Before: map recorded the path as given (relative to the folder it ran in), so evaluate
    run from another folder found no file there and silently used the true poses (the sweep's evaluation changed
    from 234 to 235 claimed pairs with the cwd), or read another file of that relative name. Now map records
    absolute paths, and a relative one of an older map is looked up in the evaluated session."""
    from sosmatch.database.poses import read_poses_csv
    from sosmatch.plugin.multisession import Sim3
    from sosmatch.workflows.evaluate.ground_truth import _map_frame_centers, load_ground_truth
    from sosmatch.workflows.map.inputs import recorded_sources

    root, a, _, _ = sessions
    session = tmp_path / "S"
    session.mkdir()
    for f in ("poses.csv", "cameras.txt"):
        (session / f).write_bytes((a / f).read_bytes())
    (session / "images").symlink_to(a / "images")
    poses = read_poses_csv(a / "poses.csv")[0]
    ekf = Poses(poses.names, poses.rotations, poses.centers + [1.5, -0.5, 0.2])  # the map's own (EKF) poses
    write_poses_csv(session / "poses_ekf.csv", ekf)
    monkeypatch.chdir(tmp_path)
    recorded = recorded_sources({"poses": "S/poses_ekf.csv", "images": "S/images", "camera": "EXIF/XMP of 3 images"})
    assert recorded == {"poses": str(session / "poses_ekf.csv"), "images": str(session / "images"),
                        "camera": "EXIF/XMP of 3 images"}
    gt = load_ground_truth(Params(), session)
    for inputs in (recorded, {"poses": "S/poses_ekf.csv"}):  # a map of this sosmatch, one of an older one
        mapped = tmp_path / "M"
        mapped.mkdir(exist_ok=True)
        (mapped / "run.json").write_text(json.dumps({"inputs": inputs}))
        for cwd in (tmp_path, root, session):
            monkeypatch.chdir(cwd)
            centers = _map_frame_centers(gt, mapped, Sim3.identity())
            assert np.allclose(centers - gt.centers, [1.5, -0.5, 0.2]), (inputs, cwd)


@pytest.mark.parametrize("flags, fragment", [
    (["--max-observers", "0"], "--max-observers must be at least 1"),  # was: F1 0.000, 'front end', exit 0
    (["--max-observers", "-2"], "--max-observers must be at least 1"),  # was: observers sliced off, exit 0
    (["--ground-height", "nan"], "--ground-height must be a finite height"),
    (["--sweep-floor", "-1"], "--sweep-floor must be at least 2"),
    (["--repeats", "0"], "--repeats must be at least 1"),
    (["--baseline-threads", "-1"], "--baseline-threads must be 0"),
])
def test_evaluate_options_that_make_no_evaluation_are_one_line(sessions, tmp_path, cli_error, flags, fragment):
    _, a, b, _ = sessions
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--methods", "sosmatch", *flags)
    assert fragment in err and not (tmp_path / "E").exists()


def test_a_sweep_floor_that_would_change_nothing_is_refused(sessions, tmp_path, cli_error):
    """nu45: `--sweep-floor 100` (above the pair's theta_S, 6 here) was ignored silently, exit 0; so was any floor
    with `--match` (the file's hypotheses are scored) or without the sosmatch method. Each is refused, nothing
    written; a floor below theta_S extends the curve."""
    _, a, b, _ = sessions
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--methods", "sosmatch", "--repeats", "1",
                    "--sweep-floor", "7")
    assert "--sweep-floor 7 is above this pair's theta_S (6" in err and not (tmp_path / "E").exists()
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--methods", "orb_ransac", "--sweep-floor", "3")
    assert "give --methods sosmatch" in err and not (tmp_path / "E").exists()
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--match", tmp_path / "m", "--sweep-floor", "3")
    assert "a --match file is scored with the hypotheses its search kept" in err and not (tmp_path / "E").exists()
    ev = run(Params(), a, b, tmp_path / "F", methods=["sosmatch"], repeats=1, sweep_floor=6)  # at theta_S: as none
    assert ev["methods"]["sosmatch"]["curve_floor_theta_S"] == 6


def test_a_sweep_floor_on_a_map_too_small_to_search_is_refused(sessions, tmp_path, cli_error):
    """fix81 left: with a map of fewer than 3 landmarks no search runs (the method claims nothing), and
    `--sweep-floor 3` was ignored silently, exit 0. Refused before any work, naming the map; without the floor the
    pair is still evaluated (an honest zero)."""
    import shutil

    from sosmatch.database.landmark_map import read_landmark_map

    _, a, b0, _ = sessions
    b = tmp_path / "B"
    shutil.copytree(b0, b)
    lmap = read_landmark_map(b / "landmarks.sosmap")
    write_landmark_map(b / "landmarks.sosmap", LandmarkMap(lmap.positions[:2], lmap.sizes[:2]))
    lines = (b / "landmarks.csv").read_text().splitlines()
    (b / "landmarks.csv").write_text("\n".join(lines[:3]) + "\n")
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--methods", "sosmatch", "--sweep-floor", "3")
    assert f"{b}: --sweep-floor 3: this map has 2 landmark(s), fewer than the 3 a transform needs" in err
    assert not (tmp_path / "E").exists()
    ev = run(Params(), a, b, tmp_path / "F", methods=["sosmatch"], repeats=1)
    n_a = len(read_landmark_map(a / "landmarks.sosmap"))
    assert ev["methods"]["sosmatch"]["note"] == f"maps have {n_a} and 2 landmarks" and ev["rows"]


def test_repeats_where_no_search_of_evaluate_runs_are_refused(sessions, tmp_path, cli_error, capsys):
    """fix81 left: `--repeats 5 --match M` timed nothing (the file's search time was reported), exit 0; so did
    --repeats without the sosmatch method. Refused like --sweep-floor there, nothing written; the default (no
    --repeats given) is not, and is the 3 repeats of before where the search runs."""
    _, a, b, _ = sessions
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--match", tmp_path / "m", "--repeats", "5")
    assert "--repeats times evaluate's own sosmatch search: a --match file is scored with the search time it " \
           "records" in err and not (tmp_path / "E").exists()
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--methods", "orb_ransac", "--repeats", "3")
    assert "give --methods sosmatch (or leave --repeats out)" in err and not (tmp_path / "E").exists()
    err = cli_error("evaluate", a, b, "--out", tmp_path / "E", "--match", tmp_path / "m")  # not given: not refused
    assert "--repeats" not in err and not (tmp_path / "E").exists()
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    from sosmatch.workflows.evaluate.workflow import DEFAULT_REPEATS

    assert f"default {DEFAULT_REPEATS};" in " ".join(capsys.readouterr().out.split())


def test_an_overwrite_refused_after_the_search_leaves_the_earlier_evaluation_as_it_was(sessions, tmp_path,
                                                                                        cli_error):
    """rev31 F3: `evaluate --overwrite --sweep-floor 7` (above the pair's theta_S, 6, known after the search) was
    refused with the earlier evaluation's files unchanged but its marker re-written incomplete: readers took the
    complete evaluation for an unfinished one. Now the folder is exactly as it was, the evaluation complete."""
    from sosmatch.database.output_markers import check_finished

    _, a, b, _ = sessions
    out = tmp_path / "E"
    run(Params(), a, b, out, methods=["sosmatch"], repeats=1)
    before = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    err = cli_error("evaluate", a, b, "--out", out, "--methods", "sosmatch", "--repeats", "2", "--sweep-floor", "7",
                    "--overwrite")
    assert "--sweep-floor 7 is above this pair's theta_S (6" in err
    assert {p.name: p.read_bytes() for p in sorted(out.iterdir())} == before
    check_finished(out)  # complete: readable as the earlier evaluation


def test_a_session_against_itself_or_a_refused_map_is_refused(sessions, tmp_path, cli_error):
    """The eighth new-user sweep: `evaluate S1 S1` (and S1 against a byte copy) scored average F1 1.000, and a map
    that `sosmatch map` refused was scored F1 0 "limited by the front end"; match refuses both."""
    import shutil

    root, a, b, _ = sessions
    err = cli_error("evaluate", a, a, "--out", tmp_path / "e1")
    assert "A and B are the same session" in err and not (tmp_path / "e1").exists()
    copy = tmp_path / "A_copy"
    shutil.copytree(a, copy)
    err = cli_error("evaluate", a, copy, "--methods", "sosmatch", "--out", tmp_path / "e2")
    assert "holds the same landmark map as" in err and not (tmp_path / "e2").exists()
    refused = tmp_path / "B_refused"
    shutil.copytree(b, refused)
    (refused / "run.json").write_text(json.dumps({"verdict": {"status": "refused", "refusals": ["no landmarks"]}}))
    err = cli_error("evaluate", a, refused, "--methods", "sosmatch", "--out", tmp_path / "e3")
    assert "`sosmatch map` refused this session" in err and not (tmp_path / "e3").exists()


def test_an_evaluation_in_a_project_moved_whole_is_the_same_evaluation(sessions, tmp_path, run_moved):
    """nu37 D1: `mv project project.moved` and the same `evaluate` again inside it was refused as "made from other
    inputs" (its identity held the inputs' real paths); the inputs are named by their content now."""
    import shutil

    root, a, b, _ = sessions
    project = tmp_path / "project"
    for s in (a, b):
        shutil.copytree(s, project / s.name)
    run_moved(project, tmp_path / "moved",
              ["evaluate", a.name, b.name, "--out", "ev", "--methods", "sosmatch", "--repeats", "1"])


def test_no_method_is_a_user_error(tmp_path, cli_error):
    """nu45: `evaluate --methods ''` evaluated nothing, wrote an evaluation without a row and exited 0."""
    err = cli_error("evaluate", tmp_path / "A", tmp_path / "B", "--out", tmp_path / "eval", "--methods", "")
    assert "no method to evaluate" in err and list(tmp_path.iterdir()) == []


def test_evaluate_searches_an_sfm_posed_map_as_match_does(sessions, tmp_path):
    """rev51 D3: a map whose poses came from structure from motion is searched with the similarity `sosmatch
    match` chooses for it (one `plan_search` / `answer_plan`), and a transform the user chose is kept, as in match;
    before, evaluate scored the rigid search whatever match would answer."""
    import shutil

    from sosmatch.database.landmark_map import read_landmark_map
    from sosmatch.workflows import match

    _, a, b, _ = sessions
    b_sfm = tmp_path / "B"
    shutil.copytree(b, b_sfm)
    lmap = read_landmark_map(b_sfm / "landmarks.sosmap")
    lmap.sfm_poses = True
    write_landmark_map(b_sfm / "landmarks.sosmap", lmap)
    ev = run(Params(), a, b_sfm, tmp_path / "ev", case="sfm", repeats=1, methods=["sosmatch"])
    ours = ev["methods"]["sosmatch"]
    matched = json.loads((match.run(Params(), a, b_sfm, tmp_path / "m", plot=False).out_dir / "match.json")
                         .read_text())
    assert ours["association"]["transform"] == "similarity" == matched["transform_kind"]
    assert ours["transform_from_poses"] == matched["search_mode"]["transform_from_poses"]
    assert ours["verification"]["accepted"] and ours["verification"]["support"] == matched["verification"]["support"]
    chosen = run(Params(), a, b_sfm, tmp_path / "ev_rigid", case="sfm", repeats=1, methods=["sosmatch"],
                 transform_chosen=True)["methods"]["sosmatch"]
    assert chosen["association"]["transform"] == "rigid" and "transform_from_poses" not in chosen
