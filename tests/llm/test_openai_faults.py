"""The openai backend against a real local HTTP server that injects every kind of fault."""

from __future__ import annotations

import json

import pytest

from skyvln_eval.errors import LLMError
from skyvln_eval.llm import GenerationConfig, LLMClient, Message, RetryPolicy, create_backend
from skyvln_eval.llm.loopback import (
    LoopbackOpenAIServer,
    answer,
    hang,
    malformed,
    refuse_schema,
    status,
    truncated,
)

FAST_RETRY = RetryPolicy(max_attempts=8, initial_delay_s=0.01, max_delay_s=0.05, jitter=0.5)
CONFIG = GenerationConfig(timeout_s=0.5)
HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]


def _client(server: LoopbackOpenAIServer, delays: list[float], **options: object) -> LLMClient:
    backend = create_backend("openai:fake-model", base_url=server.base_url, **options)
    return LLMClient(backend, retry=FAST_RETRY, sleep=delays.append)


def test_every_transport_fault_is_retried_recorded_and_survived() -> None:
    script = [
        status(429, Retry_After="0.02"),
        status(500),
        hang(2.0),  # past the 0.5 s timeout
        malformed(),
        truncated(),
        status(503),
        answer('{"greeting": "hello"}'),
    ]
    delays: list[float] = []
    with LoopbackOpenAIServer(script) as server:
        result = _client(server, delays).call("motion", HELLO, CONFIG)
        sent = len(server.requests)
    assert result.completion is not None and json.loads(result.completion.text) == {
        "greeting": "hello"
    }
    assert sent == 7
    errors = [r.error for r in result.records]
    assert len(errors) == 7 and errors[-1] is None
    expected = ["HTTP 429", "HTTP 500", "timeout", "malformed", "body cut short", "HTTP 503"]
    for error, needle in zip(errors[:-1], expected, strict=True):
        assert error is not None and needle in error
    # The server's Retry-After is honoured; later waits back off exponentially (with jitter).
    assert delays[0] == pytest.approx(0.02)
    assert delays[1] == pytest.approx(0.02, rel=0.5) and delays[2] > delays[1]
    final = result.records[-1]
    assert (final.prompt_tokens, final.completion_tokens) == (100, 20)
    assert final.module == "motion" and final.backend == "openai" and final.model == "fake-model"
    assert not final.cached and final.latency_s > 0


def test_the_client_gives_up_after_the_last_attempt_and_says_why() -> None:
    delays: list[float] = []
    with LoopbackOpenAIServer([status(500)] * 8) as server:
        result = _client(server, delays).call("subgoals", HELLO, CONFIG)
    assert result.completion is None
    assert result.error is not None and "gave up after 8 attempt(s)" in result.error
    assert len(result.records) == 8 and all("HTTP 500" in (r.error or "") for r in result.records)


def test_a_client_error_is_not_retried() -> None:
    with LoopbackOpenAIServer([status(401)]) as server:
        result = _client(server, []).call("motion", HELLO, CONFIG)
        assert len(server.requests) == 1
    assert result.completion is None and "HTTP 401" in (result.error or "")


def test_structured_output_is_requested_and_dropped_when_the_server_refuses_it() -> None:
    schema = {"type": "object", "properties": {"greeting": {"type": "string"}}}
    config = GenerationConfig(timeout_s=2.0, json_schema=schema, schema_name="greeting")
    script = [answer("{}"), refuse_schema("{}"), answer('{"greeting": "hi"}'), answer("{}")]
    with LoopbackOpenAIServer(script) as server:
        client = _client(server, [])
        first = client.call("motion", HELLO, config)
        second = client.call("motion", [*HELLO, Message("user", "again")], config)
        third = client.call("motion", [*HELLO, Message("user", "once more")], config)
        bodies = [r["body"] for r in server.requests]
    assert first.completion is not None and first.completion.structured
    sent = bodies[0]["response_format"]
    assert sent["type"] == "json_schema" and sent["json_schema"]["schema"] == schema
    # The refusal (HTTP 400) is answered by asking again without response_format ...
    assert "response_format" in bodies[1] and "response_format" not in bodies[2]
    assert second.completion is not None and not second.completion.structured
    # ... and remembered: plain prompting from then on.
    assert "response_format" not in bodies[3] and third.completion is not None


def test_images_go_as_data_urls_only_to_models_that_take_them() -> None:
    from skyvln_eval.llm import ImagePart

    image = ImagePart(b"\x89PNG fake bytes")
    messages = [Message("user", "What is this?", (image,))]
    with LoopbackOpenAIServer([answer("a"), answer("b")]) as server:
        _client(server, [], takes_images=True).call("hsd_describe", messages, CONFIG)
        _client(server, [], takes_images=False).call("hsd_describe", messages, CONFIG)
        with_images, without = (r["body"]["messages"][0]["content"] for r in server.requests)
    assert with_images[1]["image_url"]["url"].startswith("data:image/png;base64,")
    assert without == "What is this?"


def test_the_openai_backend_needs_a_model_and_a_key_for_the_real_service(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from skyvln_eval.errors import ConfigError

    with pytest.raises(ConfigError, match="openai:<model>"):
        create_backend("openai")
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    backend = create_backend("openai:gpt-4o")
    with pytest.raises(LLMError, match="OPENAI_API_KEY"):
        backend.generate(HELLO, CONFIG)
