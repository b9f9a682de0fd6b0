"""Split tracks of one object (one per pass) become one landmark; co-visible neighbours and unlike sizes do not."""

import numpy as np
import pytest

from sosmatch.database.colmap_db import affine_keypoints, track_associations, write_colmap_database
from sosmatch.plugin.geometry import Camera, Poses, project
from sosmatch.plugin.params import TriangulationParams
from sosmatch.plugin.track_fusion import TrackPiece, fuse_tracks, intersect_rays
from sosmatch.workflows.triangulation import triangulate_landmarks

pycolmap = pytest.importorskip("pycolmap")
pycolmap.logging.minloglevel = 2
CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
NADIR = np.diag([1.0, -1.0, -1.0])


def two_passes(n_per_pass=20, spacing=4.0, line_gap=30.0):
    """A lawnmower of two lines at 100 m: north along x = 0, back south along x = line_gap."""
    ys = np.arange(n_per_pass) * spacing
    c1 = np.stack([np.zeros(n_per_pass), ys, np.full(n_per_pass, 100.0)], 1)
    c2 = np.stack([np.full(n_per_pass, line_gap), ys[::-1], np.full(n_per_pass, 100.0)], 1)
    centers = np.concatenate([c1, c2])
    return Poses([f"f{i:03d}.jpg" for i in range(len(centers))], np.repeat(NADIR[None], len(centers), 0), centers)


def observe(poses, points, noise_px, rng):
    """Per keyframe the visible points' pixels (noisy) and point ids."""
    out = []
    for k in range(len(poses)):
        uv, d = project(CAM, poses.rotations[k], poses.centers[k], points)
        vis = np.flatnonzero((uv[:, 0] > 10) & (uv[:, 0] < 630) & (uv[:, 1] > 10) & (uv[:, 1] < 470) & (d > 0))
        out.append((vis, uv[vis] + rng.normal(0, noise_px, (len(vis), 2))))
    return out


def test_fuse_tracks_joins_passes_and_keeps_neighbours_apart():
    rng = np.random.default_rng(0)
    poses = two_passes()
    # 0 and 1: two objects 2.5 m apart, inside the fusion radius (2 x 1.5 m), both seen on both passes: what keeps
    # them apart is that they are seen together (their pieces share keyframes)
    points = np.array([[15.0, 30.0, 8.0], [15.0, 32.5, 8.0]])
    obs = observe(poses, points, 2.0, rng)
    pieces, owner = [], []
    n = len(poses) // 2
    for pid in range(2):
        for frames in (range(n), range(n, 2 * n)):  # one track per pass
            kf = np.array([k for k in frames if pid in obs[k][0]])
            px = np.array([obs[k][1][list(obs[k][0]).index(pid)] for k in kf])
            pieces.append(TrackPiece(kf, px, intersect_rays(CAM, poses, kf, px), 1.5))
            owner.append(pid)
    groups = fuse_tracks(pieces, CAM, poses, radius_factor=2.0, size_tolerance=0.5, max_error_px=10.0)
    assert groups == [[0, 1], [2, 3]]  # each object's two passes, never the two neighbours
    # unlike sizes are not joined, and radius_factor 0 switches fusion off
    pieces[1] = TrackPiece(pieces[1].keyframes, pieces[1].pixels, pieces[1].point, 3.0)
    assert fuse_tracks(pieces, CAM, poses, 2.0, 0.5, 10.0) == [[0], [1], [2, 3]]
    assert fuse_tracks(pieces, CAM, poses, 0.0, 0.5, 10.0) == [[0], [1], [2], [3]]
    # a piece that one point cannot explain (a wrong track 3 m away) stays alone
    shifted = TrackPiece(pieces[3].keyframes, pieces[3].pixels + [45.0, 0.0], pieces[3].point + [3.0, 0, 0], 1.5)
    assert [2] in fuse_tracks(pieces[:3] + [shifted], CAM, poses, 4.0, 0.5, 10.0)


def test_triangulation_fuses_pass_pieces_into_one_landmark(tmp_path):
    rng = np.random.default_rng(1)
    poses = two_passes()
    points = np.stack([rng.uniform(5, 25, 12), rng.uniform(20, 60, 12), rng.uniform(0, 10, 12)], 1)
    points = points[np.argsort(points[:, 1])]
    obs = observe(poses, points, 2.0, rng)
    n = len(poses) // 2
    cents, tids, sizes = [], [], []
    for k, (vis, px) in enumerate(obs):
        cents.append(px)
        tids.append(vis + (len(points) if k >= n else 0))  # the second pass starts new tracks
        d = project(CAM, poses.rotations[k], poses.centers[k], points[vis])[1]
        sizes.append(1.2 * CAM.fx / d)
    covs = [np.repeat(np.eye(2)[None] * 16.0, len(c), 0) for c in cents]
    kps = [affine_keypoints(c, cv) for c, cv in zip(cents, covs)]
    pairs = track_associations(tids, "all", 2)
    write_colmap_database(tmp_path / "database.db", CAM, poses.names, kps, pairs)
    on = triangulate_landmarks(tmp_path / "database.db", CAM, poses, sizes, tids, TriangulationParams(),
                               centroids_px=cents, covariances_px=covs)
    write_colmap_database(tmp_path / "d2.db", CAM, poses.names, kps, pairs)
    off = triangulate_landmarks(tmp_path / "d2.db", CAM, poses, sizes, tids, TriangulationParams(fuse_radius_factor=0))
    both = [p for p in range(len(points)) if any(p in o[0] for o in obs[:n]) and any(p in o[0] for o in obs[n:])]
    assert on.counts["fused"] >= len(both) - 1
    assert len(on) <= len(off) - len(both) + 1
    # a fused landmark holds both passes' observations and sits where the object is
    for i in np.flatnonzero(on.num_observations > n):
        kf = on.observations[i][:, 0]
        assert kf.min() < n <= kf.max()
        assert np.min(np.linalg.norm(points - on.positions[i], axis=1)) < 1.5
    assert np.all(np.diff(on.track_ids) >= 0)  # map order: first sighting


def test_neighbour_search_follows_each_pieces_own_size():
    """Each piece is searched within radius_factor x its own size: the pairs are exactly those the criterion
    (distance <= factor x the larger size) admits, and one wrong track's huge size (a point far below the
    ground) no longer sets the radius of every piece (3000 pieces of 2 m over 1 km2 with one of 800 m: 4.5 M
    candidate pairs and a traced peak of 234 MB before, 19 MB now)."""
    import tracemalloc

    from sosmatch.plugin.track_fusion import candidate_pairs
    from sosmatch.workflows.triangulation import suppress_duplicates

    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (400, 2))
    radii = rng.uniform(0, 6, 400)
    radii[:3] = [np.inf, np.nan, 0.0]
    i, j = candidate_pairs(xy, radii)
    assert np.all(i < j) and len(set(zip(i.tolist(), j.tolist()))) == len(i)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    want = (d <= np.fmax(radii[:, None], radii[None])) & np.triu(np.ones_like(d, bool), 1)
    got = np.zeros_like(want)
    got[i, j] = d[i, j] <= np.fmax(radii[i], radii[j])
    assert np.array_equal(got, want)

    n = 3000
    xy = rng.uniform(0, 1000, (n, 2))
    cam = Camera(320, 240, 250.0, 250.0, 160.0, 120.0)
    poses = Poses([f"{k}" for k in range(n)], np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3)))
    pieces = [TrackPiece(np.array([k]), np.zeros((1, 2)), np.array([x, y, 0.0]), 2.0) for k, (x, y) in enumerate(xy)]
    pieces[0] = TrackPiece(np.array([0]), np.zeros((1, 2)), np.array([500.0, 500.0, -3000.0]), 800.0)
    sizes = np.full(n, 2.0)
    sizes[0] = 800.0
    tracemalloc.start()
    try:
        groups = fuse_tracks(pieces, cam, poses, 2.0, 0.5, 10.0)  # sizes 400x apart: never one object
        keep = suppress_duplicates(xy, sizes, np.full(n, 5), np.ones(n), 2.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(groups) == n
    assert keep.sum() < n and not keep[1:][np.linalg.norm(xy[1:] - xy[0], axis=1) <= 1600.0].any()
    assert peak < 60e6  # the pairs some piece's own radius admits: ~n for the outlier, a few per 2 m piece


def test_a_fused_group_keeps_its_sizes_within_the_tolerance():
    """rev50 D8: pieces of one object sized 1.0, 1.25 and 1.55 m, tolerance 0.25: each neighbouring pair agrees
    (0.22, 0.21), the extremes do not (0.43); compared pair by pair the group chained past the tolerance, now its
    smallest and largest size are compared too."""
    rng = np.random.default_rng(0)
    poses = two_passes()
    obs = observe(poses, np.array([[15.0, 30.0, 8.0]]), 1.0, rng)
    n = len(poses) // 2
    seen = [k for k in range(len(poses)) if 0 in obs[k][0]]
    pieces = []
    for frames, size in ((range(n // 2), 1.0), (range(n // 2, n), 1.25), (range(n, 2 * n), 1.55)):
        kf = np.array([k for k in seen if k in frames])
        px = np.array([obs[k][1][0] for k in kf])
        pieces.append(TrackPiece(kf, px, intersect_rays(CAM, poses, kf, px), size))
    groups = fuse_tracks(pieces, CAM, poses, radius_factor=2.0, size_tolerance=0.25, max_error_px=10.0)
    sizes = [[pieces[k].size_m for k in g] for g in groups]
    assert all(2 * (max(s) - min(s)) / (max(s) + min(s)) <= 0.25 for s in sizes), groups
    assert len(groups) == 2  # one pair still fused
    assert fuse_tracks(pieces, CAM, poses, 2.0, 0.5, 10.0) == [[0, 1, 2]]  # within a wider tolerance: one
