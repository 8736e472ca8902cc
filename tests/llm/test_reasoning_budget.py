"""A reasoning model (OpenAI's o-series, gpt-5) whose hidden reasoning used the whole
budget: an empty answer with ``finish_reason: length`` (audit scenario reasoning_repair)."""

from __future__ import annotations

import json

from skyvln_eval.agent.calls import call_json
from skyvln_eval.llm import GenerationConfig, Message
from skyvln_eval.llm.config import RepairPolicy
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer
from tests.llm.loopback_clients import loopback_client

ASK = [Message("system", "Answer in JSON."), Message("user", "Decide.")]
SCHEMA = {"type": "object", "properties": {"thought": {"type": "string"}}}
DECISION = GenerationConfig(json_schema=SCHEMA, schema_name="decision", max_tokens=512)
GOOD = json.dumps({"thought": "t"})


def test_reasoning_that_used_the_budget_gets_more_budget_not_a_briefer_answer() -> None:
    spent = {
        "prompt_tokens": 1800,
        "completion_tokens": 512,
        "completion_tokens_details": {"reasoning_tokens": 512},
    }
    script = [answer("", finish_reason="length", usage=spent), answer(GOOD)]
    with LoopbackOpenAIServer(script, parameters="openai_reasoning") as server:
        client = loopback_client(server, 1)
        out = call_json(client, "motion", ASK, DECISION, json.loads, RepairPolicy(repairs=1))
        bodies = [r["body"] for r in server.requests]
    # The requests the model answered (not those it refused for max_tokens or temperature).
    answered = [b for b in bodies if "max_completion_tokens" in b and "temperature" not in b]
    assert out.value == {"thought": "t"}
    # The same request with four times the budget: nothing visible was cut to shorten.
    assert [b["max_completion_tokens"] for b in answered] == [512, 2048]
    assert answered[1]["messages"] == answered[0]["messages"]
    cut = [r for r in out.records if r.outcome == "invalid"]
    assert len(cut) == 1 and cut[0].reasoning_tokens == 512
    assert "reasoning used the whole budget of max_tokens=512 (512 reasoning tokens)" in (
        cut[0].error or ""
    )


def test_a_visible_answer_cut_short_is_still_asked_for_briefly() -> None:
    script = [answer('{"thought": "long lo', finish_reason="length"), answer(GOOD)]
    with LoopbackOpenAIServer(script) as server:
        out = call_json(
            loopback_client(server, 1), "motion", ASK, DECISION, json.loads, RepairPolicy()
        )
        bodies = [r["body"] for r in server.requests]
    assert out.value == {"thought": "t"}
    assert [b["max_tokens"] for b in bodies] == [512, 1024]
    assert "more briefly" in bodies[1]["messages"][-1]["content"]
