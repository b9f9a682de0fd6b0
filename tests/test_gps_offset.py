"""An offset of the GPS from the camera centres fixed in the cameras' frame (plugin.gps_offset) and its warning
(workflows.poses.checks.camera_frame_offset_warning)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sosmatch.plugin.geometry import Camera
from sosmatch.plugin.gps_offset import camera_frame_offset
from sosmatch.plugin.multisession import Sim3
from sosmatch.workflows.poses.checks import camera_frame_offset_warning, cropped_frames


def _nadir(heading_deg: float) -> np.ndarray:
    """world_from_cam of a nadir camera whose image top points along `heading_deg` (clockwise from north)."""
    h = np.radians(heading_deg)
    top = np.array([np.sin(h), np.cos(h), 0.0])
    y, z = -top, np.array([0.0, 0.0, -1.0])
    return np.stack([np.cross(y, z), y, z], axis=1)


def _flight(offset_right_m: float, noise_m: float = 1.0, lines: int = 4, seed: int = 0):
    """Lines flown east and west in turn, 12 images each; the GPS `noise_m` around the camera centres plus an
    offset toward each image's right. Returns (centres (N,3), world_from_cam (N,3,3), gps (N,3))."""
    rng = np.random.default_rng(seed)
    centers, rots = [], []
    for line in range(lines):
        heading = 90.0 if line % 2 == 0 else 270.0
        for k in range(12):
            centers.append([k * 10.0 if line % 2 == 0 else 110.0 - k * 10.0, line * 40.0, 100.0])
            rots.append(_nadir(heading))
    centers, rots = np.array(centers), np.array(rots)
    gps = centers + rng.normal(0, noise_m, centers.shape) + offset_right_m * rots[:, :, 0]
    gps[:, 2] = centers[:, 2]
    return centers, rots, gps


def test_an_offset_that_turns_with_the_camera_is_measured_and_one_fixed_in_the_world_is_not():
    centers, rots, gps = _flight(8.0)
    fit = camera_frame_offset((gps - centers)[:, :2] + [5.0, -3.0], rots)  # a world offset on top: the translation's
    assert fit.right_m == pytest.approx(8.0, abs=0.5) and abs(fit.top_m) < 0.5 and fit.chi2 > 1000
    assert fit.sigma_m == pytest.approx(1.0, abs=0.2)
    _, _, plain = _flight(0.0)
    assert camera_frame_offset((plain - centers)[:, :2], rots).chi2 < 18.4
    assert camera_frame_offset((gps - centers)[:12, :2], rots[:12]) is None  # one line, one way: not separable


def _geo(centers, rots, gps):
    """A georegistration in the identity frame keeping every fix (what the warning reads of one)."""
    n = len(centers)
    return SimpleNamespace(gps_indices=np.arange(n), horizontal=SimpleNamespace(inliers=np.ones(n, bool)),
                           position_shift=None, transform=Sim3(np.eye(3), np.zeros(3), 1.0))


def test_a_camera_frame_offset_beyond_the_receivers_noise_is_said_with_its_likely_causes():
    """nu42 crops: the principal point 40 px off put the camera centres 7 m to one side of their GPS on every
    line, exit 0 and nothing said (the residuals' 5.1 m sigma under 3 times the receiver's 3 m)."""
    centers, rots, gps = _flight(7.0)
    said = camera_frame_offset_warning(_geo(centers, rots, gps), centers, rots, gps, 3.0)
    assert said is not None and "7." in said and "toward the images' right" in said
    assert "principal point" in said and "cropped" in said and "aspect" not in said
    cropped = camera_frame_offset_warning(_geo(centers, rots, gps), centers, rots, gps, 3.0,
                                          [Camera(560, 480, 500.0, 500.0, 280.0, 240.0)])
    assert "the images' 560x480 is no sensor's aspect" in cropped
    assert cropped_frames([Camera(640, 480, 1, 1, 0, 0), Camera(3000, 4000, 1, 1, 0, 0), Camera(1920, 1080, 1, 1, 0, 0),
                           Camera(5472, 3648, 1, 1, 0, 0), Camera(480, 360, 1, 1, 0, 0)]) == []
    # a significant offset smaller than what the receiver itself is off by: within the GPS's own error
    centers, rots, gps = _flight(1.5, noise_m=0.3)
    assert camera_frame_offset_warning(_geo(centers, rots, gps), centers, rots, gps, 3.0) is None
    centers, rots, gps = _flight(0.0, noise_m=3.0)
    assert camera_frame_offset_warning(_geo(centers, rots, gps), centers, rots, gps, 3.0) is None


def test_the_offset_warning_reaches_the_georegistration_record_the_map_reads():
    """`map --images` read only the georegistration's own warnings of poses.json: an offset said by `poses`
    alone left the map's verdict a plain "ok" (nu42 crops: warn 0)."""
    from pathlib import Path

    from sosmatch.plugin.params import SfmParams
    from sosmatch.workflows.image_priors import ImagePriors
    from sosmatch.workflows.poses.checks import _register
    from sosmatch.workflows.poses.result import registration_warnings

    centers, rots, gps = _flight(7.0)
    n = len(centers)
    priors = ImagePriors([Path(f"f{i:03d}.jpg") for i in range(n)], [], 32632, gps, gps[:, 2].copy(),
                         np.full(n, np.nan), rots, np.full(n, "gimbal"), np.arange(n) * 2.0,
                         [Camera(640, 480, 500.0, 500.0, 320.0, 240.0)], np.zeros(n, int),
                         {"altitude_source": "GPS altitude", "capture_times": "DateTimeOriginal"})
    warnings: list[str] = []
    _, report, _ = _register(priors, np.arange(n), rots, centers, None, 100.0, 0, SfmParams(), warnings)
    said = [w for w in registration_warnings({"georegistration": report}) if "cameras' own frame" in w]
    assert len(said) == 1 and any("cameras' own frame" in w for w in warnings)
