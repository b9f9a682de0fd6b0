"""The NAIP benchmark's negative-control rasters: halves and the mirror keep the georeference of the ground."""

import numpy as np
import rasterio
from rasterio.transform import from_origin

from sosmatch.tools.benchmarks.real_naip import half_orthophoto, mirrored_orthophoto


def _geotiff(path, width=9, height=4):
    data = np.arange(3 * height * width, dtype=np.uint8).reshape(3, height, width)
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=3, dtype="uint8",
                       crs="EPSG:26914", transform=from_origin(485900.0, 5209247.0, 5.0, 5.0)) as dst:
        dst.write(data)
    return data


def test_halves_share_no_ground_and_keep_world_coordinates(tmp_path):
    data = _geotiff(tmp_path / "a.tif")
    west = half_orthophoto(tmp_path / "a.tif", "west", tmp_path / "c" / "w.tif")
    east = half_orthophoto(tmp_path / "a.tif", "east", tmp_path / "c" / "e.tif")
    with rasterio.open(west) as w, rasterio.open(east) as e:
        assert w.width + e.width == 9 and w.crs.to_epsg() == e.crs.to_epsg() == 26914
        assert w.bounds.right == e.bounds.left == 485900.0 + 5.0 * w.width  # adjacent, not overlapping
        assert np.array_equal(w.read(), data[:, :, : w.width]) and np.array_equal(e.read(), data[:, :, w.width:])
    assert not list((tmp_path / "c").glob("*.tmp.tif"))


def test_mirror_flips_east_west_in_place(tmp_path):
    data = _geotiff(tmp_path / "a.tif")
    out = mirrored_orthophoto(tmp_path / "a.tif", tmp_path / "m.tif")
    with rasterio.open(out) as m, rasterio.open(tmp_path / "a.tif") as a:
        assert m.bounds == a.bounds and np.array_equal(m.read(), data[:, :, ::-1])
