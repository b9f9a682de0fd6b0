"""The verification's refinement settles in the best alignment of its neighbourhood, wherever its start lies
within it (coarse to fine), and the chance model's samples stay one-gate refinements (one per cell of N_eff)."""

import numpy as np

from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.refinement import refine_alignment, weighted_umeyama
from sosmatch.plugin.verification import verify_alignments

STARTS = ((3.0, 0.0), (0.0, 3.0), (3.0, 3.0), (-4.0, 2.0))  # window hypotheses 3-4.5 m off (1.2-1.8 gates)


def _drifted_pair(seed):
    """A survey pair whose map B is stretched 1.5 % along x (the EKF scale drift of world 97's crossing flight:
    1.2-1.75 %) and tilted 1 deg, and the best rigid transform of its true pairs."""
    s = survey_map_pair(300, seed=seed, noise_m=1.0, size_noise=0.15, tilt_deg=1.0, yaw_deg=0.0)
    b = s.points_b.copy()
    centre = b.mean(axis=0)
    b[:, 0] = centre[0] + 1.015 * (b[:, 0] - centre[0])
    truth = weighted_umeyama(b[s.truth[:, 1]], s.points_a[s.truth[:, 0]], np.ones(len(s.truth)), False)
    return s, b, truth


def test_coarse_to_fine_refinement_does_not_stop_at_the_first_local_optimum():
    """From starts 1.2-1.8 gates off the best rigid transform, the one-gate refinement stops wherever the pairs
    first stabilise (its support depends on the start); the coarse first stage sees the partners of the whole
    overlap and its worst start is better than the one-gate refinement's worst on every map pair."""
    spread = {1.0: 0, 2.0: 0}
    for seed in range(6):
        s, b, truth = _drifted_pair(seed)
        worst = {}
        for coarse in (1.0, 2.0):
            supports = [len(refine_alignment(s.points_a, s.sizes_a, b, s.sizes_b,
                                             Sim3(truth.rotation, truth.translation + [dx, dy, 0.0]), 2.5, 0.4,
                                             coarse_factor=coarse).associations) for dx, dy in STARTS]
            worst[coarse] = min(supports)
            spread[coarse] += max(supports) - min(supports)
        assert worst[2.0] > worst[1.0]
    assert 2 * spread[2.0] < spread[1.0]


def test_the_verification_refines_its_candidates_coarse_to_fine():
    """The verification's winner from each start alone, by default and with one gate: from the worst start the
    default finds more support, on every map pair."""
    for seed in range(3):
        s, b, truth = _drifted_pair(seed)
        worst = {}
        for coarse in (1.0, None):
            supports = []
            for dx, dy in STARTS:
                cand = [(Sim3(truth.rotation, truth.translation + [dx, dy, 0.0]), np.arange(10))]
                kw = {} if coarse is None else {"coarse_factor": coarse}
                supports.append(verify_alignments(s.points_a, s.sizes_a, b, s.sizes_b, cand, 2.5, 0.4, 6,
                                                  chance_starts=0, **kw).support)
            worst[coarse] = min(supports)
        assert worst[None] > worst[1.0]
