"""The official hull-IoU of many view pairs at once, fast enough for 100,000 episodes.

The official definition (:func:`skyvln_eval.avdn.geometry.hull_iou`) runs shapely on
every pair; scoring a large run spent most of its time there. Here:

- pairs whose circumscribed circles do not meet share no area: IoU exactly 0, no work;
- the intersection of two convex quadrilaterals is computed in numpy: its vertices are
  the corners of each view inside the other and the crossings of their edges, all on its
  boundary, so sorting them by angle and applying the shoelace formula gives its area;
- the hull of the 8 corners stays with GEOS (built from a ring, which is cheap);
- coordinates are taken relative to the first view's centre, which loses less precision
  than the official absolute degrees do.

The result agrees with the shapely definition to about 1e-12; wherever it lands within
:data:`THRESHOLD_BAND` of the success threshold, and wherever a view is not a convex
quadrilateral in corner order, the shapely definition itself is used, so success and
oracle-success decisions are exactly those of the shapely definition (AVDN.md's rules on
the float64 IoU; see :mod:`skyvln_eval.metrics.official` for the official code's float32
store, which differs within 3e-9 of the threshold).
"""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import SUCCESS_IOU
from skyvln_eval.avdn.geometry import hull_iou

FloatArray = NDArray[np.float64]

#: Fast values this close to the success threshold are recomputed with shapely.
THRESHOLD_BAND = 1e-9

#: Pairs per vectorised block (bounds the (M, 24, 2) temporaries to a few MB).
_BLOCK = 8192

#: Closed-boundary tolerance in units of the first view's circumradius: a point this far
#: outside still counts as on the boundary, which can add at most ~1e-12 of area but
#: never drops a vertex of the intersection to rounding.
_EDGE_TOLERANCE = 1e-12


def _signed_areas(polygons: FloatArray) -> FloatArray:
    """Shoelace area of each polygon ``(..., K, 2)``: positive when counter-clockwise."""
    x, y = polygons[..., 0], polygons[..., 1]
    return np.asarray((x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(-1) / 2)


def circumradius(views: FloatArray) -> FloatArray:
    """Distance from each view's centre to its farthest corner."""
    centre = views.mean(axis=-2, keepdims=True)
    return np.asarray(np.linalg.norm(views - centre, axis=-1).max(axis=-1))


def hull_area_of_quads(views: FloatArray) -> FloatArray:
    """Area of the convex hull of each view's 4 corners (any corner order)."""
    # Relative to the centre: absolute degrees (~30, 40) would cancel away the area.
    local = views - views.mean(axis=-2, keepdims=True)

    def shoelace(*idx: int) -> FloatArray:
        return np.abs(_signed_areas(local[..., idx, :]))

    # The hull is the largest of the three cyclic quads and the four triangles.
    candidates = [shoelace(0, 1, 2, 3), shoelace(0, 2, 1, 3), shoelace(0, 1, 3, 2)]
    candidates += [shoelace(0, 1, 2), shoelace(0, 1, 3), shoelace(0, 2, 3), shoelace(1, 2, 3)]
    return np.asarray(np.max(candidates, axis=0))


def _lens_area(r1: FloatArray, r2: FloatArray, d: FloatArray) -> FloatArray:
    """Area shared by two discs of radii ``r1``, ``r2`` whose centres are ``d`` apart."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a1 = np.arccos(np.clip((d**2 + r1**2 - r2**2) / (2 * d * r1), -1, 1))
        a2 = np.arccos(np.clip((d**2 + r2**2 - r1**2) / (2 * d * r2), -1, 1))
        k = (-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)
        lens = r1**2 * a1 + r2**2 * a2 - 0.5 * np.sqrt(np.maximum(k, 0.0))
    lens = np.where(d <= np.abs(r1 - r2), np.pi * np.minimum(r1, r2) ** 2, lens)
    return np.where(d >= r1 + r2, 0.0, np.nan_to_num(lens))


def hull_iou_upper_bound(a: FloatArray, b: FloatArray) -> FloatArray:
    """An upper bound of the official hull-IoU of paired views, without shapely.

    The intersection lies in both views and in the lens of their circumscribed discs,
    so it is at most I = min(area A, area B, lens); the hull holds the union, so it is at
    least A + B - I. Hence hull-IoU <= I / (A + B - I). Used to skip exact IoUs that
    cannot pass a threshold; never to report a value.
    """
    area_a, area_b = hull_area_of_quads(a), hull_area_of_quads(b)
    gap = np.linalg.norm(a.mean(axis=-2) - b.mean(axis=-2), axis=-1)
    lens = _lens_area(circumradius(a), circumradius(b), gap)
    inter = np.minimum(np.minimum(area_a, area_b), lens)
    union = area_a + area_b - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def _cross(ax: FloatArray, ay: FloatArray, bx: FloatArray, by: FloatArray) -> FloatArray:
    return np.asarray(ax * by - ay * bx)


def _strictly_convex(quads: FloatArray) -> NDArray[np.bool_]:
    """Counter-clockwise quads whose every corner turns left (no bow-ties, no slivers)."""
    edges = np.roll(quads, -1, axis=1) - quads
    nxt = np.roll(edges, -1, axis=1)
    turns = _cross(edges[..., 0], edges[..., 1], nxt[..., 0], nxt[..., 1])
    return np.asarray((turns > 0).all(axis=-1))


def _inside(points: FloatArray, quads: FloatArray, tol: float) -> NDArray[np.bool_]:
    """``(M, P)``: whether each point lies in its (counter-clockwise) quad, boundary included."""
    edges = np.roll(quads, -1, axis=1) - quads  # (M, 4, 2)
    rel = points[:, :, None, :] - quads[:, None, :, :]  # (M, P, 4, 2)
    side = _cross(edges[:, None, :, 0], edges[:, None, :, 1], rel[..., 0], rel[..., 1])
    length = np.linalg.norm(edges, axis=-1)[:, None, :]
    return np.asarray((side >= -tol * length).all(axis=-1))


def _edge_crossings(
    a: FloatArray, b: FloatArray, tol: float
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Crossing points ``(M, 16, 2)`` of every edge of ``a`` with every edge of ``b``."""
    p, r = a[:, :, None, :], (np.roll(a, -1, axis=1) - a)[:, :, None, :]
    q, s = b[:, None, :, :], (np.roll(b, -1, axis=1) - b)[:, None, :, :]
    denom = _cross(r[..., 0], r[..., 1], s[..., 0], s[..., 1])  # (M, 4, 4)
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(qp[..., 0], qp[..., 1], s[..., 0], s[..., 1]) / denom
        u = _cross(qp[..., 0], qp[..., 1], r[..., 0], r[..., 1]) / denom
    # Parallel edges (denom 0) cross nowhere new: their shared points are corners,
    # which the inside tests already supply.
    valid = (denom != 0) & (t >= -tol) & (t <= 1 + tol) & (u >= -tol) & (u <= 1 + tol)
    points = p + np.where(valid, t, 0.0)[..., None] * r
    return points.reshape(len(a), 16, 2), valid.reshape(len(a), 16)


def convex_intersection_area(a: FloatArray, b: FloatArray) -> FloatArray:
    """Area of the intersection of paired counter-clockwise convex quads ``(M, 4, 2)``."""
    tol = _EDGE_TOLERANCE
    crossings, crossing_ok = _edge_crossings(a, b, tol)
    points = np.concatenate([a, b, crossings], axis=1)  # (M, 24, 2)
    valid = np.concatenate([_inside(a, b, tol), _inside(b, a, tol), crossing_ok], axis=1)
    count = valid.sum(axis=1)
    centre = (points * valid[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    rel = points - centre[:, None, :]
    angle = np.where(valid, np.arctan2(rel[..., 1], rel[..., 0]), np.inf)
    order = np.argsort(angle, axis=1, kind="stable")
    ring = np.take_along_axis(rel, order[..., None], axis=1)
    # Invalid points sorted to the end repeat the first valid one: their edges add 0.
    slots = np.arange(points.shape[1])[None, :]
    ring = np.where((slots < count[:, None])[..., None], ring, ring[:, :1, :])
    area = np.abs(_signed_areas(ring))
    return np.asarray(np.where(count >= 3, area, 0.0))


def _fast_hull_iou(a: FloatArray, b: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Hull-IoU of paired views and a mask of pairs the fast path cannot vouch for."""
    origin = a.mean(axis=1, keepdims=True)
    scale = circumradius(a)[:, None, None]
    scale = np.where(scale > 0, scale, 1.0)
    la, lb = (a - origin) / scale, (b - origin) / scale
    # Counter-clockwise corner order for the inside tests.
    la = np.where((_signed_areas(la) < 0)[:, None, None], la[:, ::-1], la)
    lb = np.where((_signed_areas(lb) < 0)[:, None, None], lb[:, ::-1], lb)
    inter = convex_intersection_area(la, lb)
    hull = shapely.area(shapely.convex_hull(shapely.linearrings(np.concatenate([la, lb], 1))))
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(hull > 0, inter / hull, 0.0)
    unsure = ~(_strictly_convex(la) & _strictly_convex(lb)) | ~np.isfinite(iou)
    unsure |= np.abs(iou - SUCCESS_IOU) <= THRESHOLD_BAND
    return np.clip(np.nan_to_num(iou), 0.0, 1.0), unsure


def sparse_hull_iou(
    a: FloatArray, b: FloatArray, needed_above: float | None = None, exact: bool = False
) -> FloatArray:
    """Official hull-IoU of paired views ``(M, 4, 2)``, computed only where needed.

    Views whose circumscribed circles do not overlap share no area: their hull-IoU is
    exactly 0. With ``needed_above``, pairs whose :func:`hull_iou_upper_bound` shows they
    cannot exceed it are skipped too and reported as 0 (use this only when the caller
    compares with that threshold). The rest go through the numpy fast path, with the
    shapely definition where that path cannot vouch for its value (see the module notes),
    or all through the shapely definition with ``exact`` (values reported as they are,
    equal to the official code's to the last bit, at about 2.5x the time).
    """
    out = np.zeros(len(a))
    if len(a) == 0:
        return out
    gap = np.linalg.norm(a.mean(axis=-2) - b.mean(axis=-2), axis=-1)
    reach = (circumradius(a) + circumradius(b)) * (1.0 + 1e-9)
    keep = gap < reach
    if needed_above is not None:
        # A relative margin keeps float error in the bound on the safe side.
        keep &= hull_iou_upper_bound(a, b) * (1.0 + 1e-6) > needed_above
    candidates = np.flatnonzero(keep)
    for start in range(0, len(candidates), _BLOCK):
        block = candidates[start : start + _BLOCK]
        if exact:
            out[block] = hull_iou(a[block], b[block])
            continue
        iou, unsure = _fast_hull_iou(a[block], b[block])
        if unsure.any():
            iou[unsure] = hull_iou(a[block[unsure]], b[block[unsure]])
        out[block] = iou
    return out
