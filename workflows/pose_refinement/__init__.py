"""Pose refinement: bundle adjustments of poses and tie points that stay in the GPS frame, for poses far from
EKF quality (consumer GPS, autopilot attitude), before mapping.

- `tie_points`: ORB tie points between overlapping images with the prior poses (`tie_point_reconstruction`), and
  the whole job (`refine_poses_from_images`).
- `with_colmap`: COLMAP's pose-prior bundle adjustment (position priors; the default, seconds).
- `with_priors`: a scipy adjustment with position and attitude priors (minutes; the derivation is there).
- `judge`: the statistics and the plausibility judgement against the priors (`RefinementRejected`).
"""

from .judge import RefinementRejected, RefinementStats, judge_refinement
from .tie_points import refine_poses_from_images, tie_point_reconstruction
from .with_colmap import poses_of_reconstruction, refine_poses_with_colmap
from .with_priors import refine_poses_with_priors

__all__ = ["RefinementRejected", "RefinementStats", "judge_refinement", "poses_of_reconstruction",
           "refine_poses_from_images", "refine_poses_with_colmap", "refine_poses_with_priors",
           "tie_point_reconstruction"]
