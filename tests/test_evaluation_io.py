"""Evaluation inputs: terrain.npz layouts, landmarks.csv observers, match.json hypotheses."""

import json

import numpy as np
import pytest

from sosmatch.database.evaluation_io import (
    read_dem,
    read_landmark_table,
    read_match_hypotheses,
    read_terrain_npz,
    terrain_of_session,
)
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.evaluation.footprints import FlatGround


def _dem(path, epsg):
    import rasterio
    from affine import Affine

    with rasterio.open(path, "w", driver="GTiff", width=10, height=8, count=1, dtype="float32",
                       crs=f"EPSG:{epsg}" if epsg else None,
                       transform=Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 5200080.0)) as d:
        d.write(np.full((1, 8, 10), 300.0, np.float32))
    return path


def test_a_dem_of_another_crs_or_area_than_the_poses_is_refused_naming_it(tmp_path):
    """rev55 D4: `evaluate --dem` with a raster in another CRS than the poses (or none), or beside the flights, gave
    every footprint 0 m^2 and the refusal blamed the flights ("do not overlap")."""
    utm, local = _dem(tmp_path / "utm.tif", 26914), _dem(tmp_path / "local.tif", 0)
    inside = np.array([[500010.0, 5200010.0], [500090.0, 5200070.0]])
    assert read_dem(utm, 26914, inside).z_range == (300.0, 300.0)
    assert read_dem(local, 0, inside).z_range == (300.0, 300.0)  # a local DEM for local poses
    for dem, epsg, said in ((utm, 0, "utm.tif: elevation raster is in EPSG:26914 but P is in a local"),
                            (utm, 32618, "is in EPSG:26914 but P is in EPSG:32618"),
                            (local, 26914, r"local.tif: elevation raster is in a local frame \(no CRS\) but")):
        with pytest.raises(InputError, match=said):
            read_dem(dem, epsg, inside, "P")
    with pytest.raises(InputError, match=r"utm.tif: elevation raster .* does not cover 1 of the 2 cameras of P, "
                                         r"e.g. at \(0, 0\)"):
        read_dem(utm, 26914, np.array([[500010.0, 5200010.0], [0.0, 0.0]]), "P")


def test_synth_terrain_layout(tmp_path):
    heights = np.arange(12, dtype=np.float32).reshape(3, 4)  # rows north (+y), columns east (+x)
    np.savez(tmp_path / "terrain.npz", heights=heights, x0=np.float64(-10), y0=np.float64(5),
             resolution_m=np.float64(2.0))
    t = read_terrain_npz(tmp_path / "terrain.npz")
    assert np.isclose(t(np.array([-10.0 + 2 * 3]), np.array([5.0 + 2 * 2]))[0], heights[2, 3])
    assert np.isclose(t(np.array([-9.0]), np.array([5.0]))[0], 0.5)
    assert terrain_of_session(tmp_path).z_range == (0.0, 11.0)
    assert isinstance(terrain_of_session(tmp_path / "none", ground_height=4.0), FlatGround)
    np.savez(tmp_path / "bad.npz", nothing=np.zeros(3))
    with pytest.raises(InputError, match="no height grid"):
        read_terrain_npz(tmp_path / "bad.npz")


@pytest.mark.parametrize("damage", ["truncated", "empty", "npy", "pickled"])
def test_a_damaged_terrain_npz_is_one_line_for_both_of_its_readers(tmp_path, damage):
    """terrain.npz is read by the evaluation (any DEM layout) and by the synthetic session. Before: a truncated
    file was zipfile.BadZipFile and an empty one EOFError out of `evaluate` (a traceback, exit 1)."""
    from sosmatch.database.synth_session import read_terrain_npz as read_synth_terrain

    path = tmp_path / "terrain.npz"
    np.savez(path, heights=np.zeros((4, 4), np.float32), x0=0.0, y0=0.0, resolution_m=1.0)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "npy":
        np.save(tmp_path / "t.npy", np.zeros(3))
        path.write_bytes((tmp_path / "t.npy").read_bytes())
    else:
        np.savez(path, heights=np.array([{"a": 1}], dtype=object))
    for reader in (read_terrain_npz, read_synth_terrain):
        with pytest.raises(InputError) as err:
            reader(path)
        assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)


def test_landmark_table(tmp_path):
    p = tmp_path / "landmarks.csv"
    p.write_text("index,point3d_id,x,y,z,size_m,num_observations,image_names\n"
                 "1,7,1,2,3,,2,b.jpg c.jpg\n0,5,4,5,6,1.5,1,a.jpg\n")
    t = read_landmark_table(p)
    assert t.image_names == [["a.jpg"], ["b.jpg", "c.jpg"]]
    assert np.allclose(t.positions, [[4, 5, 6], [1, 2, 3]]) and t.sizes[0] == 1.5 and np.isnan(t.sizes[1])
    p.write_text("index,x,y,z,size_m,image_names\n0,1,2,3,1,a\n2,1,2,3,1,a\n")
    with pytest.raises(InputError, match="without gaps"):
        read_landmark_table(p)


def test_match_hypotheses_gravity_and_sizes(tmp_path):
    tf = {"rotation": np.eye(3).tolist(), "translation": [0, 0, 0], "scale": 1.0}
    data = {"hypotheses": [
        {"associations": [[0, 1], [2, 3], [4, 5]], "tilt_deg": 1.0, "transform": tf, "accepted": False},
        {"associations": [[0, 1], [2, 3], [4, 5], [6, 7]], "tilt_deg": 40.0, "transform": tf, "accepted": False},
        {"associations": [[1, 1]], "transform": None},
    ], "timings": {"total_s": 1.25}, "params": {"association": {"min_associations": 2}}}
    (tmp_path / "match.json").write_text(json.dumps(data))
    h = read_match_hypotheses(tmp_path)
    assert h.sizes.tolist() == [3, 4, 1] and h.gravity_ok.tolist() == [True, False, False]
    assert h.seconds == 1.25 and h.min_associations == 2
    (tmp_path / "match.json").write_text("{}")
    with pytest.raises(InputError, match="hypotheses"):
        read_match_hypotheses(tmp_path / "match.json")


def test_a_label_image_of_another_depth_or_size_is_refused(tmp_path):
    """Object ids are looked up at the mask centroids' pixels. Before: an 8-bit label (ids wrapped at 256) or
    one of another size (every lookup clipped to its border) was read, and `evaluate` counted the landmarks'
    objects wrong with exit 0."""
    import cv2

    from sosmatch.database.evaluation_io import read_label_image

    good = np.zeros((24, 32), np.uint16)
    good[5:9, 5:9] = 300
    cv2.imwrite(str(tmp_path / "f.png"), good)
    assert read_label_image(tmp_path, "f.jpg", (32, 24))[6, 6] == 300
    for bad, fragment in ((good.astype(np.uint8), "1 channel(s) of uint8"),
                          (np.dstack([good] * 3), "3 channel(s) of uint16"),
                          (np.zeros((12, 16), np.uint16), "label image is 16x12 but its image is 32x24")):
        cv2.imwrite(str(tmp_path / "f.png"), bad)
        with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
            read_label_image(tmp_path, "f.jpg", (32, 24))
