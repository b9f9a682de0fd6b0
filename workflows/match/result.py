"""What `sosmatch match` computed (`MatchResult`) and the one-line summary the command prints."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...database.map_loading import LoadedMap
from ...database.match_notes import no_match_text
from ...plugin.association import SearchResult, Transform, roll_pitch_yaw_deg
from ...plugin.match_answer import MatchAnswer, ground_distance_text


@dataclass
class MatchResult:
    """What `run` computed and wrote."""

    out_dir: Path
    map_a: LoadedMap
    map_b: LoadedMap
    search: SearchResult
    associations: np.ndarray  # (K, 2) the answer's associations, empty if there is none
    transform: Transform | None  # the answer's A_from_B, None if there is none
    seconds: float  # wall time of the whole run (loading, search, verification, outputs)
    answer: MatchAnswer | None = None
    cpu_seconds: float = float("nan")  # CPU time of the same (all threads): the honest figure on a shared machine
    # the accepted answer contradicts the two maps' georeferences (`match_answer.georeference_disagreement`)
    georeferences_disagree: bool = False
    min_ratio: float | None = None  # the verification's ratio test (`no_match_text` names the refusal's cause)

    @property
    def accepted(self) -> bool:
        return bool(self.answer.accepted) if self.answer is not None else self.transform is not None

    def times(self) -> str:
        """'2.31 s, CPU 4.10 s': wall and CPU time of the run (CPU counts every thread of the process; on a
        shared machine the wall time also counts the waits for a core)."""
        cpu = f", CPU {self.cpu_seconds:.2f} s" if math.isfinite(self.cpu_seconds) else ""
        return f"{self.seconds:.2f} s{cpu}"

    def _georeference_text(self) -> str:
        """', WARNING: images agree, georeferences disagree by X: ...' when they do (the log says why), else ''."""
        if not self.georeferences_disagree or self.answer is None or self.answer.georeference_off_m is None:
            return ""
        return (f", WARNING: images agree, georeferences disagree by "
                f"{ground_distance_text(self.answer.georeference_off_m)}: one georeference is wrong (`merge` "
                "refuses it without --trust-images, `batch` keeps the two apart)")

    def summary(self) -> str:
        """The one-line summary the command prints."""
        s = self.search
        head = (f"{len(self.map_a.lmap)} x {len(self.map_b.lmap)} landmarks, {len(s.hypotheses)}/{s.num_window_pairs}"
                f" window pairs solved, {len(s.accepted)} window hypotheses over theta_S")
        ans = self.answer
        if ans is not None and ans.verification is not None:
            v = ans.verification
            if not v.accepted:  # in the words batch repeats from match.json (`match_notes.refusal_note`)
                said = no_match_text(None if v.best is None else len(v.best.associations), v.runner_up_support,
                                     None if v.chance is None else v.chance.p_value,
                                     None if v.chance is None else v.chance.mean, v.beyond_prior,
                                     None if v.layout_rival is None else v.layout_rival.text(),
                                     None if ans.searched is None else ans.searched.min_associations,
                                     None if v.best is None else v.support,
                                     None if v.chance is None else v.chance.row_placements, self.min_ratio)
                return f"{head}, {said} ({self.times()}) -> {self.out_dir / 'match.json'}"
            _, _, yaw = roll_pitch_yaw_deg(self.transform.rotation)
            near = (f" within {ans.searched.position_prior_m:g} m (horizontally) of the georeference"
                    if ans.tolerances == "georeference" and ans.searched is not None else "")
            # an imprecise answer is said at the verdict, not only at the end of the line: "verified" alone was
            # read as a clean answer while B may lie 58 m off (nu44); it passed the tests, so exit 0 stays
            imprecise = ", imprecise" if ans.uncertainty is not None and ans.uncertainty.imprecise else ""
            return (f"{head}, verified{near}{imprecise}: {len(self.associations)} associations on the full maps "
                    f"(runner-up {v.runner_up_support}{_chance_text(v)}, rms {v.best.rms_m:.2f} m, yaw {yaw:.1f} deg)"
                    f"{_imprecise_text(ans)}{self._georeference_text()} ({self.times()}) -> "
                    f"{self.out_dir / 'match.json'}")
        if s.consensus is not None and not s.consensus.accepted:
            return (f"{head}, no match: the consensus of {len(s.consensus.members)} agreeing hypotheses holds "
                    f"{len(s.consensus.associations)} associations under its refitted transform, no more than "
                    f"theta_S; not verified ({self.times()}) -> {self.out_dir / 'match.json'}")
        if self.transform is None:
            return f"{head}, no match ({self.times()}) -> {self.out_dir / 'match.json'}"
        best = s.hypotheses[s.best]
        _, _, yaw = roll_pitch_yaw_deg(self.transform.rotation)
        return (f"{head}, best |S|={best.size}, consensus {len(self.associations)} associations "
                f"(rms {s.consensus.rms_m:.2f} m, yaw {yaw:.1f} deg), not verified{_imprecise_text(ans)}"
                f"{self._georeference_text()} "
                f"({self.times()}) -> "
                f"{self.out_dir / 'match.json'}")


def _imprecise_text(ans: MatchAnswer | None) -> str:
    """', WARNING: imprecise answer ...' when the accepted answer's predicted error at B's landmarks exceeds its gate
    (`plugin.answer_uncertainty`), else ''."""
    u = None if ans is None else ans.uncertainty
    return "" if u is None or not u.imprecise else f", WARNING: {u.warning()}"


def _chance_text(v: Any) -> str:
    """', chance p 3e-09 (mean 2.1)': the probability that chance alone reaches this support somewhere."""
    return "" if v.chance is None else f", chance p {v.chance.p_value:.1g} (mean {v.chance.mean:.1f})"
