"""match.json and associations.csv: the match's record (schema in README.md, "Matching maps"), as documents."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...database.landmark_map import landmark_map_fingerprint
from ...database.map_loading import LoadedMap
from ...database.match_io import MATCH_FORMAT
from ...plugin import __version__
from ...plugin.association import Transform, WindowHypothesis, roll_pitch_yaw_deg
from ...plugin.association.hypotheses import SearchMode
from ...plugin.match_answer import MatchAnswer
from ...plugin.params import Params, params_to_dict
from ...plugin.verification import hypothesis_agrees
from .result import MatchResult


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


def params_record(params: Params) -> dict[str, Any]:
    """The settings match.json keeps under "params" (those the search and verification read)."""
    return {"association": params_to_dict(params.association), "verification": params_to_dict(params.verification),
            "seed": params.seed}


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
        "params": params_record(params),
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
        # the time of the answer: search + verification (wall, without compiling or loading numba kernels: the
        # first match of an install compiles them for minutes, `kernel_compile_s`); their parts in `timings`
        "search_seconds": result.answer.timings["total_s"] if result.answer else s.timings.get("total_s"),
        "timings": {**{k: float(v) for k, v in s.timings.items()},
                    **({"search_wall_s": result.answer.timings["search_s"],
                        "verify_s": result.answer.timings["verify_s"],
                        "kernel_compile_s": result.answer.timings["kernel_compile_s"]} if result.answer else {})},
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
