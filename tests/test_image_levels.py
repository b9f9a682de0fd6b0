"""Images of more than 8 bits whose values fill only a sliver of their range (radiometric thermal TIFFs) are read
between the flight's own levels; data that use their range read from the sensor's white level as before."""

from __future__ import annotations

import logging

import cv2
import numpy as np

from sosmatch.database.images import Levels, flight_white_level, read_gray, read_image, to_u8


def _temperatures(h: int = 120, w: int = 160, seed: int = 0, warm: float = 0.0) -> np.ndarray:
    """A radiometric thermal frame in centi-kelvin, as DJI's Thermal SDK and FLIR tools write: 20-40 degC with
    a 0.05 K sensor noise (values ~29300-31300 of 65535)."""
    rng = np.random.default_rng(seed)
    t = np.full((h, w), 25.0)
    cv2.circle(t, (50, 50), 20, 38.0, -1)
    cv2.rectangle(t, (90, 60), (140, 110), 21.0, -1)
    t += warm + rng.normal(0, 0.05, t.shape)
    return np.rint((t + 273.15) * 100).astype(np.uint16)


def test_a_radiometric_thermal_flight_is_read_between_its_own_levels(tmp_path, caplog):
    """nu39 D3: read from 0 to its white level 65535 such a flight had 6 grey levels, and its map was refused
    ("no landmarks"). Its levels are the flight's (every frame read alike: a warmer frame stays warmer), the
    range fills the 8 bits, and the user is told why."""
    paths = []
    for k, warm in enumerate((0.0, 0.0, 2.0, 0.0)):
        paths.append(tmp_path / f"t{k}.tif")
        cv2.imwrite(str(paths[-1]), _temperatures(seed=k, warm=warm))
    with caplog.at_level(logging.WARNING):
        levels = flight_white_level(paths)
    assert isinstance(levels, Levels) and 29400 < levels.black < levels.white < 31400
    assert "radiometric (thermal) file?" in caplog.text
    frame = read_image(paths[0], levels)[:, :, 0].astype(int)
    assert frame.max() - frame.min() > 180  # before: 6 grey levels
    # one mapping for the flight: the 2 K warmer frame reads brighter by the same step everywhere
    warmer = read_image(paths[2], levels)[:, :, 0].astype(int)
    step = 200 * 255 / (levels.white - levels.black)
    assert abs(float(np.median(warmer[100:, :40] - frame[100:, :40])) - step) < 3
    gray = read_gray(paths[0], levels).astype(int)
    assert np.abs(gray - frame).max() <= 1


def test_data_that_use_their_range_keep_the_sensors_white_level(tmp_path):
    """The camera's exposure is kept where the data span their range: 12-bit data read from 4095, black 0."""
    gray = np.linspace(0, 4000, 160 * 120).reshape(120, 160).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "a.tif"), gray)
    assert flight_white_level([tmp_path / "a.tif"]) == 4095
    assert to_u8(np.array([0, 4095], np.uint16), Levels(0, 4095)).tolist() == [0, 255]
    assert to_u8(np.array([100, 180, 300], np.uint16), Levels(100, 300)).tolist() == [0, 102, 255]
    assert to_u8(np.array([100, 180, 300], np.uint32), Levels(100, 300)).tolist() == [0, 102, 255]
    assert str(Levels(0, 4095)) == "4095" and str(Levels(100, 300)) == "100-300"


def test_a_flat_flight_beyond_8_bits_gets_no_division_by_zero(tmp_path):
    cv2.imwrite(str(tmp_path / "f.tif"), np.full((40, 40), 30000, np.uint16))
    levels = flight_white_level([tmp_path / "f.tif"])
    assert isinstance(levels, Levels) and levels.white > levels.black
    assert read_image(tmp_path / "f.tif", levels).shape == (40, 40, 3)



def test_colmaps_copies_of_a_thermal_flight_use_its_levels_and_are_made_again_when_they_change(tmp_path):
    """COLMAP reads 8-bit copies (`sfm.colmap_image_dir`): a thermal flight's are read between its own levels,
    and copies.json records them, so copies made at other levels are not reused."""
    import json

    from sosmatch.workflows import sfm

    images = tmp_path / "images"
    images.mkdir()
    names = [f"t{k}.tif" for k in range(3)]
    for k, name in enumerate(names):
        cv2.imwrite(str(images / name), _temperatures(seed=k))
    work = tmp_path / "work"
    assert sfm.colmap_image_dir(images, names, work) == work
    copy = cv2.imread(str(work / names[0]), cv2.IMREAD_UNCHANGED).astype(int)
    assert copy.max() - copy.min() > 180  # before: 7 grey levels
    levels = str(flight_white_level([images / n for n in names]))
    assert all(source[2] == levels for source in json.loads((work / "copies.json").read_text()).values())


def test_levels_are_measured_on_every_channel_and_the_white_level_on_every_value(tmp_path):
    """rev24: the sample strode over the flattened values, so at 640x512 RGB (a stride of 3) it read the red
    channel alone, and a flight whose red band was narrow got that band as its levels (green and blue clipped);
    and the white level came from the sample, so a 12-bit flight's highlights outside it made it 1023, not 4095."""
    rng = np.random.default_rng(3)
    rgb = np.empty((512, 640, 3), np.uint16)
    rgb[..., 0] = rng.integers(1000, 1100, (512, 640))  # cv2 writes BGR: this is blue, the narrow band
    rgb[..., 1:] = rng.integers(1000, 3000, (512, 640, 2))
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb)
    assert flight_white_level([tmp_path / "rgb.png"]) == 4095  # the data use their range: read from the white level

    frame = rng.integers(0, 1000, (1500, 2000)).astype(np.uint16)  # a dark exposure: kept dark, not stretched
    frame.reshape(-1)[1] = 4000  # one highlight between the sampled values
    cv2.imwrite(str(tmp_path / "grey.png"), frame)
    assert flight_white_level([tmp_path / "grey.png"]) == 4095


def test_change_detection_reads_a_session_s_images_between_the_levels_its_map_recorded(tmp_path):
    """rev24: change detection read each keyframe by its own white level, so a radiometric flight its map read
    at 0-255 came to the surface sweep at ~12 grey levels. It now reads them between run.json's image_levels."""
    import json

    from sosmatch.database.session_io import KeyframeImages, recorded_levels

    cv2.imwrite(str(tmp_path / "t0.tif"), _temperatures())
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": [29400, 31300]}))
    levels = recorded_levels(tmp_path)
    assert levels == Levels(29400, 31300)
    grey = KeyframeImages(tmp_path, ["t0.tif"], [(160, 120)], levels=levels)[0]
    assert grey.max() - grey.min() > 180
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": [0, 4095]}))
    assert recorded_levels(tmp_path) == 4095  # data from zero: the white level, as the map read them
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": None}))
    assert recorded_levels(tmp_path) is None
