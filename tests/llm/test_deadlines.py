"""A call's timeout bounds it from connect to last byte, and its deadline bounds it with
every retry: a server that answers one byte at a time cannot hold a call, or a run, longer."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.errors import LLMTransientError
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm import (
    GenerationConfig,
    LLMClient,
    LLMConfig,
    Message,
    RetryPolicy,
    create_backend,
)
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer, status, trickle
from skyvln_eval.metrics import read_results

HELLO = [Message("user", "Say hello.")]
#: About 300 bytes at 200 ms each: the whole answer would take about a minute, every byte
#: of it well within any read timeout.
SLOW = trickle('{"greeting": "hello"}', 0.2)
#: What a call bounded at half a second may not reach: half the answer's minute. Far above
#: the bound, so that a loaded machine cannot fail the test (one failed at 6 s, the openai
#: client's first import included, while another suite ran); far below what an unbounded
#: call takes, so that a bound that does not hold does. What is checked besides is counted:
#: attempts and their errors, not clock readings.
CUT_OFF_S = 30.0


def test_a_byte_at_a_time_answer_is_cut_off_at_the_timeout() -> None:
    with LoopbackOpenAIServer([SLOW, answer('{"greeting": "hi"}')]) as server:
        backend = create_backend("openai:slow-model", base_url=server.base_url)
        started = time.monotonic()
        with pytest.raises(LLMTransientError, match=r"within 0\.5 s .*connect to last byte"):
            backend.generate(HELLO, GenerationConfig(timeout_s=0.5))
        assert time.monotonic() - started < CUT_OFF_S
        # The backend is not left stuck on the abandoned request: the next call is answered.
        completion = backend.generate(HELLO, GenerationConfig(timeout_s=5.0))
    assert completion.text == '{"greeting": "hi"}'


def test_retries_fit_in_the_calls_deadline() -> None:
    # Twenty 0.5 s attempts would take 10 s: the 1.2 s deadline leaves room for two or
    # three, which the records count (their number, not a clock, is what is checked).
    policy = RetryPolicy(max_attempts=20, initial_delay_s=0.05, jitter=0.0, deadline_s=1.2)
    with LoopbackOpenAIServer([SLOW] * 20) as server:
        backend = create_backend("openai:slow-model", base_url=server.base_url)
        client = LLMClient(backend, retry=policy)
        started = time.monotonic()
        result = client.call("motion", HELLO, GenerationConfig(timeout_s=0.5))
        elapsed = time.monotonic() - started
    assert result.completion is None
    assert 2 <= len(result.records) <= 3
    assert elapsed < CUT_OFF_S, "twenty 0.5 s attempts must not outlast a 1.2 s deadline"
    assert all(r.latency_s < CUT_OFF_S for r in result.records)
    for record in result.records:  # each attempt cut off, the last one maybe by the deadline
        error = record.error or ""
        assert "connect to last byte" in error or "deadline" in error
    assert result.error is not None and "deadline" in result.error


def test_no_retry_waits_past_the_deadline() -> None:
    waits: list[float] = []
    policy = RetryPolicy(max_attempts=4, deadline_s=2.0)
    with LoopbackOpenAIServer([status(429, Retry_After="30"), answer("{}")]) as server:
        backend = create_backend("openai:busy-model", base_url=server.base_url)
        result = LLMClient(backend, retry=policy, sleep=waits.append).call(
            "motion", HELLO, GenerationConfig(timeout_s=1.0)
        )
        sent = len(server.requests)
    assert waits == [] and sent == 1  # a 30 s Retry-After cannot fit in a 2 s deadline
    assert result.completion is None and result.error is not None
    assert "HTTP 429" in result.error and "next wait is 30.00 s" in result.error


def test_the_default_deadline_comes_from_the_timeout() -> None:
    config = LLMConfig(timeout_s=3.0, retry={"max_attempts": 2})  # type: ignore[arg-type]
    assert config.call_deadline_s == 6.0
    pinned = LLMConfig(timeout_s=3.0, retry={"deadline_s": 4.0})  # type: ignore[arg-type]
    assert pinned.call_deadline_s == 4.0


def test_a_run_against_a_byte_at_a_time_server_ends_within_its_deadlines(
    tmp_path: Path, sample_dir: Path
) -> None:
    """The issue's case: 3 episodes on a server that trickles every answer."""
    llm = {
        "backend": "openai:slow-model",
        "base_url": "",
        "timeout_s": 0.5,
        "retry": {"max_attempts": 2, "initial_delay_s": 0.0},
    }
    with LoopbackOpenAIServer([SLOW] * 200) as server:
        llm["base_url"] = server.base_url
        config = {
            "system": "slow server",
            "data": str(sample_dir),
            "splits": ["val_unseen"],
            "limit": 3,
            "executor": "serial",
            "agent": {"name": "skyvln", "llm": llm},
        }
        path = tmp_path / "slow.yaml"
        path.write_text(yaml.safe_dump(config))
        started = time.monotonic()
        result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "run")])
        elapsed = time.monotonic() - started
    assert result.exit_code == 1, result.output
    assert "3 of 3 episode(s) ended in error" in result.output
    assert "connect to last byte" in result.output
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    calls = [c for row in rows for c in row.llm_calls]
    assert len(rows) == 3 and calls
    assert all(c.latency_s < CUT_OFF_S for c in calls), [c.latency_s for c in calls]
    # Each logical call is a first attempt and its one retry: none ran to its answer.
    assert all(c.attempt in (1, 2) for c in calls)
    assert all("connect to last byte" in (c.error or "") for c in calls)
    assert elapsed < len(calls) * CUT_OFF_S  # were any answer waited for, one alone took 60 s
