"""The JPEG quality of a flight's images from their quantization tables (`plugin.jpeg_quality`), and what the map's
verdict says of a heavily compressed flight (the 35th new-user sweep: `synth --jpeg-quality 15` kept 160 of 205
landmarks with exit 0 and no word, its image figures reading better than the clean flight's)."""

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from sosmatch.plugin.image_quality import image_figures
from sosmatch.plugin.jpeg_quality import flight_compression, ijg_table, jpeg_quality, quality_of_table


def _ground(seed: int = 0, size: int = 160) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 2.0)
    return np.clip(128 + img * (30.0 / img.std()), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("quality", [1, 7, 15, 25, 40, 50, 51, 60, 75, 88, 95, 100])
def test_the_quality_is_read_exactly_from_what_opencv_and_pillow_write(tmp_path, quality):
    rgb = np.dstack([_ground(1), _ground(2), _ground(3)])
    ok, buf = cv2.imencode(".jpg", rgb, [cv2.IMWRITE_JPEG_QUALITY, quality])
    (tmp_path / "cv.jpg").write_bytes(buf.tobytes())
    Image.fromarray(rgb).save(tmp_path / "pil.jpg", quality=quality)
    assert jpeg_quality(tmp_path / "cv.jpg") == jpeg_quality(tmp_path / "pil.jpg") == quality


def test_the_nearest_ijg_table_stands_for_an_encoder_s_own_table():
    own = ijg_table(30) * np.exp(np.random.default_rng(0).normal(0, 0.08, 64))  # another encoder's rounding
    assert abs(quality_of_table(np.maximum(np.rint(own), 1)) - 30) <= 2
    with pytest.raises(ValueError):
        quality_of_table([0] * 64)


def test_a_flight_s_compression_from_its_headers(tmp_path):
    paths = []
    for k, q in enumerate([15, 15, 20, 15, 90]):
        p = tmp_path / f"f{k}.jpg"
        Image.fromarray(_ground(k)).save(p, quality=q)
        paths.append(p)
    (tmp_path / "broken.jpg").write_bytes(b"\xff\xd8\xff\xdb\x00")  # truncated: skipped, its reader names it
    cv2.imwrite(str(tmp_path / "lossless.png"), _ground(9))
    c = flight_compression([*paths, tmp_path / "broken.jpg", tmp_path / "lossless.png"])
    assert (c.quality, c.lowest, c.samples, c.jpeg) == (15.0, 15, 7, 5)
    assert flight_compression([tmp_path / "lossless.png"]).quality is None
    assert flight_compression([]).to_dict() == {"quality": None, "lowest": None, "samples": 0, "jpeg": 0}


def test_compression_smooths_the_noise_figure_but_the_table_says_it(tmp_path):
    """Why the figures cannot be the measure: a quality-15 image reads less noisy than its original."""
    noisy = np.clip(_ground(4, 320) + np.random.default_rng(4).normal(0, 3, (320, 320)), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, 15])
    assert image_figures(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE), 400)[0] < image_figures(noisy, 400)[0]
    assert jpeg_quality(io.BytesIO(buf.tobytes())) == 15
