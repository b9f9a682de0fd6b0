"""`sosmatch synth` through a lens with distortion and a 16:9 crop of a 4:3 sensor: the camera file, the pixels,
the labels and the footprints all follow the same lens model."""

import json

import cv2
import numpy as np
import pytest

from sosmatch.database.synth_session import load_synth_session
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import project
from sosmatch.tools.cli import main
from sosmatch.workflows.synth import SynthConfig, run

# test_synth's small world (the test-wide world cache, tests/conftest.py, makes it cheap), fewer frames
SMALL = dict(world_seed=3, world_size_m=240.0, frames=6, spacing_m=8.0, width=320, height=240,
             line_length_m=40.0, line_spacing_m=25.0)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("lens")
    run(root / "ideal", SynthConfig(**SMALL))
    run(root / "lens", SynthConfig(**SMALL, lens_k1=-0.1, crop_aspect="16:9"))
    run(root / "opencv", SynthConfig(**SMALL, lens_k1=-0.08, lens_k2=0.01, lens_p1=0.001, lens_p2=-0.001))
    return {k: load_synth_session(root / k) for k in ("ideal", "lens", "opencv")}


def test_cameras_file_holds_the_lens_and_the_crop(sessions):
    lens, opencv, ideal = sessions["lens"].camera, sessions["opencv"].camera, sessions["ideal"].camera
    assert ideal.model == "PINHOLE"
    assert lens.model == "SIMPLE_RADIAL" and lens.extra == (-0.1,)
    assert (lens.width, lens.height) == (320, 180) and lens.fx == ideal.fx and lens.cy == 90.0
    assert opencv.model == "OPENCV" and opencv.extra == (-0.08, 0.01, 0.001, -0.001)
    meta = json.loads((sessions["lens"].path / "session.json").read_text())["camera"]
    assert meta["sensor"] == [320, 240] and meta["params"] == lens.params
    labels = cv2.imread(str(sessions["lens"].label_path(sessions["lens"].frames[0]["name"])), cv2.IMREAD_UNCHANGED)
    assert labels.shape == (180, 320)


@pytest.mark.parametrize("name", ["lens", "opencv"])
def test_pixels_see_what_the_ideal_lens_sees_through_the_model(sessions, name):
    """Each distorted pixel shows what the ideal camera shows at the undistorted position (same flight, same
    world): labels agree almost everywhere, which fails if the renderer ignored or inverted the distortion."""
    ideal, lens = sessions["ideal"], sessions[name]
    h, w = lens.camera.height, lens.camera.width
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pixels = np.stack([jj.ravel(), ii.ravel()], 1)
    # the same ray in the uncropped ideal image: undistort, then undo the crop's shift of the principal point
    q = lens.camera.undistort_points(pixels) + [ideal.camera.cx - lens.camera.cx, ideal.camera.cy - lens.camera.cy]
    inside = (q[:, 0] >= 1) & (q[:, 0] < ideal.camera.width - 1) & (q[:, 1] >= 1) & (q[:, 1] < ideal.camera.height - 1)
    moved = np.abs(q - pixels - [0, ideal.camera.cy - lens.camera.cy]).max()
    assert moved > 3.0  # the lens really moves pixels (by more than the label boundary tolerance)
    agree_lens, agree_naive = [], []
    for fi, fl in zip(ideal.frames, lens.frames):
        li = cv2.imread(str(ideal.label_path(fi["name"])), cv2.IMREAD_UNCHANGED)
        ll = cv2.imread(str(lens.label_path(fl["name"])), cv2.IMREAD_UNCHANGED).ravel()
        through = li[q[inside, 1].astype(int), q[inside, 0].astype(int)]
        naive = li[(pixels[inside, 1] + ideal.camera.cy - lens.camera.cy).astype(int), pixels[inside, 0].astype(int)]
        objects = (through > 0) | (ll[inside] > 0)
        agree_lens.append(np.mean(through[objects] == ll[inside][objects]))
        agree_naive.append(np.mean(naive[objects] == ll[inside][objects]))
    assert np.mean(agree_lens) > 0.9 and np.mean(agree_lens) > np.mean(agree_naive) + 0.05, (agree_lens, agree_naive)


def test_footprints_follow_the_bent_border(sessions):
    s = sessions["lens"]
    for i, f in enumerate(s.frames):
        fp = np.array(f["footprint"])
        assert fp.shape == (32, 2)  # 8 points per side: the border's rays bend
        pts = np.column_stack([fp, s.terrain.height_at(fp[:, 0], fp[:, 1])])
        uv, depth = project(s.camera, s.poses.rotations[i], s.poses.centers[i], pts)
        assert np.all(depth > 0)
        on_border = np.minimum(np.minimum(uv[:, 0], s.camera.width - uv[:, 0]),
                               np.minimum(uv[:, 1], s.camera.height - uv[:, 1]))
        assert np.abs(on_border).max() < 0.05
    assert np.array(sessions["ideal"].frames[0]["footprint"]).shape == (4, 2)


def test_impossible_lenses_and_crops_are_refused(tmp_path, capsys):
    for bad, fragment in [(dict(lens_k1=-0.6, hfov_deg=100.0), "folds"), (dict(crop_aspect="4:5"), "narrower"),
                          (dict(crop_aspect="wide"), "W:H"), (dict(lens_p1=0.2), "out of range")]:
        with pytest.raises(InputError, match=fragment):
            SynthConfig(**SMALL, **bad).validate()
    code = main(["synth", "--out", str(tmp_path / "x"), "--k1", "-0.6", "--hfov", "100", "--quiet"])
    assert code == 2 and "folds" in capsys.readouterr().err and not (tmp_path / "x").exists()
