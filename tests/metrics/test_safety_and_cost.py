"""Safety / control metrics on synthetic control logs, and LLM cost aggregation."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from skyvln_eval.errors import DataError
from skyvln_eval.llm_records import ModuleFailure
from skyvln_eval.metrics import (
    CONTROL_LOG_COLUMNS,
    LlmCall,
    MetricConventions,
    control_metrics,
    episode_costs,
    module_costs,
    read_control_log,
    score_results,
    summarise,
    summarise_control,
    summarise_costs,
)
from skyvln_eval.metrics.scores_io import read_scores, write_scores
from tests.conftest import modules_loaded_by
from tests.metrics.helpers import result, square


def control_log(
    controller: str = "nmpc", scenario: str = "static", steps: int = 50, offset_m: float = 0.0
) -> pd.DataFrame:
    """A hand-made log: reference along x at 1 m/s, flown ``offset_m`` to the side."""
    t = np.arange(steps) * 0.1
    zeros = np.zeros(steps)
    return pd.DataFrame(
        {
            "controller": controller, "scenario": scenario, "t_s": t,
            "x_m": t, "y_m": zeros + offset_m, "z_m": zeros + 10.0,
            "vx_m_s": zeros + 1.0, "vy_m_s": zeros, "vz_m_s": zeros,
            "roll_rad": zeros, "pitch_rad": zeros + 0.02, "yaw_rad": zeros + math.pi - 0.01,
            "ref_x_m": t, "ref_y_m": zeros, "ref_z_m": zeros + 10.0,
            "ref_yaw_rad": zeros - math.pi + 0.01,
            "cmd_thrust_m_s2": zeros + 9.81, "cmd_roll_rad": zeros, "cmd_pitch_rad": zeros,
            "solve_time_ms": np.linspace(0.2, 1.2, steps), "iterations": np.full(steps, 3),
            "status": "ok", "solve_failed": np.arange(steps) == 7,
            "min_clearance_m": np.full(steps, np.inf) if scenario == "static" else 5.0 - t,
            "collision": (5.0 - t) < 0.5 if scenario == "dynamic" else np.zeros(steps, bool),
            "constraint_violation": np.arange(steps) >= steps - 2,
        }
    )  # fmt: skip


def test_control_summary_hand_computed() -> None:
    summary = summarise_control(control_log(offset_m=0.3))
    # 50 steps of 0.1 s: from the first's start (t 0) to the last's end (t 4.9 + 0.1).
    assert summary.steps == 50 and summary.duration_s == pytest.approx(5.0)
    one_step = summarise_control(control_log(offset_m=0.3).iloc[:1])
    assert one_step.duration_s is None  # its length is not in the log
    assert summary.rmse_x_m == 0.0 and summary.rmse_y_m == pytest.approx(0.3)
    assert summary.rmse_pitch_rad == pytest.approx(0.02)
    assert summary.rmse_yaw_rad == pytest.approx(0.02)  # wrapped across +-pi, not 2 pi - 0.02
    assert summary.min_clearance_m is None  # no obstacles
    assert summary.soft_steps == 0
    soft = control_log().assign(status=["solved_soft"] * 3 + ["solved"] * 47)
    assert summarise_control(soft).soft_steps == 3  # the obstacle constraint relaxed 3 times
    # The PID has no obstacle constraint: nothing to relax is no value, not 0.
    assert summarise_control(control_log("pid")).soft_steps is None
    # Nor has an MPC built without obstacle slots (an audit saw its "relaxed steps" 0).
    blind = control_log("mpc")
    blind.attrs["settings"] = {"controller_settings": {"max_obstacles": 0}}
    assert summarise_control(blind).soft_steps is None
    assert control_metrics(blind)["soft_steps"].isna().all()
    # Given by argument (as the harness does: pandas deep-copies attrs at every column read).
    slots = {"controller_settings": {"max_obstacles": 0}}
    assert summarise_control(control_log("mpc"), settings=slots).soft_steps is None
    assert summarise_control(control_log("mpc"), settings={}).soft_steps == 0
    assert summary.collision_steps == 0 and not summary.collided
    assert summary.solve_failures == 1 and summary.constraint_violation_steps == 2
    assert summary.solve_time_max_ms == pytest.approx(1.2)
    assert summary.solve_time_p50_ms == pytest.approx(0.7)


def test_the_metrics_do_not_import_the_control_stack() -> None:
    # Whether a controller has an obstacle constraint is asked of the control registry
    # only when a log is summarised: scoring and notebooks need no CasADi (4 s to import).
    assert modules_loaded_by("skyvln_eval.metrics", ("casadi", "skyvln_eval.control")) == []


def test_control_metrics_per_controller_and_scenario(tmp_path: Path) -> None:
    log = pd.concat([control_log("nmpc", "dynamic"), control_log("pid", "dynamic", offset_m=1.0)])
    path = tmp_path / "log.parquet"
    log.to_parquet(path)
    table = control_metrics(read_control_log(path)).set_index("controller")
    assert table.loc["nmpc", "min_clearance_m"] == pytest.approx(5.0 - 4.9)
    assert table.loc["nmpc", "collision_steps"] == 4  # t = 4.6, 4.7, 4.8, 4.9 (5.0 - t < 0.5)
    assert bool(table.loc["pid", "collided"])
    assert table.loc["pid", "rmse_y_m"] == pytest.approx(1.0)
    log.to_csv(tmp_path / "log.csv", index=False)
    assert len(control_metrics(read_control_log(tmp_path / "log.csv"))) == 2


def test_bad_control_logs_are_located() -> None:
    with pytest.raises(DataError, match=r"missing column\(s\) \['collision'\]"):
        control_metrics(control_log().drop(columns=["collision"]), "run.parquet")
    bad = control_log()
    bad.loc[3, "x_m"] = np.nan
    with pytest.raises(DataError, match="row 3, column 'x_m': non-finite"):
        control_metrics(bad)
    numbers = control_log().assign(collision=0)  # 0/1, not booleans
    with pytest.raises(DataError, match="column 'collision' must be boolean, got int64"):
        control_metrics(numbers)
    unnamed = control_log()
    unnamed.loc[5, "status"] = None
    with pytest.raises(DataError, match="row 5, column 'status': missing value"):
        control_metrics(unnamed)
    assert set(CONTROL_LOG_COLUMNS) <= set(control_log().columns)


def test_control_summaries_reach_the_scores_without_nan_in_averages() -> None:
    g = [square(0, 0), square(50, 0)]
    with_ctrl = result(g, g, control=summarise_control(control_log("nmpc", "dynamic")))
    static = result(g, g, episode_id="b", control=summarise_control(control_log()))
    plain = result(g, g, episode_id="c")
    scores = score_results([with_ctrl, static, plain])
    assert scores.has_control.tolist() == [True, True, False]
    summary = summarise(scores, ["min_clearance_m", "collided", "success"]).set_index("metric")
    assert summary.loc["min_clearance_m", "n"] == 1  # only the episode with obstacles
    assert summary.loc["collided", "n"] == 2 and summary.loc["collided", "mean"] == 50.0
    assert summary.loc["success", "n"] == 3


def test_a_flight_that_touched_an_obstacle_never_succeeds_unless_the_conventions_say() -> None:
    # A crash ends the flight where it happened: here in the destination's view, with a
    # path shorter than the shortest one. On its views alone it would succeed with SPL 1.
    g = [square(0, 0), square(50, 0), square(100, 0)]
    crashed = summarise_control(control_log("nmpc", "dynamic"))
    assert crashed.collided
    safe = summarise_control(control_log())
    results = [
        result([g[0], square(95, 0)], g, episode_id="crash", control=crashed),
        result([g[0], square(95, 0)], g, episode_id="safe", control=safe),
    ]
    scores = score_results(results).set_index("episode_id")
    for metric in ("success", "oracle_success", "spl", "r2r_sr", "r2r_osr", "r2r_spl", "sdtw"):
        assert scores.loc["crash", metric] == 0.0, metric
        assert scores.loc["safe", metric] > 0.0, metric
    # Where it ended is still measured: NE and GP as flown.
    assert scores.loc["crash", "ne_m"] == scores.loc["safe", "ne_m"]
    assert scores.loc["crash", "gp_m"] == scores.loc["safe", "gp_m"]
    lenient = MetricConventions(collision_fails=False)
    on_views = score_results(results, lenient).set_index("episode_id")
    assert on_views.loc["crash", "success"] == 1.0 and on_views.loc["crash", "spl"] == 1.0
    assert "never succeeds" in MetricConventions().describe()
    assert "on their views alone" in lenient.describe()


def _call(module: str, **fields: object) -> LlmCall:
    return LlmCall(module=module, backend="openai", model="gpt-4o", **fields)  # type: ignore[arg-type]


def test_llm_costs_per_episode_and_module() -> None:
    g = [square(0, 0), square(50, 0)]
    calls = [
        _call("subgoals", prompt_tokens=1000, completion_tokens=100, cost_usd=0.01, latency_s=2.0),
        _call("motion", prompt_tokens=500, completion_tokens=50, cost_usd=0.005, latency_s=1.0),
        _call("motion", prompt_tokens=500, completion_tokens=50, cost_usd=0.0, cached=True),
        _call("motion", outcome="failed", error="timeout", latency_s=30.0, cost_usd=0.0),
    ]
    results = [result(g, g, llm_calls=calls), result(g, g, episode_id="b")]
    scores = score_results(results)
    assert scores.llm_calls.tolist() == [4.0, 0.0]
    assert scores.llm_cost_usd[0] == pytest.approx(0.015)
    assert scores.llm_cached_calls[0] == 1 and scores.llm_failed_calls[0] == 1
    assert scores.llm_call_failure_rate[0] == pytest.approx(0.25)
    assert np.isnan(scores.llm_call_failure_rate[1])  # no call: nothing to rate
    costs = summarise_costs(results).set_index("module")
    assert costs.loc["motion", "llm_calls"] == 3 and costs.loc["all", "llm_calls"] == 4
    assert costs.loc["motion", "llm_prompt_tokens_per_episode"] == pytest.approx(1000 / 2)
    assert costs.loc["subgoals", "latency_per_call_s"] == pytest.approx(2.0)
    assert costs.loc["all", "episodes"] == 2


def test_failed_attempts_add_the_tokens_they_reported_and_leave_the_cost_unknown() -> None:
    g = [square(0, 0), square(50, 0)]
    answered = _call("motion", prompt_tokens=500, completion_tokens=50, cost_usd=0.005)
    refused = _call("motion", outcome="failed", error="connection refused")  # no report
    billed = _call("motion", outcome="failed", error="timeout", prompt_tokens=300)
    mute = _call("motion", cost_usd=0.0)  # answered, but the server reported no usage
    scores = score_results(
        [
            result(g, g, llm_calls=[answered, refused]),
            result(g, g, episode_id="b", llm_calls=[answered, billed]),
            result(g, g, episode_id="c", llm_calls=[answered, mute]),
        ]
    )
    assert scores.llm_prompt_tokens.tolist()[:2] == [500.0, 800.0]
    assert np.isnan(scores.llm_prompt_tokens[2])  # an answer without a count: unknown
    assert np.isnan(scores.llm_cost_usd[0]) and np.isnan(scores.llm_cost_usd[1])
    assert scores.llm_unpriced_requests.tolist() == [1.0, 1.0, 0.0]
    # Only failed attempts unpriced: what the answered calls cost is a known lower bound.
    assert scores.llm_cost_lower_usd.tolist() == pytest.approx([0.005, 0.005, 0.005])
    # Its mean is unknown: nothing was resampled, so no interval method, count or seed.
    cost = summarise(scores, ["llm_cost_usd", "success"], n_resamples=50).set_index("metric")
    assert np.isnan(cost.loc["llm_cost_usd", "mean"]) and np.isnan(cost.ci_low["llm_cost_usd"])
    assert cost.loc["llm_cost_usd", ["ci_method", "ci_resamples", "ci_seed"]].isna().all()
    assert cost.ci_method["success"] == "wilson_trajectories"  # a known mean keeps its own
    unpriced = _call("motion", prompt_tokens=500, completion_tokens=50)  # answered, no price
    alone = score_results([result(g, g, episode_id="d", llm_calls=[answered, unpriced])])
    assert np.isnan(alone.llm_cost_lower_usd[0]) and np.isnan(alone.llm_cost_usd[0])


def test_no_lower_bound_of_the_cost_without_one_priced_attempt() -> None:
    # The audit's model had no price and every call failed: nothing was answered, so "every
    # answered call is priced" held vacuously, and Table II showed "≥0.0000" with that note.
    g = [square(0, 0), square(50, 0)]
    dead = [
        _call("motion", outcome="failed", error="HTTP 503", attempt=1, final=False),
        _call("motion", outcome="failed", error="HTTP 503", attempt=2),
    ]
    refused = _call("motion", outcome="refused", error="level refused", final=False)
    answered = _call("motion", prompt_tokens=500, completion_tokens=50, cost_usd=0.005, attempt=2)
    scores = score_results(
        [
            result(g, g, llm_calls=dead),
            result(g, g, episode_id="b", llm_calls=[refused, answered]),
            result(g, g, episode_id="c"),  # no call: a known 0
            # A refused form costs 0 whatever the price: no sign that the model has one.
            result(g, g, episode_id="d", llm_calls=[replace(refused, cost_usd=0.0), *dead]),
        ]
    )
    assert np.isnan(scores.llm_cost_lower_usd[3])
    assert np.isnan(scores.llm_cost_lower_usd[0]) and np.isnan(scores.llm_cost_usd[0])
    assert scores.llm_cost_lower_usd[1] == pytest.approx(0.005)  # a priced answer shows a price
    assert scores.llm_cost_lower_usd[2] == 0.0 and scores.llm_cost_usd[2] == 0.0


def test_cost_rows_name_their_episode_and_module_rows_do_not_contradict_themselves(
    tmp_path: Path,
) -> None:
    """An audit found episode_costs rows with only an index (no way to join them to the
    scores), and module rows saying decisions 0 and fallback rate n/a next to one
    fallback decision."""
    g = [square(0, 0), square(50, 0)]
    calls = [_call("motion", outcome="invalid", error="bad"), _call("motion", cost_usd=0.001)]
    failure = ModuleFailure(step_index=2, module="motion", reason="bad", substitute="stop action")
    results = [
        result(
            g, g, episode_id="1913__0_1", llm_calls=calls, module_failures=(failure,), decisions=4
        ),
        result(g, g, episode_id="1913__0_2"),
    ]
    costs = episode_costs(results)
    assert costs[["system", "split", "mode", "episode_id"]].values.tolist() == [
        ["agent", "val_seen", "andh", "1913__0_1"],
        ["agent", "val_seen", "andh", "1913__0_2"],
    ]
    joined = score_results(results).merge(costs, on=["system", "split", "mode", "episode_id"])
    assert len(joined) == 2 and joined["llm_requests_y"].tolist() == [2.0, 0.0]
    motion = module_costs(results).set_index("module").loc["motion"]
    assert motion["decisions"] == 4 and motion["fallback_decisions"] == 1
    assert motion["fallback_rate"] == pytest.approx(0.25)
    # Requests, not calls: two attempts of one call, the first (invalid) unpriced.
    assert costs["llm_unpriced_requests"].tolist() == [1.0, 0.0]


def test_a_scores_file_with_the_old_name_of_unpriced_requests_reads(tmp_path: Path) -> None:
    g = [square(0, 0), square(50, 0)]
    scores = score_results([result(g, g, llm_calls=[_call("motion")])])
    write_scores(tmp_path / "s.csv", scores, MetricConventions())
    text = (tmp_path / "s.csv").read_text().replace("llm_unpriced_requests", "llm_unpriced_calls")
    (tmp_path / "old.csv").write_text(text)
    old, _ = read_scores(tmp_path / "old.csv")
    assert "llm_unpriced_calls" not in old.columns
    assert old["llm_unpriced_requests"].tolist() == scores["llm_unpriced_requests"].tolist()


def test_a_scores_file_from_before_segments_cut_short_reads_it_as_unknown(
    tmp_path: Path,
) -> None:
    # The column came after the format's version: a file scored before is read, not refused
    # ("lacks column(s) segments_cut_short"), and says nothing of it.
    g = [square(0, 0), square(50, 0)]
    write_scores(tmp_path / "s.csv", score_results([result(g, g)]), MetricConventions())
    header, *rows = (tmp_path / "s.csv").read_text().splitlines()[2:]
    at = header.split(",").index("segments_cut_short")
    kept = [
        ",".join(c for k, c in enumerate(line.split(",")) if k != at) for line in [header, *rows]
    ]
    head = (tmp_path / "s.csv").read_text().splitlines()[:2]
    (tmp_path / "old.csv").write_text("\n".join([*head, *kept]) + "\n")
    old, _ = read_scores(tmp_path / "old.csv")
    assert old["segments_cut_short"].isna().all()


def test_scores_have_the_same_column_types_scored_or_read_back(tmp_path: Path) -> None:
    """An audit: score_results gave wall_s as Float64 (pd.NA where not recorded) and
    read_scores as float64 (NaN), so one frame compared unequal to itself saved."""
    g = [square(0, 0), square(50, 0)]
    scores = score_results([result(g, g, extra={"wall_s": 2}), result(g, g, episode_id="e2")])
    assert scores.wall_s.dtype == np.float64
    assert scores.wall_s.iloc[0] == 2.0 and math.isnan(scores.wall_s.iloc[1])
    write_scores(tmp_path / "s.csv", scores, MetricConventions())
    again, _ = read_scores(tmp_path / "s.csv")
    assert {c: str(again[c].dtype) for c in scores} == {c: str(scores[c].dtype) for c in scores}
