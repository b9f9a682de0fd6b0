"""Geodesy for survey images (pyproj): WGS84 -> UTM grid with the measured meridian convergence, and topocentric
(east-north-up at a reference point, OpenSfM's world frame) -> grid."""

from __future__ import annotations

import math

import numpy as np

# UTM is defined from 80 deg S to 84 deg N; beyond, the polar caps are Universal Polar Stereographic's (its
# scale factor is 0.994 at the pole and 1 near 81 deg: ground metres within 0.6 %). A flight up to 0.8 deg
# beyond keeps its UTM zone, as it always did (the area checks allow 100 km, `database.geojson`): a site at
# 80.001 S flown before and after would otherwise be mapped in two CRSs (review rev18)
UTM_NORTH_LIMIT_DEG, UTM_SOUTH_LIMIT_DEG = 84.8, -80.8
UPS_NORTH_EPSG, UPS_SOUTH_EPSG = 32661, 32761
# metres of a degree of latitude (and of longitude at the equator): the small-distance approximation the checks
# of a flight's fixes use (their spread, a telemetry file against the EXIF, a rounding grid), within 0.6 %
METRES_PER_DEGREE = 111_320.0


def utm_epsg(latitude: float, longitude: float) -> int:
    """EPSG code of the WGS84 / UTM zone containing a point (326zz north, 327zz south), or of WGS84 / UPS North
    (32661) or South (32761) beyond UTM's latitudes and their margin (a flight at 85.5 deg N in a UTM zone lies
    outside the zone's area, and any check of it against that area fails)."""
    if latitude > UTM_NORTH_LIMIT_DEG:
        return UPS_NORTH_EPSG
    if latitude < UTM_SOUTH_LIMIT_DEG:
        return UPS_SOUTH_EPSG
    zone = int(math.floor((longitude + 180.0) / 6.0)) % 60 + 1
    return (32600 if latitude >= 0 else 32700) + zone


def geographic_to_grid(lat: np.ndarray, lon: np.ndarray, epsg: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """WGS84 degrees -> (easting, northing, azimuth of true north in the grid in degrees) for a projected CRS."""
    from pyproj import Transformer

    tf = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    e, n = tf.transform(lon, lat)
    # Meridian convergence measured, not looked up: the grid direction of a 1e-4 degree step north.
    e2, n2 = tf.transform(lon, lat + 1e-4)
    north_az = np.degrees(np.arctan2(np.asarray(e2) - e, np.asarray(n2) - n))
    return np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64), north_az


def grid_north_azimuth(easting: np.ndarray, northing: np.ndarray, epsg: int) -> np.ndarray:
    """Azimuth of true north in the grid (degrees, clockwise from grid north: the meridian convergence) at grid
    points of a projected CRS; a heading from true north is that heading + this in the grid."""
    from pyproj import Transformer

    to_geo = Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True)
    lon, lat = to_geo.transform(np.asarray(easting, dtype=np.float64), np.asarray(northing, dtype=np.float64))
    return geographic_to_grid(np.asarray(lat), np.asarray(lon), epsg)[2]


def topocentric_frame(latitude: float, longitude: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,) in ECEF metres, ecef_from_enu rotation (3,3)) of the topocentric frame (x east, y north, z up)
    at a point of the WGS84 ellipsoid (degrees, ellipsoidal height): ECEF = origin + ecef_from_enu @ enu."""
    from pyproj import Transformer

    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    origin = np.array(to_ecef.transform(float(longitude), float(latitude), float(height)))
    la, lo = math.radians(latitude), math.radians(longitude)
    ecef_from_enu = np.array([[-math.sin(lo), -math.sin(la) * math.cos(lo), math.cos(la) * math.cos(lo)],
                              [math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la) * math.sin(lo)],
                              [0.0, math.cos(la), math.sin(la)]])
    return origin, ecef_from_enu


def topocentric_to_grid(enu: np.ndarray, origin_lla: tuple[float, float, float],
                        epsg: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Points of a topocentric frame (x east, y north, z up at `origin_lla` = latitude, longitude, ellipsoidal
    height; OpenSfM's world frame with GPS) -> (grid easting, northing, height (N,3), grid_from_topocentric
    rotations (N,3,3), EPSG code: the UTM zone of the origin unless given). Exact through ECEF (`ecef_to_grid`)."""
    lat0, lon0, h0 = (float(v) for v in origin_lla)
    p = np.asarray(enu, dtype=np.float64).reshape(-1, 3)
    x0, ecef_from_enu = topocentric_frame(lat0, lon0, h0)
    return ecef_to_grid(x0 + p @ ecef_from_enu.T, np.broadcast_to(ecef_from_enu, (len(p), 3, 3)),
                        epsg or utm_epsg(lat0, lon0))


# Earth-centred, Earth-fixed (EPSG:4978) camera centres lie at the Earth's radius (6,356.8 km at the poles to
# 6,378.1 km at the equator) plus their height; a survey flies below 10 km
ECEF_RADIUS_RANGE_M = (6_356_752.0 - 1_000.0, 6_378_137.0 + 10_000.0)
# ... and a mapping camera looks down: towards the Earth's centre, within this angle (oblique surveys included)
ECEF_VIEW_LIMIT_DEG = 60.0


def looks_like_ecef(centers: np.ndarray, rotations: np.ndarray) -> bool:
    """Whether poses of an unnamed frame are Earth-centred (ECEF) coordinates, as COLMAP's model_aligner writes
    them with GPS references (`--alignment_type ecef`): every camera centre at the Earth's radius, and the cameras
    looking towards the Earth's centre (a frame whose northing happens to be ~6,370 km has its cameras looking
    along -z instead, far from the radial direction)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    if not len(c):
        return False
    radius = np.linalg.norm(c, axis=1)
    if not np.all((radius >= ECEF_RADIUS_RANGE_M[0]) & (radius <= ECEF_RADIUS_RANGE_M[1])):
        return False
    view = np.asarray(rotations, np.float64).reshape(-1, 3, 3)[:, :, 2]  # world_from_camera: the optical axis
    down = -c / radius[:, None]
    cos = np.sum(view * down, axis=1)
    return bool(np.median(cos) >= math.cos(math.radians(ECEF_VIEW_LIMIT_DEG)))


def ecef_to_grid(centers: np.ndarray, rotations: np.ndarray,
                 epsg: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """ECEF camera centres and world_from_camera rotations -> (grid easting, northing, ellipsoidal height (N,3),
    grid_from_camera rotations, EPSG code: the UTM zone of their median position unless given). Exact through
    pyproj; each camera's grid_from_ecef rotation is the polar factor of the conversion's local Jacobian, as in
    `topocentric_to_grid`."""
    from pyproj import Transformer

    c = np.asarray(centers, np.float64).reshape(-1, 3)
    ecef_to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, _ = ecef_to_geo.transform(c[:, 0], c[:, 1], c[:, 2])
    epsg = epsg or utm_epsg(float(np.median(lat)), float(np.median(lon)))
    geo_to_grid = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)

    def grid(points: np.ndarray) -> np.ndarray:
        lo, la, h = ecef_to_geo.transform(points[:, 0], points[:, 1], points[:, 2])
        e, n = geo_to_grid.transform(lo, la)
        return np.column_stack([e, n, h])

    out = grid(c)
    jac = np.stack([(grid(c + 0.5 * np.eye(3)[k]) - grid(c - 0.5 * np.eye(3)[k])) for k in range(3)], axis=2)
    u, _, vt = np.linalg.svd(jac)
    return out, (u @ vt) @ np.asarray(rotations, np.float64).reshape(-1, 3, 3), int(epsg)
