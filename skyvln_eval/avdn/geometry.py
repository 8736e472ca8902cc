"""Official AVDN geometry in raw (lat, lng) degrees.

A *view* is an array of shape ``(4, 2)``: corners front-left, front-right, back-right,
back-left, each ``[lat, lng]``. Functions accept stacks of views (``(..., 4, 2)``) where
that is natural. Distances use the flat 111,300 m per degree of the official code, so a
view that is square in degrees is square in metres too (see DESIGN.md, Frames and units).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE, OFFICIAL_HALF_PI

FloatArray = NDArray[np.float64]


def degrees_to_metres(degrees: ArrayLike) -> Any:
    """Convert a flat degree distance to metres (official 111,300 m/deg)."""
    return np.asarray(degrees, dtype=np.float64) * METERS_PER_DEGREE


def metres_to_degrees(metres: ArrayLike) -> Any:
    """Convert metres to flat degrees (official 111,300 m/deg)."""
    return np.asarray(metres, dtype=np.float64) / METERS_PER_DEGREE


def view_centre(corners: ArrayLike) -> FloatArray:
    """Centre of a view (mean of its 4 corners), ``[lat, lng]``; ``(..., 4, 2) -> (..., 2)``."""
    return np.asarray(corners, dtype=np.float64).mean(axis=-2)


def view_edge_m(corners: ArrayLike) -> Any:
    """Edge length of a view in metres, measured front-left to front-right as officially."""
    c = np.asarray(corners, dtype=np.float64)
    return np.linalg.norm(c[..., 0, :] - c[..., 1, :], axis=-1) * METERS_PER_DEGREE


def distance_m(a: ArrayLike, b: ArrayLike) -> Any:
    """Flat distance in metres between ``[lat, lng]`` points (broadcasting)."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return np.linalg.norm(d, axis=-1) * METERS_PER_DEGREE


def official_bearing_deg(start: ArrayLike, end: ArrayLike) -> Any:
    """Compass bearing (0 = north, clockwise) from ``start`` to ``end``, official formula.

    The official code computes ``arctan(dlat / dlng) / 1.57 * 90`` (not ``/ (pi / 2)``),
    adds 180 when ``dlng < 0`` and uses 90 / 270 when ``dlng == 0``. The 1.57 makes the
    result differ from the exact bearing by up to 0.05 degree, which decides the rounding
    of stored headings, so it is reproduced here. Vectorised over leading axes.
    """
    vec = np.asarray(end, dtype=np.float64) - np.asarray(start, dtype=np.float64)
    dlat, dlng = vec[..., 0], vec[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        math_angle = np.arctan(dlat / dlng) / OFFICIAL_HALF_PI * 90.0
    math_angle = np.where(dlng < 0, math_angle + 180.0, math_angle)
    math_angle = np.where(dlng == 0, np.where(dlat > 0, 90.0, 270.0), math_angle)
    bearing = (450.0 - math_angle) % 360.0
    return bearing if bearing.ndim else float(bearing)


def view_heading_deg(corners: ArrayLike) -> Any:
    """Official heading of a view: bearing from its centre to the middle of its front edge.

    Returns a float in [0, 360) (not rounded); the official step rounds it with
    ``round(h) % 360``.
    """
    c = np.asarray(corners, dtype=np.float64)
    front_mid = (c[..., 0, :] + c[..., 1, :]) / 2.0
    return official_bearing_deg(view_centre(c), front_mid)


def view_axes(corners: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Unit forward and right vectors of a view in degree space, ``[lat, lng]`` each.

    Exact geometry (no official constants): forward points from the centre to the middle
    of the front edge, right from the centre to the middle of the right edge.
    """
    c = np.asarray(corners, dtype=np.float64)
    centre = c.mean(axis=-2)
    forward = (c[..., 0, :] + c[..., 1, :]) / 2.0 - centre
    right = (c[..., 1, :] + c[..., 2, :]) / 2.0 - centre
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    right = right / np.linalg.norm(right, axis=-1, keepdims=True)
    return forward, right


def view_from_pose(centre: ArrayLike, heading_deg: float, edge_m: float) -> FloatArray:
    """The square view with this centre ``[lat, lng]``, compass heading and edge (exact)."""
    lat, lng = (float(v) for v in np.asarray(centre, dtype=np.float64))
    half = edge_m / 2.0 / METERS_PER_DEGREE
    h = math.radians(heading_deg)
    fwd = np.array([math.cos(h), math.sin(h)]) * half  # [dlat, dlng] of a compass heading
    right = np.array([-math.sin(h), math.cos(h)]) * half
    c = np.array([lat, lng])
    return np.stack([c + fwd - right, c + fwd + right, c - fwd + right, c - fwd - right])


def _polygons(corners: ArrayLike) -> Any:
    c = np.asarray(corners, dtype=np.float64)
    return shapely.polygons(c.reshape(-1, 4, 2)).reshape(c.shape[:-2])


def hull_iou(a: ArrayLike, b: ArrayLike) -> Any:
    """Official hull-IoU: area(A intersect B) / area(convex hull of all 8 corners).

    Not the usual union: the denominator is the convex hull of both views' corners, so
    it is never larger than the usual IoU. 0 when the views do not intersect. Works on
    single views (``(4, 2)`` each, returns a float) or stacks (``(n, 4, 2)``, returns an
    array), with shapely's vectorised operations.
    """
    a_arr = np.asarray(a, dtype=np.float64)
    b_arr = np.asarray(b, dtype=np.float64)
    a_arr, b_arr = np.broadcast_arrays(a_arr, b_arr)
    poly_a = shapely.convex_hull(_polygons(a_arr))
    poly_b = shapely.convex_hull(_polygons(b_arr))
    inter = shapely.area(shapely.intersection(poly_a, poly_b))
    both = np.concatenate([a_arr, b_arr], axis=-2)
    # The hull of the 8 corners, built from a ring through them: GEOS hulls the
    # coordinates whatever the geometry type, and a ring is ~10x cheaper to make than a
    # multipoint (bit-identical areas).
    hull = shapely.area(shapely.convex_hull(shapely.linearrings(both.reshape(-1, 8, 2))))
    hull = np.asarray(hull).reshape(both.shape[:-2])
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(hull > 0, np.asarray(inter) / hull, 0.0)
    iou = np.where(np.isfinite(iou), iou, 0.0)
    return float(iou) if iou.ndim == 0 else iou


def point_in_view_strict(point: ArrayLike, corners: ArrayLike) -> Any:
    """Whether ``point`` lies strictly inside the view (its boundary excluded).

    The official success test uses shapely's ``Polygon.contains(Point)``, which is false
    on the boundary; this is the same predicate, vectorised.
    """
    pts = shapely.points(np.asarray(point, dtype=np.float64))
    inside = shapely.contains(_polygons(corners), pts)
    return bool(inside) if np.ndim(inside) == 0 else np.asarray(inside)
