"""Objects a session saw but never mapped: its tracks that no landmark holds (pure numpy).

A landmark needs more than theta_n observations, survives fusion, the reprojection and angle filters and
duplicate suppression; an object whose tracks broke into short pieces (a bush whose mask merges with the grass
every other frame, a small conifer seen on two passes) leaves no landmark, only pieces in the session's database
(tracks of `triangulation.min_piece_observations` observations and more are written there). Such an object can
still have appeared or disappeared, and the other session's segments can still say that nothing was there. Here
each such piece is triangulated (least-squares rays, the keyframe poses fixed) and kept as an unmapped object
when
- it reprojects within the map's `max_error_px`, in front of every camera that observed it, and its views fix
  the place to within the counterpart gate (2 sigma of the gate's metric with `pixel_sigma_px` of centroid
  noise): the other session is asked what is there, and a short track along one flight line often leaves
  its height open by tens of metres;
- the own map does not explain it: no own landmark is its counterpart (gate, size) and it is neither inside the
  footprint of a larger own landmark nor holds smaller ones, of any size, at that landmark's height (within the
  gate: a nested mask, a fragment of a mapped crown, a whole over mapped parts; a tree standing in a mapped
  field rises above the field's landmark); pieces of one object (up to `part_max_ratio` apart in size, inside
  each other's footprint) keep the best supported one;
- its own session's segments show it (tested in `verdict`, as "the other session's segments show it" is
  there): a size-compatible segment at its projection in at least `min_views` of its own keyframes,
  significantly more often than at the probe points around it, and hits more like those of the session's own
  landmarks than like an absence: one piece of track alone is no evidence of an object.
Change detection then judges these objects against the other session by direct evidence only (counterpart,
a holder the own session shows, the other session's segments, the absence probability), and they vouch for
nothing (a piece of track is weaker evidence than a landmark).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry import Camera, Poses
from ..landmark_size import mean_size
from ..track_fusion import intersect_rays, point_covariance, reprojection_errors
from .evidence import counterparts, holder_pairs, nested_pairs
from .observations import KeyframeSegments


@dataclass(frozen=True)
class UnmappedObjects:
    """A session's objects that are in no landmark: positions (M, 3), metric sizes (M,), observations (M,)
    and per object its track as (n, 2) rows (keyframe index, keypoint index)."""

    positions: np.ndarray
    sizes: np.ndarray
    support: np.ndarray
    tracks: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.positions)

    def subset(self, idx: np.ndarray) -> UnmappedObjects:
        return UnmappedObjects(self.positions[idx], self.sizes[idx], self.support[idx],
                               tuple(self.tracks[int(k)] for k in idx))


def no_unmapped_objects() -> UnmappedObjects:
    return UnmappedObjects(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), ())


def tracks_from_matches(matches: Sequence[tuple[int, int, np.ndarray]], keypoints_per_keyframe: Sequence[int],
                        ) -> list[np.ndarray]:
    """The tracks behind a database's matches: connected components of (keyframe, keypoint) nodes linked by the
    matched pairs (keyframe a, keyframe b, (M, 2) keypoint indices). Each track as (n, 2) rows sorted by
    keyframe; a component holding two keypoints of one keyframe is no track of one segment and is left out."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    offsets = np.concatenate([[0], np.cumsum(np.asarray(keypoints_per_keyframe, dtype=np.int64))])
    rows, cols = [], []
    for a, b, m in matches:
        m = np.asarray(m, dtype=np.int64).reshape(-1, 2)
        rows.append(offsets[a] + m[:, 0])
        cols.append(offsets[b] + m[:, 1])
    if not rows:
        return []
    r, c = np.concatenate(rows), np.concatenate(cols)
    n = int(offsets[-1])
    graph = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    linked = np.zeros(n, bool)
    linked[r] = linked[c] = True
    nodes = np.flatnonzero(linked)
    order = nodes[np.argsort(comp[nodes], kind="stable")]
    keyframe = np.searchsorted(offsets, order, side="right") - 1
    bounds = np.flatnonzero(np.r_[True, comp[order][1:] != comp[order][:-1], True])
    out = []
    for s, e in zip(bounds[:-1], bounds[1:]):
        kf, kp = keyframe[s:e], order[s:e] - offsets[keyframe[s:e]]
        if len(np.unique(kf)) < len(kf):
            continue
        srt = np.argsort(kf, kind="stable")
        out.append(np.column_stack([kf[srt], kp[srt]]))
    return out


def unmapped_objects(tracks: Sequence[np.ndarray], poses: Poses, cameras: Sequence[Camera],
                     segments: Sequence[KeyframeSegments], landmark_positions: np.ndarray,
                     landmark_sizes: np.ndarray, gate_m: float, max_size_difference: float, z_weight: float,
                     part_max_ratio: float, max_error_px: float, pixel_sigma_px: float) -> UnmappedObjects:
    """The session's candidate objects that no landmark represents, from its tracks that no landmark holds
    (`tracks`, rows (keyframe, keypoint) into `segments`); see the module docstring. Whether its own segments
    show each one is the caller's test (`verdict`, the same test as for the other session's segments)."""
    pos, size, support, kept = [], [], [], []
    for track in tracks:
        kf = track[:, 0]
        cams = {cameras[k] for k in kf}
        if len(kf) < 2 or len(cams) != 1:  # one camera per track: the rays of one lens model
            continue
        cam = cams.pop()
        pin = cam.pinhole()
        px = cam.undistort_points(np.array([segments[k].centroids[i] for k, i in track]))
        point = intersect_rays(pin, poses, kf, px)
        err = reprojection_errors(pin, poses, kf, px, point)
        if not np.all(np.isfinite(err)) or float(err.mean()) > max_error_px:
            continue
        # the other session is asked what is at this place: the place must be known to within the counterpart
        # gate (2 sigma of the gate's metric), which a short track along one flight line often does not give
        cov = point_covariance(pin, poses, kf, point, pixel_sigma_px)
        spread = float(np.sqrt(cov[0, 0] + cov[1, 1] + z_weight ** 2 * cov[2, 2]))
        if not 2.0 * spread <= gate_m:
            continue
        h_px = np.array([segments[k].sizes_px[i] for k, i in track], dtype=np.float64)
        if not np.all(np.isfinite(h_px)):
            continue
        pos.append(point)
        size.append(mean_size(pin, poses.rotations[kf], poses.centers[kf], point, h_px))
        support.append(len(kf))
        kept.append(track)
    if not pos:
        return no_unmapped_objects()
    pos_a, size_a, sup_a = np.array(pos), np.array(size), np.array(support, dtype=np.int64)
    ok = np.isfinite(size_a) & (size_a > 0)
    # explained by the map: a counterpart landmark, or a nested / part relation with one
    if len(landmark_positions):
        idx, _ = counterparts(pos_a, size_a, landmark_positions, landmark_sizes, gate_m, max_size_difference,
                              z_weight)
        ok &= idx < 0
        # nested in 3D, of any size: a piece inside a mapped crown (in its footprint and at its height, within the
        # gate) is a fragment of it, a whole over mapped parts at its height is those parts; an object standing
        # in a mapped field rises above the field's landmark and stays a candidate
        ok[nested_pairs(pos_a, size_a, landmark_positions, landmark_sizes, gate_m, z_weight)[0]] = False
        ok[nested_pairs(landmark_positions, landmark_sizes, pos_a, size_a, gate_m, z_weight)[1]] = False
    # pieces of one object (passes, nested masks): the best supported one stands for it
    part, whole = holder_pairs(pos_a, size_a, pos_a, size_a, part_max_ratio, same_map=True)
    links = [set() for _ in range(len(pos_a))]
    for i, j in zip(part, whole):
        links[i].add(int(j))
        links[j].add(int(i))
    taken: list[int] = []
    taken_set: set[int] = set()
    for c in sorted(np.flatnonzero(ok), key=lambda k: (-sup_a[k], k)):
        if links[c] & taken_set:
            continue
        taken.append(int(c))
        taken_set.add(int(c))
    keep = np.array(sorted(taken), dtype=np.int64)
    if not len(keep):
        return no_unmapped_objects()
    return UnmappedObjects(pos_a[keep], size_a[keep], sup_a[keep], tuple(kept[k] for k in keep))
