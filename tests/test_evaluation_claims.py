"""Hypotheses -> keyframe-pair claims: observers cross product, max |S| score, gravity-rejected ignored."""

import numpy as np
import pytest

from sosmatch.plugin.evaluation.claims import Hypothesis, claim_scores, observer_matrix


def test_claims_cross_product_and_max_score():
    # Map A: landmark 0 seen by keyframes {0, 1}, landmark 1 by {2}; map B: landmark 0 by {1}, 1 by {0, 3}.
    oa = observer_matrix([[0, 1], [2]], 4)
    ob = observer_matrix([[1], [0, 3]], 5)
    hyps = [
        Hypothesis(np.array([[0, 0], [1, 1]]), 7.0),
        Hypothesis(np.array([[0, 1]]), 9.0),
        Hypothesis(np.array([[1, 0]]), 50.0, valid=False),  # failed the gravity check: no claim
    ]
    s = claim_scores(hyps, oa, ob)
    assert s.shape == (4, 5)
    expect = np.full((4, 5), np.nan)
    expect[0, 1] = expect[1, 1] = 7.0  # A lm 0 x B lm 0
    expect[2, 0] = expect[2, 3] = 7.0  # A lm 1 x B lm 1
    expect[0, 0] = expect[0, 3] = expect[1, 0] = expect[1, 3] = 9.0  # A lm 0 x B lm 1 (higher score wins)
    np.testing.assert_array_equal(s, expect)


def test_max_observers_keeps_the_nearest():
    kf_xy = np.array([[0.0, 0], [10, 0], [20, 0], [30, 0]])
    m = observer_matrix([[0, 1, 2, 3]], 4, np.array([[19.0, 0]]), kf_xy, max_observers=2)
    assert sorted(m.indices.tolist()) == [1, 2]
    with pytest.raises(ValueError):
        observer_matrix([[0, 9]], 4)


def test_out_of_range_association_is_an_error():
    oa = observer_matrix([[0]], 1)
    with pytest.raises(ValueError):
        claim_scores([Hypothesis(np.array([[3, 0]]), 5.0)], oa, oa)
