"""Intersection over union of every cross-session footprint pair, vectorised with shapely 2.

An STRtree on one list finds the intersecting pairs (most pairs of a long flight do not touch), and the
intersection areas of only those pairs are computed in one vectorised shapely call.
"""

from __future__ import annotations

import numpy as np
import shapely


def iou_matrix(polys_a: np.ndarray, polys_b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) float64 IoU of two arrays of shapely polygons; 0 where they do not intersect."""
    polys_a = np.asarray(polys_a, dtype=object)
    polys_b = np.asarray(polys_b, dtype=object)
    out = np.zeros((len(polys_a), len(polys_b)))
    if len(polys_a) == 0 or len(polys_b) == 0:
        return out
    area_a, area_b = shapely.area(polys_a), shapely.area(polys_b)
    tree = shapely.STRtree(polys_b)
    ia, ib = tree.query(polys_a, predicate="intersects")
    if len(ia) == 0:
        return out
    inter = shapely.area(shapely.intersection(polys_a[ia], polys_b[ib]))
    union = area_a[ia] + area_b[ib] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        out[ia, ib] = np.where(union > 0, inter / union, 0.0)
    return out
