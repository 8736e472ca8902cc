"""Confidence intervals (seeded bootstrap, Wilson score) and paired tests between two systems.

Everything is deterministic for a given ``seed`` (numpy's PCG64 generator); the Wilson
interval is closed form. Empty input and non-finite values raise
:class:`~skyvln_eval.errors.MetricInputError`: an interval over nothing, or over NaN, is
never returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.errors import MetricInputError

FloatArray = NDArray[np.float64]

#: Resampled values gathered per chunk: ~8 MB of indices, small enough to stay in cache
#: (larger chunks measured slower); drawing the random indices is the floor of the cost.
_CHUNK_VALUES = 1_000_000


@dataclass(frozen=True)
class ConfidenceInterval:
    """Mean and percentile-bootstrap interval (same units as the values); ``low`` and
    ``high`` are NaN when the values have no spread (see :func:`percentile_interval`)."""

    mean: float
    low: float
    high: float
    confidence: float
    n: int
    n_resamples: int
    seed: int


@dataclass(frozen=True)
class PairedComparison:
    """System A minus system B on the same episodes.

    ``ci_low`` / ``ci_high``: paired bootstrap interval of the mean difference;
    ``p_value``: two-sided sign-flip permutation test of "no difference", exact (every
    sign pattern) when there are at most ``n_resamples`` patterns, else from random ones
    with the +1 correction; never 0 either way. ``unit``: what was resampled and flipped,
    single episodes or whole trajectories (``n_units`` of them).
    """

    n: int
    mean_a: float
    mean_b: float
    difference: float
    ci_low: float
    ci_high: float
    p_value: float
    confidence: float
    n_resamples: int
    seed: int
    unit: str = "episode"
    n_units: int = 0
    p_exact: bool = False


def finite_values(values: ArrayLike, what: str = "values") -> FloatArray:
    """``values`` as float64, refusing empty input and NaN / inf."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape[0] == 0:
        raise MetricInputError(f"{what}: no values (an average over zero episodes is undefined)")
    finite = np.isfinite(arr)
    if not finite.all():
        raise MetricInputError(
            f"{what}: non-finite values (NaN or inf: {int((~finite).sum())} of {arr.size}) "
            "cannot be averaged"
        )
    return arr


def bootstrap_means(values: ArrayLike, n_resamples: int = 10_000, seed: int = 0) -> FloatArray:
    """Means of ``n_resamples`` resamples (with replacement) of ``values`` ``(n,)`` or ``(n, m)``.

    Returns ``(n_resamples,)`` or ``(n_resamples, m)``. Resampling indices are drawn in
    chunks, so memory stays bounded whatever ``n * n_resamples``.
    """
    arr = finite_values(values)
    if n_resamples < 1:
        raise MetricInputError(f"n_resamples must be at least 1, got {n_resamples}")
    n = arr.shape[0]
    rng = np.random.default_rng(seed)
    width = int(np.prod(arr.shape[1:], dtype=np.int64)) if arr.ndim > 1 else 1
    chunk = max(1, _CHUNK_VALUES // (n * width))
    out = np.empty((n_resamples, *arr.shape[1:]))
    for start in range(0, n_resamples, chunk):
        stop = min(n_resamples, start + chunk)
        idx = rng.integers(
            0, n, size=(stop - start, n), dtype=np.int64
        )  # int64 draws faster than int32
        out[start:stop] = arr[idx].mean(axis=1)
    return out


def cluster_bootstrap_means(
    values: ArrayLike, clusters: ArrayLike, n_resamples: int = 10_000, seed: int = 0
) -> FloatArray:
    """Means of ``n_resamples`` resamples of ``values`` ``(n,)`` or ``(n, m)`` in which whole
    ``clusters`` (one label per value) are drawn with replacement: each resample's mean is
    the sum of its clusters' values over their number of values. For values that are not
    independent within a cluster (the rounds of one AVDN dialog share its route), where
    resampling single values would make the interval too narrow."""
    arr = finite_values(values)
    labels = np.asarray(clusters)
    if labels.shape != arr.shape[:1]:
        raise MetricInputError(f"one cluster label per value: {labels.shape} for {arr.shape}")
    if n_resamples < 1:
        raise MetricInputError(f"n_resamples must be at least 1, got {n_resamples}")
    _, members = np.unique(labels, return_inverse=True)
    n_clusters = int(members.max()) + 1
    flat = arr.reshape(len(arr), -1)
    sums = np.zeros((n_clusters, flat.shape[1]))
    np.add.at(sums, members, flat)
    sizes = np.bincount(members, minlength=n_clusters).astype(np.float64)
    rng = np.random.default_rng(seed)
    chunk = max(1, _CHUNK_VALUES // (n_clusters * flat.shape[1]))
    out = np.empty((n_resamples, flat.shape[1]))
    for start in range(0, n_resamples, chunk):
        stop = min(n_resamples, start + chunk)
        idx = rng.integers(0, n_clusters, size=(stop - start, n_clusters), dtype=np.int64)
        out[start:stop] = sums[idx].sum(axis=1) / sizes[idx].sum(axis=1)[:, None]
    return out.reshape(n_resamples, *arr.shape[1:])


def bootstrap_ci(
    values: ArrayLike, n_resamples: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> ConfidenceInterval:
    """Mean of ``values`` (1-D) with a seeded percentile-bootstrap interval."""
    arr = finite_values(values)
    if arr.ndim != 1:
        raise MetricInputError(f"bootstrap_ci takes 1-D values, got shape {arr.shape}")
    if not 0 < confidence < 1:
        raise MetricInputError(f"confidence must be in (0, 1), got {confidence}")
    low, high = percentile_interval(bootstrap_means(arr, n_resamples, seed), confidence)
    return ConfidenceInterval(
        mean=float(arr.mean()),
        low=float(low),
        high=float(high),
        confidence=confidence,
        n=len(arr),
        n_resamples=n_resamples,
        seed=seed,
    )


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a proportion, ``successes`` of ``n`` trials (fractions).

    Unlike a bootstrap it does not collapse at 0 or ``n`` successes (0 of 10 gives
    [0, 0.2775] at 95%, where every resample of ten zeros is zero), and it needs no seed.
    """
    if n < 1 or not 0 <= successes <= n:
        raise MetricInputError(
            f"a proportion needs 0 <= successes <= n and n >= 1, got {successes} of {n}"
        )
    return wilson_interval_at(successes / n, n, confidence)


def wilson_interval_at(rate: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``rate`` observed over ``n`` trials, a
    fraction of successes that need not be a whole number of them (a rate pooled over
    episodes, with their trajectories as the trials)."""
    if n < 1 or not 0.0 <= rate <= 1.0:
        raise MetricInputError(f"a proportion needs 0 <= rate <= 1 and n >= 1, got {rate} of {n}")
    if not 0 < confidence < 1:
        raise MetricInputError(f"confidence must be in (0, 1), got {confidence}")
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    p = rate
    z2n = z * z / n
    centre = (p + z2n / 2.0) / (1.0 + z2n)
    half = z / (1.0 + z2n) * math.sqrt(p * (1.0 - p) / n + z2n / (4.0 * n))
    # At a rate of 0 (or 1) the bound is exactly 0 (or 1); the formula rounds near it.
    low = 0.0 if p == 0.0 else max(0.0, centre - half)
    high = 1.0 if p == 1.0 else min(1.0, centre + half)
    return low, high


def percentile_interval(estimates: FloatArray, confidence: float) -> tuple[float, float]:
    """The percentile interval of bootstrap ``estimates``; NaN when they are all equal: a
    sample without spread (one episode, or ten SPLs of 0, or two systems that did the same
    on every episode) resamples to itself every time, and a zero-width interval would
    claim a certainty the sample does not give."""
    if np.all(estimates == estimates[0]):
        return math.nan, math.nan
    tail = (1.0 - confidence) / 2.0 * 100.0
    low, high = np.percentile(estimates, [tail, 100.0 - tail])
    return float(low), float(high)


def sign_flip_p_value(
    differences: FloatArray,
    n_resamples: int,
    seed: int,
    clusters: ArrayLike | None = None,
) -> float:
    """Two-sided p-value of mean(differences) = 0 by sign flips (paired permutation).

    With ``clusters`` (one label per difference) a flip changes the sign of a whole
    cluster, as the rounds of one dialog are not independent. With at most
    ``n_resamples`` sign patterns (``2**units``) every one is counted, which is exact and
    needs no seed (on 3 units the smallest p-value there is, 0.25); else ``n_resamples``
    random patterns, with the +1 correction.
    """
    n = len(differences)
    units = differences if clusters is None else _cluster_sums(differences, clusters)
    k = len(units)
    observed = abs(float(units.sum()) / n)
    # A tiny tolerance so ties (e.g. all-zero differences) count as extreme.
    bar = observed - 1e-12 * max(1.0, observed)
    if counts_every_pattern(k, n_resamples):
        bits = (np.arange(2**k, dtype=np.int64)[:, None] >> np.arange(k)) & 1
        permuted = np.abs(((bits * 2 - 1) * units).sum(axis=1) / n)
        return float((permuted >= bar).sum()) / 2**k
    rng = np.random.default_rng(seed)
    chunk = max(1, _CHUNK_VALUES // k)
    extreme = 0
    for start in range(0, n_resamples, chunk):
        size = min(chunk, n_resamples - start)
        signs = rng.integers(0, 2, size=(size, k), dtype=np.int8) * 2 - 1
        permuted = np.abs((signs * units).sum(axis=1) / n)
        extreme += int((permuted >= bar).sum())
    return (extreme + 1) / (n_resamples + 1)


def counts_every_pattern(units: int, n_resamples: int) -> bool:
    """Whether a sign-flip test over ``units`` counts all ``2**units`` sign patterns (at
    most ``n_resamples`` of them): exact, where sampling would only approximate."""
    return units < 63 and 2**units <= n_resamples


def _cluster_sums(values: FloatArray, clusters: ArrayLike) -> FloatArray:
    """The sum of ``values`` in each cluster, clusters in sorted label order."""
    labels = np.asarray(clusters)
    if labels.shape != values.shape:
        raise MetricInputError(f"one cluster label per value: {labels.shape} for {values.shape}")
    _, members = np.unique(labels, return_inverse=True)
    sums = np.zeros(int(members.max()) + 1 if len(members) else 0)
    np.add.at(sums, members, values)
    return sums


def paired_comparison(
    a: ArrayLike,
    b: ArrayLike,
    n_resamples: int = 10_000,
    confidence: float = 0.95,
    seed: int = 0,
    clusters: ArrayLike | None = None,
    cluster_unit: str = "cluster",
    names: tuple[str, str] = ("system A", "system B"),
) -> PairedComparison:
    """Compare paired per-episode values ``a[i]`` and ``b[i]`` (same episode ``i``); with
    ``clusters`` (one label per episode, e.g. its trajectory) the interval resamples and
    the test flips whole clusters, which the result's ``unit`` calls ``cluster_unit``.
    ``names`` says what ``a`` and ``b`` are in an error (e.g. a metric of a system)."""
    a_arr = finite_values(a, names[0])
    b_arr = finite_values(b, names[1])
    if a_arr.shape != b_arr.shape or a_arr.ndim != 1:
        raise MetricInputError(
            f"paired values need equal 1-D shapes, got {a_arr.shape} and {b_arr.shape}"
        )
    diff = a_arr - b_arr
    if clusters is None:
        ci = bootstrap_ci(diff, n_resamples, confidence, seed)
        low, high, units = ci.low, ci.high, len(diff)
    else:
        if not 0 < confidence < 1:
            raise MetricInputError(f"confidence must be in (0, 1), got {confidence}")
        means = cluster_bootstrap_means(diff, clusters, n_resamples, seed)
        low, high = percentile_interval(means, confidence)
        units = len(np.unique(np.asarray(clusters)))
    return PairedComparison(
        n=len(diff),
        mean_a=float(a_arr.mean()),
        mean_b=float(b_arr.mean()),
        difference=float(diff.mean()),
        ci_low=low,
        ci_high=high,
        p_value=sign_flip_p_value(diff, n_resamples, seed + 1, clusters),
        confidence=confidence,
        n_resamples=n_resamples,
        seed=seed,
        unit="episode" if clusters is None else cluster_unit,
        n_units=units,
        p_exact=counts_every_pattern(units, n_resamples),
    )
