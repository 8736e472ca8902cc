"""Official AVDN (ANDH) metrics, exactly as AVDN.md states them, vectorised over episodes.

With ``P_0..P_{K-1}`` the visited views (``P_0`` the start), ``G_0..G_{N-1}`` the ground
truth, ``c()`` the centre and ``d()`` the flat 111,300 m/deg distance:

- success: hull-IoU(P_last, G_last) >= 0.4 AND c(G_last) strictly inside P_last AND
  c(P_last) strictly inside G_last;
- oracle success: max_k hull-IoU(P_k, G_last) > 0.4 (strict), start included, no centre
  checks;
- D_net = d(c(G_0), c(G_last)); SPL = S * D_net / max(L_pred, D_net, 0.01), 0 when
  D_net = 0, with L_pred the sum of centre-to-centre steps;
- GP = D_net - d(c(P_last), c(G_last)) (metres, may be negative); oracle GP uses the
  minimum over visited views; ``legacy_gp`` uses G[N-2] (G[0] when N = 1) as the
  official code did until November 2023;
- NE = d(c(P_last), c(G_last)) (not official in AVDN, defined here).

Explicit rules: a ``failed`` episode and an episode with no visited view never succeed
(success, oracle success, SPL = 0); an empty path is scored as if the agent stayed at
the ground-truth start G_0 (NE = D_net, GP = 0, L_pred = 0). Degenerate (zero-area)
views have hull-IoU 0. Inputs are finite by construction, so every output is finite.

The official per-dialog-count buckets, the attention "recall" (which reports precision)
and the batch-padding-dependent evaluation order are deliberately not reproduced.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import SUCCESS_IOU
from skyvln_eval.avdn.geometry import degrees_to_metres, distance_m, hull_iou, point_in_view_strict
from skyvln_eval.metrics.batch import ViewBatch, path_lengths

FloatArray = NDArray[np.float64]

#: SPL's floor on the denominator, metres (official).
SPL_MIN_DENOMINATOR_M = 0.01

_IOU_BLOCK = 8192

#: Columns :func:`official_metrics` returns, with their units.
OFFICIAL_COLUMNS: dict[str, str] = {
    "success": "0/1",
    "oracle_success": "0/1",
    "spl": "fraction",
    "gp_m": "m",
    "oracle_gp_m": "m",
    "ne_m": "m",
    "final_iou": "hull-IoU",
    "path_length_m": "m",
    "gt_length_m": "m",
    "d_net_m": "m",
}


def _circumradius(views: FloatArray) -> FloatArray:
    centre = views.mean(axis=-2, keepdims=True)
    return np.asarray(np.linalg.norm(views - centre, axis=-1).max(axis=-1))


def _hull_area_of_quads(views: FloatArray) -> FloatArray:
    """Area of the convex hull of each view's 4 corners (any corner order)."""
    # Relative to the centre: absolute degrees (~30, 40) would cancel away the area.
    local = views - views.mean(axis=-2, keepdims=True)

    def shoelace(*idx: int) -> FloatArray:
        x, y = local[..., idx, 0], local[..., idx, 1]
        return np.abs((x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(axis=-1)) / 2

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
    area_a, area_b = _hull_area_of_quads(a), _hull_area_of_quads(b)
    gap = np.linalg.norm(a.mean(axis=-2) - b.mean(axis=-2), axis=-1)
    lens = _lens_area(_circumradius(a), _circumradius(b), gap)
    inter = np.minimum(np.minimum(area_a, area_b), lens)
    union = area_a + area_b - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def sparse_hull_iou(a: FloatArray, b: FloatArray, needed_above: float | None = None) -> FloatArray:
    """Official hull-IoU of paired views ``(M, 4, 2)``, with shapely only where needed.

    Views whose circumscribed circles do not overlap share no area: their hull-IoU is
    exactly 0 and shapely is skipped. With ``needed_above``, pairs whose
    :func:`hull_iou_upper_bound` shows they cannot exceed it are skipped too and
    reported as 0 (use this only when the caller compares with that threshold).
    """
    out = np.zeros(len(a))
    if len(a) == 0:
        return out
    gap = np.linalg.norm(a.mean(axis=-2) - b.mean(axis=-2), axis=-1)
    reach = (_circumradius(a) + _circumradius(b)) * (1.0 + 1e-9)
    keep = gap < reach
    if needed_above is not None:
        # A relative margin keeps float error in the bound on the safe side.
        keep &= hull_iou_upper_bound(a, b) * (1.0 + 1e-6) > needed_above
    candidates = np.flatnonzero(keep)
    # Blocks of a few thousand pairs: shapely's vectorised calls slow down per pair on
    # very large arrays (measured ~1.5x at 60,000 pairs).
    for start in range(0, len(candidates), _IOU_BLOCK):
        block = candidates[start : start + _IOU_BLOCK]
        out[block] = hull_iou(a[block], b[block])
    return out


def official_success(
    p_last: FloatArray, g_last: FloatArray, final_iou: FloatArray
) -> NDArray[np.bool_]:
    """Official success test on paired final views, given their hull-IoU."""
    success = final_iou >= SUCCESS_IOU
    idx = np.flatnonzero(success)
    if len(idx):
        # Centre checks only where the IoU test passed: the rest fail anyway.
        g_in_p = point_in_view_strict(g_last[idx].mean(axis=-2), p_last[idx])
        p_in_g = point_in_view_strict(p_last[idx].mean(axis=-2), g_last[idx])
        success[idx] = np.asarray(g_in_p) & np.asarray(p_in_g)
    return success


def official_metrics(
    visited: ViewBatch, gt: ViewBatch, ok: NDArray[np.bool_], legacy_gp: bool = False
) -> dict[str, FloatArray]:
    """Official per-episode metrics for ``E`` episodes (see the module docstring).

    ``visited`` must use G_0 as the stand-in for empty paths; ``ok`` is False for
    episodes that cannot succeed (failed status or empty path). Returns float arrays
    ``(E,)`` keyed as :data:`OFFICIAL_COLUMNS`.
    """
    n = len(ok)
    rows = np.arange(n)
    p_last, g_last = visited.last, gt.last
    p_c, g_c = visited.centres(), gt.centres()
    g_last_c = g_c[rows, np.maximum(gt.lengths, 1) - 1]
    p_last_c = p_c[rows, np.maximum(visited.lengths, 1) - 1]

    d_net = np.asarray(distance_m(g_c[:, 0], g_last_c))
    path_len = path_lengths(np.asarray(degrees_to_metres(p_c)))
    path_len = np.where(visited.empty, 0.0, path_len)
    gt_len = path_lengths(np.asarray(degrees_to_metres(g_c)))

    # Final views: exact hull-IoU (a reported column). Earlier views matter only through
    # "max IoU > 0.4", so pairs that provably cannot exceed 0.4 are not computed exactly.
    last_k = np.maximum(visited.lengths, 1) - 1
    final_iou = sparse_hull_iou(p_last, g_last)
    mask = visited.mask
    earlier = mask.copy()
    earlier[rows, last_k] = False
    flat_e, flat_k = np.nonzero(earlier)
    pair_iou = sparse_hull_iou(visited.views[flat_e, flat_k], g_last[flat_e], SUCCESS_IOU)
    best_earlier = np.zeros(n)
    np.maximum.at(best_earlier, flat_e, pair_iou)
    max_iou = np.maximum(final_iou, best_earlier)

    success = official_success(p_last, g_last, final_iou) & ok
    oracle = (max_iou > SUCCESS_IOU) & ok
    with np.errstate(divide="ignore", invalid="ignore"):
        spl = np.where(
            d_net > 0,
            success * d_net / np.maximum(np.maximum(path_len, d_net), SPL_MIN_DENOMINATOR_M),
            0.0,
        )

    ne = np.asarray(distance_m(p_last_c, g_last_c))
    if legacy_gp:
        g_ref = g_c[rows, np.maximum(gt.lengths - 2, 0)]
        gp = d_net - np.asarray(distance_m(p_last_c, g_ref))
    else:
        gp = d_net - ne
    dist_all = np.asarray(distance_m(p_c, g_last_c[:, None, :]))
    oracle_gp = d_net - np.where(mask, dist_all, np.inf).min(axis=1)

    return {
        "success": success.astype(np.float64),
        "oracle_success": oracle.astype(np.float64),
        "spl": spl,
        "gp_m": gp,
        "oracle_gp_m": oracle_gp,
        "ne_m": ne,
        "final_iou": final_iou,
        "path_length_m": path_len,
        "gt_length_m": gt_len,
        "d_net_m": d_net,
    }
