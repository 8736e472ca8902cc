"""The SkyVLN agent on the openai backend survives every fault a server can throw at it,
and the API key never reaches a file the toolkit writes."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from skyvln_eval.agent import AgentConfig, Stop, build_agent
from skyvln_eval.errors import LLMAuthError
from skyvln_eval.fileio import atomic_write_json
from skyvln_eval.harness import run_official_episode
from skyvln_eval.llm import LLMConfig, RetryConfig
from skyvln_eval.llm.loopback import (
    LoopbackOpenAIServer,
    answer,
    hang,
    malformed,
    rule,
    status,
    truncated,
)
from tests.toy_worlds import town_episode, town_world

RED = "Go north. The destination is a small restaurant with a red roof."
FAST = RetryConfig(max_attempts=8, initial_delay_s=0.01, max_delay_s=0.05)


def openai_agent(base_url: str, tmp_path: Path, model: str = "fake-model") -> AgentConfig:
    llm = LLMConfig(
        backend=f"openai:{model}",
        base_url=base_url,
        # Long enough that a loaded machine's slow answer is no timeout (at 0.5 s the
        # script's faults met other calls than the test's under load), short of the hang.
        timeout_s=2.0,
        retry=FAST,
        cache_path=str(tmp_path / "llm-cache.sqlite"),
        send_task_data=True,  # the loopback server answers as the rule backend from it
    )
    return AgentConfig(llm=llm, detector={"miss_rate": 0.0, "false_positive_rate": 0.0})  # type: ignore[arg-type]


def test_the_agent_survives_every_fault_with_retries_repair_and_fallback(tmp_path: Path) -> None:
    script = [
        status(429, Retry_After="0.01"),  # the first call (sub-goals) meets every transport fault
        status(500),
        hang(5.0),
        malformed(),
        truncated(),
        answer("I would fly north, it looks nice.", task="motion"),  # step 0: prose ...
        rule(task="motion"),  # ... repaired
        answer("Let me think about it.", task="motion"),  # step 1: prose twice -> fallback
        answer("Still thinking!", task="motion"),
    ]
    with LoopbackOpenAIServer(script) as server:
        rollout = run_official_episode(
            build_agent(openai_agent(server.base_url, tmp_path)), town_episode(RED), town_world()
        )
        requests = server.requests
    assert rollout.stop_reason == "stop" and rollout.error is None
    errors = [r.error for r in rollout.llm_calls if r.error]
    for needle in ("HTTP 429", "HTTP 500", "timeout", "malformed", "body cut short"):
        assert sum(needle in e for e in errors) == 1, needle
    assert sum("invalid output" in e for e in errors) == 3
    # Step 0: the prose answer was sent back once and the repair worked.
    assert rollout.traces[0]["repaired"] and rollout.traces[0]["fallback"] is None
    motion = [r for r in rollout.llm_calls if r.module == "motion"]
    assert [(r.repair, r.outcome) for r in motion[:2]] == [(False, "invalid"), (True, "ok")]
    # The repair was asked at a higher temperature than the first try, with the reason.
    assert motion[1].temperature is not None and motion[0].temperature is not None
    assert motion[1].temperature > motion[0].temperature
    # Step 1: the repair failed too: the safe fallback (STOP) was taken and says why.
    assert isinstance(rollout.actions[1], Stop)
    assert "after 1 repair" in rollout.traces[1]["fallback"]
    assert [(f.step_index, f.module) for f in rollout.failures] == [(1, "motion")]
    assert rollout.failures[0].action_fallback
    # The first request asked for structured output with the decision schema; the repair
    # request carried the invalid answer and the parser's reason.
    first = next(r for r in requests if r["task"] == "motion")
    assert first["body"]["response_format"]["json_schema"]["name"] == "decision"
    repair = next(r for r in requests if r["task"] == "motion" and len(r["body"]["messages"]) > 2)
    assert repair["body"]["messages"][-2]["content"] == "I would fly north, it looks nice."
    assert "not a JSON object" in repair["body"]["messages"][-1]["content"]
    assert sum(1 for r in rollout.llm_calls if r.error is None) == len(requests) - 8
    assert len(rollout.llm_calls) == len(requests)  # every request made is accounted for


def test_the_api_key_appears_in_no_file_the_toolkit_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sentinel = "sk-SENTINEL-7f3c9e1d2b4a"
    monkeypatch.setenv("OPENAI_API_KEY", sentinel)
    log_file = tmp_path / "run.log"
    handler = logging.FileHandler(log_file)
    root = logging.getLogger()
    previous_level = root.level
    root.addHandler(handler)
    root.setLevel(logging.DEBUG)  # everything any library logs goes to the file
    try:
        # The server echoes the key in an error, as real services do with a wrong key.
        script = [status(401), answer("not json at all", task="motion")]
        with LoopbackOpenAIServer(
            script, error_message=f"Incorrect API key provided: {sentinel}."
        ) as server:
            agent = build_agent(openai_agent(server.base_url, tmp_path))
            # Refused credentials stop the episode (and the run) at once: no call can work.
            with pytest.raises(LLMAuthError) as refused:
                run_official_episode(agent, town_episode(RED), town_world())
            auth = {
                {k.lower(): v for k, v in r["headers"].items()}.get("authorization")
                for r in server.requests
            }
        message = str(refused.value)
        atomic_write_json(tmp_path / "results" / "error.json", {"error": message})
        atomic_write_json(tmp_path / "results" / "settings.json", agent.settings())
    finally:
        root.removeHandler(handler)
        root.setLevel(previous_level)
        handler.close()
    assert auth == {f"Bearer {sentinel}"}  # the key was used ...
    assert "HTTP 401" in message and "OPENAI_API_KEY" in message  # names the variable
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert {p.name for p in written} >= {"run.log", "llm-cache.sqlite", "error.json"}
    assert log_file.stat().st_size > 0
    for path in written:  # ... and written nowhere
        assert sentinel.encode() not in path.read_bytes(), path
    assert "[API key]" in message  # the echoed key was scrubbed
