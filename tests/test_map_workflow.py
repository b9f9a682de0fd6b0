"""`sosmatch map` end to end on a tiny rendered session: outputs, accuracy, resume, and bad input via the CLI."""

import json
import os
import shutil
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.cameras import read_cameras_txt, write_cameras_txt
from sosmatch.database.landmark_map import read_landmark_map
from sosmatch.database.poses import write_poses_csv
from sosmatch.database.session_io import read_session
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, Poses
from sosmatch.plugin.params import Params, with_overrides
from sosmatch.tools.cli import main
from sosmatch.workflows import map as map_workflow

pycolmap = pytest.importorskip("pycolmap")
# the last: the output marker (sosmatch.database.outputs)
OUTPUT_NAMES = {"database.db", "sparse", "landmarks.sosmap", "landmarks.ply", "landmarks.csv", "quality.png",
                "pose_check.json", "run.json", ".sosmatch-output.json"}


def render_session(root: Path, n_frames=25, width=320, height=240, altitude=60.0, n_objects=40, seed=0):
    """Nadir flight (2 m steps along x) over a flat textured field with coloured discs: images/, poses.csv,
    cameras.txt. Returns the camera, poses and objects (x, y, radius) on the ground plane z = 0."""
    rng = np.random.default_rng(seed)
    cam = Camera(width, height, 0.8 * width, 0.8 * width, width / 2, height / 2)
    gsd, x0, x1, y0, y1 = 0.1, -40.0, n_frames * 2.0 + 40.0, -35.0, 35.0
    w, h = int((x1 - x0) / gsd), int((y1 - y0) / gsd)
    noise = cv2.GaussianBlur(rng.normal(0, 25, (h, w, 3)), (0, 0), 2)
    ortho = np.clip(rng.integers(70, 110, 3) + noise, 0, 255).astype(np.uint8)
    objs = np.stack([rng.uniform(x0 + 10, x1 - 10, n_objects), rng.uniform(y0 + 8, y1 - 8, n_objects),
                     rng.uniform(1.5, 4.0, n_objects)], 1)
    for x, y, r in objs:
        color = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(ortho, (int((x - x0) / gsd), int((y1 - y) / gsd)), int(r / gsd), color, -1, cv2.LINE_AA)
    centers = np.stack([np.arange(n_frames) * 2.0, np.zeros(n_frames), np.full(n_frames, altitude)], 1)
    names = [f"frame_{i:05d}.jpg" for i in range(n_frames)]
    (root / "images").mkdir(parents=True)
    s = altitude / cam.fx / gsd  # ortho pixels per image pixel
    for name, c in zip(names, centers):
        # image pixel index i (centre at COLMAP u = i + 0.5) -> ground -> ortho pixel index
        a = np.array([[s, 0, (c[0] - x0) / gsd - 0.5 + s * (0.5 - cam.cx)],
                      [0, s, (y1 - c[1]) / gsd - 0.5 + s * (0.5 - cam.cy)]])
        img = cv2.warpAffine(ortho, a, (width, height), flags=cv2.WARP_INVERSE_MAP | cv2.INTER_AREA)
        cv2.imwrite(str(root / "images" / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    poses = Poses(names, np.repeat(np.diag([1.0, -1.0, -1.0])[None], n_frames, 0), centers)
    write_poses_csv(root / "poses.csv", poses)
    write_cameras_txt(root / "cameras.txt", {1: cam})
    return cam, poses, objs


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic")
    cam, poses, objs = render_session(root)
    out = root / "mapped"
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    summary = map_workflow.run(Params(), inputs, out, progress=False)
    return root, objs, out, summary


def test_the_map_measures_its_ground_resolution_and_segments_by_it(session):
    """The pose check's flying height over the focal length is the images' ground resolution (run.json); the
    classical backend's working size is the one `for_ground_resolution` gives for it."""
    from sosmatch.plugin.params import for_ground_resolution

    root, _, out, _ = session
    record = json.loads((out / "run.json").read_text())
    camera = read_cameras_txt(root / "cameras.txt")[1]
    true_gsd = 60.0 / camera.fx  # render_session: flat ground 60 m below every camera
    assert abs(record["ground_resolution_m"] / true_gsd - 1) < 0.03
    seg = record["params"]["segmentation"]
    expected = for_ground_resolution(Params(), record["ground_resolution_m"], camera.width, camera.height)
    # 320 px images at 0.23 m/px: segmented whole, already finer than the target
    assert seg["classical_max_side"] == expected.segmentation.classical_max_side == 400


def test_the_map_records_its_images_jpeg_quality_and_says_nothing_of_a_mild_one(session):
    """run.json keeps the flight's JPEG quality from its files' tables (render_session writes quality 95); a
    flight compressed that little is no cause of anything."""
    _, _, out, summary = session
    record = json.loads((out / "run.json").read_text())
    assert record["quality"]["images"]["jpeg"] == {"quality": 95.0, "lowest": 95, "samples": 12, "jpeg": 12}
    assert not any("compressed" in w for w in summary.verdict.warnings)


def test_a_folder_holding_another_sessions_landmark_map_is_refused(session, tmp_path, capsys):
    """run.json records the fingerprint of the landmarks.sosmap it was written with: a folder whose map was
    replaced by another session's (its model and database are this one's) is refused by every reader."""
    from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map

    _, _, out, _ = session
    assert read_session(out).landmarks is not None  # its own map passes
    mixed = tmp_path / "mixed"
    shutil.copytree(out, mixed)
    own = read_landmark_map(out / "landmarks.sosmap")
    other = LandmarkMap(own.positions + np.array([5.0, 0.0, 0.0]), own.sizes, own.origin, own.epsg)
    write_landmark_map(mixed / "landmarks.sosmap", other)
    with pytest.raises(InputError, match="not the landmark map this session's run.json was written with"):
        read_session(mixed)
    assert main(["export", str(mixed), "--csv", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(mixed / "landmarks.sosmap") in err
    assert not (tmp_path / "x.csv").exists()
    assert main(["match", str(mixed), str(out), "--out", str(tmp_path / "m")]) == 2
    assert "two sessions" in capsys.readouterr().err and not (tmp_path / "m").exists()


def test_a_folder_holding_another_sessions_model_or_database_is_refused(session, tmp_path):
    """The nineteenth sweep: another session's sparse/ (or database.db) beside this one's map passed every check
    when the sessions share image names; `merge` fused 11 landmarks instead of 98 and `changes` read the other
    session's segments, exit 0. sparse/ must hold the landmarks where they are; database.db the keypoints that
    are the model's 2D points."""
    import pycolmap

    from sosmatch.database.session_io import read_session_observations

    _, _, out, _ = session
    assert len(read_session_observations(out).segments) > 0  # its own files pass
    model = tmp_path / "model"
    shutil.copytree(out, model)
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    for point in rec.points3D.values():
        point.xyz = point.xyz + np.array([0.0, 0.0, 0.5])
    rec.write(str(model / "sparse"))
    with pytest.raises(InputError, match="not the session's landmarks") as err:
        read_session(model)
    assert str(model / "sparse") in str(err.value)

    database = tmp_path / "database"
    shutil.copytree(out, database)
    with sqlite3.connect(database / "database.db") as con:
        image_id, rows, cols, blob = con.execute("SELECT k.image_id, k.rows, k.cols, k.data FROM keypoints k "
                                                 "WHERE k.rows > 0 ORDER BY k.image_id LIMIT 1").fetchone()
        kp = np.frombuffer(blob, "<f4").reshape(rows, cols).copy()
        kp[:, :2] += 3.0  # another session's segments in the same image
        con.execute("UPDATE keypoints SET data = ? WHERE image_id = ?", (kp.tobytes(), image_id))
    with pytest.raises(InputError, match="are not the 2D points of") as err:
        read_session_observations(database)
    assert str(database / "database.db") in str(err.value)


def test_a_mapped_session_without_its_landmark_map_is_not_matched_from_sparse(session, tmp_path):
    """The nineteenth sweep: with landmarks.sosmap deleted, `match` read the session's sparse/ points instead
    (without the map's noise figures or checks, exit 0) while every other command refused the folder."""
    from sosmatch.database.map_loading import load_map

    _, _, out, _ = session
    bare = tmp_path / "bare"
    shutil.copytree(out, bare)
    (bare / "landmarks.sosmap").unlink()
    with pytest.raises(InputError, match="mapped session without its landmarks.sosmap"):
        load_map(bare)
    assert load_map(bare / "sparse").kind == "colmap"  # asked for explicitly, the model is matched


def test_a_project_moved_whole_still_finds_its_images(session, tmp_path):
    """run.json records the images relative to the session too: a project folder moved elsewhere (sessions and
    images together) found no images, and `changes` ran without their evidence (a warning only; the nineteenth
    sweep: 4 gone / 10 new where the images said 1 / 6)."""
    from sosmatch.database.session_images import recorded_images_dir, session_images_dir

    root, _, out, _ = session
    moved = tmp_path / "moved"
    shutil.copytree(root / "images", moved / "images")
    shutil.copytree(out, moved / "mapped")
    record = json.loads((moved / "mapped" / "run.json").read_text())
    assert record["inputs_from_session"]["images"] == "../images"
    record["inputs"]["images"] = str(tmp_path / "gone" / "images")  # where the project was before the move
    (moved / "mapped" / "run.json").write_text(json.dumps(record))
    assert recorded_images_dir(moved / "mapped") == moved / "images"
    assert session_images_dir(moved / "mapped") == moved / "images"  # and they are the map's images


def _cli(capsys, *args):
    code = main(["map", "--no-progress", *map(str, args)])
    return code, capsys.readouterr()


def test_outputs_are_complete_and_consistent(session):
    root, objs, out, summary = session
    assert {p.name for p in out.iterdir()} == OUTPUT_NAMES  # no .partial, no temporaries
    lmap = read_landmark_map(out / "landmarks.sosmap")
    assert len(lmap) == summary.num_landmarks >= 10
    assert summary.map_bytes == (out / "landmarks.sosmap").stat().st_size == 84 + 14 * len(lmap)  # + noise figures
    assert np.abs(lmap.origin - np.median(lmap.positions, 0)).max() <= 0.5  # origin near the data
    # Landmarks sit on the discs: horizontal error to the nearest disc centre, height near the ground.
    d = np.linalg.norm(lmap.positions[:, None, :2] - objs[None, :, :2], axis=2).min(1)
    assert np.median(d) < 0.5 and np.median(np.abs(lmap.positions[:, 2])) < 1.5
    sess = read_session(out)  # the multi-session stages' reader agrees with the map
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    assert rec.num_points3D() == len(lmap) and rec.num_reg_images() == summary.num_keyframes
    for i, pid in enumerate(sess.point3d_ids):
        assert np.allclose(rec.points3D[int(pid)].xyz, lmap.positions[i], atol=1e-3)
    ply = (out / "landmarks.ply").read_bytes()
    assert f"element vertex {len(lmap)}\n".encode() in ply
    run = json.loads((out / "run.json").read_text())
    assert run["counts"]["landmarks"] == len(lmap) and run["params"]["triangulation"]["min_observations"] == 5
    assert set(run["versions"]) >= {"pycolmap", "numpy", "sosmatch"} and len(run["fingerprints"]["inputs"]) == 64
    db = pycolmap.Database.open(str(out / "database.db"))
    try:
        assert db.num_images() == summary.num_keyframes and db.num_keypoints() == summary.num_masks
    finally:
        db.close()
    line = summary.line()
    assert f"{summary.num_landmarks} landmarks" in line and "\n" not in line


def test_map_records_its_noise_and_landmarks_find_their_objects(session, tmp_path):
    from sosmatch.database.evaluation_io import landmark_observed_objects
    from sosmatch.database.map_loading import load_map
    from sosmatch.plugin.evaluation.landmark_truth import majority_objects
    from sosmatch.plugin.geometry import project

    root, objs, out, _ = session
    noise = load_map(out).noise
    # the map file carries the figures run.json records, so a copy of it is matched as the session is
    from sosmatch.database.map_loading import read_map_noise

    assert noise == read_map_noise(out) and load_map(out / "landmarks.sosmap").noise == noise
    (tmp_path / "copy.sosmap").write_bytes((out / "landmarks.sosmap").read_bytes())
    assert load_map(tmp_path / "copy.sosmap").noise == noise and load_map(tmp_path / "copy.sosmap").kind == "sosmap"
    # exact poses, flat discs at 0.075 m/px: a centroid is within a few pixels, one disc's size alike in all views
    assert noise.ground_resolution_m == pytest.approx(60.0 / 256.0, rel=0.02)
    assert 0 < noise.residual_m < 0.5 and 0 < noise.size_log_std < 0.2 and noise.landmarks > 10
    # label images (object id per pixel, 0 = ground) as `sosmatch synth` writes them: each landmark is its disc
    cam = Camera(320, 240, 256.0, 256.0, 160.0, 120.0)
    labels = tmp_path / "labels"
    labels.mkdir()
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    for image in rec.images.values():
        center = np.array([float(image.name[6:11]) * 2.0, 0.0, 60.0])
        lab = np.zeros((240, 320), np.uint16)
        for k, (x, y, r) in enumerate(objs):
            uv, _ = project(cam, np.diag([1.0, -1.0, -1.0]), center, np.array([[x, y, 0.0]]))
            cv2.circle(lab, (int(uv[0, 0]), int(uv[0, 1])), int(r * cam.fx / 60.0), k + 1, -1)
        cv2.imwrite(str(labels / (Path(image.name).stem + ".png")), lab)
    found = majority_objects(landmark_observed_objects(out, labels))
    lmap = read_landmark_map(out / "landmarks.sosmap")
    on = np.flatnonzero(found.object_ids > 0)
    assert len(on) >= 0.8 * len(lmap) and np.median(found.purity[on]) == 1.0
    dist = np.linalg.norm(lmap.positions[on, :2] - objs[found.object_ids[on] - 1, :2], axis=1)
    assert np.all(dist < objs[found.object_ids[on] - 1, 2])  # inside the disc it was voted to
    (labels / (Path(rec.images[1].name).stem + ".png")).unlink()
    with pytest.raises(InputError, match="label image"):
        landmark_observed_objects(out, labels)


def test_interrupted_run_resumes_to_identical_outputs(session, tmp_path):
    root, _, out_ref, _ = session

    class Stop(Exception):
        pass

    def stop_after_8(k):
        if k == 8:
            raise Stop

    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    out = tmp_path / "resumed"
    with pytest.raises(Stop):
        map_workflow.run(Params(), inputs, out, progress=False, on_keyframe=stop_after_8)
    # nothing half-written in the session itself
    assert {p.name for p in out.iterdir()} == {".partial", ".sosmatch-output.json"}
    assert len(list((out / ".partial" / "cache").glob("*.npz"))) == 9
    summary = map_workflow.run(Params(), inputs, out, progress=False)
    assert summary.keyframes_from_cache == 9
    for name in ("landmarks.sosmap", "landmarks.csv", "landmarks.ply"):
        assert (out / name).read_bytes() == (out_ref / name).read_bytes(), name
    ref, new = pycolmap.Reconstruction(str(out_ref / "sparse")), pycolmap.Reconstruction(str(out / "sparse"))
    assert sorted(ref.point3D_ids()) == sorted(new.point3D_ids())


def test_same_command_again_and_changed_inputs_are_refused(session, tmp_path, capsys):
    root, _, out, _ = session
    poses = root / "poses.csv"
    moved = tmp_path / "poses.csv"
    moved.write_text(poses.read_text().replace("60.0,", "61.0,"))
    before = (out / "run.json").read_bytes()
    code, cap = _cli(capsys, "--images", root / "images", "--poses", moved, "--camera", root / "cameras.txt",
                     "--out", out)
    assert code == 2 and "other inputs" in cap.err and len(cap.err.strip().splitlines()) == 1
    assert (out / "run.json").read_bytes() == before


@pytest.mark.parametrize("row, fragment", [
    ("frame_00003.jpg,6,0,nan,0,1,0,0", "NaN"),
    ("frame_00003.jpg,6,0,60,0.5,1,0,0", "unit length"),
    ("frame_00003.jpg,6,0,60,0,1,0", "columns"),
])
def test_bad_pose_rows_exit_2_without_output(session, tmp_path, capsys, row, fragment):
    root = session[0]
    lines = (root / "poses.csv").read_text().splitlines()
    idx = next(i for i, line in enumerate(lines) if line.startswith("frame_00003.jpg"))
    lines[idx] = row
    bad = tmp_path / "poses.csv"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    code, cap = _cli(capsys, "--images", root / "images", "--poses", bad, "--camera", root / "cameras.txt",
                     "--out", out)
    assert code == 2 and fragment in cap.err and f"{bad}:{idx + 1}:" in cap.err
    assert len(cap.err.strip().splitlines()) == 1 and not out.exists()


def test_missing_pose_is_skipped_or_strict_error(session, tmp_path, capsys):
    root = session[0]
    lines = (root / "poses.csv").read_text().splitlines()
    short = tmp_path / "poses.csv"
    short.write_text("\n".join(line for line in lines if not line.startswith("frame_00024")) + "\n")
    out = tmp_path / "out"
    args = ["--images", root / "images", "--poses", short, "--camera", root / "cameras.txt", "--out", out]
    code, cap = _cli(capsys, *args, "--strict")
    assert code == 2 and "without a pose: frame_00024.jpg" in cap.err and not out.exists()
    inputs = map_workflow.load_inputs(root / "images", short, root / "cameras.txt")
    assert len(inputs.image_paths) == 24 and "frame_00024.jpg" not in inputs.poses.names


def test_unwritable_output_and_locked_database(session, tmp_path, capsys):
    root = session[0]
    blocker = tmp_path / "file"
    blocker.write_text("x")
    args = ["--images", root / "images", "--poses", root / "poses.csv", "--camera", root / "cameras.txt"]
    code, cap = _cli(capsys, *args, "--out", blocker / "session")
    assert code == 2 and "cannot create output directory" in cap.err and len(cap.err.strip().splitlines()) == 1
    out = tmp_path / "locked"
    shutil.copytree(session[2], out)  # this very session (same inputs and parameters), its database held open
    con = sqlite3.connect(out / "database.db")
    con.execute("BEGIN EXCLUSIVE")
    try:
        code, cap = _cli(capsys, *args, "--out", out)
    finally:
        con.rollback()
        con.close()
    assert code == 2 and "locked" in cap.err
    assert {p.name for p in out.iterdir()} == OUTPUT_NAMES


def test_foreign_directory_is_refused_even_with_overwrite(session, tmp_path, capsys):
    root = session[0]
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"x")
    for extra in ((), ("--overwrite",)):
        code, cap = _cli(capsys, "--images", root / "images", "--poses", root / "poses.csv", "--camera",
                         root / "cameras.txt", "--out", out, *extra)
        assert code == 2 and "is not a `sosmatch map` output" in cap.err
        assert os.listdir(out) == ["holiday.jpg"]


def test_poses_from_a_colmap_model_and_a_synth_session(session, tmp_path):
    root, _, out, _ = session
    from_csv = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    from_model = map_workflow.load_inputs(root / "images", out / "sparse" / "images.bin")  # camera from the model
    assert from_model.poses.names == from_csv.poses.names and from_model.camera == from_csv.camera
    assert np.allclose(from_model.poses.centers, from_csv.poses.centers, atol=1e-9)
    assert map_workflow.input_fingerprints(from_model)["images"] == map_workflow.input_fingerprints(from_csv)["images"]
    # A synth session directory: images/, cameras.txt and poses.csv (or poses_ekf.csv) found inside.
    synth = tmp_path / "S1"
    synth.mkdir()
    (synth / "images").symlink_to(root / "images")
    for name in ("cameras.txt", "poses.csv"):
        (synth / name).write_bytes((root / name).read_bytes())
    (synth / "poses_ekf.csv").write_text((root / "poses.csv").read_text().replace(",60.0,", ",60.5,"))
    (synth / "session.json").write_text("{}")
    gt = map_workflow.load_inputs(None, synth)
    ekf = map_workflow.load_inputs(None, synth, ekf=True)
    assert gt.camera == from_csv.camera and np.allclose(gt.poses.centers, from_csv.poses.centers)
    assert np.allclose(ekf.poses.centers[:, 2], 60.5)


def test_two_workers_describe_keyframes_identically(session, tmp_path):
    root = session[0]
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    keyframes = np.arange(4)
    runs = []
    for workers in (1, 2):
        feats, motion, cached = map_workflow.describe_keyframes(inputs, keyframes, Params(), tmp_path / f"c{workers}",
                                                                 "key", progress=False, workers=workers)
        assert cached == 0 and len(feats) == 4 and motion[0] == (0.0, 0.0) and motion[1][0] > 0
        runs.append((feats, motion))
    (f1, m1), (f2, m2) = runs
    assert m1 == m2
    for a, b in zip(f1, f2):
        assert np.array_equal(a.centroids, b.centroids) and np.array_equal(a.sift_desc, b.sift_desc)


def test_tracking_reads_descriptors_from_the_cache_and_the_map_holds_none(session, tmp_path):
    """A flight's SIFT descriptors are ~95 % of its keyframes' descriptions (~1 MB a keyframe at 320 px: 1.7 GB held
    for 1500 keyframes, the nu22 sweep). The map keeps them in the keyframe cache and tracking reads the few
    keyframes it compares; the tracks are those of descriptors held in memory."""
    from sosmatch.plugin.tracking import track_masks

    root = session[0]
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    keyframes = np.arange(6)
    held, motion, _ = map_workflow.describe_keyframes(inputs, keyframes, Params(), tmp_path / "c", "key",
                                                      progress=False)
    light, motion2, cached = map_workflow.describe_keyframes(inputs, keyframes, Params(), tmp_path / "c", "key",
                                                             progress=False, hold_descriptors=False)
    assert cached == 6 and motion2 == motion
    assert all(f.sift_desc.shape == (0, 128) for f in light) and sum(len(f.sift_desc) for f in held) > 100
    read = []

    def descriptors(k: int) -> np.ndarray:
        read.append(k)
        return map_workflow.cached_descriptors(tmp_path / "c", inputs.poses.subset(keyframes).names)(k)

    kf_poses = inputs.poses.subset(keyframes)
    a = track_masks(held, inputs.camera, kf_poses, motion, Params().tracking)
    b = track_masks(light, inputs.camera, kf_poses, motion2, Params().tracking, descriptors)
    assert all(np.array_equal(x, y) for x, y in zip(a.track_ids, b.track_ids)) and a.num_tracks == b.num_tracks
    assert sorted(set(read)) == list(range(6))


def test_run_killed_while_publishing_resumes(session, tmp_path):
    root, _, out_ref, _ = session
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    out = tmp_path / "killed"
    real_replace = os.replace
    calls = []

    def dying_replace(src, dst):
        if Path(dst).parent == out:  # moves into the session itself (os is one module: atomic writes come here too)
            calls.append(dst)
            if len(calls) == 4:  # the output marker and two outputs moved into place, then the process "dies"
                raise KeyboardInterrupt
        return real_replace(src, dst)

    os.replace = dying_replace
    try:
        with pytest.raises(KeyboardInterrupt):
            map_workflow.run(Params(), inputs, out, progress=False)
    finally:
        os.replace = real_replace
    assert not (out / "run.json").exists() and (out / "database.db").exists()
    summary = map_workflow.run(Params(), inputs, out, progress=False)
    assert summary.keyframes_from_cache == summary.num_keyframes
    assert (out / "landmarks.sosmap").read_bytes() == (out_ref / "landmarks.sosmap").read_bytes()
    assert {p.name for p in out.iterdir()} == OUTPUT_NAMES


def test_a_failed_map_does_not_block_its_own_retry(session, tmp_path, capsys):
    """Issue 14, defect 4: after a corrupt image (or a camera of the wrong size) the run fails with the one-line
    error; once the file is fixed the same command resumes, without --overwrite, and recomputes only what the
    fix changed (the bad keyframe and the one after it)."""
    root = session[0]
    images = tmp_path / "images"
    shutil.copytree(root / "images", images)
    good = (images / "frame_00010.jpg").read_bytes()
    (images / "frame_00010.jpg").write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    out = tmp_path / "s"
    args = ["--images", images, "--poses", root / "poses.csv", "--camera", root / "cameras.txt", "--out", out]
    # the pose check, the first stage, reads the bad image before any keyframe is described
    code, cap = _cli(capsys, *args)
    assert code == 2 and "frame_00010.jpg" in cap.err and len(cap.err.strip().splitlines()) == 1
    assert not list((out / ".partial" / "cache").glob("*.npz"))
    # without it, the keyframes fail there, keeping the ones described before
    off = {"pose_check.enabled": False}
    code, cap = _cli(capsys, *args[:-1], tmp_path / "s_off", "--set", "pose_check.enabled=false")
    assert code == 2 and "frame_00010.jpg" in cap.err and len(cap.err.strip().splitlines()) == 1
    cached = len(list((tmp_path / "s_off" / ".partial" / "cache").glob("*.npz")))
    assert cached >= 10  # keyframes 0-9 were described before the bad one
    (images / "frame_00010.jpg").write_bytes(good)
    inputs = map_workflow.load_inputs(images, root / "poses.csv", root / "cameras.txt")
    summary = map_workflow.run(Params(), inputs, out, progress=False)
    assert (out / "landmarks.sosmap").read_bytes() == (session[2] / "landmarks.sosmap").read_bytes()
    summary = map_workflow.run(with_overrides(Params(), off), inputs, tmp_path / "s_off", progress=False)
    assert summary.keyframes_from_cache == cached
    fresh = map_workflow.run(with_overrides(Params(), off), inputs, tmp_path / "s_fresh", progress=False)
    assert fresh.keyframes_from_cache == 0
    resumed, from_scratch = (tmp_path / name / "landmarks.sosmap" for name in ("s_off", "s_fresh"))
    assert resumed.read_bytes() == from_scratch.read_bytes()
    # a camera of the wrong size: refused, then fixed, then resumed the same way
    wrong = tmp_path / "cameras.txt"
    wrong.write_text((root / "cameras.txt").read_text().replace(" 320 240 ", " 640 480 "))
    out2 = tmp_path / "s2"
    code, cap = _cli(capsys, *args[:4], "--camera", wrong, "--out", out2)
    assert code == 2 and "camera is" in cap.err
    code, cap = _cli(capsys, *args[:6], "--out", out2)
    assert code == 0, cap.err


def test_database_that_is_a_directory_or_damaged_is_refused(session, tmp_path, capsys):
    root, _, ref, _ = session
    args = ["--images", root / "images", "--poses", root / "poses.csv", "--camera", root / "cameras.txt"]
    out = tmp_path / "s"
    shutil.copytree(ref, out)
    damaged = os.urandom(4096)
    # our own output, damaged: not told from a user's file put there (its sha256 is not the one recorded), so it is
    # refused, not replaced; removed, the re-run writes it again
    (out / "database.db").write_bytes(damaged)
    code, cap = _cli(capsys, *args, "--out", out)
    assert code == 2 and "database.db: was changed since `sosmatch map` wrote it" in cap.err
    assert (out / "database.db").read_bytes() == damaged
    (out / "database.db").unlink()
    code, cap = _cli(capsys, *args, "--out", out)
    assert code == 0, cap.err
    pycolmap.Database.open(str(out / "database.db")).close()
    (out / "database.db").unlink()
    (out / "database.db").mkdir()
    (out / "database.db" / "mine.txt").write_text("x")
    code, cap = _cli(capsys, *args, "--out", out)
    assert code == 2 and "database.db" in cap.err and len(cap.err.strip().splitlines()) == 1
    assert (out / "database.db" / "mine.txt").read_text() == "x"


def test_second_concurrent_map_on_one_directory_is_refused(session, tmp_path):
    import subprocess
    import sys

    root = session[0]
    out = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", "import sys\nfrom sosmatch.database.outputs import "
                               "open_output_dir\nwith open_output_dir(sys.argv[1], 'map', 'first run'):\n"
                               "    print('held', flush=True)\n    sys.stdin.read()\n", str(out)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
        with pytest.raises(map_workflow.InputError, match=f"in use by sosmatch map \\(pid {holder.pid}\\)"):
            map_workflow.run(Params(), inputs, out, progress=False)
    finally:
        holder.communicate("")


def test_a_picture_that_cannot_be_drawn_loses_nothing(session, tmp_path, monkeypatch):
    """quality.png is an aid: when drawing it fails the map is still published, and no picture of an earlier run
    stands beside the new map."""
    from sosmatch.workflows.map import figure

    root, _, out_ref, _ = session
    out = tmp_path / "no_picture"
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    map_workflow.run(Params(), inputs, out, progress=False)
    assert (out / "quality.png").is_file()

    def broken(*args, **kwargs):
        raise RuntimeError("no display")

    monkeypatch.setattr(figure, "draw_map_figure", broken)
    map_workflow.run(Params(), inputs, out, progress=False, overwrite=True)
    assert not (out / "quality.png").exists()  # the earlier run's picture is not left beside this map
    assert {p.name for p in out.iterdir()} == OUTPUT_NAMES - {"quality.png"}
    assert (out / "landmarks.sosmap").read_bytes() == (out_ref / "landmarks.sosmap").read_bytes()


def test_frames_whose_names_do_not_follow_the_flight_are_mapped_in_flight_order(session, tmp_path, caplog):
    """The same images and poses under shuffled file names (renamed files, a wrapped counter), the pose file in
    name order as a COLMAP export by name gives it: the map follows the camera path, not the names. Before, the
    keyframes were taken in name order, every consecutive pair a jump across the flight: tracks broke at each, and
    the map kept a fraction of the landmarks, accepted without a word."""
    import logging

    root, _, _, summary = session
    poses = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt").poses
    rng = np.random.default_rng(4)
    new_names = [f"IMG_{k:04d}.jpg" for k in rng.permutation(len(poses.names))]
    (tmp_path / "images").mkdir()
    for old, new in zip(poses.names, new_names):
        shutil.copy2(root / "images" / old, tmp_path / "images" / new)
    by_name = np.argsort(new_names)
    shuffled = Poses([new_names[i] for i in by_name], poses.rotations[by_name], poses.centers[by_name])
    write_poses_csv(tmp_path / "poses.csv", shuffled)
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.map"):
        inputs = map_workflow.load_inputs(tmp_path / "images", tmp_path / "poses.csv", root / "cameras.txt")
        mixed = map_workflow.run(Params(), inputs, tmp_path / "mapped", progress=False)
    assert any("not listed in flight order" in r.getMessage() for r in caplog.records)
    assert mixed.num_keyframes == summary.num_keyframes
    assert mixed.num_landmarks >= 0.9 * summary.num_landmarks, (mixed.num_landmarks, summary.num_landmarks)


def test_two_flights_whose_capture_times_overlap_are_mapped_one_after_the_other(session, tmp_path, caplog):
    """nu57 D3 end to end: the session's line as two flights (frames 0-12 and 13-24, 26 m further on) whose camera
    clocks overlap (EXIF times 2 s apart each, the second's 1 s after the first's), as two batteries after a
    clock reset or two drones at once put in one folder. Ordered by capture time the keyframes alternated between
    the flights (tracks broken at every jump: -24 % landmarks on nu57's BATT); now each flight in time order, one
    after the other: the keyframes and the map of the flight listed in order, and one warning saying so."""
    import datetime
    import logging

    from sosmatch.database.exif import ImageMetadata
    from sosmatch.database.exif_write import embed_metadata

    root, _, out, summary = session
    names = json.loads((out / "run.json").read_text())["keyframes"]
    poses = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt").poses
    (tmp_path / "images").mkdir()
    start = datetime.datetime(2024, 5, 1, 10, 0, 0)
    seconds = np.array([2 * k if k < 13 else 2 * (k - 13) + 1 for k in range(len(poses.names))])
    for name, second in zip(poses.names, seconds):
        stamp = (start + datetime.timedelta(seconds=int(second))).strftime("%Y:%m:%d %H:%M:%S")
        meta = ImageMetadata(Path(name), 320, 240, datetime_original=stamp)
        (tmp_path / "images" / name).write_bytes(embed_metadata((root / "images" / name).read_bytes(), meta))
    by_time = np.argsort(seconds)  # the pose file in capture-time order, as an export sorted by time lists it
    write_poses_csv(tmp_path / "poses.csv", Poses([poses.names[i] for i in by_time], poses.rotations[by_time],
                                                  poses.centers[by_time]))
    with caplog.at_level(logging.WARNING, logger="sosmatch.workflows.map"):
        inputs = map_workflow.load_inputs(tmp_path / "images", tmp_path / "poses.csv", root / "cameras.txt")
        two = map_workflow.run(Params(), inputs, tmp_path / "mapped", progress=False)
    said = [r.getMessage() for r in caplog.records if "capture times interleave flights" in r.getMessage()]
    assert len(said) == 1 and "ordered per flight along the camera path" in said[0]
    assert json.loads((tmp_path / "mapped" / "run.json").read_text())["keyframes"] == names
    assert two.num_landmarks == summary.num_landmarks


def test_a_low_flight_keeps_the_landmarks_its_views_allow(tmp_path, capsys):
    """40 m above ground with frames 7 m apart, an object is in ~5 keyframes of a pass, so no track could have the
    6 observations theta_n = 5 asks for: 24 and 31 landmarks on two worlds against 238 and 225 at 100 m. theta_n
    follows the views (2 here, recorded in run.json), and the landmarks that need it are most of the map."""
    session = tmp_path / "low"
    assert main(["synth", "--out", str(session), "--frames", "24", "--width", "320", "--height", "240",
                 "--altitude", "40", "--world-size", "400", "--world-seed", "5", "-q"]) == 0
    out = tmp_path / "mapped"
    assert _cli(capsys, "--poses", session, "--out", out)[0] == 0
    counts = json.loads((out / "run.json").read_text())["counts"]
    assert 4.0 < counts["views_per_pass"] < 7.0  # 240 px along the motion, ~44 px per 7 m step
    assert counts["min_observations"] == 2
    observations = np.loadtxt(out / "landmarks.csv", delimiter=",", skiprows=1, usecols=6, ndmin=1)
    print(f"{len(observations)} landmarks, {np.sum(observations > 5)} with more than 5 observations")
    assert len(observations) >= 3 * max(1, int(np.sum(observations > 5)))


def test_the_summary_points_at_the_published_pose_check_record(session):
    """The eighth new-user sweep: MapSummary.pose_check.out named OUT/.partial/pose_check.json, gone once the map
    was published."""
    _, _, out, summary = session
    assert summary.pose_check.out == out / "pose_check.json" and summary.pose_check.out.is_file()


def test_byte_identical_images_are_named(tmp_path, caplog):
    """The eighth new-user sweep: two byte-identical copies under other names were mapped without a word (and
    the pose check called the identical pair 'reversed')."""
    from sosmatch.workflows.map.inputs import warn_duplicate_images

    paths = [tmp_path / n for n in ("a.jpg", "b.jpg", "a_copy.jpg")]
    with caplog.at_level("WARNING"):
        assert warn_duplicate_images(paths, ["x", "y", "x"]).copies == [["a.jpg", "a_copy.jpg"]]
    assert "a.jpg = a_copy.jpg" in caplog.text
    assert warn_duplicate_images(paths, ["x", "y", "z"]).copies == []


def test_pose_names_spelt_otherwise_pair_with_their_images(session, tmp_path):
    """The ninth new-user sweep: a pose CSV naming the images in upper case (as the camera wrote them) or in the
    composed Unicode form (files named on macOS are decomposed) paired with none of them."""
    import unicodedata

    root = session[0]
    images = tmp_path / "images"
    images.mkdir()
    names = sorted(p.name for p in (root / "images").iterdir())[:6]
    renamed = {n: unicodedata.normalize("NFD", f"Bild ü_{n}") for n in names[:3]}
    for n in names:
        shutil.copy(root / "images" / n, images / renamed.get(n, n))
    others = {p.name for p in (root / "images").iterdir()} - set(names)
    lines = [ln for ln in (root / "poses.csv").read_text().splitlines() if ln.split(",")[0] not in others]
    text = "\n".join(lines) + "\n"
    for n in names[:3]:
        text = text.replace(n + ",", unicodedata.normalize("NFC", f"Bild ü_{n}") + ",")
    for n in names[3:]:
        text = text.replace(n + ",", n.upper() + ",")
    (tmp_path / "poses.csv").write_text(text)
    inputs = map_workflow.load_inputs(images, tmp_path / "poses.csv", root / "cameras.txt", strict=True)
    assert sorted(p.name for p in inputs.image_paths) == sorted(renamed.get(n, n) for n in names)


def test_a_map_logged_to_a_file_says_how_far_its_keyframes_are(tmp_path, capsys, caplog, monkeypatch):
    """New-user sweep 22: with stderr not a terminal (`> log 2>&1`, nohup) the map command turned progress off,
    and a 1500-frame map printed two INFO lines and nothing during its 5.6-minute keyframe stage. Off a terminal
    the stages now log where they are every 30 s (the clock here: 31 s per reading)."""
    from sosmatch.workflows import progress

    ticks = iter(range(0, 10**6, 31))
    monkeypatch.setattr(progress, "_clock", lambda: float(next(ticks)))
    render_session(tmp_path / "s", n_frames=8)
    code = main(["map", "--poses", str(tmp_path / "s" / "poses.csv"), "--images", str(tmp_path / "s" / "images"),
                 "--camera", str(tmp_path / "s" / "cameras.txt"), "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err
    assert code == 0, err
    lines = [r.getMessage() for r in caplog.records if r.name == "sosmatch.progress"]
    assert any(line.startswith("keyframes: 1/8 kf") for line in lines), lines
    assert any(line.startswith("keyframes: 8/8 kf (100 %), done in") for line in lines), lines
    assert "\r" not in err  # no bar drawn into the log


def test_a_copied_project_reads_its_own_images_not_the_originals(tmp_path):
    """nu37 D2: after `cp -a project project.copy` the copy's run.json still records the original's absolute
    images path, which exists; the copy read the original's images (edits there changed the copy's results).
    The place relative to the session moves with the project and is taken first when it exists; the absolute path
    only when it does not (a session folder moved alone)."""
    from sosmatch.database.session_images import recorded_images_dir

    for project in ("project", "project.copy"):
        (tmp_path / project / "images").mkdir(parents=True)
        (tmp_path / project / "mapped").mkdir()
        (tmp_path / project / "mapped" / "run.json").write_text(json.dumps({
            "inputs": {"images": str(tmp_path / "project" / "images")},
            "inputs_from_session": {"images": "../images"}}))
    assert recorded_images_dir(tmp_path / "project.copy" / "mapped") == tmp_path / "project.copy" / "images"
    assert recorded_images_dir(tmp_path / "project" / "mapped") == tmp_path / "project" / "images"
    alone = tmp_path / "elsewhere" / "mapped"  # the session folder moved alone: its ../images is not there
    shutil.copytree(tmp_path / "project.copy" / "mapped", alone)
    assert recorded_images_dir(alone) == tmp_path / "project" / "images"


def test_a_session_reached_through_a_symlinked_folder_finds_its_images(session, tmp_path):
    """rev44 D1: `flights/M1 -> ../M1` with run.json recording `../S1/images`: the OS found `M1/../S1/images`, but
    the lexical `flights/S1/images` was returned, which does not exist, and `changes` (and batch over such a
    folder) compared the sessions without their images. The path returned is the one that exists; with the
    relative place gone either way, the absolute path run.json records."""
    from sosmatch.database.session_images import recorded_images_dir, session_images_dir

    root, _, out, _ = session
    flights = tmp_path / "flights"
    flights.mkdir()
    (flights / "mapped").symlink_to(out, target_is_directory=True)
    record = json.loads((out / "run.json").read_text())
    assert record["inputs_from_session"]["images"] == "../images"
    found = recorded_images_dir(flights / "mapped")
    assert found.is_dir() and found.samefile(root / "images")
    assert session_images_dir(flights / "mapped") == found  # and they are the map's images

    # the relative place exists neither from the link nor from the real folder: the absolute path recorded
    project = tmp_path / "project"
    (project / "mapped").mkdir(parents=True)
    (project / "mapped" / "run.json").write_text(json.dumps({
        "inputs": {"images": str(root / "images")}, "inputs_from_session": {"images": "../../nowhere/images"}}))
    (flights / "linked").symlink_to(project / "mapped", target_is_directory=True)
    assert recorded_images_dir(flights / "linked") == root / "images"


def test_an_output_folder_moved_mid_run_stops_it_in_one_line_and_nothing_comes_back(session, tmp_path, capsys,
                                                                                    monkeypatch):
    """`mv OUT NEW` while map writes OUT: exit 2 with one line naming OUT and the new place, nothing re-created at
    OUT (a re-run there would refuse it as a folder sosmatch did not make), and the same command on NEW resumes."""
    from sosmatch.workflows.map import keyframes

    root = session[0]
    out, moved = tmp_path / "out", tmp_path / "moved"
    describe_one = keyframes._describe_one

    def move_at_the_fourth(*args, **kwargs):
        if args[4].name.startswith("00003_"):  # the cache entry of keyframe 3: OUT is moved before it is written
            os.rename(out, moved)
        return describe_one(*args, **kwargs)

    monkeypatch.setattr(keyframes, "_describe_one", move_at_the_fourth)
    args = ["--images", root / "images", "--poses", root / "poses.csv", "--camera", root / "cameras.txt"]
    code, cap = _cli(capsys, *args, "--workers", 1, "--out", out)
    assert code == 2, cap.err
    assert cap.err.strip() == (f"sosmatch map: error: {out}: was moved or deleted while sosmatch map was writing it "
                               f"(now {moved}): re-run the same command on its new place to resume")
    assert not out.exists()
    assert not (moved / ".sosmatch-output.lock").exists()  # the run's lock moved with the folder, and was released
    assert len(list((moved / ".partial" / "cache").glob("*.npz"))) == 3
    monkeypatch.setattr(keyframes, "_describe_one", describe_one)
    code, cap = _cli(capsys, *args, "--out", moved)
    assert code == 0, cap.err
    assert (moved / "landmarks.sosmap").read_bytes() == (session[2] / "landmarks.sosmap").read_bytes()


def test_an_output_folder_moved_while_workers_describe_keyframes_is_not_re_created(session, tmp_path):
    """The pool workers write the cache entries by path: after the move they re-create nothing at the old place."""
    root = session[0]
    out, moved = tmp_path / "out", tmp_path / "moved"

    def move(k):
        if k == 1:
            os.rename(out, moved)

    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    with pytest.raises(InputError, match=f"^{out}: was moved or deleted while sosmatch map was writing it "
                                         rf"\(now {moved}\)"):
        map_workflow.run(Params(), inputs, out, progress=False, on_keyframe=move, workers=2)
    assert not out.exists() and not (moved / ".sosmatch-output.lock").exists()


class _NoMasks:
    """A `masks_for` object (as the benchmarks' ground-truth masks): no mask in any image."""

    def __call__(self, name, image):
        from sosmatch.plugin.segmentation import MaskSet

        return MaskSet.empty(image.shape[:2])


def test_masks_from_a_callable_object_are_named_by_its_class_not_its_address(session, tmp_path):
    """The identity and cache key of a map whose masks come from a callable object held its repr (with its memory
    address) until fix98: the same command again was refused as another map, and its cache never reused."""
    root = session[0]
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    params = with_overrides(Params(), {"quality.refuse": False, "pose_check.enabled": False})
    out = tmp_path / "gt"
    map_workflow.run(params, inputs, out, progress=False, masks_for=_NoMasks())
    summary = map_workflow.run(params, inputs, out, progress=False, masks_for=_NoMasks(), keep_cache=True)
    assert json.loads((out / "run.json").read_text())["masks"] == "_NoMasks"
    again = map_workflow.run(params, inputs, out, progress=False, masks_for=_NoMasks())
    assert again.keyframes_from_cache == summary.num_keyframes > 0


def test_map_without_poses_names_a_pose_file_beside_the_images(tmp_path, caplog):
    """nu54 M6: `map --images flight/images` (--poses forgotten, flight/poses.csv beside) ran structure from motion
    for minutes at a nominal scale, and nothing pointed at the pose file. One warning line names it now."""
    flight = tmp_path / "flight"
    (flight / "images").mkdir(parents=True)
    (flight / "images" / "frame_00000.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    (flight / "poses.csv").write_text("name,x,y,z,qw,qx,qy,qz\n")
    assert map_workflow.pose_file_beside(flight / "images") == flight / "poses.csv"
    assert map_workflow.pose_file_beside(flight) == flight / "poses.csv"  # a poses.csv inside the folder
    with caplog.at_level("WARNING"):
        main(["map", "--images", str(flight / "images"), "--out", str(tmp_path / "m")])  # then fails on the image
    said = [r.getMessage() for r in caplog.records if "looks like this flight's poses" in r.getMessage()]
    assert len(said) == 1 and f"pass --poses {flight / 'poses.csv'} to use them" in said[0], caplog.text
    (flight / "session.json").write_text("{}")  # a synth session: its folder is what --poses takes
    assert map_workflow.pose_file_beside(flight / "images") == flight
    assert map_workflow.pose_file_beside(tmp_path) is None
