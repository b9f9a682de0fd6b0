"""The sweep's ground noise and the relief test on heights as the sweep gives them: its levels, SWEEP_STEP_M apart
(plugin.changes.surface: `heights_above_ground` takes the best level and does not interpolate)."""

import numpy as np
import pytest

from sosmatch.plugin.changes.objectness import ground_noise_known
from sosmatch.plugin.changes.surface import (
    SWEEP_BELOW_M,
    SWEEP_STEP_M,
    ground_noise_fit,
    ground_sweep_noise,
    height_limit,
    shows_relief,
    stands_above_ground,
)


def swept(x: np.ndarray) -> np.ndarray:
    """Heights as the sweep gives them: its levels, from SWEEP_BELOW_M below the ground up."""
    return np.round(np.maximum(x, -SWEEP_BELOW_M) / SWEEP_STEP_M) * SWEEP_STEP_M


@pytest.mark.parametrize("sigma", [0.25, 0.5, 1.0])
def test_the_ground_noise_is_measured_on_the_levels_without_bias(sigma):
    # a 0 is anything within half a step of the ground, half of it above: counted whole below, the root mean
    # square of the heights at or below 0 measured 0.85-0.92 of sigma
    rng = np.random.default_rng(7)
    ground = swept(rng.normal(0.0, sigma, 4000))
    objects = swept(rng.uniform(2.0, 15.0, 1000))  # objects only add height: they must not widen the noise
    assert ground_sweep_noise(np.concatenate([ground, objects, [np.nan]])) == pytest.approx(sigma, rel=0.04)


def test_the_ground_noise_fit_says_how_much_the_levels_tell():
    rng = np.random.default_rng(8)
    assert ground_noise_fit(np.zeros(200)) == (0.0, 200.0, 200)  # all at the ground's level: no noise it shows
    assert np.isnan(ground_sweep_noise(np.array([-0.5, 0.0, 3.0])))  # too few places
    # coarser than a step, the levels tell almost as much as the heights: a normal sample of nearly as many places
    sigma, dof, n = ground_noise_fit(swept(rng.normal(0.0, 1.0, 4000)))
    assert sigma == pytest.approx(1.0, rel=0.05) and 0.8 * n < dof < n
    # finer than a step, most places are at the ground's level and tell little
    sigma, dof, n = ground_noise_fit(swept(rng.normal(0.0, 0.25, 4000)))
    assert sigma == pytest.approx(0.25, rel=0.1) and dof < 0.5 * n


@pytest.mark.parametrize(("sigma", "places", "p", "most"), [(0.5, 100, 0.01, 3), (0.75, 300, 0.01, 3),
                                                            (0.5, 300, 0.05, 12), (1.0, 100, 0.05, 12)])
def test_bare_ground_swept_to_levels_shows_no_relief(sigma, places, p, most):
    # measured on the levels, the noise was low and the levels stood above its limit more often than its rate:
    # 26 / 100, 17 / 100, 30 / 100 and 24 / 100 of these flat sessions showed relief
    rng = np.random.default_rng(9)
    shown = sum(shows_relief(swept(rng.normal(0.0, sigma, places)), p) for _ in range(100))
    assert shown <= most


def test_a_few_objects_among_the_levels_are_still_relief():
    rng = np.random.default_rng(10)
    found = 0
    for _ in range(50):
        h = rng.normal(0.0, 0.5, 100)
        h[:5] = rng.uniform(2.0, 5.0, 5)  # 5 % stand 2-5 m up
        found += shows_relief(swept(h), 0.01)
    assert found >= 48


@pytest.mark.parametrize(("sigma", "places"), [(0.5, 3), (1.0, 3), (1.0, 6)])
def test_a_few_ground_places_make_a_test_that_bare_ground_passes_at_its_rate(sigma, places):
    # below 10 places at ground level the limit was NaN and every place stood (rate 1): on small pairs which
    # session set the frame decided whether the test was made (nu39: 3 vs 24 false claims in the two orders).
    # The fit's sigma is measured on the few: the normal quantile over it let bare ground stand at 4-6 x p;
    # Student-t with the fit's degrees of freedom keeps it near p
    rng = np.random.default_rng(11)
    p, trials, stood = 0.01, 1500, 0
    for _ in range(trials):
        ref = swept(rng.normal(0.0, sigma, 2 * places))  # about `places` of them at or below the ground
        stood += bool(stands_above_ground(swept(rng.normal(0.0, sigma, 1)), ref, p)[0])
    assert stood / trials < 2.5 * p


def test_the_limit_widens_as_the_ground_places_thin_and_is_never_off():
    rng = np.random.default_rng(12)
    ground = swept(rng.normal(0.0, 1.0, 4000))
    ground = ground[ground <= 0]
    limits = [height_limit(ground[:n], 0.01) for n in (2, 3, 5, 10, 40, len(ground))]
    assert np.all(np.isfinite(limits))
    assert limits[0] > limits[-1] * 1.5  # a handful of places: a stricter test, not none
    assert limits[-1] == pytest.approx(2.326, rel=0.1)  # on many, the normal's quantile
    # an object far above the ground stands over the few places' limit
    assert stands_above_ground(np.array([15.0, 0.0]), ground[:3], 0.01).tolist() == [True, False]
    assert ground_noise_known((ground[:2], np.array([-0.5, 4.0])))
    assert not ground_noise_known((ground[:2], np.array([2.0, 4.0])))  # no place at ground level in one
