"""Toy mapped sessions without images: COLMAP models, landmark maps and landmarks.csv built directly from a
random world of objects seen by a downward camera, plus the ground truth needed to check merge and batch.

This is a fixture generator for tests and quick experiments of the multi-session stages (merge, batch,
executors). It skips segmentation and triangulation entirely: observations are exact projections plus pixel
noise, landmark positions are the true object positions (in the session's frame) plus noise. For the real
pipeline use `sosmatch synth` + `sosmatch map`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..database.atomic import atomic_path, write_text_atomic
from ..database.landmark_map import LandmarkMap, landmark_map_fingerprint, read_landmark_map, write_landmark_map
from ..database.poses import write_poses_csv
from ..database.session_io import write_landmarks_csv
from ..plugin.geometry import Camera, Poses, project
from ..plugin.multisession import Sim3

TOY_CAMERA = Camera(640, 480, 400.0, 400.0, 320.0, 240.0)


@dataclass
class ToyWorld:
    """Objects (N,3) positions and (N,) sizes in the world frame."""

    positions: np.ndarray
    sizes: np.ndarray


@dataclass
class ToySession:
    """A written toy session: its directory, session_from_world transform and the world object of each landmark."""

    path: Path
    session_from_world: Sim3
    object_ids: np.ndarray  # (L,) world object index of landmark i


def make_world(num_objects: int = 300, extent_m: float = 240.0, seed: int = 0) -> ToyWorld:
    """Objects scattered over a square area, a few metres of relief, sizes 0.5-6 m."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, extent_m, (num_objects, 2))
    z = rng.uniform(0.0, 6.0, (num_objects, 1))
    return ToyWorld(np.hstack([xy, z]), rng.uniform(0.5, 6.0, num_objects))


def make_spaced_world(num_objects: int, extent_m: float = 240.0, sizes: tuple[float, float] = (0.5, 3.0),
                      seed: int = 0) -> ToyWorld:
    """Objects that do not overlap, as real crowns, roofs and boulders: footprints (radius 2 h) apart; sizes
    uniform in `sizes`, heights 0-6 m. (make_world lets objects overlap, which no change detection could
    tell apart.)"""
    rng = np.random.default_rng(seed)
    pos: list[np.ndarray] = []
    size: list[float] = []
    while len(pos) < num_objects:
        xy, h = rng.uniform(0.0, extent_m, 2), float(rng.uniform(*sizes))
        if all(np.hypot(*(xy - q[:2])) > 2.0 * (h + g) for q, g in zip(pos, size)):
            pos.append(np.r_[xy, rng.uniform(0.0, 6.0)])
            size.append(h)
    return ToyWorld(np.array(pos).reshape(-1, 3), np.array(size))


def lawnmower(x0: float, x1: float, y0: float, y1: float, altitude: float, spacing: float, step: float) -> np.ndarray:
    """Camera centres along back-and-forth lines (east-west legs, `spacing` apart, a frame every `step` m)."""
    centers = []
    for k, y in enumerate(np.arange(y0, y1 + 1e-9, spacing)):
        xs = np.arange(x0, x1 + 1e-9, step)
        for x in xs if k % 2 == 0 else xs[::-1]:
            centers.append((x, y, altitude))
    return np.asarray(centers, dtype=np.float64)


def write_toy_session(
    path: str | Path,
    world: ToyWorld,
    centers_world: np.ndarray,
    session_from_world: Sim3,
    seed: int = 0,
    pixel_noise_px: float = 1.0,
    landmark_noise_m: float = 0.05,
    min_observations: int = 3,
    present: np.ndarray | None = None,
) -> ToySession:
    """Write a mapped-session directory (sparse/, landmarks.sosmap, landmarks.csv, poses.csv, truth.json).

    Cameras look straight down (image x = world x, image y = -world y). Every object seen in at least
    `min_observations` frames becomes a COLMAP 3D point and a landmark. The whole session lives in the frame
    `session_from_world` (what a vehicle with its own odometry frame would see). `present` (bool per world
    object) leaves the other objects out of this session (removed ones; the truth of change detection).
    """
    import pycolmap

    path = Path(path)
    rng = np.random.default_rng(seed)
    cam = TOY_CAMERA
    r_wc_world = np.diag([1.0, -1.0, -1.0])  # camera looking down
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                        params=[cam.fx, cam.fy, cam.cx, cam.cy], camera_id=1)
    )
    obs: dict[int, list[tuple[int, int]]] = {}
    names = []
    # Poses in the session frame: rotate the camera with the frame (scale moves only the centre).
    r_wc = session_from_world.rotation @ r_wc_world
    centers = session_from_world.apply(centers_world)
    for i, c in enumerate(centers_world):
        uv, depth = project(cam, r_wc_world, c, world.positions)
        inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        if present is not None:
            inside &= np.asarray(present, dtype=bool)
        ids = np.flatnonzero(inside)
        kp = uv[ids] + rng.normal(0.0, pixel_noise_px, (len(ids), 2))
        name = f"frame_{i:05d}.jpg"
        names.append(name)
        image = pycolmap.Image(name=name, keypoints=kp, camera_id=1, image_id=i + 1)
        r_cw = r_wc.T
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw), -r_cw @ centers[i]))
        for k, oid in enumerate(ids):
            obs.setdefault(int(oid), []).append((i + 1, k))
    object_ids, point_ids = [], []
    for oid in sorted(obs, key=lambda o: (obs[o][0][0], o)):  # landmark order: first sighting, like tracks
        if len(obs[oid]) < min_observations:
            continue
        track = pycolmap.Track()
        for iid, k in obs[oid]:
            track.add_element(iid, k)
        xyz = session_from_world.apply(world.positions[oid]) + rng.normal(0.0, landmark_noise_m, 3)
        point_ids.append(rec.add_point3D(xyz, track))
        object_ids.append(oid)
    rec.update_point_3d_errors()
    object_ids_arr = np.asarray(object_ids, dtype=np.int64)
    positions = np.array([rec.points3D[p].xyz for p in point_ids]).reshape(-1, 3)
    sizes = world.sizes[object_ids_arr] * session_from_world.scale * rng.uniform(0.95, 1.05, len(object_ids_arr))
    origin = np.round(positions.mean(0)) if len(positions) else np.zeros(3)
    lmap = LandmarkMap(positions, sizes, origin)
    path.mkdir(parents=True, exist_ok=True)
    with atomic_path(path / "sparse") as tmp:
        tmp.mkdir()
        rec.write_binary(str(tmp))
    write_landmark_map(path / "landmarks.sosmap", lmap)
    image_names = [sorted({names[e.image_id - 1] for e in rec.points3D[p].track.elements}) for p in point_ids]
    write_landmarks_csv(
        path / "landmarks.csv", lmap, np.asarray(point_ids), np.array([len(n) for n in image_names]), image_names
    )
    rot = np.broadcast_to(r_wc, (len(centers), 3, 3))
    write_poses_csv(path / "poses.csv", Poses(names, rot, centers))
    truth = {"session_from_world": session_from_world.to_dict(), "object_ids": object_ids_arr.tolist()}
    write_text_atomic(path / "truth.json", json.dumps(truth) + "\n")
    return ToySession(path, session_from_world, object_ids_arr)


def yaw_transform(yaw_deg: float, translation: tuple[float, float, float], scale: float = 1.0) -> Sim3:
    """A frame rotated about z (gravity stays vertical, as between two vehicles' odometry frames)."""
    a = np.radians(yaw_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return Sim3(rot, np.asarray(translation, dtype=np.float64), scale)


def true_associations(a: ToySession, b: ToySession) -> np.ndarray:
    """(K,2) landmark index pairs (in A, in B) of landmarks that are the same world object."""
    index_b = {int(o): j for j, o in enumerate(b.object_ids)}
    return np.array(
        [(i, index_b[int(o)]) for i, o in enumerate(a.object_ids) if int(o) in index_b], dtype=np.int64
    ).reshape(-1, 2)


def toy_match_json(
    a: ToySession,
    b: ToySession,
    path: str | Path,
    transform: Sim3 | None = None,
    num_outliers: int = 0,
    seed: int = 0,
) -> Path:
    """Write a match.json for (A, B) as the association stage would: true associations (plus optional wrong
    ones) and the transform a_from_b (the truth unless given)."""
    rng = np.random.default_rng(seed)
    truth = a.session_from_world.compose(b.session_from_world.inverse())
    assoc = true_associations(a, b)
    if num_outliers:
        wrong = np.stack([rng.integers(0, len(a.object_ids), num_outliers),
                          rng.integers(0, len(b.object_ids), num_outliers)], 1)
        assoc = np.vstack([assoc, wrong])
    transform = transform or truth
    accepted = len(assoc) > 6
    hyp = {"associations": assoc.tolist(), "transform": transform.to_dict(), "accepted": bool(accepted)}

    def ref(s: ToySession) -> dict:
        lmap = read_landmark_map(s.path / "landmarks.sosmap")
        return {"path": str(s.path), "landmarks": len(lmap), "fingerprint": landmark_map_fingerprint(lmap)}

    data = {
        "format": "sosmatch match v1",
        "map_a": ref(a),
        "map_b": ref(b),
        "transform_kind": "similarity" if not np.isclose(transform.scale, 1.0) else "rigid",
        "hypotheses": [hyp],
        "best": 0,
    }
    path = Path(path)
    write_text_atomic(path, json.dumps(data) + "\n")
    return path


def load_toy_session(path: str | Path) -> ToySession:
    """Re-open a toy session written by `write_toy_session` (its truth.json)."""
    path = Path(path)
    truth = json.loads((path / "truth.json").read_text(encoding="utf-8"))
    return ToySession(path, Sim3.from_dict(truth["session_from_world"]),
                      np.asarray(truth["object_ids"], dtype=np.int64))


def oracle_pair_task(session_a: str, session_b: str, pair_dir: str, params: object = None) -> dict:
    """A ground-truth matcher for toy sessions with the signature of `sosmatch.workflows.batch.pair_task`:
    writes pair_dir/match.json with the true associations and transform (accepted when there are more than
    6), so the graph and merge stages can be checked in isolation from the association search."""
    from ..workflows.batch import summarise_match

    a, b = load_toy_session(session_a), load_toy_session(session_b)
    path = toy_match_json(a, b, Path(pair_dir) / "match.json")
    return summarise_match(path)


def render_disc_flight(root: str | Path, camera: Camera, frames: int = 25, altitude: float = 60.0,
                       seed: int = 0) -> np.ndarray:
    """A tiny flight with real images: one nadir line (2 m steps along x) over a flat textured field with 40
    coloured discs, every pixel's ray through `camera`'s lens model meeting the ground plane z = 0 and sampling a
    0.1 m orthophoto. Writes ROOT/images/, poses.csv and cameras.txt (the `sosmatch map` inputs); returns the
    discs (x, y, radius). The same seed gives the same world whatever the camera."""
    import cv2

    from ..database.cameras import write_cameras_txt
    from ..plugin.geometry import pixel_rays

    root = Path(root)
    rng = np.random.default_rng(seed)
    gsd, x0, x1, y0, y1 = 0.1, -45.0, frames * 2.0 + 45.0, -40.0, 40.0
    w, h = int((x1 - x0) / gsd), int((y1 - y0) / gsd)
    noise = cv2.GaussianBlur(rng.normal(0, 25, (h, w, 3)), (0, 0), 2)
    ortho = np.clip(rng.integers(70, 110, 3) + noise, 0, 255).astype(np.uint8)
    objs = np.stack([rng.uniform(x0 + 12, x1 - 12, 40), rng.uniform(y0 + 10, y1 - 10, 40), rng.uniform(1.5, 4, 40)], 1)
    for x, y, r in objs:
        color = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(ortho, (int((x - x0) / gsd), int((y1 - y) / gsd)), int(r / gsd), color, -1, cv2.LINE_AA)
    ortho = cv2.GaussianBlur(ortho, (0, 0), 1.0)  # an image pixel spans ~2 ortho pixels: low-pass before sampling
    centers = np.stack([np.arange(frames) * 2.0, np.zeros(frames), np.full(frames, altitude)], 1)
    names = [f"frame_{i:05d}.jpg" for i in range(frames)]
    r_wc = np.diag([1.0, -1.0, -1.0])
    jj, ii = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = pixel_rays(camera, np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], 1), r_wc)
    (root / "images").mkdir(parents=True)
    for name, c in zip(names, centers):
        ground = c + rays * (-c[2] / rays[:, 2:3])
        map_x = ((ground[:, 0] - x0) / gsd - 0.5).reshape(camera.height, camera.width).astype(np.float32)
        map_y = ((y1 - ground[:, 1]) / gsd - 0.5).reshape(camera.height, camera.width).astype(np.float32)
        img = cv2.remap(ortho, map_x, map_y, cv2.INTER_LINEAR)
        cv2.imwrite(str(root / "images" / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    write_poses_csv(root / "poses.csv", Poses(names, np.repeat(r_wc[None], frames, 0), centers))
    write_cameras_txt(root / "cameras.txt", {1: camera})
    return objs


# --- change detection: two sessions of one world, as `plugin.changes` sees them (no files) ----------------------

CHANGE_CAMERA = Camera(640, 480, 400.0, 400.0, 320.0, 240.0)
NADIR = np.diag([1.0, -1.0, -1.0])  # world_from_camera of a camera looking straight down


def nadir_poses(centers: np.ndarray) -> Poses:
    return Poses([f"f{i:04d}.jpg" for i in range(len(centers))], np.broadcast_to(NADIR, (len(centers), 3, 3)),
                 centers)


def change_session(positions: np.ndarray, sizes: np.ndarray, present: np.ndarray, centers: np.ndarray, seed: int,
                   clutter: int = 25, session_from_world: Sim3 | None = None, camera: Camera = CHANGE_CAMERA,
                   ) -> tuple[object, np.ndarray]:
    """A session of the world: landmarks = present objects seen >= 6 times (with noise), segments = the present
    objects' projections plus random clutter segments, all in the frame session_from_world. Returns the
    `SessionObservations` and the world index of each landmark."""
    from ..plugin.changes import KeyframeSegments, SessionObservations, in_view

    cam = camera
    rng = np.random.default_rng(seed)
    poses = nadir_poses(centers)
    seen, uv, depth = in_view(positions, sizes, poses, [cam] * len(poses))
    keep = present & (seen.sum(0) >= 6)
    segs = []
    for k in range(len(poses)):
        vis = np.flatnonzero(seen[k] & present)
        c = uv[k, vis] + rng.normal(0.0, 1.0, (len(vis), 2))
        h = sizes[vis] * cam.fx / depth[k, vis] * rng.uniform(0.9, 1.1, len(vis))
        cl = rng.uniform([0, 0], [cam.width, cam.height], (clutter, 2))
        segs.append(KeyframeSegments(np.vstack([c, cl]), np.concatenate([h, rng.uniform(2.0, 30.0, clutter)])))
    pos = positions[keep] + rng.normal(0.0, 0.3, (int(keep.sum()), 3))
    size = sizes[keep] * rng.uniform(0.92, 1.08, int(keep.sum()))
    obs = SessionObservations(pos, size, poses, cam, tuple(segs), seen.sum(0)[keep].astype(float))
    if session_from_world is not None:
        obs = obs.transformed(session_from_world)
    return obs, np.flatnonzero(keep)


def toy_change_pair() -> tuple:
    """Two partly overlapping sessions of one 260-object world, each with about a tenth of the objects absent,
    B in a frame of its own: (positions, sizes, present_a, present_b, a, ids_a, b, ids_b, a_from_b)."""
    w = make_spaced_world(260, 240.0, (1.0, 4.0), 3)
    positions, sizes = w.positions, w.sizes
    rng = np.random.default_rng(5)
    n = len(positions)
    present_a = rng.random(n) > 0.1
    present_b = rng.random(n) > 0.1
    cams_a = lawnmower(30, 150, 30, 150, 70, 30, 8)
    cams_b = lawnmower(90, 210, 60, 180, 70, 30, 8)  # overlaps A in part
    frame_b = yaw_transform(35.0, (12.0, -7.0, 2.0))
    a, ids_a = change_session(positions, sizes, present_a, cams_a, 1)
    b, ids_b = change_session(positions, sizes, present_b, cams_b, 2, session_from_world=frame_b)
    return positions, sizes, present_a, present_b, a, ids_a, b, ids_b, frame_b.inverse()


def render_nadir_images(poses: Poses, camera: Camera, positions: np.ndarray, sizes: np.ndarray, drawn: np.ndarray,
                        world_seed: int, gain: float = 1.0, offset: float = 0.0, noise_seed: int = 0,
                        ) -> list[np.ndarray]:
    """Grey images of a world seen by nadir pinhole keyframes: a textured ground plane at z = 0 (sinusoids of
    0.8-12 m drawn from `world_seed`, the same in every session: fine enough to tell heights by) and a disc of
    radius 2 h at each drawn point's height, with a texture of its own (dark, ringed and spotted, phases from the
    world seed); brightness gain and offset and pixel noise per session (another illumination, another
    exposure). The higher disc hides the lower; a disc at height 0 is a patch of the ground (a shadow)."""
    rng = np.random.default_rng(world_seed)
    waves = [(np.exp(rng.uniform(np.log(0.8), np.log(12.0))), rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi))
             for _ in range(16)]
    spots = rng.uniform(0, 2 * np.pi, (len(positions), 2))
    noise = np.random.default_rng(noise_seed)
    v, u = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    ray = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    order = np.argsort(positions[:, 2])  # the higher disc hides the lower
    images = []
    for k in range(len(poses)):
        d = ray @ poses.rotations[k].T
        c = poses.centers[k]

        def at(z: float, c: np.ndarray = c, d: np.ndarray = d) -> tuple[np.ndarray, np.ndarray]:
            t = (z - c[2]) / d[..., 2]  # the pixels' rays meet the plane at height z
            return c[0] + t * d[..., 0], c[1] + t * d[..., 1]

        x, y = at(0.0)
        img = 120.0 + sum(12.0 * np.sin(2 * np.pi * (x * np.cos(a) + y * np.sin(a)) / lam + ph)
                          for lam, a, ph in waves)
        uv, depth = project(camera, poses.rotations[k], c, positions)
        reach = 2.0 * sizes * camera.fx / np.maximum(depth, 1e-6) + 2.0
        for i in order[drawn[order] & (depth[order] > 0)]:
            u0, u1 = (np.clip([uv[i, 0] - reach[i], uv[i, 0] + reach[i] + 1], 0, camera.width)).astype(int)
            v0, v1 = (np.clip([uv[i, 1] - reach[i], uv[i, 1] + reach[i] + 1], 0, camera.height)).astype(int)
            if u1 <= u0 or v1 <= v0:
                continue
            box = (slice(v0, v1), slice(u0, u1))  # the disc's pixels only
            ox, oy = at(float(positions[i, 2]), c, d[box])
            dx, dy = ox - positions[i, 0], oy - positions[i, 1]
            r = np.hypot(dx, dy)
            tex = (55.0 + 25.0 * np.cos(2 * np.pi * r / sizes[i])
                   + 20.0 * np.sin(2.2 * dx + spots[i, 0]) * np.sin(1.9 * dy + spots[i, 1]))
            img[box] = np.where(r <= 2.0 * sizes[i], tex, img[box])
        images.append(np.clip(gain * img + offset + noise.normal(0.0, 3.0, img.shape), 0, 255).astype(np.float32))
    return images


def record_georeference_offset(match_json: str | Path, b_path: str | Path, radius_m: float = 50.0) -> float:
    """Write into a toy match.json what `match` records of maps in one EPSG: how far the answer moves B from its
    georeference (the median over its paired landmarks, `chance.median_horizontal_move`), the radius it is trusted
    to and how the search used it; returns that offset (m). For the georeference rule of merge, changes, batch."""
    from ..database.match_io import read_match
    from ..plugin.chance import median_horizontal_move

    match_json = Path(match_json)
    m = read_match(match_json)
    off = median_horizontal_move(m.transform, read_landmark_map(Path(b_path) / "landmarks.sosmap").positions[
        m.associations[:, 1]])
    data = json.loads(match_json.read_text())
    data["search_mode"] = {"position_prior": f"georeference {radius_m:g} m: refused there",
                           "georeference_off_m": round(off, 2)}
    data["params"] = {"association": {"georeference_prior_m": radius_m}}
    match_json.write_text(json.dumps(data))
    return off


def overlapping_pair(root: str | Path) -> tuple[ToyWorld, ToySession, ToySession]:
    """Two toy sessions of one 260-object world that overlap in part (B turned 40 deg and shifted against the
    world), in ROOT/A and ROOT/B: the pair of the merge, changes and georeference tests."""
    root = Path(root)
    world = make_world(260, seed=11)
    a = write_toy_session(root / "A", world, lawnmower(20, 140, 20, 140, 60, 40, 10), Sim3.identity(), seed=1)
    b = write_toy_session(root / "B", world, lawnmower(90, 220, 90, 220, 60, 40, 10), yaw_transform(40, (15, -8, 3)),
                          seed=2)
    return world, a, b


def stamp_epsg(session_dir: str | Path, epsg: int) -> None:
    """Give a toy session's landmark map the EPSG code `epsg` (positions unchanged): a georeferenced map."""
    path = Path(session_dir) / "landmarks.sosmap"
    lm = read_landmark_map(path)
    write_landmark_map(path, LandmarkMap(lm.positions, lm.sizes, lm.origin, epsg))
