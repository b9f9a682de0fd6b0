"""Associate two landmark maps (`sosmatch match A B --out DIR`): the windowed CLIPPER search of SOS-Match,
then its verification on the full maps.

`run(params, a, b, out_dir)` loads both maps (session directory, .sosmap file or COLMAP model; see
`sosmatch.database.map_loading`), computes the match's answer (`sosmatch.plugin.match_answer.match_maps`: the
search, then, unless `verify` is off, the verification of its hypotheses on the full maps) and writes, atomically:
    match.json          every solved window pair (hypothesis), the best accepted one, the consensus, the
                        verification, which search mode ran, timings (schema in README.md, "Matching maps")
    associations.csv    the answer's associations (the verified alignment's, or the consensus'), else none
    match.png           both maps in A's frame (B moved by the answer's transform), associations drawn, the best
                        hypothesis highlighted
Transforms map B into A's frame: x_A = scale * R @ x_B + t, in the maps' world coordinates.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import write_bytes_atomic, write_text_atomic
from ..database.landmark_map import (
    check_two_maps,
    crs_disagreement,
    georeference_offset_m,
    landmark_map_fingerprint,
)
from ..database.map_loading import LoadedMap, load_map, size_definition_disagreement
from ..database.match_io import MATCH_FORMAT, parse_match
from ..database.match_notes import no_match_text
from ..database.output_markers import versioned_identity
from ..database.outputs import open_output_dir
from ..plugin import __version__
from ..plugin.answer_uncertainty import refused_scale_note
from ..plugin.association import SearchResult, Transform, WindowHypothesis, roll_pitch_yaw_deg
from ..plugin.association.hypotheses import MIN_LANDMARKS_TO_ALIGN, SearchMode
from ..plugin.errors import InputError
from ..plugin.map_noise import derived_search_params
from ..plugin.match_answer import MatchAnswer, georeference_disagreement, ground_distance_text, match_maps
from ..plugin.params import Params, params_to_dict
from ..plugin.verification import hypothesis_agrees

log = logging.getLogger(__name__)


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


def _num(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def transform_to_json(t: Transform | None) -> dict[str, Any] | None:
    """{"rotation": 3x3 rows, "translation": [x, y, z], "scale": s, "roll_deg", "pitch_deg", "yaw_deg"}."""
    if t is None:
        return None
    roll, pitch, yaw = roll_pitch_yaw_deg(t.rotation)
    return {"rotation": t.rotation.tolist(), "translation": t.translation.tolist(), "scale": float(t.scale),
            "roll_deg": roll, "pitch_deg": pitch, "yaw_deg": yaw}


def hypothesis_to_json(h: WindowHypothesis) -> dict[str, Any]:
    """One window pair of match.json."""
    return {
        "window_a": list(h.window_a), "window_b": list(h.window_b),
        "num_putative": h.num_putative, "num_core": h.num_core, "size": h.size, "score": _num(h.score),
        "associations": h.associations.tolist(), "transform": transform_to_json(h.transform),
        "roll_deg": _num(h.roll_deg), "pitch_deg": _num(h.pitch_deg), "tilt_deg": _num(h.tilt_deg),
        "accepted": h.accepted, "yaw_slice": h.yaw_slice,
    }


def search_mode_json(params: Params, answer: MatchAnswer | None) -> dict[str, Any]:
    """Which search ran: the consistency test, windows, solver, yaw slices and the position prior."""
    ap = params.association
    mode = SearchMode.of(ap)
    return {"consistency": ap.consistency, "windows": ap.windows, "solver": ap.solver, "yaw_slices": mode.nslices,
            "position_prior_m": ap.position_prior_m, "position_prior": answer.prior if answer else "off",
            "tolerances": answer.tolerances if answer else "configured",
            # theta_S and windows of the search whose hypotheses match.json lists (`MatchAnswer.searched`)
            "searched": _searched_json(answer.searched if answer and answer.searched else ap),
            "paper": ap.consistency == "distance" and ap.windows == "id" and ap.solver == "clipper"
            and ap.position_prior_m == 0 and not (answer and answer.tolerances == "georeference"),
            # georeferenced maps (one EPSG, or two: `landmark_map.georeference_offset_m`): how far the accepted
            # answer moves B from where its georeference puts it; what merge and batch judge (`georeference_note`)
            **({"georeference_off_m": round(answer.georeference_off_m, 2)}
               if answer and answer.georeference_off_m is not None else {})}


def _searched_json(ap: Any) -> dict[str, Any]:
    return {"window_length": ap.window_length, "window_stride": ap.window_stride,
            # each map's window is window_length x its factor (equal-area windows; 1 and 1 the paper's)
            "window_factors": [ap.window_factor_a, ap.window_factor_b],
            "min_associations": ap.min_associations, "distance_tolerance_m": ap.distance_tolerance_m,
            "max_size_difference": ap.max_size_difference,
            # > 0: only associations this near where the maps' georeferences put them (`position_prior`)
            "position_prior_m": ap.position_prior_m}


def _imprecise_text(ans: MatchAnswer | None) -> str:
    """', WARNING: imprecise answer ...' when the accepted answer's predicted error at B's landmarks exceeds its gate
    (`plugin.answer_uncertainty`), else ''."""
    u = None if ans is None else ans.uncertainty
    return "" if u is None or not u.imprecise else f", WARNING: {u.warning()}"


def _chance_text(v: Any) -> str:
    """', chance p 3e-09 (mean 2.1)': the probability that chance alone reaches this support somewhere."""
    return "" if v.chance is None else f", chance p {v.chance.p_value:.1g} (mean {v.chance.mean:.1f})"


def verification_json(answer: MatchAnswer | None, params: Params) -> dict[str, Any] | None:
    """The verification's result (None when it did not run)."""
    if answer is None or answer.verification is None:
        return None
    v, vp = answer.verification, params.verification
    best = v.best
    return {"accepted": bool(v.accepted), "transform": transform_to_json(answer.transform),
            "support": 0 if best is None else len(best.associations), "runner_up_support": int(v.runner_up_support),
            "rms_m": None if best is None else _num(best.rms_m), "num_refined": int(v.num_refined),
            "support_dof": int(v.support), "clear": bool(v.clear),
            # with a position prior: the winner lay beyond it, where its chance test does not reach (not accepted)
            "beyond_prior": bool(v.beyond_prior),
            # the runner-up when the maps' own layout placed it (a shift by a repeat of A's layout, a turn by one of
            # its symmetries; `plugin.layout_rivals`): {"support", "shift_m", "turn_deg"}; None: another rival
            "layout_rival": None if v.layout_rival is None else v.layout_rival.to_dict(),
            # the F test of a tilt in the winner's pairs' heights (the fitted tilt is shrunk by tilt_prior_deg)
            "tilt_p": None if v.tilt_p is None else _num(v.tilt_p),
            "chance": None if v.chance is None else {**v.chance.to_dict(), "false_alarm": vp.false_alarm},
            "associations": answer.associations.tolist(),
            # with_scale: every refinement fitted a scale too (association.transform "similarity")
            "method": {"dof": vp.dof, "with_scale": params.association.transform == "similarity",
                       "final_dof": vp.final_dof, "tilt_prior_deg": vp.tilt_prior_deg,
                       "min_ratio": vp.min_ratio, "z_weight": vp.z_weight,
                       "max_candidates": vp.max_candidates, "gate_m": params.association.distance_tolerance_m,
                       "max_size_difference": vp.max_size_difference, "chance_starts": vp.chance_starts,
                       "false_alarm": vp.false_alarm, "min_support": params.association.min_associations}}


def _agreement(result: MatchResult, params: Params) -> list[bool | None]:
    """Per window hypothesis: does it agree with the verified answer (None: no accepted verified answer)."""
    hyps = result.search.hypotheses
    ans = result.answer
    if ans is None or ans.source != "verified" or not ans.accepted or ans.transform is None:
        return [None] * len(hyps)
    tol = 2.0 * params.association.distance_tolerance_m
    pa, pb = result.map_a.lmap.positions, result.map_b.lmap.positions
    return [hypothesis_agrees(h.associations, ans.transform, pa, pb, tol) for h in hyps]


def match_to_json(result: MatchResult, params: Params) -> dict[str, Any]:
    """The match.json document (see README.md for the schema)."""
    s = result.search

    def source(m: LoadedMap) -> dict[str, Any]:
        return {"path": str(m.path), "kind": m.kind, "landmarks": len(m.lmap), "has_sizes": m.lmap.has_sizes,
                "epsg": m.lmap.epsg, "fingerprint": landmark_map_fingerprint(m.lmap)}

    consensus = None
    if s.consensus is not None:
        consensus = {"members": s.consensus.members, "transform": transform_to_json(s.consensus.transform),
                     "num_associations": len(s.consensus.associations), "rms_m": _num(s.consensus.rms_m),
                     "accepted": bool(s.consensus.accepted), "associations": s.consensus.associations.tolist()}
    return {
        "format": MATCH_FORMAT,
        "version": __version__,
        "map_a": source(result.map_a),
        "map_b": source(result.map_b),
        "params": {"association": params_to_dict(params.association),
                   "verification": params_to_dict(params.verification), "seed": params.seed},
        "search_mode": search_mode_json(params, result.answer),
        "map_noise": [None if m.noise is None else m.noise.to_dict() for m in (result.map_a, result.map_b)],
        "transform_kind": params.association.transform,
        "transform_convention": "x_A = scale * R @ x_B + t (A_from_B, world coordinates of the maps)",
        "num_windows": [len(s.windows_a), len(s.windows_b)],
        "num_window_pairs": s.num_window_pairs,
        "num_solved": len(s.hypotheses),
        "num_accepted": len(s.accepted),
        "best": s.best,
        "accepted": s.accepted,
        "consensus": consensus,
        "verification": verification_json(result.answer, params),
        # the accepted answer's predicted placement error at B's landmarks in the common area against its gate
        # (`plugin.answer_uncertainty`; "imprecise": true when it exceeds the gate); null without an accepted answer
        "answer_uncertainty": (result.answer.uncertainty.to_dict() if result.answer is not None
                               and result.accepted and result.answer.uncertainty is not None else None),
        # the answer consumers read (database.match_io.read_match): "verified" or "consensus"
        "answer": result.answer.source if result.answer is not None else "consensus",
        # every window hypothesis, and (verified answer accepted) whether it agrees with it: an agreeing one lends
        # the answer its associations, never its own transform (`plugin.verification.hypothesis_agrees`)
        "hypotheses": [{**hypothesis_to_json(h), "agrees_with_answer": agree}
                       for h, agree in zip(s.hypotheses, _agreement(result, params))],
        # the time of the answer: search + verification (wall); their parts in `timings`
        "search_seconds": result.answer.timings["total_s"] if result.answer else s.timings.get("total_s"),
        "timings": {**{k: float(v) for k, v in s.timings.items()},
                    **({"search_wall_s": result.answer.timings["search_s"],
                        "verify_s": result.answer.timings["verify_s"]} if result.answer else {})},
    }


def associations_csv(result: MatchResult) -> str:
    """index_a,index_b,x_a,y_a,z_a,x_b,y_b,z_b,size_a,size_b,residual_m (residual after the consensus transform)."""
    a, b = result.map_a.lmap, result.map_b.lmap
    lines = ["index_a,index_b,x_a,y_a,z_a,x_b,y_b,z_b,size_a,size_b,residual_m"]
    if len(result.associations):
        ia, ib = result.associations[:, 0], result.associations[:, 1]
        res = np.linalg.norm(result.transform.apply(b.positions[ib]) - a.positions[ia], axis=1)
        for k in range(len(ia)):
            pa, pb = a.positions[ia[k]], b.positions[ib[k]]
            lines.append(f"{ia[k]},{ib[k]},{pa[0]:.3f},{pa[1]:.3f},{pa[2]:.3f},{pb[0]:.3f},{pb[1]:.3f},{pb[2]:.3f},"
                         f"{a.sizes[ia[k]]:.2f},{b.sizes[ib[k]]:.2f},{res[k]:.3f}")
    return "\n".join(lines) + "\n"


def alignment_png(result: MatchResult) -> bytes:
    """Both maps in A's frame (top view), associations as segments, the best hypothesis highlighted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    a, b = result.map_a.lmap.positions, result.map_b.lmap.positions
    s = result.search
    transform = result.transform
    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    ax.scatter(a[:, 0], a[:, 1], s=6, c="#1f77b4", label=f"map A ({len(a)})", linewidths=0)
    if transform is not None:
        bt = transform.apply(b)
        ax.scatter(bt[:, 0], bt[:, 1], s=6, c="#ff7f0e", label=f"map B in A's frame ({len(b)})", linewidths=0)
        assoc = result.associations
        segs = np.stack([a[assoc[:, 0], :2], bt[assoc[:, 1], :2]], axis=1)
        ax.add_collection(LineCollection(segs, colors="#2ca02c", linewidths=1.0))
        # at map scale the segments are sub-metre: mark the associated landmarks too
        ax.scatter(a[assoc[:, 0], 0], a[assoc[:, 0], 1], s=14, marker="+", c="#2ca02c", linewidths=0.8,
                   label=f"consensus associations ({len(assoc)})")
        if s.best is not None:
            best = s.hypotheses[s.best]
            ax.scatter(a[best.associations[:, 0], 0], a[best.associations[:, 0], 1], s=40, facecolors="none",
                       edgecolors="#d62728", linewidths=1.2, label=f"best hypothesis |S|={best.size}")
        title = f"{len(s.accepted)} accepted of {len(s.hypotheses)} solved window pairs"
        if result.answer is not None and result.answer.verification is not None:
            title += ", verified" if result.accepted else ", verification refused it"
    else:
        ax.scatter(b[:, 0], b[:, 1], s=6, c="#ff7f0e", label=f"map B, own frame ({len(b)})", linewidths=0)
        title = "no accepted hypothesis (map B shown in its own frame)"
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


# Ellipsoidal and sea-level heights differ by the geoid's undulation, at most ~106 m anywhere on Earth: two
# georeferenced maps whose heights differ by more are not on one height datum (heights above take-off, feet)
MAX_DATUM_DIFFERENCE_M = 110.0


def _georeference_warning(ans: Any, path_b: str | Path, radius_m: float) -> str | None:
    """The warning when the answer moves B farther from its georeference than `radius_m`
    (`match_answer.georeference_disagreement`, the rule merge and batch repeat from match.json), else None."""
    if (said := georeference_disagreement(ans.georeference_off_m, radius_m, ans.prior)) is not None:
        return f"{path_b}: {said}"
    return None


def _tilt_warning(ans: Any, a: str | Path, b: str | Path) -> str | None:
    """The warning when an accepted answer is the verification's free 6-DOF fit because the maps are tilted against
    each other (`verification.maps_tilted`): a level fit would have lost most pairs. None otherwise."""
    v = ans.verification
    if not ans.accepted or v is None or v.tilted_deg is None:
        return None
    return (f"{b}: the maps' vertical axes differ by {v.tilted_deg:.1f} deg (not both gravity-aligned?): the answer "
            f"is the free 6-DOF fit ({v.support} pairs; a level fit kept far fewer); {a} and {b} are not in one "
            "gravity-aligned frame")


def _height_datum_warning(ans: Any, points_b: np.ndarray, path_b: str | Path) -> str | None:
    """The warning when an accepted alignment of two maps in one EPSG moves B's landmarks vertically by more than
    two height datums can differ (MAX_DATUM_DIFFERENCE_M): the search and the prior are horizontal, so it still
    finds the alignment, but the maps' heights are not comparable. None: within that."""
    pairs = np.asarray(ans.associations, np.int64).reshape(-1, 2)
    if not len(pairs) or ans.transform is None:
        return None
    pb = np.asarray(points_b, np.float64)[pairs[:, 1]]
    dz = float(np.median(ans.transform.apply(pb)[:, 2] - pb[:, 2]))
    if abs(dz) > MAX_DATUM_DIFFERENCE_M:
        return (f"{path_b}: its landmarks lie {abs(dz):.0f} m {'below' if dz > 0 else 'above'} those of A under the "
                "answer, more than ellipsoidal and sea-level heights differ anywhere: the two maps' altitudes are not "
                "on one datum (heights above take-off, or in feet?)")
    return None


def _takeoff_height_warning(ans: Any, points_b: np.ndarray, a: str | Path, b: str | Path) -> str | None:
    """The warning when an accepted answer moves B vertically while a map's ground lies far from where its
    recorded heights above take-off put it (run.json "height_above_takeoff", `map.recorded_height`): a focal
    length off scales that map's heights, and the vertical move carries the error (nu42: B moved 102.6 m by a
    map 100 m low, within two height datums' difference, so `_height_datum_warning` was silent). None otherwise."""
    from ..database.session_io import read_map_record
    from .map.recorded_height import ground_off_beyond

    pairs = np.asarray(ans.associations, np.int64).reshape(-1, 2)
    if not len(pairs) or ans.transform is None:
        return None
    off = []
    for path in (a, b):
        try:
            record = read_map_record(path) if Path(path).is_dir() else None
        except InputError:
            record = None
        if (ground := ground_off_beyond((record or {}).get("height_above_takeoff"))) is not None:
            off.append(f"{path}'s ground lies {abs(ground):.0f} m {'above' if ground > 0 else 'below'}")
    if not off:
        return None
    pb = np.asarray(points_b, np.float64)[pairs[:, 1]]
    dz = float(np.median(ans.transform.apply(pb)[:, 2] - pb[:, 2]))
    return (f"the answer moves B {dz:+.1f} m vertically, and {' and '.join(off)} where its recorded heights above "
            "take-off put it (its map's warning: ground that far from the take-off point's, or a focal length off): if "
            "the focal length, the vertical part of this answer, and heights compared across these maps, inherit that "
            "error")


def run(params: Params, a: str | Path, b: str | Path, out_dir: str | Path, workers: int | None = None,
        exhaustive: bool = False, plot: bool = True, overwrite: bool = False,
        verify: bool | None = None) -> MatchResult:
    """Match map `b` against map `a` and write match.json, associations.csv and match.png into `out_dir`.

    a, b: session directories, .sosmap files or COLMAP models. workers: unused (the search runs in one process).
    exhaustive: use the straightforward reference search (every window pair from scratch; slow, same result).
    verify: verify the search's hypotheses on the full maps (default `params.verification.enabled`); off, the
    answer is the window consensus. A position prior (`association.position_prior_m`) is used only when both maps
    are georeferenced in one EPSG. overwrite: replace a complete match of other maps or settings in `out_dir` (see
    `sosmatch.database.outputs` for what is never replaced). Raises InputError for unreadable or unusable maps.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    out_dir = Path(out_dir)
    map_a, map_b = load_map(a), load_map(b)
    la, lb = map_a.lmap, map_b.lmap
    prints = check_two_maps(a, b, la, lb, "match")
    for m in (map_a, map_b):
        # named here, at the edge: the search's own check knows the map only as "A" or "B" (nu27)
        if len(m.lmap) < MIN_LANDMARKS_TO_ALIGN:
            raise InputError(f"holds {len(m.lmap)} landmark(s); at least {MIN_LANDMARKS_TO_ALIGN} are needed to "
                             "match it with another map (a rigid transform needs 3 points)", m.path)
    said: list[str] = []  # every warning, logged and recorded in match.json `warnings`

    def warn(text: str | None) -> None:
        if text is not None:
            log.warning("%s", text)
            said.append(text)

    warn(crs_disagreement(la, lb))
    warn(size_definition_disagreement(map_a, map_b))
    if verify is not None:
        params = dataclasses.replace(params, verification=dataclasses.replace(params.verification, enabled=verify))
    # tolerances from the maps' own noise and windows from their geometry when `association.derive_from_maps`
    # (recorded in match.json's params and search_mode "derived"), searched first with the tighter of the
    # derived and the configured tolerances (`match_answer`, module doc)
    if params.association.derive_from_maps:
        for name, m in (("A", map_a), ("B", map_b)):
            if m.noise is None:
                warn(f"map {name} ({m.path}) records no noise figures (a COLMAP model, or a .sosmap written before "
                     "map files carried them): the configured tolerances are used, not ones derived from the "
                     "maps; give its mapped session directory to derive them")
    derivation = derived_search_params(params.association, map_a.noise, map_b.noise, la.positions, la.sizes,
                                       lb.positions, lb.sizes)
    first_try = derivation.first_try
    params = dataclasses.replace(params, association=derivation.params)
    identity = versioned_identity(lambda as_dict: {
        "a": prints[0], "b": prints[1], "association": as_dict(params.association),
        "first_try": None if first_try is None else as_dict(first_try),
        # only when there is one: outputs of maps that get no wider search keep their identity
        **({} if derivation.wider_try is None else {"wider_try": as_dict(derivation.wider_try)}),
        **({} if derivation.near_try is None else {"near_try": as_dict(derivation.near_try)}),
        "verification": as_dict(params.verification), "seed": params.seed, "exhaustive": exhaustive, "plot": plot})
    with open_output_dir(out_dir, "match", identity, inputs=[a, b], overwrite=overwrite,
                         legacy_record="match.json") as out:
        common = la.epsg == lb.epsg != 0
        if params.association.position_prior_m > 0 and not common:
            warn(f"position prior ignored: the maps are not georeferenced in one EPSG (A: {la.epsg}, B: {lb.epsg})")
        ans = match_maps(la.positions, la.sizes, lb.positions, lb.sizes, params, common_frame=common,
                         exhaustive=exhaustive, first_try=first_try, wider_try=derivation.wider_try,
                         near_try=derivation.near_try)
        if ans.accepted and not common and ans.transform is not None:
            # two EPSG codes: where each puts B on the ground (`georeference_offset_m`; None without both codes),
            # judged by the rule of one EPSG: a wrong label is a wrong georeference, one site in two zones is not
            ans.georeference_off_m = georeference_offset_m(la, lb, ans.transform, ans.associations)
        geo_warning = _georeference_warning(ans, b, params.association.georeference_prior_m) if ans.accepted else None
        warn(geo_warning)
        if common and ans.accepted:
            warn(_height_datum_warning(ans, lb.positions, b))
            warn(_takeoff_height_warning(ans, lb.positions, a, b))
        warn(_tilt_warning(ans, a, b))
        if ans.accepted and ans.uncertainty is not None and ans.uncertainty.imprecise:
            warn(f"{b}: {ans.uncertainty.warning()}; merge and changes inherit that error")
        ver = ans.verification
        if not ans.accepted and ver is not None and ver.best is not None:
            # a refusal that a scale explains says so: a rigid search of two domed SfM maps was refused bare (nu54)
            note = refused_scale_note(la.positions, lb.positions, ver.best.transform, ver.best.associations)
            warn(None if note is None else f"{b}: {note}")
        # a refused answer names no associations (match.json's verification keeps what was tried)
        result = MatchResult(out_dir, map_a, map_b, ans.search,
                             ans.associations if ans.accepted else np.zeros((0, 2), np.int64),
                             ans.transform if ans.accepted else None, 0.0, ans)
        result.georeferences_disagree = geo_warning is not None
        result.min_ratio = params.verification.min_ratio
        result.seconds, result.cpu_seconds = time.perf_counter() - t0, time.process_time() - cpu0
        doc = match_to_json(result, params)
        doc["search_mode"]["derived"] = derivation.record
        doc["seconds_total"] = result.seconds
        doc["cpu_seconds_total"] = result.cpu_seconds
        doc["warnings"] = said
        parse_match(doc, out_dir / "match.json")  # the reader's validation: never write what it would refuse
        write_text_atomic(out_dir / "associations.csv", associations_csv(result))
        if plot:
            write_bytes_atomic(out.staged("match.png"), alignment_png(result))
        # not plotted: a previous run's picture (of other maps, perhaps) is removed, not left beside this match.json
        out.publish(["match.png"], optional=("match.png",))
        write_text_atomic(out_dir / "match.json", json.dumps(doc, indent=1) + "\n")  # last: its presence = done
        out.finish()
    return result
