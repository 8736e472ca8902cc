"""The openai backend against a real local HTTP server that injects every kind of fault."""

from __future__ import annotations

import json
import ssl

import pytest

from skyvln_eval.errors import ConfigError, LLMAuthError, LLMError
from skyvln_eval.llm import (
    GenerationConfig,
    ImagePart,
    LLMClient,
    Message,
    RetryPolicy,
    create_backend,
)
from skyvln_eval.llm.loopback import (
    LoopbackOpenAIServer,
    answer,
    error_body,
    hang,
    malformed,
    raw,
    status,
    truncated,
)
from skyvln_eval.llm.openai_errors import retry_after_s
from skyvln_eval.llm.openai_request import without_system_role

FAST_RETRY = RetryPolicy(max_attempts=8, initial_delay_s=0.01, max_delay_s=0.05, jitter=0.5)
# Room for an answer on a loaded machine (at 0.5 s, one came too late under a load of
# 4.6 on 2 cores: an 8th attempt); the hang below outlasts it.
CONFIG = GenerationConfig(timeout_s=2.0)
HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]


def _client(server: LoopbackOpenAIServer, delays: list[float], **options: object) -> LLMClient:
    backend = create_backend("openai:fake-model", base_url=server.base_url, **options)
    return LLMClient(backend, retry=FAST_RETRY, sleep=delays.append)


def test_every_transport_fault_is_retried_recorded_and_survived() -> None:
    script = [
        status(429, Retry_After="0.02"),
        status(500),
        hang(4.0),  # past the 2 s timeout
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


@pytest.mark.parametrize(
    ("code", "error_class"),
    [(404, "LLMEndpointError"), (405, "LLMEndpointError"), (413, "LLMError")],
)
def test_a_client_error_is_not_retried(code: int, error_class: str) -> None:
    """A route or model the endpoint does not have is the endpoint's failure (the call got
    no answer of the model); a request refused for its size is the request's."""
    with LoopbackOpenAIServer([status(code)]) as server:
        result = _client(server, []).call("motion", HELLO, CONFIG)
        assert len(server.requests) == 1
    assert result.completion is None and f"HTTP {code}" in (result.error or "")
    assert [r.outcome for r in result.records] == ["failed"]
    assert (result.records[0].error or "").startswith(f"{error_class}:")
    assert result.records[0].unanswered_after_retries is (error_class == "LLMEndpointError")


@pytest.mark.parametrize("code", [408, 409, 425])
def test_a_status_that_asks_to_try_again_is_retried(code: int) -> None:
    with LoopbackOpenAIServer([status(code), answer('{"greeting": "hello"}')]) as server:
        result = _client(server, []).call("motion", HELLO, CONFIG)
        assert len(server.requests) == 2
    assert result.completion is not None
    assert f"LLMTransientError: try again later (HTTP {code}" in (result.records[0].error or "")


def test_refused_credentials_stop_at_once_naming_the_key_variable() -> None:
    with LoopbackOpenAIServer([status(401)]) as server:
        with pytest.raises(LLMAuthError, match="MY_KEY_VAR") as refused:
            _client(server, [], api_key_env="MY_KEY_VAR").call("motion", HELLO, CONFIG)
        assert len(server.requests) == 1
    assert "HTTP 401" in str(refused.value)


def test_a_dead_endpoint_is_named_without_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    import socket

    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    monkeypatch.setenv("DEAD_KEY", "sk-very-secret")
    base_url = f"http://127.0.0.1:{port}/v1"
    backend = create_backend("openai:gpt-4o-mini", base_url=base_url, api_key_env="DEAD_KEY")
    retry = RetryPolicy(max_attempts=2, initial_delay_s=0.0, max_delay_s=0.0)
    result = LLMClient(backend, retry=retry, sleep=lambda _: None).call("motion", HELLO, CONFIG)
    assert result.completion is None and result.error is not None
    where = f"openai:gpt-4o-mini@{base_url}"
    assert f"{where}: connection failed or body cut short" in result.error
    for text in [result.error, *(r.error or "" for r in result.records)]:
        assert "sk-" not in text


def test_a_server_url_with_a_password_or_a_query_is_refused_without_showing_them() -> None:
    # Before, a backend made with one masked them in its own messages only: the price
    # warning, run configs, labels and logs had them, and the client sent the password as
    # Basic auth instead of the key. Refused, they reach nothing.
    base_url = "http://user:hunter2@127.0.0.1:9/v1?api-key=sk-in-the-url"
    with pytest.raises(ConfigError) as refused:
        create_backend("openai:gpt-4o-mini", base_url=base_url, api_key_env="DEAD_KEY")
    assert str(refused.value).startswith(
        "base_url 'http://[credentials]@127.0.0.1:9/v1?[query]' has credentials "
        "(user:password@) and a query string in it"
    )
    assert "hunter2" not in str(refused.value) and "sk-" not in str(refused.value)


def test_a_context_overflow_is_its_own_failure_and_keeps_structured_output() -> None:
    schema = {"type": "object", "properties": {"greeting": {"type": "string"}}}
    config = GenerationConfig(timeout_s=2.0, json_schema=schema, schema_name="greeting")
    overflow = "This model's maximum context length is 8192 tokens; you requested 9000."
    with LoopbackOpenAIServer([status(400, message=overflow), answer("{}")]) as server:
        client = _client(server, [])
        result = client.call("motion", HELLO, config)
        again = client.call("motion", [*HELLO, Message("user", "short")], config)
        bodies = [r["body"] for r in server.requests]
    assert len(bodies) == 2  # not retried unchanged, not taken for a format refusal
    assert result.completion is None and "context" in (result.error or "")
    assert "LLMContextOverflowError" in (result.records[0].error or "")
    assert bodies[1]["response_format"]["type"] == "json_schema"
    assert again.completion is not None and again.completion.structured_output == "json_schema"


SCHEMA = {"type": "object", "properties": {"greeting": {"type": "string", "maxLength": 20}}}
STRUCTURED = GenerationConfig(timeout_s=2.0, json_schema=SCHEMA, schema_name="greeting")


def test_structured_output_is_negotiated_down_to_what_a_llama_cpp_server_takes() -> None:
    with LoopbackOpenAIServer([answer("{}")] * 3, structured="llama_cpp") as server:
        client = _client(server, [])
        first = client.call("motion", HELLO, STRUCTURED)
        second = client.call("motion", [*HELLO, Message("user", "again")], STRUCTURED)
        formats = [r["body"].get("response_format") for r in server.requests]
    # json_schema (strict) answered with HTTP 500 naming response_format: one level down,
    # at once (not retried as a server fault), with the schema attached ...
    assert formats[0]["type"] == "json_schema" and formats[0]["json_schema"]["strict"] is True
    assert "maxLength" not in json.dumps(formats[0])  # strict mode takes no string lengths
    assert formats[1] == {"type": "json_object", "schema": SCHEMA}
    assert first.completion is not None
    assert first.completion.structured_output == "json_object_schema"
    # The refused request is an attempt of its own (negotiation, not a failure) ...
    assert [(r.outcome, r.structured_output) for r in first.records] == [
        ("refused", "json_schema"),
        ("ok", "json_object_schema"),
    ]
    assert "HTTP 500" in (first.records[0].error or "")
    # ... and remembered for the endpoint: the next call starts there.
    assert formats[2] == {"type": "json_object", "schema": SCHEMA} and len(formats) == 3
    assert [r.structured_output for r in second.records] == ["json_object_schema"]


def test_a_refused_level_is_remembered_even_when_the_next_attempt_fails() -> None:
    # Refused, then the lower level times out: the refusal is still known for the endpoint
    # (it was learnt only from an answer, so every call tried json_schema again first).
    # Every answer takes 0.4 s and a call 0.6: the refusal leaves too little for the next try.
    quick = GenerationConfig(timeout_s=0.6, json_schema=SCHEMA, schema_name="greeting")
    with LoopbackOpenAIServer([answer("{}")], structured="llama_cpp", latency_s=0.4) as server:
        backend = create_backend("openai:fake-model", base_url=server.base_url)
        once = RetryPolicy(max_attempts=1, initial_delay_s=0.0, max_delay_s=0.0)
        client = LLMClient(backend, retry=once, sleep=lambda _: None)
        failed = client.call("motion", HELLO, quick)
        assert failed.completion is None
        # Both requests are recorded: the refused level, then the timeout that ended the call.
        assert [(r.outcome, r.final) for r in failed.records] == [
            ("refused", False),
            ("failed", True),
        ]
        again = client.call("motion", [*HELLO, Message("user", "again")], quick)
        formats = [r["body"].get("response_format") for r in server.requests]
    assert [f["type"] for f in formats] == ["json_schema", "json_object", "json_object"]
    assert again.completion is not None  # straight at the level the server takes


def test_a_server_without_any_response_format_is_prompted_plainly() -> None:
    with LoopbackOpenAIServer([answer("{}")], structured="none") as server:
        result = _client(server, []).call("motion", HELLO, STRUCTURED)
        formats = [r["body"].get("response_format") for r in server.requests]
    assert [f and f["type"] for f in formats] == ["json_schema", "json_object", "json_object", None]
    assert result.completion is not None and result.completion.structured_output == "prompt"


def test_a_pinned_level_is_used_as_is_and_a_refusal_says_so() -> None:
    with LoopbackOpenAIServer([answer("{}")] * 2, structured="llama_cpp") as server:
        pinned = _client(server, [], structured_output="json_object_schema")
        assert pinned.call("motion", HELLO, STRUCTURED).completion is not None
        strict = _client(server, [], structured_output="json_schema")
        result = strict.call("motion", HELLO, STRUCTURED)
        formats = [r["body"]["response_format"]["type"] for r in server.requests]
    assert formats == ["json_object", "json_schema"]
    assert result.completion is None and "pinned" in (result.error or "")


def test_images_go_as_data_urls_only_to_models_that_take_them() -> None:
    image = ImagePart(b"\x89PNG fake bytes")
    messages = [Message("user", "What is this?", (image,))]
    with LoopbackOpenAIServer([answer("a"), answer("b")]) as server:
        _client(server, [], takes_images=True).call("hsd_describe", messages, CONFIG)
        _client(server, [], takes_images=False).call("hsd_describe", messages, CONFIG)
        with_images, without = (r["body"]["messages"][0]["content"] for r in server.requests)
    assert with_images[1]["image_url"]["url"].startswith("data:image/png;base64,")
    assert without == "What is this?"


def test_a_model_without_a_system_role_gets_the_system_prompt_in_its_first_user_turn() -> None:
    images = (ImagePart(b"\x89PNG fake bytes"),)
    messages = [
        Message("system", "You fly a drone."),
        Message("user", "Where now?", images),
        Message("assistant", "{}"),
        Message("user", "Answer again."),
    ]
    with LoopbackOpenAIServer([answer("a"), answer("b")]) as server:
        folded = _client(server, [], system_role=False, takes_images=True)
        folded.call("motion", messages, CONFIG)
        _client(server, [], takes_images=True).call("motion", messages, CONFIG)
        sent_folded, sent_plain = (r["body"]["messages"] for r in server.requests)
    assert [m["role"] for m in sent_folded] == ["user", "assistant", "user"]
    first = sent_folded[0]["content"]
    assert first[0] == {"type": "text", "text": "You fly a drone.\n\nWhere now?"}
    assert first[1]["image_url"]["url"].startswith("data:image/png;base64,")  # kept
    assert sent_folded[2]["content"] == "Answer again."
    assert [m["role"] for m in sent_plain] == ["system", "user", "assistant", "user"]
    # The two forms are different prompts to the model: their answers are cached apart.
    assert folded.backend.identity() != _client(server, []).backend.identity()
    only_system = without_system_role([Message("system", "Rules."), Message("system", "More.")])
    assert only_system == [Message("user", "Rules.\n\nMore.")]


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


def test_clients_share_one_tls_context_that_verifies_certificates() -> None:
    # Made once per process (not per client), and never at the price of verification.
    from skyvln_eval.llm.openai_backend import _tls_context

    context = _tls_context()
    assert isinstance(context, ssl.SSLContext) and _tls_context() is context
    assert context.verify_mode == ssl.CERT_REQUIRED and context.check_hostname


def test_threads_that_start_clients_at_once_make_one_tls_context() -> None:
    """Episode threads start together: they must not each load the certificate store."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from skyvln_eval.llm import openai_backend

    openai_backend._made_tls_context.cache_clear()
    start = threading.Barrier(6)

    def make(_: int) -> object:
        start.wait()
        return openai_backend._tls_context()

    with ThreadPoolExecutor(6) as pool:
        contexts = list(pool.map(make, range(6)))
    assert openai_backend._made_tls_context.cache_info().misses == 1
    assert all(c is contexts[0] for c in contexts)


def test_every_form_of_the_servers_wait_is_read() -> None:
    import email.utils

    now = 1_800_000_000.0
    in_90_s = email.utils.formatdate(now + 90, usegmt=True)
    assert retry_after_s({"retry-after": "2.5"}) == 2.5
    assert retry_after_s({"retry-after-ms": "250", "retry-after": "9"}) == 0.25  # OpenAI's
    assert retry_after_s({"retry-after": in_90_s}, now=now) == pytest.approx(90.0)
    assert retry_after_s({"retry-after": email.utils.formatdate(now - 5)}, now=now) == 0.0
    # Nothing readable: our own backoff decides.
    for unreadable in ({}, {"retry-after": "soon"}, {"retry-after": "nan"}, None):
        assert retry_after_s(unreadable) is None
    assert retry_after_s({"retry-after-ms": "x", "retry-after": "3"}) == 3.0


def test_a_retry_after_date_is_honoured() -> None:
    import email.utils
    import time

    in_2_s = email.utils.formatdate(time.time() + 2.0, usegmt=True)
    delays: list[float] = []
    with LoopbackOpenAIServer(
        [status(429, Retry_After=in_2_s), answer('{"greeting": "hello"}')]
    ) as server:
        result = _client(server, delays).call("motion", HELLO, CONFIG)
    assert result.completion is not None
    assert len(delays) == 1 and 0.5 < delays[0] <= 2.0  # an HTTP date has whole seconds


def test_a_gateways_error_object_in_a_200_is_a_retried_fault_that_says_why() -> None:
    delays: list[float] = []
    script = [error_body("upstream model overloaded"), answer('{"greeting": "hello"}')]
    with LoopbackOpenAIServer(script) as server:
        result = _client(server, delays).call("motion", HELLO, CONFIG)
    assert result.completion is not None
    failed, answered = result.records
    assert failed.outcome == "failed" and "no choices" in (failed.error or "")
    assert "upstream model overloaded" in (failed.error or "")  # what the gateway said
    assert answered.outcome == "ok" and answered.attempt == 2


@pytest.mark.parametrize(
    ("code", "body"),
    [
        # FastAPI's request validation naming the field it does not take.
        (
            422,
            '{"detail": [{"loc": ["body", "response_format"], "msg": "extra fields not '
            'permitted", "type": "value_error.extra"}]}',
        ),
        # vLLM's words; "model" in it was taken for another cause, and every call failed.
        (400, '{"error": {"message": "unsupported guided decoding backend for this model"}}'),
    ],
)
def test_a_refusal_of_the_format_in_other_words_steps_down(code: int, body: str) -> None:
    with LoopbackOpenAIServer([raw(body, code=code), answer("{}")]) as server:
        result = _client(server, []).call("motion", HELLO, STRUCTURED)
        formats = [r["body"]["response_format"]["type"] for r in server.requests]
    assert formats == ["json_schema", "json_object"]
    assert result.completion is not None
    assert [r.outcome for r in result.records] == ["refused", "ok"]
