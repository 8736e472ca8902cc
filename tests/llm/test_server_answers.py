"""What a misbehaving server's answers become in the call records (from an audit): a key
echoed in an escaped form, a usage object of zeros, an HTML page or broken JSON with
HTTP 200, a ``finish_reason`` of null."""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.agent.calls import call_json
from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm import GenerationConfig, LLMClient, Message
from skyvln_eval.llm.cache import ResponseCache
from skyvln_eval.llm.config import RepairPolicy
from skyvln_eval.llm.loopback import (
    LoopbackOpenAIServer,
    Reply,
    answer,
    echo_key,
    key_forms,
    raw,
    refusal,
)
from skyvln_eval.llm.redact import REDACTED, scrub
from skyvln_eval.metrics.cost import call_totals
from tests.llm.loopback_clients import fake_model_prices, loopback_client

HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
CONFIG = GenerationConfig(timeout_s=5.0)
SCHEMA = {"type": "object", "properties": {"greeting": {"type": "string"}}}
STRUCTURED = GenerationConfig(timeout_s=5.0, json_schema=SCHEMA, schema_name="greeting")
#: A key with the characters JSON and URLs escape.
KEY = "sk-proj-AUDIT/9f8e+7d6c5b4a=="


def _client(server: LoopbackOpenAIServer, attempts: int = 2, **options: object) -> LLMClient:
    return loopback_client(server, attempts, **options)


def test_every_escaped_form_of_the_key_is_scrubbed() -> None:
    for name, form in key_forms(KEY).items():
        assert scrub(f"before {form} after", KEY) == f"before {REDACTED} after", name
    # repr (the openai client's error message shows the parsed body so) and hex in capitals.
    assert scrub(repr({"k": KEY}), KEY) == repr({"k": REDACTED})
    assert scrub(KEY.replace("/", "%2F"), KEY) == REDACTED
    assert scrub("nothing to hide", KEY) == "nothing to hide" and scrub(KEY, None) == KEY
    # A placeholder key ("x", as local servers take any) is no secret: scrubbing each "x"
    # would garble the error ("chatcmpl-fa[API key]e" once for a key "k").
    assert scrub("chatcmpl-fake: max tokens exceeded", "x") == "chatcmpl-fake: max tokens exceeded"
    assert scrub("key abcd1234 refused", "abcd1234") == f"key {REDACTED} refused"


def test_every_base64_form_of_the_key_is_scrubbed_whole() -> None:
    # A server that echoed "Authorization: Basic base64(user:key)" put the key into
    # stderr, run.json, results.jsonl and the MCAPs: the scrub knew the key's text only.
    for prefix in ["", "u:", "us:", "user:"]:  # each offset of the key in base64's 3 bytes
        raw = (prefix + KEY).encode()
        encoded = {
            "standard": base64.b64encode(raw).decode(),
            "unpadded": base64.b64encode(raw).decode().rstrip("="),
            "url_safe": base64.urlsafe_b64encode(raw).decode(),
            "url_safe_unpadded": base64.urlsafe_b64encode(raw).decode().rstrip("="),
        }
        for name, form in encoded.items():
            header = f'{{"echo": "Authorization: Basic {form}"}}'
            assert scrub(header, KEY) == f'{{"echo": "Authorization: Basic {REDACTED}"}}', name
            slashed = header.replace("/", "\\/")  # JSON's \/ inside the base64 text
            assert form[4:-4] not in scrub(slashed, KEY).replace("\\/", "/"), name
    # Base64 of something else is left as it is.
    other = base64.b64encode(b"user:another-key-entirely").decode()
    assert scrub(f"Basic {other}", KEY) == f"Basic {other}"


@pytest.mark.parametrize("code", [400, 401, 500])
def test_a_key_echoed_in_any_escaping_reaches_no_record(
    code: int, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("ECHO_KEY", KEY)
    with LoopbackOpenAIServer([echo_key(code)] * 12) as server:
        client = _client(server, api_key_env="ECHO_KEY")
        try:
            result = client.call("motion", HELLO, STRUCTURED)
            texts = [result.error or "", *(r.error or "" for r in result.records)]
        except Exception as error:  # refused credentials stop the call with an error
            texts = [str(error)]
        sent = len(server.requests)
    assert sent >= 1 and all(texts)
    texts.append(caplog.text)  # the negotiation's warnings quote the body too
    for text in texts:
        for name, form in key_forms(KEY).items():
            assert form not in text, (name, text)
    assert REDACTED in texts[0]


def test_a_usage_object_of_zeros_is_no_count_and_no_known_cost(tmp_path: Path) -> None:
    zeros = {"prompt_tokens": 0, "completion_tokens": 0, "total_tokens": 0}
    with LoopbackOpenAIServer([answer('{"greeting": "hi"}', usage=zeros)]) as server:
        priced = loopback_client(server, 2, prices=fake_model_prices(server, tmp_path))
        result = priced.call("motion", HELLO, CONFIG)
    [record] = result.records
    assert record.outcome == "ok"
    # A prompt was sent: 0 prompt tokens means the server did not count, not that it was free.
    assert (record.prompt_tokens, record.completion_tokens, record.cost_usd) == (None, None, None)
    totals = call_totals(result.records)
    assert all(
        totals[column] != totals[column]  # NaN: unknown, shown as n/a
        for column in ("llm_cost_usd", "llm_cost_lower_usd", "llm_prompt_tokens")
    )


@pytest.mark.parametrize(
    ("body", "content_type", "says"),
    [
        (
            "<html><body>502 Bad Gateway for KEY</body></html>",
            "text/html",
            "the body is not JSON (content-type text/html): '<html><body>502 Bad Gateway",
        ),
        (
            '{"id": "KEY", "choices": [{"index": 0, "mess',
            "application/json",
            "the body is not valid JSON (Unterminated string",
        ),
        (
            '["KEY"]',
            "application/json",
            "no choices (AttributeError): the body is '[\"[API key]\"]'",
        ),
        (  # content not text, the key across the 80 characters shown (an audit: cut first,
            # a prefix of the key was no longer the key, and was shown)
            '{"choices": [{"index": 0, "message": {"role": "assistant", "content": '
            + '{"pad": "'
            + "x" * 60
            + '", "k": "KEY"}}, "finish_reason": "stop"}]}',
            "application/json",
            "the message content is dict",
        ),
    ],
)
def test_a_body_that_is_no_completion_is_shown_in_the_error(
    body: str, content_type: str, says: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ECHO_KEY", KEY)
    echoed = body.replace("KEY", KEY.replace("/", "\\/"))  # as JSON may write it
    with LoopbackOpenAIServer([raw(echoed, content_type)]) as server:
        result = _client(server, attempts=1, api_key_env="ECHO_KEY").call("motion", HELLO, CONFIG)
    assert result.completion is None
    [record] = result.records
    error = record.error or ""
    assert record.outcome == "failed" and "malformed response" in error and says in error, error
    assert KEY not in error and KEY[:8] not in error  # nor a prefix of it, cut short
    assert REDACTED in error or error.endswith('"[A, not text')  # what was cut is the marker


def test_a_long_body_is_shown_by_its_start() -> None:
    page = "<html>" + "x" * 5000 + "</html>"
    with LoopbackOpenAIServer([raw(page, "text/html")]) as server:
        result = _client(server, attempts=1).call("motion", HELLO, CONFIG)
    error = result.records[0].error or ""
    assert "'<html>xxx" in error and "…'" in error and len(error) < 400


def _greeting(text: str) -> str:
    if "greeting" not in text:
        raise ActionParseError("no greeting")
    return text


def test_a_null_finish_reason_is_recorded_as_none_and_length_is_still_caught() -> None:
    script = [
        answer('{"greeting": "hi"}', finish_reason=None),
        answer('{"greet', finish_reason="length"),
        answer('{"greeting": "hello"}'),
        answer('{"greeting": "hello again"}'),
    ]
    with LoopbackOpenAIServer(script) as server:
        client = _client(server)
        unsaid = client.call("motion", HELLO, CONFIG)
        cut = call_json(
            client,
            "motion",
            [*HELLO, Message("user", "again")],
            CONFIG,
            _greeting,
            RepairPolicy(repairs=1, budget_factor=2.0),
        )
        plain = call_json(client, "motion", [*HELLO, Message("user", "more")], CONFIG, _greeting)
    assert unsaid.completion is not None and unsaid.completion.finish_reason is None
    assert unsaid.records[0].finish_reason is None  # was recorded as "stop"
    # A cut-off answer is still told apart (and repaired with a larger budget).
    assert cut.records[0].finish_reason == "length" and "cut off" in (cut.records[0].error or "")
    assert cut.value is not None and cut.repairs == 1
    assert plain.value is not None and plain.records[0].finish_reason == "stop"


def _completion_body(message: dict[str, Any], finish: str | None = "stop", **extra: Any) -> str:
    """A chat-completion body around ``message``, as a server would write it."""
    choice = {"index": 0, "message": {"role": "assistant", **message}, "finish_reason": finish}
    return json.dumps({"id": "c", "object": "chat.completion", "choices": [choice], **extra})


@pytest.mark.parametrize(
    ("prompt_tokens", "counted"),
    [
        (True, None),  # int(True) counted 1 token, at a known cost
        (100.7, None),  # cut to 100
        (1e30, None),  # a cost of 1e25 USD an episode
        (-5, None),
        ("100", 100),
        (100.0, 100),
        (120, 120),
    ],
)
def test_only_a_whole_plausible_number_is_a_token_count(
    prompt_tokens: Any, counted: int | None, tmp_path: Path
) -> None:
    usage = {"prompt_tokens": prompt_tokens, "completion_tokens": 20}
    body = _completion_body({"content": '{"greeting": "hi"}'}, usage=usage)
    with LoopbackOpenAIServer([raw(body)]) as server:
        priced = loopback_client(server, 1, prices=fake_model_prices(server, tmp_path))
        [record] = priced.call("motion", HELLO, CONFIG).records
    assert record.outcome == "ok" and record.prompt_tokens == counted
    assert (record.cost_usd is None) == (counted is None)


def test_content_in_parts_is_read_and_content_that_is_no_text_is_a_fault() -> None:
    parts = [{"type": "text", "text": '{"greeting": '}, {"type": "text", "text": '"hi"}'}]
    script = [
        raw(_completion_body({"content": parts})),
        raw(_completion_body({"content": 42})),  # crashed the agent ('int' has no len())
        raw(_completion_body({"content": [{"type": "image_url"}]})),
        answer('{"greeting": "hello"}'),
    ]
    with LoopbackOpenAIServer(script) as server:
        client = loopback_client(server, 3)
        joined = client.call("motion", HELLO, CONFIG)
        retried = client.call("motion", [*HELLO, Message("user", "again")], CONFIG)
    assert joined.completion is not None and joined.completion.text == '{"greeting": "hi"}'
    assert retried.completion is not None and retried.completion.text == '{"greeting": "hello"}'
    assert [r.outcome for r in retried.records] == ["failed", "failed", "ok"]
    errors = [r.error or "" for r in retried.records[:2]]
    assert "the message content is int 42" in errors[0]
    assert "the message content is list" in errors[1]


def test_what_is_no_answer_is_not_cached_and_is_asked_again(tmp_path: Path) -> None:
    # A content filter's stop or an empty reply came back from the cache on every resume:
    # --retry-failed could not reach the server that answered by then.
    script = [
        raw(_completion_body({"content": '{"greeting": "hi"}'}, finish="content_filter")),
        raw(_completion_body({"content": None, "tool_calls": []})),
        answer('{"greeting": "hello"}'),
    ]
    cache = ResponseCache(tmp_path / "cache.sqlite")
    with LoopbackOpenAIServer(script) as server:
        client = loopback_client(server, 1)
        client.cache = cache
        finishes = []
        for _ in range(3):
            completion = client.call("motion", HELLO, CONFIG).completion
            assert completion is not None
            finishes.append((completion.finish_reason, completion.text, len(cache)))
        cached = client.call("motion", HELLO, CONFIG).completion
        sent = len(server.requests)
    assert finishes == [
        ("content_filter", '{"greeting": "hi"}', 0),
        ("stop", "", 0),
        ("stop", '{"greeting": "hello"}', 1),
    ]
    assert sent == 3 and cached is not None and cached.cached


def test_an_answer_without_text_says_so() -> None:
    with LoopbackOpenAIServer(
        [raw(_completion_body({"content": None, "tool_calls": []}))]
    ) as server:
        out = call_json(_client(server, attempts=1), "motion", HELLO, CONFIG, _greeting)
    assert out.value is None and out.error == "the answer had no text"


def test_a_key_echoed_in_an_answer_is_scrubbed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ECHO_KEY", KEY)
    body = _completion_body({"content": f"your key is {KEY}"})
    with LoopbackOpenAIServer([raw(body)]) as server:
        result = _client(server, api_key_env="ECHO_KEY").call("motion", HELLO, CONFIG)
    assert result.completion is not None
    assert result.completion.text == f"your key is {REDACTED}"


def test_a_generation_that_failed_on_the_servers_side_is_a_retried_fault() -> None:
    script = [
        raw(_completion_body({"content": '{"greeting": "half'}, finish="error")),
        answer('{"greeting": "hello"}'),
    ]
    with LoopbackOpenAIServer(script) as server:
        result = _client(server).call("motion", HELLO, CONFIG)
    assert [r.outcome for r in result.records] == ["failed", "ok"]
    assert "the server's generation failed (finish_reason 'error')" in (
        result.records[0].error or ""
    )


def test_the_loopback_server_answers_only_its_endpoint_and_only_with_a_key() -> None:
    # The test server answered any request: a client that posted elsewhere, or sent no
    # key, passed every test against it. It now refuses them as a real server would.
    import urllib.error
    import urllib.request

    def post(url: str, headers: dict[str, str]) -> int:
        request = urllib.request.Request(url, data=b"{}", headers=headers, method="POST")
        try:
            with urllib.request.urlopen(request, timeout=10) as response:
                return int(response.status)
        except urllib.error.HTTPError as error:
            return int(error.code)

    key = {"Authorization": "Bearer sk-test", "Content-Type": "application/json"}
    with LoopbackOpenAIServer() as server:
        assert post(f"{server.base_url}/chat/completions", key) == 200
        assert post(f"{server.base_url}/completions", key) == 404
        assert post(f"{server.base_url}/chat/completions", {}) == 401
        assert len(server.requests) == 1  # only the one it answered
        # The toolkit's client posts where a real server listens, with its key.
        assert _client(server).call("motion", HELLO, CONFIG).text


@pytest.mark.parametrize(
    ("reply", "finish"),
    [
        # OpenAI's structured outputs: the model declines (content null, finish "stop").
        (refusal("I'm sorry, I can't help with that."), "refusal"),
        (answer('{"greeting": "long long', finish_reason="length"), "length"),  # cut off
    ],
    ids=["refusal", "length"],
)
def test_a_refusal_or_a_cut_off_answer_is_not_cached(
    reply: Reply, finish: str, tmp_path: Path
) -> None:
    cache = ResponseCache(tmp_path / "cache.sqlite")
    with LoopbackOpenAIServer([reply, answer('{"greeting": "hello"}')]) as server:
        client = loopback_client(server, 1)
        client.cache = cache
        first = client.call("motion", HELLO, STRUCTURED).completion
        second = client.call("motion", HELLO, STRUCTURED).completion
        sent = len(server.requests)
    assert first is not None and first.finish_reason == finish
    assert second is not None and not second.cached and second.text == '{"greeting": "hello"}'
    assert sent == 2 and len(cache) == 1


def test_a_calls_latency_is_its_request_not_the_making_of_a_client(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # An audit: each process's first call counted its client's set-up (~0.2 s of a
    # 0.06 s request) as the model's latency. A clock that moves only while a client is
    # made: the latency recorded must not see it.
    from skyvln_eval.llm import openai_backend

    clock = [0.0]

    def perf_counter() -> float:  # a millisecond a reading, and 5 s to make a client
        clock[0] += 0.001
        return clock[0]

    monkeypatch.setattr(openai_backend.time, "perf_counter", perf_counter)
    checkout = openai_backend.OpenAIBackend._checkout

    def slow_checkout(self: openai_backend.OpenAIBackend) -> Any:
        clock[0] += 5.0
        return checkout(self)

    monkeypatch.setattr(openai_backend.OpenAIBackend, "_checkout", slow_checkout)
    with LoopbackOpenAIServer([answer('{"greeting": "hello"}')]) as server:
        completion = _client(server).call("motion", HELLO, CONFIG).completion
    assert completion is not None and completion.latency_s < 5.0
