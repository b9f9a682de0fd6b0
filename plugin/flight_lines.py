"""The registered poses against their tags, and the flight lines of a track (pure numpy).

`compare_with_priors` measures every image's orientation against its attitude tags and finds flight lines whose
tags contradict the images (a 180 degree yaw); `flight_lines` splits a track into its straight lines. Both follow
the georegistration (`plugin.georegistration`), which puts the block where the tags and the GPS can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import rotation_angle_deg


@dataclass
class PriorComparison:
    """Per image: the registered orientation against the prior (tags), and the contradictions found."""

    angle_deg: np.ndarray  # total rotation between registered and prior orientation
    yaw_deg: np.ndarray  # signed yaw of the prior against the registered orientation, wrapped to +-180
    tilt_deg: np.ndarray  # angle between the two optical axes (the part a yaw error leaves alone)
    position_m: np.ndarray  # distance between registered centre and prior (GPS) position (nan without)
    yaw_bias_deg: float  # the median yaw difference of agreeing images (a compass offset)
    contradicting: np.ndarray  # bool: yaw off the bias by more than 90 degrees
    lines: list[dict]  # flight lines with contradicting tags: first/last index, count, their mean yaw


def _heading_deg(world_from_cam: np.ndarray) -> np.ndarray:
    """Azimuth (degrees, counter-clockwise from +x) of each image's top direction (-y axis) projected on the
    ground; for a nadir camera the yaw that the tags encode."""
    top = -world_from_cam[:, :, 1]
    return np.degrees(np.arctan2(top[:, 1], top[:, 0]))


def _wrap(deg: np.ndarray) -> np.ndarray:
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


def _circular_mean_deg(deg: np.ndarray) -> float:
    """Mean direction of angles (degrees, wrapped to +-180): +179 and -179 average to 180, not 0."""
    a = np.radians(np.asarray(deg, dtype=np.float64))
    return float(np.degrees(np.arctan2(np.sin(a).mean(), np.cos(a).mean())))


def compare_with_priors(
    world_from_cam: np.ndarray,
    centers: np.ndarray,
    prior_world_from_cam: np.ndarray,
    prior_centers: np.ndarray,
    line_ids: np.ndarray,
) -> PriorComparison:
    """Registered vs prior orientation of every image, and the flight lines (`line_ids`, -1 = none) on which
    most images' tags contradict the images by more than 90 degrees of yaw."""
    angle = np.asarray(rotation_angle_deg(world_from_cam, prior_world_from_cam), dtype=np.float64).reshape(-1)
    yaw = _wrap(_heading_deg(prior_world_from_cam) - _heading_deg(world_from_cam))
    axes = np.einsum("ni,ni->n", world_from_cam[:, :, 2], prior_world_from_cam[:, :, 2])
    tilt = np.degrees(np.arccos(np.clip(axes, -1.0, 1.0)))
    first = np.abs(yaw) <= 90.0
    bias = float(np.median(yaw[first])) if first.any() else 0.0
    contradicting = np.abs(_wrap(yaw - bias)) > 90.0
    pos = np.linalg.norm(centers - prior_centers, axis=1)
    lines = []
    ids = np.asarray(line_ids)
    for line in sorted(set(ids.tolist()) - {-1}):
        members = np.flatnonzero(ids == line)
        bad = contradicting[members]
        if bad.sum() > 0.5 * len(members):
            lines.append({"line": int(line), "first": int(members[0]), "last": int(members[-1]),
                          "images": int(len(members)), "contradicting": int(bad.sum()),
                          "median_yaw_deg": _circular_mean_deg(yaw[members][bad] - bias)})
    return PriorComparison(angle, yaw, tilt, pos, bias, contradicting, lines)


def frame_yaw_deg(world_from_cam: np.ndarray, prior_world_from_cam: np.ndarray) -> float:
    """The rotation about the vertical (degrees, counter-clockwise) that turns the registered orientations onto
    the priors' yaw: the offset most images agree on within 90 degrees (their circular mean), so that a
    flight line of contradicting tags does not pull it. For a frame whose yaw is unknown (a local frame without
    GPS), where only the tags' yaw relative to one another can be checked. 0 without images."""
    if not len(world_from_cam):
        return 0.0
    yaw = _wrap(_heading_deg(prior_world_from_cam) - _heading_deg(world_from_cam))
    mode = yaw[int(np.argmax(_within_90_counts(yaw)))]
    return _circular_mean_deg(yaw[np.abs(_wrap(yaw - mode)) <= 90.0])


def _within_90_counts(yaw: np.ndarray) -> np.ndarray:
    """For each offset (degrees, wrapped), how many offsets lie within 90 degrees of it around the circle, itself
    included. Counted on the sorted offsets with their copies a turn below and above (a window of 180 degrees
    holds each offset once), in N log N time and memory N: the N x N comparison took 3.2 GB at 20 000 images."""
    ring = np.sort(yaw)
    ring = np.concatenate([ring - 360.0, ring, ring + 360.0])
    return np.searchsorted(ring, yaw + 90.0, side="right") - np.searchsorted(ring, yaw - 90.0, side="left")


def flight_lines(centers: np.ndarray, max_turn_deg: float = 30.0, min_images: int = 3) -> np.ndarray:
    """Flight line id per image (in capture order) from the track: the steps between consecutive images are cut
    into runs wherever the direction turns by more than `max_turn_deg` from the run's mean, each image joins the
    longer of the runs of its incoming and outgoing step (a turn's diagonal step loses), and lines of fewer
    than `min_images` images get -1. So does a crossing between two lines: a run shorter than the runs before and
    after it, across them (more than 45 deg off their axis, which they share within 45 deg). Lines are numbered
    0, 1, ... in the order flown, as `sosmatch synth` numbers them (`--yaw-fault-lines`, session.json
    `geo.flight_lines`: the crossings of a lawnmower flight are no lines there either)."""
    c = np.asarray(centers, float)
    n = len(c)
    ids = np.full(n, -1, dtype=np.int64)
    if n < 2:
        return ids
    step = np.diff(c[:, :2], axis=0)
    heading = np.degrees(np.arctan2(step[:, 1], step[:, 0]))
    run = np.zeros(n - 1, dtype=np.int64)
    start, ref = 0, heading[0]
    for i in range(1, n - 1):
        if abs(_wrap(heading[i] - ref)) > max_turn_deg:
            run[i], start, ref = run[i - 1] + 1, i, heading[i]
        else:
            run[i] = run[i - 1]
            ref = ref + _wrap(heading[i] - ref) / (i - start + 1)  # running mean direction
    length = np.bincount(run)
    incoming = np.r_[run[0], run]  # image i's incoming step is i - 1 (image 0: its outgoing one)
    outgoing = np.r_[run, run[-1]]
    member = np.where(length[incoming] >= length[outgoing], incoming, outgoing)
    runs = [r for r in range(len(length)) if np.sum(member == r) >= min_images]
    step_len = np.linalg.norm(step, axis=1)
    extent = {r: float(step_len[run == r].sum()) for r in runs}
    axis = {r: _axis_deg(heading[run == r], step_len[run == r]) for r in runs}
    crossing = {r for prev, r, nxt in zip(runs, runs[1:], runs[2:])
                if _axis_angle_deg(axis[prev], axis[nxt]) <= 45.0
                and min(_axis_angle_deg(axis[r], axis[prev]), _axis_angle_deg(axis[r], axis[nxt])) > 45.0
                and extent[r] < min(extent[prev], extent[nxt])}
    line = 0
    for r in runs:
        if r not in crossing:
            ids[member == r] = line
            line += 1
    return ids


def _axis_deg(heading_deg: np.ndarray, weight: np.ndarray) -> float:
    """The mean axis (direction modulo 180 degrees) of weighted headings: a line flown either way has one axis."""
    doubled = np.radians(2.0 * np.asarray(heading_deg, float))
    return float(np.degrees(np.arctan2(np.sum(weight * np.sin(doubled)), np.sum(weight * np.cos(doubled)))) / 2.0)


def _axis_angle_deg(a: float, b: float) -> float:
    """Angle between two axes (directions modulo 180 degrees), 0-90."""
    d = abs(float(_wrap(a - b))) % 180.0
    return min(d, 180.0 - d)
