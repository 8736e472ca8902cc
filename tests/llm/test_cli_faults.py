"""LLM server faults through `skyvln-eval run`, as a user meets them: refused credentials,
a context overflow, a 400-digit number in an action."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm.loopback import (
    LoopbackOpenAIServer,
    Reply,
    answer,
    echo_key,
    key_forms,
    status,
)
from skyvln_eval.metrics import read_results
from tests.conftest import CliOutcome

Cli = Callable[..., CliOutcome]
SENTINEL = "sk-SENTINEL-15c0ffee15"
FAST_RETRY = {"max_attempts": 2, "initial_delay_s": 0.0, "max_delay_s": 0.0}


def _config_file(tmp_path: Path, sample_dir: Path, base_url: str, **overrides: Any) -> Path:
    config = {
        "system": "faulty server",
        "data": str(sample_dir),
        "splits": ["val_unseen"],
        "limit": 2,
        "executor": "serial",
        "agent": {
            "name": "skyvln",
            "llm": {
                "backend": "openai:test-model",
                "base_url": base_url,
                "api_key_env": "SKYVLN_TEST_KEY",
                "send_task_data": True,  # the server answers as the rule backend from it
                "retry": FAST_RETRY,
                "timeout_s": 5.0,
            },
        },
        **overrides,
    }
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_refused_credentials_stop_the_run_at_once_and_the_run_resumes_once_fixed(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", SENTINEL)
    run_dir = tmp_path / "run"
    # The server echoes the key in its error, as real services do with a wrong key.
    refusals: list[Reply] = [status(401) for _ in range(50)]
    with LoopbackOpenAIServer(refusals, error_message=f"Incorrect API key: {SENTINEL}") as server:
        path = _config_file(
            tmp_path, sample_dir, server.base_url, limit=4, executor="threads", workers=2
        )
        stopped = cli("run", str(path), "--out", str(run_dir))
        sent = len(server.requests)
        server.script.clear()  # the key is fixed: from now on the server answers
        resumed = cli("run", str(path), "--out", str(run_dir))
    assert stopped.code == 1, stopped
    endpoint = f"openai:test-model@{server.base_url}"
    assert (
        f"faulty server: the run stopped early: {endpoint} refused the credentials (HTTP 401"
        in stopped.err
    )
    assert "check the API key in the environment variable SKYVLN_TEST_KEY" in stopped.err
    # How many never ran, and that the same command runs them once the key is fixed.
    # The stopping row is no result and no error: the counts say so (it said "1 error").
    assert re.search(r"\b4 of 4 selected episode\(s\) have no result", stopped.err)
    said = " ".join((stopped.out + stopped.err).split())
    assert (
        "(the one that stopped the run among them); once the cause is fixed, the same "
        "command runs them" in said
    )
    assert "ended in error" not in said and "--retry-failed" not in said
    assert "1 error" not in said  # nor on the progress bar (an audit: "1/2 ... 1 error")
    assert sent <= 2, "at once: one request per worker, not one per episode"
    everything = stopped.out + stopped.err + resumed.out + resumed.err
    everything += "".join(p.read_text(errors="replace") for p in run_dir.rglob("*") if p.is_file())
    assert SENTINEL not in everything and "[API key]" in stopped.err
    # The episodes the refusal stopped are not counted as done: they run again.
    assert resumed.code == 0, resumed
    rows = read_results(run_dir / RESULTS_FILE)
    assert len(rows) == 4 and len({r.key for r in rows}) == 4
    assert all(r.status == "ok" and "fatal" not in r.extra for r in rows)


def test_a_context_overflow_is_recorded_and_structured_output_stays_on(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    overflow = "This model's maximum context length is 8192 tokens. However, you requested 9001."
    script = [status(400, task="motion", message=overflow)]
    with LoopbackOpenAIServer(script) as server:
        path = _config_file(tmp_path, sample_dir, server.base_url, limit=1)
        outcome = cli("run", str(path), "--out", str(tmp_path / "run"))
        requests = [r for r in server.requests if r["task"] == "motion"]
    # The one decision's call overflowed, so its action was the fallback: the model chose
    # no move of the episode, an error (exit 1), whose reason is the overflow.
    assert outcome.code == 1, outcome
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    failed = [c for c in row.llm_calls if c.outcome == "failed"]
    assert len(failed) == 1 and "LLMContextOverflowError" in (failed[0].error or "")
    assert "maximum context length" in (failed[0].error or "")
    # Not retried unchanged, not taken for a refusal of the response format:
    first = requests[0]["body"]
    assert sum(r["body"] == first for r in requests) == 1
    assert all(r["body"]["response_format"]["type"] == "json_schema" for r in requests)
    report = json.loads((tmp_path / "run" / "run.json").read_text())
    assert report["structured_output"] == {"openai:test-model": "json_schema"}
    assert row.status == "error" and "maximum context length" in (row.error or "")
    assert (row.error or "").startswith("no action of the episode was the model's")


def test_an_outage_of_one_module_is_an_error_and_retry_failed_runs_it_again(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The sub-goals were answered, every motion call got 503s: each decision fell back to
    # STOP, and the episode was a 'degraded' failure to navigate, with exit 0 and no way
    # to run it again once the endpoint was back.
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    outage = [status(503, task="motion") for _ in range(2 * FAST_RETRY["max_attempts"])]
    run_dir = tmp_path / "run"
    with LoopbackOpenAIServer(outage) as server:
        path = _config_file(tmp_path, sample_dir, server.base_url, limit=2)
        down = cli("run", str(path), "--out", str(run_dir))
        assert not server.script, "every motion call of the two episodes met the outage"
        rows = read_results(run_dir / RESULTS_FILE)
        resumed = cli("run", str(path), "--out", str(run_dir))
        again = cli("run", str(path), "--out", str(run_dir), "--retry-failed")
    assert down.code == 1, down
    assert [r.status for r in rows] == ["error", "error"]
    assert all(any(c.module == "subgoals" and c.outcome == "ok" for c in r.llm_calls) for r in rows)
    assert (rows[0].error or "").startswith(
        "an LLM call got no answer (module motion, 2 attempt(s)); LLMTransientError: "
    )
    assert "--retry-failed" in down.err
    assert resumed.code == 1, "a resume leaves error rows be"
    assert again.code == 0, again
    assert [r.status for r in read_results(run_dir / RESULTS_FILE)] == ["ok", "ok"]


def test_a_model_that_never_chose_an_action_is_an_error_and_retry_failed_asks_it_again(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every motion answer had the wrong shape: each episode's one decision fell back to
    # STOP, and the run was 'degraded' with exit 0 (a table of zeros as a result). Then
    # --retry-failed, the endpoint fixed, replayed the unusable answers from the response
    # cache and sent nothing.
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    wrong = [answer('{"answer": 42}', task="motion") for _ in range(40)]
    run_dir = tmp_path / "run"
    with LoopbackOpenAIServer(wrong) as server:
        path = _config_file(tmp_path, sample_dir, server.base_url, limit=2)
        llm = yaml.safe_load(path.read_text())
        llm["agent"]["llm"]["cache_path"] = str(tmp_path / "llm-cache")
        path.write_text(yaml.safe_dump(llm))
        down = cli("run", str(path), "--out", str(run_dir))
        rows = read_results(run_dir / RESULTS_FILE)
        server.script.clear()  # the endpoint is fixed: it answers as the rule backend
        before = len(server.requests)
        again = cli("run", str(path), "--out", str(run_dir), "--retry-failed")
        asked = [r["task"] for r in server.requests[before:]]
    assert down.code == 1, down
    assert [r.status for r in rows] == ["error", "error"]
    assert all(r.decisions == 1 and r.fallback_decisions == 1 for r in rows)
    assert (rows[0].error or "").startswith(
        "no action of the episode was the model's: all 1 decision(s) fell back to the stop"
    )
    assert "motion" in asked and "subgoals" in asked, "the retried episodes asked the endpoint"
    assert again.code == 0, again
    retried = read_results(run_dir / RESULTS_FILE)
    assert [r.status for r in retried] == ["ok", "ok"]
    assert not any(c.cached for r in retried for c in r.llm_calls)


def test_a_400_digit_distance_is_refused_with_a_reason_and_repaired(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    huge = "9" * 400
    decision = (
        '{"thought": "far away", "action": {"type": "move_forward", "distance_m": ' + huge + "}}"
    )
    with LoopbackOpenAIServer([answer(decision, task="motion")]) as server:
        path = _config_file(tmp_path, sample_dir, server.base_url, limit=1)
        outcome = cli("run", str(path), "--out", str(tmp_path / "run"))
        requests = [r for r in server.requests if r["task"] == "motion"]
    assert outcome.code == 0, outcome
    assert "OverflowError" not in outcome.out + outcome.err
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    motion = [c for c in row.llm_calls if c.module == "motion"]
    assert [(c.repair, c.outcome) for c in motion[:2]] == [(False, "invalid"), (True, "ok")]
    reason = "field 'distance_m' is far outside the allowed [0, 400]"
    assert reason in (motion[0].error or "")
    # The repair request carried the huge answer back with the parser's reason.
    repair = requests[1]["body"]["messages"]
    assert huge in repair[-2]["content"] and reason in repair[-1]["content"]
    assert row.status == "ok"


def test_refused_credentials_stop_reproduce_with_the_reason_not_a_missing_table(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The stop used to surface as "no scores for system(s) [...]" from the tables.
    monkeypatch.setenv("SKYVLN_TEST_KEY", SENTINEL)
    full = {"label": "Full", "mode": "official", "agent": {"name": "skyvln"}}
    with LoopbackOpenAIServer([status(401) for _ in range(20)]) as server:
        llm = {
            "backend": "openai:test-model",
            "base_url": server.base_url,
            "api_key_env": "SKYVLN_TEST_KEY",
            "retry": FAST_RETRY,
        }
        plan = {
            "name": "refused",
            "data": str(sample_dir),
            "limit": 1,
            "resamples": 0,
            "table1": {"splits": ["test_unseen"], "systems": [full]},
            "table2": {
                "split": "test_unseen",
                "system": full,
                "backends": [{"label": "refused key", "llm": llm}],
                "environment_variable": None,
            },
            "control_figures": {"controllers": [], "cases": []},
            "trajectory_figures": 0,
            "recordings": 0,
        }
        path = tmp_path / "plan.yaml"
        path.write_text(yaml.safe_dump(plan))
        out = tmp_path / "out"
        stopped = cli("reproduce", "--plan", str(path), "--out", str(out), "--executor", "serial")
    assert stopped.code == 1, stopped
    assert "reproduce (refused) stopped before its tables" in stopped.err
    assert "refused the credentials (HTTP 401" in stopped.err
    assert "SKYVLN_TEST_KEY" in stopped.err and "no scores for" not in stopped.err
    assert not (out / "SUMMARY.md").exists()


def _stored_text(path: Path) -> str:
    """Everything a run file holds, as text: its bytes, and for an MCAP log the messages,
    metadata and attachments its compressed chunks hold."""
    data = path.read_bytes()
    parts = [data.decode("utf-8", errors="replace")]
    if path.suffix == ".mcap":
        from mcap.reader import make_reader

        with path.open("rb") as stream:
            reader = make_reader(stream)
            parts += [m.data.decode("utf-8", "replace") for _, _, m in reader.iter_messages()]
            parts += [json.dumps(m.metadata) for m in reader.iter_metadata()]
            parts += [a.data.decode("utf-8", "replace") for a in reader.iter_attachments()]
    return "\n".join(parts)


def test_a_key_echoed_in_escaped_forms_is_in_no_file_of_the_run_and_no_output(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The audit's server escaped "/" as "\/" (legal JSON): the exact-text scrub missed it,
    # and the key went to results.jsonl, run.json, the MCAP logs and stderr.
    key = "sk-SENTINEL/15c0+ffee=15"
    monkeypatch.setenv("SKYVLN_TEST_KEY", key)
    run_dir = tmp_path / "run"
    with LoopbackOpenAIServer([echo_key(400) for _ in range(200)]) as server:
        path = _config_file(tmp_path, sample_dir, server.base_url, limit=1)
        outcome = cli("run", str(path), "--out", str(run_dir))
        sent = len(server.requests)
    assert outcome.code == 1 and sent > 1, outcome  # an error episode, recorded
    files = [p for p in run_dir.rglob("*") if p.is_file()]
    assert {"results.jsonl", "run.json"} <= {p.name for p in files}
    assert any(p.suffix == ".mcap" for p in files)
    everything = outcome.out + outcome.err + "".join(_stored_text(p) for p in files)
    for name, form in key_forms(key).items():
        assert form not in everything, name
    assert "[API key]" in outcome.err
