"""Aggregate per-episode scores per system and split, check completeness, compare systems.

The summary is a long table, one row per (system, split, mode, metric): ``n`` episodes,
``mean`` (rates in percent, lengths in metres) and, when asked, an interval made as
``ci_method`` says (:data:`CI_METHODS`): a seeded percentile bootstrap over whole
trajectories (the default ``ci_unit``), or over episodes, where a rate of 0/1 values
(:data:`BINARY_METRICS`) gets the Wilson score interval instead (a bootstrap of ten
zeros would say [0, 0]); over trajectories, a 0/1 rate gets the Wilson interval with the
trajectories as trials, widened to the bootstrap's where that reaches further (Wilson
alone where every value is the same); NaN (shown "n/a") where a bootstrap has no spread
to resample (one episode, or values that are all the same: SPL 0 in every episode of an
SR of 0/10), and no interval at all for an unknown mean. Rules: a frame
that repeats an episode, or misses an official metric's value, is refused
(:func:`checked_scores`); a group with no value for a metric (e.g. no control summary)
has no row for it; NaN / inf never reach a mean (they raise); a metric that can be
unknown (cost, tokens: :data:`~skyvln_eval.metrics.cost.UNKNOWN_IF_ANY_UNKNOWN`) has a
NaN mean, shown as "n/a", when any episode's value is unknown; other missing values (a
rate with nothing to rate) are left out. The call failure and fallback rates are
pooled (:data:`POOLED_RATES`): failed calls of all the group's calls, not a mean of
per-episode rates. A run that misses episodes of its split fails :func:`check_complete`
with the missing ids.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import pandas as pd

from skyvln_eval.avdn.records import trajectory_of
from skyvln_eval.errors import IncompleteRunError, MetricInputError, listed
from skyvln_eval.metrics.conventions import CONVENTIONS_ATTR
from skyvln_eval.metrics.cost import UNKNOWN_IF_ANY_UNKNOWN
from skyvln_eval.metrics.official import OFFICIAL_COLUMNS
from skyvln_eval.metrics.scoring import METRIC_UNITS
from skyvln_eval.metrics.stats import (
    bootstrap_means,
    cluster_bootstrap_means,
    finite_values,
    paired_comparison,
    percentile_interval,
    wilson_interval,
    wilson_interval_at,
)

GROUP_KEYS = ["system", "split", "mode"]

#: Fractions reported in percent.
PERCENT_METRICS = frozenset(
    {
        "success",
        "oracle_success",
        "spl",
        "r2r_sr",
        "r2r_osr",
        "r2r_spl",
        "ndtw",
        "sdtw",
        "cls",
        "collided",
        "status_ok",
        "status_degraded",
        "status_error",
        "llm_call_failure_rate",
        "fallback_rate",
    }
)

#: Short display names of the metrics that tables and figures show.
DISPLAY_NAMES: dict[str, str] = {
    "success": "SR",
    "oracle_success": "OSR",
    "spl": "SPL",
    "gp_m": "GP",
    "oracle_gp_m": "OGP",
    "ne_m": "NE",
    "path_length_m": "TL",
    "r2r_sr": "SR@d",
    "r2r_osr": "OSR@d",
    "r2r_spl": "SPL@d",
    "ndtw": "nDTW",
    "sdtw": "SDTW",
    "cls": "CLS",
    "fallback_rate": "fallback",
    "llm_call_failure_rate": "call fail",
    "llm_cost_usd": "cost",
    "llm_latency_s": "LLM time",
    "status_error": "error",
    "status_degraded": "degraded",
}

#: Metrics where lower is better (tables mark the best accordingly).
LOWER_IS_BETTER = frozenset(
    {
        "ne_m",
        "r2r_ne_m",
        "collision_steps",
        "collided",
        "constraint_violation_steps",
        "solve_failures",
        "segments_cut_short",
        "rmse_x_m",
        "rmse_y_m",
        "rmse_z_m",
        "rmse_yaw_rad",
        "solve_time_mean_ms",
        "solve_time_p95_ms",
        "llm_cost_usd",
        "llm_latency_s",
        "status_error",
        "status_degraded",
        "llm_call_failure_rate",
        "fallback_rate",
    }
)


#: Metrics whose per-episode values are 0 or 1 by definition (unit "0/1": success, a
#: status, a collision): over episodes, their rate's interval is the Wilson score
#: interval, which a bootstrap of ten zeros (every resample 0) would give as [0, 0]; over
#: trajectories, the Wilson one with the trajectories as trials, widened to the
#: trajectory bootstrap's where that reaches further (see :func:`_widened_wilson`).
BINARY_METRICS = frozenset(m for m, unit in METRIC_UNITS.items() if unit == "0/1")

#: How a summary's interval was made (its ``ci_method``), as a table's note says it.
CiMethod = Literal[
    "wilson",
    "bootstrap",
    "wilson_trajectories",
    "trajectory_bootstrap",
    "wilson_or_bootstrap",
    "wilson_or_trajectory_bootstrap",
]
CI_METHODS: dict[str, str] = {
    "wilson": "Wilson score interval, the episodes as trials",
    "bootstrap": "percentile bootstrap of the episodes",
    "wilson_trajectories": "Wilson score interval, the trajectories as trials",
    "trajectory_bootstrap": (
        "percentile bootstrap of the trajectories (the rounds of a dialog drawn together)"
    ),
    "wilson_or_bootstrap": (
        "Wilson score interval at the pooled rate, the episodes as trials, each bound "
        "widened to the percentile bootstrap of the episodes' where that reaches further"
    ),
    "wilson_or_trajectory_bootstrap": (
        "Wilson score interval at the rate, the trajectories as trials, each bound widened "
        "to the percentile bootstrap of the trajectories' where that reaches further"
    ),
}
#: What an interval resamples: episodes, or trajectories (AVDN's ANDH episodes are the
#: rounds of dialogs, several per route: their results are not independent, and an
#: interval over episodes is then too narrow).
CiUnit = Literal["episode", "trajectory"]
CI_UNITS: tuple[CiUnit, ...] = get_args(CiUnit)


def ci_unit_named(value: object) -> CiUnit | None:
    """``value`` as an interval unit, ``None`` if it names none (each reader says where)."""
    return next((unit for unit in CI_UNITS if value == unit), None)


def _bootstrap_method(unit: CiUnit) -> CiMethod:
    return "bootstrap" if unit == "episode" else "trajectory_bootstrap"


@dataclass(frozen=True)
class _Resampling:
    """How one group's intervals resample: its episodes, or their ``clusters``."""

    clusters: np.ndarray | None  # a trajectory label per episode, or None: episodes

    def means(self, values: np.ndarray, n_resamples: int, seed: int) -> np.ndarray:
        if self.clusters is None:
            return bootstrap_means(values, n_resamples, seed)
        return cluster_bootstrap_means(values, self.clusters, n_resamples, seed)

    def trials(self, n_values: int) -> int:
        """How many independent trials a Wilson interval counts."""
        return n_values if self.clusters is None else len(set(self.clusters.tolist()))

    @property
    def bootstrap(self) -> CiMethod:
        return _bootstrap_method("episode" if self.clusters is None else "trajectory")

    @property
    def wilson(self) -> CiMethod:
        return "wilson" if self.clusters is None else "wilson_trajectories"

    @property
    def widened_wilson(self) -> CiMethod:
        return "wilson_or_bootstrap" if self.clusters is None else "wilson_or_trajectory_bootstrap"


#: Rates whose summary is the share over all the group's episodes pooled (failed calls of
#: all calls, fallback decisions of all decisions), not the mean of per-episode rates, in
#: which an episode of one failed call weighed as much as one of twenty answered ones.
#: Their intervals are the Wilson one at the pooled share with the episodes (or the
#: trajectories) as trials, widened to the bootstrap's (the ratio of sums of each
#: resample) where that reaches further. The episodes, not the calls, are the trials,
#: since the calls of an episode fail together (a dead endpoint fails them all). When no
#: episode had a failure (or every call of every episode failed) each resample gives the
#: same 0% (100%): the interval is the Wilson one of "0 of n episodes had one" (n of n),
#: which bounds the share of episodes with a failure, which bounds the share of calls as
#: far as episodes are alike in size; one failed call more never narrows it.
POOLED_RATES: dict[str, tuple[str, str]] = {
    "llm_call_failure_rate": ("llm_failed_calls", "llm_calls"),
    "fallback_rate": ("fallback_decisions", "decisions"),
}


#: Metrics every scored episode has (official AVDN, from its path and ground truth): a
#: missing value is a damaged frame, not "nothing to rate".
ALWAYS_SCORED = frozenset(OFFICIAL_COLUMNS)


def checked_scores(scores: pd.DataFrame, metrics: Sequence[str]) -> None:
    """Refuse a scores frame that would give a wrong number without a word: key columns or
    metrics missing (named, with the metrics it has), an episode in it twice (a notebook
    cell that concatenated a frame again counts it twice), an always-scored metric with
    a missing value (it would be left out of the mean as if it had nothing to rate), or a
    system whose episodes an oracle flew and an agent too (one row would average both)."""
    missing = [c for c in (*GROUP_KEYS, "episode_id") if c not in scores.columns]
    if missing:
        raise MetricInputError(
            f"the scores frame lacks the column(s) {missing} (a frame of score_results or "
            "read_scores has them)"
        )
    needed = [part for m in metrics for part in (m, *POOLED_RATES.get(m, ()))]
    unknown = [m for m in dict.fromkeys(needed) if m not in scores.columns]
    if unknown:
        known = [m for m in METRIC_UNITS if m in scores.columns]
        raise MetricInputError(f"no metric {unknown} in the scores frame; it has {known}")
    twice = scores.duplicated([*GROUP_KEYS, "episode_id"], keep="first")
    if twice.any():
        first = scores.loc[twice, [*GROUP_KEYS, "episode_id"]].iloc[0].tolist()
        raise MetricInputError(
            f"{int(twice.sum())} rows of the scores frame repeat an episode, e.g. "
            f"{'/'.join(map(str, first))}: each would count more than once (concatenated "
            "twice?)"
        )
    _check_oracle_apart(scores)
    for metric in (m for m in metrics if m in ALWAYS_SCORED):
        gaps = scores[metric].isna()
        if gaps.any():
            row = scores.loc[gaps].iloc[0]
            where = "/".join(str(row[k]) for k in (*GROUP_KEYS, "episode_id"))
            raise MetricInputError(
                f"{int(gaps.sum())} episode(s) have no {metric}, e.g. {where}: every scored "
                "episode has one (a damaged scores frame?)"
            )


def _check_oracle_apart(scores: pd.DataFrame) -> None:
    """No system has both episodes the oracle flew and episodes an agent flew."""
    if "oracle" not in scores.columns:
        return
    known = scores.loc[scores["oracle"].notna(), ["system", "oracle"]]
    kinds = known.groupby("system", sort=True)["oracle"].nunique()
    if (kinds > 1).any():
        system = kinds.index[kinds > 1][0]
        raise MetricInputError(
            f"system {system!r} has episodes flown by the ground-truth oracle and episodes "
            "flown by an agent, which its rows would average as one: give the runs "
            "different system labels"
        )


def oracle_systems(scores: pd.DataFrame) -> list[str]:
    """The systems of ``scores`` the harness's oracle flew (references a table never
    ranks); none where the scores do not say (no ``oracle`` column, or empty cells)."""
    if "oracle" not in scores.columns:
        return []
    flown = scores["oracle"].astype("boolean").fillna(False).to_numpy(bool)
    return sorted(set(scores.loc[flown, "system"]))


def unit_of(metric: str) -> str:
    return "%" if metric in PERCENT_METRICS else METRIC_UNITS.get(metric, "")


def summarise(
    scores: pd.DataFrame,
    metrics: Sequence[str] | None = None,
    n_resamples: int = 0,
    confidence: float = 0.95,
    seed: int = 0,
    ci_unit: CiUnit = "trajectory",
    *,
    warn_errors: bool = True,
) -> pd.DataFrame:
    """Per (system, split, mode, metric): n, mean and, if ``n_resamples``, an interval
    (``ci_low``, ``ci_high``, ``confidence``, ``ci_method``: see the module docstring),
    and ``oracle`` (whether the harness's ground-truth oracle flew the system) where the
    scores say.

    ``n_error`` counts the group's episodes that ended in error (where the scores have a
    ``status``): they are in the means, scored as failures (the tables mark such cells, or
    show ``error`` where every episode did), so a dead endpoint's SR 0 is not a result.
    A :class:`ErroredEpisodesWarning` names the groups with errors unless ``warn_errors``
    is false (the tables, which show them).

    ``ci_unit="trajectory"`` resamples whole trajectories (:func:`trajectory_of`) instead
    of episodes: the rounds of one dialog fly one route and succeed or fail together more
    often than independent episodes would. Its 0/1 rates are bootstrapped too (Wilson
    over the trajectories where every episode has the same value); ``n_trajectories``
    says how many trajectories each row's episodes come from.

    Every bootstrapped metric of a group is resampled with the same ``seed``, so metrics
    defined on the same episodes share their resamples. Episodes are taken in episode-id
    order, so the result does not depend on the order of the rows (a parallel run records
    episodes in the order they finish).
    """
    if not isinstance(scores, pd.DataFrame):
        raise MetricInputError(
            f"summarise takes scores (a DataFrame of score_results(results) or "
            f"read_scores(path)), not {type(scores).__name__}"
        )
    if scores.empty:
        raise MetricInputError("no scores to summarise")
    if ci_unit_named(ci_unit) is None:
        raise MetricInputError(f"ci_unit must be one of {CI_UNITS}, got {ci_unit!r}")
    metrics = list(metrics or [m for m in METRIC_UNITS if m in scores.columns])
    checked_scores(scores, metrics)
    oracles = set(oracle_systems(scores)) if "oracle" in scores.columns else None
    errors = error_counts(scores)
    if warn_errors:
        warn_of_errors(errors, "summarise")
    rows = []
    for key, unordered in scores.groupby(GROUP_KEYS, sort=True):
        group = unordered.sort_values("episode_id", kind="stable")
        for metric in metrics:
            column = group[metric]
            present = column.notna().to_numpy()
            row = dict(zip(GROUP_KEYS, key, strict=True))
            if oracles is not None:  # a reference row says so wherever it is read
                row["oracle"] = row["system"] in oracles
            if errors is not None:
                row["n_error"] = errors.get(key, (0, 0))[1]
            row.update(metric=metric, unit=unit_of(metric))
            what = f"{'/'.join(map(str, key))} {metric}"
            if metric in UNKNOWN_IF_ANY_UNKNOWN and not present.all():
                # A mean over the known part would pass for the whole: it is unknown.
                row.update(n=len(column), mean=math.nan)
                if n_resamples:  # nothing was resampled: no method, count or seed
                    row.update(ci_low=math.nan, ci_high=math.nan, confidence=confidence)
                rows.append(row)
                continue
            if not present.any():
                continue
            ids = group.loc[present, "episode_id"]
            resampling = _Resampling(
                None if ci_unit == "episode" else np.array([trajectory_of(e) for e in ids])
            )
            if resampling.clusters is not None:  # how many units the interval rests on
                row["n_trajectories"] = len(set(resampling.clusters.tolist()))
            if metric in POOLED_RATES:  # checked_scores made sure of both parts
                # Numerator and denominator of the episodes with something to rate.
                parts = group.loc[present, list(POOLED_RATES[metric])]
                pairs = finite_values(parts.to_numpy(np.float64), what)
                mean = 100.0 * pairs[:, 0].sum() / pairs[:, 1].sum()
                row.update(n=len(pairs), mean=float(mean))
                if n_resamples:
                    row.update(_pooled_interval(pairs, n_resamples, confidence, seed, resampling))
            else:
                values = finite_values(column[present].to_numpy(np.float64), what)
                scaled = values * (100.0 if metric in PERCENT_METRICS else 1.0)
                row.update(n=len(values), mean=float(scaled.mean()))
                binary = metric in BINARY_METRICS
                if n_resamples and binary:
                    successes = _successes(values, ids, what)
                    trials = resampling.trials(len(values))
                    if resampling.clusters is None:
                        row.update(_wilson(successes, trials, confidence))
                    elif _alike(values):  # each trajectory one trial, all alike
                        won = trials * int(values[0])
                        row.update(_wilson(won, trials, confidence, resampling.wilson))
                    else:
                        estimates = resampling.means(scaled, n_resamples, seed)
                        rate = successes / len(values)
                        row.update(_widened_wilson(rate, trials, estimates, confidence, resampling))
                elif n_resamples:
                    estimates = resampling.means(scaled, n_resamples, seed)
                    row.update(_percentiles(estimates, confidence, resampling.bootstrap))
            rows.append(row)
    summary = pd.DataFrame(rows)
    for count in ("n_trajectories", "n_error"):
        if count in summary.columns:  # a count, not a float
            summary[count] = summary[count].astype("Int64")
    if n_resamples and "ci_method" in summary.columns:
        # Another seed or count gives other bootstrap bounds: which made these goes along.
        drawn = summary["ci_method"].astype(str).str.contains("bootstrap")
        summary["ci_resamples"] = pd.array([n_resamples if d else None for d in drawn], "Int64")
        summary["ci_seed"] = pd.array([seed if d else None for d in drawn], "Int64")
    if CONVENTIONS_ATTR in scores.attrs:  # which conventions scored it goes along
        summary.attrs[CONVENTIONS_ATTR] = scores.attrs[CONVENTIONS_ATTR]
    return summary


class ErroredEpisodesWarning(UserWarning):
    """Scores of episodes that ended in error are being averaged (as failures)."""


def error_counts(scores: pd.DataFrame) -> dict[tuple[str, str, str], tuple[int, int]] | None:
    """Per (system, split, mode): (episodes, episodes that ended in error); None when
    the scores have no ``status``."""
    if "status" not in scores.columns:
        return None
    failed = scores["status"].astype(str).eq("error")
    counts = failed.groupby([scores[k] for k in GROUP_KEYS], sort=True).agg(["size", "sum"])
    return {key: (int(n), int(e)) for key, n, e in counts.itertuples(name=None)}


def warn_of_errors(errors: dict[tuple[str, str, str], tuple[int, int]] | None, where: str) -> None:
    """Warn, naming them, of groups with episodes that ended in error: their means count
    those episodes as failures, which a bare number does not say."""
    failed = {key: c for key, c in (errors or {}).items() if c[1]}
    if not failed:
        return
    shown = "; ".join(f"{'/'.join(map(str, key))}: {e} of {n}" for key, (n, e) in failed.items())
    warnings.warn(
        f"{where}: episodes that ended in error (no usable LLM answer, or the episode "
        f"raised) are scored as failures: {shown}. Their rows say so (n_error; the "
        "tables show 'error' or mark the cell); a mean over them measures the failure, "
        "not the agent",
        ErroredEpisodesWarning,
        stacklevel=3,
    )


def _interval(low: float, high: float, method: CiMethod, confidence: float) -> dict[str, object]:
    """An interval as summary columns."""
    return {"ci_low": low, "ci_high": high, "confidence": confidence, "ci_method": method}


def _percentiles(
    estimates: np.ndarray, confidence: float, method: CiMethod = "bootstrap"
) -> dict[str, object]:
    """The percentile interval of bootstrap ``estimates`` (NaN without spread, one episode
    included: see :func:`~skyvln_eval.metrics.stats.percentile_interval`)."""
    return _interval(*percentile_interval(estimates, confidence), method, confidence)


def _wilson(
    successes: int, n: int, confidence: float, method: CiMethod = "wilson"
) -> dict[str, object]:
    """The Wilson score interval of ``successes`` of ``n``, in percent."""
    low, high = wilson_interval(successes, n, confidence)
    return _interval(100.0 * low, 100.0 * high, method, confidence)


def _widened_wilson(
    rate: float, trials: int, estimates: np.ndarray, confidence: float, resampling: _Resampling
) -> dict[str, object]:
    """The Wilson interval of ``rate`` (a fraction) over ``trials``, each bound widened to
    the percentile interval of the bootstrap ``estimates`` (in percent) where that reaches
    further; the Wilson one alone when the bootstrap has no spread (one trajectory).

    Either alone misleads at a rare event: the bootstrap of a share with one failure is
    narrower than the Wilson interval of none (an audit: 1 error in 30 episodes over 17
    trajectories gave [0, 10.7]%, no error [0, 18.4]%), and the Wilson one with the
    trajectories as trials misses a large trajectory's weight. Widened, a failure more
    never narrows the interval, and an interval never claims more trials than it has.
    """
    low, high = (100.0 * b for b in wilson_interval_at(rate, trials, confidence))
    b_low, b_high = percentile_interval(estimates, confidence)
    if math.isnan(b_low):
        return _interval(low, high, resampling.wilson, confidence)
    return _interval(min(low, b_low), max(high, b_high), resampling.widened_wilson, confidence)


def _alike(values: np.ndarray) -> bool:
    """Whether every value is the same (a bootstrap of them has no spread)."""
    return bool((values == values[0]).all())


def _successes(values: np.ndarray, episode_ids: pd.Series, what: str) -> int:
    """How many of a 0/1 metric's ``values`` are 1 (refusing any other value: the Wilson
    interval counts trials)."""
    other = np.flatnonzero((values != 0.0) & (values != 1.0))
    if len(other):
        raise MetricInputError(
            f"{what}: a 0/1 metric has {len(other)} value(s) other than 0 and 1, e.g. "
            f"{float(values[other[0]])!r} in episode {episode_ids.iloc[other[0]]} (a damaged "
            "scores frame?)"
        )
    return int(values.sum())


def _pooled_interval(
    pairs: np.ndarray,
    n_resamples: int,
    confidence: float,
    seed: int,
    resampling: _Resampling = _Resampling(None),
) -> dict[str, object]:
    """Interval of a pooled share from the episodes' (numerator, denominator) ``pairs``:
    Wilson over the episodes (or the trajectories) at the pooled share, widened to the
    percentile interval of the ratio of sums of each bootstrap resample (see
    :func:`_widened_wilson`); Wilson alone when every resample would give the same 0%
    or 100% (see :data:`POOLED_RATES`)."""
    failed, total = pairs[:, 0], pairs[:, 1]
    trials = resampling.trials(len(pairs))
    if not failed.any():
        return _wilson(0, trials, confidence, resampling.wilson)
    if (failed == total).all():
        return _wilson(trials, trials, confidence, resampling.wilson)
    means = resampling.means(pairs, n_resamples, seed)
    estimates = 100.0 * means[:, 0] / means[:, 1]
    rate = float(failed.sum() / total.sum())
    return _widened_wilson(rate, trials, estimates, confidence, resampling)


def check_complete(
    episode_ids: Iterable[str], expected_ids: Iterable[str], what: str = "run"
) -> None:
    """Raise :class:`IncompleteRunError` naming missing (and unknown) episode ids."""
    got = set(episode_ids)
    expected = list(dict.fromkeys(expected_ids))
    missing = [e for e in expected if e not in got]
    unexpected = sorted(got - set(expected))
    if missing or unexpected:
        raise IncompleteRunError(what, missing, unexpected)


def check_scores_complete(scores: pd.DataFrame, expected_ids: Sequence[str]) -> None:
    """Every (system, split, mode) group of ``scores`` must cover ``expected_ids`` exactly."""
    for key, group in scores.groupby(GROUP_KEYS, sort=True):
        check_complete(group["episode_id"], expected_ids, "run " + "/".join(map(str, key)))


def compare_systems(
    scores: pd.DataFrame,
    system_a: str,
    system_b: str,
    metric: str,
    split: str,
    mode: str = "andh",
    n_resamples: int = 10_000,
    seed: int = 0,
    ci_unit: CiUnit = "trajectory",
) -> pd.Series:
    """Paired bootstrap and sign-flip test of ``metric`` between two systems on one split.

    ``ci_unit="trajectory"`` resamples and flips whole trajectories (the rounds of one
    dialog fly one route: counted as independent episodes, they make the interval too
    narrow and the p-value too small). ``n_units`` says how many units there were, and
    ``p_exact`` whether the test counted every sign pattern (at most ``n_resamples`` of
    them: then no test can give a p-value below ``2 / 2**n_units``).

    Both systems must have scored exactly the same episodes (else it raises, naming the
    episodes only one of them has). Rates are compared in percent.

    The interval (percentile bootstrap of the mean difference) and ``p_value`` (paired
    sign-flip permutation test) are different procedures and can disagree near the 5%
    level on a few dozen episodes: the percentile interval is the less conservative there
    (it is too narrow on small samples), so an interval that excludes 0 with a p-value
    above 0.05 is not a significant difference: ``significant`` is the test's verdict at
    5% (``p_value < 0.05``), whatever the interval shows. Systems that did the same on
    every episode have no interval (NaN: the differences have no spread to resample).

    ``errors_a`` / ``errors_b`` count each system's episodes that ended in error (scored
    as failures; an :class:`ErroredEpisodesWarning` says so): against a dead endpoint the
    difference measures the failure, not the model.
    """

    checked_scores(scores, [metric])
    if ci_unit_named(ci_unit) is None:
        raise MetricInputError(f"ci_unit must be one of {CI_UNITS}, got {ci_unit!r}")

    def values(system: str) -> pd.Series:
        sel = scores[(scores.system == system) & (scores.split == split) & (scores["mode"] == mode)]
        if sel.empty:
            raise MetricInputError(_no_scores_for(scores, system, split, mode))
        # Episode order fixes the bootstrap's resamples: sorted, so input order never matters.
        return sel.set_index("episode_id")[metric].astype(np.float64).sort_index()

    a, b = values(system_a), values(system_b)
    only_a, only_b = sorted(set(a.index) - set(b.index)), sorted(set(b.index) - set(a.index))
    if only_a or only_b:
        raise MetricInputError(
            f"{system_a!r} and {system_b!r} did not run the same episodes on {split}: "
            f"only {system_a!r}: {listed(only_a, 10)}; only {system_b!r}: {listed(only_b, 10)}"
        )
    b = b.loc[a.index]
    errors = error_counts(
        scores[scores.system.isin([system_a, system_b]) & (scores.split == split)
               & (scores["mode"] == mode)]
    )  # fmt: skip
    warn_of_errors(errors, "compare_systems")
    scale = 100.0 if metric in PERCENT_METRICS else 1.0
    clusters = None if ci_unit == "episode" else [trajectory_of(e) for e in a.index]
    result = paired_comparison(
        a.to_numpy() * scale,
        b.to_numpy() * scale,
        n_resamples,
        seed=seed,
        clusters=clusters,
        cluster_unit="trajectory",
        # Unknown values (e.g. a cost not reported) are refused naming what they are of.
        names=(
            f"compare_systems: {metric} of system {system_a!r} on {split}/{mode}",
            f"compare_systems: {metric} of system {system_b!r} on {split}/{mode}",
        ),
    )
    return pd.Series(
        {
            "metric": metric,
            "system_a": system_a,
            "system_b": system_b,
            **result.__dict__,
            "significant": bool(result.p_value < 0.05),
            **(
                {}
                if errors is None
                else {
                    f"errors_{side}": errors.get((system, split, mode), (0, 0))[1]
                    for side, system in (("a", system_a), ("b", system_b))
                }
            ),
        }
    )


def _no_scores_for(scores: pd.DataFrame, system: str, split: str, mode: str) -> str:
    """Why ``system`` has no scores on ``split``/``mode``: the systems there are, or, for
    one that exists, the splits and modes it has (a typo and a missing split look alike)."""
    where = scores[scores.system == system]
    if where.empty:
        systems = list(dict.fromkeys(scores["system"].astype(str)))
        # A run's own name, where the scores label it by what answered it ("Full †").
        marked = [s for s in systems if s.startswith(f"{system} ")]
        # A table's label, which marks a stand-in's rows ("Full rule †"): its system's name.
        unmarked = [s for s in systems if system.startswith(f"{s} ")]
        hint = f" (did you mean {listed(marked or unmarked)}?)" if marked or unmarked else ""
        return (
            f"no scores for system {system!r}{hint}; the scores have the systems {listed(systems)}"
        )
    has = list(dict.fromkeys(where["split"].astype(str) + "/" + where["mode"].astype(str)))
    return f"no scores for system {system!r} on {split}/{mode}; it has {listed(has)}"
