"""The map's picture (`quality.png`): landmarks over a few keyframes, a top view and a side view.

A map can pass every number and still be wrong; a look shows it: in the keyframes each observation is a circle of
the landmark's metric size at the mask centroid (yellow) with a line to where the landmark reprojects through
the real camera (red); the top view shows the landmarks (coloured by height) under the camera path, the side
view their heights and the cameras' along the direction in which the ground rises most, where a tilted block,
landmarks above the cameras or layers of landmarks at different heights stand out. The verdict is the title.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...plugin.geometry import Camera, Poses, project
from ...plugin.ground_plane import robust_plane_normal
from ...plugin.map_quality import MapQuality
from ...plugin.map_verdict import Verdict

if TYPE_CHECKING:
    from ...database.images import Levels


def pick_keyframes(observed_keyframes: list[np.ndarray], num_keyframes: int, count: int = 3) -> list[int]:
    """`count` keyframes spread over the flight (first, middle, last third), each the one of its third that
    observes the most landmarks."""
    seen = np.zeros(num_keyframes, np.int64)
    for kfs in observed_keyframes:
        np.add.at(seen, np.asarray(kfs, np.int64), 1)
    picks = []
    for part in np.array_split(np.arange(num_keyframes), count):
        if len(part):
            picks.append(int(part[np.argmax(seen[part])]))
    return picks


def draw_keyframe(image: np.ndarray, camera: Camera, r_wc: np.ndarray, center: np.ndarray,
                  keypoints: np.ndarray, points: np.ndarray, sizes_m: np.ndarray) -> np.ndarray:
    """`image` (H, W, 3 uint8, RGB) with the observations `keypoints` (M, 2, COLMAP pixels) of landmarks `points`
    (M, 3) of metric sizes `sizes_m` (M,): circles at the keypoints, lines to the reprojections (through the lens)."""
    import cv2

    out = np.ascontiguousarray(image.copy())
    if not len(points):
        return out
    uv, depth = project(camera, r_wc, center, points)
    thick = max(1, round(max(out.shape[:2]) / 400))
    focal = float(np.sqrt(camera.fx * camera.fy))
    for kp, pr, d, size in zip(keypoints, uv, depth, sizes_m):
        radius = int(round(size * focal / d)) if np.isfinite(size) and d > 0 else 3
        obs = (int(round(kp[0] - 0.5)), int(round(kp[1] - 0.5)))
        cv2.circle(out, obs, max(3, radius), (255, 255, 0), thick)
        if d > 0 and np.all(np.isfinite(pr)):
            end = (int(round(pr[0] - 0.5)), int(round(pr[1] - 0.5)))
            cv2.line(out, obs, end, (255, 0, 0), thick)
            cv2.circle(out, end, 2 * thick, (255, 0, 0), -1)
    return out


def shrink_to_panel(image: np.ndarray, panel_px: tuple[float, float], oversample: float = 2.0) -> np.ndarray:
    """`image` resized (area interpolation, so the drawn circles and lines thin rather than vanish) to at most
    `oversample` image pixels per pixel of the (width, height) `panel_px` it is shown in; as it is when smaller.
    The margin covers `tight_layout` enlarging the panel and leaves matplotlib something to antialias."""
    import cv2

    h, w = image.shape[:2]
    scale = oversample * min(panel_px[0] / w, panel_px[1] / h)
    if not scale < 1.0:
        return image
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def draw_map_figure(
    out: Path,
    positions: np.ndarray,
    sizes_m: np.ndarray,
    observations: list[np.ndarray],
    keypoints: list[np.ndarray],
    poses: Poses,
    camera: Camera,
    image_paths: list[Path],
    quality: MapQuality,
    verdict: Verdict,
    title: str = "",
    white: Levels | int | None = None,
) -> None:
    """Write the figure to `out` (PNG; the caller makes it atomic).

    Args:
        positions, sizes_m: landmarks (L, 3) and their metric sizes (L,).
        observations: per landmark, (n, 2) int (keyframe index, keypoint index).
        keypoints: per keyframe, (K, >= 2) keypoints in COLMAP pixels (the real, distorted ones).
        poses, camera, image_paths: the keyframes' poses, the real camera and the image files.
        white: the flight's white level (`database.flight_levels.flight_white_level`; None: found here).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ...database.flight_levels import flight_white_level
    from ...database.images import read_image

    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    picks = pick_keyframes([o[:, 0] for o in observations], len(poses))
    white = flight_white_level(image_paths) if white is None else white
    fig = plt.figure(figsize=(4.2 * max(3, len(picks)), 8.4), dpi=100)
    grid = fig.add_gridspec(2, max(3, len(picks)), height_ratios=[1.0, 1.1])
    for col, k in enumerate(picks):
        ax = fig.add_subplot(grid[0, col])
        rows = [(i, kp) for i, o in enumerate(observations) for kf, kp in o if kf == k]
        idx = np.array([i for i, _ in rows], np.int64)
        kps = np.array([keypoints[k][kp, :2] for _, kp in rows]).reshape(-1, 2)
        try:
            image = read_image(image_paths[k], white)
        except Exception:  # a figure must never fail a map: an unreadable image stays blank
            image = np.zeros((camera.height, camera.width, 3), np.uint8)
        drawn = draw_keyframe(image, camera, poses.rotations[k], poses.centers[k], kps, positions[idx],
                              np.asarray(sizes_m, np.float64)[idx])
        # matplotlib keeps float RGBA copies of what it shows: a native 4000x3000 keyframe cost ~1.3 GB to show in a
        # panel of a few hundred pixels. Shrink it to the panel (from the figure's size and dpi) first.
        box = ax.get_position()
        panel_px = (box.width * fig.get_figwidth() * fig.dpi, box.height * fig.get_figheight() * fig.dpi)
        ax.imshow(shrink_to_panel(drawn, panel_px))
        ax.set_title(f"{poses.names[k]}: {len(idx)} landmarks", fontsize=9)
        ax.axis("off")
    # local coordinates: UTM-sized numbers would end up as an axis offset nobody reads
    origin = np.round(np.median(poses.centers, axis=0))
    centres = poses.centers - origin
    positions = positions - origin
    ax = fig.add_subplot(grid[1, : max(3, len(picks)) // 2 + 1])
    ax.plot(centres[:, 0], centres[:, 1], "-", color="0.6", lw=0.8, label="cameras")
    if len(positions):
        lo, hi = np.percentile(positions[:, 2], [2, 98])  # a few wild landmarks must not wash out the colours
        sc = ax.scatter(positions[:, 0], positions[:, 1], c=positions[:, 2], s=8, cmap="viridis", vmin=lo, vmax=hi,
                        label="landmarks")
        fig.colorbar(sc, ax=ax, label=f"height - {origin[2]:.0f} (m)", shrink=0.8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"x - {origin[0]:.0f} (m)")
    ax.set_ylabel(f"y - {origin[1]:.0f} (m)")
    ax.set_title("top view", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    ax = fig.add_subplot(grid[1, max(3, len(picks)) // 2 + 1:])
    # side view along the direction of steepest ground (the landmarks' plane), else along the flight's extent
    normal = robust_plane_normal(positions) if len(positions) >= 3 else np.array([0.0, 0.0, 1.0])
    direction = normal[:2] if np.hypot(*normal[:2]) > 1e-3 else _main_axis(centres[:, :2])
    direction = direction / np.linalg.norm(direction)
    ax.plot(centres[:, :2] @ direction, centres[:, 2], ".", color="0.5", ms=3, label="cameras")
    if len(positions):
        ax.plot(positions[:, :2] @ direction, positions[:, 2], ".", color="tab:green", ms=3, label="landmarks")
    ax.set_xlabel("distance along the ground's steepest direction (m)")
    ax.set_ylabel(f"height - {origin[2]:.0f} (m)")
    ax.set_title("side view", fontsize=9)
    ax.legend(loc="best", fontsize=8)
    status = "REFUSED: " + "; ".join(verdict.refusals) if verdict.refusals else "ok"
    if verdict.warnings:
        status += "  (warnings: " + "; ".join(verdict.warnings) + ")"
    fig.suptitle(f"{title}\n{quality.landmarks} landmarks, {quality.line()}\n{status}", fontsize=10,
                 color="tab:red" if verdict.refusals else "black")
    fig.tight_layout()
    fig.savefig(out, format="png")
    plt.close(fig)


def _main_axis(xy: np.ndarray) -> np.ndarray:
    if len(xy) < 2:
        return np.array([1.0, 0.0])
    d = xy - xy.mean(axis=0)
    _, vecs = np.linalg.eigh(d.T @ d)
    return vecs[:, -1]
