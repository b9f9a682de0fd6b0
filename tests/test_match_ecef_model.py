"""A COLMAP landmark model aligned to Earth-centred coordinates (`colmap model_aligner --alignment_type ecef`) is
matched in its UTM zone, as `map` reads such poses: matched as a local frame (z not up) it gave "no match",
exit 0, where the same model in ENU matched every landmark (the nu18 sweep, x_ref_ecef)."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
from pyproj import Transformer

from sosmatch.database.map_loading import load_map
from sosmatch.plugin.geodesy import topocentric_frame
from sosmatch.tools.cli import main

LAT, LON, HEIGHT = 47.0, 8.0, 400.0  # UTM zone 32N


def _ecef_copy(sparse, out):
    """The model moved from its local frame (x east, y north, z up) into ECEF at (LAT, LON, HEIGHT)."""
    x0, ecef_from_enu = topocentric_frame(LAT, LON, HEIGHT)
    rec = pycolmap.Reconstruction(str(sparse))
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(ecef_from_enu), x0))
    out.mkdir()
    rec.write_binary(str(out))
    ids = sorted(rec.point3D_ids())
    return np.array([rec.point3D(i).xyz for i in ids])


def test_an_ecef_model_is_matched_in_its_utm_zone(toy_sessions, tmp_path, capsys):
    a = toy_sessions.a.path
    ecef = _ecef_copy(a / "sparse", tmp_path / "ecef")
    loaded = load_map(tmp_path / "ecef")
    assert loaded.lmap.epsg == 32632
    lon, lat, h = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*ecef.T)
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(loaded.lmap.positions, np.column_stack([e, n, h]), atol=1e-3)
    # ... and matches its own session as the local model does
    local = load_map(a / "sparse").lmap
    assert main(["match", str(a), str(tmp_path / "ecef"), "--out", str(tmp_path / "m")]) == 0
    capsys.readouterr()
    doc = json.loads((tmp_path / "m" / "match.json").read_text())
    assert doc["map_b"]["epsg"] == 32632 and doc["answer"] == "verified"
    assert doc["verification"]["support"] >= 0.9 * len(local)
