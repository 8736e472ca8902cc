"""Every request that reaches the server is one attempt record, negotiation included.

The audit counted requests on the wire against records: a structured-output level the
server refused used to be folded into the call (its time in the answer's latency, no record
of its own), and a call that failed for good was recorded with a latency of 0.0. Here the
loopback server keeps every request it got, so the two counts are compared directly; it
sleeps ``LATENCY_S`` before every reply, which bounds each request's time from below
(never a threshold on how fast anything is).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from skyvln_eval.errors import LLMAuthError
from skyvln_eval.llm import GenerationConfig, LLMClient, Message
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer, no_choices, status
from skyvln_eval.llm.negotiation import negotiated_level, negotiated_levels
from skyvln_eval.llm.openai_errors import FormatRefused
from skyvln_eval.llm_records import module_usage
from skyvln_eval.metrics.cost import call_totals
from tests.llm.loopback_clients import fake_model_prices, loopback_client

SCHEMA = {"type": "object", "properties": {"greeting": {"type": "string"}}}
STRUCTURED = GenerationConfig(timeout_s=5.0, json_schema=SCHEMA, schema_name="greeting")
HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
LATENCY_S = 0.05


def _client(server: LoopbackOpenAIServer) -> LLMClient:
    return loopback_client(server, attempts=3)


def test_a_refused_level_is_an_attempt_of_its_own_with_its_own_time() -> None:
    with LoopbackOpenAIServer(
        [answer('{"greeting": "hi"}')], structured="llama_cpp", latency_s=LATENCY_S
    ) as server:
        began = time.perf_counter()
        result = _client(server).call("motion", HELLO, STRUCTURED)
        elapsed = time.perf_counter() - began
        sent = len(server.requests)
    assert result.completion is not None
    assert sent == len(result.records) == 2  # was 2 requests, 1 record
    refused, answered = result.records
    assert (refused.outcome, refused.attempt, refused.final) == ("refused", 1, False)
    assert refused.structured_output == "json_schema"
    assert "json_schema" in (refused.error or "") and "HTTP 500" in (refused.error or "")
    assert refused.prompt_tokens is None and refused.cost_usd == 0.0  # not generated, not billed
    assert (answered.outcome, answered.attempt, answered.final) == ("ok", 2, True)
    # Each request's time is its own: both waited for the server, and together they fit in
    # the call (the answer's latency no longer holds the refused request's time too).
    assert refused.latency_s >= LATENCY_S and answered.latency_s >= LATENCY_S
    assert refused.latency_s + answered.latency_s <= elapsed
    # Counted as a request, not as a failed call; its missing token count hides nothing.
    totals = call_totals(result.records)
    assert totals["llm_calls"] == 1 and totals["llm_requests"] == 2
    assert totals["llm_refused_requests"] == 1
    assert totals["llm_failed_calls"] == 0 and totals["llm_call_failure_rate"] == 0.0
    assert (totals["llm_prompt_tokens"], totals["llm_completion_tokens"]) == (100, 20)
    assert math.isnan(totals["llm_cost_usd"])  # no price for the model: unknown, not 0
    usage = module_usage(result.records, ())["motion"]
    assert (usage["calls"], usage["requests"], usage["refused_requests"]) == (1, 2, 1)
    assert usage["failed_calls"] == 0 and usage["prompt_tokens"] == 100


def test_a_server_refusing_everything_leaves_one_record_per_request_each_timed() -> None:
    # HTTP 400 to every request: json_schema, json_object with the schema and plain
    # json_object are refused formats; the plain request's 400 ends the call; the repair
    # call starts at the remembered level and fails in one request.
    refusal = "unsupported response_format"  # named: believed at once (see below for a bare 400)
    with LoopbackOpenAIServer([status(400, message=refusal)] * 5, latency_s=LATENCY_S) as server:
        client = _client(server)
        first = client.call("motion", HELLO, STRUCTURED)
        again = client.call("motion", [*HELLO, Message("user", "again")], STRUCTURED, repair=True)
        sent = len(server.requests)
    records = [*first.records, *again.records]
    assert sent == len(records) == 5  # was 5 requests, 2 records
    assert [(r.outcome, r.final, r.structured_output) for r in first.records] == [
        ("refused", False, "json_schema"),
        ("refused", False, "json_object_schema"),
        ("refused", False, "json_object"),
        ("failed", True, None),
    ]
    assert [r.attempt for r in first.records] == [1, 2, 3, 4]
    assert [(r.outcome, r.final) for r in again.records] == [("failed", True)]
    assert first.completion is None and "HTTP 400" in (first.error or "")
    # A failed call's latency is its measured time (it was 0.0).
    assert all(r.latency_s >= LATENCY_S for r in records)
    totals = call_totals(records)
    assert (totals["llm_calls"], totals["llm_failed_calls"]) == (2, 2)
    assert (totals["llm_requests"], totals["llm_refused_requests"]) == (5, 3)
    assert totals["llm_latency_s"] == sum(r.latency_s for r in records)


def test_tokens_reported_with_no_choices_are_counted_and_priced(tmp_path: Path) -> None:
    # HTTP 200 with "choices": [] and a usage object: no answer, but tokens the server says
    # it billed. They count (the failed attempt's record has them) and, priced, the cost is
    # known; without a price it stays unknown, never 0.
    script = [no_choices(), answer('{"greeting": "hi"}')] * 2
    with LoopbackOpenAIServer(script) as server:
        priced = loopback_client(server, prices=fake_model_prices(server, tmp_path))
        result = priced.call("motion", HELLO, GenerationConfig(timeout_s=5.0))
        unpriced = _client(server).call("motion", HELLO, GenerationConfig(timeout_s=5.0))
    failed, answered = result.records
    assert failed.outcome == "failed" and "no choices" in (failed.error or "")
    assert (failed.prompt_tokens, failed.completion_tokens) == (100, 20)  # were None
    assert failed.cost_usd == pytest.approx((100 * 1.0 + 20 * 2.0) / 1e6)
    totals = call_totals(result.records)
    assert (totals["llm_prompt_tokens"], totals["llm_completion_tokens"]) == (200, 40)
    assert totals["llm_cost_usd"] == pytest.approx(2 * 140 / 1e6)
    assert answered.outcome == "ok"
    unknown = unpriced.records[0]
    assert unknown.outcome == "failed" and unknown.prompt_tokens == 100
    assert unknown.cost_usd is None


def test_a_priced_endpoint_that_negotiates_has_a_known_cost(tmp_path: Path) -> None:
    # llama.cpp-style: json_schema refused (HTTP 500 naming it), json_object with the schema
    # answered. The refused request was never generated, so it costs nothing: the call's
    # cost is the answer's, known, not unknown or a lower bound.
    with LoopbackOpenAIServer(
        [answer('{"greeting": "hi"}')], structured="llama_cpp", latency_s=0.0
    ) as server:
        priced = loopback_client(server, prices=fake_model_prices(server, tmp_path))
        result = priced.call("motion", HELLO, STRUCTURED)
    refused, answered = result.records
    assert refused.outcome == "refused" and refused.cost_usd == 0.0
    totals = call_totals(result.records)
    assert totals["llm_cost_usd"] == pytest.approx(answered.cost_usd) == 140 / 1e6
    assert totals["llm_cost_lower_usd"] == totals["llm_cost_usd"]


@pytest.mark.parametrize(
    "message",
    [
        "The model `fake-model` does not exist or you do not have access to it.",
        "max_tokens is too large: 100000. This model supports at most 16384 tokens.",
    ],
)
def test_a_400_naming_another_cause_is_that_error_not_a_format_refusal(message: str) -> None:
    with LoopbackOpenAIServer([status(400, message=message), answer("{}")]) as server:
        client = _client(server)
        result = client.call("motion", HELLO, STRUCTURED)
        sent = len(server.requests)
        again = client.call("motion", [*HELLO, Message("user", "again")], STRUCTURED)
        formats = [r["body"]["response_format"]["type"] for r in server.requests]
    # Asked once, not sent down every level; the user reads the server's words.
    assert sent == 1 and [r.outcome for r in result.records] == ["failed"]
    assert result.completion is None and message[:40] in (result.error or "")
    # The endpoint keeps its level: the next call asks for json_schema again.
    assert formats == ["json_schema", "json_schema"] and again.completion is not None
    assert negotiated_level(client.backend.endpoint) is None  # type: ignore[attr-defined]


@pytest.mark.parametrize("code", [401, 403])
def test_refused_credentials_are_never_a_format_refusal(code: int) -> None:
    message = "Invalid API key; response_format json_schema requires a paid plan."
    with LoopbackOpenAIServer([status(code, message=message)] * 4) as server:
        client = _client(server)
        with pytest.raises(LLMAuthError, match=f"HTTP {code}"):
            client.call("motion", HELLO, STRUCTURED)
        assert len(server.requests) == 1
    assert negotiated_level(client.backend.endpoint) is None  # type: ignore[attr-defined]
    (record,) = client.calls_made()
    assert record.outcome == "failed" and record.final


def test_an_episodes_first_error_is_the_failed_requests_not_a_refused_level() -> None:
    # From an audit: a server that only streams refuses every structured-output level, then
    # the plain request, with its reason. The episode said "structured output level
    # 'json_schema' refused" (the first record with an error) instead of that reason.
    from skyvln_eval.metrics.records import judge_status

    streams = "this server only supports stream=true"
    with LoopbackOpenAIServer([status(400, message=streams)] * 8) as server:
        result = _client(server).call("motion", HELLO, STRUCTURED)
    outcomes = [r.outcome for r in result.records]
    assert outcomes[0] == "refused" and outcomes[-1] == "failed", outcomes
    status_, why = judge_status(result.records, [], None)
    assert status_ == "error" and why is not None
    assert "request refused (HTTP 400" in why and streams in why
    assert "structured output level" not in why
    # Only refusals (no request failed after them): the first refusal is still the reason.
    only_refused = [r for r in result.records if r.outcome == "refused"]
    assert "structured output level 'json_schema'" in (
        judge_status(only_refused, [], None)[1] or ""
    )


def test_a_refusal_message_keeps_what_the_server_said_not_its_traceback() -> None:
    # llama-cpp-python's 500 for a json_schema response format: a validation error, then
    # the Python traceback of the server (cut by the old 300-character excerpt mid-path).
    body = (
        "Error code: 500 - 1 validation error:\n  {'type': 'literal_error', 'loc': "
        "('body', 'response_format', 'type'), 'msg': \"Input should be 'text' or "
        "'json_object'\"}\n\n  File \"/venv/lib/python3.11/site-packages/llama_cpp/server/"
        'errors.py", line 171, in custom_route_handler\n    response = await '
        "original_route_handler(request)\n"
    )
    said = str(FormatRefused(500, body))
    assert said.startswith("HTTP 500: Error code: 500 - 1 validation error: {'type'")
    assert said.endswith("'json_object'\"}")
    assert "File" not in said and "\n" not in said
    long = str(FormatRefused(500, "schema " * 100))
    assert len(long) == len("HTTP 500: ") + 300 and long.endswith("…")


def test_a_bare_400_gives_a_level_up_for_the_endpoint_only_when_it_happens_again() -> None:
    # One "400 bad request" (a one-off fault) lowered the endpoint's level for the rest of
    # the process, though the server takes json_schema.
    with LoopbackOpenAIServer([status(400, message="bad request")], latency_s=0.0) as server:
        client = _client(server)
        once = client.call("motion", HELLO, STRUCTURED)
        after = client.call("motion", [*HELLO, Message("user", "again")], STRUCTURED)
        formats = [r["body"]["response_format"]["type"] for r in server.requests]
    assert once.completion is not None and after.completion is not None
    assert formats == ["json_schema", "json_object", "json_schema"]  # tried again, answered
    assert after.completion.structured_output == "json_schema"
    # Refused so again: given up for the endpoint at the second time, the third call
    # starts one level down.
    bare = status(400, message="bad request")
    with LoopbackOpenAIServer([bare, answer("{}"), bare, answer("{}")]) as server:
        client = _client(server)
        for k in range(3):
            assert client.call("motion", [*HELLO, Message("user", str(k))], STRUCTURED).completion
        sent = [r["body"]["response_format"]["type"] for r in server.requests]
    assert sent == ["json_schema", "json_object", "json_schema", "json_object", "json_object"]
    # A burst of bare 400s (a proxy's fault) that the plain request gets as well was never
    # about the format: no level is given up, the next call starts at the top again.
    with LoopbackOpenAIServer([bare] * 8 + [answer("{}")]) as server:
        client = _client(server)
        for k in range(2):
            client.call("motion", [*HELLO, Message("user", str(k))], STRUCTURED)
        client.call("motion", [*HELLO, Message("user", "after")], STRUCTURED)
        sent = [(r["body"].get("response_format") or {}).get("type") for r in server.requests]
    assert sent[-1] == "json_schema"
    assert negotiated_level(client.backend.endpoint) is None  # type: ignore[attr-defined]
    # A refusal that names the format is believed at once.
    with LoopbackOpenAIServer([answer("{}")], structured="none") as server:
        client = _client(server)
        for k in range(2):
            assert client.call("motion", [*HELLO, Message("user", str(k))], STRUCTURED).completion
        sent = [(r["body"].get("response_format") or {}).get("type") for r in server.requests]
    assert sent == ["json_schema", "json_object", "json_object", None, None]


def test_a_schema_the_endpoint_refuses_steps_down_for_that_schema_only() -> None:
    # OpenAI's strict mode refuses one schema ("Invalid schema for response_format ...")
    # and never takes a schema beside json_object: the audit's endpoint then sent every
    # later call, of every module, as plain json_object for the rest of the run.
    subgoals = GenerationConfig(timeout_s=5.0, json_schema=SCHEMA, schema_name="subgoals")
    script = [
        status(400, message="Invalid schema for response_format 'subgoals': In context=("
               "'properties', 'context_landmarks'), array schema missing items."),
        status(400, message="Unknown parameter: 'response_format.schema'."),
        answer('{"greeting": "hi"}'),  # subgoals at json_object
        answer('{"greeting": "hi"}'),  # greeting: still json_schema
        answer('{"greeting": "hi"}'),  # subgoals again: json_object at once
    ]  # fmt: skip
    with LoopbackOpenAIServer(script) as server:
        client = _client(server)
        first = client.call("subgoals", HELLO, subgoals)
        other = client.call("motion", HELLO, STRUCTURED)
        again = client.call("subgoals", [*HELLO, Message("user", "again")], subgoals)
        formats = [(r["body"].get("response_format") or {}).get("type") for r in server.requests]
    assert [r.structured_output for r in first.records] == [
        "json_schema", "json_object_schema", "json_object"]  # fmt: skip
    assert [r.structured_output for r in other.records] == ["json_schema"]
    assert [r.structured_output for r in again.records] == ["json_object"]
    assert formats == ["json_schema", "json_object", "json_object", "json_schema", "json_object"]
    # Provenance names the schema that went down, and the endpoint's level is untouched.
    levels = negotiated_levels()
    assert list(levels.values()) == ["json_object"]
    assert next(iter(levels)).endswith(" schema subgoals")
