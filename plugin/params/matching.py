"""Parameters of matching two maps: the windowed association search and the verification on the full maps."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError
from .checks import (
    Checked,
    count,
    flag,
    fraction,
    non_negative,
    one_of,
    within,
)

# theta_S can be no larger than this: no map pair holds a million common landmarks, and match.json's reader
# (`database.match_io`) holds its record to the same bound
MAX_ASSOCIATIONS = 10**6


@dataclass(frozen=True)
class AssociationParams(Checked):
    # theta_WL: landmarks per window; with factors > 1 below, the window of the map whose factor is 1 (the sparser)
    window_length: int = count(50, 3)
    window_stride: int = count(10, 1)  # theta_SL: stride between windows (scaled by the same factors)
    # (ours) each map's windows are window_length x its factor landmarks, stride window_stride x its factor: the
    # paper's windows are one length in both maps, which in maps of unequal density cover unequal ground (world 97,
    # 284 summer landmarks at 100 m against 95 winter ones at 130 m: 50-landmark windows span 9 400 and 30 400 m^2,
    # so a window pair held a third of the common objects at most and no true set reached theta_S). With
    # `equal_area_windows` and `derive_from_maps` the factors are derived from the maps
    # (`window_chance.area_factors`: the denser map's window grows by the largest power of two whose window spans
    # no more ground than the sparser map's; 1 and 1 for maps within a factor of two of each other's density, the
    # paper's windows); otherwise they are used as configured (1 and 1: the same length in both maps, literally)
    equal_area_windows: bool = flag(True)
    window_factor_a: int = count(1, 1)
    window_factor_b: int = count(1, 1)
    max_size_difference: float = fraction(0.2)  # theta_r: putative pairs need r(h_i, h_j) <= this
    # theta_eps: pairwise distance mismatch still called consistent (1 mm .. 1 km: beyond, every pair is consistent)
    distance_tolerance_m: float = within(2.0, 1e-3, 1e3)
    # sigma (ours) of the CLIPPER affinity exp(-c^2 / 2 sigma^2): the spread of the distance mismatch c of a true
    # pair (four landmarks with ~0.3-0.5 m noise each give ~1 m); affinity at the gate eps = 2 m is exp(-2) = 0.14
    affinity_sigma_m: float = within(1.0, 1e-3, 1e3)
    # theta_alpha: max roll/pitch difference of an accepted transform
    max_gravity_angle_deg: float = within(22.5, 0.0, 180.0)
    # theta_S (ours default; swept for precision-recall): accept if |S| > this. On synthetic 1000-landmark survey
    # maps (tools/benchmarks/bench_match.py) theta_S = 4 accepts wrong window pairs, 5 and 6 none: 6 keeps a margin,
    # and a larger theta_S also makes the search faster (only theta_S-cores are solved)
    min_associations: int = count(6, 2, MAX_ASSOCIATIONS)
    transform: str = one_of("rigid", "rigid", "similarity")  # "rigid" (Arun/Umeyama) or "similarity"
    # -- how the search forms its graphs (all ours; the paper's method is consistency "distance", windows "id",
    # no position prior: the "paper" preset). One definition of each test: plugin/association/consistency.py.
    # consistency: "distance" = the paper's | ||a|| - ||b|| | <= theta_eps on 3D landmark-pair vectors a (map A)
    # and b (map B); "gravity" = both maps are gravity-aligned, so a pair carries two invariants: the horizontal
    # lengths agree within theta_eps and the height differences agree within theta_eps + L tan(gravity_tilt_deg)
    # (L the longer horizontal length); and with yaw_slice_deg > 0 a consistent set must also share one yaw.
    consistency: str = one_of("gravity", "distance", "gravity")
    # (ours) tilt between the two maps' vertical axes the gravity test tolerates (EKF frames: 0.4-2.1 deg measured)
    gravity_tilt_deg: float = within(5.0, 0.0, 90.0, hi_open=True)
    # (ours) gravity: the height differences of a landmark pair may disagree by this times theta_eps beyond the
    # tilt's share. Landmark heights are noisier than their ground positions: on the evaluation suite's EKF maps
    # the 95th percentile of the height mismatch of true pairs is ~1.5x the horizontal one (BENCHMARKS.md)
    height_tolerance_factor: float = non_negative(2.0)
    # (ours) gravity: the yaw that a pair of associations implies (direction of a in A minus direction of b in B,
    # within asin(theta_eps / length)) must fall in one slice of this width for all pairs of a set; every window
    # pair is solved per slice and keeps its largest set. Chance-consistent pairs scatter over the 360 degrees,
    # a true set (and never a mirror image) shares one yaw. 0 = off.
    yaw_slice_deg: float = within(7.5, 0.5, 180.0, off=0.0)
    # windows: "id" = theta_WL landmarks in id (time) order, as in the paper; "spatial" = the same windows over
    # each map's landmarks sorted along a Hilbert curve of their horizontal positions in the map's own frame, so a
    # window is a compact patch of ground whatever the flight path (crossing flights share windows)
    windows: str = one_of("id", "id", "spatial")
    # (ours) position prior: > 0 = putative associations only between landmarks whose horizontal positions, in
    # the maps' common world frame (both georeferenced in one EPSG, or one shared local frame), are within this
    # distance (GNSS sigma x k); 0 = off (maps in unrelated frames)
    position_prior_m: float = non_negative(0.0)
    # (ours) maps georeferenced in one EPSG are also searched only within this horizontal distance of where their
    # georeferences put them, that search verified with the chance model of alignments that near (`plugin.chance`:
    # a spring and a crossing winter map of world 229 hold 21-23 true pairs, chance p 0.09 among every alignment of
    # the maps and 6e-6 among those within 50 m). Its answer is taken only when the search everywhere accepts nothing
    # and finds no alignment elsewhere with as many pairs (`match_answer.reconcile_near`): a georeference wrong by
    # more than this leaves near it partial alignments of a regular site. Two sessions' GNSS georeferences agree
    # within a few metres (consumer receivers 2-5 m, NAIP orthophotos 6 m at 95 %, sosmatch's EKF frames 1-2 m):
    # 50 m is ten times that. Not used with a position prior (a hard limit) or without the verification; 0 = off
    georeference_prior_m: float = non_negative(50.0)
    # solver of each window pair (plugin/association/clipper.solve): "clipper" = the relaxation and greedy rounding
    # on the theta_S-core (the paper); "bounded" = a greedy clique of the highest cores bounds the answer and the
    # relaxation runs only on the part of the core that could hold a larger set (ours; never a smaller set)
    solver: str = one_of("bounded", "clipper", "bounded")
    # (ours) derive theta_eps, sigma and theta_r from the two maps' own noise figures (`plugin.map_noise`: the
    # per-observation residual and size spread each mapped session records in run.json) instead of the values
    # above; maps without the figures (.sosmap files, COLMAP models) keep the values above. On by default: with
    # the fixed 2 m / 0.2 the held-out worlds 23 and 42 lost summer vs winter at 130 m (recall 0 on both: the
    # 130 m map's residual is 1.15 m, its common landmarks 3 m apart) and world 42 on the same path (0); derived,
    # every summer-winter case of worlds 5, 11, 23, 42 reaches recall 0.90-1.00 at P >= 0.99 and NAIP matches
    # (BENCHMARKS.md, issue 16). The paper preset keeps the paper's values
    derive_from_maps: bool = flag(True)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_windows(self)


def check_windows(p: AssociationParams) -> None:
    """Refuse windows that cannot work, however the params are made (a config file, --set, `config check`,
    direct construction): each field within its range is not enough. Both searches (`windows` "id" and "spatial")
    and each map's window factor scale length and stride alike, so the configured pair decides."""
    if p.window_length <= p.min_associations:
        # a window hypothesis is accepted only with more than theta_S associations, each of a distinct landmark of
        # the window: `--set association.window_length=3` searched 315 window pairs for a "no match", exit 0 (rev42)
        raise InputError(f"association.window_length {p.window_length} is at most association.min_associations "
                         f"(theta_S) {p.min_associations}: a window of {p.window_length} landmarks holds at most "
                         f"{p.window_length} associations and a match needs more than {p.min_associations}; raise "
                         "window_length or lower min_associations")
    if p.window_stride > p.window_length:
        # windows [0, 50), [100, 150), ... leave landmarks 50-99 of every 100 out of every search, silently (rev42).
        # Refused rather than clamped: a clamped stride is a different search than the one asked for and recorded
        raise InputError(f"association.window_stride {p.window_stride} exceeds association.window_length "
                         f"{p.window_length}: the landmarks between windows would never be searched; set "
                         "window_stride <= window_length")


@dataclass(frozen=True)
class VerificationParams(Checked):
    """Verification of a match on the full maps (`plugin.verification.verify_search`; a stage of `sosmatch match`,
    all ours). Across seasons one window pair's |S| is 4-14 for true and chance hypotheses alike; over the full
    maps a true transform brings many more landmarks of B onto landmarks of A (BENCHMARKS.md, Multi-session)."""

    enabled: bool = flag(True)  # off (`match --no-verify`): the answer is the window consensus as it is
    dof: int = one_of(4, 4, 6)  # ICP degrees of freedom: 4 = yaw + translation (gravity-aligned maps), 6 = rigid
    final_dof: int = one_of(6, 0, 6)  # the winner refitted 6-DOF on its pairs (0: keep the `dof` fit)
    # ... its tilt (roll, pitch) from its pairs' heights, shrunk towards level by a Gaussian prior of this many
    # degrees per axis (the relative tilt of two gravity-aligned EKF maps: 0.2-1.4 deg on the synthetic worlds).
    # A free 6-DOF refit tilted maps that agree within 0.4 deg by 1.5 deg on 14-25 pairs (the ninth new-user
    # sweep: it fitted the frames' local distortion); 0: no tilt, the gravity-aligned fit stands
    tilt_prior_deg: float = within(1.0, 0.0, 30.0)
    min_ratio: float = within(1.2, 1.0, None)  # the winner's support over the best alignment that puts B elsewhere
    # heights count this much in the nearest-neighbour distance (noisier)
    z_weight: float = within(0.5, 0.0, 100.0, lo_open=True)
    max_candidates: int = count(400, 1)  # window hypotheses tried, largest first (bounds dense maps)
    # The chance model (`plugin.chance.chance_test`): B refined from this many random placements over A
    # measures the support chance alignments of these two maps reach (0: off, the ratio alone decides, which
    # accepted 2 of 8 pairs of maps of different worlds). The winner is the best of N_eff ~1e5 distinct
    # alignments (`effective_trials`), so it is accepted only when the probability that the best of N_eff
    # chance alignments reaches its support is at most `false_alarm`: the rate at which two maps of different
    # places would be reported as aligned. At most this many placements: `sequential_chance` stops after 16 once
    # the answer is beyond doubt (its bootstrap interval past a stop) and draws more while in doubt, as the tail is
    # extrapolated from the samples' moments and a few dozen samples of a skewed count scatter widely: a true
    # sparse winter pair of world 64 (never used before; support 32, chance max 11) read p 0.037 (refused) from
    # 64 samples, 0.005 from 128, 3e-4 from 256, 2e-5 from 512 (0.6 s of CPU for 1,000 refinements there; the
    # model then without each placement's opportunity, `chance.chance_opportunity`)
    chance_starts: int = count(512, 0, 100_000)
    false_alarm: float = within(1e-2, 0.0, 1.0, lo_open=True)
    # the size gate of the verification's pairs (r of mutual nearest neighbours within theta_eps). Across seasons
    # one object's sizes differ by r 0.12 (median) / 0.3-0.4 (80th percentile) between two maps (worlds 5, 11);
    # inside an alignment the positions already single out the partner, so this gate follows that spread while
    # the search's theta_r, where a wrong pair makes a wrong transform, stays tight (BENCHMARKS.md, issue 16)
    max_size_difference: float = fraction(0.4)
    # the verification's candidates and displaced rivals are refined first at this many gates, then at the gate
    # (`refinement.refine_alignment`; the chance placements stay one-gate, `verify_alignments` says why): 2 = the
    # resolution at which the verification tells two alignments apart (`chance.converged_to_winner`); at the gate
    # alone the fit stopped in a fragment's local optimum (world 97's crossing flight: 18 pairs where 22 were
    # 1.7 m away). 1: one stage, as before
    coarse_factor: float = within(2.0, 1.0, None)
