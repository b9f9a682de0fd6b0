"""Several images per capture (`workflows.image_rigs`): a MicaSense-style folder (five bands per trigger, one
time and position) is refused naming the cause; a DJI P4 Multispectral-style folder (one RGB JPEG beside five
TIFF bands) is read as its JPEGs; a plain flight is read whole."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sosmatch.database.exif import read_image_metadata
from sosmatch.database.exif_write import encode_exif
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main
from sosmatch.workflows.image_priors import read_image_priors


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rigs") / "flight"
    assert main(["synth", "--out", str(out), "--frames", "12", "--width", "160", "--height", "120", "--world-size",
                 "400", "--line-length", "60", "--geotags", "dji", "-q"]) == 0
    return out


def _bands(flight: Path, folder: Path, rgb_too: bool) -> None:
    """Per frame five 16-bit band TIFFs carrying its tags (and, `rgb_too`, its JPEG), as a multispectral
    camera writes them: every file of a trigger the same time and position."""
    folder.mkdir()
    for i, jpg in enumerate(sorted((flight / "images").glob("*.jpg"))):
        exif = Image.Exif()
        exif.load(b"Exif\x00\x00" + encode_exif(read_image_metadata(jpg)))
        rgb = np.asarray(Image.open(jpg).convert("RGB"), dtype=np.uint16)
        if rgb_too:
            (folder / f"DJI_{10 * i + 10:04d}.JPG").write_bytes(jpg.read_bytes())
        for k in range(5):
            band = rgb[:, :, min(k, 2)] * 16
            name = f"DJI_{10 * i + 11 + k:04d}.TIF" if rgb_too else f"IMG_{i:04d}_{k + 1}.tif"
            Image.fromarray(band).save(folder / name, exif=exif)


def test_a_multispectral_folder_is_refused_naming_the_cause(flight, tmp_path, cli_error):
    _bands(flight, tmp_path / "mica", rgb_too=False)
    with pytest.raises(InputError, match=r"mica: 5 images per capture \(same time and position\): a multispectral "
                                         r"or multi-camera rig\? map one band's images"):
        read_image_priors(tmp_path / "mica")
    err = cli_error("map", "--images", tmp_path / "mica", "--pose-source", "exif", "--out", tmp_path / "m")
    assert "5 images per capture" in err and not (tmp_path / "m").exists()


def test_the_rgb_image_of_each_capture_is_used_and_the_bands_named(flight, tmp_path, caplog):
    _bands(flight, tmp_path / "p4m", rgb_too=True)
    with caplog.at_level(logging.INFO):
        priors = read_image_priors(tmp_path / "p4m")
    assert len(priors.names) == 12 and all(n.endswith(".JPG") for n in priors.names)
    assert "6 images per capture" in caplog.text and "the 60 band images (.TIF) are left out" in caplog.text


def test_a_flight_of_one_image_per_capture_is_read_whole(flight):
    assert len(read_image_priors(flight / "images").names) == 12


def _with_exposure(jpg: Path, seconds: float | None) -> Image.Exif:
    """`jpg`'s tags, with ExposureTime `seconds` (None: none)."""
    exif = Image.Exif()
    exif.load(b"Exif\x00\x00" + encode_exif(read_image_metadata(jpg)))
    if seconds is not None:
        exif.get_ifd(0x8769)[0x829A] = seconds
    return exif


def test_bracketed_colour_exposures_at_one_fix_are_no_rig(flight, tmp_path, caplog):
    """Three colour frames per position and clock second (exposure bracketing: one view, three exposure times)
    were mapped before the rig check; they must not be refused as a multispectral camera, nor left out as
    copies of one exposure (their exposure times differ)."""
    folder = tmp_path / "bracketed"
    folder.mkdir()
    for i, jpg in enumerate(sorted((flight / "images").glob("*.jpg"))):
        for k in range(3):
            Image.open(jpg).save(folder / f"DJI_{3 * i + k:04d}.JPG", exif=_with_exposure(jpg, 1 / (250 * 2 ** k)))
    with caplog.at_level(logging.WARNING):
        priors = read_image_priors(folder)
    assert len(priors.names) == 36
    assert "exposure" not in caplog.text
    # rev26: nor a receiver updating slower than the camera, with GPS noise added for it
    assert "repeat the previous image's GPS fix" not in caplog.text
    assert priors.summary["gps_quantisation"] is None


@pytest.mark.parametrize("mode", ["L", "RGB"])
def test_one_gray_or_colour_camera_shooting_faster_than_its_clock_is_no_rig(flight, tmp_path, mode):
    """rev22: a lone NIR or thermal camera (one band) at 2 frames per second with whole-second EXIF times and a 1 Hz
    GPS gives two frames per (second, fix); it was refused as "a multispectral or multi-camera rig"."""
    folder = tmp_path / f"cam_{mode}"
    folder.mkdir()
    for i, jpg in enumerate(sorted((flight / "images").glob("*.jpg"))):
        exif = Image.Exif()
        exif.load(b"Exif\x00\x00" + encode_exif(read_image_metadata(jpg)))
        img = np.asarray(Image.open(jpg).convert(mode))
        for k in range(2):  # the second frame half a second on: the ground moved 6 px across it
            Image.fromarray(np.roll(img, 6 * k, axis=1)).save(folder / f"NIR_{2 * i + k:04d}.jpg", exif=exif)
    assert len(read_image_priors(folder).names) == 24


def test_an_edited_copy_of_an_image_is_one_exposure_left_out_and_named(flight, tmp_path, caplog):
    """nu42 D7: Lightroom-style copies ('frame_00010-Edit.jpg': auto-contrast, the original's tags) beside their
    originals replaced them as keyframes without a word (byte-identical copies were warned of, these were not).
    Same capture time, position and exposure and the same view: one exposure; the original is kept whatever the
    order of the names ('-' sorts before '.'), and the warning names both."""
    from PIL import ImageOps

    folder = tmp_path / "edited"
    folder.mkdir()
    jpgs = sorted((flight / "images").glob("*.jpg"))
    for i, jpg in enumerate(jpgs):
        (folder / jpg.name).write_bytes(jpg.read_bytes())
        if i in (3, 7):
            ImageOps.autocontrast(Image.open(jpg), cutoff=2).save(folder / f"{jpg.stem}-Edit.jpg",
                                                                  exif=_with_exposure(jpg, None))
    with caplog.at_level(logging.WARNING):
        priors = read_image_priors(folder)
    assert priors.names == [j.name for j in jpgs]
    said = [w for w in priors.summary["warnings"] if "repeat another's exposure" in w]
    assert len(said) == 1 and f"{jpgs[3].stem}-Edit.jpg (= {jpgs[3].name})" in said[0] and said[0] in caplog.text


def test_the_original_of_one_exposure_is_the_name_the_others_derive_from():
    from sosmatch.workflows.image_rigs import original_name

    assert original_name(["frame_00010-Edit.jpg", "frame_00010.jpg"]) == 1
    assert original_name(["copy of DJI_0001.JPG", "DJI_0001.JPG", "DJI_0001 (1).JPG"]) == 1
    assert original_name(["b.jpg", "a.jpg"]) == 1  # renamed: the shortest, then the first by name
