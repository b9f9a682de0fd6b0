"""Whole-map landmark filters: height outliers."""

import numpy as np

from sosmatch.plugin.landmark_filters import height_outliers
from sosmatch.plugin.params import preset_params


def _terrain(n=300, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 500, (n, 2))
    z = 200.0 + 0.05 * xy[:, 0] + 3.0 * np.sin(xy[:, 1] / 60.0) + rng.normal(0, 1.0, n)  # slope + hills + noise
    return np.column_stack([xy, z])


def test_landmarks_far_off_their_neighbours_ground_are_flagged_and_terrain_is_not():
    p = _terrain()
    assert not height_outliers(p, 8, 6.0).any()  # a slope and hills of 25 m over the map are terrain, not outliers
    wrong = p.copy()
    wrong[[3, 50, 120], 2] += [-400.0, -40.0, 60.0]  # wrong tracks: far below, and above, the ground
    flagged = height_outliers(wrong, 8, 6.0)
    assert set(np.flatnonzero(flagged)) == {3, 50, 120}


def test_height_outliers_need_enough_landmarks_and_spread():
    p = _terrain(8)
    assert not height_outliers(p, 8, 6.0).any()  # fewer than neighbours + 1 landmarks: nothing to compare with
    flat = np.column_stack([np.arange(20.0), np.zeros(20), np.zeros(20)])
    assert not height_outliers(flat, 4, 6.0).any()  # no spread: no scale to judge by


def test_survey_preset_turns_the_filter_on_and_the_paper_keeps_it_off():
    assert preset_params("survey").triangulation.height_outlier_sigmas > 0
    assert preset_params("paper").triangulation.height_outlier_sigmas == 0


def test_landmarks_a_flying_height_off_their_neighbours_are_impossible_whatever_the_spread():
    """The eleventh sweep: default synthetic maps kept landmarks 290-644 m under a 100 m flight (the spread-sized
    filter is off where tree crowns stand 20-30 m over the ground beside them) and said ok."""
    from sosmatch.plugin.landmark_filters import beyond_flying_height

    p = _terrain()
    p[::7, 2] += 25.0  # tree crowns 25 m over the ground: objects, kept
    cameras = np.column_stack([np.linspace(0, 500, 50), np.full(50, 250.0), np.full(50, 310.0)])  # ~100 m up
    assert not beyond_flying_height(p, cameras, 8).any()
    wrong = p.copy()
    wrong[[3, 50, 120], 2] += [-644.0, -290.0, 130.0]  # under the ground, and above the cameras
    assert set(np.flatnonzero(beyond_flying_height(wrong, cameras, 8))) == {3, 50, 120}
    assert not beyond_flying_height(wrong, cameras[:0], 8).any()  # no cameras: no flying height to judge by
