"""OpenDroneMap's geo.txt as a positions source (database.geo_txt; nu58 D4): read wherever a telemetry file is
taken, named beside images without GPS, refused on one line naming the file and line."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Transformer

from sosmatch.database.geo_txt import read_geo_txt
from sosmatch.database.telemetry_io import read_telemetry_csv
from sosmatch.plugin.errors import InputError
from sosmatch.workflows import poses_from_exif as pfe

from .test_exif import write_jpeg

LATS = [47.0, 47.0, 47.0, 47.0]
LONS = [-99.0 + k * 1e-4 for k in range(4)]


def test_geo_txt_rows_in_lon_lat_order_and_in_a_projected_crs(tmp_path):
    geo = tmp_path / "geo.txt"
    geo.write_text("EPSG:4326\n" + "".join(f"f{k}.jpg {LONS[k]!r} {LATS[k]!r} 512.5 0 0 0 1.0 2.0\n"
                                           for k in range(4)))
    rows = read_telemetry_csv(geo)  # the telemetry reader takes it (it refused: "needs an image name column")
    assert rows["f2.jpg"] == {"lat": 47.0, "lon": LONS[2], "alt": 512.5}
    # UTM as ODM writes it (easting first), in both of ODM's spellings of the CRS; no height: no alt
    e, n = Transformer.from_crs(4326, 32614, always_xy=True).transform(LONS, LATS)
    for crs in ("EPSG:32614", "WGS84 UTM 14N"):
        geo.write_text(f"{crs}\n" + "".join(f"f{k}.jpg {e[k]:.3f} {n[k]:.3f}\n" for k in range(4)))
        rows = read_geo_txt(geo)
        np.testing.assert_allclose([rows[f"f{k}.jpg"]["lon"] for k in range(4)], LONS, atol=1e-7)
        np.testing.assert_allclose([rows[f"f{k}.jpg"]["lat"] for k in range(4)], LATS, atol=1e-7)
        assert "alt" not in rows["f0.jpg"]


@pytest.mark.parametrize("body, where, what", [
    ("EPSG:4326\nf0.jpg -99.0\n", ":2", "needs image_name geo_x geo_y"),
    ("EPSG:4326\nf0.jpg -99.0 47.0\nf1.jpg x 47.0\n", ":3", "non-numeric coordinate"),
    ("EPSG:4326\nf0.jpg -99.0 47.0\nf0.jpg -99.0 47.0\n", ":3", "f0.jpg is given twice (also line 2)"),
    ("EPSG:4326\nf0.jpg 47.0 -99.0\n", ":2", "off the globe in EPSG:4326 (geo_x is the longitude"),
    ("EPSG:999999\nf0.jpg 1 2\n", ":1", "not one pyproj knows"),
])
def test_a_bad_geo_txt_is_one_line_naming_the_file_and_line(tmp_path, cli_error, body, where, what):
    img = tmp_path / "images"
    img.mkdir()
    write_jpeg(img / "f0.jpg", None, None)
    geo = tmp_path / "geo.txt"
    geo.write_text(body)
    err = cli_error("poses-from-exif", img, "--telemetry", geo, "--out", tmp_path / "p.csv")
    assert f"geo.txt{where}" in err and what in err


def test_geo_txt_beside_images_without_gps_is_named_and_taken_when_given(tmp_path, caplog):
    img = tmp_path / "images"
    img.mkdir()
    for k in range(4):
        write_jpeg(img / f"f{k}.jpg", None, None)
    geo = img / "geo.txt"
    geo.write_text("EPSG:4326\n" + "".join(f"f{k}.jpg {LONS[k]!r} {LATS[k]!r} 500.0\n" for k in range(4)))
    with pytest.raises(InputError, match=r"geo.txt \(OpenDroneMap's image positions\) is not read by itself: "
                                         r"give it with --telemetry .*geo.txt"):
        pfe.poses_from_images(img)
    res = pfe.poses_from_images(img, telemetry=geo)
    assert res.summary["position_sources"] == {"telemetry CSV": 4} and res.summary["crs"] == "EPSG:32614"
    np.testing.assert_allclose(np.linalg.norm(np.diff(res.poses.centers[:, :2], axis=0), axis=1), 7.58, atol=0.05)
    # beside images that have GPS: the user hears that it is not what the positions come from
    for k in range(4):
        write_jpeg(img / f"f{k}.jpg", LATS[k], LONS[k], 500.0)
    pfe.poses_from_images(img)
    assert "the positions are the images' own GPS; " in caplog.text and "give it with --telemetry" in caplog.text


def test_a_geo_txt_with_latitude_and_longitude_swapped_is_refused_when_the_images_gps_says_so(tmp_path, cli_error):
    """rev56 D7: EPSG:4326 rows written latitude first (47 8: Switzerland) read as a point off Somalia whenever
    both are within +-90. The images' own GPS tells: read the other way round, the rows lie on it."""
    img = tmp_path / "images"
    img.mkdir()
    lats, lons = [47.0 + k * 1e-4 for k in range(8)], [8.0 + (k % 2) * 2e-4 for k in range(8)]
    for k in range(8):
        write_jpeg(img / f"f{k}.jpg", lats[k], lons[k], 500.0)
    geo = tmp_path / "geo.txt"
    geo.write_text("EPSG:4326\n" + "".join(f"f{k}.jpg {lats[k]!r} {lons[k]!r} 500.0\n" for k in range(8)))
    err = cli_error("poses-from-exif", img, "--telemetry", geo, "--out", tmp_path / "p.csv")
    assert "geo.txt" in err and "latitude and longitude look swapped" in err and "longitude first" in err
    # in the right order it is taken
    geo.write_text("EPSG:4326\n" + "".join(f"f{k}.jpg {lons[k]!r} {lats[k]!r} 500.0\n" for k in range(8)))
    assert pfe.poses_from_images(img, telemetry=geo).summary["position_sources"] == {"telemetry CSV": 8}


def test_a_geo_txt_read_says_where_its_first_image_lies(tmp_path, caplog):
    """Without the images' own GPS nothing tells a swapped EPSG:4326 file (rev56 D7): the log says the place."""
    geo = tmp_path / "geo.txt"
    geo.write_text("EPSG:4326\nf0.jpg 47.0 8.0 520\n")
    with caplog.at_level("INFO"):
        read_geo_txt(geo)
    assert "1 image positions in EPSG:4326, f0.jpg at lat 8.000000, lon 47.000000" in caplog.text
