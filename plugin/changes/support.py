"""Is the alignment plausible? The counterpart rate of the given transform against B displaced (chance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def implausible_alignment(support: AlignmentSupport, gate_m: float, verified: bool) -> str | None:
    """Why a transform does not bring two maps together (None: it does), by its counterpart control
    (`alignment_support` at `gate_m`): the one rule of `changes` and `merge`. A verified alignment (match's
    verification on the full maps decided) is refused only when it pairs no more often than B displaced (1.5x the
    chance rate) and, where none of A's landmarks was compared, stands; an unverified one (a window consensus,
    `match --no-verify`: 7 associations can be a chance alignment 181 m off) must also be significant
    (p < UNVERIFIED_MAX_P), and with nothing compared it is not confirmed. The text names no file: the caller does,
    and says what it did not do."""
    if not support.compared:
        return None if verified else ("none of A's landmarks lies where B's keyframes looked under the transform "
                                      "(in view of enough of them to be compared): nothing confirms the alignment")
    if support.plausible(max_p=1.0 if verified else UNVERIFIED_MAX_P):
        return None
    return (f"the transform does not bring the maps together: {support.rate:.0%} of A's {support.compared} "
            f"compared landmarks have a counterpart, {support.displaced_rate:.0%} with B moved "
            f"{CONTROL_SHIFT * gate_m:.0f} m (chance): the alignment is wrong, or the maps share too few landmarks "
            "to confirm it")


def alignment_support(a: SessionObservations, b_in_a: SessionObservations, gate_m: float,
                      params: ChangeParams) -> AlignmentSupport:
    """Counterpart rate of A's compared landmarks with B as given and with B displaced horizontally by
    CONTROL_SHIFT x the gate in 6 directions (a control: the same maps, no true pairs). A wrong transform (an
    accepted match of the wrong place, a mirrored map) gives as many counterparts as the control."""
    seen, _, _ = in_view(a.positions, a.sizes, b_in_a.poses, b_in_a.cameras)
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
