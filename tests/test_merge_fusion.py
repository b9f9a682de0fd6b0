"""What a merge fuses (rev33's findings): one-to-one per session pair, every fused association within its gate
measured in the metres the gate is in, and every association not fused counted."""

import numpy as np
import pycolmap
import pytest

from sosmatch.database.match_io import read_match
from sosmatch.database.session_io import read_session
from sosmatch.plugin.multisession import Sim3, associations_not_fused, fusion_groups, one_to_one
from sosmatch.tools.toy_sessions import overlapping_pair, toy_match_json, true_associations
from sosmatch.workflows import merge
from sosmatch.workflows.merge_pairs import filter_associations, match_fuse_pair


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("pair")
    return (root, *overlapping_pair(root))


def test_one_to_one_takes_the_nearest_first_and_each_landmark_once():
    assoc = np.array([[0, 5], [0, 6], [1, 5], [2, 7], [3, 7]])
    dist = np.array([1.0, 0.5, 0.2, 0.3, 0.3])
    # (1,5) 0.2, then (2,7) 0.3 (ties: the smaller a index), then (0,6) 0.5; (0,5) and (3,7) lose
    assert one_to_one(assoc, dist).tolist() == [2, 3, 1]
    assert one_to_one(assoc, dist, dist < 0.4).tolist() == [2, 3]


def test_a_group_never_joins_two_landmarks_of_one_session_and_the_rest_is_counted():
    pairs = [(0, 1, np.array([[0, 0]])), (1, 2, np.array([[0, 0]])), (2, 0, np.array([[0, 3]]))]
    groups = fusion_groups(pairs)
    assert groups == [[(0, 0), (1, 0), (2, 0)]]
    assert associations_not_fused(pairs, groups) == 1  # (2,0)-(0,3) would put 0:0 and 0:3 into one point


def test_an_unverified_match_pairing_one_landmark_with_two_fuses_only_what_associations_link(pair, tmp_path):
    """rev33: a window consensus (match --no-verify) paired A265 with B7, B22 and B225; grouped as they came, the
    chain A257-B22-A265-B7 fused A257 with B7 (5.74 m apart, gate 2.95 m, no association between them) and merge
    said "0 associations not fused". Here: two true pairs (a1, b1), (a2, b2) and a wrong (a2, b1) within the
    gate: the old grouping made one point of the four (two of them, the first of each session, fused: a1 with b2
    when b2 < b1, which no association links) and counted nothing."""
    _, _, a, b = pair
    sa, sb = read_session(a.path), read_session(b.path)
    truth = true_associations(a, b)
    a_from_b = a.session_from_world.compose(b.session_from_world.inverse())
    # two true pairs whose A landmarks are nearest to each other (a1 < a2)
    pa = sa.landmarks.positions[truth[:, 0]]
    d = np.linalg.norm(pa[:, None] - pa[None], axis=2) + np.eye(len(truth)) * 1e9
    i, j = np.unravel_index(np.argmin(d), d.shape)
    (a1, b1), (a2, b2) = sorted([truth[i], truth[j]], key=lambda t: t[0])
    gate = float(d[i, j]) + 1.0
    assoc = np.vstack([truth, [[a2, b1]]])
    res = merge.merge_sessions([sa, sb], [Sim3.identity(), a_from_b], [(0, 1, assoc)], tmp_path / "M",
                               max_fuse_distance_m=gate)
    assert res.num_rejected == 1  # the wrong association, counted
    assert res.num_fused == len(truth)  # every true pair fused, each into its own point
    rec = pycolmap.Reconstruction(str(tmp_path / "M" / "sparse"))
    n_a = pycolmap.Reconstruction(str(a.path / "sparse")).num_points3D()
    n_b = pycolmap.Reconstruction(str(b.path / "sparse")).num_points3D()
    assert rec.num_points3D() == n_a + n_b - len(truth)


def test_the_gate_is_in_the_metres_of_the_pairs_own_frame(pair):
    """rev33 (scalegate.py): with a reference frame at scale 2 or 3 (an edge of a merge of three sessions that
    does not touch the reference), distances were measured there against a gate in the pair's own metres: 138 /
    52 / 21 of 138 associations fused at scale 1 / 2 / 3."""
    _, _, a, b = pair
    sa, sb = read_session(a.path), read_session(b.path)
    match = read_match(toy_match_json(a, b, a.path.parent / "gate" / "match.json"))
    fuse = [match_fuse_pair(0, 1, match)._replace(gate_m=0.3)]
    counts = []
    for scale in (1.0, 3.0, 10.0):
        ref_from_a = Sim3(np.eye(3), np.array([5.0, -3.0, 1.0]), scale)
        kept, rejected = filter_associations([sa, sb], [ref_from_a, ref_from_a.compose(match.transform)], fuse, 2.0)
        counts.append((len(kept[0][2]), rejected))
    assert counts[0][0] > 20 and counts == [counts[0]] * 3
