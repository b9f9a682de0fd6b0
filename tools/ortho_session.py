"""Nadir views with exact poses rendered from a georeferenced orthophoto (pure numpy + OpenCV; no file I/O).

The ground is taken as the plane z = 0 of the orthophoto's projected CRS, so a pinhole view of it is exactly
the plane-induced homography  x_img ~ K [r1 r2 t] (X, Y, 1)^T  (r1, r2: the first two columns of R_cam_from_world,
t = -R_cam_from_world C). Composed with the raster's affine transform it maps orthophoto pixels straight to
image pixels, and one cv2.warpPerspective renders the view. Poses are world_from_camera in the raster's CRS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..plugin.geometry import Camera, Poses


@dataclass
class Orthophoto:
    """An RGB raster (H, W, 3) uint8 with a north-up affine transform (pixel centre (col, row) ->
    E = x0 + dx (col + 0.5), N = y0 + dy (row + 0.5); dy < 0 for north-up), a validity mask and its EPSG code."""

    rgb: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    epsg: int
    valid: np.ndarray | None = None

    @property
    def world_from_pixel(self) -> np.ndarray:
        """3x3 matrix mapping homogeneous (col, row, 1) pixel indices to (E, N, 1)."""
        return np.array([[self.dx, 0.0, self.x0 + 0.5 * self.dx], [0.0, self.dy, self.y0 + 0.5 * self.dy],
                         [0.0, 0.0, 1.0]])

    def bounds(self) -> tuple[float, float, float, float]:
        """(min E, min N, max E, max N) of the valid area (the whole raster without a mask)."""
        if self.valid is not None and self.valid.any():
            rows, cols = np.nonzero(self.valid)
            c0, c1, r0, r1 = cols.min(), cols.max() + 1, rows.min(), rows.max() + 1
        else:
            h, w = self.rgb.shape[:2]
            c0, c1, r0, r1 = 0, w, 0, h
        xs = (self.x0 + self.dx * c0, self.x0 + self.dx * c1)
        ys = (self.y0 + self.dy * r0, self.y0 + self.dy * r1)
        return min(xs), min(ys), max(xs), max(ys)


def camera_for(width: int, height: int, hfov_deg: float) -> Camera:
    """A centred pinhole camera with the given horizontal field of view."""
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
    return Camera(width, height, f, f, width / 2.0, height / 2.0)


def nadir_rotation(heading_deg: float, tilt_east_deg: float = 0.0, tilt_north_deg: float = 0.0) -> np.ndarray:
    """world_from_camera rotation of a downward camera whose image top points along `heading_deg` (clockwise
    from grid north), then tilted by small angles about the world east and north axes."""
    h = math.radians(heading_deg)
    top = np.array([math.sin(h), math.cos(h), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    y_cam = -top  # image y points down the image, i.e. away from the image top
    x_cam = np.cross(y_cam, down)
    r = np.stack([x_cam, y_cam, down], axis=1)
    a, b = math.radians(tilt_north_deg), math.radians(tilt_east_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    return ry @ rx @ r


def plan_path(
    bounds: tuple[float, float, float, float],
    camera: Camera,
    altitude_m: float,
    kind: str = "lawnmower",
    frame_spacing_m: float | None = None,
    line_spacing_m: float | None = None,
    heading_deg: float | None = None,
    offset_m: float = 0.0,
    max_frames: int | None = None,
    max_plan_frames: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres (N, 3) at `altitude_m` and headings (N,) of a flight over `bounds` (min E, min N, max E,
    max N) that keeps every nadir footprint inside the bounds.

    kind: "lawnmower" (parallel lines, alternating direction), "line" (one line through the centre) or
    "cross" (two lines through the centre, the second perpendicular). Lines run along the longer side unless
    `heading_deg` (0 = north, 90 = east) says otherwise. Defaults: frames every 1/8 of the footprint length
    (a ground point is seen in ~8 consecutive frames per line), lines every half footprint width (50% sidelap).
    `offset_m` shifts the lines sideways (a second session on a parallel path). `max_frames`: only the first frames
    of the plan; `max_plan_frames`: more frames made than this is a ValueError, not an allocation.
    """
    gsd = altitude_m / camera.fx
    along_len, across_len = camera.height * gsd, camera.width * gsd  # image top points along the track
    e0, n0, e1, n1 = bounds
    if heading_deg is None:
        heading_deg = 90.0 if (e1 - e0) >= (n1 - n0) else 0.0
    frame_spacing_m = frame_spacing_m or along_len / 8.0
    line_spacing_m = line_spacing_m or across_len / 2.0
    h = math.radians(heading_deg)
    u = np.array([math.sin(h), math.cos(h)])  # along track
    v = np.array([u[1], -u[0]])  # across track (to the right)
    centre = np.array([(e0 + e1) / 2.0, (n0 + n1) / 2.0])
    corners = np.array([[e0, n0], [e1, n0], [e1, n1], [e0, n1]]) - centre
    # Extent of the bounds along u and v; a footprint's half-extent along them is subtracted (conservatively
    # for oblique headings, the footprint's bounding box along the axes).
    half_a = np.abs(corners @ u).max() - 0.5 * along_len
    half_c = np.abs(corners @ v).max() - 0.5 * across_len
    if half_a < 0 or (kind == "lawnmower" and half_c < 0):
        raise ValueError("the area is smaller than one footprint: lower the altitude or the field of view")
    planned = (2 * half_a / frame_spacing_m + 1) * (2 * max(half_c, 0.0) / line_spacing_m + 1 if kind == "lawnmower"
                                                     else 2.0)
    # the frames made: the first max_frames of the plan (a short high-resolution test session of a large raster
    # was refused for the size of the plan it cut)
    made = planned if max_frames is None else min(planned, max_frames)
    if max_plan_frames is not None and made > max_plan_frames:
        raise ValueError(f"the flight plan would hold ~{planned:.3g} frames, more than {max_plan_frames}: a larger "
                         "frame or line spacing, or fewer frames")
    cap = max_frames if max_frames is not None else math.inf
    n_steps = math.ceil((2 * half_a + 1e-9) / frame_spacing_m)  # np.arange's length
    if n_steps <= cap:
        steps = np.arange(-half_a, half_a + 1e-9, frame_spacing_m)
        steps += (half_a - steps[-1]) / 2.0  # centre the frames on the track
    else:  # only the frames made along the first line
        steps = -half_a + np.arange(int(cap)) * frame_spacing_m
        steps += (half_a - (-half_a + (n_steps - 1) * frame_spacing_m)) / 2.0
    lines_made = max(1, math.ceil(cap / len(steps))) if cap < math.inf else None
    if kind == "lawnmower":
        n_lines = max(1, int(math.floor(2 * max(half_c, 0.0) / line_spacing_m)) + 1)
        across = (np.arange(min(n_lines, lines_made or n_lines)) - (n_lines - 1) / 2.0) * line_spacing_m + offset_m
        lines = [(a, 1.0 if k % 2 == 0 else -1.0) for k, a in enumerate(across)]
        heads = [heading_deg, heading_deg + 180.0]
        segs = [(centre + a * v, u * d, heads[0 if d > 0 else 1]) for a, d in lines]
    elif kind == "line":
        segs = [(centre + offset_m * v, u, heading_deg)]
    elif kind == "cross":
        segs = [(centre + offset_m * v, u, heading_deg)]
        half_v = np.abs(corners @ v).max() - 0.5 * along_len
        perp = np.arange(-half_v, half_v + 1e-9, frame_spacing_m) if len(steps) < cap else np.zeros(0)
        if len(perp):
            perp += (half_v - perp[-1]) / 2.0
    else:
        raise ValueError(f"unknown path {kind!r} (lawnmower, line, cross)")
    centers, headings = [], []
    for origin, direction, head in segs:
        for s in steps:
            centers.append(origin + s * direction)
            headings.append(head % 360.0)
    if kind == "cross":
        for s in perp:
            centers.append(centre + offset_m * u + s * v)
            headings.append((heading_deg + 90.0) % 360.0)
    xy = np.array(centers).reshape(-1, 2)
    out = np.column_stack([xy, np.full(len(xy), float(altitude_m))])
    heads_arr = np.array(headings)
    if max_frames is not None:
        out, heads_arr = out[:max_frames], heads_arr[:max_frames]
    return out, heads_arr


def make_poses(centers: np.ndarray, headings: np.ndarray, max_tilt_deg: float = 0.0, seed: int = 0,
               prefix: str = "frame_") -> Poses:
    """Poses of the planned frames; `max_tilt_deg` adds a seeded uniform tilt about east and north."""
    rng = np.random.default_rng(seed)
    tilts = rng.uniform(-max_tilt_deg, max_tilt_deg, size=(len(centers), 2)) if max_tilt_deg > 0 else \
        np.zeros((len(centers), 2))
    rots = np.stack([nadir_rotation(h, te, tn) for h, (te, tn) in zip(headings, tilts)]) if len(centers) else \
        np.zeros((0, 3, 3))
    return Poses([f"{prefix}{i:05d}.jpg" for i in range(len(centers))], rots, centers)


def image_from_ground(camera: Camera, r_wc: np.ndarray, center: np.ndarray) -> np.ndarray:
    """3x3 homography from ground (E, N, 1) on z = 0 to COLMAP pixel coordinates: K [r1 r2 t]."""
    r_cw = r_wc.T
    t = -r_cw @ center
    return camera.K @ np.column_stack([r_cw[:, 0], r_cw[:, 1], t])


def render_view(ortho: Orthophoto, camera: Camera, r_wc: np.ndarray, center: np.ndarray) -> np.ndarray:
    """The (H, W, 3) uint8 view of the orthophoto from one camera (black outside the raster)."""
    import cv2

    # COLMAP pixel (u, v) has OpenCV index (u - 0.5, v - 0.5).
    to_index = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    h = to_index @ image_from_ground(camera, r_wc, center) @ ortho.world_from_pixel
    return cv2.warpPerspective(ortho.rgb, h, (camera.width, camera.height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))


def footprint(camera: Camera, r_wc: np.ndarray, center: np.ndarray, per_side: int = 1) -> np.ndarray:
    """Ground polygon (M, 2) on z = 0 seen by a camera: the image border back-projected (corners first)."""
    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, per_side + 1)[:-1]
    border = np.concatenate([
        np.column_stack([t * w, np.zeros_like(t)]), np.column_stack([np.full_like(t, w), t * h]),
        np.column_stack([w - t * w, np.full_like(t, h)]), np.column_stack([np.zeros_like(t), h - t * h]),
    ])
    d = np.column_stack([(border[:, 0] - camera.cx) / camera.fx, (border[:, 1] - camera.cy) / camera.fy,
                         np.ones(len(border))]) @ r_wc.T
    lam = -center[2] / d[:, 2]
    return center[:2] + lam[:, None] * d[:, :2]
