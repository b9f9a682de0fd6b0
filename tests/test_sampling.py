"""`plugin.sampling.evenly_spaced`: the one way stages pick a few of many items."""

from hypothesis import given, settings
from hypothesis import strategies as st

from sosmatch.plugin.sampling import evenly_spaced


@settings(max_examples=300, deadline=None)
@given(count=st.integers(0, 5000), limit=st.integers(0, 50))
def test_samples_are_distinct_ascending_and_span_the_items(count, limit):
    picks = evenly_spaced(count, limit)
    assert len(picks) == min(count, limit)
    assert picks == sorted(set(picks))
    if picks and limit >= 2:
        assert picks[0] == 0 and picks[-1] == count - 1  # the first and the last item are always looked at
    if picks:
        assert all(0 <= i < count for i in picks)


@settings(max_examples=200, deadline=None)
@given(count=st.integers(2, 5000), limit=st.integers(2, 50))
def test_no_gap_is_much_wider_than_an_even_step(count, limit):
    picks = evenly_spaced(count, limit)
    if count > limit:
        step = (count - 1) / (limit - 1)
        assert max(b - a for a, b in zip(picks, picks[1:])) <= step + 1  # rounding moves each pick by <= 1/2


def test_a_short_list_is_taken_whole():
    assert evenly_spaced(3, 9) == [0, 1, 2]
    assert evenly_spaced(10, 4) == [0, 3, 6, 9]
