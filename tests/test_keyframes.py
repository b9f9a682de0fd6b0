"""Keyframe selection by travelled distance."""

import numpy as np
import pytest

from sosmatch.plugin.keyframes import select_keyframes


def _brute(centers, interval):
    keys = [0]
    for i in range(1, len(centers)):
        if np.linalg.norm(centers[i] - centers[keys[-1]]) >= interval:
            keys.append(i)
    return keys


def test_straight_line_every_interval():
    centers = np.stack([np.arange(0, 10.01, 0.5), np.zeros(21), np.full(21, 100.0)], 1)
    keys = select_keyframes(centers, 2.0)
    assert keys.tolist() == [0, 4, 8, 12, 16, 20]
    assert keys.dtype == np.int64


def test_matches_sequential_definition_on_random_walk():
    rng = np.random.default_rng(3)
    centers = np.cumsum(rng.normal(scale=0.7, size=(400, 3)), axis=0)
    keys = select_keyframes(centers, 2.0)
    assert keys.tolist() == _brute(centers, 2.0)
    assert np.all(np.diff(keys) > 0)
    # every consecutive keyframe pair is at least the interval apart
    assert np.all(np.linalg.norm(np.diff(centers[keys], axis=0), axis=1) >= 2.0)


def test_hovering_adds_no_keyframes_and_edge_cases():
    hover = np.zeros((50, 3)) + np.random.default_rng(0).normal(scale=0.1, size=(50, 3))
    assert select_keyframes(hover, 2.0).tolist() == [0]
    assert select_keyframes(np.zeros((0, 3)), 2.0).tolist() == []
    assert select_keyframes(hover[:5], 0.0).tolist() == [0, 1, 2, 3, 4]
    # distance from the last keyframe, not path length: going out and back returns no extra keyframe
    back = np.array([[0, 0, 0], [1.5, 0, 0], [0, 0, 0], [1.5, 0, 0]], float)
    assert select_keyframes(back, 2.0).tolist() == [0]
    with pytest.raises(ValueError):
        select_keyframes(np.zeros((4, 2)), 2.0)
