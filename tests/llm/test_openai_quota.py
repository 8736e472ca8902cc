"""A 429 that no wait mends: OpenAI's ``insufficient_quota`` and billing codes stop the run
as refused credentials do (audit scenario quota), while a rate limit is retried."""

from __future__ import annotations

import json

import pytest

from skyvln_eval.errors import LLMAuthError, LLMQuotaError, stops_the_run
from skyvln_eval.llm import GenerationConfig, Message
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer, raw
from tests.llm.loopback_clients import loopback_client

HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
CONFIG = GenerationConfig(timeout_s=5.0)


def _error_429(code: str, type_: str) -> str:
    message = "You exceeded your current quota, please check your plan and billing details."
    return json.dumps({"error": {"message": message, "type": type_, "param": None, "code": code}})


@pytest.mark.parametrize(
    ("code", "type_"),
    [
        ("insufficient_quota", "insufficient_quota"),
        ("billing_hard_limit_reached", "invalid_request_error"),
        (None, "insufficient_quota"),
    ],
)
def test_a_used_up_quota_is_one_request_and_stops_the_run(code: str, type_: str) -> None:
    with LoopbackOpenAIServer([raw(_error_429(code, type_), code=429)] * 4) as server:
        client = loopback_client(server, 4)
        with pytest.raises(LLMQuotaError, match="quota or billing limit") as stopped:
            client.call("motion", HELLO, CONFIG)
        sent = len(server.requests)
    assert sent == 1
    assert isinstance(stopped.value, LLMAuthError)  # the run stops as for HTTP 401
    assert stops_the_run(stopped.value) == str(stopped.value)
    [record] = client.calls_made()  # the refused request is kept before the run stops
    assert record.outcome == "failed" and (record.error or "").startswith("LLMQuotaError:")


def test_a_rate_limit_is_still_retried() -> None:
    limited = raw(_error_429("rate_limit_exceeded", "requests"), code=429)
    with LoopbackOpenAIServer([limited, answer('{"greeting": "hi"}')]) as server:
        result = loopback_client(server, 4).call("motion", HELLO, CONFIG)
        sent = len(server.requests)
    assert sent == 2 and result.completion is not None
