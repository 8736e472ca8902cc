"""Retries with exponential backoff and jitter for transient LLM faults (429, 5xx, timeouts).

A call may also have a deadline (``deadline_s``): its attempts and the waits between them
all fit in it. The caller bounds each attempt by the time left (see
:class:`~skyvln_eval.llm.client.LLMClient`); here no wait is started that would end
past the deadline, so a flaky server can never hold a call longer than that.
"""

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
    Retry-After when it gives one (capped at ``max_retry_after_s``). Delays in seconds.
    ``deadline_s`` bounds the whole call, every attempt and wait included (``None``: only
    each attempt's own timeout bounds it)."""

    max_attempts: int = 4
    initial_delay_s: float = 0.5
    multiplier: float = 2.0
    max_delay_s: float = 20.0
    jitter: float = 0.25
    max_retry_after_s: float = 60.0
    seed: int = 0
    deadline_s: float | None = None

    def __post_init__(self) -> None:
        if self.max_attempts < 1:
            raise ConfigError(f"retry max_attempts must be >= 1, got {self.max_attempts}")
        if self.initial_delay_s < 0 or self.max_delay_s < 0 or self.jitter < 0:
            raise ConfigError("retry delays and jitter must be >= 0")
        if self.deadline_s is not None and not self.deadline_s > 0:
            raise ConfigError(f"retry deadline_s must be > 0, got {self.deadline_s}")

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
    time_left_s: Callable[[], float | None] = lambda: None,
) -> T:
    """Run ``attempt`` until it succeeds or the policy gives up (re-raising the last fault).

    ``on_fault(error, attempt_latency_s)`` is told of every transient fault, retried or
    not, so each one is recorded. Non-transient errors propagate at once. ``time_left_s``
    says how much of the call's deadline is left (``None``: no deadline); a retry whose
    wait would not end before it is not made.
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
            delay = policy.delay_s(index, error, rng)
            left = time_left_s()
            if left is not None and delay >= left:
                why = (
                    "the call's deadline has passed"
                    if left <= 0.0
                    else f"no time for another attempt before the call's deadline ({left:.2f} s "
                    f"left, the next wait is {delay:.2f} s)"
                )
                raise LLMTransientError(f"{error}; {why}") from error
            sleep(delay)
    raise AssertionError("unreachable")  # pragma: no cover
