"""The session's COLMAP database: keypoints from masks, matches from tracks, pycolmap and COLMAP 3.8 interop."""

import shutil
import sqlite3
import subprocess

import numpy as np
import pytest

from sosmatch.database.colmap_db import (
    PRIOR_COLUMNS_38,
    affine_keypoints,
    check_database_writable,
    epipolar_errors_px,
    track_associations,
    verify_associations,
    write_colmap_database,
)
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, Poses, project

pycolmap = pytest.importorskip("pycolmap")
pycolmap.logging.minloglevel = 2


def nadir_scene(n_frames=12, n_points=60, noise_px=0.0, seed=0):
    """Nadir camera flying along x at 100 m over random points; tracks are the true point ids."""
    rng = np.random.default_rng(seed)
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r_wc = np.diag([1.0, -1.0, -1.0])
    centers = np.stack([np.arange(n_frames) * 2.0, np.zeros(n_frames), np.full(n_frames, 100.0)], 1)
    poses = Poses([f"f{i:03d}.jpg" for i in range(n_frames)], np.repeat(r_wc[None], n_frames, 0), centers)
    pts = np.stack([rng.uniform(-30, 2 * n_frames + 30, n_points), rng.uniform(-40, 40, n_points),
                    rng.uniform(0, 10, n_points)], 1)
    cents, tids = [], []
    for k in range(n_frames):
        uv, d = project(cam, r_wc, centers[k], pts)
        vis = np.flatnonzero((uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (d > 0))
        perm = rng.permutation(vis)
        cents.append(uv[perm] + rng.normal(0, noise_px, (len(perm), 2)))
        tids.append(perm.astype(np.int64))
    return cam, poses, pts, cents, tids


def test_affine_shape_squares_to_the_covariance():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(20, 2, 2))
    cov = m @ np.transpose(m, (0, 2, 1)) + 0.5 * np.eye(2)
    kp = affine_keypoints(rng.uniform(0, 100, (20, 2)), cov)
    a = kp[:, 2:].reshape(-1, 2, 2).astype(np.float64)
    assert kp.dtype == np.float32 and kp.shape == (20, 6)
    assert np.allclose(a @ a, cov, rtol=1e-4, atol=1e-4)
    # A single-pixel mask has zero covariance: the shape stays invertible.
    deg = affine_keypoints(np.zeros((1, 2)), np.zeros((1, 2, 2)))
    assert abs(np.linalg.det(deg[0, 2:].reshape(2, 2))) > 0


def test_track_associations_modes_and_min_observations():
    # Track 7 is seen in frames 0, 1, 3; track 8 in 0 and 2; -1 is untracked.
    tids = [np.array([7, 8, -1]), np.array([-1, 7]), np.array([8]), np.array([5, 7])]
    cons = track_associations(tids, "consecutive")
    assert {k: v.tolist() for k, v in cons.items()} == {(0, 1): [[0, 1]], (1, 3): [[1, 1]], (0, 2): [[1, 0]]}
    full = track_associations(tids, "all")
    assert {k: v.tolist() for k, v in full.items()} == {
        (0, 1): [[0, 1]], (0, 2): [[1, 0]], (0, 3): [[0, 1]], (1, 3): [[1, 1]]}
    only_long = track_associations(tids, "all", min_observations=2)
    assert set(only_long) == {(0, 1), (0, 3), (1, 3)}
    with pytest.raises(ValueError):
        track_associations(tids, "nearest")
    with pytest.raises(ValueError, match="same keyframe"):
        track_associations([np.array([1, 1])], "all")


def test_epipolar_verification_removes_a_wrong_association():
    cam, poses, _, cents, tids = nadir_scene()
    pairs = track_associations(tids, "consecutive")
    (a, b), m = next(iter(pairs.items()))
    assert np.all(epipolar_errors_px(cam, poses, a, b, cents[a][m[:, 0]], cents[b][m[:, 1]]) < 1e-6)
    bad = {k: v.copy() for k, v in pairs.items()}
    # Swap the partners of two associations whose centroids differ across the flight direction.
    ys = cents[b][bad[(a, b)][:, 1], 1]
    i, j = int(np.argmin(ys)), int(np.argmax(ys))
    bad[(a, b)][[i, j], 1] = bad[(a, b)][[j, i], 1]
    kept, removed = verify_associations(cam, poses, cents, bad, max_error_px=12.0)
    assert removed == 2 and len(kept[(a, b)]) == len(pairs[(a, b)]) - 2


def test_database_round_trip_in_pycolmap(tmp_path):
    cam, poses, _, cents, tids = nadir_scene()
    cov = np.tile(np.diag([9.0, 4.0]), (1, 1, 1))
    kps = [affine_keypoints(c, np.repeat(cov, len(c), 0)) for c in cents]
    pairs = track_associations(tids, "all", min_observations=3)
    path = tmp_path / "out" / "database.db"
    summary = write_colmap_database(path, cam, poses.names, kps, pairs)
    assert summary.num_images == len(poses) and summary.num_pairs == len(pairs)
    assert summary.num_matches == sum(len(m) for m in pairs.values())
    assert [p.name for p in path.parent.iterdir()] == ["database.db"]  # no temporary left behind
    db = pycolmap.Database.open(str(path))
    try:
        assert db.num_images() == len(poses) and db.num_frames() == len(poses) and db.num_rigs() == 1
        assert db.read_image(3).name == poses.names[2]
        assert np.allclose(db.read_keypoints(3), kps[2])
        assert db.num_inlier_matches() == summary.num_matches
        a, b = sorted(pairs)[0]
        tvg = db.read_two_view_geometry(a + 1, b + 1)
        assert tvg.config == pycolmap.TwoViewGeometryConfiguration.CALIBRATED
        assert np.array_equal(np.asarray(tvg.inlier_matches), pairs[(a, b)])
        camera = db.read_camera(1)
        assert camera.model.name == "PINHOLE" and np.allclose(camera.params, [500, 500, 320, 240])
    finally:
        db.close()
    con = sqlite3.connect(path)
    cols = {row[1] for row in con.execute("PRAGMA table_info(images)")}
    con.close()
    assert set(PRIOR_COLUMNS_38) <= cols


def test_locked_database_is_a_user_error(tmp_path):
    path = tmp_path / "database.db"
    write_colmap_database(path, Camera(10, 10, 5.0, 5.0, 5.0, 5.0), ["a.jpg"], [np.zeros((0, 2))], {})
    check_database_writable(path)  # not locked: fine
    con = sqlite3.connect(path)
    con.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(InputError, match="locked"):
            check_database_writable(path)
    finally:
        con.rollback()
        con.close()


@pytest.mark.skipif(shutil.which("colmap") is None, reason="COLMAP command-line program not installed")
def test_colmap_38_point_triangulator_runs_on_the_database(tmp_path):
    from sosmatch.workflows.triangulation import build_reconstruction

    cam, poses, pts, cents, tids = nadir_scene()
    kps = [affine_keypoints(c, np.repeat(np.eye(2)[None] * 4, len(c), 0)) for c in cents]
    db_path = tmp_path / "database.db"
    write_colmap_database(db_path, cam, poses.names, kps, track_associations(tids, "all", 5))
    model_in, model_out, images = tmp_path / "in", tmp_path / "out", tmp_path / "images"
    for d in (model_in, model_out, images):
        d.mkdir()
    build_reconstruction(cam, poses).write_text(str(model_in))
    proc = subprocess.run(
        ["colmap", "point_triangulator", "--database_path", str(db_path), "--image_path", str(images),
         "--input_path", str(model_in), "--output_path", str(model_out), "--Mapper.extract_colors", "0",
         "--Mapper.num_threads", "1"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = pycolmap.Reconstruction(str(model_out))
    assert rec.num_points3D() > 0.5 * len({t for ids in tids for t in ids})
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    nearest = np.linalg.norm(xyz[:, None, :] - pts[None], axis=2).min(1)
    assert np.median(nearest) < 0.05  # noise-free centroids: the points are exact


def test_reading_a_database_leaves_it_byte_identical(tmp_path):
    """New-user sweep: `changes` (and `match` of a COLMAP model with its database) read database.db through
    pycolmap, which opens read-write and commits on open: every read moved the file's change counter and mtime,
    so a batch re-run saw its mapped flights as changed. The reader gives pycolmap's keypoints, read-only."""
    import hashlib
    import os

    from sosmatch.database.colmap_db import read_segment_detections

    cam, poses, _, cents, tids = nadir_scene()
    kps = [affine_keypoints(c, np.repeat(np.diag([9.0, 4.0])[None], len(c), 0)) for c in cents]
    path = tmp_path / "database.db"
    write_colmap_database(path, cam, poses.names, kps, track_associations(tids, "all", min_observations=3))
    os.utime(path, ns=(1_000_000_000, 1_000_000_000))
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    dets = read_segment_detections(path, poses.names[::-1])
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before and path.stat().st_mtime_ns == 1_000_000_000
    assert [p.name for p in tmp_path.iterdir()] == ["database.db"]  # no -wal / -shm of a WAL-mode reader left
    for det, kp in zip(dets, kps[::-1]):
        assert np.allclose(det.centroids, kp[:, :2]) and np.allclose(det.sizes_px, 3.0, rtol=1e-5)


def test_the_matches_are_read_read_only_as_written(tmp_path):
    """`changes` reads the tracks behind a session's database (objects never mapped) from its matches: the
    read-only reader had no matches (the call went to a pycolmap method it lacks, so every `changes` run on a
    mapped session failed); the pairs and keypoint indices are the ones written, in the caller's image order,
    and the file is left as it was."""
    import hashlib

    from sosmatch.database.colmap_db import read_keyframe_matches

    cam, poses, _, cents, tids = nadir_scene()
    kps = [affine_keypoints(c, np.repeat(np.diag([9.0, 4.0])[None], len(c), 0)) for c in cents]
    path = tmp_path / "database.db"
    pairs = track_associations(tids, "all", min_observations=3)
    write_colmap_database(path, cam, poses.names, kps, pairs)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    names = poses.names[::-1]  # the caller's order: index k is names[k]
    got = {(a, b): m for a, b, m in read_keyframe_matches(path, names)}
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    n = len(names)
    want = {(n - 1 - a, n - 1 - b): m for (a, b), m in pairs.items() if len(m)}
    assert len(got) == len(want) > 0
    for (a, b), m in want.items():
        # COLMAP stores each pair once, ordered by image id; reversed names swap the columns' roles
        g = got[(a, b)] if (a, b) in got else got[(b, a)][:, ::-1]
        assert {tuple(r) for r in g.tolist()} == {tuple(r) for r in m.tolist()}
    some = read_keyframe_matches(path, names[:3])  # pairs with an image outside the names are left out
    assert some and all(max(a, b) < 3 for a, b, _ in some)
