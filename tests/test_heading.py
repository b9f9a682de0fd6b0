"""plugin.heading: camera headings from the image motion against the GPS directions of the pairs."""

from __future__ import annotations

import numpy as np

from sosmatch.plugin.heading import heading_corrections


def test_a_pair_too_close_for_the_gps_to_give_its_direction_does_not_turn_a_camera():
    """nu58 D2: Seneca's IMG_0521 and IMG_0527 (two lines 5.7 m apart, 342 matches) turned each other -156 / -173
    deg while their pairs at 21-34 m said a few degrees; the matches outweighed them and both ended ~140 deg off.
    With a 3 m GPS the 5 m pair's direction is unknown to ~40 deg: it is not used, and the long pairs decide."""
    nadir = np.diag([1.0, -1.0, -1.0])  # world_from_camera: image right east, image down south, looking down
    rotations = np.repeat(nadir[None], 4, axis=0)
    centers = np.array([[0.0, 0.0, 100.0], [30.0, 0.0, 100.0], [0.0, 5.0, 100.0], [-30.0, 0.0, 100.0]])
    east, west = np.array([1.0, 0.0]), np.array([-1.0, 0.0])
    north_flipped = np.array([0.0, 1.0])  # camera 2 seen towards the image bottom: south, while the GPS says north
    pairs = [(0, 1, east, west, 20.0), (0, 3, west, east, 25.0), (0, 2, north_flipped, -north_flipped, 300.0)]
    exact = np.degrees(heading_corrections(rotations, centers, pairs))
    assert abs(abs(exact[0]) - 180.0) < 1e-6  # taken as exact fixes, the many matches of the short pair decide
    turns = np.degrees(heading_corrections(rotations, centers, pairs, position_sigma_m=3.0))
    assert abs(turns[0]) < 1e-6 and abs(turns[1]) < 1e-6 and abs(turns[3]) < 1e-6
    assert np.isnan(turns[2])  # its only pair is too short: left to the others' mean (`headings_from_image_motion`)
