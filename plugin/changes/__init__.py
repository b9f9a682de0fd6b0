"""What changed between two aligned sessions, object by object (pure numpy; `sosmatch changes` wraps it).

Two sessions A and B of one place, B brought into A's frame by the accepted transform a_from_b. Every
landmark of either map gets one class:

- `unseen`: the other session cannot tell. Its keyframes should have seen the landmark (the landmark projected
  into the image with its own footprint, radius 2 h, as margin) fewer than `min_views` times: outside the
  other's flight, at the edge of it, or seen too rarely to have been mapped there. A landmark outside the
  common area is therefore never a change.
- `kept`: the other map has a counterpart, a landmark within the counterpart gate (`tolerance_factor` x
  theta_eps, distance in x, y and z_weight x z) of a compatible size (size ratio r <= `max_size_difference`);
  the size change is reported. One object is often several landmarks (a crown, its lit half, the clump it
  stands in: nested masks of the segmenter), and the other session may map other parts of it, so landmarks
  are judged by object: a landmark belongs to the best-supported landmark whose footprint holds it
  (`landmark_groups`), and a group with one member matched is kept as a whole. A group without a counterpart
  is still kept when the other session's own segments (every mask of its keyframes, tracked or not) show a
  size-compatible segment at the landmark's projection in significantly more keyframes than at probe points
  around it (`segment_evidence`): the object was there, only not mapped.
- `gone` (a landmark of A) / `new` (of B): seen well by the other session, no counterpart, no evidence.

Confidence (gone / new): how likely the other session would have mapped the object had it still been there.
It is the pair's own re-observation rate of landmarks like this one, fitted on every object group that the
other session saw (matched or not) by logistic regression on log size, log views and height above the ground
(`reobservation_model`): large, tall objects seen in many keyframes are found again, small ground-level
patches seldom are; a winter session re-observes summer crowns less often, and its claims get lower
confidence. Below `min_confidence` a claim is reported as unseen.

The ground under the landmarks (for heights above ground and the keyframes' ground footprints) is a coarse
height field of a low quantile of the nearby landmarks' heights (`ground_height_field`): most landmarks of a
survey are ground texture, and objects only stand above it.

Modules: `observations` (what a session saw), `evidence` (what the other session shows at a place), `confidence`
(the re-observation model), `support` (is the alignment plausible), `verdict` (`detect_changes`).
"""

from .confidence import fit_logistic, predict_logistic, reobservation_features
from .evidence import binomial_tail, counterparts, holder_pairs, inside_larger, segment_evidence
from .observations import (
    FOOTPRINT_MARGIN,
    KeyframeSegments,
    SessionObservations,
    ground_height_field,
    in_view,
    observed_area,
)
from .support import CONTROL_SHIFT, AlignmentSupport, alignment_support
from .verdict import (
    BY_LANDMARK,
    BY_NESTING,
    BY_PART,
    BY_SEGMENTS,
    CLASSES,
    GONE,
    KEPT,
    LOW_CONFIDENCE,
    NEW,
    NO_EVIDENCE,
    TOO_FEW_VIEWS,
    UNSEEN,
    ChangeResult,
    LandmarkChanges,
    detect_changes,
)

__all__ = ["BY_LANDMARK", "BY_NESTING", "BY_PART", "BY_SEGMENTS", "CLASSES", "CONTROL_SHIFT", "FOOTPRINT_MARGIN",
           "GONE", "KEPT", "LOW_CONFIDENCE", "NEW", "NO_EVIDENCE", "TOO_FEW_VIEWS", "UNSEEN", "AlignmentSupport",
           "ChangeResult", "KeyframeSegments", "LandmarkChanges", "SessionObservations", "alignment_support",
           "binomial_tail", "counterparts", "detect_changes", "fit_logistic", "ground_height_field", "holder_pairs",
           "in_view", "inside_larger", "observed_area", "predict_logistic", "reobservation_features",
           "segment_evidence"]
