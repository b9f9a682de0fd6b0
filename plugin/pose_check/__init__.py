"""Do the poses agree with what the images show? A check of given poses against image matches found without them.

A map made on wrong poses can look like a map of a real site (a drifting GPS altitude or camera centres on a
tilted plane make the ground slope; `plugin.map_quality` cannot tell that from a hillside). The images can: two
overlapping images fix their relative rotation and the direction of their relative motion, whatever the poses
say. So, for pairs of overlapping images (a bounded subsample, chosen from the capture order, not from the
poses, plus pairs the poses say overlap across flight lines), image features are matched WITHOUT the poses
(`plugin.image_matching`: ORB at a bounded size, ratio test, RANSAC fundamental matrix), and the poses' own
relative geometry is asked to explain those matches:

- **epipolar error**: the Sampson distance of every match under the essential matrix E = [t]x R that the two
  poses imply (through the camera model, lens distortion included), in pixels of the ideal pinhole image;
  per pair its median. A pair's matches fit its poses to the feature noise (a fraction of a pixel) when the
  relative rotation and the direction of motion are right; a wrong heading, a wrong attitude or a wrong
  position move them off their epipolar lines. This is what the mapping's tracker needs: its epipolar gate
  (`tracking.epipolar_margin_px`) rejects correspondences further off.
- **direction of motion**: E does not change when t flips sign, so a camera that the poses turn by 180 deg
  still has small epipolar errors; but its matches triangulate BEHIND the cameras (cheirality). A pair whose
  matches fit the epipolar geometry while most triangulate behind a camera is *reversed*: the poses say the
  camera moved the other way (a flight line with a yaw 180 deg off, a wrong heading convention).
- **systematic errors**, fitted jointly over all pairs by least squares on the epipolar errors (robust
  Cauchy loss): a drift of the cameras' heights over the capture order (a GPS altitude drifting during the
  flight), a tilt of the cameras' heights over their ground positions (centres on an inclined plane; a
  georegistration that tilted the positions), and one attitude bias shared by all cameras (a mounting or
  heading-convention offset). The images measure heights as relative changes of depth between overlapping
  views, i.e. against the flying height H, and independently of the terrain (both views see the same ground).
  A real slope under the flight is not a tilt of the poses: the images see the cameras climb with it. The
  uncertainties are cluster-robust (by pair): the matches of one pair share its pose errors, so they are not
  independent evidence. The epipolar error left after the fit is the random part of the pose errors.

The package, in the order of the data: `two_view` (the poses' epipolar geometry), `matches` (one pair's
pose-free matches), `systematic` (the joint fit of the systematic errors), `swaps` (cameras whose poses fit the
images exchanged: the sign of a baseline, which the epipolar error cannot see), `check` (pair selection and the
figures), `verdict` (`judge_poses`: refusals and warnings; limits and reasons in `params.PoseCheckParams`).
Everything here is numpy + OpenCV on arrays; reading the images is the caller's (`workflows.pose_check`).
"""

from .check import PairCheck, PoseCheck, anchor_images, check_poses, cross_partners, wide_offset
from .matches import PairMatches, match_pair
from .swaps import Exchange, exchanged_cameras
from .systematic import SystematicErrors, fit_systematic_errors, pair_sampson_px
from .two_view import essential_matrices, relative_poses, sampson_distances, triangulation_depths
from .verdict import judge_poses, poses_fit_images, poses_loose

__all__ = [
    "Exchange", "PairCheck", "PairMatches", "PoseCheck", "SystematicErrors", "anchor_images", "check_poses",
    "cross_partners", "essential_matrices", "exchanged_cameras", "fit_systematic_errors", "judge_poses",
    "match_pair", "pair_sampson_px", "poses_fit_images", "poses_loose", "relative_poses", "sampson_distances",
    "triangulation_depths", "wide_offset",
]
