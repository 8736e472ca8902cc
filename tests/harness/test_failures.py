"""A failure never looks like a result: a dead LLM endpoint, an unpriced model and the
rule stand-in, through `reproduce` and `run` as a user calls them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer, status
from skyvln_eval.metrics import read_results

FAST_RETRY = {"max_attempts": 2, "initial_delay_s": 0.0, "max_delay_s": 0.0}
#: What Gemma 3 270M wrote as sub-goals under its grammar.
JUNK_SUBGOALS = json.dumps(
    {"subgoals": [{"kind": "pass", "landmark": "}, {", "side": "left"}], "context_landmarks": []}
)


def _llm(base_url: str, model: str, **extra: Any) -> dict[str, Any]:
    return {
        "backend": f"openai:{model}",
        "base_url": base_url,
        "api_key_env": "SKYVLN_TEST_KEY",
        "retry": FAST_RETRY,
        **extra,
    }


def _plan(path: Path, data: str, dead_url: str, live_url: str, junk_url: str) -> Path:
    full = {"label": "Full", "mode": "official", "agent": {"name": "skyvln"}}
    plan = {
        "name": "faults",
        "data": data,
        "limit": 2,
        "resamples": 20,
        "table1": {"splits": ["test_unseen"], "systems": [full]},
        "table2": {
            "split": "test_unseen",
            "system": full,
            "backends": [
                {"label": "dead endpoint", "llm": _llm(dead_url, "dead-model")},
                # Answers (as the rule backend would), but its model has no price.
                {
                    "label": "unpriced model",
                    "llm": _llm(live_url, "unpriced-model", send_task_data=True),
                },
                # Answers, but its sub-goals are fragments no dialog holds.
                {"label": "junk sub-goals", "llm": _llm(junk_url, "junk", send_task_data=True)},
                {"label": "rule-based (not an LLM)", "llm": {"backend": "rule"}},
            ],
            "environment_variable": None,
        },
        "control_figures": {"controllers": [], "cases": []},
        "trajectory_figures": 0,
    }
    path.write_text(yaml.safe_dump(plan))
    return path


def _reproduce(plan: Path, out: Path, *extra: str) -> Any:
    args = ["reproduce", "--plan", str(plan), "--out", str(out), "--workers", "1"]
    return CliRunner().invoke(app, [*args, "--executor", "serial", *extra])


def _row(table: str, label: str) -> list[str]:
    line = next(line for line in table.splitlines() if line.startswith(f"| {label}"))
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_a_dead_endpoint_is_an_error_in_every_table_and_fails_the_command(
    tmp_path: Path, sample_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    out = tmp_path / "out"
    with (
        LoopbackOpenAIServer([status(500)] * 500) as dead,
        LoopbackOpenAIServer() as live,
        LoopbackOpenAIServer([answer(JUNK_SUBGOALS, task="subgoals")] * 100) as junk,
    ):
        urls = (dead.base_url, live.base_url, junk.base_url)
        plan = _plan(tmp_path / "faults.yaml", str(sample_dir), *urls)
        failed = _reproduce(plan, out)
        # The user allows every episode to err: the command passes, the rows do not change.
        allowed = _reproduce(plan, out, "--fail-on-error", "1.0")
    assert failed.exit_code == 1, failed.output
    assert "dead endpoint: 2 of 2 episode(s) ended in error" in failed.output
    assert "HTTP 500" in failed.output  # why: the first error text of its kind
    assert allowed.exit_code == 0, allowed.output

    rows = read_results(next(out.glob(f"runs/backends/dead-endpoint/*/{RESULTS_FILE}")))
    assert [r.status for r in rows] == ["error", "error"]
    assert all("no LLM call" in (r.error or "") for r in rows)
    assert all(r.fallback_decisions == r.decisions >= 1 for r in rows)

    table2 = (out / "tables" / "table2.md").read_text()
    header = [cell.strip() for cell in table2.splitlines()[0].strip("|").split("|")]
    dead_row = dict(zip(header, _row(table2, "dead endpoint"), strict=True))
    assert dead_row["Unseen Testing Error/% ↓"].strip("*<u>/") == "100.00"
    assert dead_row["Unseen Testing Call fail/% ↓"].strip("*<u>/") == "100.00"
    assert dead_row["Unseen Testing Fallback/% ↓"].strip("*<u>/") == "100.00"
    assert dead_row["Unseen Testing Degraded/% ↓"].strip("*<u>/") == "0.00"  # errors, not that
    # Sub-goals refused at every try: the decisions are the model's, the episodes degraded.
    junk_row = dict(zip(header, _row(table2, "junk sub-goals"), strict=True))
    assert junk_row["Unseen Testing Degraded/% ↓"].strip("*<u>/") == "100.00"
    assert junk_row["Unseen Testing Fallback/% ↓"].strip("*<u>/") == "0.00"
    assert junk_row["Unseen Testing Error/% ↓"].strip("*<u>/") == "0.00"
    # Its episodes score as failures, but a 0 would read as a result: the cells say so.
    assert dead_row["Unseen Testing SR/% ↑"] == dead_row["Unseen Testing NE/m ↓"] == "error"
    assert "Episodes that ended in error: dead endpoint on Unseen Testing 2 of 2" in table2
    # Unknown cost is "n/a", never 0: in Table II, the cost table, the summary CSV ...
    unpriced = dict(zip(header, _row(table2, "unpriced model"), strict=True))
    assert unpriced["Unseen Testing Cost/$ ↓"] == "n/a"
    assert unpriced["Unseen Testing Error/% ↓"].strip("*<u>/") == "0.00"
    rule = dict(zip(header, _row(table2, "rule-based (not an LLM)"), strict=True))
    assert rule["Unseen Testing Cost/$ ↓"].strip("*<u>/") == "0.0000"  # known to be free
    # Neither the dead endpoint (it fails fast) nor the stand-in (no network, not an LLM)
    # is marked the best or second of the backends on any column.
    for row in (dead_row, rule):
        assert not [cell for cell in row.values() if "**" in cell or "<u>" in cell], row
    # The servers of these rows are sent the task data (the loopback answers from it as
    # the rule stand-in does): marked, and not ranked either, whatever model they name.
    assert (
        "Not ranked (a reference, not a competitor): rule-based (not an LLM), "
        "unpriced model ¶, junk sub-goals ¶." in table2
    )
    assert "¶ the server was sent each request's task data" in table2
    cost_table = (out / "tables" / "cost.md").read_text()
    cost_header = [c.strip() for c in cost_table.splitlines()[2].strip("|").split("|")]
    cost_row = dict(zip(cost_header, _row(cost_table, "unpriced model"), strict=True))
    assert cost_row["llm_cost_usd"] == "n/a" and cost_row["llm_prompt_tokens"] != "n/a"
    summary = pd.read_csv(out / "scores" / "summary.csv", comment="#")
    cost = summary[(summary.system == "unpriced model") & (summary.metric == "llm_cost_usd")]
    assert len(cost) == 1 and cost["mean"].isna().all()
    assert "n/a" in (out / "scores" / "summary.csv").read_text()
    # ... and SUMMARY.md counts each status and inlines the tables.
    page = (out / "SUMMARY.md").read_text()
    assert "2 error (no usable LLM answer" in page and "n/a" in page
    assert "| dead endpoint (Table II) | test_unseen | 2 | 0 | 0 | 2 |" in page
    # Table I says its rows were answered by the rule stand-in.
    table1 = (out / "tables" / "table1.md").read_text()
    assert "| Full † |" in table1 and "† LLM modules answered by the rule-based" in table1
    report = json.loads(next(out.glob("runs/backends/unpriced-model/*/run.json")).read_text())
    assert report["statuses"] == {"ok": 2}
    assert report["structured_output"] == {"openai:unpriced-model": "json_schema"}


def test_run_exits_non_zero_when_episodes_err_unless_allowed(
    tmp_path: Path, sample_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    with LoopbackOpenAIServer([status(503)] * 200) as dead:
        config = {
            "system": "dead",
            "data": str(sample_dir),
            "splits": ["val_unseen"],
            "limit": 1,
            "executor": "serial",
            "agent": {"name": "navgpt", "llm": _llm(dead.base_url, "dead-model")},
        }
        path = tmp_path / "dead.yaml"
        path.write_text(yaml.safe_dump(config))
        args = ["run", str(path), "--out", str(tmp_path / "run")]
        failed = CliRunner().invoke(app, args)
        allowed = CliRunner().invoke(app, [*args, "--fail-on-error", "1"])
    assert failed.exit_code == 1 and "1 of 1 episode(s) ended in error" in failed.output
    assert "(1 error)" in failed.output  # the report line counts statuses
    assert allowed.exit_code == 0, allowed.output
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    assert row.status == "error" and row.llm_modules()["navgpt"]["failed_calls"] == 1


def test_a_model_refusing_decoding_parameters_runs_and_the_run_says_what_went_unsent(
    tmp_path: Path, sample_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    with LoopbackOpenAIServer(parameters="openai_reasoning") as reasoning:
        config = {
            "system": "reasoning",
            "data": str(sample_dir),
            "splits": ["val_unseen"],
            "limit": 1,
            "executor": "serial",
            "agent": {
                "name": "skyvln",
                "llm": _llm(reasoning.base_url, "o-model", send_task_data=True),
            },
        }
        path = tmp_path / "reasoning.yaml"
        path.write_text(yaml.safe_dump(config))
        result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "run")])
        bodies = [r["body"] for r in reasoning.requests]
    assert result.exit_code == 0, result.output
    assert "not sent (the model refuses them; its defaults applied): " in result.output
    assert "openai:o-model: temperature" in result.output
    # Every call after the first refusals went in the form the model takes.
    assert "max_tokens" not in bodies[-1] and "temperature" not in bodies[-1]
    assert bodies[-1]["max_completion_tokens"] >= 16
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    assert row.status == "ok" and row.llm_calls
    answered = [c for c in row.llm_calls if c.outcome == "ok"]
    assert answered and all(c.server_defaults == ("temperature",) for c in answered)
    assert all(c.temperature is None for c in answered)
    report = json.loads((tmp_path / "run" / "run.json").read_text())
    assert report["server_defaults"] == {"openai:o-model": "temperature"}
