"""A summary's intervals: Wilson for 0/1 rates, bootstrap for the rest, n/a where none."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics import BINARY_METRICS, bootstrap_ci, summarise, wilson_interval
from skyvln_eval.metrics.stats import wilson_interval_at


def frame(**columns: list[float]) -> pd.DataFrame:
    """A scores frame of one system on one split, an episode per value."""
    n = len(next(iter(columns.values())))
    keys = {"system": "A", "split": "test_unseen", "mode": "andh"}
    return pd.DataFrame({**keys, "episode_id": [f"e{k:02d}" for k in range(n)], **columns})


def interval(summary: pd.DataFrame, metric: str) -> tuple[float, float, str]:
    row = summary.set_index("metric").loc[metric]
    return float(row["ci_low"]), float(row["ci_high"]), str(row["ci_method"])


def test_a_rate_of_all_failures_or_all_successes_has_its_wilson_interval_not_a_point() -> None:
    none = summarise(frame(success=[0.0] * 10), ["success"], n_resamples=200, ci_unit="episode")
    low, high, method = interval(none, "success")
    assert (low, method) == (0.0, "wilson") and high == pytest.approx(27.75, abs=0.005)
    every = summarise(frame(success=[1.0] * 10), ["success"], n_resamples=200, ci_unit="episode")
    low, high, method = interval(every, "success")
    assert low == pytest.approx(72.25, abs=0.005) and (high, method) == (100.0, "wilson")
    # Closed form: no seed or resample count changes it; other levels are other widths.
    again = summarise(
        frame(success=[1.0] * 10), ["success"], n_resamples=7, seed=3, ci_unit="episode"
    )
    assert interval(again, "success") == interval(every, "success")
    wider = summarise(
        frame(success=[1.0] * 10), ["success"], n_resamples=7, confidence=0.99, ci_unit="episode"
    )
    assert interval(wider, "success")[0] < low


def test_wilson_interval_matches_the_textbook_values() -> None:
    low, high = wilson_interval(3, 10)  # Newcombe (1998), method 3: 0.1078 to 0.6032
    assert (low, high) == pytest.approx((0.1078, 0.6032), abs=5e-5)
    assert wilson_interval(0, 1) == pytest.approx((0.0, 0.7935), abs=5e-5)
    with pytest.raises(MetricInputError, match="got 11 of 10"):
        wilson_interval(11, 10)


def test_every_0_1_metric_gets_wilson_and_a_value_other_than_0_or_1_is_refused() -> None:
    assert {"success", "oracle_success", "r2r_sr", "collided", "status_error"} <= BINARY_METRICS
    assert not {"spl", "ndtw", "fallback_rate", "llm_call_failure_rate"} & BINARY_METRICS
    damaged = r"A/test_unseen/andh success: .* e\.g\. 0\.5 in episode e01"
    with pytest.raises(MetricInputError, match=damaged):
        summarise(frame(success=[0.0, 0.5, 1.0]), ["success"], n_resamples=10, ci_unit="episode")


def test_a_continuous_metric_of_one_episode_has_no_interval() -> None:
    summary = summarise(
        frame(ne_m=[12.5], success=[1.0]), ["ne_m", "success"], n_resamples=100, ci_unit="episode"
    )
    low, high, method = interval(summary, "ne_m")
    assert math.isnan(low) and math.isnan(high) and method == "bootstrap"
    assert summary.set_index("metric").loc["ne_m", "mean"] == 12.5
    # A rate of one episode still has its (wide) Wilson interval.
    assert interval(summary, "success")[:2] == pytest.approx((20.65, 100.0), abs=0.005)


def test_a_continuous_metric_of_many_episodes_keeps_its_bootstrap_interval() -> None:
    ne = np.random.default_rng(3).gamma(2.0, 30.0, size=25)
    summary = summarise(frame(ne_m=list(ne)), ["ne_m"], n_resamples=500, seed=9, ci_unit="episode")
    expected = bootstrap_ci(ne, 500, seed=9)  # the same episodes, in episode-id order
    assert interval(summary, "ne_m") == (expected.low, expected.high, "bootstrap")
    assert expected.low < expected.high


def test_a_pooled_share_with_no_failure_is_wilson_over_the_episodes() -> None:
    # 30 answered calls in 10 episodes: every resample says 0%, which the calls of one
    # dead endpoint (failing together) would not; 0 of 10 episodes had a failed call.
    calls = frame(
        llm_calls=[3.0] * 10,
        llm_failed_calls=[0.0] * 10,
        llm_call_failure_rate=[0.0] * 10,
        decisions=[2.0] * 10,
        fallback_decisions=[2.0] * 10,
        fallback_rate=[1.0] * 10,
    )
    rates = ["llm_call_failure_rate", "fallback_rate"]
    summary = summarise(calls, rates, n_resamples=100, ci_unit="episode")
    low, high, method = interval(summary, "llm_call_failure_rate")
    assert (low, method) == (0.0, "wilson") and high == pytest.approx(27.75, abs=0.005)
    low, high, method = interval(summary, "fallback_rate")  # every decision fell back
    assert low == pytest.approx(72.25, abs=0.005) and (high, method) == (100.0, "wilson")
    one_failed = calls.assign(llm_failed_calls=[1.0] + [0.0] * 9)
    low, high, method = interval(
        summarise(one_failed, rates, n_resamples=100, ci_unit="episode"), rates[0]
    )
    # One failed call never narrows the interval of none: the Wilson one at the pooled
    # share, widened to the bootstrap's (which alone gave a bound below the none's).
    assert method == "wilson_or_bootstrap" and low < 100 / 30 < high
    assert high >= 27.75


def test_a_failure_more_never_narrows_a_rates_trajectory_interval() -> None:
    # An audit: 1 error in 30 episodes over 17 trajectories had the bootstrap's
    # [0, 10.7]%, none the Wilson [0, 18.4]%: a failure made the interval tighter.
    rounds = [[0.0, 0.0]] * 13 + [[0.0]] * 4  # 30 episodes, 17 trajectories
    none = summarise(rounds_frame(rounds, "status_error"), ["status_error"], 1000)
    one = [[1.0, 0.0], *rounds[1:]]
    once = summarise(rounds_frame(one, "status_error"), ["status_error"], 1000)
    _, high_none, method_none = interval(none, "status_error")
    low, high, method = interval(once, "status_error")
    assert method_none == "wilson_trajectories" and method == "wilson_or_trajectory_bootstrap"
    assert high >= high_none and low < 100 / 30 < high
    # Never claiming more trials than there are trajectories.
    assert high >= 100 * wilson_interval_at(1 / 30, 17)[1]


def test_a_continuous_metric_without_spread_has_no_interval() -> None:
    # SPL of 0 in each of ten failed episodes: every resample is 0, which says nothing of
    # how far the mean may be; the SR beside it has its Wilson interval.
    zeros = frame(spl=[0.0] * 10, success=[0.0] * 10)
    summary = summarise(zeros, ["spl", "success"], n_resamples=200, ci_unit="episode")
    low, high, method = interval(summary, "spl")
    assert math.isnan(low) and math.isnan(high) and method == "bootstrap"
    assert interval(summary, "success")[1] == pytest.approx(27.75, abs=0.005)


def rounds_frame(per_trajectory: list[list[float]], metric: str) -> pd.DataFrame:
    """A scores frame whose episodes are the rounds of AVDN trajectories (``<map>__<t>_<r>``)."""
    ids, values = [], []
    for t, rounds in enumerate(per_trajectory):
        for r, value in enumerate(rounds, start=1):
            ids.append(f"1913__{t}_{r}")
            values.append(value)
    keys = {"system": "A", "split": "test_unseen", "mode": "andh"}
    return pd.DataFrame({**keys, "episode_id": ids, metric: values})


def test_trajectory_intervals_draw_the_rounds_of_a_dialog_together() -> None:
    # Rounds of one route that succeed or fail together: 20 trajectories, 3 rounds each.
    rng = np.random.default_rng(1)
    outcomes = [[float(rng.random() < 0.4)] * 3 for _ in range(20)]
    scores = rounds_frame(outcomes, "success").assign(spl=lambda f: f["success"] * 0.8)
    by_episode = summarise(scores, ["success", "spl"], n_resamples=2000, ci_unit="episode")
    by_trajectory = summarise(scores, ["success", "spl"], n_resamples=2000, ci_unit="trajectory")
    for metric, made in (
        ("success", "wilson_or_trajectory_bootstrap"),
        ("spl", "trajectory_bootstrap"),
    ):
        low_e, high_e, _ = interval(by_episode, metric)
        low_t, high_t, method = interval(by_trajectory, metric)
        assert method == made
        # 20 independent trials, not 60: the honest interval is about sqrt(3) wider.
        assert (high_t - low_t) > 1.4 * (high_e - low_e), metric
    same = by_trajectory.set_index("metric")
    assert same.loc["success", "n"] == 60  # the mean is still over episodes
    assert same.loc["success", "n_trajectories"] == 20  # what the interval rests on
    assert "n_trajectories" not in by_episode.columns
    assert same.loc["success", "mean"] == by_episode.set_index("metric").loc["success", "mean"]
    # Every round failed: Wilson over the 20 trajectories, wider than over 60 episodes.
    none = summarise(
        rounds_frame([[0.0] * 3] * 20, "success"), ["success"], 200, ci_unit="trajectory"
    )
    low, high, method = interval(none, "success")
    assert (low, method) == (0.0, "wilson_trajectories")
    assert high == pytest.approx(100 * wilson_interval(0, 20)[1])


def test_trajectory_of_episode_ids_and_singleton_clusters() -> None:
    from skyvln_eval.metrics import trajectory_of
    from skyvln_eval.metrics.stats import bootstrap_means, cluster_bootstrap_means

    assert trajectory_of("1913__3_2") == trajectory_of("1913__3_1") == "1913__3"
    assert trajectory_of("1913__3_x") == "1913__3_x" and trajectory_of("e01") == "e01"
    values = np.random.default_rng(2).normal(size=50)
    # Every value its own cluster (labels in value order): the episode bootstrap's draws.
    labels = np.array([f"c{k:03d}" for k in range(50)])
    np.testing.assert_allclose(
        cluster_bootstrap_means(values, labels, 300, seed=4),
        bootstrap_means(values, 300, seed=4),
        rtol=1e-12,
    )
    with pytest.raises(MetricInputError, match="one cluster label per value"):
        cluster_bootstrap_means(values, labels[:3], 10)
    with pytest.raises(MetricInputError, match="ci_unit must be one of"):
        summarise(frame(spl=[0.1, 0.2]), ["spl"], 10, ci_unit="map")  # type: ignore[arg-type]
