"""Aggregation, completeness, bootstrap intervals, paired tests, and GT replay on the sample."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from skyvln_eval.avdn import load_split, replay_ground_truth
from skyvln_eval.errors import DataError, FormatVersionError, IncompleteRunError, MetricInputError
from skyvln_eval.metrics import (
    EpisodeResult,
    ErroredEpisodesWarning,
    MetricConventions,
    bootstrap_ci,
    check_complete,
    check_scores_complete,
    compare_systems,
    paired_comparison,
    score_results,
    summarise,
)
from skyvln_eval.metrics.aggregate import oracle_systems
from skyvln_eval.metrics.scores_io import read_scores, summary_csv_text, write_scores
from skyvln_eval.reports import TABLE_I, build_table
from tests.metrics.helpers import result, square


def test_ground_truth_replay_on_the_sample_scores_sr_and_osr_100(sample_dir: Path) -> None:
    results = []
    for split in ("train", "val_seen", "val_unseen", "test_unseen"):
        for ep in load_split(sample_dir, split).episodes("andh"):
            georef = ep.georef
            views = replay_ground_truth(
                ep.gt_path_corners, georef.gps_botm_left, georef.gps_top_right
            )
            replay = EpisodeResult(
                episode_id=ep.episode_id,
                split=split,
                mode="andh",
                system="GT replay",
                status="ok",
                visited_views=views,
                gt_path_corners=ep.gt_path_corners,
            )
            results.append(replay)
    scores = score_results(results)
    assert scores.success.eq(1.0).all() and scores.oracle_success.eq(1.0).all()
    longer = scores.path_length_m > scores.d_net_m * (1 + 1e-9)
    assert longer.any()
    assert (scores.spl[longer] < 1.0).all()
    np.testing.assert_allclose(scores.spl[~longer], 1.0)
    summary = summarise(scores, ["success", "oracle_success", "spl"])
    for split, group in summary.groupby("split"):
        by_metric = group.set_index("metric")["mean"]
        assert by_metric["success"] == 100.0 and by_metric["oracle_success"] == 100.0, split
        assert by_metric["spl"] < 100.0, split


def scores_of_two_systems() -> pd.DataFrame:
    rng = np.random.default_rng(1)
    results = []
    for k in range(40):
        g0, g1 = square(0, 0), square(100, 0)
        good = square(100 + rng.normal(0, 5), rng.normal(0, 5))
        bad = square(60 + rng.normal(0, 30), rng.normal(0, 30))
        results.append(result([g0, good], [g0, g1], episode_id=f"e{k}", system="A"))
        results.append(result([g0, bad], [g0, g1], episode_id=f"e{k}", system="B"))
    return score_results(results)


def test_summary_is_per_system_in_percent_with_seeded_intervals() -> None:
    scores = scores_of_two_systems()
    summary = summarise(scores, ["success", "ne_m"], n_resamples=500, seed=4)
    again = summarise(scores, ["success", "ne_m"], n_resamples=500, seed=4)
    pd.testing.assert_frame_equal(summary, again)
    row = summary[(summary.system == "A") & (summary.metric == "success")].iloc[0]
    assert row["mean"] == pytest.approx(scores[scores.system == "A"].success.mean() * 100)
    assert row.unit == "%" and row.n == 40
    assert row.ci_low <= row["mean"] <= row.ci_high
    with pytest.raises(MetricInputError, match="no scores"):
        summarise(scores.iloc[:0])


def test_summary_and_comparison_say_which_episodes_ended_in_error() -> None:
    # An audit: summarise and compare_systems gave a dead endpoint's system ordinary
    # figures (SR 0, NE as from the start), nothing saying its episodes had errored.
    g0, g1 = square(0, 0), square(100, 0)
    results = []
    for k in range(6):
        results.append(result([g0, g1], [g0, g1], episode_id=f"e{k}", system="live"))
        status = "error" if k < 4 else "ok"  # 4 of 6 raised: they stayed at the start
        results.append(result([g0], [g0, g1], status, episode_id=f"e{k}", system="dead"))
    scores = score_results(results)
    with pytest.warns(ErroredEpisodesWarning, match=r"dead/val_seen/andh: 4 of 6") as caught:
        summary = summarise(scores, ["success", "ne_m"])
    assert "live" not in str(caught[0].message)
    counts = summary.set_index(["system", "metric"])["n_error"]
    assert counts[("dead", "success")] == 4 and counts[("dead", "ne_m")] == 4
    assert counts[("live", "success")] == 0
    assert str(summary["n_error"].dtype) == "Int64"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the tables show errors themselves: no warning
        summarise(scores, ["success"], warn_errors=False)
    with pytest.warns(ErroredEpisodesWarning, match="compare_systems"):
        diff = compare_systems(scores, "live", "dead", "success", "val_seen", n_resamples=200)
    assert diff.errors_a == 0 and diff.errors_b == 4
    without = scores.drop(columns="status")  # a frame that does not say: no column
    assert "n_error" not in summarise(without, ["success"]).columns


def test_intervals_and_paired_tests_do_not_depend_on_row_order() -> None:
    # A parallel run records episodes in the order they finish: the numbers must not care.
    scores = scores_of_two_systems()
    shuffled = scores.sample(frac=1.0, random_state=7)
    assert not shuffled.episode_id.equals(scores.episode_id)
    pd.testing.assert_frame_equal(
        summarise(scores, ["success", "ne_m"], n_resamples=300),
        summarise(shuffled, ["success", "ne_m"], n_resamples=300),
    )
    pd.testing.assert_series_equal(
        compare_systems(scores, "A", "B", "ne_m", "val_seen", n_resamples=300),
        compare_systems(shuffled, "A", "B", "ne_m", "val_seen", n_resamples=300),
    )


def test_bootstrap_ci_rules() -> None:
    constant = bootstrap_ci([2.0, 2.0, 2.0], 100)  # no spread: no interval, not [2, 2]
    assert constant.mean == 2.0 and math.isnan(constant.low) and math.isnan(constant.high)
    with pytest.raises(MetricInputError, match="no values"):
        bootstrap_ci([])
    with pytest.raises(MetricInputError, match="non-finite"):
        bootstrap_ci([1.0, np.nan])
    rng = np.random.default_rng(0)
    values = (rng.random(4000) < 0.3).astype(float)
    ci = bootstrap_ci(values, 2000, seed=5)
    assert ci == bootstrap_ci(values, 2000, seed=5)
    normal_half_width = 1.96 * np.sqrt(values.mean() * (1 - values.mean()) / len(values))
    assert (ci.high - ci.low) / 2 == pytest.approx(normal_half_width, rel=0.1)


def test_paired_test_finds_a_real_difference_and_not_a_null_one() -> None:
    scores = scores_of_two_systems()
    diff = compare_systems(scores, "A", "B", "success", "val_seen", n_resamples=2000)
    assert diff.difference > 0 and diff.ci_low > 0 and diff.p_value < 0.01
    assert diff.significant  # the test's verdict at 5%, beside the interval
    # A few trajectories: the interval can exclude 0 while the test cannot reject (an
    # audit met [7.7, 62.5] beside p = 0.25): the verdict is the test's.
    few = compare_systems(scores.iloc[: len(scores) // 10], "A", "B", "success", "val_seen")
    assert few.significant is (few.p_value < 0.05)
    same = paired_comparison(np.ones(30), np.ones(30), 500)
    assert same.difference == 0.0 and same.p_value == 1.0
    assert math.isnan(same.ci_low) and math.isnan(same.ci_high)  # not a certain [0, 0]
    missing = scores[~((scores.system == "B") & (scores.episode_id == "e3"))]
    with pytest.raises(MetricInputError, match=r"only 'A': 'e3'; only 'B': none"):
        compare_systems(missing, "A", "B", "success", "val_seen")


def test_compare_systems_names_the_system_and_metric_of_unknown_values() -> None:
    # An audit: 'system A: non-finite values (NaN or inf) cannot be averaged', for
    # llm_cost_usd of the second system given.
    scores = scores_of_two_systems()
    scores["llm_cost_usd"] = 0.01
    scores.loc[(scores.system == "B") & (scores.episode_id == "e3"), "llm_cost_usd"] = np.nan
    with pytest.raises(MetricInputError) as unknown:
        compare_systems(scores, "B", "A", "llm_cost_usd", "val_seen", n_resamples=100)
    assert str(unknown.value).startswith(
        "compare_systems: llm_cost_usd of system 'B' on val_seen/andh: non-finite values "
        f"(NaN or inf: 1 of {(scores.system == 'B').sum()}) cannot be averaged"
    )


def test_compare_systems_names_the_systems_there_are_and_says_how_many_it_cut() -> None:
    # An audit asked for 'Full' where the system is 'Full †': the error named neither.
    scores = scores_of_two_systems()
    with pytest.raises(MetricInputError) as unknown:
        compare_systems(scores, "Full", "B", "success", "val_seen")
    assert "no scores for system 'Full'; the scores have the systems 'A', 'B'" in str(unknown.value)
    marked = scores.replace({"system": {"A": "A †"}})  # reproduce labels stand-in rows so
    with pytest.raises(MetricInputError, match=r"system 'A' \(did you mean 'A †'\?\)"):
        compare_systems(marked, "A", "B", "success", "val_seen")
    # ... and a table marks a run's rows: its label names the system without the marker.
    with pytest.raises(MetricInputError, match=r"system 'A †' \(did you mean 'A'\?\)"):
        compare_systems(scores, "A †", "B", "success", "val_seen")
    with pytest.raises(MetricInputError, match=r"'A' on val_unseen/andh; it has 'val_seen/andh'"):
        compare_systems(scores, "A", "B", "success", "val_unseen")
    # Only A has the last 15 episodes: 10 are named, and the 5 others counted.
    fewer = scores[~((scores.system == "B") & (scores.episode_id.str[1:].astype(int) >= 25))]
    with pytest.raises(MetricInputError) as cut:
        compare_systems(fewer, "A", "B", "success", "val_seen")
    assert "'e34' and 5 more; only 'B': none" in str(cut.value)


def test_completeness_names_missing_and_unknown_episodes() -> None:
    check_complete(["a", "b"], ["b", "a"])
    with pytest.raises(
        IncompleteRunError, match=r"1 missing episode\(s\): c; 1 episode\(s\) not in the split: z"
    ):
        check_complete(["a", "b", "z"], ["a", "b", "c"], "run X")
    scores = scores_of_two_systems()
    expected = [f"e{k}" for k in range(41)]
    with pytest.raises(
        IncompleteRunError, match="run A/val_seen/andh is incomplete: 1 missing episode\\(s\\): e40"
    ):
        check_scores_complete(scores, expected)


def test_a_scores_file_is_the_same_whatever_order_the_rows_came_in(tmp_path: Path) -> None:
    from skyvln_eval.metrics import MetricConventions
    from skyvln_eval.metrics.scores_io import read_scores, write_scores

    scores = scores_of_two_systems()
    write_scores(tmp_path / "a.csv", scores, MetricConventions())
    write_scores(tmp_path / "b.csv", scores.sample(frac=1.0, random_state=3), MetricConventions())
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    back, _ = read_scores(tmp_path / "a.csv")
    assert list(back.system) == sorted(scores.system)  # sorted by system, then episode


def test_call_failure_and_fallback_rates_are_shares_of_all_calls_and_decisions() -> None:
    # One episode whose only call failed, one of 19 answered calls, one without any: the
    # share of failed calls is 1 of 20 (the mean of per-episode rates said 50%).
    nan = float("nan")
    scores = pd.DataFrame(
        {
            "system": "A",
            "split": "test_unseen",
            "mode": "andh",
            "episode_id": ["e0", "e1", "e2"],
            "llm_calls": [1.0, 19.0, 0.0],
            "llm_failed_calls": [1.0, 0.0, 0.0],
            "llm_call_failure_rate": [1.0, 0.0, nan],
            "decisions": [1.0, 9.0, 0.0],
            "fallback_decisions": [1.0, 0.0, 0.0],
            "fallback_rate": [1.0, 0.0, nan],
        }
    )
    rates = ["llm_call_failure_rate", "fallback_rate"]
    summary = summarise(scores, rates, n_resamples=200, seed=1).set_index("metric")
    assert summary.loc["llm_call_failure_rate", "mean"] == pytest.approx(5.0)
    assert summary.loc["fallback_rate", "mean"] == pytest.approx(10.0)
    assert list(summary["n"]) == [2, 2] and list(summary["unit"]) == ["%", "%"]
    # Resampling the two episodes gives 0%, 5% or 100% of the calls.
    low, high = summary.loc["llm_call_failure_rate", ["ci_low", "ci_high"]]
    assert 0.0 <= low <= 5.0 <= high <= 100.0


def test_a_frame_that_would_give_a_wrong_number_is_refused_with_the_reason() -> None:
    scores = scores_of_two_systems()
    again = pd.concat([scores, scores[scores.system == "A"].iloc[:3]])  # a cell run twice
    with pytest.raises(MetricInputError, match="3 rows of the scores frame repeat an episode"):
        summarise(again, ["success"])
    with pytest.raises(MetricInputError, match="repeat an episode"):
        compare_systems(again, "A", "B", "success", "val_seen", n_resamples=10)
    with pytest.raises(MetricInputError, match=r"no metric \['sr'\] in the scores frame"):
        summarise(scores, ["sr"])
    with pytest.raises(MetricInputError, match=r"lacks the column\(s\) \['mode'\]"):
        summarise(scores.drop(columns=["mode"]), ["success"])
    damaged = scores.copy()
    damaged.loc[damaged.index[0], "ne_m"] = np.nan  # not left out as "nothing to rate"
    with pytest.raises(MetricInputError, match="1 episode\\(s\\) have no ne_m"):
        summarise(damaged, ["ne_m"])


def test_a_table_or_summary_cannot_name_conventions_other_than_those_that_scored_it(
    tmp_path: Path,
) -> None:
    results = [
        result([square(0, 0), square(100, 0)], [square(0, 0), square(100, 0)], episode_id=f"e{k}")
        for k in range(3)
    ]
    legacy = MetricConventions(legacy_gp=True)
    scores = score_results(results, legacy)
    summary = summarise(scores, ["success", "spl", "gp_m"])
    with pytest.raises(MetricInputError, match="but its scores were made with"):
        build_table(summary, TABLE_I, MetricConventions())
    with pytest.raises(MetricInputError, match="the summary CSV would say"):
        summary_csv_text(summary, MetricConventions())
    assert build_table(summary, TABLE_I, legacy).conventions == legacy
    write_scores(tmp_path / "scores.csv", scores, legacy)
    again, read_back = read_scores(tmp_path / "scores.csv")
    assert read_back == legacy
    with pytest.raises(MetricInputError, match="but its scores were made with"):
        build_table(summarise(again, ["success"]), TABLE_I, MetricConventions())


def test_a_scores_file_says_which_systems_the_oracle_flew_and_an_old_one_says_nothing(
    tmp_path: Path,
) -> None:
    g = [square(0, 0), square(100, 0)]
    results = [
        result(g, g, episode_id=f"e{k}", system="GT", extra={"oracle": True}) for k in range(2)
    ]
    results += [
        result([g[0]], g, episode_id=f"e{k}", system="A", extra={"oracle": False}) for k in range(2)
    ]
    results += [result([g[0]], g, episode_id="e0", system="predictions")]  # nothing said
    scores = score_results(results)
    assert oracle_systems(scores) == ["GT"]
    write_scores(tmp_path / "v2.csv", scores, MetricConventions())
    back, _ = read_scores(tmp_path / "v2.csv")
    assert back["oracle"].tolist() == [False, False, True, True, pd.NA]
    assert oracle_systems(back) == ["GT"]

    # A version 1 file (before the column) reads, every row "not said" and ranked.
    lines = (tmp_path / "v2.csv").read_text().splitlines()
    header = lines[2].split(",")
    at = header.index("oracle")
    old = ["# skyvln-eval.scores v1", lines[1]]
    old += [",".join(c for k, c in enumerate(line.split(",")) if k != at) for line in lines[2:]]
    (tmp_path / "v1.csv").write_text("\n".join(old) + "\n")
    v1, _ = read_scores(tmp_path / "v1.csv")
    assert v1["oracle"].isna().all() and oracle_systems(v1) == []
    assert list(v1.columns) == list(back.columns)

    damaged = (tmp_path / "v2.csv").read_text().replace(",True,", ",yes,", 1)
    (tmp_path / "bad.csv").write_text(damaged)
    with pytest.raises(DataError, match=r"record 2 of .*bad.csv \(line 6\): oracle is 'yes'"):
        read_scores(tmp_path / "bad.csv")
    (tmp_path / "v4.csv").write_text("# skyvln-eval.scores v4\n" + "\n".join(lines[1:]))
    with pytest.raises(FormatVersionError, match="version '4' is not supported"):
        read_scores(tmp_path / "v4.csv")
    # Scored by older formulas (metrics v1: a crashed flight could succeed): refused, the
    # file named, and what to do said.
    old = "\n".join(lines).replace('"metrics_version":3', '"metrics_version":1')
    (tmp_path / "old.csv").write_text(old)
    with pytest.raises(DataError, match=r"old.csv: scored with metrics_version 1; .* score"):
        read_scores(tmp_path / "old.csv")


def test_a_system_flown_by_the_oracle_and_by_an_agent_is_refused() -> None:
    g = [square(0, 0), square(100, 0)]
    results = [
        result(g, g, episode_id="e0", system="X", extra={"oracle": True}),
        result([g[0]], g, episode_id="e1", system="X", split="val_unseen", extra={"oracle": False}),
    ]
    with pytest.raises(MetricInputError, match="system 'X' has episodes flown by the ground-truth"):
        summarise(score_results(results), ["success"])
    wrong = [result(g, g, extra={"oracle": "yes"})]
    with pytest.raises(MetricInputError, match=r"agent/val_seen/andh/1913__0_1: extra.oracle"):
        score_results(wrong)


def test_a_sign_flip_test_on_few_units_is_exact() -> None:
    """On 3 paired episodes there are 8 sign patterns: the test counts them all, so its
    p-value is a multiple of 1/8 and at least 0.25 (it reported 0.244 by sampling)."""
    three = paired_comparison([1.0, 2.0, 3.0], [0.0, 0.5, 1.0], n_resamples=10_000, seed=3)
    assert three.p_exact and three.n_units == 3 and three.p_value == 0.25
    other_seed = paired_comparison([1.0, 2.0, 3.0], [0.0, 0.5, 1.0], 10_000, seed=9)
    assert other_seed.p_value == 0.25  # counted, not sampled: no seed changes it
    mixed = paired_comparison([1.0, -2.0, 3.0], [0.0, 0.0, 0.0], n_resamples=10_000)
    # Sums of +-1 +-2 +-3: 6, 0, 2, -4, 4, -2, 0, -6; six reach the observed |2|.
    assert mixed.p_value == 0.75
    many = paired_comparison(np.arange(20.0), np.zeros(20), n_resamples=1000)
    assert not many.p_exact and many.p_value == pytest.approx(1 / 1001)


def test_a_comparison_over_clusters_names_them_as_the_caller_does() -> None:
    """Clusters are not always trajectories: the unit is what the caller calls them."""
    values, clusters = np.arange(6.0), ["x", "x", "y", "y", "z", "z"]
    plain = paired_comparison(values, np.zeros(6), 500, clusters=clusters)
    scenes = paired_comparison(values, np.zeros(6), 500, clusters=clusters, cluster_unit="scene")
    assert (plain.unit, plain.n_units) == ("cluster", 3)
    assert (scenes.unit, scenes.n_units) == ("scene", 3)


def test_a_comparison_over_trajectories_flips_and_resamples_whole_dialogs() -> None:
    """Ten dialogs of four rounds: system A beats B on every round of dialogs 0-5 and
    loses on every round of 6-9. Per episode that looks like 40 independent pairs; per
    dialog it is 10, and the test and interval say so."""
    rows = []
    for k in range(40):
        dialog, round_ = divmod(k, 4)
        episode = f"9101__{dialog}_{round_ + 1}"
        a_wins = dialog < 6
        rows.append({"system": "A", "episode_id": episode, "ne_m": 10.0 if a_wins else 30.0})
        rows.append({"system": "B", "episode_id": episode, "ne_m": 30.0 if a_wins else 10.0})
    scores = pd.DataFrame(rows).assign(split="val_seen", mode="andh")
    by_episode = compare_systems(
        scores, "A", "B", "ne_m", "val_seen", n_resamples=4000, ci_unit="episode"
    )
    by_dialog = compare_systems(
        scores, "A", "B", "ne_m", "val_seen", n_resamples=4000, ci_unit="trajectory"
    )
    assert by_episode.unit == "episode" and by_episode.n_units == 40
    assert by_dialog.unit == "trajectory" and by_dialog.n_units == 10 and by_dialog.p_exact
    assert by_dialog.difference == by_episode.difference == pytest.approx(-4.0)
    assert by_dialog.p_value > by_episode.p_value
    assert by_dialog.ci_high - by_dialog.ci_low > by_episode.ci_high - by_episode.ci_low
    # Exact over 2**10 patterns of dialog signs: |sum| >= 2 dialogs' worth, two-sided.
    signs = np.array([[1 if (p >> i) & 1 else -1 for i in range(10)] for p in range(1024)])
    dialog_sums = np.array([-80.0] * 6 + [80.0] * 4)
    expected = np.mean(np.abs(signs @ dialog_sums) >= 160.0 - 1e-9)
    assert by_dialog.p_value == pytest.approx(expected)
    with pytest.raises(MetricInputError, match="ci_unit"):
        compare_systems(scores, "A", "B", "ne_m", "val_seen", ci_unit="dialog")  # type: ignore[arg-type]


def test_scores_keep_how_an_episode_ran_and_why_it_failed(tmp_path: Path) -> None:
    """An audit found the error text and the execution mode dropped from the scores: a
    researcher filtering failures in pandas could not see why, nor which runs flew."""
    g = [square(0, 0), square(100, 0)]
    results = [
        result(g, g, episode_id="e0", extra={"execution_mode": "dynamics"}),
        result(
            [g[0]],
            g,
            "error",
            episode_id="e1",
            error='HTTP 500: {"error": "boom", "at": 3}\nTraceback (most recent call last)',
            extra={"execution_mode": "official"},
        ),
        result([g[0]], g, episode_id="e2"),  # results that do not say how it ran
        result([g[0]], g, "error", episode_id="e3", error="None"),  # text, not missing
    ]
    scores = score_results(results)
    assert scores["execution_mode"].tolist() == ["dynamics", "official", pd.NA, pd.NA]
    boom = 'HTTP 500: {"error": "boom", "at": 3}'
    assert scores["error"].tolist() == [pd.NA, boom, pd.NA, "None"]
    write_scores(tmp_path / "s.csv", scores, MetricConventions())
    back, _ = read_scores(tmp_path / "s.csv")
    for column in ("execution_mode", "error"):
        pd.testing.assert_series_equal(back[column], scores[column], check_names=True)
    # A file scored before the columns reads with them empty, in the same place.
    lines = (tmp_path / "s.csv").read_text().splitlines()
    header = lines[2].split(",")
    cut = [header.index("execution_mode"), header.index("error")]
    kept = [lines[0], lines[1]] + [
        ",".join(c for k, c in enumerate(line.split(",")) if k not in cut)
        for line in [lines[2], *[row for row in lines[3:] if '"' not in row]]
    ]
    (tmp_path / "old.csv").write_text("\n".join(kept) + "\n")
    old, _ = read_scores(tmp_path / "old.csv")
    assert list(old.columns) == list(back.columns)
    assert old["execution_mode"].isna().all() and old["error"].isna().all()
