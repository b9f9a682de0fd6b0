"""Duplicate landmark suppression: nested / partial masks of one object leave one landmark, distinct neighbours two."""

import numpy as np
import pytest

from sosmatch.database.colmap_db import affine_keypoints, track_associations, write_colmap_database
from sosmatch.plugin.geometry import Camera, Poses, project
from sosmatch.plugin.params import TriangulationParams
from sosmatch.workflows.triangulation import LandmarkRow, duplicates_kept, suppress_duplicates, triangulate_landmarks

pycolmap = pytest.importorskip("pycolmap")
pycolmap.logging.minloglevel = 2
SIZE_M = 1.5  # metric size h of every object (a crown of radius 3 m)


def test_planted_duplicate_is_dropped_distinct_neighbour_kept():
    # 0: an object; 1: a part of it (0.8 h away, fewer observations); 2: a touching neighbour (4 h away);
    # 3: a far object
    pos = np.array([[0.0, 0.0, 5.0], [0.8 * SIZE_M, 0.0, 7.0], [4 * SIZE_M, 0.0, 5.0], [50.0, 0.0, 5.0]])
    sizes = np.full(4, SIZE_M)
    keep = suppress_duplicates(pos, sizes, np.array([20, 12, 18, 15]), np.ones(4), 1.5)
    assert keep.tolist() == [True, False, True, True]
    # support decides which of the pair survives, not the index
    keep = suppress_duplicates(pos, sizes, np.array([12, 20, 18, 15]), np.ones(4), 1.5)
    assert keep.tolist() == [False, True, True, True]
    # equal support: the lower reprojection error wins
    keep = suppress_duplicates(pos, sizes, np.array([20, 20, 18, 15]), np.array([3.0, 1.0, 1.0, 1.0]), 1.5)
    assert keep.tolist() == [False, True, True, True]
    assert suppress_duplicates(pos, sizes, np.array([20, 12, 18, 15]), np.ones(4), 0.0).all()  # off


def test_chain_keeps_survivors_of_suppressed_landmarks():
    # a -- b -- c in a row, 1 h apart: b is a duplicate of both; once b is dropped by a, c (2 h from a) stays
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    keep = suppress_duplicates(pos, np.ones(3), np.array([30, 20, 10]), np.ones(3), 1.5)
    assert keep.tolist() == [True, False, True]


def test_larger_size_sets_the_radius():
    # a crown (h = 3) and a fragment (h = 0.5) 2.5 m off its centre: a duplicate of the crown
    pos = np.array([[0.0, 0.0, 0.0], [2.5, 0.0, 0.0]])
    assert suppress_duplicates(pos, np.array([3.0, 0.5]), np.array([9, 9]), np.ones(2), 1.5).tolist() == [True, False]
    # two small objects 2.5 m apart are distinct
    assert suppress_duplicates(pos, np.array([0.5, 0.5]), np.array([9, 9]), np.ones(2), 1.5).all()


def test_triangulation_fuses_nested_mask_landmarks(tmp_path):
    """Through pycolmap: every object also yields a 'part' mask (centroid 0.8 h off, seen in fewer frames);
    the part landmarks are dropped, all whole-object landmarks stay, also of objects 4 h apart."""
    rng = np.random.default_rng(3)
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r_wc = np.diag([1.0, -1.0, -1.0])
    n_frames = 24
    centers = np.stack([np.arange(n_frames) * 2.0, rng.normal(0, 0.5, n_frames), np.full(n_frames, 100.0)], 1)
    poses = Poses([f"f{i:03d}.jpg" for i in range(n_frames)], np.repeat(r_wc[None], n_frames, 0), centers)
    # objects on a grid 4 h apart (touching crowns), plus each object's part 0.8 h east of it
    gx, gy = np.meshgrid(np.arange(6) * 4 * SIZE_M + 10, np.arange(4) * 4 * SIZE_M - 10)
    objects = np.stack([gx.ravel(), gy.ravel(), rng.uniform(3, 8, gx.size)], 1)
    parts = objects + [0.8 * SIZE_M, 0.0, 0.5]
    pts = np.concatenate([objects, parts])
    n_obj = len(objects)
    cents, tids, sizes = [], [], []
    for k in range(n_frames):
        uv, d = project(cam, r_wc, centers[k], pts)
        vis = (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (d > 0)
        vis[n_obj:] &= k % 3 != 0  # parts are missed in every third frame: less support
        idx = rng.permutation(np.flatnonzero(vis))
        cents.append(uv[idx] + rng.normal(0, 1.0, (len(idx), 2)))
        tids.append(idx.astype(np.int64))
        h = np.where(idx < n_obj, SIZE_M, 0.6 * SIZE_M)  # a part is smaller than its object
        sizes.append(h * cam.fx / d[idx])
    params = TriangulationParams(duplicate_radius_factor=2.0)
    kps = [affine_keypoints(c, np.repeat(np.eye(2)[None] * 4, len(c), 0)) for c in cents]
    write_colmap_database(tmp_path / "database.db", cam, poses.names, kps,
                          track_associations(tids, "all", params.min_observations))
    lm = triangulate_landmarks(tmp_path / "database.db", cam, poses, sizes, tids, params)
    assert set(lm.track_ids.tolist()) == set(range(n_obj))  # every object kept, no part
    assert lm.counts["dropped_duplicate"] == n_obj
    assert lm.reconstruction.num_points3D() == len(lm)  # dropped points left the model too
    off = TriangulationParams(duplicate_radius_factor=0.0)
    write_colmap_database(tmp_path / "d2.db", cam, poses.names, kps,
                          track_associations(tids, "all", off.min_observations))
    assert len(triangulate_landmarks(tmp_path / "d2.db", cam, poses, sizes, tids, off)) == len(pts)


def test_duplicates_ranked_by_bundle_adjusted_error_not_recorded_one():
    """A landmark moved to its whole views records an error over those views only; duplicate suppression ranks
    by the bundle-adjusted error over all views (the one the error filter judged), so the two orders disagree
    here on purpose: landmark 0 is better by the recorded error, landmark 1 by the bundle-adjusted one."""
    obs = np.zeros((5, 2), dtype=np.int64)
    rows = [LandmarkRow(0, 10, np.array([0.0, 0.0, 5.0]), SIZE_M, 5, 0.5, obs, 3.0),
            LandmarkRow(1, 11, np.array([0.5 * SIZE_M, 0.0, 5.0]), SIZE_M, 5, 2.0, obs, 1.0),
            LandmarkRow(2, 12, np.array([50.0, 0.0, 5.0]), SIZE_M, 5, 1.0, obs, 1.0)]
    assert duplicates_kept(rows, 1.5).tolist() == [False, True, True]
    # the same landmarks with recorded = bundle-adjusted error: the ranking follows it
    same = [r._replace(adjusted_error_px=r.error_px) for r in rows]
    assert duplicates_kept(same, 1.5).tolist() == [True, False, True]
