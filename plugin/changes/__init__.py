"""What changed between two aligned sessions, object by object (pure numpy; `sosmatch changes` wraps it).

Two sessions A and B of one place, B brought into A's frame by the accepted transform a_from_b. Every
landmark of either map gets one class:

- `unseen`: the other session cannot tell. Its keyframes should have seen the landmark (the landmark projected
  into the image with its own footprint, radius 2 h, as margin, within the lens model's reach, and near enough
  that its mask reaches the smallest its segmenter keeps: `in_view`) fewer than `min_views` times: outside the
  other's flight, at the edge of it, too far away in an oblique view, or seen too rarely to have been mapped
  there. A landmark outside the
  common area is therefore never a change.
- `kept`: the other map has a counterpart, a landmark within the counterpart gate (`tolerance_factor` x
  theta_eps, distance in x, y and z_weight x z) of a compatible size (size ratio r <= `max_size_difference`);
  the size change is reported. One object is often several landmarks (a crown, its lit half, the clump it
  stands in: nested masks of the segmenter), and the other session may map other parts of it, so a landmark
  without a counterpart is still kept when a larger landmark of the other map (up to `nest_max_ratio` x its
  size) holds it in its footprint (evidence `nested`), when it lies in the footprint of a larger landmark of
  its own map that the other session shows or that is nested there, or when smaller landmarks of the other map
  inside its own footprint have counterparts in its map (both up to `part_max_ratio`; evidence `part`: one
  object, whole in one map and parts in the other), or when the other session's own segments (every mask of its
  keyframes, tracked or not) show it (`segment_evidence`, evidence `segments`): a size-compatible segment at the
  landmark's projection in significantly more keyframes than at probe points around it, and hits more like those
  of an object that is there than like its absence (absence probability below 1/2): the object was there, only
  not mapped. A link vouches only with direct evidence behind it: the holder in the other map must be shown by
  this landmark's own session too (a counterpart landmark in its map, or its segments), and the whole in the
  own map must be shown by the other session or nested in such a holder. A ground patch that one session sees
  where the other's object stood, or a whole kept only through a part link of its own, is no evidence that the
  object is still there (such chains kept most of the removed and added objects that were mapped).
- `gone` (a landmark of A) / `new` (of B): seen well by the other session, no counterpart, no evidence, and an
  object that went: with both sessions' images, its own session's surface stands above the local ground at the
  landmark's place or on a ring inside its footprint (`surface.stands_above_ground`, `surface.footprint_places`,
  `changes.object_height_p`, `changes.object_height_ring`: the highest of those places, at the significance for
  all of them), and the other session's surface stands at none of those places. A place where nothing stands
  (a moved shadow, ground texture, snow over a field, a flat object), or where what stands stands in both
  sessions (the crown beside a shadow that moved), is unseen with evidence `flat`: a change of looks, not of an
  object.

Confidence (gone / new): the probability that the object is absent from the other session, from that session's
own observations at the place rather than from its map (`verdict.absence_probability`). In each of its keyframes
that should have seen the landmark, a hit is a size-compatible segment at the projection (`segment_hits`); if
the object is absent, hits come at the local chance rate (probes around it); if present, at the rate at which
the other session's segments show objects of this size that both maps have (`presence_rate`, measured on this
pair's landmarks with a counterpart, so it calibrates itself per pair, season and segmenter), scaled by how often
the landmark's own session shows it against landmarks of its size (`landmark_presence_rate`: a fragment its own
session segments in half of its views would show as rarely in the other's). The
log-likelihood ratio of the two binomials is divided by the dispersion of a count of n views, 1 + (n - 1) rho
(`dispersion`; rho the views' intra-class correlation measured on the references' hits, `view_correlation`:
neighbouring keyframes see an object alike, so n views are fewer independent looks) and turned
into a probability at prior odds 1. A claim below `min_confidence` (0.8 by default) is reported as unseen: the
other session's images do not say that the object went. Without the other session's database (no segments)
the only sign of absence is that its map lacks the landmark: the confidence is then the probability of absence
at prior odds 1 given how often that map holds landmarks like this one, 1 / (2 - p), with p the pair's
re-observation rate (`confidence`: logistic in log size, log views, height above ground and support, fitted on
the compared landmarks, each landmark scored by a fit it took no part in: `held_out_logistic`); it reaches 0.8
only where p >= 0.75. A claim that could
not be tested for an object standing there (no images of either session, or images without relief) has its
confidence multiplied by `untested_object_rate`, the measured ratio of such claims' precision to tested ones'
(most are changes of looks), so the default `min_confidence` reports none of them.

Surface heights (`surface`, `changes.surface_evidence`, with both sessions' images): removed and added trees,
buildings and boulders change the surface, moved shadows and ground texture do not. At each tested landmark each
session's surface height above the local ground is estimated from its own keyframes alone (a plane sweep of a
small patch in the keyframes of widest baselines, registered on the ground around the place), and the two
heights become a log-likelihood ratio of absence calibrated on the pair's landmarks with a counterpart
(`surface.height_log_ratio`), added to the segments' before the confidence: a removed crown is high in its own
session and ground in the other, a fragment of a kept one high in both; a place without height of its own (ground
texture, a shadow, a flat object) gets no evidence either way.

The ground under the landmarks (for heights above ground and the keyframes' ground footprints) is a coarse
height field of a low quantile of the nearby landmarks' heights about their local slope (`ground_height_field`,
a median plane: on a hillside the level quantile would lie downhill): most landmarks of a survey are ground
texture, and objects only stand above it. A landmark lower than it by more than
`max_depth_sigmas` robust standard deviations of its map's heights is a wrong triangulation and is compared with
nothing (`below_the_ground`; unseen, evidence `height`).

Modules: `observations` (what a session saw), `evidence` (what the other session shows at a place, and how
often it shows present objects), `surface` (each session's surface height at a place from its own images),
`confidence` (the re-observation model, the fallback without segments), `support` (is the alignment plausible),
`direct` (what the other session shows of each landmark before any containment link), `verdict` (`detect_changes`,
`absence_probability`).
"""

from .confidence import fit_logistic, held_out_logistic, predict_logistic, reobservation_features
from .evidence import (
    absence_log_ratio,
    binomial_tail,
    counterparts,
    dispersion,
    holder_pairs,
    inside_larger,
    landmark_presence_rate,
    presence_rate,
    segment_evidence,
    segment_hits,
    view_correlation,
)
from .observations import (
    FOOTPRINT_MARGIN,
    KeyframeSegments,
    SessionObservations,
    below_the_ground,
    ground_height_field,
    in_view,
    observed_area,
    resolution_depth,
    smallest_mask_area,
)
from .support import (
    CONTROL_SHIFT,
    AlignmentSupport,
    alignment_support,
    counterpart_gate,
    implausible_alignment,
    implausible_pair,
    pair_support,
)
from .surface import ground_sweep_noise, height_log_ratio, heights_above_ground, stands_above_ground
from .unmapped import UnmappedObjects, no_unmapped_objects, tracks_from_matches, unmapped_objects
from .verdict import (
    BELOW_GROUND,
    BY_LANDMARK,
    BY_NESTING,
    BY_PART,
    BY_SEGMENTS,
    CLASSES,
    COUNT_KEYS,
    EVIDENCE,
    FLAT,
    GONE,
    KEPT,
    LOW_CONFIDENCE,
    NEW,
    NO_EVIDENCE,
    TOO_FEW_VIEWS,
    UNSEEN,
    ChangeResult,
    LandmarkChanges,
    counts_summary,
    detect_changes,
)

__all__ = ["BELOW_GROUND", "BY_LANDMARK", "BY_NESTING", "BY_PART", "BY_SEGMENTS", "CLASSES", "CONTROL_SHIFT",
           "COUNT_KEYS",
           "EVIDENCE", "FLAT", "FOOTPRINT_MARGIN", "GONE", "KEPT", "LOW_CONFIDENCE", "NEW", "NO_EVIDENCE",
           "TOO_FEW_VIEWS", "UNSEEN", "AlignmentSupport", "ChangeResult", "KeyframeSegments", "LandmarkChanges",
           "SessionObservations", "UnmappedObjects", "absence_log_ratio", "alignment_support", "below_the_ground",
           "binomial_tail", "counterpart_gate", "counterparts", "counts_summary", "detect_changes", "dispersion",
           "fit_logistic",
           "ground_height_field", "ground_sweep_noise", "height_log_ratio", "held_out_logistic", "heights_above_ground",
           "holder_pairs",
           "implausible_alignment", "implausible_pair", "in_view", "inside_larger", "landmark_presence_rate",
           "no_unmapped_objects", "observed_area", "pair_support", "predict_logistic", "presence_rate",
           "reobservation_features", "resolution_depth", "segment_evidence",
           "segment_hits", "smallest_mask_area", "stands_above_ground", "tracks_from_matches", "unmapped_objects",
           "view_correlation"]
