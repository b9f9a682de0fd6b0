"""The map's lens check (`plugin.lens_check`, `workflows.map.lens`): a camera file whose distortion the images
contradict (signs flipped, distortion left out) is said, with what it does to the map's heights, and refused when
that is large; the right lens is not."""

import json
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.cameras import write_cameras_txt
from sosmatch.plugin.geometry import Camera
from sosmatch.plugin.lens_check import (
    LensCheck,
    jackknife_se,
    judge_lens,
    landmark_groups,
    lens_displacement_px,
    refit_camera,
)
from sosmatch.plugin.params import Params
from sosmatch.tools.toy_sessions import render_disc_flight
from sosmatch.workflows import map as map_workflow
from sosmatch.workflows.map.quality import MapRefused

pycolmap = pytest.importorskip("pycolmap")

WIDTH, HEIGHT, ALTITUDE, FRAMES = 320, 240, 60.0, 25
K = (0.8 * WIDTH, 0.8 * WIDTH, WIDTH / 2, HEIGHT / 2)
LENS = Camera(WIDTH, HEIGHT, *K, "SIMPLE_RADIAL", (-0.18,))  # 64 deg wide, 15 px at the corners


def _map(root: Path, name: str, camera: Camera) -> tuple[dict, bool]:
    """The map of the flight in `root` through `camera` (run.json, refused?)."""
    write_cameras_txt(root / f"{name}.txt", {1: camera})
    refused = False
    try:
        map_workflow.run(Params(), map_workflow.load_inputs(root / "images", root / "poses.csv", root / f"{name}.txt"),
                         root / name, progress=False)
    except MapRefused:
        refused = True
    return json.loads((root / name / "run.json").read_text()), refused


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("lens_check")
    render_disc_flight(root, LENS, FRAMES, ALTITUDE, seed=0)
    return root


def test_the_right_lens_is_not_called_wrong(flight):
    run, refused = _map(flight, "right", LENS)
    lens = run["lens_check"]
    assert not refused and run["verdict"]["status"] == "ok"
    assert not any("lens" in w for w in run["verdict"]["warnings"])
    assert lens["camera_file"].endswith("right.txt") and lens["landmarks"] >= 16
    assert abs(lens["height_shift_m"]) < 0.02 * ALTITUDE


def test_flipped_distortion_is_refused_with_its_height_error(flight):
    flipped = Camera(WIDTH, HEIGHT, *K, "SIMPLE_RADIAL", (0.18,))
    run, refused = _map(flight, "flipped", flipped)
    lens = run["lens_check"]
    assert refused and run["verdict"]["status"] == "refused"
    said = [r for r in run["verdict"]["refusals"] if "flipped.txt" in r]
    assert len(said) == 1 and "m lower than the lens the images fit" in said[0]
    # the ground is z = 0: the map sits below it by about what the check says
    csv = [line for line in (flight / "flipped" / "landmarks.csv").read_text().splitlines() if not line.startswith("#")]
    z_col = csv[0].split(",").index("z")
    below = -np.median([float(line.split(",")[z_col]) for line in csv[1:]])
    assert below > 0.1 * ALTITUDE
    assert lens["height_shift_m"] == pytest.approx(below, rel=0.3)
    assert lens["fitted"]["params"][-1] < 0  # the refit finds the barrel lens back


def test_forgotten_distortion_is_said(flight):
    # PINHOLE for the barrel lens: refit as OPENCV, the map about 8 % of its flying height low, a warning
    run, refused = _map(flight, "pinhole", Camera(WIDTH, HEIGHT, *K))
    lens = run["lens_check"]
    assert not refused and lens["fitted"]["model"] == "OPENCV" and lens["height_shift_m"] > 0
    said = [w for w in run["verdict"]["warnings"] if "pinhole.txt puts the map" in w]
    assert len(said) == 1 and "check the camera file's distortion" in said[0]


def test_forgotten_distortion_is_refit_in_a_lens_model():
    pinhole = Camera(WIDTH, HEIGHT, *K)
    start = refit_camera(pinhole)
    assert start.model == "OPENCV" and start.extra == (0.0,) * 4 and start.pinhole() == pinhole
    assert refit_camera(LENS) is LENS
    # eight free terms run away on a map's observations: such a camera is not checked
    assert refit_camera(Camera(WIDTH, HEIGHT, *K, "FULL_OPENCV", (-0.18,) + (0.0,) * 7)) is None
    assert lens_displacement_px(start, start) == pytest.approx(0.0, abs=1e-9)
    assert 10 < lens_displacement_px(pinhole, LENS) < 30


def test_jackknife_and_groups():
    assert jackknife_se(np.array([1.0, 1.0, 1.0])) == 0.0
    # K leave-one-out means of K values: the jackknife gives the usual standard error of the mean
    x = np.array([0.3, 1.2, -0.4, 2.0, 0.9, 1.1])
    loo = np.array([np.delete(x, i).mean() for i in range(len(x))])
    assert jackknife_se(loo) == pytest.approx(x.std(ddof=1) / np.sqrt(len(x)))
    g = landmark_groups(20, 8)
    assert g.min() == 0 and g.max() == 7 and np.all(np.diff(g) >= 0)


def _check(shift: float, se: float, height: float = 100.0) -> LensCheck:
    return LensCheck("cams.txt", LENS, LENS, shift, se, height, 5.0, 3.0, 2.0, 100)


def test_judged_on_significance_and_consequence():
    args = (5.0, 0.05, 0.10)
    assert judge_lens(None, *args) == ([], [])
    assert judge_lens(_check(20.0, 5.0), *args) == ([], [])  # large but not proven (4 standard errors)
    assert judge_lens(_check(3.0, 0.1), *args) == ([], [])  # proven but small (3 % of the flying height)
    warnings, refusals = judge_lens(_check(-7.0, 0.5), *args)
    assert not refusals and "cams.txt puts the map 7.0 m higher" in warnings[0]
    warnings, refusals = judge_lens(_check(25.0, 1.0), *args)
    assert not warnings and "cams.txt puts the map 25.0 m lower" in refusals[0]
