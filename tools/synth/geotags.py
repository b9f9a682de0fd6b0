"""Geotags of a synthetic session: the EXIF GPS and DJI-style XMP a consumer drone writes into its JPEGs, drawn
from the exact poses with that kind of drone's errors, so the poses-from-images path (`sosmatch poses`) is
tested against exact truth.

Georeference: the world's (x, y, z) is the UTM grid shifted by `GeoFrame.offset` (east, north, height above
the ellipsoid): the world centre lies at `geo_origin_latlon`, the world's axes are the grid's, so the truth of a
session in UTM is simply `poses.centers + offset` (rotations unchanged). Latitude and longitude are the inverse
UTM projection of the noisy grid position; headings are written from true north (the grid azimuth minus the
meridian convergence), as a drone's compass reports them.

Errors (each drawn from the session seed, `SynthConfig.geotag_*` settings):
- GPS: white horizontal noise (`gps_sigma_m` per axis) and vertical noise (`gps_altitude_sigma_m`), plus an
  altitude drift growing linearly with the flight time to `gps_altitude_drift_m` at the last image (consumer
  receivers' heights wander by tens of metres within a flight; the drift accumulates from take-off, the first
  image);
- DJI XMP (`geotags="dji"`): gimbal yaw/pitch/roll of the true camera orientation rotated by a small random
  rotation (`attitude_tag_sigma_deg` about the horizontal axes, `yaw_tag_sigma_deg` about the vertical), the
  airframe's Flight* angles (yaw near the gimbal's, a few degrees of pitch and roll), RelativeAltitude = the
  height above the take-off point (the terrain under the first image; barometric, `relative_altitude_sigma_m`)
  and AbsoluteAltitude = the GPS altitude; `yaw_fault_lines` adds 180 degrees to both yaws on those flight
  lines (`flights.flight_line_ids`), the fault seen on a real DJI flight;
- EXIF: FocalLength for a sensor of `sensor_width_mm` and the 35 mm equivalent of the sensor's full frame
  (whole millimetres, as EXIF stores it), DateTimeOriginal + SubSecTimeOriginal at the flight speed.
"""

from __future__ import annotations

import calendar
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...database.exif import EXIF_DATETIME_FORMAT, ImageMetadata
from ...plugin.association.rigid import roll_pitch_yaw_deg
from ...plugin.attitude import ENU_FROM_NED, GIMBAL_MOUNT
from ...plugin.geodesy import geographic_to_grid, utm_epsg
from ...plugin.geometry import Camera, Poses
from .noise import rng_for

_T_GEOTAGS = 31
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
START_TIME = "2024:06:01 10:00:00"
GEOTAG_KINDS = ("", "exif", "dji")


@dataclass(frozen=True)
class GeotagSettings:
    """What the drone writes and how wrong it is (see the module doc)."""

    kind: str = "dji"  # "exif": GPS + camera EXIF only; "dji": also DJI XMP attitude and heights
    origin_latlon: tuple[float, float] = (47.0, 8.0)
    ground_altitude_m: float = 420.0  # ellipsoidal height of the world's z = 0
    gps_sigma_m: float = 1.0
    gps_altitude_sigma_m: float = 1.5
    gps_altitude_drift_m: float = 0.0
    attitude_tag_sigma_deg: float = 0.5
    yaw_tag_sigma_deg: float = 1.0
    relative_altitude_sigma_m: float = 0.1
    yaw_fault_lines: tuple[int, ...] = ()
    speed_mps: float = 5.0
    sensor_width_mm: float = 6.3  # a 1/2.3" sensor


@dataclass(frozen=True)
class GeoFrame:
    """UTM zone (EPSG code) of the world and the offset with utm = world + offset."""

    epsg: int
    offset: tuple[float, float, float]

    def to_dict(self) -> dict:
        return {"epsg": self.epsg, "world_to_crs_offset": list(self.offset),
                "convention": "crs = world + offset (axes shared)"}


def geo_frame(settings: GeotagSettings, world_size_m: float) -> GeoFrame:
    """The UTM zone of the origin and the offset that puts the world centre there (whole metres)."""
    lat, lon = settings.origin_latlon
    epsg = utm_epsg(lat, lon)
    e, n, _ = geographic_to_grid(np.array([lat]), np.array([lon]), epsg)
    half = world_size_m / 2.0
    return GeoFrame(epsg, (float(round(e[0] - half)), float(round(n[0] - half)), float(settings.ground_altitude_m)))


def _small_rotations(rng: np.random.Generator, n: int, tilt_sigma_deg: float, yaw_sigma_deg: float) -> np.ndarray:
    """(n,3,3) random rotations: about world x and y by `tilt_sigma_deg`, about world z by `yaw_sigma_deg`."""
    from scipy.spatial.transform import Rotation

    vec = np.radians(rng.normal(0.0, 1.0, (n, 3)) * [tilt_sigma_deg, tilt_sigma_deg, yaw_sigma_deg])
    return Rotation.from_rotvec(vec).as_matrix()


def _gimbal_angles(rotations: np.ndarray, north_az_deg: np.ndarray) -> np.ndarray:
    """(n,3) DJI gimbal (yaw from true north, pitch, roll) of world_from_camera rotations in the ENU grid."""
    out = np.empty((len(rotations), 3))
    for i, r in enumerate(rotations):
        ned_from_body = ENU_FROM_NED @ r @ GIMBAL_MOUNT.T  # the conventions the reader inverts (its own inverse)
        roll, pitch, yaw = roll_pitch_yaw_deg(ned_from_body)
        out[i] = (yaw - north_az_deg[i], pitch, roll)
    out[:, 0] = (out[:, 0] + 180.0) % 360.0 - 180.0
    return out


def _signed(value: float, digits: int = 2) -> str:
    return f"{value:+.{digits}f}"


def session_geotags(
    settings: GeotagSettings,
    frame: GeoFrame,
    poses: Poses,
    camera: Camera,
    sensor_size_px: tuple[int, int],
    line_ids: np.ndarray,
    takeoff_height_m: float,
    spacing_m: float,
    seeds: tuple[int, int],
) -> list[ImageMetadata]:
    """Per image, the metadata to embed (`database.exif_write.embed_metadata`). `sensor_size_px` is the full sensor
    frame (the 35 mm figure refers to its diagonal even when the images are a crop of it), `takeoff_height_m`
    the world height of the take-off point, `seeds` (world seed, session seed)."""
    from pyproj import Transformer

    n = len(poses)
    rng = rng_for(_T_GEOTAGS, *seeds)
    off = np.asarray(frame.offset)
    truth = poses.centers + off
    noise = rng.normal(0.0, 1.0, (n, 3)) * [settings.gps_sigma_m, settings.gps_sigma_m, settings.gps_altitude_sigma_m]
    fraction = np.arange(n) / max(n - 1, 1)  # frames are equally spaced in time
    gps = truth + noise
    gps[:, 2] += settings.gps_altitude_drift_m * fraction
    to_geo = Transformer.from_crs(f"EPSG:{frame.epsg}", "EPSG:4326", always_xy=True)
    lon, lat = to_geo.transform(gps[:, 0], gps[:, 1])
    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    _, _, north_az = geographic_to_grid(lat, lon, frame.epsg)

    tagged = _small_rotations(rng, n, settings.attitude_tag_sigma_deg, settings.yaw_tag_sigma_deg) @ poses.rotations
    gimbal = _gimbal_angles(tagged, north_az)
    flight_yaw = gimbal[:, 0] + rng.normal(0.0, 1.0, n)
    flight_pitch, flight_roll = rng.normal(0.0, 3.0, n), rng.normal(0.0, 2.0, n)
    fault = np.isin(line_ids, np.asarray(settings.yaw_fault_lines, dtype=np.int64)) & (line_ids >= 0)
    gimbal[fault, 0] = (gimbal[fault, 0] + 360.0) % 360.0 - 180.0
    flight_yaw[fault] += 180.0
    flight_yaw = (flight_yaw + 180.0) % 360.0 - 180.0
    relative = poses.centers[:, 2] - takeoff_height_m + rng.normal(0.0, settings.relative_altitude_sigma_m, n)

    diagonal_px = math.hypot(*sensor_size_px)
    focal_mm = camera.fx / sensor_size_px[0] * settings.sensor_width_mm
    focal_35 = camera.fx / diagonal_px * FULL_FRAME_DIAGONAL_MM
    start = calendar.timegm(time.strptime(START_TIME, EXIF_DATETIME_FORMAT))
    centiseconds = np.round(np.arange(n) * (spacing_m / settings.speed_mps) * 100.0).astype(np.int64)
    out = []
    for i in range(n):
        whole, sub = start + int(centiseconds[i]) // 100, int(centiseconds[i]) % 100
        meta = ImageMetadata(path=Path(poses.names[i]), width=camera.width, height=camera.height,
                             latitude=float(lat[i]), longitude=float(lon[i]), altitude=float(gps[i, 2]),
                             focal_mm=round(focal_mm, 3), focal_35mm=float(round(focal_35)),
                             make="DJI" if settings.kind == "dji" else "SynthCam",
                             model="FC-SYNTH" if settings.kind == "dji" else "Compact 1",
                             datetime_original=time.strftime(EXIF_DATETIME_FORMAT, time.gmtime(whole)),
                             subsec_original=f"{sub:02d}")
        if settings.kind == "dji":
            meta.xmp = {
                "AbsoluteAltitude": _signed(gps[i, 2]), "RelativeAltitude": _signed(relative[i]),
                "GimbalRollDegree": _signed(gimbal[i, 2]), "GimbalYawDegree": _signed(gimbal[i, 0]),
                "GimbalPitchDegree": _signed(gimbal[i, 1]), "FlightRollDegree": _signed(flight_roll[i]),
                "FlightYawDegree": _signed(flight_yaw[i]), "FlightPitchDegree": _signed(flight_pitch[i]),
            }
        out.append(meta)
    return out

