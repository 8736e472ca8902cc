"""R2R / VLN-CE family on view centres in metres, vectorised over episodes.

Points are view centres in flat metres (2-D), or with a height of ``edge_m / 2`` (3-D),
as :class:`~skyvln_eval.metrics.conventions.MetricConventions` says. With ``P`` the
visited points, ``R`` the ground-truth points and ``d_th`` the threshold:

- TL: path length of ``P``; NE: ``|P_last - R_last|``;
- SR: NE < d_th (``<=`` when not strict); OSR: ``min_k |P_k - R_last|`` under d_th;
- SPL: SR * L_R / max(TL, L_R), with ``L_R`` the ground-truth path length; 0 when L_R = 0;
- nDTW: exp(-DTW(P, R) / (|R| * d_th)), exact DTW with Euclidean cost; SDTW = SR * nDTW;
- CLS: PC * LS with PC = mean_r exp(-d(r, P) / d_th), EPL = PC * L_R,
  LS = EPL / (EPL + |EPL - TL|), and LS = 1 when EPL = TL (both 0 included).

Explicit rules: failed episodes and empty paths have SR = OSR = SPL = SDTW = 0; an empty
path stands at the ground-truth start for NE and TL = 0, and has nDTW = CLS = 0. So has
an episode that ended in error, whatever it flew (``errored``): its path fidelity is the
failure's, not the agent's, and one that raised (no views) and one whose model never
answered (the start view) score alike. Its TL and NE still describe where it went.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.metrics.batch import ViewBatch, path_lengths
from skyvln_eval.metrics.conventions import MetricConventions

FloatArray = NDArray[np.float64]

R2R_COLUMNS: dict[str, str] = {
    "r2r_tl_m": "m",
    "r2r_ne_m": "m",
    "r2r_sr": "0/1",
    "r2r_osr": "0/1",
    "r2r_spl": "fraction",
    "ndtw": "fraction",
    "sdtw": "fraction",
    "cls": "fraction",
}

_CHUNK_CELLS = 4_000_000  # cost-matrix cells per DTW chunk (~32 MB of float64)


def _chunks(p_len: NDArray[np.int64], r_len: NDArray[np.int64]) -> list[slice]:
    """Consecutive slices of size-sorted episodes: bounded cells, little padding waste."""
    slices = []
    start = 0
    kmax = nmax = 1
    for e in range(len(p_len)):
        k, m = max(kmax, int(p_len[e])), max(nmax, int(r_len[e]))
        first = int(p_len[start]) * int(r_len[start])
        if e > start and ((e + 1 - start) * k * m > _CHUNK_CELLS or k * m > 2 * first):
            slices.append(slice(start, e))
            start, k, m = e, int(p_len[e]), int(r_len[e])
        kmax, nmax = k, m
    if len(p_len):
        slices.append(slice(start, len(p_len)))
    return slices


def dtw_and_coverage(
    points: FloatArray,
    p_len: NDArray[np.int64],
    ref: FloatArray,
    r_len: NDArray[np.int64],
    d_th: float,
) -> tuple[FloatArray, FloatArray]:
    """Exact DTW and CLS path coverage of ``points[e, :p_len[e]]`` against ``ref[e, :r_len[e]]``.

    DTW is the classic recurrence D[i, j] = c[i, j] + min(D[i-1, j], D[i, j-1],
    D[i-1, j-1]) with Euclidean cost c, run cell by cell but vectorised over episodes;
    coverage is mean_j exp(-min_i c[i, j] / d_th). Episodes are sorted by size and
    chunked so one long episode does not pad all the others. Lengths must be >= 1, and
    padding must repeat the last point (as :func:`~.batch.pack_views` does).
    """
    n = len(points)
    dtw = np.empty(n)
    coverage = np.empty(n)
    order = np.lexsort((r_len, p_len))
    for part in _chunks(p_len[order], r_len[order]):
        idx = order[part]
        kmax, nmax = int(p_len[idx].max()), int(r_len[idx].max())
        cost = np.linalg.norm(points[idx, :kmax, None, :] - ref[idx, None, :nmax, :], axis=-1)
        acc = np.empty_like(cost)
        acc[:, 0, :] = np.cumsum(cost[:, 0, :], axis=1)
        for i in range(1, kmax):
            acc[:, i, 0] = cost[:, i, 0] + acc[:, i - 1, 0]
            for j in range(1, nmax):
                best = np.minimum(
                    np.minimum(acc[:, i - 1, j], acc[:, i, j - 1]), acc[:, i - 1, j - 1]
                )
                acc[:, i, j] = cost[:, i, j] + best
        rows = np.arange(len(idx))
        dtw[idx] = acc[rows, p_len[idx] - 1, r_len[idx] - 1]
        nearest = cost.min(axis=1)  # padding repeats the last point, so this is exact
        real = np.arange(nmax)[None, :] < r_len[idx][:, None]
        coverage[idx] = np.where(real, np.exp(-nearest / d_th), 0.0).sum(axis=1) / r_len[idx]
    return dtw, coverage


def dtw_distance(
    points: FloatArray, p_len: NDArray[np.int64], ref: FloatArray, r_len: NDArray[np.int64]
) -> FloatArray:
    """Exact DTW distances only (see :func:`dtw_and_coverage`)."""
    return dtw_and_coverage(points, p_len, ref, r_len, 1.0)[0]


def _under(distance: FloatArray, conventions: MetricConventions) -> NDArray[np.bool_]:
    if conventions.strict_threshold:
        return distance < conventions.threshold_m
    return distance <= conventions.threshold_m


def r2r_metrics(
    visited: ViewBatch,
    gt: ViewBatch,
    ok: NDArray[np.bool_],
    conventions: MetricConventions,
    errored: NDArray[np.bool_] | None = None,
) -> dict[str, FloatArray]:
    """R2R-family per-episode metrics (see the module docstring); arrays ``(E,)``.
    ``ok``: the episodes a success can count for; ``errored``: those that ended in error
    (nDTW and CLS 0)."""
    n = len(ok)
    rows = np.arange(n)
    d_th = conventions.threshold_m
    origin = gt.centres()[:, 0]  # one origin for both paths of an episode
    p = visited.points_m(conventions.distance, origin)
    r = gt.points_m(conventions.distance, origin)
    p_len = np.maximum(visited.lengths, 1)
    r_len = np.maximum(gt.lengths, 1)
    goal = r[rows, r_len - 1]

    tl = np.where(visited.empty, 0.0, path_lengths(p))
    ref_len = path_lengths(r)
    ne = np.linalg.norm(p[rows, p_len - 1] - goal, axis=-1)
    to_goal = np.where(visited.mask, np.linalg.norm(p - goal[:, None, :], axis=-1), np.inf)
    sr = _under(ne, conventions) & ok
    osr = _under(to_goal.min(axis=1), conventions) & ok
    with np.errstate(divide="ignore", invalid="ignore"):
        spl = np.where(ref_len > 0, sr * ref_len / np.maximum(tl, ref_len), 0.0)

    dtw, coverage = dtw_and_coverage(p, p_len, r, r_len, d_th)
    no_fidelity = visited.empty if errored is None else visited.empty | errored
    ndtw = np.where(no_fidelity, 0.0, np.exp(-dtw / (r_len * d_th)))
    epl = coverage * ref_len
    denom = epl + np.abs(epl - tl)
    with np.errstate(divide="ignore", invalid="ignore"):
        length_score = np.where(denom > 0, epl / denom, 1.0)
    cls = np.where(no_fidelity, 0.0, coverage * length_score)

    return {
        "r2r_tl_m": tl,
        "r2r_ne_m": ne,
        "r2r_sr": sr.astype(np.float64),
        "r2r_osr": osr.astype(np.float64),
        "r2r_spl": spl,
        "ndtw": ndtw,
        "sdtw": sr * ndtw,
        "cls": cls,
    }
