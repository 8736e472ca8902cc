"""The agent's way of calling an LLM: cache, retries, concurrency limit and accounting.

:class:`LLMClient` wraps one backend. Each :meth:`LLMClient.call` is made for a named
agent module and returns the completion (or ``None`` when the backend gave up) with one
:class:`LLMCallRecord` per attempt: a retried 429 leaves a record with its error, the
successful attempt one with tokens, cost and latency. Cached answers are recorded with the
original call's tokens, cost and latency and ``cached=True``, so a run replayed from the
cache reproduces its cost table exactly while saying it paid nothing again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from skyvln_eval.errors import ConfigError, LLMError, LLMTransientError
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.cache import ResponseCache, cache_key
from skyvln_eval.llm.prices import PriceTable
from skyvln_eval.llm.retry import RetryPolicy, call_with_retries
from skyvln_eval.llm.types import Completion, GenerationConfig, LLMCallRecord, Message

#: Backends whose calls cost nothing whatever the price table says.
FREE_KINDS = frozenset({"rule", "random", "scripted"})


@dataclass(frozen=True)
class CallResult:
    """A completion (``None`` if every attempt failed), the records of every attempt, the error."""

    completion: Completion | None
    records: tuple[LLMCallRecord, ...]
    error: str | None = None

    @property
    def text(self) -> str | None:
        return None if self.completion is None else self.completion.text


@dataclass
class LLMClient:
    """Calls one backend through the cache, the retry policy and a concurrency limit."""

    backend: LLMBackend
    cache: ResponseCache | None = None
    retry: RetryPolicy = field(default_factory=RetryPolicy)
    prices: PriceTable = field(default_factory=PriceTable)
    max_concurrency: int = 4
    sleep: Callable[[float], None] = time.sleep

    def __post_init__(self) -> None:
        if self.max_concurrency < 1:
            raise ConfigError(f"max_concurrency must be >= 1, got {self.max_concurrency}")
        if self.backend.kind == "replay" and self.cache is None:
            raise ConfigError("the replay backend answers only from a cache: set a cache path")
        self._slots = threading.BoundedSemaphore(self.max_concurrency)

    def _cost(self, backend: str, model: str, completion: Completion) -> float | None:
        if self.backend.kind in FREE_KINDS:
            return 0.0
        return self.prices.cost_usd(
            backend, model, completion.prompt_tokens, completion.completion_tokens
        )

    def _record(
        self, module: str, completion: Completion | None, latency_s: float, error: str | None
    ) -> LLMCallRecord:
        identity = self.backend.identity()
        backend, model = str(identity["backend"]), str(identity["model"])
        if completion is None:
            return LLMCallRecord(module, backend, model, 0, 0, 0.0, latency_s, False, error)
        return LLMCallRecord(
            module=module,
            backend=backend,
            model=model,
            prompt_tokens=completion.prompt_tokens,
            completion_tokens=completion.completion_tokens,
            cost_usd=self._cost(backend, model, completion),
            latency_s=completion.latency_s,
            cached=completion.cached,
            error=error,
        )

    def call(
        self, module: str, messages: Sequence[Message], config: GenerationConfig
    ) -> CallResult:
        """One logical call for agent module ``module``.

        Never raises for backend faults (they are returned and recorded), except
        :class:`~skyvln_eval.errors.CacheMissError` from ``replay``, which must stop a run.
        """
        key = None
        if self.cache is not None:
            key = cache_key(self.backend.identity(), messages, config)
            hit = self.cache.get(key)
            if hit is not None:
                return CallResult(hit, (self._record(module, hit, hit.latency_s, None),))
        records: list[LLMCallRecord] = []

        def attempt() -> Completion:
            with self._slots:
                started = time.perf_counter()
                completion = self.backend.generate(messages, config)
            latency = time.perf_counter() - started
            if completion.latency_s <= 0.0:
                completion = replace(completion, latency_s=latency)
            return completion

        def on_fault(error: LLMTransientError, latency_s: float) -> None:
            records.append(
                self._record(module, None, latency_s, f"{type(error).__name__}: {error}")
            )

        try:
            completion = call_with_retries(attempt, self.retry, on_fault, sleep=self.sleep)
        except LLMTransientError as error:
            return CallResult(
                None, tuple(records), f"gave up after {len(records)} attempt(s): {error}"
            )
        except LLMError as error:
            records.append(self._record(module, None, 0.0, f"{type(error).__name__}: {error}"))
            return CallResult(None, tuple(records), str(error))
        records.append(self._record(module, completion, completion.latency_s, None))
        if self.cache is not None and key is not None:
            self.cache.put(key, completion)
        return CallResult(completion, tuple(records))
