"""OpenSfM / OpenDroneMap reconstruction.json: cameras against OpenSfM's own projection formulas, poses from the
topocentric frame into UTM, `poses --opensfm` and `map --poses reconstruction.json`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from sosmatch.database.opensfm import camera_from_opensfm, read_opensfm_reconstruction
from sosmatch.database.poses import read_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import rotation_angle_deg
from sosmatch.tools.cli import main
from sosmatch.workflows.map import load_inputs


def _opensfm_project(cam: dict, xy: np.ndarray, lla=(47.0, 8.0, 400.0)):
    """The OpenSfM pixel (COLMAP convention) of normalised camera points, by OpenSfM's documented formulas."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    kind = cam["projection_type"]
    w, h = cam["width"], cam["height"]
    s = max(w, h)
    if kind == "perspective":
        d = 1 + cam["k1"] * r2 + cam["k2"] * r2**2
        u, v = cam["focal"] * d * x, cam["focal"] * d * y
    elif kind == "brown":
        dr = 1 + cam["k1"] * r2 + cam["k2"] * r2**2 + cam["k3"] * r2**3
        dtx = 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)
        dty = 2 * cam["p2"] * x * y + cam["p1"] * (r2 + 2 * y * y)
        u = cam["focal_x"] * (dr * x + dtx) + cam["c_x"]
        v = cam["focal_y"] * (dr * y + dty) + cam["c_y"]
    else:  # fisheye
        r = np.sqrt(r2)
        theta = np.arctan(r)
        d = 1 + cam["k1"] * theta**2 + cam["k2"] * theta**4
        u, v = cam["focal"] * d * theta * x / r, cam["focal"] * d * theta * y / r
    return np.stack([s * u + w / 2.0, s * v + h / 2.0], 1)


@pytest.mark.parametrize("cam", [
    {"projection_type": "perspective", "width": 4000, "height": 3000, "focal": 0.85, "k1": -0.1, "k2": 0.02},
    {"projection_type": "brown", "width": 5472, "height": 3648, "focal_x": 0.666, "focal_y": 0.667, "c_x": -0.0015,
     "c_y": 0.0047, "k1": -0.264, "k2": 0.102, "p1": 0.0007, "p2": 0.0003, "k3": -0.026},
    {"projection_type": "fisheye", "width": 1920, "height": 1080, "focal": 0.5, "k1": 0.05, "k2": -0.01},
])
def test_cameras_project_as_opensfm_does(cam, tmp_path):
    camera = camera_from_opensfm(cam, "camera", tmp_path / "r.json")
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.4, 0.4, (50, 2))
    np.testing.assert_allclose(camera.img_from_cam(xy), _opensfm_project(cam, xy), atol=1e-6)


def test_unsupported_projection_is_named(tmp_path):
    with pytest.raises(InputError, match="spherical"):
        camera_from_opensfm({"projection_type": "spherical", "width": 10, "height": 5}, "camera 'x'", tmp_path)


def _write_project(tmp_path, names, centers_utm, rotations, epsg, lla):
    """An ODM-style project: opensfm/reconstruction.json (topocentric at lla) + opensfm/reference_lla.json."""
    to_geo = Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4979", always_xy=True)
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    lon, lat, h = to_geo.transform(centers_utm[:, 0], centers_utm[:, 1], centers_utm[:, 2])
    ecef = np.column_stack(to_ecef.transform(lon, lat, h))
    x0 = np.array(to_ecef.transform(lla[1], lla[0], lla[2]))
    la, lo = math.radians(lla[0]), math.radians(lla[1])
    enu_from_ecef = np.array([[-math.sin(lo), math.cos(lo), 0.0],
                              [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                              [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])
    enu = (ecef - x0) @ enu_from_ecef.T
    # rotations: the grid is the topocentric frame turned by the meridian convergence (measured numerically)
    e, n = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform([lla[1], lla[1]],
                                                                                     [lla[0], lla[0] + 1e-4])
    conv = math.atan2(e[1] - e[0], n[1] - n[0])
    topo_from_grid = Rotation.from_euler("z", conv).as_matrix()
    shots = {}
    for name, c, r_wc in zip(names, enu, rotations):
        r_cw = (topo_from_grid @ r_wc).T
        shots[name] = {"rotation": Rotation.from_matrix(r_cw).as_rotvec().tolist(),
                       "translation": (-r_cw @ c).tolist(), "camera": "v2 test 640 480 brown 0.78"}
    cam = {"projection_type": "brown", "width": 320, "height": 240, "focal_x": 0.78, "focal_y": 0.78, "c_x": 0.0,
           "c_y": 0.0, "k1": -0.1, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}
    (tmp_path / "odm" / "opensfm").mkdir(parents=True)
    rec = [{"cameras": {"v2 test 640 480 brown 0.78": cam}, "shots": shots, "points": {}},
           {"cameras": {"v2 test 640 480 brown 0.78": cam}, "shots": dict(list(shots.items())[:2]), "points": {}}]
    (tmp_path / "odm" / "opensfm" / "reconstruction.json").write_text(json.dumps(rec))
    (tmp_path / "odm" / "opensfm" / "reference_lla.json").write_text(
        json.dumps({"latitude": lla[0], "longitude": lla[1], "altitude": lla[2]}))
    return tmp_path / "odm"


# the six-shot flight the ODM projects below hold: UTM zone 32N, topocentric about this point
EPSG, LLA = 32632, (47.0, 8.0, 400.0)


def _six_shot_project(tmp_path):
    """An ODM project of a six-shot flight (and a 2-shot second reconstruction): (project, names, true UTM
    centres, world_from_camera rotations)."""
    from sosmatch.tools.synth.flights import camera_rotation

    e0, n0 = Transformer.from_crs("EPSG:4326", f"EPSG:{EPSG}", always_xy=True).transform(8.001, 47.001)
    names = [f"img_{k:03d}.jpg" for k in range(6)]
    centers = np.array([[e0 + 7.0 * k, n0 + 3.0 * k, 520.0 + k] for k in range(6)])
    rotations = np.stack([camera_rotation(0.3 * k, 0.02, -0.01) for k in range(6)])
    return _write_project(tmp_path, names, centers, rotations, EPSG, LLA), names, centers, rotations


def test_poses_from_an_odm_project_are_in_utm(tmp_path, capsys):
    epsg, lla = EPSG, LLA
    project, names, centers, rotations = _six_shot_project(tmp_path)
    rec = read_opensfm_reconstruction(project)
    assert rec.reference_lla == lla and rec.other_reconstructions == [2] and len(rec.poses) == 6
    images = tmp_path / "images"
    images.mkdir()
    import cv2

    for n in names:  # the originals: twice the size OpenSfM processed
        cv2.imwrite(str(images / n), np.zeros((480, 640, 3), np.uint8))
    assert main(["poses", str(images), "--opensfm", str(project), "--out", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    poses, got_epsg = read_poses_csv(tmp_path / "p" / "poses.csv")
    assert got_epsg == epsg and poses.names == names
    np.testing.assert_allclose(poses.centers, centers, atol=1e-3)
    # (the test turns by the convergence at the origin; the code by the local one: 0.002 deg apart here)
    assert np.max(rotation_angle_deg(poses.rotations, rotations)) < 1e-2
    text = (tmp_path / "p" / "cameras.txt").read_text()
    assert "OPENCV 640 480 499.2" in text  # 0.78 x 640, rescaled to the image files
    assert "1 other reconstruction(s) (sizes 2) ignored" in json.loads((tmp_path / "p" / "poses.json").read_text()
                                                                    )["warnings"]
    inputs = load_inputs(images, project / "opensfm" / "reconstruction.json")
    assert inputs.epsg == epsg and inputs.camera.width == 640 and inputs.camera.model == "OPENCV"
    np.testing.assert_allclose(inputs.poses.centers, centers, atol=1e-3)
    # an imported model's poses are given by either path (rev51 D4: through `poses --opensfm` they were flagged
    # "structure from motion", so match chose another transform for the same poses)
    from sosmatch.database.landmark_map import POSE_SOURCE_GIVEN
    from sosmatch.database.map_loading import recorded_sfm_poses

    assert inputs.pose_source == POSE_SOURCE_GIVEN
    assert load_inputs(images, tmp_path / "p" / "poses.csv").pose_source == POSE_SOURCE_GIVEN
    assert not recorded_sfm_poses({"inputs": {"poses": str(tmp_path / "p" / "poses.csv")}})


def test_damaged_reconstruction_is_a_clear_error(tmp_path):
    p = tmp_path / "reconstruction.json"
    p.write_text('[{"cameras": {"c": {"projection_type": "perspective", "width": 10, "height": 10, "focal": 1}},'
                 ' "shots": {"a.jpg": {"rotation": [0, 0], "translation": [0, 0, 0], "camera": "c"}}}]')
    with pytest.raises(InputError, match="shot 'a.jpg'"):
        read_opensfm_reconstruction(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_opensfm_reconstruction(p)


def _odm2_project(tmp_path, topocentric=True):
    """ODM >= 2 after georeferencing (stages/run_opensfm.py): opensfm/reconstruction.json rewritten by
    `export_geocoords --offset-x/-y` in UTM minus odm_georeferencing/coords.txt (z absolute), the topocentric one kept
    as reconstruction.topocentric.json (dropped when `topocentric` is False, as some archives do). Returns (project,
    names, true UTM centers)."""
    offset = (437000, 5207000)
    project, names, centers, rotations = _six_shot_project(tmp_path)
    osfm = project / "opensfm"
    rec = json.loads((osfm / "reconstruction.json").read_text())
    if topocentric:
        (osfm / "reconstruction.topocentric.json").write_text(json.dumps(rec))
    for shot, c, r_wc in zip(rec[0]["shots"].values(), centers - [*offset, 0.0], rotations):
        shot["rotation"] = Rotation.from_matrix(r_wc.T).as_rotvec().tolist()
        shot["translation"] = (-r_wc.T @ c).tolist()
    (osfm / "reconstruction.json").write_text(json.dumps(rec))
    (project / "odm_georeferencing").mkdir()
    (project / "odm_georeferencing" / "coords.txt").write_text(f"WGS84 UTM 32N\n{offset[0]} {offset[1]}\n")
    return project, names, centers


def test_odm2_project_reads_the_topocentric_reconstruction(tmp_path, caplog):
    from sosmatch.workflows.poses import opensfm_poses

    project, names, centers = _odm2_project(tmp_path)
    for given in (project, project / "opensfm" / "reconstruction.json"):
        caplog.clear()
        with caplog.at_level("INFO", logger="sosmatch"):
            poses, _, _, epsg, info = opensfm_poses(given)
        assert info["source"].endswith("reconstruction.topocentric.json")
        assert any("reconstruction.topocentric.json" in r.getMessage() and r.levelname == "INFO"
                   for r in caplog.records)
        assert epsg == 32632 and poses.names == names
        np.testing.assert_allclose(poses.centers, centers, atol=1e-3)


def test_odm2_geocoords_reconstruction_alone_is_refused(tmp_path, capsys):
    project, _, _ = _odm2_project(tmp_path, topocentric=False)
    with pytest.raises(InputError, match="reconstruction.topocentric.json"):
        read_opensfm_reconstruction(project)
    assert main(["poses", str(tmp_path), "--opensfm", str(project), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "reconstruction.json" in err[0]
    assert not (tmp_path / "p").exists()


def test_smaller_reconstructions_are_named_not_dropped_silently(tmp_path, caplog):
    """The largest reconstruction is read; the others' images would otherwise only count as unposed."""
    project, names, _, _ = _six_shot_project(tmp_path)  # a 6-shot and a 2-shot reconstruction
    images = tmp_path / "images"
    images.mkdir()
    import cv2

    for n in names:
        cv2.imwrite(str(images / n), np.zeros((240, 320, 3), np.uint8))
    with caplog.at_level("WARNING", logger="sosmatch"):
        load_inputs(images, project)
    assert any("1 other reconstruction(s) (sizes 2)" in r.getMessage() and "ignored" in r.getMessage()
               and "reconstruction.json" in r.getMessage() for r in caplog.records)


def test_an_odd_sized_image_of_an_odm_project_is_named(tmp_path):
    """An OpenSfM camera is fitted to the size all its shots' images share, as map's and check-poses' cameras
    (one function): with the first image full size and one other halved, the camera was rescaled to the first
    image and the odd ones left to fail in map, naming the camera size. The first odd one is named, the others
    listed."""
    import cv2

    project, names, _, _ = _six_shot_project(tmp_path)
    images = tmp_path / "images"
    images.mkdir()
    for n in names:
        size = (240, 320, 3) if n in (names[3], names[5]) else (480, 640, 3)
        cv2.imwrite(str(images / n), np.zeros(size, np.uint8))
    with pytest.raises(InputError) as err:
        load_inputs(images, project / "opensfm" / "reconstruction.json")
    text = str(err.value)
    assert text.startswith(f"{images / names[3]}: image is 320x240 (the size of OpenSfM camera 'v2 test 640 480 "
                           f"brown 0.78' in {project / 'opensfm' / 'reconstruction.json'}) but 4 of the 6 images "
                           f"are 640x480; 1 more odd: {names[5]} 320x240: ")
