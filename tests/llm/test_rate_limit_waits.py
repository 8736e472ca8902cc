"""How long a 429 without Retry-After waits: OpenAI's rate-limit headers or its message's
"Please try again in 41.724s", capped by the retry policy's ``max_retry_after_s``."""

from __future__ import annotations

import pytest

from skyvln_eval.llm import GenerationConfig, LLMClient, Message, RetryPolicy, create_backend
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, Reply, answer, status
from skyvln_eval.llm.openai_errors import duration_s

HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
CONFIG = GenerationConfig(timeout_s=5.0)
TRY_AGAIN = (
    "Rate limit reached for gpt-4o-mini in organization org-x on tokens per min (TPM): "
    "Limit 200000, Used 199000, Requested 2000. Please try again in {}. Visit "
    "https://platform.openai.com/account/rate-limits to learn more."
)


def _waits(limited: Reply, max_retry_after_s: float = 60.0) -> list[float]:
    delays: list[float] = []
    with LoopbackOpenAIServer([limited, answer('{"greeting": "hi"}')]) as server:
        backend = create_backend("openai:fake-model", base_url=server.base_url)
        retry = RetryPolicy(initial_delay_s=0.5, jitter=0.0, max_retry_after_s=max_retry_after_s)
        client = LLMClient(backend, retry=retry, sleep=delays.append)
        assert client.call("motion", HELLO, CONFIG).completion is not None
    return delays


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("6m0s", 360.0), ("1s", 1.0), ("20ms", 0.02), ("41.724s", 41.724), ("1h2m3.5s", 3723.5)],
)
def test_openai_durations_are_read(text: str, seconds: float) -> None:
    assert duration_s(text) == pytest.approx(seconds)


def test_a_429_with_only_the_rate_limit_headers_waits_for_the_used_up_limit() -> None:
    limited = status(
        429,
        x_ratelimit_reset_requests="6m0s",
        x_ratelimit_remaining_requests="4999",
        x_ratelimit_reset_tokens="1.5s",
        x_ratelimit_remaining_tokens="0",
    )
    assert _waits(limited) == [pytest.approx(1.5)]  # not the backoff's 0.5 s


def test_a_429_with_only_the_message_waits_as_it_says() -> None:
    assert _waits(status(429, message=TRY_AGAIN.format("2.25s"))) == [pytest.approx(2.25)]
    assert _waits(status(429, message=TRY_AGAIN.format("20ms"))) == [pytest.approx(0.02)]


def test_a_long_wait_is_capped_by_the_retry_policy() -> None:
    limited = status(429, x_ratelimit_reset_requests="6m0s")
    assert _waits(limited, max_retry_after_s=3.0) == [pytest.approx(3.0)]
