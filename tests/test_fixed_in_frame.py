"""Features fixed in the image frame (a burned-in stamp) are learned from the flight and left out of the pose-free
matches of the pose refinement's tie points and of the pose check (`plugin.fixed_in_frame`)."""

from __future__ import annotations

import cv2
import numpy as np

from sosmatch.plugin.fixed_in_frame import camera_moved, learn_fixed_in_frame

W, H = 320, 240


def _flight(tmp_path, n: int = 8, step: int = 24, stamp: bool = True) -> list:
    """Images of a camera moving `step` px per frame over a random texture, a stamp burned into a corner."""
    rng = np.random.default_rng(3)
    ground = cv2.GaussianBlur(rng.integers(0, 256, (H + 40, W + n * step + 40)).astype(np.uint8), (5, 5), 1.2)
    paths = []
    for i in range(n):
        img = ground[20:20 + H, 20 + i * step:20 + i * step + W].copy()
        if stamp:
            cv2.rectangle(img, (0, H - 50), (200, H), 0, -1)
            cv2.putText(img, "2026-06-15 SKY", (6, H - 28), cv2.FONT_HERSHEY_SIMPLEX, 0.55, 255, 1, cv2.LINE_AA)
            cv2.putText(img, "H 100m F/2.8", (6, H - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.55, 255, 1, cv2.LINE_AA)
        path = tmp_path / f"frame_{i:03d}.png"
        cv2.imwrite(str(path), img)
        paths.append(path)
    return paths


def _pairs(rng, n_pairs: int, shift: float, static_at: tuple[float, float] | None) -> list:
    out = []
    for _ in range(n_pairs):
        a = rng.uniform([0, 0], [W, H], (60, 2))
        b = a + [shift, 0.0]
        if static_at is not None:
            s = rng.normal(static_at, 4.0, (10, 2))
            a, b = np.vstack([a, s]), np.vstack([b, s + rng.normal(0, 0.5, s.shape)])
        out.append((a, b))
    return out


def test_static_cluster_of_a_moving_camera_is_fixed():
    rng = np.random.default_rng(0)
    fixed = learn_fixed_in_frame(_pairs(rng, 10, 30.0, (40.0, 220.0)), W, H)
    assert fixed and fixed.pairs_taught == 10
    assert fixed.contains(np.array([[40.0, 220.0]]))[0] and not fixed.contains(np.array([[250.0, 60.0]]))[0]
    (x0, x1, y0, y1), = fixed.boxes()
    assert x0 <= 40 <= x1 and y0 <= 220 <= y1 and "burned-in text" in fixed.describe()


def test_a_hovering_camera_teaches_nothing():
    rng = np.random.default_rng(1)
    pairs = _pairs(rng, 10, 0.5, (40.0, 220.0))  # everything static: the camera did not move
    assert not any(camera_moved(a, b) for a, b in pairs)
    fixed = learn_fixed_in_frame(pairs, W, H)
    assert not fixed and fixed.pairs_taught == 0 and fixed.describe() == ""


def test_no_overlay_nothing_fixed():
    fixed = learn_fixed_in_frame(_pairs(np.random.default_rng(2), 10, 30.0, None), W, H)
    assert fixed.pairs_taught == 10 and not fixed


def test_tie_points_leave_the_stamp_out(tmp_path):
    from sosmatch.workflows.pose_refinement.tie_points import match_tie_points

    class Cam:
        width, height = W, H

    paths = _flight(tmp_path)
    centers = np.column_stack([np.arange(len(paths)) * 2.4, np.zeros(len(paths)), np.full(len(paths), 50.0)])
    tie = match_tie_points(paths, centers, Cam(), max_features=1000)
    static = sum(int((np.linalg.norm(tie.keypoints[i][m[:, 0]] - tie.keypoints[j][m[:, 1]], axis=1) < 3).sum())
                 for (i, j), m in tie.pair_matches.items())
    assert tie.pair_matches and static == 0
    assert tie.fixed_in_frame is not None and tie.fixed_in_frame.boxes(tie.pixel_scale)[0][2] >= H - 80


def test_tie_points_of_a_clean_flight_are_unchanged(tmp_path):
    from sosmatch.workflows.pose_refinement.tie_points import match_tie_points

    class Cam:
        width, height = W, H

    paths = _flight(tmp_path, stamp=False)
    centers = np.column_stack([np.arange(len(paths)) * 2.4, np.zeros(len(paths)), np.full(len(paths), 50.0)])
    tie = match_tie_points(paths, centers, Cam(), max_features=1000)
    assert tie.pair_matches and tie.fixed_in_frame is None


def test_the_stamp_does_not_take_the_feature_budget(tmp_path):
    """ORB keeps a fixed number of features per pyramid level: a stamp's glyphs took two thirds of them on nu35's
    stamp flight, and the refined block tilted. Detected again with the stamp masked out, the ground gets them."""
    from sosmatch.workflows.pose_refinement.tie_points import match_tie_points

    class Cam:
        width, height = W, H

    centers = np.column_stack([np.arange(8) * 2.4, np.zeros(8), np.full(8, 50.0)])
    (tmp_path / "clean").mkdir()
    (tmp_path / "stamp").mkdir()
    clean = match_tie_points(_flight(tmp_path / "clean", stamp=False), centers, Cam(), max_features=300)
    tie = match_tie_points(_flight(tmp_path / "stamp"), centers, Cam(), max_features=300)
    fixed = tie.fixed_in_frame
    assert fixed is not None
    inside = [int(fixed.contains(k / tie.pixel_scale - 0.5).sum()) for k in tie.keypoints]
    assert sum(inside) == 0  # no keypoint left where only the stamp's matches were
    ground = [int((~fixed.contains(k - 0.5)).sum()) for k in clean.keypoints]
    assert sum(len(k) for k in tie.keypoints) >= 0.9 * sum(ground)  # as many as the clean flight has there


def test_detection_mask_matches_the_cells():
    fixed = learn_fixed_in_frame(_pairs(np.random.default_rng(0), 10, 30.0, (40.0, 220.0)), W, H)
    mask = fixed.detection_mask()
    assert mask.shape == (H, W)
    ys, xs = np.mgrid[0:H, 0:W]
    inside = fixed.contains(np.column_stack([xs.ravel(), ys.ravel()])).reshape(H, W)
    assert np.array_equal(mask == 0, inside) and inside.any()
