"""Images of more than 8 bits whose values fill only a sliver of their range (radiometric thermal TIFFs) are read
between the flight's own levels; data that use their range read from the sensor's white level as before."""

from __future__ import annotations

import logging

import cv2
import numpy as np

from sosmatch.database.flight_levels import flight_white_level
from sosmatch.database.images import Levels, read_gray, read_image, to_u8


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

    from sosmatch.database.session_images import KeyframeImages, recorded_levels

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
    # signed data below zero and float degC (nu41 D5): their own levels come back as the map read them
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": [-113, 146]}))
    assert recorded_levels(tmp_path) == Levels(-113, 146)
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": [13.69, 39.616]}))
    assert recorded_levels(tmp_path) == Levels(13.69, 39.616)
    (tmp_path / "run.json").write_text(json.dumps({"image_levels": [0, 40.5]}))
    assert recorded_levels(tmp_path) == Levels(0, 40.5)


def _thermal_flight(tmp_path, edit, n: int = 4) -> list:
    """`n` thermal frames (`_temperatures`), frame k changed by edit(k, frame)."""
    paths = []
    for k in range(n):
        paths.append(tmp_path / f"e{k}.tif")
        cv2.imwrite(str(paths[-1]), edit(k, _temperatures(seed=k)))
    return paths


def _set(frame: np.ndarray, where, value: int) -> np.ndarray:
    frame[where] = value
    return frame


def test_no_data_and_saturated_values_set_no_level(tmp_path, caplog):
    """nu41 D1: one row of zeros per frame (a no-data line), zero-filled corners or a dead column at 0 or 65535
    made a thermal flight read from 0 to 65535 again (6 grey levels, no landmarks): the 0.1 % tail fell on them
    and flipped the offset-vs-dark decision. Values at exactly 0 or the type's maximum set no level; the
    decision comes from the central 5-95 %."""
    (tmp_path / "ref").mkdir()
    reference = flight_white_level(_thermal_flight(tmp_path / "ref", lambda k, f: f))
    edits = {"row": lambda k, f: _set(f, (0, slice(None)), 0),
             "corners": lambda k, f: _set(_set(f, (slice(0, 12), slice(0, 12)), 0),
                                          (slice(-12, None), slice(-12, None)), 0),
             "dead0": lambda k, f: _set(f, (slice(None), 70), 0),
             "dead65535": lambda k, f: _set(f, (slice(None), 70), 65535)}
    for name, edit in edits.items():
        (tmp_path / name).mkdir()
        with caplog.at_level(logging.WARNING):
            levels = flight_white_level(_thermal_flight(tmp_path / name, edit))
        assert isinstance(levels, Levels), name
        assert abs(levels.black - reference.black) <= 2 and abs(levels.white - reference.white) <= 2, name
        assert "no-data or saturated" in caplog.text
        assert np.ptp(read_image(tmp_path / name / "e0.tif", levels)[60:, :, 0].astype(int)) > 180, name


def test_a_small_hot_object_clips_rather_than_stretching_the_flight(tmp_path, caplog):
    """nu41 D1: a 20x20 patch at 87 degC in 3 of 40 frames stretched the flight's levels to 28684-36000 (21
    landmarks instead of 36). Values beyond the flight's bulk by more than its width are left out of the levels
    and clip, and the log says how many."""
    (tmp_path / "ref").mkdir()
    reference = flight_white_level(_thermal_flight(tmp_path / "ref", lambda k, f: f))
    (tmp_path / "hot").mkdir()
    paths = _thermal_flight(tmp_path / "hot", lambda k, f: _set(f, (slice(5, 17), slice(5, 17)), 36000) if k in (0, 2)
                            else f)
    with caplog.at_level(logging.WARNING):
        levels = flight_white_level(paths)
    assert isinstance(levels, Levels) and abs(levels.white - reference.white) <= 2, levels
    assert "a hot object or dead pixels" in caplog.text and "clip" in caplog.text
    assert read_image(paths[0], levels)[5:17, 5:17, 0].min() == 255  # the hot patch clips to white


def test_signed_data_below_zero_are_read_between_their_own_levels(tmp_path, caplog):
    """nu41 D5: signed 16-bit deci-degC of a winter scene (-15..+20 degC) read from 0: 65 % of it black, and
    nothing said so. Read between the flight's own levels, and told why."""
    deci = (_temperatures().astype(np.int32) - 29315 - 1600) // 10  # deci-degC, about -150..+60
    cv2.imwrite(str(tmp_path / "w.tif"), deci.astype(np.int16))
    with caplog.at_level(logging.WARNING):
        levels = flight_white_level([tmp_path / "w.tif"])
    assert isinstance(levels, Levels) and levels.black < 0 < levels.white, levels
    assert "below zero or beyond" in caplog.text
    grey = read_image(tmp_path / "w.tif", levels)[:, :, 0].astype(int)
    assert np.ptp(grey) > 180 and np.mean(grey == 0) < 0.05  # before: most of the frame 0
    assert np.abs(read_gray(tmp_path / "w.tif", levels).astype(int) - grey).max() <= 1
    assert to_u8(np.array([-100, 0, 155], np.int16), Levels(-100, 155)).tolist() == [0, 100, 255]


def test_float_temperatures_are_read_between_their_own_levels(tmp_path):
    """nu41 D5: float32 degC (14..40) read as grey 0..255 had 25 grey levels."""
    degc = (_temperatures().astype(np.float64) / 100 - 273.15).astype(np.float32)
    cv2.imwrite(str(tmp_path / "f.tif"), degc)
    levels = flight_white_level([tmp_path / "f.tif"])
    assert isinstance(levels, Levels) and 20 < levels.black < levels.white < 40, levels
    grey = read_image(tmp_path / "f.tif", levels)[:, :, 0].astype(int)
    # the 21 degC field and the 25 degC ground: 4 grey levels apart before
    assert np.ptp(grey) > 180 and np.median(grey[:10, :]) - np.median(grey[70:100, 100:130]) > 40
    assert np.abs(read_gray(tmp_path / "f.tif", levels).astype(int) - grey).max() <= 1
    # float data that are light (0..1) read as before
    cv2.imwrite(str(tmp_path / "l.tif"), np.linspace(0, 1, 120 * 160).reshape(120, 160).astype(np.float32))
    assert flight_white_level([tmp_path / "l.tif"]) is None
    # float centi-kelvin, beyond 255: read as 0..255 every pixel was white
    cv2.imwrite(str(tmp_path / "k.tif"), _temperatures().astype(np.float32))
    levels = flight_white_level([tmp_path / "k.tif"])
    assert isinstance(levels, Levels) and 29000 < levels.black < levels.white < 31500, levels
    assert np.ptp(read_image(tmp_path / "k.tif", levels)[:, :, 0].astype(int)) > 180


def test_float_measurements_are_read_between_their_own_levels_above_zero_too(tmp_path):
    """rev25: float degC of a spring scene (5-40) were read as grey 0..255 (36 levels) while a winter one (-5-30)
    got its own levels (256): one site read two ways by whether a pixel fell below zero. Zero is a temperature."""
    rng = np.random.default_rng(5)
    for name, low in (("spring", 5.0), ("winter", -5.0)):
        frame = (low + 35.0 * rng.random((120, 160))).astype(np.float32)
        frame[:10, :10] = 0.0  # 0 degC: a value, not no-data
        cv2.imwrite(str(tmp_path / f"{name}.tif"), frame)
        levels = flight_white_level([tmp_path / f"{name}.tif"])
        assert isinstance(levels, Levels) and levels.black <= low + 0.5 and levels.white > low + 34.0
        grey = read_image(tmp_path / f"{name}.tif", levels)[:, :, 0].astype(int)
        assert grey.max() - grey.min() > 200


def test_a_float64_colour_tiff_is_read_like_its_float32_copy(tmp_path, capfd):
    """nu53 M2: a 3-channel float64 TIFF (reflectances 0..0.6) was a cv2 traceback in `segment` (cv2.cvtColor
    takes no float64) and unreadable to `read_gray`. Read as its float32 copy is, in RGB order, and without the
    "[ERROR] imdecode_" line OpenCV printed for every image it could not turn to gray while decoding (rev47)."""
    rng = np.random.default_rng(0)
    rgb = rng.random((60, 80, 3)) * 0.6
    rgb[..., 0] *= 0.25  # a dark red channel: a swapped order shows
    for dtype in ("float64", "float32"):
        assert cv2.imwrite(str(tmp_path / f"{dtype}.tif"), rgb[..., ::-1].astype(dtype))  # OpenCV writes BGR
    wide, narrow = read_image(tmp_path / "float64.tif"), read_image(tmp_path / "float32.tif")
    assert wide.shape == (60, 80, 3) and wide.dtype == np.uint8
    assert np.array_equal(wide, narrow)
    assert wide[..., 0].mean() < 0.5 * wide[..., 2].mean()
    capfd.readouterr()
    assert np.array_equal(read_gray(tmp_path / "float64.tif"), read_gray(tmp_path / "float32.tif"))
    assert "imdecode" not in capfd.readouterr().err
