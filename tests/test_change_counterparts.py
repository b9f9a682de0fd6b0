"""A counterpart vouches only for what it stands on (`changes.flat_counterparts`, `objectness.flat_counterparts`):
a removed object's landmark paired with a ground patch that the other session mapped where it stood."""

from dataclasses import replace

import numpy as np

from sosmatch.plugin.changes import GONE, KEPT, detect_changes
from sosmatch.plugin.geometry import Camera
from sosmatch.plugin.params import ChangeParams
from sosmatch.tools.toy_sessions import change_session, lawnmower, render_nadir_images, yaw_transform

CAM = Camera(320, 240, 200.0, 200.0, 160.0, 120.0)  # 0.23 m a pixel from 45 m


def test_a_removed_object_paired_with_a_ground_patch_of_the_other_map_is_gone():
    """25 objects (3-8 m discs) on textured ground, 4 removed in B; where object 2 stood, B's segmenter outlined
    a patch of the ground (drawn flat, of the object's size) and mapped it: a landmark of compatible size within
    the counterpart gate, so A's landmark of the removed object was kept (worlds 3, 7: "counterpart on the
    ground", 2 + 4 of the same-season misses). A's images show the object standing there, B's show the ground
    there, and B's landmark is flat in B's own images: the pair is no evidence that the object is in both."""
    rng = np.random.default_rng(5)
    gx, gy = np.meshgrid(np.arange(5) * 17.0 + 11.0, np.arange(5) * 17.0 + 11.0)
    objects = np.column_stack([gx.ravel() + rng.uniform(-2, 2, 25), gy.ravel() + rng.uniform(-2, 2, 25),
                               rng.uniform(3.0, 8.0, 25)])
    objects[2, 2] = 4.0  # low enough that a ground landmark under it lies within the gate (z weighs half)
    shadows = np.array([[40.0, 46.0, 0.0], [44.0, 41.0, 0.0]])  # 25 in A only, 26 in B only
    patch = np.array([[objects[2, 0], objects[2, 1], 0.0]])  # 27: B's ground patch where object 2 stood
    positions = np.vstack([objects, shadows, patch])
    sizes = np.concatenate([rng.uniform(1.2, 2.2, 25), np.full(2, 1.5), [0.0]])
    sizes[27] = sizes[2]
    removed = np.array([2, 8, 16, 22])
    present_a, present_b = np.ones(28, bool), np.ones(28, bool)
    present_b[removed], present_a[26], present_b[25], present_a[27] = False, False, False, False
    a, ids_a = change_session(positions, sizes, present_a, lawnmower(5, 85, 5, 85, 45, 10, 6), 1, camera=CAM)
    b, ids_b = change_session(positions, sizes, present_b, lawnmower(7, 87, 3, 83, 45, 10, 6), 2, camera=CAM)
    a = replace(a, images=render_nadir_images(a.poses, CAM, positions, sizes, present_a, 7, noise_seed=1))
    b = replace(b, images=render_nadir_images(b.poses, CAM, positions, sizes, present_b, 7, gain=0.8, offset=25.0,
                                              noise_seed=2))
    same_frame = yaw_transform(0.0, (0.0, 0.0, 0.0))
    i2, j27 = int(np.flatnonzero(ids_a == 2)[0]), int(np.flatnonzero(ids_b == 27)[0])
    before = detect_changes(a, b, same_frame, ChangeParams(flat_counterparts=False), 2.0)
    assert before.a.label[i2] == KEPT and before.a.counterpart[i2] == j27  # the ground patch kept it
    after = detect_changes(a, b, same_frame, ChangeParams(flat_counterparts=True), 2.0)
    assert after.a.label[i2] == GONE and after.a.confidence[i2] >= 0.8
    assert all(after.a.label[int(np.flatnonzero(ids_a == o)[0])] == GONE for o in removed)
    # nothing else moves: the objects present in both keep their counterparts (both stand), and a ground patch
    # paired with ground (B's patch itself: flat where it lies) is judged as before
    others = np.arange(len(ids_a)) != i2
    assert np.array_equal(after.a.label[others], before.a.label[others])
    assert np.array_equal(after.a.counterpart[others], before.a.counterpart[others])
    assert np.array_equal(after.b.label, before.b.label)
