"""The objectness test by a landmark's whole footprint (plugin.changes.objectness): a low object whose flat top
fills its footprint stands by the mean of the footprint's sweeps, measured against the noise of such means."""

import numpy as np
import pytest

from sosmatch.plugin.changes import objectness
from sosmatch.plugin.changes.objectness import flat_landmarks, footprint_mean_limit, footprint_means
from sosmatch.plugin.changes.surface import SWEEP_STEP_M, height_limit
from sosmatch.plugin.params import ChangeParams


def _levels(h: np.ndarray) -> np.ndarray:
    """Heights as the sweep reports them: its levels."""
    return np.round(h / SWEEP_STEP_M) * SWEEP_STEP_M


def test_the_mean_of_a_footprint_is_taken_where_most_of_it_is_known():
    h = np.array([[1.0, 0.0, 0.5, np.nan], [np.nan, np.nan, np.nan, 1.0], [0.5, 0.5, np.nan, np.nan]])
    assert np.allclose(footprint_means(h), [0.5, np.nan, 0.5], equal_nan=True)


def test_the_noise_of_a_mean_is_measured_on_the_means_at_ground_level():
    rng = np.random.default_rng(5)
    means = _levels(rng.normal(0.0, 0.5, (3000, 7))).mean(axis=1)  # bare ground, independent places
    limit = footprint_mean_limit(means, 0.005, 7)
    assert limit == pytest.approx(2.576 * 0.5 / np.sqrt(7), rel=0.15)
    objects = np.concatenate([means, np.full(300, 3.0)])  # objects only add height: the same limit
    assert footprint_mean_limit(objects, 0.005, 7) == pytest.approx(limit, rel=0.05)
    assert np.isnan(footprint_mean_limit(np.array([1.0, 2.0]), 0.005, 7))


def test_a_low_bush_stands_by_its_footprints_mean(monkeypatch):
    # a bush of 1 m: every place of its footprint sweeps to 1 m, under the limit of the highest of 7 sweeps of
    # bare ground (the noise of one sweep 0.5 m) but far above the noise of their mean
    rng = np.random.default_rng(6)
    references = _levels(rng.normal(0.0, 0.5, 400))
    ground = _levels(rng.normal(0.0, 0.5, (200, 7)))
    bush = np.full((1, 7), 1.0)
    sweeps = np.vstack([ground, bush])
    assert sweeps.max(axis=1)[-1] < height_limit(references, 0.01, 7)
    monkeypatch.setattr(objectness, "ring_heights", lambda points, sizes, *a: sweeps[: len(points), 1:])
    points = np.zeros((len(sweeps), 3))
    sizes = np.ones(len(sweeps))
    flat, pick, _, _, wide = flat_landmarks(points, sizes, sweeps[:, 0], None, None, references,
                                              ChangeParams())
    assert not flat[-1] and wide[-1] and pick[-1] == -1
    # bare ground stands about as rarely as under the one test at p (here by either test, each at p / 2)
    assert np.mean(~flat[:-1]) < 0.04
    _, _, _, _, wide = flat_landmarks(points, sizes, sweeps[:, 0], None, None, references,
                                      ChangeParams(object_height_mean=False))
    assert not wide.any()
