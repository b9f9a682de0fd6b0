"""COLMAP reads images of more than 8 bits as white-levelled 8-bit copies (`sfm.colmap_image_dir`): 12-bit data
in 16-bit TIFFs (a MicaSense band) reached COLMAP's SIFT at 1/16 of its contrast and registered nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sosmatch.database.exif import read_image_metadata
from sosmatch.database.exif_write import encode_exif
from sosmatch.plugin.params import Params, with_overrides
from sosmatch.tools.cli import main
from sosmatch.workflows import poses as poses_wf
from sosmatch.workflows import sfm


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bits") / "flight"
    assert main(["synth", "--out", str(out), "--frames", "20", "--width", "320", "--height", "240", "--world-size",
                 "400", "--line-length", "100", "--geotags", "dji", "-q"]) == 0
    return out


def _twelve_bit_tiffs(flight: Path, folder: Path) -> list[str]:
    """The flight's frames as single-band 12-bit data in 16-bit TIFFs with their EXIF (GPS, time, camera)."""
    folder.mkdir()
    names = []
    for jpg in sorted((flight / "images").glob("*.jpg")):
        gray = np.asarray(Image.open(jpg).convert("L"), dtype=np.float64)
        exif = Image.Exif()
        exif.load(b"Exif\x00\x00" + encode_exif(read_image_metadata(jpg)))
        name = jpg.stem + ".tif"
        Image.fromarray(np.rint(gray * 4095 / 255).astype(np.uint16)).save(folder / name, exif=exif)
        names.append(name)
    return names


def test_a_12_bit_flight_in_16_bit_tiffs_registers(flight, tmp_path):
    images = tmp_path / "band"
    names = _twelve_bit_tiffs(flight, images)
    result = poses_wf.run(images, tmp_path / "poses", with_overrides(Params(), {"sfm.max_features": 1500}))
    assert len(result.poses) == len(names)  # before: 0 registered ("the images do not overlap ...")
    assert sorted(result.poses.names) == names  # the model names the user's files


def test_8_bit_copies_are_white_levelled_and_reused_and_8_bit_folders_are_read_in_place(flight, tmp_path):
    images = tmp_path / "band"
    names = _twelve_bit_tiffs(flight, images)[:3]
    work = tmp_path / "work"
    assert sfm.colmap_image_dir(images, names, work) == work
    copy = np.asarray(Image.open(work / names[0]))
    frame = np.asarray(Image.open(flight / "images" / names[0].replace(".tif", ".jpg")).convert("L"))
    assert copy.dtype == np.uint8 and copy.ndim == 2  # 12 bits -> the 8-bit range, not 1/16 of it
    assert np.abs(copy.astype(int) - frame).max() <= 1
    stamp = (work / names[0]).stat().st_mtime_ns
    assert sfm.colmap_image_dir(images, names, work) == work and (work / names[0]).stat().st_mtime_ns == stamp
    jpgs = [p.name for p in sorted((flight / "images").glob("*.jpg"))]
    assert sfm.colmap_image_dir(flight / "images", jpgs, tmp_path / "none") == flight / "images"
    assert not (tmp_path / "none").exists()  # an 8-bit flight costs nothing


def test_a_copy_is_made_again_when_its_image_changes(flight, tmp_path):
    """rev22: the copies were reused by name alone, so after the user replaced an image a re-run fed COLMAP the old
    pixels."""
    images = tmp_path / "band"
    names = _twelve_bit_tiffs(flight, images)[:3]
    work = tmp_path / "work"
    sfm.colmap_image_dir(images, names, work)
    before = np.asarray(Image.open(work / names[0])).astype(int)
    exif = Image.open(images / names[0]).getexif()
    dark = np.asarray(Image.open(images / names[0])).astype(np.float64) / 4
    Image.fromarray(np.rint(dark).astype(np.uint16)).save(images / names[0], exif=exif)
    sfm.colmap_image_dir(images, names, work)
    after = np.asarray(Image.open(work / names[0])).astype(int)
    assert abs(after.mean() - before.mean() / 4) < 2  # the new image's pixels, not the old copy
