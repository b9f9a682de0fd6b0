"""Fixed-pose triangulation through pycolmap, the landmark filters, metric sizes, and COLMAP model I/O."""

import numpy as np
import pytest

from sosmatch.database.colmap_db import affine_keypoints, track_associations, write_colmap_database
from sosmatch.database.colmap_model import (
    encode_ply,
    read_camera_file,
    read_colmap_model_poses,
    write_model,
)
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, Poses, project
from sosmatch.plugin.landmark_size import cut_by_border
from sosmatch.plugin.params import TriangulationParams
from sosmatch.workflows.triangulation import build_reconstruction, triangulate_landmarks

pycolmap = pytest.importorskip("pycolmap")
pycolmap.logging.minloglevel = 2
OBJECT_SIZE_M = 2.0


def scene(n_frames=30, n_points=100, noise_px=3.0, seed=0):
    """Nadir flight at 100 m, 2 m between keyframes; tracks = true point ids; mask size of a 2 m object."""
    rng = np.random.default_rng(seed)
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r_wc = np.diag([1.0, -1.0, -1.0])
    centers = np.stack([np.arange(n_frames) * 2.0, rng.normal(0, 1, n_frames), np.full(n_frames, 100.0)], 1)
    poses = Poses([f"f{i:03d}.jpg" for i in range(n_frames)], np.repeat(r_wc[None], n_frames, 0), centers)
    pts = np.stack([rng.uniform(-30, 2 * n_frames + 30, n_points), rng.uniform(-40, 40, n_points),
                    rng.uniform(0, 10, n_points)], 1)
    cents, tids, sizes = [], [], []
    for k in range(n_frames):
        uv, d = project(cam, r_wc, centers[k], pts)
        vis = np.flatnonzero((uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (d > 0))
        perm = rng.permutation(vis)
        cents.append(uv[perm] + rng.normal(0, noise_px, (len(perm), 2)))
        tids.append(perm.astype(np.int64))
        sizes.append(OBJECT_SIZE_M * cam.fx / d[perm])
    return cam, poses, pts, cents, tids, sizes


def run(tmp_path, cam, poses, cents, tids, sizes, params=None, mode="all"):
    # the scene's points are random, many closer than their footprints (size 2 m = 8 m across), so duplicate
    # suppression is off here (tests/test_landmark_fusion.py covers it)
    params = params or TriangulationParams(duplicate_radius_factor=0.0)
    kps = [affine_keypoints(c, np.repeat(np.eye(2)[None] * 9, len(c), 0)) for c in cents]
    pairs = track_associations(tids, mode, params.min_observations)
    write_colmap_database(tmp_path / "database.db", cam, poses.names, kps, pairs)
    return triangulate_landmarks(tmp_path / "database.db", cam, poses, sizes, tids, params)


def test_landmarks_are_accurate_ordered_and_sized(tmp_path):
    cam, poses, pts, cents, tids, sizes = scene()
    lm = run(tmp_path, cam, poses, cents, tids, sizes)
    seen = np.bincount(np.concatenate(tids), minlength=len(pts))
    assert len(lm) >= 0.9 * np.count_nonzero(seen > 5)
    assert np.all(lm.num_observations > 5) and np.all(np.diff(lm.track_ids) > 0)  # map order = track order
    err = lm.positions - pts[lm.track_ids]
    assert np.median(np.linalg.norm(err[:, :2], axis=1)) < 0.5 and np.median(np.abs(err[:, 2])) < 1.5
    assert abs(np.median(lm.sizes_m) - OBJECT_SIZE_M) < 0.1
    assert np.all(lm.errors_px <= TriangulationParams().max_reprojection_error_px)
    # Observations are (keyframe, mask) rows that really belong to the landmark's track.
    for t, obs in zip(lm.track_ids, lm.observations):
        assert all(tids[k][i] == t for k, i in obs)
    rec = lm.reconstruction
    assert set(rec.point3D_ids()) == set(lm.point3d_ids.tolist())
    assert lm.counts["kept"] == len(lm)


def test_consecutive_links_also_triangulate(tmp_path):
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    lm = run(tmp_path, cam, poses, cents, tids, sizes, mode="consecutive")
    assert len(lm) > 20
    assert np.median(np.linalg.norm(lm.positions - pts[lm.track_ids], axis=1)) < 0.5


def test_short_tracks_and_small_angles_are_dropped(tmp_path):
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    strict = TriangulationParams(min_observations=20)
    lm = run(tmp_path, cam, poses, cents, tids, sizes, params=strict)
    assert len(lm) > 0 and np.all(lm.num_observations > 20)
    wide = TriangulationParams(min_triangulation_angle_deg=60.0)  # more than any ray pair here spans
    kps = [affine_keypoints(c, np.repeat(np.eye(2)[None], len(c), 0)) for c in cents]
    write_colmap_database(tmp_path / "d2.db", cam, poses.names, kps, track_associations(tids, "all", 5))
    none = triangulate_landmarks(tmp_path / "d2.db", cam, poses, sizes, tids, wide)
    assert len(none) == 0 and none.reconstruction.num_points3D() == 0


def test_wrong_track_is_not_a_landmark_at_its_false_position(tmp_path):
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    # Corrupt: in the second half of the flight, point A's observations take point B's track id.
    counts = np.bincount(np.concatenate(tids))
    a, b = np.argsort(counts)[-2:]
    for k in range(15, len(tids)):
        ids = tids[k]
        if a in ids and b not in ids:
            ids[ids == a] = b
    lm = run(tmp_path, cam, poses, cents, tids, sizes)
    err = np.linalg.norm(lm.positions - pts[lm.track_ids], axis=1)
    # The merged track either splits into two correct points or is dropped; it never averages into a bad one.
    bad = err > 3.0
    assert not np.any(bad & np.isin(lm.track_ids, [b])) or np.all(
        np.min(np.linalg.norm(lm.positions[bad][:, None] - pts[[a, b]][None], axis=2), 1) < 3.0)


def test_model_write_and_pose_read_back(tmp_path):
    cam, poses, *_ = scene(n_frames=5, n_points=10)
    rec = build_reconstruction(cam, poses)
    for text in (False, True):
        d = tmp_path / ("text" if text else "bin")
        write_model(rec, d, text=text)
        back, cameras, cam_of = read_colmap_model_poses(d / ("images.txt" if text else "images.bin"))
        assert back.names == poses.names and set(cam_of.values()) == {1}
        assert np.allclose(back.centers, poses.centers) and np.allclose(back.rotations, poses.rotations)
        assert read_camera_file(d) == cam
    # A pose-only text export (no points3D.txt) is read by our own parser.
    (tmp_path / "text" / "points3D.txt").unlink()
    back, _, _ = read_colmap_model_poses(tmp_path / "text")
    assert np.allclose(back.centers, poses.centers)


@pytest.mark.parametrize("edit, fragment", [
    (lambda f: f.replace("\n2 ", "\n2 nan-x ", 1), "non-numeric"),
    (lambda f: f.replace("\n2 0", "\n2 3", 1), "unit length"),
])
def test_bad_images_txt_names_file_and_line(tmp_path, edit, fragment):
    cam, poses, *_ = scene(n_frames=3, n_points=5)
    write_model(build_reconstruction(cam, poses), tmp_path / "m", text=True)
    (tmp_path / "m" / "points3D.txt").unlink()
    images = tmp_path / "m" / "images.txt"
    images.write_text(edit(images.read_text()))
    with pytest.raises(InputError, match=fragment) as exc:
        read_colmap_model_poses(tmp_path / "m")
    assert str(exc.value).startswith(f"{images}:")


def test_ply_is_float32_local_with_origin_comment():
    origin = np.array([500000.0, 6000000.0, 50.0])
    data = encode_ply(np.array([[1.25, -2.5, 3.0]]), np.array([1.5]), origin, epsg=32633)
    header, _, body = data.partition(b"end_header\n")
    assert b"element vertex 1" in header and b"comment origin 500000.0 6000000.0 50.0" in header
    assert b"EPSG:32633" in header
    assert np.allclose(np.frombuffer(body, "<f4"), [1.25, -2.5, 3.0, 1.5])


def observe_wrong_tracks(cam, poses, pts, cents, tids, sizes, below):
    """Add consistent observations of points `below` the scene to its keyframes (their centroids, track ids after
    the scene's, sizes): what a wrong track along a straight flight line triangulates to. Returns their ids."""
    ids = len(pts) + np.arange(len(below))
    for k in range(len(poses)):
        uv, d = project(cam, poses.rotations[k], poses.centers[k], below)
        vis = (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (d > 0)
        cents[k] = np.vstack([cents[k], uv[vis]])
        tids[k] = np.concatenate([tids[k], ids[vis]])
        sizes[k] = np.concatenate([sizes[k], OBJECT_SIZE_M * cam.fx / d[vis]])
    return ids


def test_wrong_tracks_far_below_the_ground_are_dropped_as_height_outliers(tmp_path):
    # consistent observations of "objects" 45-60 m below a 0-10 m high scene: what a wrong track along a straight
    # flight line triangulates to; they pass every per-point check and only the neighbours' heights betray them
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    # (within one flying height of the ground: farther ones are dropped always, `beyond_flying_height`)
    below = np.array([[20.0, 5.0, -60.0], [40.0, -10.0, -45.0]])
    ids = observe_wrong_tracks(cam, poses, pts, cents, tids, sizes, below)
    off = run(tmp_path / "off", cam, poses, cents, tids, sizes)
    assert set(ids) <= set(off.track_ids.tolist())  # without the filter they are landmarks
    params = TriangulationParams(duplicate_radius_factor=0.0, height_outlier_sigmas=6.0)
    on = run(tmp_path / "on", cam, poses, cents, tids, sizes, params)
    assert not set(ids) & set(on.track_ids.tolist())
    assert on.counts["dropped_height_outlier"] == len(off) - len(on) >= len(ids)
    assert len(on) >= len(off) - len(ids) - 2  # the scene's own landmarks stay (at most a stray one or two)
    assert set(on.reconstruction.point3D_ids()) == set(on.point3d_ids.tolist())


def test_wrong_tracks_a_flying_height_below_the_ground_are_dropped_always(tmp_path):
    """The eleventh sweep: with the spread-sized filter off (the default) wrong tracks 290-644 m under a 100 m
    flight stayed landmarks and the map said ok. A whole flying height off the ground is impossible: dropped."""
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    below = np.array([[20.0, 5.0, -300.0], [40.0, -10.0, -250.0]])
    ids = observe_wrong_tracks(cam, poses, pts, cents, tids, sizes, below)
    out = run(tmp_path, cam, poses, cents, tids, sizes)  # height_outlier_sigmas 0: the spread filter is off
    assert not set(ids) & set(out.track_ids.tolist())
    assert out.counts["dropped_beyond_flying_height"] == len(ids) and out.counts["dropped_height_outlier"] == 0
    assert set(out.reconstruction.point3D_ids()) == set(out.point3d_ids.tolist())


def _text_model(tmp_path, complete):
    cam, poses, *_ = scene(n_frames=4, n_points=5)
    d = tmp_path / ("complete" if complete else "pose-only")
    write_model(build_reconstruction(cam, poses), d, text=True)
    if not complete:
        (d / "points3D.txt").unlink()
    return d, poses


@pytest.mark.parametrize("complete", [False, True])
def test_images_txt_without_points2d_lines_is_refused_saying_so(tmp_path, complete):
    """An images.txt with one line per image (no POINTS2D line after each): before, a pose-only model read every
    second image line as the POINTS2D line of the one before (half the frames, 'skipping 2 image(s) without a
    pose'), and a complete one was called 'truncated or edited'."""
    d, _ = _text_model(tmp_path, complete)
    images = d / "images.txt"
    lines = images.read_text().splitlines(keepends=True)
    images.write_text("".join(line for line in lines if line.strip()))  # the (empty) POINTS2D lines dropped
    with pytest.raises(InputError, match=r"needs a POINTS2D line \(empty is fine\) after every image line") as exc:
        read_colmap_model_poses(d)
    first = next(k for k, line in enumerate(lines, 1) if line.startswith("1 "))
    assert str(exc.value).startswith(f"{images}:{first + 1}: ")


@pytest.mark.parametrize("complete", [False, True])
def test_images_txt_with_blank_lines_between_records_reads_as_colmap_does(tmp_path, complete):
    """COLMAP (3.8 and pycolmap 4) skip blank and white-space lines where an image line is due, while the line
    right after an image line is its POINTS2D line even when empty. Before, a complete model with blank lines
    between its records was refused as 'holds 6 records but 4: truncated or edited'."""
    d, poses = _text_model(tmp_path, complete)
    images = d / "images.txt"
    lines = images.read_text().splitlines(keepends=True)
    spaced = []
    for k, line in enumerate(lines):
        spaced.append(line)
        if not line.startswith("#") and k > 0 and not lines[k - 1].startswith("#") and not line[:1].isdigit():
            spaced.append("\n \t\n")  # after each POINTS2D line: blank and white-space lines
    assert "".join(spaced).count("\n\n") >= len(poses.names)
    images.write_text("".join(spaced))
    back, _, _ = read_colmap_model_poses(d)
    assert back.names == poses.names and np.allclose(back.centers, poses.centers)
    # a comment where a POINTS2D line is due is refused (COLMAP fails there), not skipped: skipping it read the
    # next image line as the POINTS2D line
    first = next(k for k, line in enumerate(spaced) if line.startswith("1 "))
    images.write_text("".join(spaced[:first + 1] + ["# a note\n"] + spaced[first + 1:]))
    with pytest.raises(InputError, match=r"POINTS2D") as exc:
        read_colmap_model_poses(d)
    assert str(exc.value).startswith(f"{images}:{first + 2}: ")
    if complete:  # cut right after the last image line: pycolmap drops that image without a word
        last = max(k for k, line in enumerate(spaced) if line[:1].isdigit())
        images.write_text("".join(spaced[:last + 1]))
        with pytest.raises(InputError, match="ends with an image line without its POINTS2D line"):
            read_colmap_model_poses(d)


def clipped_disc(cam, r_wc, center, middle, radius_m, n=4000):
    """Centroid and pixel covariance of the part inside the image of a ground disc (what a segmenter returns
    for an object the frame cuts)."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rad = radius_m * np.sqrt((np.arange(n) + 0.5) / n)  # a sunflower disc: uniform area sampling
    pts = middle[None] + np.stack([rad * np.cos(ang * 137.508), rad * np.sin(ang * 137.508), np.zeros(n)], 1)
    uv, _ = project(cam, r_wc, center, pts)
    uv = uv[(uv[:, 0] > 0) & (uv[:, 0] < cam.width) & (uv[:, 1] > 0) & (uv[:, 1] < cam.height)]
    if len(uv) < 3:
        return np.full(2, np.nan), np.full((2, 2), np.nan)
    return uv.mean(0), np.cov(uv.T)


def test_masks_cut_by_the_image_border_do_not_locate_the_landmark(tmp_path):
    """An object entering the frame is cut by its border: the visible part's centroid slides with the camera, so
    triangulated with the whole views it lands metres below the ground (nu22: 2 m keyframes, 12 % of landmarks
    > 5 m below). The whole views locate it (`located_from_whole_masks`); the cut ones stay in its track."""
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r_wc = np.diag([1.0, -1.0, -1.0])
    n = 40
    centers = np.stack([np.arange(n) * 2.0, np.zeros(n), np.full(n, 100.0)], 1)
    poses = Poses([f"f{i:03d}.jpg" for i in range(n)], np.repeat(r_wc[None], n, 0), centers)
    middle = np.array([100.0, 0.0, 0.0])  # a disc of 20 m radius (100 px) entering the frame during the flight
    cents, covs, tids, sizes = [], [], [], []
    for k in range(n):
        c, cov = clipped_disc(cam, r_wc, centers[k], middle, 20.0)
        seen = int(np.isfinite(cov).all() and c[0] < cam.width - 20)  # a sliver at the border is no mask
        cents.append(c[None][:seen])
        covs.append(cov[None][:seen])
        tids.append(np.zeros(seen, np.int64))
        sizes.append(np.sqrt(np.linalg.eigvalsh(cov[None][:seen])[:, -1]))
    kps = [affine_keypoints(c, v) for c, v in zip(cents, covs)]
    write_colmap_database(tmp_path / "d.db", cam, poses.names, kps, track_associations(tids, "all", 5))

    def landmark(whole_masks_only):
        params = TriangulationParams(duplicate_radius_factor=0.0, fuse_radius_factor=0.0,
                                     whole_masks_only=whole_masks_only)
        lm = triangulate_landmarks(tmp_path / "d.db", cam, poses, sizes, tids, params, centroids_px=cents,
                                   covariances_px=covs)
        assert len(lm) == 1
        point = lm.reconstruction.points3D[int(lm.point3d_ids[0])]
        assert np.allclose(point.xyz, lm.positions[0])  # sparse/ holds the landmark where the map has it
        assert point.error == lm.errors_px[0]  # and its error
        return lm.positions[0], lm.num_observations[0], lm.errors_px[0]

    (x_all, n_all, _), (x_whole, n_whole, e_whole) = landmark(False), landmark(True)
    # the error of the moved landmark is its position's over the views that locate it (the whole ones), not the
    # bundle-adjusted point's over all views, which stayed recorded
    obs = [(k, 0) for k in range(n) if len(cents[k])]
    pix = np.array([cents[k][0] for k, _ in obs])
    cut = cut_by_border(cam, pix, np.array([covs[k][0] for k, _ in obs]))
    reproj = np.array([np.linalg.norm(project(cam, r_wc, centers[k], x_whole[None])[0][0] - p)
                       for (k, _), p in zip(obs, pix)])
    assert cut.sum() > 3 and e_whole == pytest.approx(reproj[~cut].mean(), abs=1e-3)  # keypoints: float32
    assert e_whole < 1.0 < reproj[cut].mean()
    assert x_all[2] < -10.0 and np.linalg.norm(x_all[:2] - middle[:2]) > 5.0  # what this guards against: -35 m
    assert abs(x_whole[2]) < 0.5 and np.linalg.norm(x_whole[:2] - middle[:2]) < 0.5
    assert n_whole == n_all  # the cut views are still observations of the landmark


def two_view_pieces(tids, per_piece=2):
    """Track ids with every track split into pieces of `per_piece` observations that never share a keyframe and
    span the track (piece j: observations j, j + m, ...; m = pieces), each piece with its own id; a landmark's
    piece ids are its point id x 1000 + j."""
    seen = {}
    for k, ids in enumerate(tids):
        for i, t in enumerate(ids):
            seen.setdefault(int(t), []).append((k, i))
    out = [np.full(len(ids), -1, np.int64) for ids in tids]
    for t, rows in seen.items():
        m = len(rows) // per_piece
        for j in range(m):
            for k, i in rows[j:m * per_piece:m]:
                out[k][i] = t * 1000 + j
    return out


def test_two_view_tracks_are_triangulated_where_the_parameters_admit_them(tmp_path):
    """theta_n = 1 makes a two-view track a landmark and min_piece_observations = 2 makes it a piece that fusion
    joins with the object's other pieces (both documented; both were accepted and ignored: pycolmap skipped
    every two-view track)."""
    cam, poses, pts, cents, tids, sizes = scene(noise_px=1.0)
    kps = [affine_keypoints(c, np.repeat(np.eye(2)[None] * 9, len(c), 0)) for c in cents]
    split = two_view_pieces(tids)
    write_colmap_database(tmp_path / "d.db", cam, poses.names, kps, track_associations(split, "all", 1))

    def landmarks(**kw):
        params = TriangulationParams(duplicate_radius_factor=0.0, **kw)
        return triangulate_landmarks(tmp_path / "d.db", cam, poses, sizes, split, params)

    pairs = landmarks(min_observations=1, fuse_radius_factor=0.0)  # every piece a landmark of two views
    assert len(pairs) > 100 and np.all(pairs.num_observations == 2)
    assert np.median(np.linalg.norm(pairs.positions - pts[pairs.track_ids // 1000], axis=1)) < 2.0
    fused = landmarks(min_observations=5, min_piece_observations=2)  # the pieces of an object fused into one
    assert len(fused) > 20 and np.all(fused.num_observations > 5)
    assert np.median(np.linalg.norm(fused.positions - pts[fused.track_ids // 1000], axis=1)) < 0.5
    assert len(landmarks(min_observations=5)) == 0  # pieces of 3 observations (the default): none here
