"""A map's own noise figures and the association tolerances derived from them."""

import dataclasses
import json

import numpy as np
import pytest

from sosmatch.database.map_loading import load_map, read_map_noise
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, project
from sosmatch.plugin.map_noise import MapNoise, derived_association_params, measure_map_noise
from sosmatch.plugin.params import AssociationParams

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
NADIR = np.diag([1.0, -1.0, -1.0])


def noisy_map(pixel_sigma, size_sigma, seed=0, n_landmarks=60, views=10):
    rng = np.random.default_rng(seed)
    centers = np.stack([np.zeros(40), np.arange(40) * 3.0, np.full(40, 100.0)], 1)
    rots = np.repeat(NADIR[None], len(centers), 0)
    points = np.stack([rng.uniform(-20, 20, n_landmarks), rng.uniform(20, 100, n_landmarks), np.zeros(n_landmarks)], 1)
    obs, pix, cov = [], [], []
    for p in points:
        kf = np.flatnonzero(np.abs(centers[:, 1] - p[1]) < 30)[:views]
        uv = np.concatenate([project(CAM, NADIR, centers[k], p[None])[0] for k in kf])
        obs.append(kf)
        pix.append(uv + rng.normal(0, pixel_sigma, uv.shape))
        h = 10.0 * np.exp(rng.normal(0, size_sigma, len(kf)))  # 10 px: 2 m at 100 m
        cov.append(np.eye(2)[None] * (h**2)[:, None, None])
    return measure_map_noise(CAM, rots, centers, points, obs, pix, cov)


def test_measured_noise_follows_pixel_and_size_noise():
    quiet, loud = noisy_map(1.0, 0.05), noisy_map(4.0, 0.2)
    assert quiet.ground_resolution_m == pytest.approx(0.2, rel=0.01)  # 100 m / 500 px
    # median of |2-D normal| = sigma sqrt(2 ln 2) = 1.18 sigma px, x 0.2 m/px
    assert quiet.residual_m == pytest.approx(1.18 * 0.2, rel=0.15)
    assert loud.residual_m == pytest.approx(4 * quiet.residual_m, rel=0.2)
    assert quiet.size_log_std == pytest.approx(0.05, rel=0.25) and loud.size_log_std == pytest.approx(0.2, rel=0.25)
    assert MapNoise.from_dict(json.loads(json.dumps(loud.to_dict()))) == loud


def test_derived_tolerances_and_when_they_apply():
    base = AssociationParams(derive_from_maps=True)
    a = MapNoise(0.2, 0.9, 0.08, 300)
    b = MapNoise(0.2, 1.1, 0.09, 200)
    got = derived_association_params(base, a, b)
    assert got.affinity_sigma_m == pytest.approx(1.65) and got.distance_tolerance_m == pytest.approx(3.3)
    assert got.max_size_difference == pytest.approx(3.0 * np.hypot(0.08, 0.09), abs=1e-3)
    assert (got.window_length, got.min_associations) == (base.window_length, base.min_associations)
    # off, or a map without figures (a .sosmap file, an empty map): the configured values
    off = dataclasses.replace(base, derive_from_maps=False)
    assert derived_association_params(off, a, b) == off
    assert derived_association_params(base, a, None) == base
    assert derived_association_params(base, a, MapNoise(float("nan"), float("nan"), float("nan"), 0)) == base


def test_session_noise_is_read_from_run_json(tmp_path):
    from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map

    write_landmark_map(tmp_path / "landmarks.sosmap", LandmarkMap(np.zeros((3, 3)), np.ones(3, np.float32)))
    assert read_map_noise(tmp_path) is None and load_map(tmp_path).noise is None
    noise = MapNoise(0.2, 0.9, 0.08, 3)
    (tmp_path / "run.json").write_text(json.dumps({"noise": noise.to_dict()}))
    assert load_map(tmp_path).noise == noise
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(InputError, match="run.json"):
        load_map(tmp_path)
