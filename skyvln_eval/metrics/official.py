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

Explicit rules: an ``error`` episode and an episode with no visited view never succeed
(success, oracle success, SPL = 0); an empty path is scored as if the agent stayed at
the ground-truth start G_0 (NE = D_net, GP = 0, L_pred = 0). Degenerate (zero-area)
views have hull-IoU 0. Inputs are finite by construction, so every output is finite.

The official per-dialog-count buckets, the attention "recall" (which reports precision)
and the batch-padding-dependent evaluation order are deliberately not reproduced. Nor is
the official code's float32 store of each IoU (its teacher's ``progress`` array), which
makes its two thresholds read "float32(IoU) >= float32(0.4)": an IoU within 3e-9 below
0.4 succeeds there, and one of exactly 0.4 is an oracle success. The tests here are
AVDN.md's, on the float64 IoU; the two differ only in that band, where no fixture
episode lies.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import SUCCESS_IOU
from skyvln_eval.avdn.geometry import distance_m, hull_iou, point_in_view_strict
from skyvln_eval.metrics.batch import ViewBatch, step_distances_m
from skyvln_eval.metrics.view_overlap import sparse_hull_iou

FloatArray = NDArray[np.float64]

#: SPL's floor on the denominator, metres (official).
SPL_MIN_DENOMINATOR_M = 0.01

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


def view_success(final_view: FloatArray, gt_end_view: FloatArray) -> bool:
    """AVDN success of one episode's final view: :func:`official_success` for one pair."""
    final = np.asarray(final_view, dtype=np.float64)[None]
    gt_end = np.asarray(gt_end_view, dtype=np.float64)[None]
    iou = np.atleast_1d(hull_iou(final, gt_end))
    return bool(official_success(final, gt_end, iou)[0])


def official_metrics(
    visited: ViewBatch, gt: ViewBatch, ok: NDArray[np.bool_], legacy_gp: bool = False
) -> dict[str, FloatArray]:
    """Official per-episode metrics for ``E`` episodes (see the module docstring).

    ``visited`` must use G_0 as the stand-in for empty paths; ``ok`` is False for
    episodes that cannot succeed (status error or empty path). Returns float arrays
    ``(E,)`` keyed as :data:`OFFICIAL_COLUMNS`.
    """
    n = len(ok)
    rows = np.arange(n)
    p_last, g_last = visited.last, gt.last
    p_c, g_c = visited.centres(), gt.centres()
    g_last_c = g_c[rows, np.maximum(gt.lengths, 1) - 1]
    p_last_c = p_c[rows, np.maximum(visited.lengths, 1) - 1]

    d_net = np.asarray(distance_m(g_c[:, 0], g_last_c))
    # Each step's distance as the spec defines it (the norm of a degree difference, times
    # 111,300): metres of absolute positions (~5e6 m) would cancel digits in the difference.
    path_len = np.where(visited.empty, 0.0, step_distances_m(p_c).sum(axis=1))
    gt_len = step_distances_m(g_c).sum(axis=1)

    # Final views: the official definition to the last bit (a reported column). Earlier
    # views matter only through "max IoU > 0.4", so pairs that provably cannot exceed 0.4
    # are not computed, and the rest by the fast path (exact where it nears 0.4).
    last_k = np.maximum(visited.lengths, 1) - 1
    final_iou = sparse_hull_iou(p_last, g_last, exact=True)
    mask = visited.mask
    earlier = mask.copy()
    earlier[rows, last_k] = False
    # Where the final view already exceeds the threshold, oracle success is settled and
    # the earlier views need no IoU at all.
    earlier[final_iou > SUCCESS_IOU] = False
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
