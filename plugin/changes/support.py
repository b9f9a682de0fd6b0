"""Is the alignment plausible? The counterpart rate of the given transform against B displaced (chance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..multisession import Sim3
from ..params import ChangeParams
from .evidence import binomial_tail, counterparts
from .observations import SessionObservations, in_view


@dataclass(frozen=True)
class AlignmentSupport:
    """How many compared landmarks of A find a counterpart in B with the given transform, against the same count
    with B displaced (the chance level of counterparts at this map density and these sizes)."""

    compared: int  # landmarks of A that B's keyframes saw >= min_views times
    matched: int  # of those, with a counterpart under the transform
    displaced_rate: float  # the highest counterpart rate with B moved CONTROL_SHIFTS x gate in 6 directions
    p_value: float  # P(>= matched | compared, displaced_rate): the transform explains no more than chance

    @property
    def rate(self) -> float:
        """The share of compared landmarks with a counterpart at the true alignment (0 when none was compared)."""
        return self.matched / self.compared if self.compared else 0.0

    def counterpart_log_ratio(self) -> float:
        """log P(counterpart | absent) / P(counterpart | present): a removed object's place finds a counterpart at
        the chance (displaced) rate, a present one at the transform's rate (both at least 1 / compared)."""
        floor = 1.0 / max(self.compared, 1)
        return float(np.log(max(self.displaced_rate, floor) / max(self.rate, floor)))

    def plausible(self, max_p: float = 1e-3, min_ratio: float = 1.5) -> bool:
        """The transform pairs the maps clearly better than chance: significant, and 1.5x the chance rate."""
        return self.p_value < max_p and self.rate >= min_ratio * self.displaced_rate


CONTROL_SHIFT = 3.0  # x the counterpart gate: a displacement beyond any landmark scatter the gate allows
# an alignment nobody verified must be significant, not merely better than chance (`implausible_alignment`)
UNVERIFIED_MAX_P = 1e-3


def counterpart_gate(params: ChangeParams, association_tolerance_m: float) -> float:
    """The counterpart gate of change detection and of its alignment control: `params.tolerance_factor` x theta_eps
    of the association that aligned the maps."""
    return params.tolerance_factor * association_tolerance_m


def implausible_alignment(support: AlignmentSupport, gate_m: float, verified: bool,
                          names: tuple[str, str] = ("A", "B")) -> str | None:
    """Why a transform does not bring two maps together (None: it does), by one direction's counterpart control
    (`alignment_support` at `gate_m`: the landmarks of the first of `names` against the second): the rule of
    `changes` and `merge`, which apply it to both directions (`implausible_pair`). A verified alignment (match's
    verification on the full maps decided) is refused only when it pairs no more often than B displaced (1.5x the
    chance rate) and, where none of A's landmarks was compared, stands; an unverified one (a window consensus,
    `match --no-verify`: 7 associations can be a chance alignment 181 m off) must also be significant
    (p < UNVERIFIED_MAX_P), and with nothing compared it is not confirmed. The text names no file: the caller does,
    and says what it did not do."""
    mine, other = names
    if not support.compared:
        return None if verified else (f"none of {mine}'s landmarks lies where {other}'s keyframes looked under the "
                                      "transform (in view of enough of them to be compared): nothing confirms the "
                                      "alignment")
    if support.plausible(max_p=1.0 if verified else UNVERIFIED_MAX_P):
        return None
    return (f"the transform does not bring the maps together: {support.rate:.0%} of {mine}'s {support.compared} "
            f"compared landmarks have a counterpart, {support.displaced_rate:.0%} with {other} moved "
            f"{CONTROL_SHIFT * gate_m:.0f} m (chance): the alignment is wrong, or the maps share too few landmarks "
            "to confirm it")


def pair_support(a: SessionObservations, b: SessionObservations, a_from_b: Sim3, gate_m: float,
                 params: ChangeParams, a_side: AlignmentSupport | None = None
                 ) -> tuple[AlignmentSupport, AlignmentSupport]:
    """The counterpart control of an alignment in both directions, each in its own map's frame: A's landmarks that
    B's keyframes saw against B moved by a_from_b (`alignment_support`), and B's that A's keyframes saw against A
    moved by its inverse. The pair (B, A) with the inverse transform gives the same two, swapped: each direction's
    count, chance level (B displaced along 6 directions of its own frame) and p do not depend on which session is
    named first (rev33: one direction alone checked 328 landmarks of A at a chance rate of 0.11 and passed, the
    other order 156 of W at 0.24 and refused the same alignment). `a_side`: A's direction at this gate where the
    caller has it already (`detect_changes`' own `ChangeResult.support`), not computed again."""
    if a_side is None:
        a_side = alignment_support(a, b.transformed(a_from_b), gate_m, params)
    return a_side, alignment_support(b, a.transformed(a_from_b.inverse()), gate_m, params)


def implausible_pair(supports: tuple[AlignmentSupport, AlignmentSupport], gate_m: float,
                     verified: bool) -> str | None:
    """Why an alignment does not bring the two maps together (None: it does), by both directions of its control
    (`pair_support`): each must pass `implausible_alignment`. Each direction alone tests the same null hypothesis
    (the transform pairs no better than chance) with its own landmarks, and the alignment is claimed only when both
    reject it: an intersection-union test, whose false-alarm rate is at most each direction's, with no correction,
    and whose verdict is the pair's, not the argument order's. The two counts are not pooled: one counterpart pair
    is mostly counted in both (the gate and the size ratio are symmetric), so a pooled binomial p would count its
    evidence twice."""
    for support, names in zip(supports, (("A", "B"), ("B", "A"))):
        if (why := implausible_alignment(support, gate_m, verified, names)) is not None:
            return why
    return None


def alignment_support(a: SessionObservations, b_in_a: SessionObservations, gate_m: float,
                      params: ChangeParams) -> AlignmentSupport:
    """Counterpart rate of A's compared landmarks with B as given and with B displaced horizontally by
    CONTROL_SHIFT x the gate in 6 directions (a control: the same maps, no true pairs). A wrong transform (an
    accepted match of the wrong place, a mirrored map) gives as many counterparts as the control."""
    seen, _, _ = in_view(a.positions, a.sizes, b_in_a.poses, b_in_a.cameras, min_area_px=b_in_a.smallest_mask_px,
                         size_tolerance=params.max_size_difference)
    compared = np.flatnonzero(seen.sum(0) >= b_in_a.views_needed(params.min_views))
    pa, ha = a.positions[compared], a.sizes[compared]

    def matched(shift: np.ndarray) -> int:
        idx, _ = counterparts(pa, ha, b_in_a.positions + shift, b_in_a.sizes, gate_m, params.max_size_difference,
                              params.z_weight)
        return int(np.count_nonzero(idx >= 0))

    n = len(compared)
    real = matched(np.zeros(3))
    ang = np.arange(6) * np.pi / 3.0
    shifts = CONTROL_SHIFT * gate_m * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(6)])
    control = max((matched(d) for d in shifts), default=0) / n if n else 0.0
    p = float(binomial_tail(np.array([real]), np.array([n]), np.array([max(control, 1.0 / max(n, 1))]))[0])
    return AlignmentSupport(n, real, control, p)
