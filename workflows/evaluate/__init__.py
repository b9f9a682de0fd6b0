"""Evaluate cross-session matching like the paper (`sosmatch evaluate`): Table I and the precision-recall figure.

`run(params, session_a, session_b, out_dir, ...)`:
  1. ground truth: keyframes every `keyframes.interval_m` on the ground-truth poses (poses.csv) of each
     session, their ground footprints on the terrain (SESSION/terrain.npz, an elevation raster, or a flat
     ground) and the IoU of every cross-session keyframe pair (plugin/evaluation);
  2. SOS-Match: the windowed search between the two landmark maps (in-process, or the hypotheses of a given
     match.json), its hypotheses turned into keyframe-pair claims scored by |S| (plugin/evaluation/claims.py);
  3. baselines (tools/baselines): ORB+RANSAC and SIFT+RANSAC on the same keyframe images, scored by inliers;
  4. the PR curve of every method, recall at precision >= 0.99, average F1, mean search time, map size;
  5. writes evaluation.json, evaluation.md (the table), pr.png and overlay.png into `out_dir`, each atomically.

Search time of SOS-Match is the median of `repeats` runs of the match's answer at the configured theta_S (the
operating point): the windowed search and its verification on the full maps, as `sosmatch match` computes it
(`plugin.match_answer.match_maps`); the overlay draws that answer. The curve sweeps the score threshold over
those runs' hypotheses (|S| > theta_S), or, with `sweep_floor` below theta_S, over one extra run at that lower
floor (the solver only runs where a set larger than theta_S can exist, so lower floors collect more, smaller
hypotheses, at a much higher cost).
Map size is the mean of the two sessions' maps: landmarks.sosmap bytes for SOS-Match, keypoints + descriptors
bytes for the baselines.
"""

from .ground_truth import GroundTruthSession, load_ground_truth
from .report import LABELS, format_table, limiting_stage, plot_overlay, plot_pr
from .sosmatch_method import error_to_identity
from .workflow import METHODS, demo_step, run

__all__ = ["LABELS", "METHODS", "GroundTruthSession", "demo_step", "error_to_identity", "format_table",
           "limiting_stage", "load_ground_truth", "plot_overlay", "plot_pr", "run"]
