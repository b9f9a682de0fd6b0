"""The alignment check of `changes`, `merge` and `batch` (`changes.check_alignment` ->
`plugin.changes.implausible_pair`) is a verdict on the pair, not on which session is named first (rev33: it counted
only A's landmarks that B's keyframes saw, and a transform 3 m off passed as (A, W) and was refused as (W, A))."""

import numpy as np
import pytest

from sosmatch.database.session_io import read_session
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.params import Params
from sosmatch.tools.toy_sessions import lawnmower, make_world, write_toy_session, yaw_transform
from sosmatch.workflows.changes import check_alignment


@pytest.fixture(scope="module")
def dense_and_sparse(tmp_path_factory):
    """A maps every object of its area; B, overlapping it in part, a fifth of them (the sparse map of the pair)."""
    root = tmp_path_factory.mktemp("dense_sparse")
    world = make_world(300, seed=11)
    present = np.random.default_rng(4).random(len(world.positions)) < 0.2
    a = write_toy_session(root / "A", world, lawnmower(20, 160, 20, 160, 60, 40, 10), Sim3.identity(), seed=1)
    b = write_toy_session(root / "B", world, lawnmower(60, 200, 40, 180, 60, 40, 10),
                          yaw_transform(40, (15, -8, 3)), seed=2, present=present)
    return read_session(a.path), read_session(b.path), a.session_from_world.compose(b.session_from_world.inverse())


def _verdict(first, second, transform, verified):
    """None when the check lets the alignment stand, else its refusal."""
    try:
        check_alignment(first, second, transform, Params(), verified, 2.0, "match.json", "nothing done")
    except InputError as e:
        return str(e)
    return None


@pytest.mark.parametrize("shift_m", [0.0, 2.6])
def test_the_alignment_check_gives_one_verdict_whichever_session_is_first(dense_and_sparse, shift_m):
    a, b, truth = dense_and_sparse
    a_from_b = Sim3(np.eye(3), np.array([shift_m, 0.0, 0.0])).compose(truth)
    for verified in (True, False):
        ab, ba = _verdict(a, b, a_from_b, verified), _verdict(b, a, a_from_b.inverse(), verified)
        assert (ab is None) == (ba is None), (verified, ab, ba)
        if shift_m == 0.0:  # the true alignment stands in either order
            assert ab is None
    # 2.6 m off (the counterpart gate is 3 m): B's few landmarks all find one of A's many, A's mostly none of B's;
    # an unverified alignment must be significant both ways (one direction alone passed as (B, A) only)
    if shift_m:
        assert "does not bring the maps together" in _verdict(b, a, a_from_b.inverse(), False)
