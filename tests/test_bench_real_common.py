"""The Seneca cross-session benchmark's count of common landmarks: mutual nearest neighbours in the ground plane."""

import numpy as np

from sosmatch.tools.benchmarks.real_seneca import common_landmarks


def test_common_landmarks_are_mutual_nearest_within_radius():
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.uniform(0, 500, (40, 2)), rng.normal(220, 1, 40)])
    b = a[[5, 6, 7, 8]] + [[1.0, 0.5, -30.0], [0.0, 4.5, 0.0], [6.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
    b = np.vstack([b, a[8] + [2.5, 0.0, 0.0]])  # a second B near A 8: only the nearer one pairs with it
    pairs = common_landmarks(a, b, 4.0)
    # height is ignored (-30 m), 4.5 m and 6 m are too far, A 8 pairs with its nearer B (index 3, not 4)
    assert pairs.tolist() == [[5, 0], [8, 3]]
    assert common_landmarks(a, b, 5.0).tolist() == [[5, 0], [6, 1], [8, 3]]
    assert common_landmarks(a, b[:0], 5.0).shape == (0, 2)
