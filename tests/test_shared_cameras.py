"""One camera written once per image (COLMAP's and hloc's default when cameras are not shared) is one camera:
`map --poses MODEL` and `--camera MODEL` take it; cameras that really differ are refused with how many, from
COLMAP models and OpenSfM projects alike (the nu18 sweep: m_percam, odm_twocam)."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest

from sosmatch.database.colmap_model import read_camera_file
from sosmatch.plugin.errors import InputError
from sosmatch.workflows.map import load_inputs

W, H, F = 160, 120, 120.0
NAMES = [f"f{k:03d}.png" for k in range(4)]


def _images(root):
    import cv2

    root.mkdir(parents=True)
    for n in NAMES:
        cv2.imwrite(str(root / n), np.zeros((H, W, 3), np.uint8))
    return root


def _per_image_model(path, focals, text=False):
    """A COLMAP model of a flight looking down, one camera per image with the given focal lengths."""
    rec = pycolmap.Reconstruction()
    down = np.diag([1.0, -1.0, -1.0])  # world_from_camera: optical axis along -z
    for k, (name, f) in enumerate(zip(NAMES, focals), start=1):
        rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=k, model="PINHOLE", width=W, height=H,
                                                        params=[f, f, W / 2, H / 2]))
        r_cw = down.T
        center = np.array([10.0 * k, 0.0, 100.0])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=k, image_id=k),
                                         pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), -r_cw @ center))
    path.mkdir(parents=True)
    rec.write_text(str(path)) if text else rec.write_binary(str(path))
    return path


@pytest.mark.parametrize("text", [False, True])
def test_a_model_with_one_identical_camera_per_image_is_one_camera(tmp_path, text):
    """Before: "holds 4 cameras (images of several sizes or cameras?)": COLMAP's default output refused. A last
    digit changed by a float round trip is still the same camera."""
    images = _images(tmp_path / "images")
    model = _per_image_model(tmp_path / "model", [F, F, F * (1 + 1e-12), F], text)
    inputs = load_inputs(images, model)
    assert (inputs.camera.width, inputs.camera.height, inputs.camera.fx) == (W, H, F)
    assert len(inputs.poses) == 4
    assert read_camera_file(model).fx == F  # the same model given as --camera


def test_cameras_that_really_differ_are_still_refused_and_counted(tmp_path, cli_error):
    images = _images(tmp_path / "images")
    model = _per_image_model(tmp_path / "model", [F, F, F * 1.01, F])
    err = cli_error("map", "--images", images, "--poses", model, "--out", tmp_path / "M")
    assert f"{model}: holds 2 different cameras (of 4" in err and "--camera" in err
    assert not (tmp_path / "M").exists()
    with pytest.raises(InputError, match="found 2 different ones among 4"):
        read_camera_file(model)


def _opensfm_two_cameras(root, second_focal):
    """An OpenSfM project (local frame) whose second half of the shots names a second camera."""
    cam = {"projection_type": "perspective", "width": W, "height": H, "focal": F / W, "k1": 0.0, "k2": 0.0}
    shots = {}
    for k, name in enumerate(NAMES):
        shots[name] = {"rotation": [np.pi, 0.0, 0.0], "translation": [-10.0 * k, 0.0, 100.0],
                       "camera": "a" if k < 2 else "b"}
    rec = [{"cameras": {"a": cam, "b": dict(cam, focal=second_focal / W)}, "shots": shots, "points": {}}]
    (root / "opensfm").mkdir(parents=True)
    (root / "opensfm" / "reconstruction.json").write_text(json.dumps(rec))
    return root


def test_an_opensfm_project_of_two_cameras_says_so(tmp_path, cli_error):
    """Before: two OpenSfM cameras were answered "no camera intrinsics: give --camera"; now as for a COLMAP
    model: two copies of one camera are that camera, two different ones are named."""
    images = _images(tmp_path / "images")
    same = _opensfm_two_cameras(tmp_path / "same", F)
    assert load_inputs(images, same).camera.fx == pytest.approx(F)
    other = _opensfm_two_cameras(tmp_path / "other", F * 1.2)
    err = cli_error("map", "--images", images, "--poses", other, "--out", tmp_path / "M")
    assert f"{other}: holds 2 different cameras (of 2" in err and not (tmp_path / "M").exists()
