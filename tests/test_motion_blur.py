"""The smear along the track (`plugin.motion_blur`), measured on a flight rendered here and blurred along each
frame's own motion, and what the map's verdict and `changes` say of it (the 35th new-user sweep: a 12 px motion
blur kept 120 of 205 landmarks with no word, and `changes` against a clean session made 4 false claims)."""

import cv2
import numpy as np
import pytest

from sosmatch.database.synth_session import load_synth_session
from sosmatch.plugin.image_quality import flight_images, image_causes
from sosmatch.plugin.motion_blur import flight_smear, motion_directions, motion_smear
from sosmatch.workflows.synth import SynthConfig, run

# a lawnmower turned by 45 deg (the blur is diagonal in the image), both directions of pass, 320 x 240 (working
# size 320: full and working pixels are the same)
FLIGHT = dict(world_seed=3, world_size_m=240.0, frames=10, spacing_m=8.0, width=320, height=240,
              line_length_m=40.0, line_spacing_m=25.0, rotate_deg=45.0)
SIDE = 400


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOSMATCH_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        out = tmp_path_factory.mktemp("blur") / "S"
        run(out, SynthConfig(**FLIGHT), workers=1)
    s = load_synth_session(out)
    grays = [cv2.imread(str(out / "images" / n), cv2.IMREAD_GRAYSCALE) for n in s.poses.names]
    return grays, motion_directions(s.poses)


def _smeared(gray: np.ndarray, direction: np.ndarray, length: int) -> np.ndarray:
    """A linear blur of `length` px along `direction` (a box: the ground moving at constant speed)."""
    k = np.zeros((2 * length + 1, 2 * length + 1), np.float32)
    for t in np.linspace(-length / 2, length / 2, 4 * length):
        k[int(round(length + t * direction[1])), int(round(length + t * direction[0]))] += 1
    return cv2.filter2D(gray, -1, k / k.sum())


def test_the_motion_directions_follow_each_pass():
    from sosmatch.plugin.geometry import Poses

    eye = np.eye(3)
    p = Poses(["a", "b", "c"], [eye] * 3, [[0, 0, 0], [1, 1, 0], [2, 2, 0]])
    assert np.allclose(motion_directions(p), np.sqrt(0.5))
    assert np.isnan(motion_directions(Poses(["a"], [eye], [[0, 0, 0]]))).all()  # no motion to measure along


@pytest.mark.parametrize("length", [0, 4, 8, 12])
def test_the_smear_is_measured_along_each_frame_s_motion(flight, length):
    grays, dirs = flight
    smears = [motion_smear(g if not length else _smeared(g, d, length), SIDE, d) for g, d in zip(grays, dirs)]
    if length:
        assert abs(flight_smear(smears) - length) <= 0.2 * length
    else:
        assert flight_smear(smears) < 1.0


def test_ground_with_rows_along_the_track_is_not_a_smear():
    """Rows of crops along the track take detail from one direction at every scale: no nulls, no smear."""
    rng = np.random.default_rng(5)
    x = np.arange(320)
    rows = 128 + 40 * np.sin(2 * np.pi * x / 5.0)[None, :] * np.ones((240, 1))  # rows along y, 5 px apart
    g = np.clip(rows + cv2.GaussianBlur(rng.normal(0, 20, (240, 320)), (0, 0), 1.0), 0, 255).astype(np.uint8)
    assert motion_smear(g, SIDE, np.array([0.0, 1.0])) < 2.0
    assert motion_smear(g, SIDE, np.array([1.0, 0.0])) < 2.0  # flown across the rows


def test_the_verdict_names_a_smeared_flight_and_records_it(flight):
    grays, dirs = flight
    figures = [np.array([1.0, 30.0, 0.4])] * len(grays)
    smears = [motion_smear(_smeared(g, d, 8), SIDE, d) for g, d in zip(grays, dirs)]
    images = flight_images(figures, [f"k{i}" for i in range(len(grays))], None, smears)
    (cause,) = image_causes(images, 3.0, 0.15, 75.0, 2.0)
    assert cause.startswith("images motion-blurred: the ground is smeared 8")
    assert images.to_dict()["motion_smear_px"] == pytest.approx(8.0, abs=1.6)
    clean = flight_images(figures, ["k"] * len(grays), None, [motion_smear(g, SIDE, d) for g, d in zip(grays, dirs)])
    assert image_causes(clean, 3.0, 0.15, 75.0, 2.0) == []
    assert flight_images(figures, ["k"] * len(grays)).to_dict()["motion_smear_px"] is None  # not measured


def test_changes_names_the_claims_a_smeared_session_puts_in_doubt(tmp_path):
    import json
    from types import SimpleNamespace

    from sosmatch.plugin.changes import GONE, NEW
    from sosmatch.workflows.changes_images import blur_note, session_smear

    (tmp_path / "run.json").write_text(json.dumps({"quality": {"images": {"motion_smear_px": 7.5}}}))
    assert session_smear(tmp_path) == 7.5
    assert np.isnan(session_smear(tmp_path / "nothing"))  # a map made before the smear was recorded
    result = SimpleNamespace(a=SimpleNamespace(label=np.array([GONE, 0])), b=SimpleNamespace(label=np.array([NEW])),
                             tracks_a=None, tracks_b=None)
    note = blur_note(result, "B", "maps/B", 7.5, 2.0)
    assert "motion-blurred (the ground smeared 7.5 working px" in note and "2 landmark(s) (gone A#0, new B#0)" in note
    assert blur_note(result, "B", "maps/B", 0.5, 2.0) == ""  # a clean flight
    assert blur_note(result, "B", "maps/B", float("nan"), 2.0) == ""  # not recorded: nothing said


def test_a_cached_keyframe_gives_the_smear_along_the_new_poses_motion_as_a_fresh_run_does(flight, tmp_path):
    """The direction of motion comes from the poses, which enter no cache key: a map re-run with other poses for
    the same images (`--overwrite` with a new pose file) must read the smear along its own direction, not the one
    measured along the first poses' (same inputs -> same outputs, with or without a cache)."""
    from sosmatch.database.cameras import write_cameras_txt
    from sosmatch.database.poses import write_poses_csv
    from sosmatch.plugin.geometry import Camera, Poses
    from sosmatch.plugin.params import Params
    from sosmatch.workflows import map as map_workflow
    from sosmatch.workflows.map.keyframes import cached_motion_smears

    grays, _ = flight
    names = [f"f{i:03d}.jpg" for i in range(len(grays))]
    (tmp_path / "images").mkdir()
    for name, g in zip(names, grays):  # smeared 8 px along the image's x axis
        cv2.imwrite(str(tmp_path / "images" / name), _smeared(g, np.array([1.0, 0.0]), 8),
                    [cv2.IMWRITE_JPEG_QUALITY, 95])
    write_cameras_txt(tmp_path / "cameras.txt", {1: Camera(320, 240, 256.0, 256.0, 160.0, 120.0)})
    centers = np.stack([np.arange(len(names)) * 8.0, np.zeros(len(names)), np.full(len(names), 60.0)], 1)
    nadir = np.diag([1.0, -1.0, -1.0])  # camera x along the world's x: the motion is along the image's x
    turned = nadir @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # ... along its y
    keyframes = np.arange(len(names))

    def smears(rotation: np.ndarray, cache: str) -> np.ndarray:
        poses = Poses(names, np.repeat(rotation[None], len(names), 0), centers)
        write_poses_csv(tmp_path / "poses.csv", poses)
        inputs = map_workflow.load_inputs(tmp_path / "images", tmp_path / "poses.csv", tmp_path / "cameras.txt")
        map_workflow.describe_keyframes(inputs, keyframes, Params(), tmp_path / cache, "key", progress=False)
        return cached_motion_smears(tmp_path / cache, names, motion_directions(poses))

    along = smears(nadir, "reused")
    reused = smears(turned, "reused")  # every keyframe from the cache the first poses filled
    fresh = smears(turned, "fresh")
    assert abs(flight_smear(along) - 8) <= 1.6 and flight_smear(fresh) < 1.0
    assert np.array_equal(reused, fresh, equal_nan=True)


def test_the_exposure_s_prediction_is_recorded_and_said_only_where_it_agrees(tmp_path):
    """speed x ExposureTime over the ground of a working pixel: physical evidence beside the spectrum's measure."""
    from PIL import Image

    from sosmatch.database.exif import read_image_metadata
    from sosmatch.plugin.motion_blur import exposure_smear

    img = Image.new("RGB", (64, 48))
    exif = img.getexif()
    exif.get_ifd(0x8769)[0x829A] = 0.003125  # 1/320 s, as Seneca's camera
    img.save(tmp_path / "a.jpg", exif=exif)
    assert read_image_metadata(tmp_path / "a.jpg").exposure_s == pytest.approx(0.003125)
    # 10 m/s (10 m between frames a second apart) x 1/100 s over 0.05 m per working pixel: 2 px
    centers = np.stack([np.arange(5) * 10.0, np.zeros(5), np.full(5, 60.0)], 1)
    assert exposure_smear(centers, [0, 1, 2, 3, 4], [0.01] * 5, 0.05) == pytest.approx(2.0)
    assert np.isnan(exposure_smear(centers, [None] * 5, [0.01] * 5, 0.05))  # no capture times: no speed
    assert np.isnan(exposure_smear(centers, [0, 1, 2, 3, 4], [None] * 5, 0.05))  # no ExposureTime

    figures = [np.array([1.0, 30.0, 0.4])] * 3
    agree = flight_images(figures, ["a", "b", "c"], None, [7.5] * 3, 6.0)
    assert "as the speed and exposure time predict (6.0 px)" in image_causes(agree, 3.0, 0.15, 75.0, 2.0)[0]
    assert agree.to_dict()["motion_smear_predicted_px"] == 6.0
    apart = flight_images(figures, ["a", "b", "c"], None, [7.5] * 3, 0.1)  # a wrong height, a stuck shutter tag
    (cause,) = image_causes(apart, 3.0, 0.15, 75.0, 2.0)
    assert "predict" not in cause and apart.to_dict()["motion_smear_predicted_px"] == 0.1
    # a large prediction with a clean spectrum: recorded, no warning
    assert image_causes(flight_images(figures, ["a", "b", "c"], None, [0.0] * 3, 6.0), 3.0, 0.15, 75.0, 2.0) == []
