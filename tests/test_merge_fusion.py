"""What a merge fuses (rev33's findings): every fused association within its gate measured in the metres the gate
is in."""

import numpy as np
import pytest

from sosmatch.database.match_io import read_match
from sosmatch.database.session_io import read_session
from sosmatch.plugin.multisession import Sim3
from sosmatch.tools.toy_sessions import overlapping_pair, toy_match_json
from sosmatch.workflows.merge_pairs import filter_associations, match_fuse_pair


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("pair")
    return (root, *overlapping_pair(root))


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
