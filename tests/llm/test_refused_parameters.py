"""Models that refuse decoding parameters (OpenAI's reasoning models): the request is
adapted at once, the endpoint keeps the adaptation, and every record says what went unsent."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from skyvln_eval.llm import GenerationConfig, LLMClient, Message, RetryPolicy, create_backend
from skyvln_eval.llm.cache import ResponseCache
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer, status
from skyvln_eval.llm_records import LlmCall

SCHEMA = {"type": "object", "properties": {"greeting": {"type": "string"}}}
CONFIG = GenerationConfig(
    temperature=0.0, max_tokens=64, stop=("\n\n",), timeout_s=2.0, json_schema=SCHEMA
)
HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
RETRY = RetryPolicy(max_attempts=3, initial_delay_s=0.0, max_delay_s=0.0)


def _client(server: LoopbackOpenAIServer, cache: ResponseCache | None = None) -> LLMClient:
    backend = create_backend("openai:o-model", base_url=server.base_url)
    return LLMClient(backend, retry=RETRY, cache=cache)


def test_a_reasoning_model_gets_the_budget_as_max_completion_tokens_and_its_defaults() -> None:
    script = [answer('{"greeting": "hi"}'), answer('{"greeting": "again"}')]
    with LoopbackOpenAIServer(script, parameters="openai_reasoning") as server:
        client = _client(server)
        first = client.call("motion", HELLO, CONFIG)
        repair = dataclasses.replace(CONFIG, temperature=0.7)
        second = client.call("motion", [*HELLO, Message("user", "again")], repair, repair=True)
        bodies = [r["body"] for r in server.requests]
    # max_tokens, then the temperature, then stop refused, each sent again at once (no
    # backoff, no failed call), then the answer; the schema level is untouched.
    assert [("max_tokens" in b, "temperature" in b, "stop" in b) for b in bodies[:4]] == [
        (True, True, True),
        (False, True, True),
        (False, False, True),
        (False, False, False),
    ]
    assert all(b["response_format"]["type"] == "json_schema" for b in bodies)
    assert bodies[3]["max_completion_tokens"] == 64 and bodies[3]["top_p"] == 1.0
    assert first.completion is not None and first.completion.text == '{"greeting": "hi"}'
    # Every request sent is an attempt of its own: the three refused ones as such, each with
    # what it went without, the server's words and its own time.
    *refused, record = first.records
    assert [(r.outcome, r.attempt, r.final) for r in first.records] == [
        ("refused", 1, False),
        ("refused", 2, False),
        ("refused", 3, False),
        ("ok", 4, True),
    ]
    assert [r.server_defaults for r in refused] == [(), (), ("temperature",)]
    assert [r.temperature for r in refused] == [0.0, 0.0, None]
    assert ["'max_tokens'" in (r.error or "") for r in refused] == [True, False, False]
    assert "'stop'" in (refused[2].error or "") and all(r.latency_s > 0 for r in refused)
    assert record.server_defaults == ("stop", "temperature")
    assert record.temperature is None  # not sent: the model decoded at its own default
    assert record.max_tokens == 64 and record.structured_output == "json_schema"
    # The endpoint keeps what it refused: the repair goes in one request, still without
    # its temperature of 0.7, and says so.
    assert len(bodies) == 5 and "temperature" not in bodies[4] and "max_tokens" not in bodies[4]
    assert second.completion is not None
    assert second.records[0].server_defaults == ("stop", "temperature")
    assert second.records[0].temperature is None and second.records[0].repair


def test_a_model_that_takes_every_parameter_records_none_unsent() -> None:
    with LoopbackOpenAIServer([answer("{}")]) as server:
        result = _client(server).call("motion", HELLO, CONFIG)
        (body,) = (r["body"] for r in server.requests)
    assert body["max_tokens"] == 64 and body["temperature"] == 0.0 and body["stop"] == ["\n\n"]
    assert result.records[0].server_defaults == () and result.records[0].temperature == 0.0


def test_a_refused_parameter_that_cannot_be_left_out_is_a_clear_refusal() -> None:
    message = "Unsupported parameter: 'messages' must hold at least two turns."
    with LoopbackOpenAIServer([status(400, message=message)]) as server:
        result = _client(server).call("motion", HELLO, CONFIG)
        sent = len(server.requests)
    assert sent == 1  # neither adapted nor retried: nothing in the request can change
    assert result.completion is None
    assert result.error is not None and "request refused" in result.error
    assert "'messages'" in result.error


def test_what_went_unsent_survives_the_cache_and_the_records_json(tmp_path: Path) -> None:
    cache = ResponseCache(tmp_path / "llm.sqlite")
    with LoopbackOpenAIServer([answer("{}")], parameters="openai_reasoning") as server:
        fresh = _client(server, cache).call("motion", HELLO, CONFIG)
        again = _client(server, cache).call("motion", HELLO, CONFIG)
    assert again.completion is not None and again.completion.cached
    assert again.records[0].server_defaults == fresh.records[-1].server_defaults != ()
    assert len(again.records) == 1  # the cache answers: nothing is sent, nothing refused
    record = fresh.records[-1]
    assert LlmCall.from_json_dict(record.to_json_dict()) == record


def test_a_budget_refused_for_its_size_is_not_taken_for_an_unsupported_parameter() -> None:
    message = "max_tokens is too large: 100000. This model supports at most 16384 tokens."
    free_text = dataclasses.replace(CONFIG, json_schema=None)
    with LoopbackOpenAIServer([status(400, message=message)]) as server:
        result = _client(server).call("motion", HELLO, free_text)
        bodies = [r["body"] for r in server.requests]
    assert len(bodies) == 1 and "max_tokens" in bodies[0]  # not renamed, not retried
    assert result.completion is None and "too large" in (result.error or "")


def test_fields_of_the_users_go_in_every_request_and_in_the_cache_identity() -> None:
    from skyvln_eval.errors import ConfigError
    from skyvln_eval.llm import LLMConfig, build_client

    with LoopbackOpenAIServer([answer("{}")]) as server:
        config = LLMConfig(
            backend="openai:o-model",
            base_url=server.base_url,
            extra_body={"reasoning_effort": "low"},
        )
        client = build_client(config)
        assert client.call("motion", HELLO, CONFIG).completion is not None
        (body,) = (r["body"] for r in server.requests)
    assert body["reasoning_effort"] == "low"
    plain = build_client(config.model_copy(update={"extra_body": {}}))
    assert client.backend.identity()["extra_body"] == {"reasoning_effort": "low"}
    assert "extra_body" not in plain.backend.identity()  # other fields: other cache keys
    replay = create_backend(
        "replay:openai:o-model", base_url=server.base_url, extra_body={"reasoning_effort": "low"}
    )
    assert replay.identity() == client.backend.identity()  # a replay finds the answers
    with pytest.raises(ValueError, match="extra_body cannot set max_tokens, stream"):
        LLMConfig(backend="openai:o-model", extra_body={"stream": True, "max_tokens": 5})
    with pytest.raises(ConfigError, match="plain JSON"):
        create_backend("openai:o-model", extra_body={"when": object()})


def test_answers_of_a_server_sent_the_task_data_are_never_replayed_as_the_model_s(
    tmp_path: Path,
) -> None:
    """A test server answers from the task data as the rule stand-in does: its cached
    answers have keys of their own, which neither the model nor its replay finds; a
    replay that asks for them is recorded as what it is."""
    from skyvln_eval.llm import LLMConfig, build_client

    url = "http://127.0.0.1:9/v1"
    fed = LLMConfig(backend="openai:gpt-4o", base_url=url, send_task_data=True)
    model = fed.model_copy(update={"send_task_data": False})
    fed_identity = build_client(fed).backend.identity()
    assert fed_identity != build_client(model).backend.identity()
    replayed = {"backend": "replay:openai:gpt-4o", "cache_path": str(tmp_path / "cache.sqlite")}
    replay = model.model_copy(update=replayed)
    assert build_client(replay).backend.identity() != fed_identity
    fed_replay = fed.model_copy(update=replayed)
    assert build_client(fed_replay).backend.identity() == fed_identity
    assert fed_replay.answered_by == "task-data:replay:openai:gpt-4o"


def test_a_refused_system_role_points_to_the_setting() -> None:
    message = "Unsupported value: 'messages[0].role' does not support 'system' with this model."
    with LoopbackOpenAIServer([status(400, message=message)] * 2) as server:
        refused = _client(server).call("motion", HELLO, CONFIG)
        assert len(server.requests) == 1  # not a parameter the request can go without
    assert refused.error is not None and "set system_role: false" in refused.error
