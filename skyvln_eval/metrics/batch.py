"""Pack many variable-length view sequences into padded arrays for vectorised metrics.

A padded row repeats its last view, so step lengths, minima and maxima over a row are
those of the real sequence. Empty sequences (a failed episode that never saw its start)
are replaced by a stand-in view chosen by the caller and flagged in ``empty``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.geometry import degrees_to_metres, distance_m, view_centre, view_edge_m

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ViewBatch:
    """``views`` ``(E, K, 4, 2)`` padded by repeating the last view; ``lengths`` ``(E,)``."""

    views: FloatArray
    lengths: NDArray[np.int64]
    empty: NDArray[np.bool_]

    @property
    def last(self) -> FloatArray:
        """The last real view of each row, ``(E, 4, 2)``."""
        return self.views[np.arange(len(self.views)), np.maximum(self.lengths, 1) - 1]

    @property
    def mask(self) -> NDArray[np.bool_]:
        """``(E, K)``: True where a view is real (not padding)."""
        k = np.arange(self.views.shape[1])
        return k[None, :] < np.maximum(self.lengths, 1)[:, None]

    def centres(self) -> FloatArray:
        return view_centre(self.views)

    def points_m(self, distance: str, origin: FloatArray) -> FloatArray:
        """View centres in flat metres ``(E, K, 2)`` from each row's ``origin`` ``(E, 2)``
        (``[lat, lng]``), or ``(E, K, 3)`` with height edge/2. From a nearby origin, not
        from (0, 0): metres of absolute positions (~5e6 m) would cancel digits in every
        difference taken later."""
        xy = degrees_to_metres(self.centres() - origin[:, None, :])
        if distance == "2d":
            return np.asarray(xy)
        height = np.asarray(view_edge_m(self.views)) / 2.0
        return np.concatenate([xy, height[..., None]], axis=-1)


def pack_views(
    sequences: Sequence[FloatArray], stand_ins: Sequence[FloatArray] | None = None
) -> ViewBatch:
    """Pad ``(K_e, 4, 2)`` sequences into one batch; empty ones use ``stand_ins[e]``."""
    n = len(sequences)
    lengths = np.array([len(s) for s in sequences], dtype=np.int64)
    empty = lengths == 0
    width = max(1, int(lengths.max(initial=1)))
    views = np.empty((n, width, 4, 2), dtype=np.float64)
    for e, seq in enumerate(sequences):
        k = len(seq)
        if k == 0:
            if stand_ins is None:
                raise ValueError("an empty sequence needs a stand-in view")
            views[e, :] = stand_ins[e]
            continue
        views[e, :k] = seq
        views[e, k:] = seq[k - 1]
    return ViewBatch(views=views, lengths=lengths, empty=empty)


def step_distances_m(centres: FloatArray) -> FloatArray:
    """Official distances (metres) between consecutive ``[lat, lng]`` centres along axis 1
    of ``(E, K, 2)``: ``(E, K - 1)`` (padding, which repeats the last view, adds 0)."""
    return np.asarray(distance_m(centres[:, 1:], centres[:, :-1])).reshape(len(centres), -1)


def path_lengths(points: FloatArray) -> FloatArray:
    """Sum of consecutive step lengths along axis 1 of ``(E, K, D)`` (padding adds 0)."""
    if points.shape[1] < 2:
        return np.zeros(points.shape[0])
    return np.asarray(np.linalg.norm(np.diff(points, axis=1), axis=-1).sum(axis=1))
