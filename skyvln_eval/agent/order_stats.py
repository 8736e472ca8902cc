"""Column medians and percentiles of small point blocks, as numpy gives them, bit for bit.

Perception places every detection at the median of its pixels' ground points and sizes it
by their 5-95 % spread, several times per view. ``np.median`` and ``np.percentile`` spend a
third of their time there on argument handling and generic paths; these functions make
the partitions numpy makes (the same kth) and combine the values with numpy's own
arithmetic (tests compare them with numpy bit for bit, signed zeros included):

- the median is the middle value, or for an even count the sum of the two middle values
  halved (the sum starts from 0.0, as numpy's does);
- a percentile ``p`` (the "linear" method, numpy's default) sits at the virtual index
  ``(n - 1) * (p / 100)`` between the sorted values ``a`` (its floor) and ``b`` (the next):
  ``a + (b - a) * g`` with ``g`` the fractional part, or ``b - (b - a) * (1 - g)`` when
  ``g >= 0.5``; at or past the last index it is the largest value.

A block with NaN (never, from finite depth) is handed to numpy, whose NaN rules then hold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray


def _columns(block: NDArray[np.float64]) -> NDArray[np.float64]:
    """The block's columns as contiguous rows: numpy partitions a column in a contiguous
    copy anyway, so the same values meet the same algorithm, without the strided copies."""
    return np.ascontiguousarray(block.T)


def _medians(columns: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.median(block, axis=0)`` of a non-empty block without NaN, from its
    :func:`_columns`."""
    k = columns.shape[1]
    middle = [(k - 1) // 2] if k % 2 else [k // 2 - 1, k // 2]
    part = np.partition(columns, [*middle, -1], axis=1)  # numpy's kth, -1 for its NaN check
    # np.mean of the middle value(s): a sum that starts from 0.0 (so -0.0 becomes 0.0),
    # divided by the count.
    total = 0.0 + part[:, middle[0]]
    if k % 2:
        return total
    return (total + part[:, middle[1]]) / 2.0


def column_medians(block: NDArray[np.float64]) -> tuple[float, float]:
    """``np.median(block, axis=0)`` of a ``(k, 2)`` block; NaN medians when it is empty."""
    if len(block) == 0:
        return math.nan, math.nan
    median = np.median(block, axis=0) if np.isnan(block).any() else _medians(_columns(block))
    return float(median[0]), float(median[1])


def column_median_and_percentiles(
    block: NDArray[np.float64], percents: Sequence[float]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``np.median(block, axis=0)`` and ``np.percentile(block, percents, axis=0)`` of a
    non-empty ``(k, c)`` block."""
    k = len(block)
    if k == 0:
        raise ValueError("the medians and percentiles of an empty block are undefined")
    if np.isnan(block).any():
        return np.median(block, axis=0), np.percentile(block, list(percents), axis=0)
    virtual = (k - 1) * (np.asarray(percents, dtype=np.float64) / 100)
    # numpy's bookkeeping, kept as it is because the fraction depends on it: at or past
    # the last index both neighbours are the last value (index -1), and the fraction is
    # measured from -1.
    previous = np.floor(virtual)
    following = previous + 1
    past_end = virtual >= k - 1
    previous[past_end] = following[past_end] = -1
    gamma = virtual - previous
    below, above = previous.astype(np.intp), following.astype(np.intp)
    # The partition numpy makes: which of two equal values (0.0 and -0.0) lands where
    # depends on it.
    columns = _columns(block)
    kth = np.unique(np.concatenate(([0, -1], below, above)))
    part = np.partition(columns, kth, axis=1)
    a, b = part[:, below].T, part[:, above].T
    diff = b - a
    g = gamma[:, None]
    values = a + diff * g
    np.subtract(b, diff * (1 - g), out=values, where=g >= 0.5)
    return _medians(columns), values
