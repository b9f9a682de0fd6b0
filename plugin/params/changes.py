"""Parameters of object-level change detection between two aligned sessions."""

from __future__ import annotations

from dataclasses import dataclass

from .checks import (
    Checked,
    count,
    flag,
    fraction,
    non_negative,
    within,
)


@dataclass(frozen=True)
class ChangeParams(Checked):
    """Object-level change detection between two aligned sessions (`sosmatch.plugin.changes`; all ours)."""

    # A landmark is compared only where the other session's keyframes should have seen it (projected inside the
    # image with its own extent as margin) at least this often: theta_n + 1, the fewest observations a landmark
    # can have (`triangulation.min_observations`), so fewer views could not have mapped it at all. At most one more
    # than the theta_n the viewing session's map was made with (run.json; `map` lowers it where the flight's views
    # allow fewer: `SessionObservations.views_needed`).
    min_views: int = count(6, 1)
    # counterpart gate = this x theta_eps (`association.distance_tolerance_m`), distance in x, y and z_weight x z.
    # theta_eps is the landmark scatter the association already allows (2 m on drone maps, 10 m in the aerial
    # preset); between two EKF maps 90 % of the landmarks of one object have the other map's nearest landmark of
    # that object within 2.8-3.9 m (BENCHMARKS.md, Change detection), so 1.5 theta_eps = 3 m.
    tolerance_factor: float = within(1.5, 0.0, 100.0, lo_open=True)
    z_weight: float = within(0.5, 0.0, 100.0)  # heights are the noisy direction of a nadir survey (as in refinement)
    # r = 2 |h_a - h_b| / (h_a + h_b) of a counterpart (theta_r is 0.2 for association, where a wrong pair costs
    # a wrong transform; here a re-segmented object must still count as present: sizes within a factor 1.67)
    max_size_difference: float = within(0.5, 0.0, 2.0)
    # A landmark without a counterpart is kept when a larger landmark of the other map (up to this many times
    # its size) holds it in its footprint (ground distance <= 2 h) and this session shows that landmark too (a
    # counterpart here, or this session's segments): the other session mapped the object whole where this map
    # has a part of it; a ground patch seen where this map's object stood is no such whole. 0 = off.
    nest_max_ratio: float = non_negative(2.0)
    # One object is often several landmarks of one map (a crown, its lit half, the clump it stands in; split
    # tracks), and the other session may have mapped only some of them: a landmark inside the footprint of a
    # larger own landmark (at most this many times its size) that the other session shows directly (a
    # counterpart, or its segments) or holds in a landmark of its own is kept with it (not through a whole
    # kept only by a part link itself: chained links let ground regions hold what really went), and so is
    # a landmark whose footprint holds smaller landmarks of the other map (down to 1 / this of its size) that
    # have counterparts in its own map (the object whole here, as parts there; on the 7 development worlds this
    # removed 5 of 6 false same-season new claims for 2 of 15 found). A wider reach lets large ground regions
    # and neighbouring crowns hold objects that really went. 0 = off.
    part_max_ratio: float = non_negative(2.5)
    # A place without a counterpart landmark is still called occupied when the other session's own segments
    # (every mask in its database, tracked or not) show a size-compatible segment at the landmark's projection
    # in significantly more of its keyframes than at probe points around it: binomial tail probability below this
    # (0.05: on worlds 7 and 11 it cut the false gone / new claims from 9 to 5 for 2 of 38 changed objects found
    # fewer than at 0.01; worlds 23 and 31 showed no difference; BENCHMARKS.md, Change detection, ablation)
    segment_evidence_p: float = fraction(0.05)
    # probes for the chance rate of segments: this many points on a circle of radius (probe_radius_factor x the
    # counterpart gate + 2 h) around the landmark
    probe_count: int = count(8, 1, 360)
    probe_radius_factor: float = within(2.0, 0.0, 100.0, lo_open=True)
    # The presence rate (how often the other session's segments show an object of a given size that is there) is
    # measured on the landmarks with a counterpart, pooled with a Gaussian kernel of this width in log size
    # (0.3: sizes within a factor 1.35 count fully; a landmark's size scatters by about that between sessions)
    presence_bandwidth: float = within(0.3, 0.0, 10.0, lo_open=True)
    # A gone / new claim needs the other session's segments to say the object is absent: its confidence is
    # P(absent | segment hits) (quasi-binomial, prior odds 1, `verdict.absence_probability`); claims below this
    # are reported as unseen (the other session cannot tell). 0.8 (odds 4:1) on the 7 development worlds of
    # BENCHMARKS.md raised same-season gone precision from 0.71 to 0.91 at unchanged recall; 0 reports every
    # claim. Without the other session's database the confidence is its re-observation rate of such landmarks.
    min_confidence: float = fraction(0.8)
    # (ours) A session whose images are JPEG-compressed below this quality (`plugin.jpeg_quality`; 0: never said)
    # loses small objects and segments block artefacts as objects: its claims are named as doubtful in a warning.
    # World 7, nothing changed, B (`synth --jpeg-quality Q`) against A at 88: false gone + new claims at Q 15
    # 1 + 10, 25 1 + 0 (re-encoded from 88: 3 + 3), 40 0 + 3, 50 1 + 1, 60 1 + 3 (confidences to 0.999); none at 75
    # and 88; seed 3 at 20 3 + 1. Cameras write 90-97 (Seneca 90)
    min_jpeg_quality: float = within(75.0, 0.0, 100.0)
    # (ours) A session whose images are smeared along its track by more than this (working px, as its run.json
    # records it: `plugin.motion_blur`, `QualityParams.max_motion_smear_px`; 0: never said) has its claims named
    # as doubtful. World 7, nothing changed, B blurred 12 px along the track (7.5 working px) against A: 4 false
    # claims at high confidence; clean flights measure 0-0.5
    max_motion_smear_px: float = within(2.0, 0.0, None)
    # (ours) The surface heights as evidence (`plugin.changes.surface`): at each tested landmark (compared, no
    # counterpart) each session's surface height above the local ground from its own keyframes alone (a plane
    # sweep of a 2 m patch in `surface_views` keyframes of wide baselines, registered on the ground around the
    # place), compared across the sessions as a likelihood ratio calibrated on the pair's landmarks with a
    # counterpart, and added to the segments' evidence of absence: a removed crown is high in its own session and
    # ground in the other, a fragment of a kept one high in both, a moved shadow ground in both (no evidence).
    # Needs both sessions' images (`sosmatch changes --images-a/--images-b`, or those each map's run.json
    # records); without them the segments alone decide.
    surface_evidence: bool = flag(True)
    surface_views: int = count(6, 2, 100)
    # the surface heights may also overrule a counterpart or containment link: a landmark whose heights say
    # absent more strongly than its counterpart says present (the pair's chance counterpart rate against its
    # counterpart rate, `AlignmentSupport.counterpart_log_ratio`) is judged as one without. False: the heights
    # only add to the evidence of landmarks without a counterpart.
    surface_overrules_links: bool = flag(False)
    # (ours) A gone / new claim is a claim about an object, and the objects that come and go (trees, buildings,
    # bushes, boulders) stand above the ground: the landmark's own session must see its surface there above the
    # local ground by more than its sweep's ground noise at this one-sided significance (the noise measured on
    # the pair's reference places, mirrored from their heights at or below the ground, which objects never add
    # to; `surface.stands_above_ground`). A place that stands no higher is a change of looks (a moved shadow,
    # ground texture segmented otherwise, a flat object such as a pond) and is reported unseen with evidence
    # `flat`: nothing in the images says an object went. On 12 development pairs such places made 359 of the
    # 415 same-season claims of radius >= 2 m; the test cut the false changes from 6.6 to 1.0 / ha (29.8 to 2.2
    # across seasons) and cost a quarter of the found objects, low bushes and conifers (BENCHMARKS.md, Change
    # detection, ninth round). Not applied (with a warning) to a session whose images show no relief at all:
    # no more of its reference places stand than this p lets the noise raise (`surface.shows_relief`: an
    # orthophoto's views, bare fields). 1 = off (needs both sessions' images, as surface_evidence).
    object_height_p: float = fraction(0.01)
    # (ours) Where that test could not run (either session's images missing, `surface_evidence` off, images
    # without relief, object_height_p 1), a claim's confidence is P(absent | segments) times this: nothing tells
    # a change of looks (a moved shadow, ground texture segmented otherwise) from an object that went, and such
    # claims are right this much less often than claims that passed it. Measured (fix46) as the precision of
    # every claimed landmark without image evidence (surface_evidence off) over that with it, on the same pairs:
    # 6 pairs of worlds 3, 7 at --changed 0.10 (bench_changes --cached, 100 frames) 0.11 (23/211) / 0.31 (20/64)
    # = 0.35 (0.32 at confidences >= 0.95); 40-frame pairs of world 37 (--changed 0.1 and 0) 0.25 (9/36) / 0.31
    # (4/13), nu37 D4's 0.14 (3/22) / 0.33 (2/6); all pooled 0.13 / 0.31 = 0.42. 1 = the segments' probability
    # alone (before: on D4's pair 19 of 22 claims false at up to 0.999).
    untested_object_rate: float = fraction(0.4)
    # (ours) the landmark's own session's surface is swept at its place and, where that does not stand, at this
    # many places on a ring at half its footprint's radius (`surface.footprint_places`); the highest is tested at
    # the limit for that many places (Sidak, so bare ground passes as rarely as one place does at
    # object_height_p): a landmark's centroid may sit beside a small crown's top or a cone's tip, where the
    # sweep finds the ground (BENCHMARKS.md, Change detection, tenth round: more removed and added objects found
    # at the same precision). A landmark judged on its ring is judged where its object stands: the heights'
    # evidence is read there, and where the other session's surface stands on the same places (the crown beside
    # a shadow that moved) it is `flat`. 0 = the landmark's own place only (the other session's surface is still
    # tested there).
    object_height_ring: int = count(6, 0, 360)
    # (ours) a landmark whose place and ring do not stand is also tested by the mean of those sweeps against
    # the noise of such means, measured on the pair's swept footprints (`objectness.footprint_mean_limit`); the
    # highest and the mean each at half object_height_p (Bonferroni): a low crown or bush stands in several places
    # of its footprint by less than the 7-place limit. Found 3 more of 30 changed objects across seasons on
    # worlds 23, 61 (at the same precision, fewer false changes / ha), none more in the same season
    # (BENCHMARKS.md, Change detection, thirteenth round). False = the highest only, at object_height_p.
    object_height_mean: bool = flag(True)
    # (ours) objects a session saw but never mapped (`plugin.changes.unmapped`): the tracks of its database that
    # no landmark holds, triangulated, not explained by its own map and shown by its own segments in at least
    # min_views keyframes, are judged against the other session as its landmarks are (direct evidence only; they
    # vouch for nothing). An object whose track broke into pieces too short for a landmark can then still be
    # reported gone / new. False: landmarks only.
    unmapped_objects: bool = flag(True)
    # the mean reprojection error (px) such a track's point may have: the map's own landmark limit
    # (triangulation.max_reprojection_error_px, 10 px by default)
    unmapped_max_error_px: float = within(10.0, 0.0, 1e4, lo_open=True)
    # the centroid noise (px) behind such a point's position uncertainty (the map's triangulation.pixel_sigma_px):
    # its place must be known to within the counterpart gate at 2 sigma to ask the other session what is there
    unmapped_pixel_sigma_px: float = within(3.0, 0.0, 1e4, lo_open=True)
    # A landmark (or an object never mapped) lower than the ground by more than this many robust standard
    # deviations of its own map's heights above the ground (1.4826 x their median absolute deviation, about 2 m
    # on drone maps) is a wrong triangulation (two patches linked into one track): no object lies under the
    # ground its session looked at, and its place is wrong with its height (a ground patch triangulated 33 m
    # deep fell inside the other session's images, 3.4 m outside its footprint). It is compared with nothing
    # (unseen, evidence 'height'). The development maps' object landmarks lie at most 2.3-7 m below the ground
    # field (1 %), wrong triangulations down to 40 m.
    max_depth_sigmas: float = within(4.0, 0.0, 100.0, lo_open=True)
