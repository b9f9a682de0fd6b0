"""`sosmatch segment` end to end, and robust image reading (8/16-bit, gray, alpha, corrupt files)."""

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from sosmatch.database.images import list_images, read_image
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
    out = tmp_path / "out"
    code = main(["segment", str(src), "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "d_corrupt.jpg" in err
    for stem in ("a", "b_gray", "c_black"):
        assert (out / f"{stem}.png").is_file()
        doc = json.loads((out / f"{stem}.json").read_text())
        assert doc["width"] == 320 or stem == "c_black"
    a = json.loads((out / "a.json").read_text())
    assert len(a["masks"]) >= 3
    # the white disc at (220, 150) (OpenCV) is (220.5, 150.5) in COLMAP pixels
    assert min(np.hypot(m["centroid"][0] - 220.5, m["centroid"][1] - 150.5) for m in a["masks"]) < 1.5
    assert json.loads((out / "c_black.json").read_text())["masks"] == []
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 5 and "d_corrupt.jpg" in rows[-1]
    overlay = cv2.imread(str(out / "a.png"))
    assert overlay.shape == (240, 320, 3) and not np.array_equal(overlay[..., ::-1], _scene(seed=1))
    # only good files: exit 0 (another set of images over a complete output needs --overwrite); a missing input is
    # a one-line user error
    assert main(["segment", str(src / "a.png"), "--out", str(out), "-q"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["segment", str(src / "a.png"), "--out", str(out), "-q", "--overwrite"]) == 0
    assert main(["segment", str(tmp_path / "nothing"), "--out", str(out), "-q"]) == 2
    assert main(["segment", str(src / "a.png"), "--out", str(out), "--backend", "nope", "-q"]) == 2
