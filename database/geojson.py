"""Landmarks as GeoJSON (RFC 7946: WGS84 longitude/latitude) for QGIS and web maps, written atomically.

Each landmark is a Feature: a Point (longitude, latitude, height) or, with `geometry="circle"`, a Polygon of the
object the landmark's metric size describes: size_m is sqrt(lambda_max) of its segment, a standard deviation
(R/2 for a disc of radius R), so the circle is the disc of that second moment, radius 2 x size_m (drawn as a
diameter of size_m it was a quarter of the object's radius, dots inside crowns and roofs: the sixteenth
sweep), drawn in the map's projected CRS and then transformed, so it has the right size on the ground.
Properties: index, size_m, x, y, z (the map's CRS), plus any per-landmark extras given (e.g. num_observations).
The FeatureCollection's properties carry the source CRS and origin, and `height_reference` (HEIGHT_REFERENCE).
A polygon that crosses the antimeridian is cut there into a MultiPolygon (`polygon_geometry`, RFC 7946 3.1.9).

Heights. The third coordinate is the map's z as it is: the height datum of the poses the map was made from, not
converted. RFC 7946 means the height above the WGS84 ellipsoid; a map from the images' own tags (`map --images`)
has the altitude as the receiver reported it (EXIF GPSAltitude / DJI AbsoluteAltitude; a take-off altitude +
RelativeAltitude is that datum too): above mean sea level for most consumer drones' GPS, but RTK / PPK receivers
often report the ellipsoidal height, and the tags do not say which. The two differ by the geoid undulation
(-106..+85 m over the earth, e.g. +48 m in central Europe); converting needs a geoid grid (EGM96/EGM2008), which
this package does not carry. So the file says what is known (nu34: it claimed "above mean sea level" for RTK
flights whose heights were ellipsoidal).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..plugin.errors import InputError
from .landmark_map import LandmarkMap


def check_projected_crs(epsg: int, source: str | Path | None = None) -> None:
    """Refuse (InputError naming `source`, the file that gave the code) an EPSG code that is unknown or not a
    projected CRS: a landmark map's world frame is metric, so EPSG:4326 (degrees) would turn metres into
    degrees."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    where = "the map's" if source is not None else "the given"
    try:
        crs = CRS.from_epsg(int(epsg))
    except (CRSError, ValueError, OverflowError):
        raise InputError(f"unknown EPSG code {epsg} ({where} CRS)", source) from None
    if not crs.is_projected:
        raise InputError(f"EPSG:{epsg} ({crs.name}) is not a projected CRS in metres, as a landmark map's world "
                         f"frame must be ({where} CRS)", source)


# How far outside a CRS's area of use coordinates may lie (a map across a UTM zone edge: tens of km)
CRS_AREA_MARGIN_M = 100_000.0


def check_within_crs_area(epsg: int, xy: np.ndarray, source: str | Path | None = None,
                          what: str = "the landmarks") -> None:
    """Refuse (InputError naming `source`) coordinates more than CRS_AREA_MARGIN_M outside the projected
    bounds of the CRS's area of use: a local map stamped with a CRS (a synthetic session's 300 m coordinates as
    UTM zone 33N) converts to lon/lat without complaint, in the Gulf of Guinea. A CRS without a recorded or
    projectable area (Web Mercator's is the world) is not checked; points without finite coordinates are not
    judged here."""
    from pyproj import CRS

    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    bounds = crs_area_bounds(epsg)
    if bounds is None or not _beyond(bounds, xy).any():
        return
    x0, y0, x1, y1 = bounds
    lo, hi, m = xy.min(axis=0), xy.max(axis=0), CRS_AREA_MARGIN_M
    raise InputError(f"{what} lie at x {lo[0]:.0f}..{hi[0]:.0f}, y {lo[1]:.0f}..{hi[1]:.0f} m, more than "
                     f"{m / 1000:.0f} km outside where EPSG:{epsg} ({CRS.from_epsg(int(epsg)).name}) is used "
                     f"(x {x0:.0f}..{x1:.0f}, y {y0:.0f}..{y1:.0f}): a local frame given a CRS?", source)


def outside_crs_area(epsg: int, xy: np.ndarray) -> np.ndarray:
    """(N,) True for the points of `xy` (projected coordinates of EPSG:`epsg`) more than CRS_AREA_MARGIN_M
    outside the projected bounds of the CRS's area of use, or not finite (all False where it has no area)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    bounds = crs_area_bounds(epsg)
    if bounds is None:
        return np.zeros(len(xy), bool)
    with np.errstate(invalid="ignore"):
        return _beyond(bounds, xy) | ~np.all(np.isfinite(xy), axis=1)


def _beyond(bounds: tuple[float, float, float, float], xy: np.ndarray) -> np.ndarray:
    """(N,) True for the points of `xy` more than CRS_AREA_MARGIN_M outside `bounds` (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = bounds
    m = CRS_AREA_MARGIN_M
    return (xy[:, 0] < x0 - m) | (xy[:, 0] > x1 + m) | (xy[:, 1] < y0 - m) | (xy[:, 1] > y1 + m)


def crs_area_bounds(epsg: int) -> tuple[float, float, float, float] | None:
    """The projected bounds (x0, y0, x1, y1) of EPSG:`epsg`'s area of use, or None: no recorded area, one across
    the antimeridian, or none that projects (Web Mercator's is the world)."""
    from pyproj import CRS, Transformer

    crs = CRS.from_epsg(int(epsg))
    area = crs.area_of_use
    if area is None or area.east < area.west:
        return None
    try:
        tf = Transformer.from_crs(CRS.from_epsg(4326), crs, always_xy=True)
        bounds = tf.transform_bounds(area.west, area.south, area.east, area.north)
    except Exception:  # pyproj.ProjError and friends: no projected bounds, nothing to check against
        return None
    return tuple(float(v) for v in bounds) if all(np.isfinite(bounds)) else None  # type: ignore[return-value]


def to_wgs84(xy: np.ndarray, epsg: int) -> np.ndarray:
    """(N, 2) coordinates of a projected CRS (EPSG code) -> (N, 2) WGS84 longitude, latitude in degrees."""
    from pyproj import CRS, Transformer

    check_projected_crs(epsg)
    tf = Transformer.from_crs(CRS.from_epsg(int(epsg)), CRS.from_epsg(4326), always_xy=True)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    lon, lat = tf.transform(xy[:, 0], xy[:, 1])
    return np.column_stack([lon, lat])


def polygon_geometry(ring: np.ndarray, digits: int = 8) -> dict:
    """A GeoJSON Polygon of a closed ring of (longitude, latitude) degrees, cut at the antimeridian into a
    MultiPolygon where it crosses it (RFC 7946 3.1.9), coordinates rounded to `digits` decimals.

    A ring is taken as the small shape it is on the ground: from vertex to vertex it goes the short way round
    (less than 180 degrees of longitude). Drawn as given, a circle a metre across the antimeridian had vertices at
    both +-179.99999 and spanned 360 degrees to a planar GIS (the nu25 sweep: 7 of 75 circles, invalid to
    shapely). Cut, each part lies within -180..180 and the parts meet on the antimeridian. A ring around a pole
    (its longitudes go once round) becomes the cap it bounds, closed along the pole's latitude. Rings that
    cross nothing are written vertex for vertex as given."""
    import shapely
    from shapely.affinity import translate
    from shapely.geometry import box
    from shapely.geometry.polygon import orient

    ring = np.asarray(ring, dtype=np.float64).reshape(-1, 2)
    lon = np.unwrap(ring[:, 0], period=360.0)
    if lon.min() >= -180.0 and lon.max() <= 180.0 and abs(lon[-1] - lon[0]) < 180.0:
        return {"type": "Polygon", "coordinates": [np.round(ring, digits).tolist()]}
    pts = np.column_stack([lon, ring[:, 1]])
    turns = round((lon[-1] - lon[0]) / 360.0)
    if turns:  # around a pole: along the ring, then back at the pole's latitude
        pole = math.copysign(90.0, float(np.mean(ring[:, 1])))
        pts = np.vstack([pts, [[lon[-1], pole], [lon[0], pole]]])
    shape = shapely.make_valid(shapely.Polygon(pts))
    # the unwrapped shape lies within a turn of -180..180 either way: its part in each 360-degree band, moved back
    parts = [translate(shape.intersection(box(k * 360.0 - 180.0, -90.0, k * 360.0 + 180.0, 90.0)), -k * 360.0)
             for k in (-1, 0, 1)]
    merged = shapely.union_all([p for p in parts if not p.is_empty])
    polys = [orient(g, sign=1.0) for g in getattr(merged, "geoms", [merged]) if isinstance(g, shapely.Polygon)
             and not g.is_empty]
    coords = [[np.round(np.asarray(r.coords), digits).tolist() for r in (g.exterior, *g.interiors)] for g in polys]
    if len(coords) == 1:
        return {"type": "Polygon", "coordinates": coords[0]}
    return {"type": "MultiPolygon", "coordinates": coords}


# What the third coordinate is (module doc), written into every FeatureCollection's properties: a GIS that takes
# it for RFC 7946's ellipsoidal height puts the landmarks tens of metres too low or too high
HEIGHT_REFERENCE = ("z of the map's frame, unconverted: the vertical datum of the poses it was made from (from "
                    "images' EXIF/DJI GPS altitudes: the altitude as the receiver reported it, above mean sea level "
                    "for most drones' GPS, often the ellipsoidal height for RTK/PPK receivers), not converted to the "
                    "WGS84 ellipsoidal height of RFC 7946")


# a disc of radius R has sqrt(lambda_max) = R / 2: the circle of a landmark of size s (module doc)
CIRCLE_RADIUS_PER_SIZE = 2.0


def landmarks_feature_collection(
    lmap: LandmarkMap,
    epsg: int | None = None,
    geometry: str = "point",
    extras: dict[str, np.ndarray] | None = None,
    circle_vertices: int = 24,
) -> dict:
    """A GeoJSON FeatureCollection (dict) of the landmarks. `epsg` overrides the map's own (needed when the map
    says 0, a local frame). Coordinates are rounded to 1e-8 degrees (~1 mm); heights are the map's z
    (HEIGHT_REFERENCE: not converted to ellipsoidal); circles across the antimeridian are MultiPolygons
    (`polygon_geometry`)."""
    epsg = int(epsg or lmap.epsg)
    if not epsg:
        raise InputError("the landmark map has no geographic reference (EPSG 0, a local frame): "
                         "give the EPSG code of its world frame if it has one")
    if geometry not in ("point", "circle"):
        raise ValueError(f"geometry must be 'point' or 'circle', got {geometry!r}")
    n = len(lmap)
    lonlat = to_wgs84(lmap.positions[:, :2], epsg) if n else np.zeros((0, 2))
    rings: list[np.ndarray] = []
    if geometry == "circle" and n:
        t = np.linspace(0.0, 2.0 * math.pi, circle_vertices, endpoint=False)
        unit = np.column_stack([np.cos(t), np.sin(t)])
        radius = np.where(np.isfinite(lmap.sizes), CIRCLE_RADIUS_PER_SIZE * lmap.sizes, 0.5).astype(np.float64)
        ring_xy = lmap.positions[:, None, :2] + radius[:, None, None] * unit[None]
        ring_ll = to_wgs84(ring_xy.reshape(-1, 2), epsg).reshape(n, circle_vertices, 2)
        rings = [np.vstack([r, r[:1]]) for r in ring_ll]
    extras = extras or {}
    features = []
    for i in range(n):
        x, y, z = (float(v) for v in lmap.positions[i])
        size = float(lmap.sizes[i])
        props: dict = {"index": i, "size_m": round(size, 3) if math.isfinite(size) else None,
                       "x": round(x, 3), "y": round(y, 3), "z": round(z, 3)}
        for key, values in extras.items():
            value = values[i]
            props[key] = value.item() if hasattr(value, "item") else value
        if geometry == "point":
            geom = {"type": "Point", "coordinates": [round(float(lonlat[i, 0]), 8), round(float(lonlat[i, 1]), 8),
                                                     round(z, 3)]}
        else:
            geom = polygon_geometry(rings[i])
        features.append({"type": "Feature", "id": i, "geometry": geom, "properties": props})
    return {"type": "FeatureCollection",
            "properties": {"source_crs": f"EPSG:{epsg}", "origin": [float(v) for v in lmap.origin],
                           "landmarks": n, "height_reference": HEIGHT_REFERENCE},
            "features": features}


def geojson_text(lmap: LandmarkMap, epsg: int | None = None, geometry: str = "point",
                 extras: dict[str, np.ndarray] | None = None) -> str:
    """The FeatureCollection as compact GeoJSON text."""
    return json.dumps(landmarks_feature_collection(lmap, epsg, geometry, extras), separators=(",", ":")) + "\n"

