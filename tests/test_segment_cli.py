"""`sosmatch segment` end to end, and robust image reading (8/16-bit, gray, alpha, corrupt files)."""

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sosmatch.database.flight_levels import flight_white_level
from sosmatch.database.images import list_images, read_gray, read_image
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main


def _scene(h=240, w=320, seed=0):
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), (150, 100, 90), np.uint8)
    img = np.clip(img + rng.normal(0, 6, (h, w, 1)), 0, 255).astype(np.uint8)
    cv2.circle(img, (80, 80), 25, (40, 150, 60), -1)
    cv2.circle(img, (220, 150), 30, (230, 230, 240), -1)
    cv2.rectangle(img, (40, 170), (100, 220), (60, 60, 200), -1)
    return img


def test_read_image_variants(tmp_path):
    rgb = _scene()
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    Image.fromarray(np.dstack([rgb, np.full(rgb.shape[:2], 128, np.uint8)])).save(tmp_path / "rgba.png")
    gray = rgb[:, :, 1]
    Image.fromarray(gray).save(tmp_path / "gray.png")
    cv2.imwrite(str(tmp_path / "gray16.png"), gray.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "rgb16.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "gray12.tif"), gray.astype(np.uint16) * 16)  # 12-bit data in 16 bits
    Image.fromarray(rgb).save(tmp_path / "rgb.jpg", quality=95)
    assert np.array_equal(read_image(tmp_path / "rgb.png"), rgb)
    assert np.array_equal(read_image(tmp_path / "rgba.png"), rgb)
    for name in ("gray.png", "gray16.png", "gray12.tif"):
        out = read_image(tmp_path / name)
        assert out.shape == rgb.shape and out.dtype == np.uint8
        assert np.abs(out[:, :, 0].astype(int) - gray).max() <= 1, name
        assert np.array_equal(out[:, :, 0], out[:, :, 2])
    assert np.abs(read_image(tmp_path / "rgb16.png").astype(int) - rgb).max() <= 1
    assert np.abs(read_image(tmp_path / "rgb.jpg").astype(int) - rgb).mean() < 3


@pytest.mark.parametrize("bits", [10, 12, 14])
def test_sensor_data_in_16_bits_reads_at_its_bit_depth(tmp_path, bits):
    """12-bit data in a 16-bit RGB TIFF or PNG came out nearly black (max 15 of 255: PIL keeps the high byte of
    16-bit colour), and 14-bit gray at a quarter of its range: a map of such a flight was refused for want of
    landmarks. Colour beyond 8 bits is decoded whole now and every such image is read from its sensor's white
    level (2^bits - 1)."""
    rgb = _scene()
    scale = (2**bits - 1) / 255.0
    for name, pixels in (("rgb.tif", rgb), ("rgb.png", rgb), ("gray.tif", rgb[:, :, 1]), ("gray.png", rgb[:, :, 1])):
        data = np.rint(pixels.astype(np.float64) * scale).astype(np.uint16)
        cv2.imwrite(str(tmp_path / name), cv2.cvtColor(data, cv2.COLOR_RGB2BGR) if data.ndim == 3 else data)
        out = read_image(tmp_path / name)
        want = rgb if data.ndim == 3 else np.dstack([rgb[:, :, 1]] * 3)
        assert np.abs(out.astype(int) - want).max() <= 1, name
        assert flight_white_level([tmp_path / name]) == 2**bits - 1
        # the tie points' gray reader too (nu15: OpenCV alone kept the high byte, 12-bit data 16 times too dark)
        gray = read_gray(tmp_path / name, 2**bits - 1)
        want_gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if data.ndim == 3 else rgb[:, :, 1]
        assert gray.dtype == np.uint8 and np.abs(gray.astype(int) - want_gray).max() <= 2, name


def test_a_flights_white_level_is_the_cameras_not_the_frames(tmp_path):
    """A dark frame of a 16-bit flight (its maximum below 4096) was read as 12-bit data, 16 times brighter than
    its neighbours. The white level is the flight's (`flight_white_level`, from a sample of its images), so the
    frame keeps its exposure; 8-bit flights have none (told from the headers)."""
    gray = _scene()[:, :, 1].astype(np.float64)
    paths = []
    for k, gain in enumerate((257.0, 257.0, 257.0 / 20.0, 257.0)):  # the third frame 20 times darker
        paths.append(tmp_path / f"f{k}.tif")
        cv2.imwrite(str(paths[-1]), np.rint(gray * gain).astype(np.uint16))
    white = flight_white_level(paths)
    assert white == 65535
    dark, bright = read_image(paths[2], white), read_image(paths[0], white)
    assert abs(float(dark.mean()) * 20.0 / float(bright.mean()) - 1.0) < 0.05
    assert read_image(paths[2]).mean() > 10 * dark.mean()  # what the frame alone says: 16x too bright
    Image.fromarray(_scene()).save(tmp_path / "a.jpg")
    assert flight_white_level([tmp_path / "a.jpg"]) is None and flight_white_level([]) is None


def test_a_folder_without_images_says_what_it_holds_instead(tmp_path):
    """A drone folder of raw DNG files, a DCIM folder whose images are one level down, or a folder of videos gave
    only "no images in directory"; the error now says what to do."""
    from sosmatch.database.images import no_images_message

    raw = tmp_path / "raw"
    raw.mkdir()
    for k in range(3):
        (raw / f"DJI_{k:04d}.DNG").write_bytes(b"II*\x00")
    assert "its 3 DNG files are camera raw" in no_images_message(raw)
    dcim = tmp_path / "DCIM"
    (dcim / "100MEDIA").mkdir(parents=True)
    Image.fromarray(_scene()).save(dcim / "100MEDIA" / "a.jpg")
    assert "folder(s) below hold images (e.g. 100MEDIA)" in no_images_message(dcim)
    (tmp_path / "video").mkdir()
    (tmp_path / "video" / "flight.MP4").write_bytes(b"\x00")
    assert "video files" in no_images_message(tmp_path / "video")
    assert main(["segment", str(raw), "--out", str(tmp_path / "o"), "-q"]) == 2


def test_bad_images_raise_input_error_naming_the_file(tmp_path):
    Image.fromarray(_scene()).save(tmp_path / "ok.jpg", quality=90)
    data = (tmp_path / "ok.jpg").read_bytes()
    (tmp_path / "truncated.jpg").write_bytes(data[: len(data) // 2])
    (tmp_path / "garbage.png").write_bytes(b"not an image at all" * 10)
    (tmp_path / "empty.jpg").write_bytes(b"")
    for name in ("truncated.jpg", "garbage.png", "empty.jpg", "missing.jpg"):
        with pytest.raises(InputError) as err:
            read_image(tmp_path / name)
        assert name in str(err.value)
    assert [p.name for p in list_images([tmp_path])] == ["empty.jpg", "garbage.png", "ok.jpg", "truncated.jpg"]
    with pytest.raises(InputError, match="nowhere"):
        list_images([tmp_path / "nowhere"])


def test_cli_directory_run_skips_bad_files_and_exits_nonzero(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    Image.fromarray(_scene(seed=1)).save(src / "a.png")
    Image.fromarray(_scene(seed=2)[:, :, 0]).save(src / "b_gray.png")
    Image.fromarray(np.zeros((120, 160, 3), np.uint8)).save(src / "c_black.png")  # no masks: not an error
    (src / "d_corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0 broken")
    Image.fromarray(_scene(seed=3)[:1]).save(src / "e_one_row.png")  # refused by the backend (rev50 D1)
    out = tmp_path / "out"
    code = main(["segment", str(src), "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "d_corrupt.jpg" in err and "e_one_row.png: image of 320x1 px is too small" in err
    assert "Traceback" not in err
    for name in ("a.png", "b_gray.png", "c_black.png"):
        assert (out / f"{name}.png").is_file()
        doc = json.loads((out / f"{name}.json").read_text())
        assert doc["width"] == 320 or name == "c_black.png"
    a = json.loads((out / "a.png.json").read_text())
    assert len(a["masks"]) >= 3
    # the white disc at (220, 150) (OpenCV) is (220.5, 150.5) in COLMAP pixels
    assert min(np.hypot(m["centroid"][0] - 220.5, m["centroid"][1] - 150.5) for m in a["masks"]) < 1.5
    assert json.loads((out / "c_black.png.json").read_text())["masks"] == []
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 6 and "d_corrupt.jpg" in rows[-2] and "too small" in rows[-1]
    overlay = cv2.imread(str(out / "a.png.png"))
    assert overlay.shape == (240, 320, 3) and not np.array_equal(overlay[..., ::-1], _scene(seed=1))
    # only good files: exit 0 (another set of images over a complete output needs --overwrite); a missing input is
    # a one-line user error
    assert main(["segment", str(src / "a.png"), "--out", str(out), "-q"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["segment", str(src / "a.png"), "--out", str(out), "-q", "--overwrite"]) == 0
    assert main(["segment", str(tmp_path / "nothing"), "--out", str(out), "-q"]) == 2
    assert main(["segment", str(src / "a.png"), "--out", str(out), "--backend", "nope", "-q"]) == 2
    # rev55 D8: the option and its choices, not the internal SegmentationParams.backend
    assert "error: --backend must be one of 'classical', 'sam-onnx', got 'nope'" in capsys.readouterr().err


def test_images_of_one_stem_keep_their_own_outputs_and_summary_rows_are_csv(tmp_path):
    """rev35: outputs were named by the stem, so x.jpg's x.json and overlay x.png were overwritten by x.png's
    (exit 0, summary.csv listing both); and summary.csv was joined by hand, so `a,b.jpg` made a 10-field row under
    the 9-field header. Outputs are named by the whole file name now (as COLMAP names an image's outputs) and the
    summary is written by the csv module."""
    import csv

    src = tmp_path / "in"
    src.mkdir()
    Image.fromarray(_scene(seed=1)).save(src / "x.jpg", quality=95)
    Image.fromarray(_scene(seed=2, h=200)).save(src / "x.png")
    Image.fromarray(_scene(seed=3)).save(src / "a,b.jpg", quality=95)
    out = tmp_path / "out"
    assert main(["segment", str(src), "--out", str(out), "-q"]) == 0
    assert json.loads((out / "x.jpg.json").read_text())["image"] == "x.jpg"
    assert json.loads((out / "x.png.json").read_text())["height"] == 200
    assert cv2.imread(str(out / "x.jpg.png")).shape[0] == 240 and cv2.imread(str(out / "x.png.png")).shape[0] == 200
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert {len(r) for r in rows} == {9} and sorted(r[0] for r in rows[1:]) == ["a,b.jpg", "x.jpg", "x.png"]


def test_a_re_run_replaces_the_outputs_an_earlier_version_named_by_the_stem(tmp_path):
    """rev36: a re-run over an output of an earlier sosmatch (NAME.json / NAME.png, the same identity) wrote
    NAME.EXT.json / .png beside the old files, which stayed (one holding the wrong image where x.png's had replaced
    x.jpg's). The old outputs of an image of the run go; a file segment did not make for it stays."""
    src = tmp_path / "in"
    src.mkdir()
    Image.fromarray(_scene(seed=1)).save(src / "f0.jpg", quality=95)
    Image.fromarray(_scene(seed=2)).save(src / "f1.jpg", quality=95)
    out = tmp_path / "out"
    assert main(["segment", str(src), "--out", str(out), "-q"]) == 0
    for name in ("f0", "f1"):  # as an earlier version named them
        (out / f"{name}.jpg.json").rename(out / f"{name}.json")
        (out / f"{name}.jpg.png").rename(out / f"{name}.png")
    (out / "f1.json").write_text(json.dumps({"image": "other.jpg"}))  # not made for an image of this run
    marker = json.loads((out / ".sosmatch-output.json").read_text())
    del marker["files"]  # an earlier version's marker records no files: its files are taken as segment's
    (out / ".sosmatch-output.json").write_text(json.dumps(marker))
    assert main(["segment", str(src), "--out", str(out), "-q"]) == 0
    left = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert "f0.json" not in left and "f0.png" not in left
    assert {"f0.jpg.json", "f0.jpg.png", "f1.jpg.json", "f1.jpg.png", "f1.json", "f1.png"} <= set(left)


def test_images_of_one_file_name_in_two_folders_are_refused_up_front(tmp_path, capsys):
    """rev35: `segment a b` with a/x.jpg and b/x.jpg wrote one x.json holding b's image, exit 0. Refused now
    before anything is written, as `map` refuses them: one line naming both images."""
    for folder, seed in (("a", 1), ("b", 2)):
        (tmp_path / folder).mkdir()
        Image.fromarray(_scene(seed=seed)).save(tmp_path / folder / "x.jpg", quality=95)
    out = tmp_path / "out"
    assert main(["segment", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "a" / "x.jpg") in err[0] and str(tmp_path / "b" / "x.jpg") in err[0]
    assert not out.exists()
    # one image given twice (a folder and a file of it): said so, not as two images
    assert main(["segment", str(tmp_path / "a"), str(tmp_path / "a" / "x.jpg"), "--out", str(out), "-q"]) == 2
    assert "given twice" in capsys.readouterr().err and not out.exists()


def test_big_endian_16_bit_gray_tiff_reads(tmp_path):
    """rev17: PIL hands a big-endian 16-bit gray TIFF over as dtype >u2, which the reader refused as an
    unsupported pixel type (before and after the white-level change)."""
    tifffile = pytest.importorskip("tifffile")
    gray = _scene()[:, :, 1].astype(np.uint16) * 257
    tifffile.imwrite(tmp_path / "be.tif", gray, byteorder=">")
    out = read_image(tmp_path / "be.tif")
    assert np.abs(out[:, :, 0].astype(int) - _scene()[:, :, 1]).max() <= 1


def test_folders_given_together_keep_their_own_white_level(tmp_path):
    """rev17: `segment A B` read both folders at one white level, so a 12-bit camera's images beside a 16-bit
    camera's came out 16 times too dark and lost most of their segments. Each folder keeps its own."""
    from sosmatch.workflows.segment import run

    scene = _scene()
    for folder, bits in (("twelve", 12), ("sixteen", 16)):
        (tmp_path / folder).mkdir()
        data = np.rint(scene.astype(np.float64) * (2**bits - 1) / 255.0).astype(np.uint16)
        cv2.imwrite(str(tmp_path / folder / f"{folder}.tif"), cv2.cvtColor(data, cv2.COLOR_RGB2BGR))
    alone = run([tmp_path / "twelve"], tmp_path / "out_alone", write_overlays=False)
    together = run([tmp_path / "twelve", tmp_path / "sixteen"], tmp_path / "out_both", write_overlays=False)
    masks = {r.path.name: r.num_masks for r in together.images}
    assert alone.images[0].num_masks >= 3
    assert masks["twelve.tif"] == alone.images[0].num_masks == masks["sixteen.tif"]


def test_signed_16_bit_gray_reads_in_both_readers(tmp_path):
    """rev18: OpenCV hands the tie points' gray reader a signed 16-bit TIFF as int16, which it refused; both
    readers read it now (values below 0 are no light)."""
    tifffile = pytest.importorskip("tifffile")
    gray = _scene()[:, :, 1].astype(np.int16) * 16  # 12-bit data
    tifffile.imwrite(tmp_path / "s.tif", gray, photometric="minisblack")
    out = read_gray(tmp_path / "s.tif", 4095)
    assert out.dtype == np.uint8 and np.abs(out.astype(int) - _scene()[:, :, 1]).max() <= 1
    assert read_image(tmp_path / "s.tif").shape == (*gray.shape, 3)
