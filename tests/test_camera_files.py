"""Camera files checked up front (the fiftieth new-user sweep): a principal point off the image, parameters that are
no number, and a calibration of another image size each get one line naming the cameras file and the camera;
a calibration of the full-resolution frames is rescaled to downscaled images, as COLMAP rescales a camera."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from sosmatch.database import cameras as cameras_io
from sosmatch.database.cameras import read_cameras_txt, write_cameras_txt
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera

LENS = Camera(640, 480, 500.0, 505.0, 333.0, 226.0, "OPENCV", (-0.1, 0.02, 1e-3, -1e-3))


@pytest.mark.parametrize("line, fragment", [
    ("1 PINHOLE 320 240 251 251 -50 120", "camera 1: the principal point (-50, 120) lies outside the 320x240 image"),
    # was refused as a distortion that "folds the image over", blaming the right k for the wrong pp
    ("7 SIMPLE_RADIAL 320 240 251 400 120 -0.2", "camera 7: the principal point (400, 120) lies outside"),
    ("1 PINHOLE 320 240 251 251 160 241", "(160, 241) lies outside"),
])
def test_a_principal_point_off_the_image_is_refused_naming_file_and_camera(tmp_path, line, fragment):
    path = tmp_path / "cameras.txt"
    path.write_text(f"# a comment\n{line}\n")
    with pytest.raises(InputError) as err:
        read_cameras_txt(path)
    assert str(err.value).startswith(f"{path}:2: ") and fragment in str(err.value)


def test_a_principal_point_far_off_centre_but_on_the_image_is_kept(tmp_path):
    """A crop's calibration (the corner of a larger frame) has its principal point far from the centre, still on the
    image; the edges themselves are on it in COLMAP's convention (pixels span 0..width)."""
    path = tmp_path / "cameras.txt"
    path.write_text("1 PINHOLE 320 240 251 251 300 20\n2 PINHOLE 320 240 251 251 0 240\n")
    cams = read_cameras_txt(path)
    assert (cams[1].cx, cams[1].cy, cams[2].cx, cams[2].cy) == (300.0, 20.0, 0.0, 240.0)


@pytest.mark.parametrize("line, fragment", [
    ("1 SIMPLE_RADIAL 320 240 nan 160 120 -0.2", "camera 1: the SIMPLE_RADIAL parameter f is nan"),
    ("3 SIMPLE_RADIAL 320 240 251 160 120 nan", "camera 3: the SIMPLE_RADIAL parameter k is nan"),
    ("1 PINHOLE 320 240 251 251 160 inf", "camera 1: the PINHOLE parameter cy is inf"),
    ("1 OPENCV 320 240 251 -inf 160 120 0 0 0 0", "the OPENCV parameter fy is -inf"),
])
def test_a_parameter_that_is_no_number_is_named_with_its_value(tmp_path, line, fragment):
    """Before: "NaN or infinite camera parameter" (which?), and a NaN focal length "camera model SIMPLE_RADIAL has one
    focal length, got fx=nan fy=nan"."""
    path = tmp_path / "cameras.txt"
    path.write_text(line + "\n")
    with pytest.raises(InputError) as err:
        read_cameras_txt(path)
    assert str(err.value).startswith(f"{path}:1: ") and fragment in str(err.value)


@pytest.mark.parametrize("calibrated, images, resize", [
    ((4000, 3000), (1200, 900), True), ((4000, 3000), (1199, 900), True),  # a side floored, not rounded
    ((5472, 3648), (1368, 912), True), ((160, 120), (320, 240), True),
    ((4000, 3000), (1200, 880), False), ((640, 480), (480, 360 - 2), False),  # crops
    ((640, 480), (480, 640), False),
])
def test_a_resize_is_the_same_frame_within_each_sides_rounding(calibrated, images, resize):
    cam = Camera(*calibrated, 1000.0, 1000.0, calibrated[0] / 2, calibrated[1] / 2)
    if resize:
        got = cameras_io.camera_for_images(cam, *images, "c.txt")
        assert (got.width, got.height) == images
    else:
        with pytest.raises(InputError, match="another aspect ratio"):
            cameras_io.camera_for_images(cam, *images, "c.txt")


def test_camera_for_images_rescales_a_resize_and_refuses_a_crop(caplog):
    cam = LENS
    assert cameras_io.camera_for_images(cam, 640, 480, "cameras.txt") is cam
    with caplog.at_level(logging.WARNING):
        half = cameras_io.camera_for_images(cam, 320, 240, "cameras.txt")
    assert half == cam.resized(320, 240) and "rescaled x0.5" in caplog.text and "cameras.txt" in caplog.text
    with pytest.raises(InputError, match="^cameras.txt: the camera is 640x480 but the images are 640x360"):
        cameras_io.camera_for_images(cam, 640, 360, "cameras.txt")
    with pytest.raises(InputError, match="480x640 .turned by 90 degrees"):
        cameras_io.camera_for_images(cam, 480, 640, "cameras.txt")
    # a 320x240 calibration whose size alone was edited to 640x480: its pp a quarter of the frame off the centre is
    # no full frame's, so no rescale is guessed (rescaled, a pinhole's poses were refused for a 39 deg attitude
    # error and a GPS height drift: the errors that blamed GPS and mounting for a pp off the image)
    edited = Camera(640, 480, 251.0, 251.0, 160.0, 120.0, "SIMPLE_RADIAL", (-0.2,))
    with pytest.raises(InputError, match=r"principal point \(160, 120\) 25 % of the frame off its centre"):
        cameras_io.camera_for_images(edited, 320, 240, "cameras.txt")


def _disc_flight(root):
    from sosmatch.tools.toy_sessions import render_disc_flight

    camera = Camera(160, 120, 120.0, 120.0, 80.0, 60.0, "SIMPLE_RADIAL", (-0.1,))
    render_disc_flight(root, camera, frames=4)
    return root, camera


def test_map_inputs_take_a_full_resolution_calibration_for_downscaled_images(tmp_path, caplog):
    """`map --camera` and `check-poses` (both `load_inputs`) met a 640x480 calibration of 320x240 images with "image
    is 320x240 but the camera is 640x480", naming an image deep in the run; OpenSfM's cameras were rescaled. Now one
    function decides for all: rescaled, said once, and recorded."""
    from sosmatch.workflows.map import load_inputs

    root, camera = _disc_flight(tmp_path / "f")
    full = tmp_path / "full.txt"
    write_cameras_txt(full, {1: camera.resized(320, 240)})
    with caplog.at_level(logging.WARNING):
        inputs = load_inputs(root / "images", root / "poses.csv", full)
    assert inputs.camera == camera.resized(320, 240).resized(160, 120)
    np.testing.assert_allclose(inputs.camera.params, camera.params, rtol=1e-12)
    assert inputs.sources["camera_rescaled"] == "320x240 -> 160x120" and f"{full}: the camera is 320x240" in caplog.text
    assert "camera_rescaled" not in load_inputs(root / "images", root / "poses.csv", root / "cameras.txt").sources


@pytest.mark.parametrize("line, fragment", [
    ("1 SIMPLE_RADIAL 160 120 120 -50 60 -0.1", "camera 1: the principal point (-50, 60) lies outside"),
    ("1 SIMPLE_RADIAL 160 120 nan 80 60 -0.1", "camera 1: the SIMPLE_RADIAL parameter f is nan"),
    ("1 SIMPLE_RADIAL 160 100 120 80 50 -0.1", "the camera is 160x100 but the images are 160x120"),
])
@pytest.mark.parametrize("command", ["map", "check-poses"])
def test_map_and_check_poses_refuse_a_bad_camera_file_before_any_work(tmp_path, cli_error, line, fragment,
                                                                      command):
    root, _ = _disc_flight(tmp_path / "f")
    bad = tmp_path / "bad.txt"
    bad.write_text(line + "\n")
    out = tmp_path / ("M" if command == "map" else "check.json")
    err = cli_error(command, "--images", root / "images", "--poses", root / "poses.csv", "--camera", bad,
                    "--out", out)
    assert f"error: {bad}:" in err and fragment in err and not out.exists()


def _resize_images(images, names, size):
    import cv2

    for n in names:
        cv2.imwrite(str(images / n), cv2.resize(cv2.imread(str(images / n)), size, interpolation=cv2.INTER_AREA))


@pytest.mark.parametrize("command", ["map", "check-poses"])
def test_one_odd_sized_image_is_named_not_the_ones_that_match_the_camera(tmp_path, cli_error, command):
    """Only the first image halved (a thumbnail among full frames): the camera was rescaled to the first image's
    size, then every other image (which matched the cameras file) refused, naming one of those (rev39). Now every
    image's size is read and the odd one named against the others and the camera, before any rescale."""
    root, _ = _disc_flight(tmp_path / "f")
    images = root / "images"
    _resize_images(images, ["frame_00000.jpg"], (80, 60))
    out = tmp_path / ("M" if command == "map" else "check.json")
    err = cli_error(command, "--images", images, "--poses", root / "poses.csv", "--camera", root / "cameras.txt",
                    "--out", out)
    assert (f"error: {images / 'frame_00000.jpg'}: image is 80x60 but 3 of the 4 images are 160x120 (the size of "
            f"the camera in {root / 'cameras.txt'})") in err
    assert "rescaled" not in err and not out.exists()


def test_an_odd_image_matching_the_camera_is_named_as_such(tmp_path):
    """Images downscaled but one left at the calibrated size: no rescale to either size; the odd image is named,
    saying the camera has its size."""
    from sosmatch.workflows.map import load_inputs

    root, camera = _disc_flight(tmp_path / "f")
    images = root / "images"
    _resize_images(images, ["frame_00000.jpg", "frame_00001.jpg", "frame_00003.jpg"], (80, 60))
    with pytest.raises(InputError) as err:
        load_inputs(images, root / "poses.csv", root / "cameras.txt")
    assert str(err.value).startswith(f"{images / 'frame_00002.jpg'}: image is 160x120 (the size of the camera "
                                     f"in {root / 'cameras.txt'}) but 3 of the 4 images are 80x60: ")
    # all downscaled alike: the one size they share is the camera's frame resized, so rescaled
    _resize_images(images, ["frame_00002.jpg"], (80, 60))
    assert load_inputs(images, root / "poses.csv", root / "cameras.txt").camera == camera.resized(80, 60)
