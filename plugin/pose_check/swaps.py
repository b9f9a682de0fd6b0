"""Cameras whose poses were exchanged (a pose table joined to its images one row off for two frames, two rows
swapped): told by asking the images whether the poses fit BETTER exchanged.

The pair error of `check` (the Sampson distance under E = [t]x R) is blind to the sign of the baseline: E and -E
have the same epipolar lines. Two consecutive frames' poses exchanged flip the sign of their own pair's baseline
(its matches then triangulate behind the cameras: `PairCheck.in_front` near 0) and give each neighbour pair a
baseline of two steps or none in the right direction, which the epipolar error sees only through the small
differences of the two frames' attitudes (1-3 px where the flight's median is 0.3 px; BENCHMARKS.md). Neither is
beyond a limit a sound flight's pairs stay under, so the swap passed as "ok". Nor can a distant swap always be
seen camera by camera: a camera with a single checked pair cannot be blamed for it (`verdict.wrong_cameras`).

The test here is the hypothesis itself: for two cameras c, d, the checked pairs that contain either are judged
again with the poses of c and d exchanged (epipolar error and the side the matches triangulate on). The poses are
exchanged when, exchanged, none of those pairs fails (beyond the camera limit, or reversed), their median error
falls to at most `EXCHANGE_GAIN` of what the poses as given leave, and the poses as given misfit those pairs
clearly (their median beyond `EXCHANGE_MISFIT` times the flight's median pair error: noisy poses put two
positions in the wrong order, and an exchange fits those better too). On sound
poses exchanging two cameras only makes their pairs worse. Candidates: every two consecutive images, and every two
cameras of failing pairs (bounded, `MAX_SUSPECTS`). A camera without a checked pair is judged through the other:
exchanged, its pose is the one the other's pairs are asked to fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from ..geometry import Poses
from .matches import PairMatches
from .systematic import pair_sampson_px
from .two_view import relative_poses, triangulation_depths

# the exchanged poses must take the pairs' median error to at most this share of the given poses' (measured:
# swaps 0.05-0.3, sound poses' neighbours exchanged 2-20; BENCHMARKS.md "Exchanged cameras")
EXCHANGE_GAIN = 0.5
# ... and the given poses must misfit those pairs clearly: their median beyond this many times the flight's median
# pair error. A reversed pair alone is no such evidence: 3 m of GPS noise on 7 m steps puts two consecutive
# positions in the wrong order, which an exchange fits better (7.0 -> 3.1 px where the flight's median is 5.1 px)
EXCHANGE_MISFIT = 3.0
# cameras of failing pairs tried against each other (pairs of them: at most MAX_SUSPECTS^2 / 2 small re-checks)
MAX_SUSPECTS = 40


@dataclass(frozen=True)
class Exchange:
    """Two cameras whose poses fit the images exchanged (`exchanged_cameras`)."""

    a: int
    b: int
    pairs: int  # checked pairs that contain either
    given_px: float  # their median epipolar error on the poses as given
    exchanged_px: float  # ... and with the two poses exchanged
    failing: int  # of them failing on the poses as given (beyond the camera limit, or reversed)
    exchanged_fit: bool = True  # none of them fails with the two poses exchanged

    def to_dict(self, names: list[str] | None = None) -> dict:
        def name(i: int) -> str | int:
            return names[i] if names is not None and i < len(names) else i

        return {"a": name(self.a), "b": name(self.b), "pairs": self.pairs, "given_px": round(self.given_px, 3),
                "exchanged_px": round(self.exchanged_px, 3), "failing": self.failing}


def pair_figures(poses: Poses, pairs: list[PairMatches], focal_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(median Sampson distance px, share of inliers triangulated in front of both cameras) of each pair under
    `poses`, as `check.check_poses` measures them (NaN where the poses give a pair no baseline)."""
    if not pairs:
        return np.zeros(0), np.zeros(0)
    raw = np.split(pair_sampson_px(poses, pairs, focal_px), np.cumsum([p.inliers for p in pairs])[:-1])
    rot, t = relative_poses(poses.rotations, poses.centers, np.array([p.a for p in pairs]),
                            np.array([p.b for p in pairs]))
    med, front = [], []
    for p, r, r_p, t_p in zip(pairs, raw, rot, t):
        finite = r[np.isfinite(r)]
        med.append(float(np.median(finite)) if len(finite) else float("nan"))
        d_a, d_b = triangulation_depths(p.x_a, p.x_b, r_p, t_p)
        front.append(float(np.mean((d_a > 0) & (d_b > 0))))
    return np.array(med), np.array(front)


def _exchanged(poses: Poses, c: int, d: int) -> Poses:
    order = np.arange(len(poses))
    order[[c, d]] = order[[d, c]]
    return Poses(poses.names, poses.rotations[order], poses.centers[order])


def exchanged_cameras(poses: Poses, pairs: list[PairMatches], epipolar_px: np.ndarray, in_front: np.ndarray,
                      sees_direction: np.ndarray, focal_px: float, limit_px: float, flight_px: float
                      ) -> list[Exchange]:
    """The cameras whose poses fit the images exchanged (module doc), best gain first, each camera at most once.
    `pairs`: the checked pairs' matches; `epipolar_px`, `in_front`, `sees_direction`: their figures on `poses`
    (`PairCheck`); `limit_px`: the pair error beyond which a pair fails (`check.camera_limit_px`); `flight_px`:
    the flight's median pair error."""
    checked = {c for p in pairs for c in (p.a, p.b)}
    # a camera without a checked pair of its own cannot tell an exchange from the other camera's pose being a
    # little off: its pose, given to the other's images, fits them better for either reason (rev59 D1: one frame
    # turned 1 deg on a 250-frame flight, whose pairs are drawn from 80 anchors, was refused as swapped with its
    # pairless neighbour, 5.1 px as given). There the given poses must fail a pair outright (the camera limit, or
    # a reversed pair), as a swap's do
    found = [e for e in exchange_trials(poses, pairs, epipolar_px, in_front, sees_direction, focal_px, limit_px)
             if e.exchanged_fit and e.exchanged_px <= EXCHANGE_GAIN * e.given_px
             and e.given_px > EXCHANGE_MISFIT * flight_px
             and (e.failing > 0 or (e.a in checked and e.b in checked))]
    out, used = [], set()
    for e in sorted(found, key=lambda e: (e.exchanged_px / e.given_px, e.a, e.b)):
        if e.a not in used and e.b not in used:
            out.append(e)
            used |= {e.a, e.b}
    return out


def exchange_trials(poses: Poses, pairs: list[PairMatches], epipolar_px: np.ndarray, in_front: np.ndarray,
                    sees_direction: np.ndarray, focal_px: float, limit_px: float) -> list[Exchange]:
    """Every candidate exchange (every two consecutive cameras, either with checked pairs; every two cameras of
    failing pairs) with at least two checked pairs measured, judged exchanged (`exchanged_cameras`' arguments)."""
    if len(pairs) < 2 or not np.isfinite(limit_px):
        return []
    sees = np.asarray(sees_direction, dtype=bool)
    touching: dict[int, list[int]] = {}
    for k, p in enumerate(pairs):
        touching.setdefault(p.a, []).append(k)
        touching.setdefault(p.b, []).append(k)

    def failing(med: np.ndarray, front: np.ndarray, idx: list[int]) -> np.ndarray:
        # NaN (no baseline) fails neither way; a reversed pair only where its parallax tells the direction
        return (med > limit_px) | (sees[idx] & (front < 0.5))

    given_fail = failing(np.asarray(epipolar_px), np.asarray(in_front), list(range(len(pairs))))
    suspects = sorted({c for k in np.flatnonzero(given_fail) for c in (pairs[k].a, pairs[k].b)})[:MAX_SUSPECTS]
    # two consecutive cameras where either has checked pairs: exchanged, the other's pose is judged by them
    n = len(poses)
    candidates = ({(c - 1, c) for c in touching if c > 0} | {(c, c + 1) for c in touching if c + 1 < n}
                  | set(combinations(suspects, 2)))
    out = []
    for c, d in sorted(candidates):
        idx = sorted(set(touching.get(c, [])) | set(touching.get(d, [])))
        given = np.asarray(epipolar_px)[idx]
        known = np.isfinite(given)
        if np.count_nonzero(known) < 2:  # the pair c/d alone: exchanging only flips its sign
            continue
        med, front = pair_figures(_exchanged(poses, c, d), [pairs[k] for k in idx], focal_px)
        fit = not np.any(failing(med, front, idx)) and bool(np.all(np.isfinite(med[known])))
        out.append(Exchange(int(c), int(d), len(idx), float(np.median(given[known])),
                            float(np.nanmedian(med[known])) if np.isfinite(med[known]).any() else float("nan"),
                            int(np.count_nonzero(given_fail[idx])), fit))
    return out
