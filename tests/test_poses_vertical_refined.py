"""`poses-from-exif`'s check of the refined block's vertical (`_rests_on_nadir`, `_tilted_by_drift`)."""

import numpy as np
from scipy.spatial.transform import Rotation

from sosmatch.plugin.geometry import Poses
from sosmatch.workflows.poses_from_exif import _rests_on_nadir

NADIR = np.diag([1.0, -1.0, -1.0])  # world_from_camera of a level camera looking down


def _two_lines(drift_m: float, tilt_deg: float, seed: int = 0):
    """Two lines 40 m apart flown one after the other (times in capture order), nadir priors at the GPS fixes
    whose altitude drifts by `drift_m` over the flight, and a "refined" block whose centres follow those heights
    and whose cameras are tilted by `tilt_deg` about the lines (what the refinement does with a drift, rev56 D1)."""
    rng = np.random.default_rng(seed)
    y = np.arange(20) * 6.0
    centers = np.r_[np.c_[np.zeros(20), y, np.full(20, 80.0)], np.c_[np.full(20, 40.0), y[::-1], np.full(20, 80.0)]]
    centers += [500000.0, 5200000.0, 300.0]
    times = np.arange(40) * 2.0
    gps = centers + np.c_[rng.normal(0, 0.3, (40, 2)), rng.normal(0, 0.2, 40)]
    gps[:, 2] += drift_m * times / times.max()
    names = [f"frame_{k:05d}.jpg" for k in range(40)]
    prior = Poses(names, np.tile(NADIR, (40, 1, 1)), gps)
    turn = Rotation.from_euler("y", tilt_deg, degrees=True).as_matrix()
    noise = Rotation.from_rotvec(np.radians(rng.normal(0, 0.5, (40, 3)))).as_matrix()
    refined = Poses(names, noise @ turn @ NADIR, gps + rng.normal(0, 0.05, (40, 3)))
    return prior, refined, list(times)


def test_a_block_tilted_to_follow_a_drifting_gps_altitude_is_said():
    """rev56 D1: a two-line flight whose GPS altitude drifts 12 m, refined by poses-from-exif, came out with its
    cameras 7-12 deg off the vertical and no word; the check compared the refined block with itself."""
    prior, refined, times = _two_lines(12.0, 9.0)
    said = _rests_on_nadir(prior, refined, np.ones(40, bool), times)
    assert any("off the vertical" in w and "drift" in w and "sosmatch poses" in w for w in said), said
    # the capture order where a time is missing tells it as well
    assert any("off the vertical" in w for w in _rests_on_nadir(prior, refined, np.ones(40, bool), None))


def test_a_level_refined_block_is_not_told_of_a_tilt():
    prior, refined, times = _two_lines(0.0, 0.0)
    assert not any("off the vertical" in w for w in _rests_on_nadir(prior, refined, np.ones(40, bool), times))
