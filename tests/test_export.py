"""GeoJSON / PLY / CSV export of landmark maps."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyproj import Transformer
from shapely.geometry import Polygon

from sosmatch.database.geojson import landmarks_feature_collection
from sosmatch.database.landmark_map import LandmarkMap, read_landmark_map, write_landmark_map
from sosmatch.plugin.errors import InputError
from sosmatch.tools.cli import main
from sosmatch.workflows.export import run as export


def _map(epsg=32614):
    rng = np.random.default_rng(0)
    pos = np.column_stack([486000 + rng.uniform(0, 3000, 20), 5206000 + rng.uniform(0, 3000, 20),
                           rng.uniform(0, 5, 20)])
    sizes = rng.uniform(5, 60, 20).astype(np.float32)
    sizes[3] = np.nan
    return LandmarkMap(pos, sizes, origin=pos.mean(0).round(), epsg=epsg)


def test_points_round_trip_to_the_map_crs():
    lmap = _map()
    fc = landmarks_feature_collection(lmap)
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == 20
    ll = np.array([f["geometry"]["coordinates"][:2] for f in fc["features"]])
    assert np.all((ll[:, 0] > -100) & (ll[:, 0] < -98) & (ll[:, 1] > 46) & (ll[:, 1] < 48))  # North Dakota
    back = np.column_stack(Transformer.from_crs("EPSG:4326", "EPSG:32614", always_xy=True).transform(ll[:, 0],
                                                                                                    ll[:, 1]))
    np.testing.assert_allclose(back, lmap.positions[:, :2], atol=0.01)
    assert fc["features"][3]["properties"]["size_m"] is None
    assert fc["features"][0]["properties"]["size_m"] == pytest.approx(float(lmap.sizes[0]), abs=1e-3)
    assert fc["properties"]["source_crs"] == "EPSG:32614"
    # RFC 7946 means ellipsoidal heights; these are the map's z (as the receiver reported it): said in the file
    assert "not converted to the WGS84 ellipsoidal height" in fc["properties"]["height_reference"]
    # nu34 D5: RTK receivers often report ellipsoidal heights: no claim that may be wrong
    assert "often the ellipsoidal height for RTK" in fc["properties"]["height_reference"]


def test_circles_have_the_landmark_size_on_the_ground():
    """A landmark's size is sqrt(lambda_max) of its segment (R/2 for a disc of radius R): its circle has radius
    2 x size (nu16: drawn as a diameter of size_m, it was a quarter of the object's radius)."""
    lmap = _map()
    fc = landmarks_feature_collection(lmap, geometry="circle")
    tf = Transformer.from_crs("EPSG:4326", "EPSG:32614", always_xy=True)
    ring = np.array(fc["features"][0]["geometry"]["coordinates"][0])
    xy = np.column_stack(tf.transform(ring[:, 0], ring[:, 1]))
    poly = Polygon(xy)
    r = 2.0 * lmap.sizes[0]
    assert poly.area == pytest.approx(np.pi * r * r, rel=0.03)  # 24-gon
    np.testing.assert_allclose(np.array(poly.centroid.coords)[0], lmap.positions[0, :2], atol=0.05)


def test_local_map_needs_an_epsg(tmp_path):
    lmap = _map(epsg=0)
    with pytest.raises(InputError, match="no geographic reference"):
        landmarks_feature_collection(lmap)
    assert len(landmarks_feature_collection(lmap, epsg=32614)["features"]) == 20


def test_cli_session_dir_geojson_ply_csv(tmp_path, capsys):
    lmap = _map()
    sess = tmp_path / "sess"
    sess.mkdir()
    write_landmark_map(sess / "landmarks.sosmap", lmap)
    rows = ["index,point3d_id,x,y,z,size_m,num_observations,image_names"]
    rows += [f"{i},{i + 1},0,0,0,1,{7 + i},a.jpg b.jpg" for i in range(20)]
    (sess / "landmarks.csv").write_text("\n".join(rows) + "\n")
    assert main(["export", "--geojson", str(sess), "--out", str(tmp_path / "l.geojson")]) == 0
    fc = json.loads((tmp_path / "l.geojson").read_text())
    assert [f["properties"]["num_observations"] for f in fc["features"]] == list(range(7, 27))
    # PLY: parse the binary body back.
    export(sess / "landmarks.sosmap", ply=tmp_path / "l.ply", csv_out=tmp_path / "l.csv")
    data = (tmp_path / "l.ply").read_bytes()
    body = data[data.index(b"end_header\n") + len(b"end_header\n"):]
    rec = np.frombuffer(body, dtype=[("xyz", "<f8", (3,)), ("size", "<f4")])
    np.testing.assert_array_equal(rec["xyz"], read_landmark_map(sess / "landmarks.sosmap").positions)
    np.testing.assert_allclose(rec["xyz"], lmap.positions, atol=1e-3)  # float32 offsets in the .sosmap
    assert b"EPSG:32614" in data[:200]
    # world coordinates, and no origin comment (the session's own landmarks.ply says "world = vertex + origin":
    # the tenth sweep read the export's origin line the same way and doubled the coordinates)
    header = data[:data.index(b"end_header\n")].decode("ascii").splitlines()
    assert not [line for line in header if line.startswith("comment origin")]
    assert any("world coordinates" in line for line in header)
    lines = (tmp_path / "l.csv").read_text().splitlines()
    assert lines[0] == "index,x,y,z,size_m,lon,lat" and len(lines) == 21
    capsys.readouterr()
    assert main(["export", "--geojson", str(tmp_path / "missing"), "--out", str(tmp_path / "m.geojson")]) == 2
    assert "not found" in capsys.readouterr().err


def test_a_local_map_given_a_crs_it_cannot_lie_in_is_refused(tmp_path, cli_error):
    """`export --epsg` on a map in a local frame (a synthetic session: coordinates of a few hundred metres).
    Before: exit 0, a GeoJSON at lon 10.5, lat 0.003 (UTM 33N) or in the Atlantic (CH LV95). Now the landmarks
    must lie within 100 km of the CRS's area of use; a map a little past a UTM zone's edge is still exported."""
    local = _map(epsg=0)
    pos = local.positions - local.positions.min(0) + 250.0
    local = LandmarkMap(pos, local.sizes, origin=pos.mean(0).round(), epsg=0)
    path = tmp_path / "local.sosmap"
    write_landmark_map(path, local)
    for code in ("32633", "2056", "32714"):
        err = cli_error("export", "--geojson", path, "--epsg", code, "--out", tmp_path / "l.geojson")
        assert f"{path}: the landmarks lie at x 250..3" in err and f"outside where EPSG:{code}" in err
        err = cli_error("export", "--csv", path, "--epsg", code, "--out", tmp_path / "l.csv")
        assert "a local frame given a CRS?" in err
        # rev58 D2: PLY records the CRS in its header, and wrote it unchecked (exit 0) where --csv refused
        err = cli_error("export", "--ply", path, "--epsg", code, "--out", tmp_path / "l.ply")
        assert "a local frame given a CRS?" in err
    assert not any((tmp_path / f"l.{ext}").exists() for ext in ("geojson", "csv", "ply"))
    assert main(["export", "--ply", str(path), "--out", str(tmp_path / "l.ply")]) == 0  # no CRS claimed: written
    # UTM zone 14N at x 900 km: 66 km past the east edge of the zone's projected box (834 km), is exported
    edge = _map()
    pos = edge.positions + [-486000 + 900000, 0, 0]
    edge = LandmarkMap(pos, edge.sizes, origin=pos.mean(0).round(), epsg=32614)
    write_landmark_map(tmp_path / "edge.sosmap", edge)
    assert main(["export", "--geojson", str(tmp_path / "edge.sosmap"), "--out", str(tmp_path / "e.geojson")]) == 0


def test_another_crs_than_the_one_the_map_records_is_refused(tmp_path, cli_error):
    """The ninth new-user sweep: `export --epsg 32618` on a map recorded in EPSG:32617 moved every landmark 500 km
    (a relabelling, not a reprojection), exit 0. The recorded code itself is fine."""
    path = tmp_path / "m.sosmap"
    write_landmark_map(path, _map(epsg=32614))
    err = cli_error("export", "--geojson", path, "--epsg", "32615", "--out", tmp_path / "x.geojson")
    assert "records its frame as EPSG:32614" in err and not (tmp_path / "x.geojson").exists()
    assert main(["export", "--geojson", str(path), "--epsg", "32614", "--out", str(tmp_path / "y.geojson")]) == 0


def _geodesic_area(geometry: dict) -> float:
    from pyproj import Geod
    from shapely.geometry import shape

    s = shape(geometry)
    return sum(abs(Geod(ellps="WGS84").geometry_area_perimeter(p)[0]) for p in getattr(s, "geoms", [s]))


def test_circles_across_the_antimeridian_are_cut_into_multipolygons():
    """The nu25 sweep (Fiji, UTM 60S): circles a metre across the antimeridian had vertices at both +-179.99999, a
    360-degree-wide polygon to a planar GIS, invalid to shapely. RFC 7946 3.1.9: cut into a MultiPolygon whose
    parts each lie within -180..180 and meet on the antimeridian; the area on the ground stays."""
    from shapely.geometry import shape

    lon = np.array([179.99999, -179.99999, 179.9, -179.9, 180.0])
    lat = np.full(len(lon), -17.8)
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:32760", always_xy=True).transform(lon, lat)
    lmap = LandmarkMap(np.column_stack([x, y, np.zeros(len(x))]), np.full(len(x), 2.0, np.float32),
                       origin=np.array([x[0], y[0], 0.0]).round(), epsg=32760)
    fc = landmarks_feature_collection(lmap, geometry="circle")
    n = 24  # the circle is a 24-gon of radius 2 x size
    polygon_area = 0.5 * n * np.sin(2 * np.pi / n) * 4.0**2
    kinds = []
    for f in fc["features"]:
        g = f["geometry"]
        kinds.append(g["type"])
        s = shape(g)
        assert s.is_valid, f["id"]
        for part in getattr(s, "geoms", [s]):
            x0, _, x1, _ = part.bounds
            assert -180.0 <= x0 and x1 <= 180.0 and x1 - x0 < 1e-3, (f["id"], part.bounds)
        if g["type"] == "MultiPolygon":
            edges = sorted(round(p.bounds[0] if p.bounds[0] < 0 else p.bounds[2], 6) for p in s.geoms)
            assert edges == [-180.0, 180.0]  # the parts meet on the antimeridian
        assert _geodesic_area(g) == pytest.approx(polygon_area, rel=0.01)
    assert kinds == ["MultiPolygon", "MultiPolygon", "Polygon", "Polygon", "MultiPolygon"]


def test_polygon_geometry_keeps_other_rings_and_closes_a_polar_cap():
    """A ring that crosses nothing is written vertex for vertex; one around a pole (a landmark at the South Pole in
    UPS) becomes the cap it bounds, one polygon from -180 to 180 closed along latitude -90."""
    from shapely.geometry import shape

    from sosmatch.database.geojson import polygon_geometry

    ring = np.array([[10.0, 47.0], [10.001, 47.0], [10.001, 47.001], [10.0, 47.0]])
    assert polygon_geometry(ring) == {"type": "Polygon", "coordinates": [ring.tolist()]}
    t = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    xy = np.column_stack([2e6 + 4.0 * np.cos(t), 2e6 + 4.0 * np.sin(t)])
    lon, lat = Transformer.from_crs("EPSG:32761", "EPSG:4326", always_xy=True).transform(xy[:, 0], xy[:, 1])
    cap = polygon_geometry(np.vstack([np.column_stack([lon, lat]), [[lon[0], lat[0]]]]))
    s = shape(cap)
    assert cap["type"] == "Polygon" and s.is_valid
    assert s.bounds[0] == -180.0 and s.bounds[2] == 180.0 and s.bounds[1] == -90.0
    # UPS grid metres are 0.994 ground metres at the pole (its scale factor)
    assert _geodesic_area(cap) == pytest.approx(0.5 * 24 * np.sin(2 * np.pi / 24) * 16.0 / 0.994**2, rel=0.01)


def test_the_crs_area_check_and_the_per_point_test_agree():
    """One bounds test behind both (rev58 D4). A point without finite coordinates no longer hides the others from
    the refusal (the min/max over the points were NaN, and every comparison false)."""
    from sosmatch.database.geojson import check_within_crs_area, outside_crs_area

    xy = np.array([[500_000.0, 4_000_000.0], [300.0, 250.0], [np.nan, 1.0]])
    assert outside_crs_area(32614, xy).tolist() == [False, True, True]
    check_within_crs_area(32614, xy[:1])
    with pytest.raises(InputError, match="a local frame given a CRS"):
        check_within_crs_area(32614, xy[1:])


def test_a_batch_output_folder_is_named_as_one_with_what_in_it_to_give(tmp_path, cli_error):
    """nu60 D3: `export B1 --csv` of a batch's output folder said "B1/landmarks.sosmap: landmark map not found".
    It is no session; the error says so and names its merged models and sessions, which export as before."""
    from sosmatch.database.map_loading import load_map
    from sosmatch.database.outputs import open_output_dir
    from sosmatch.database.session_io import read_session

    batch = tmp_path / "B1"
    with open_output_dir(batch, "batch", "identity") as out:
        for name in ("merged/a1", "sessions/a1", "sessions/a2"):
            (batch / name).mkdir(parents=True)
            write_landmark_map(batch / name / "landmarks.sosmap", _map())
        out.finish()
    err = cli_error("export", "--csv", batch, "--out", tmp_path / "x.csv")
    assert f"{batch}: is the output folder of `sosmatch batch`, not a session" in err
    assert "in it: merged/a1, sessions/a1, sessions/a2" in err
    assert not (tmp_path / "x.csv").exists()
    with pytest.raises(InputError, match="output folder of `sosmatch batch`"):  # match, merge, changes read so
        read_session(batch)
    with pytest.raises(InputError, match="output folder of `sosmatch batch`"):  # and match's and merge's loader
        load_map(batch)
    assert main(["export", "--csv", str(batch / "merged" / "a1"), "--out", str(tmp_path / "m.csv")]) == 0
