"""Which transform `match` searches two maps with, from where their poses came from.

A map whose poses came from sosmatch's structure from motion (`sosmatch poses`, `map --images`: run.json
`pose_source`, the map file's flag 4) may be domed: on small images the bundle adjustment determines the lens's k1
poorly, the cameras stay on their GPS priors and the error goes into the rotations, which lean away from (or
toward) the block's centre in proportion to the distance from it; every landmark is then scaled about the centre
by 1-5 % in plan and depth (BENCHMARKS.md "Two SfM maps of one place refused"). Two such maps, or one and a map of
given poses, differ by that scale, which a rigid transform with noise tolerances cannot absorb: nu54's two
photo-mapped flights were refused, two other pairs verified "imprecise". So when either map is SfM-posed and the
user did not choose `association.transform`, the search and verification fit a similarity (the verification's
chance placements fit a scale too, so chance is judged with the same freedom), and the answer is kept only when
its scale is one a dome can make (`MAX_DOME_SCALE`); beyond it, the rigid match is the answer, as before. Maps of
given poses (EKF, telemetry, synth, EXIF tags) are matched rigidly as before, byte for byte.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ...plugin.params import Params

# how far from 1 the scale between two SfM maps may be and still be called a dome's: measured 0.959-1.041 between
# two domed 320x240 blocks (each 0.97-1.05 against the truth, dome coefficients a x 100 m up to 0.05); two blocks
# domed oppositely at that limit differ by ~10 %. A larger scale is not a dome: a scale error of the GPS or the
# focal length, which the map's own checks report (pose_check's GPS lengths, the height above take-off)
MAX_DOME_SCALE = 0.10


@dataclass(frozen=True)
class TransformChoice:
    """The parameters to search with and, when the maps' pose source chose a similarity, what to say of it."""

    params: Params
    note: str | None = None  # None: the transform is the configured one


def choose_transform(params: Params, chosen: bool, sfm_a: bool, sfm_b: bool) -> TransformChoice:
    """`params` with `association.transform` "similarity" when either map's poses came from structure from motion
    (`sfm_a`, `sfm_b`: `LoadedMap.sfm_poses`), the configured transform is "rigid" and the user did not choose it
    (`chosen`: set by --set, --config or --preset); otherwise `params` as they are (module doc)."""
    if chosen or params.association.transform != "rigid" or not (sfm_a or sfm_b):
        return TransformChoice(params)
    which = "A's and B's" if sfm_a and sfm_b else "A's" if sfm_a else "B's"
    note = (f"searched with a similarity (association.transform \"similarity\"): {which} poses came from structure "
            "from motion, whose block can be domed, scaled by a few % about its centre; a scale beyond "
            f"{MAX_DOME_SCALE:.0%} is not kept (`--set association.transform=rigid` to match rigidly)")
    association = dataclasses.replace(params.association, transform="similarity")
    return TransformChoice(dataclasses.replace(params, association=association), note)


def beyond_dome(scale: float) -> str | None:
    """What to say when a similarity answer's `scale` (B into A) is more than a dome makes (`MAX_DOME_SCALE`),
    else None."""
    if abs(scale - 1.0) <= MAX_DOME_SCALE:
        return None
    return (f"the similarity's answer scales B by x {scale:.4f}, more than an SfM block's dome makes "
            f"(within {MAX_DOME_SCALE:.0%}): not kept; the rigid match answers")
