"""Retries with exponential backoff and jitter for transient LLM faults (429, 5xx, timeouts)."""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from skyvln_eval.errors import ConfigError, LLMTransientError

T = TypeVar("T")


@dataclass(frozen=True)
class RetryPolicy:
    """How to retry: at most ``max_attempts`` tries, waiting ``initial_delay_s * multiplier**k``
    (capped at ``max_delay_s``) plus up to ``jitter`` of that at random, or the server's
    Retry-After when it gives one (capped at ``max_retry_after_s``). Delays in seconds."""

    max_attempts: int = 4
    initial_delay_s: float = 0.5
    multiplier: float = 2.0
    max_delay_s: float = 20.0
    jitter: float = 0.25
    max_retry_after_s: float = 60.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.max_attempts < 1:
            raise ConfigError(f"retry max_attempts must be >= 1, got {self.max_attempts}")
        if self.initial_delay_s < 0 or self.max_delay_s < 0 or self.jitter < 0:
            raise ConfigError("retry delays and jitter must be >= 0")

    def delay_s(self, retry_index: int, error: LLMTransientError, rng: random.Random) -> float:
        """Seconds to wait before retry number ``retry_index`` (0-based)."""
        if error.retry_after_s is not None:
            return min(max(error.retry_after_s, 0.0), self.max_retry_after_s)
        base = min(self.initial_delay_s * self.multiplier**retry_index, self.max_delay_s)
        return base * (1.0 + self.jitter * rng.random())


def call_with_retries(
    attempt: Callable[[], T],
    policy: RetryPolicy,
    on_fault: Callable[[LLMTransientError, float], None],
    sleep: Callable[[float], None] = time.sleep,
) -> T:
    """Run ``attempt`` until it succeeds or the policy gives up (re-raising the last fault).

    ``on_fault(error, attempt_latency_s)`` is told of every transient fault, retried or
    not, so each one is recorded. Non-transient errors propagate at once.
    """
    rng = random.Random(policy.seed)
    for index in range(policy.max_attempts):
        started = time.perf_counter()
        try:
            return attempt()
        except LLMTransientError as error:
            on_fault(error, time.perf_counter() - started)
            if index + 1 >= policy.max_attempts:
                raise
            sleep(policy.delay_s(index, error, rng))
    raise AssertionError("unreachable")  # pragma: no cover
