"""The map's lens check (`plugin.lens_check`, `workflows.map.lens`): a camera file whose distortion the images
contradict (signs flipped, distortion left out) is said, with what it does to the map's heights, and refused when
that is large; the right lens is not."""

import json
from pathlib import Path

import numpy as np
import pytest

from sosmatch.database.cameras import write_cameras_txt
from sosmatch.plugin.errors import MAX_PROBLEM_CHARS
from sosmatch.plugin.geometry import Camera
from sosmatch.plugin.lens_check import (
    LensCheck,
    camera_kind,
    jackknife_se,
    judge_lens,
    landmark_groups,
    lens_displacement_px,
    refit_camera,
)
from sosmatch.plugin.params import Params, with_overrides
from sosmatch.tools.toy_sessions import render_disc_flight
from sosmatch.workflows import map as map_workflow
from sosmatch.workflows.map import lens as lens_module
from sosmatch.workflows.map.quality import FIGURE, MapRefused

pycolmap = pytest.importorskip("pycolmap")

WIDTH, HEIGHT, ALTITUDE, FRAMES = 320, 240, 60.0, 25
K = (0.8 * WIDTH, 0.8 * WIDTH, WIDTH / 2, HEIGHT / 2)
LENS = Camera(WIDTH, HEIGHT, *K, "SIMPLE_RADIAL", (-0.18,))  # 64 deg wide, 15 px at the corners


def _map(root: Path, name: str, camera: Camera, params: Params | None = None) -> tuple[dict, bool]:
    """The map of the flight in `root` through `camera` (run.json, refused?)."""
    write_cameras_txt(root / f"{name}.txt", {1: camera})
    refused = False
    try:
        inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / f"{name}.txt")
        map_workflow.run(params or Params(), inputs, root / name, progress=False)
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
    assert lens["camera_kind"] == "file" and lens["judged"] is True  # the toy flight's exact poses fit its images


def test_flipped_distortion_is_refused_with_its_height_error(flight):
    flipped = Camera(WIDTH, HEIGHT, *K, "SIMPLE_RADIAL", (0.18,))
    run, refused = _map(flight, "flipped", flipped)
    lens = run["lens_check"]
    assert refused and run["verdict"]["status"] == "refused"
    said = [r for r in run["verdict"]["refusals"] if "flipped.txt" in r]
    assert len(said) == 1 and " m lower (" in said[0] and "than the lens the images fit" in said[0]
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
    assert len(said) == 1 and "fix its distortion" in said[0] and "quality.lens_check=false" in said[0]


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


def test_a_lens_is_refused_only_on_poses_that_fit_the_images():
    """rev40: the refit absorbs pose errors (a barrel lens k1 -0.27..-0.38 invented for a correct pinhole camera on
    unrefined EXIF tag poses, heights 6.4-7.7 % of H; z up to 10.3 on correct lenses): without the pose check's
    word that the poses fit the images, a large shift is a warning naming both causes, never a refusal."""
    args = (5.0, 0.05, 0.10)
    for shift in (7.0, 25.0):
        warnings, refusals = judge_lens(_check(shift, 0.5), *args, "file", False)
        assert not refusals and len(warnings) == 1
        assert warnings[0].startswith("the images fit another lens or other poses: ")
        assert "better poses, or fix its distortion" in warnings[0]
    assert judge_lens(_check(3.0, 0.1), *args, "file", False) == ([], [])  # small: nothing either way


def test_the_remedy_follows_where_the_camera_came_from():
    """rev40 defect 2: a camera from EXIF (no file to edit, no --camera beside --pose-source exif) or from a
    model was blamed on "the camera file"; each source names its own remedy and the switch off, in one cut line."""
    assert camera_kind("EXIF of GEOW/images", "GEOW/images") == "EXIF"
    assert camera_kind("model/sparse/0", "model/sparse/0") == "model"
    assert camera_kind("P/cameras.txt", "P/poses.csv") == "file"
    said = {}
    for kind in ("file", "EXIF", "model"):
        _, refusals = judge_lens(_check(25.0, 1.0), 5.0, 0.05, 0.10, kind)
        said[kind] = refusals[0]
        assert "--set quality.lens_check=false" in refusals[0]
    assert "fix its distortion" in said["file"]
    assert "poses-from-exif writes cameras.txt" in said["EXIF"] and "--poses/--camera" in said["EXIF"]
    assert "model's camera" in said["model"] and "camera file" not in said["model"]
    # the whole refusal line (raise_if_refused's wording) keeps the remedy and the pointer with a long path
    long_path = "/data/surveys/2026-12-07/site-with-a-long-name/flight-03/exif-poses/camera-from-the-drone.txt"
    check = LensCheck(long_path, LENS, LENS, 25.0, 1.0, 100.0, 5.0, 3.0, 2.0, 100)
    for kind in said:
        _, refusals = judge_lens(check, 5.0, 0.05, 0.10, kind)
        assert refusals[0].count(long_path) == 1
        assert len(f"map refused: {refusals[0]} (see {FIGURE} and run.json)") <= MAX_PROBLEM_CHARS


def test_a_check_that_fails_keeps_the_map(flight, monkeypatch, caplog):
    """rev40 defect 4: an error inside the refit (here the bundle adjustment raising, as a pycolmap error would)
    threw away the finished map with a traceback; now the map is written, the failure warned and recorded."""
    def broken(*_args, **_kwargs):
        raise RuntimeError("bundle adjustment failed")

    monkeypatch.setattr(lens_module, "_solve", broken)
    run, refused = _map(flight, "broken", LENS)
    assert not refused and (flight / "broken" / "landmarks.sosmap").is_file()
    assert run["lens_check"] == {"camera_file": str(flight / "broken.txt"),
                                 "error": "RuntimeError: bundle adjustment failed"}
    assert any(w.startswith("lens not checked: RuntimeError") for w in run["verdict"]["warnings"])
    assert any("lens not checked" in r.getMessage() and r.levelname == "WARNING" for r in caplog.records)


def test_without_the_pose_checks_word_a_wrong_lens_is_only_a_warning(flight):
    """The map passes the pose check's finding to the lens check: with the pose check off nothing says the poses
    fit the images, so the flipped lens (refused above) is a warning naming both causes, the map kept."""
    flipped = Camera(WIDTH, HEIGHT, *K, "SIMPLE_RADIAL", (0.18,))
    run, refused = _map(flight, "unjudged", flipped, with_overrides(Params(), {"pose_check.enabled": False}))
    assert not refused and run["lens_check"]["judged"] is False and run["lens_check"]["relative_shift"] > 0.1
    said = [w for w in run["verdict"]["warnings"] if "unjudged.txt puts the map" in w]
    assert len(said) == 1 and said[0].startswith("the images fit another lens or other poses")
