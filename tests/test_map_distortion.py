"""Mapping distorted images with their real lens model: the database and the model keep the real camera and the
real keypoints, tracking runs on undistorted centroids, and the map is as good as with an ideal lens."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.cameras import write_cameras_txt
from sosmatch.database.landmark_map import read_landmark_map
from sosmatch.database.poses import write_poses_csv
from sosmatch.plugin.geometry import Camera, Poses, pixel_rays
from sosmatch.plugin.params import Params
from sosmatch.workflows import map as map_workflow

pycolmap = pytest.importorskip("pycolmap")

WIDTH, HEIGHT, ALTITUDE, FRAMES = 320, 240, 60.0, 25
PINHOLE = Camera(WIDTH, HEIGHT, 0.8 * WIDTH, 0.8 * WIDTH, WIDTH / 2, HEIGHT / 2)
# strong barrel distortion: 9 px at the image corners of a 320 px frame (k1 = -0.1 at ~0.6 normalised radius)
LENS = Camera(WIDTH, HEIGHT, 0.8 * WIDTH, 0.8 * WIDTH, WIDTH / 2, HEIGHT / 2, "OPENCV", (-0.1, 0.01, 0.0005, -0.0005))


def render(root: Path, camera: Camera, seed: int = 0) -> np.ndarray:
    """Nadir flight over a flat field with coloured discs, imaged through `camera`'s lens (every pixel's ray meets
    the ground plane z = 0 and samples a 0.1 m orthophoto). Writes images/, poses.csv, cameras.txt; returns the
    discs (x, y, radius)."""
    rng = np.random.default_rng(seed)
    gsd, x0, x1, y0, y1 = 0.1, -45.0, FRAMES * 2.0 + 45.0, -40.0, 40.0
    w, h = int((x1 - x0) / gsd), int((y1 - y0) / gsd)
    noise = cv2.GaussianBlur(rng.normal(0, 25, (h, w, 3)), (0, 0), 2)
    ortho = np.clip(rng.integers(70, 110, 3) + noise, 0, 255).astype(np.uint8)
    objs = np.stack([rng.uniform(x0 + 12, x1 - 12, 40), rng.uniform(y0 + 10, y1 - 10, 40), rng.uniform(1.5, 4, 40)], 1)
    for x, y, r in objs:
        color = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(ortho, (int((x - x0) / gsd), int((y1 - y) / gsd)), int(r / gsd), color, -1, cv2.LINE_AA)
    ortho = cv2.GaussianBlur(ortho, (0, 0), 1.0)  # the image pixel is ~2.3 ortho pixels: low-pass before sampling
    centers = np.stack([np.arange(FRAMES) * 2.0, np.zeros(FRAMES), np.full(FRAMES, ALTITUDE)], 1)
    names = [f"frame_{i:05d}.jpg" for i in range(FRAMES)]
    r_wc = np.diag([1.0, -1.0, -1.0])
    jj, ii = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    pixels = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], 1)
    rays = pixel_rays(camera, pixels, r_wc)
    (root / "images").mkdir(parents=True)
    for name, c in zip(names, centers):
        ground = c + rays * (-c[2] / rays[:, 2:3])
        map_x = ((ground[:, 0] - x0) / gsd - 0.5).reshape(HEIGHT, WIDTH).astype(np.float32)
        map_y = ((y1 - ground[:, 1]) / gsd - 0.5).reshape(HEIGHT, WIDTH).astype(np.float32)
        img = cv2.remap(ortho, map_x, map_y, cv2.INTER_LINEAR)
        cv2.imwrite(str(root / "images" / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    write_poses_csv(root / "poses.csv", Poses(names, np.repeat(r_wc[None], FRAMES, 0), centers))
    write_cameras_txt(root / "cameras.txt", {1: camera})
    return objs


def _map(root: Path, out: Path, camera_file: Path):
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", camera_file)
    map_workflow.run(Params(), inputs, out, progress=False)
    return read_landmark_map(out / "landmarks.sosmap")


def _horizontal_errors(positions: np.ndarray, objs: np.ndarray) -> np.ndarray:
    return np.linalg.norm(positions[:, None, :2] - objs[None, :, :2], axis=2).min(1)


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    root = tmp_path_factory.mktemp("lens")
    objs = render(root / "ideal", PINHOLE)
    assert np.array_equal(render(root / "distorted", LENS), objs)
    ideal = _map(root / "ideal", root / "ideal_map", root / "ideal" / "cameras.txt")
    lens = _map(root / "distorted", root / "lens_map", root / "distorted" / "cameras.txt")
    write_cameras_txt(root / "pinhole.txt", {1: PINHOLE})
    ignored = _map(root / "distorted", root / "ignored_map", root / "pinhole.txt")
    return root, objs, ideal, lens, ignored


def test_distorted_images_map_as_well_as_ideal_ones(mapped):
    root, objs, ideal_map, lens_map, ignored_map = mapped
    ideal, lens, ignored = ideal_map.positions, lens_map.positions, ignored_map.positions
    e_ideal, e_lens, e_ignored = (_horizontal_errors(p, objs) for p in (ideal, lens, ignored))
    assert len(lens) >= 0.8 * len(ideal) >= 8
    assert np.median(e_lens) <= max(1.25 * np.median(e_ideal), np.median(e_ideal) + 0.1)
    assert np.median(np.abs(lens[:, 2])) < 1.5  # on the ground
    # the same images taken for an ideal lens: the lens bends the rays and the map pays for it
    assert np.median(e_ignored) > np.median(e_lens) or len(ignored) < 0.8 * len(lens)


def test_database_and_model_keep_the_real_camera_and_keypoints(mapped):
    root = mapped[0]
    out = root / "lens_map"
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    (cam,) = rec.cameras.values()
    assert cam.model.name == "OPENCV" and np.allclose(cam.params, LENS.params)
    db = pycolmap.Database.open(str(out / "database.db"))
    try:
        (db_cam,) = db.read_all_cameras()
        assert db_cam.model.name == "OPENCV" and np.allclose(db_cam.params, LENS.params)
        # the real keypoints: each landmark reprojects through the real lens onto its (distorted) keypoints
        errors = []
        for point in rec.points3D.values():
            for el in point.track.elements:
                image = rec.images[el.image_id]
                kp = db.read_keypoints(el.image_id)[el.point2D_idx, :2]
                uv = cam.img_from_cam(image.cam_from_world() * point.xyz)
                errors.append(np.linalg.norm(uv - kp))
        assert np.median(errors) < 3.0
    finally:
        db.close()
    run = json.loads((out / "run.json").read_text())
    assert run["camera"]["model"] == "OPENCV" and run["camera"]["params"] == LENS.params


def test_metric_sizes_stay_right_through_the_lens(mapped):
    """Sizes come from the undistorted covariances: a landmark of the distorted flight has the size of the same
    landmark of the ideal flight (barrel distortion shrinks objects near the border by up to ~10 % in pixels)."""
    from scipy.spatial import cKDTree

    _, _, ideal, lens, _ = mapped
    d, j = cKDTree(ideal.positions[:, :2]).query(lens.positions[:, :2])
    same = d < 0.5
    assert np.count_nonzero(same) >= 10
    ratio = lens.sizes[same].astype(float) / ideal.sizes[j[same]].astype(float)
    assert abs(np.median(ratio) - 1.0) < 0.05, np.median(ratio)
