"""GPS kept in .xmp sidecars beside the images is named where the images' missing GPS is an error (nu42 D6)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sosmatch.database.exif import ImageMetadata
from sosmatch.database.exif_write import embed_metadata
from sosmatch.database.xmp_sidecar import sidecar_of, sidecars_with_gps, xmp_coordinate
from sosmatch.plugin.errors import InputError
from sosmatch.workflows import poses_from_exif as pfe

SIDECAR = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
           '<rdf:Description rdf:about="" xmlns:exif="http://ns.adobe.com/exif/1.0/" exif:GPSLatitude="{lat}" '
           'exif:GPSLongitude="{lon}"/></rdf:RDF></x:xmpmeta>')


def _image(path: Path) -> None:
    """A small JPEG with a focal length and DJI gimbal angles, but no GPS."""
    buf = io.BytesIO()
    Image.fromarray(np.zeros((60, 80, 3), np.uint8)).save(buf, "JPEG")
    xmp = {"GimbalYawDegree": "0.0", "GimbalPitchDegree": "-90.0", "GimbalRollDegree": "0.0"}
    path.write_bytes(embed_metadata(buf.getvalue(), ImageMetadata(path, 80, 60, focal_mm=4.5, focal_35mm=24.0,
                                                                  xmp=xmp)))


def test_xmp_coordinates_of_lightroom_and_exiftool():
    assert xmp_coordinate("42,30.123N") == pytest.approx(42 + 30.123 / 60)
    assert xmp_coordinate("7,59,30.6W") == pytest.approx(-(7 + 59 / 60 + 30.6 / 3600))
    assert xmp_coordinate("33,52.5s") == pytest.approx(-33.875)
    assert xmp_coordinate("42.5") is None and xmp_coordinate("") is None


def test_missing_gps_names_the_sidecars_that_hold_it(tmp_path):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(3):
        _image(img / f"f{k}.jpg")
    (img / "f0.xmp").write_text(SIDECAR.format(lat="46,59.95663407N", lon="7,59.98933953E"))
    (img / "f1.jpg.xmp").write_text(SIDECAR.format(lat="46,59.96N", lon="7,59.99E"))  # darktable's naming
    assert sidecar_of(img / "f1.jpg") == img / "f1.jpg.xmp" and sidecar_of(img / "f2.jpg") is None
    with pytest.raises(InputError, match=r"3 of 3 images have no GPS .*their \.xmp sidecars hold GPS \(2 of them, "
                                         r"e\.g\. f0\.xmp: 46\.999277, 7\.999822\).*exiftool -tagsfromfile %d%f\.xmp "
                                         r"\"-GPS:all<XMP-exif:all\""):
        pfe.run(img, tmp_path / "o" / "poses.csv")
    assert not (tmp_path / "o").exists()
    assert sidecars_with_gps([img / "f2.jpg"]) is None
    # darktable's `<image>.xmp` sidecars are named so in the copy (exiftool's %e: the image's extension)
    assert "-tagsfromfile %d%f.%e.xmp " in sidecars_with_gps([img / "f1.jpg"])
    (img / "f2.xmp").write_text("<x:xmpmeta broken")  # a damaged sidecar is no GPS, not a crash
    assert sidecars_with_gps([img / "f2.jpg"]) is None
