"""COLMAP camera models in numpy (`plugin.camera_models`, `geometry.Camera`) against pycolmap's own projection,
and their files: cameras.txt, cameras.bin / models, the database and reconstructions."""

import zlib

import numpy as np
import pytest

from sosmatch.database.cameras import (
    camera_from_pycolmap,
    pycolmap_camera,
    read_cameras_txt,
    write_cameras_txt,
)
from sosmatch.database.colmap_model import read_camera_file
from sosmatch.plugin.camera_models import CAMERA_MODELS
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, pixel_rays, project, quat_to_rotmat

pycolmap = pytest.importorskip("pycolmap")

# Moderate, drone-lens-like distortion for each model (about what COLMAP estimates for real lenses), in order.
EXTRA = {
    "SIMPLE_RADIAL": [-0.1], "RADIAL": [-0.1, 0.02], "OPENCV": [-0.1, 0.02, 0.001, -0.002],
    "OPENCV_FISHEYE": [0.05, -0.01, 0.002, -0.001],
    "FULL_OPENCV": [-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.005, 0.001],
    "FOV": [0.9], "SIMPLE_RADIAL_FISHEYE": [0.05], "RADIAL_FISHEYE": [0.05, -0.01],
    "THIN_PRISM_FISHEYE": [0.05, -0.01, 0.001, -0.001, 0.002, -0.001, 0.001, -0.002],
    "RAD_TAN_THIN_PRISM_FISHEYE": [0.05, -0.01, 0.002, -0.001, 5e-4, -1e-4, 0.001, -0.001, 0.001, -5e-4, 7e-4,
                                   2e-4],
    "SIMPLE_DIVISION": [-0.1], "DIVISION": [-0.1], "EUCM": [0.6, 1.1],
}


def _camera(name: str, width: int = 640, height: int = 480) -> Camera:
    spec = CAMERA_MODELS[name]
    focal = [0.78 * width] if spec.num_focal == 1 else [0.78 * width, 0.79 * width]
    return Camera.from_colmap(name, width, height, focal + [width / 2 + 1.3, height / 2 - 2.1] + EXTRA.get(name, []))


def test_every_model_has_test_parameters():
    assert set(EXTRA) | {n for n, m in CAMERA_MODELS.items() if not m.extra_names} == set(CAMERA_MODELS)
    assert "EQUIRECTANGULAR" not in CAMERA_MODELS


@pytest.mark.parametrize("name", sorted(CAMERA_MODELS))
def test_projection_matches_pycolmap(name):
    cam = _camera(name)
    pc = pycolmap_camera(cam)
    assert pc.model.name == name and np.allclose(pc.params, cam.params)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    uv = rng.uniform([0, 0], [cam.width, cam.height], (400, 2))
    ours = cam.cam_from_img(uv)
    theirs = np.asarray(pc.cam_from_img(uv))
    assert np.all(np.isfinite(ours)) and np.abs(ours - theirs).max() < 1e-9
    assert np.abs(cam.img_from_cam(ours) - uv).max() < 1e-6  # round trip in pixels
    points = np.concatenate([rng.uniform(-0.6, 0.6, (400, 2)), np.ones((400, 1))], 1) * rng.uniform(1, 80, (400, 1))
    assert np.abs(cam.img_from_cam(points) - np.asarray(pc.img_from_cam(points))).max() < 1e-8
    # the equivalent pinhole and back
    pin = cam.undistort_points(uv)
    assert np.abs(pin - cam.pinhole().img_from_cam(theirs)).max() < 1e-6
    assert np.abs(cam.distort_points(pin) - uv).max() < 1e-6


@pytest.mark.parametrize("name", sorted(CAMERA_MODELS))
def test_world_projection_and_rays_go_through_the_model(name):
    cam = _camera(name)
    pc = pycolmap_camera(cam)
    rng = np.random.default_rng(1)
    r_wc = quat_to_rotmat(np.array([0.1, 0.99, 0.05, -0.02]))
    center = np.array([10.0, -5.0, 100.0])
    uv = rng.uniform([0, 0], [cam.width, cam.height], (200, 2))
    rays = pixel_rays(cam, uv, r_wc)
    depth = rng.uniform(50, 150, (200, 1))
    points = center + rays * depth
    back, z = project(cam, r_wc, center, points)
    assert np.allclose(z, depth[:, 0]) and np.abs(back - uv).max() < 1e-6
    p_cam = (points - center) @ r_wc
    assert np.abs(back - np.asarray(pc.img_from_cam(p_cam))).max() < 1e-6


def test_pinhole_models_keep_the_fast_path_and_their_name():
    simple = Camera.from_colmap("SIMPLE_PINHOLE", 640, 480, [500.0, 320.0, 240.0])
    assert simple.is_pinhole and simple.model == "SIMPLE_PINHOLE" and simple.fx == simple.fy == 500.0
    assert Camera.from_colmap("SIMPLE_RADIAL", 640, 480, [500.0, 320.0, 240.0, 0.0]).is_pinhole
    assert not _camera("SIMPLE_RADIAL").is_pinhole
    assert not Camera.from_colmap("SIMPLE_FISHEYE", 640, 480, [500.0, 320.0, 240.0]).is_pinhole  # its own projection
    pin = _camera("OPENCV").pinhole()
    assert pin.model == "PINHOLE" and pin.extra == () and np.allclose(pin.K, _camera("OPENCV").K)
    uv = np.array([[10.0, 20.0], [600.0, 400.0]])
    assert np.array_equal(simple.undistort_points(uv), uv)


def test_invalid_cameras_are_value_errors():
    with pytest.raises(ValueError, match="takes 4 parameters"):
        Camera.from_colmap("SIMPLE_RADIAL", 640, 480, [500.0, 320.0, 240.0])
    with pytest.raises(ValueError, match="one focal length"):
        Camera(640, 480, 500.0, 501.0, 320.0, 240.0, "SIMPLE_RADIAL", (0.1,))
    with pytest.raises(ValueError, match="spherical"):
        Camera.from_colmap("EQUIRECTANGULAR", 640, 480, [640.0, 480.0])


def test_scaled_and_cropped_cameras_see_the_same_rays():
    cam = _camera("OPENCV", 800, 600)
    uv = np.array([[13.0, 17.0], [400.0, 300.0], [790.0, 580.0]])
    half = cam.scaled(0.5)
    assert half.model == "OPENCV" and half.extra == cam.extra
    assert np.allclose(half.cam_from_img(uv * 0.5), cam.cam_from_img(uv), atol=1e-9)
    crop = cam.cropped(0, 75, 800, 450)  # the 16:9 band of a 4:3 sensor
    assert (crop.width, crop.height, crop.cy) == (800, 450, cam.cy - 75)
    assert np.allclose(crop.cam_from_img(uv - [0, 75]), cam.cam_from_img(uv), atol=1e-12)


@pytest.mark.parametrize("model", sorted(CAMERA_MODELS))
def test_a_resized_camera_is_colmaps_rescale_and_sees_the_same_rays(model):
    """`Camera.resized` (a calibration of full-resolution frames fitted to downscaled images:
    `database.cameras.camera_for_images`) is COLMAP's `Camera::Rescale` for every model, and every model's
    distortion acts on normalised coordinates: at a pure scale the same ray lands at s x the pixel."""
    cam = _camera(model)
    for size in ((320, 240), (1280, 960), (321, 240)):  # a half, a double, and a side rounded differently
        ours = cam.resized(*size)
        theirs = pycolmap_camera(cam)
        theirs.rescale(*size)
        assert (ours.width, ours.height) == size and ours.extra == cam.extra
        np.testing.assert_allclose(ours.params, theirs.params, rtol=1e-12)
    half = cam.resized(320, 240)
    rays = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, 1.0], [-0.5, 0.35, 1.0]])
    np.testing.assert_allclose(half.img_from_cam(rays), 0.5 * cam.img_from_cam(rays), rtol=1e-9, atol=1e-9)


def test_covariances_follow_the_lens_to_first_order():
    cam = _camera("OPENCV", 1000, 750)
    rng = np.random.default_rng(3)
    mean = np.array([[930.0, 700.0]])  # near a corner, where the lens bends most
    cov = np.array([[[9.0, 3.0], [3.0, 4.0]]])
    samples = rng.multivariate_normal(mean[0], cov[0], 200_000)
    empirical = np.cov(cam.undistort_points(samples).T)
    predicted = cam.undistort_covariances(mean, cov)[0]
    assert not np.allclose(predicted, cov[0], rtol=0.05)  # the lens does change the shape there
    assert np.allclose(predicted, empirical, rtol=0.02, atol=0.05)


def test_every_model_round_trips_through_cameras_txt_and_cameras_bin(tmp_path):
    cams = {i + 1: _camera(name) for i, name in enumerate(sorted(CAMERA_MODELS))}
    write_cameras_txt(tmp_path / "cameras.txt", cams)
    assert read_cameras_txt(tmp_path / "cameras.txt") == cams
    # COLMAP's own reader agrees with our text file, and our pycolmap reader with COLMAP's binary file
    rec = pycolmap.Reconstruction()
    for cid, cam in cams.items():
        rec.add_camera(pycolmap_camera(cam, cid))
    rec.write_binary(str(tmp_path))
    back = pycolmap.Reconstruction(str(tmp_path))
    for cid, cam in cams.items():
        assert camera_from_pycolmap(back.cameras[cid]) == cam
    one = tmp_path / "one"
    one.mkdir()
    single = pycolmap.Reconstruction()
    single.add_camera(pycolmap_camera(cams[5], 1))
    single.write_binary(str(one))
    assert read_camera_file(one / "cameras.bin") == cams[5]


def test_a_lens_that_folds_the_image_over_is_refused_in_one_line(tmp_path):
    """SIMPLE_RADIAL k = -0.6 at f 377 on 480x360: the radius bends back inside the sensor, so some pixels have
    no ray. Before: `sosmatch map` stopped with a LinAlgError traceback in the tracker; `synth` already refused
    such a lens. Every drone-like lens of every model (EXTRA above) is kept."""
    assert not any(_camera(name).lens_folds() for name in CAMERA_MODELS)
    assert Camera.from_colmap("SIMPLE_RADIAL", 480, 360, [376.7, 240, 180, -0.15]).lens_folds() is False
    path = tmp_path / "cameras.txt"
    path.write_text("1 SIMPLE_RADIAL 480 360 376.7 240 180 -0.6\n")
    with pytest.raises(InputError, match="folds the image over") as err:  # the CLI's one-line user error
        read_cameras_txt(path)
    assert str(err.value).startswith(f"{path}:1:")
