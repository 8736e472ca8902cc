"""The agent's way of calling an LLM: cache, retries, concurrency limit and accounting.

:class:`LLMClient` wraps one backend. Each :meth:`LLMClient.call` is made for a named
agent module and returns the completion (or ``None`` when the backend gave up) with one
:class:`~skyvln_eval.llm_records.LlmCall` per request sent: a retried 429 leaves a
``failed`` record with its error, a request the server turned down for its form (a
structured-output level, a decoding parameter: negotiation, answered at once in another
form) a ``refused`` one, the answered request one with tokens, cost, latency, the decoding
settings sent and the structured-output level used. Each record's latency is its own
request's time only (a call's answer does not include the refused requests before it,
nor a failed one the time of earlier ones); the call's LLM time is the sum over its
records. The wait for a free slot under ``max_concurrency`` is recorded apart
(``queue_s``, on the first request of the attempt that waited).

A call has a deadline (the retry policy's ``deadline_s``), counted from the moment its
first attempt gets a slot: each attempt is given the time left as its timeout (the
backend bounds an attempt from connect to last byte) and no retry starts that could not
end before it, so no server, however slow, holds a call longer.

Cached answers are recorded with the original call's tokens, cost and latency and
``cached=True``, so a run replayed from the cache reproduces its cost table exactly while
saying it paid nothing again. Cost is ``None`` (unknown) when the model has no price or
the server reported no tokens; only the offline stand-ins cost a known 0.

The client also keeps the records of the calls it made (:meth:`LLMClient.calls_made`):
the agent hands its calls on with its decisions, but a decision that raises hands on
nothing, and its calls, paid for all the same, must still count (the harness takes them
from here, see :mod:`skyvln_eval.harness.rollout`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from skyvln_eval.errors import ConfigError, LLMAuthError, LLMError, LLMTransientError
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.cache import ResponseCache, cache_key
from skyvln_eval.llm.prices import PriceTable, price_key
from skyvln_eval.llm.retry import RetryPolicy, call_with_retries
from skyvln_eval.llm.types import Completion, GenerationConfig, Message, RefusedRequest
from skyvln_eval.llm_records import LlmCall

#: Backends whose calls cost nothing whatever the price table says.
FREE_KINDS = frozenset({"rule", "random", "scripted"})


@dataclass(frozen=True)
class CallResult:
    """A completion (``None`` if every attempt failed), the records of every attempt, the error."""

    completion: Completion | None
    records: tuple[LlmCall, ...]
    error: str | None = None

    @property
    def text(self) -> str | None:
        return None if self.completion is None else self.completion.text


class _Deadline:
    """The deadline of one call: started by its first attempt, in ``time.monotonic`` time."""

    def __init__(self, budget_s: float | None) -> None:
        self.budget_s = budget_s
        self.at: float | None = None

    def left_s(self) -> float | None:
        if self.budget_s is None or self.at is None:
            return self.budget_s
        return self.at - time.monotonic()

    def bound(self, config: GenerationConfig) -> GenerationConfig:
        """``config`` with its timeout cut to the time left (starting the clock)."""
        if self.budget_s is None:
            return config
        if self.at is None:
            self.at = time.monotonic() + self.budget_s
        left = self.at - time.monotonic()
        if left <= 0.0:
            raise LLMTransientError(f"the call's deadline of {self.budget_s:g} s has passed")
        return config if left >= config.timeout_s else replace(config, timeout_s=left)


@dataclass
class LLMClient:
    """Calls one backend through the cache, the retry policy and a concurrency limit.

    ``read_cache=False`` sends every call to the backend and writes its answer over the
    cached one: an episode run again because its answers were unusable (``run
    --retry-failed``) must not get the same answers back from the cache. The ``replay``
    backend always reads (it answers from nothing else).
    """

    backend: LLMBackend
    cache: ResponseCache | None = None
    read_cache: bool = True
    retry: RetryPolicy = field(default_factory=RetryPolicy)
    prices: PriceTable = field(default_factory=PriceTable)
    max_concurrency: int = 4
    sleep: Callable[[float], None] = time.sleep

    def __post_init__(self) -> None:
        if self.max_concurrency < 1:
            raise ConfigError(f"max_concurrency must be >= 1, got {self.max_concurrency}")
        if self.backend.kind == "replay" and self.cache is None:
            raise ConfigError("the replay backend answers only from a cache: set a cache path")
        if self.backend.kind == "replay" and self.cache is not None and not self.cache.usable:
            # Refused here, with the reason: every call would miss, and each miss would
            # blame the cache's contents ("no cached answer") for what its file did.
            raise ConfigError(
                f"the replay backend answers only from a cache, and {self.cache.path} cannot "
                f"be opened ({self.cache.problem or 'closed'})"
            )
        self._slots = threading.BoundedSemaphore(self.max_concurrency)
        self._made: list[LlmCall] = []
        self._made_lock = threading.Lock()

    def calls_made(self, since: int = 0) -> tuple[LlmCall, ...]:
        """The records of the attempts this client made (from the ``since``-th on), in the
        order their calls ended, as made: an answer the agent then found unusable is not
        marked ``invalid`` here (the agent marks its own copy)."""
        with self._made_lock:
            return tuple(self._made[since:])

    def _cost(self, completion: Completion) -> float | None:
        return self._attempt_cost(
            completion.prompt_tokens, completion.completion_tokens, completion.cached_prompt_tokens
        )

    def _attempt_cost(
        self,
        prompt_tokens: int | None,
        completion_tokens: int | None,
        cached_prompt_tokens: int | None = None,
    ) -> float | None:
        """What one request cost: priced from the tokens the server reported for it, answered
        or not; unknown (``None``) when it reported none, since a server may bill a request
        it did not answer. The offline stand-ins cost nothing."""
        if self.backend.kind in FREE_KINDS:
            return 0.0
        if prompt_tokens is None or completion_tokens is None:
            return None  # the server did not say how many tokens it billed
        return self.prices.cost_usd(
            price_key(self.backend.identity()),
            prompt_tokens,
            completion_tokens,
            cached_prompt_tokens,
        )

    def _refused_cost(self, request: RefusedRequest) -> float | None:
        """What a request refused for its form cost: priced from the tokens it reported,
        else nothing. The server turned it down before generating (HTTP 400, or a 5xx
        naming the response format it cannot compile), and providers do not bill such
        requests; counting them as unknown would leave every endpoint that negotiates
        without a cost."""
        if request.prompt_tokens is None or request.completion_tokens is None:
            return 0.0
        return self._attempt_cost(request.prompt_tokens, request.completion_tokens)

    def _base(self, module: str, config: GenerationConfig, repair: bool) -> LlmCall:
        identity = self.backend.identity()
        return LlmCall(
            module=module,
            backend=str(identity["backend"]),
            model=str(identity["model"]) or "-",
            repair=repair,
            temperature=config.temperature,
            max_tokens=config.max_tokens,
        )

    def answered(
        self, base: LlmCall, completion: Completion, attempt: int, queue_s: float
    ) -> LlmCall:
        """The record of an attempt that got ``completion``."""
        return replace(
            base,
            attempt=attempt,
            prompt_tokens=completion.prompt_tokens,
            completion_tokens=completion.completion_tokens,
            cached_prompt_tokens=completion.cached_prompt_tokens,
            reasoning_tokens=completion.reasoning_tokens,
            cost_usd=self._cost(completion),
            latency_s=completion.latency_s,
            queue_s=queue_s,
            cached=completion.cached,
            finish_reason=completion.finish_reason,
            structured_output=completion.structured_output,
            server_defaults=completion.server_defaults,
            temperature=None if "temperature" in completion.server_defaults else base.temperature,
        )

    def call(
        self,
        module: str,
        messages: Sequence[Message],
        config: GenerationConfig,
        repair: bool = False,
    ) -> CallResult:
        """One logical call for agent module ``module`` (``repair``: it asks again after an
        unusable answer).

        Never raises for backend faults (they are returned and recorded), except
        :class:`~skyvln_eval.errors.CacheMissError` from ``replay``, which must stop a run,
        and :class:`~skyvln_eval.errors.LLMAuthError`: with credentials refused, no call
        can succeed.
        """
        result = self._call(module, messages, config, repair)
        self._keep(result.records)
        return result

    def _keep(self, records: Sequence[LlmCall]) -> None:
        with self._made_lock:
            self._made.extend(records)

    def _call(
        self, module: str, messages: Sequence[Message], config: GenerationConfig, repair: bool
    ) -> CallResult:
        base = self._base(module, config, repair)
        key = None
        if self.cache is not None:
            key = cache_key(self.backend.identity(), messages, config)
            reads = self.read_cache or self.backend.kind == "replay"
            hit = self.cache.get(key) if reads else None
            if hit is not None:
                return CallResult(hit, (self.answered(base, hit, 1, 0.0),))
        records: list[LlmCall] = []
        queue_s = [0.0]
        began = [0.0]  # when the latest attempt began: the time of one that fails for good
        deadline = _Deadline(self.retry.deadline_s)

        def attempt() -> Completion:
            waited = began[0] = time.perf_counter()
            with self._slots:
                started = time.perf_counter()
                queue_s[0] = started - waited
                completion = self.backend.generate(messages, deadline.bound(config))
            latency = time.perf_counter() - started
            if completion.latency_s <= 0.0:
                completion = replace(completion, latency_s=latency)
            return completion

        def failed(error: LLMError, latency_s: float, final: bool) -> None:
            # The requests the server turned down for their form before this one are
            # attempts of their own; what is left of the measured time is this request's.
            waited = queue_s[0]
            refused_s = self._keep_refused(base, error.refused, records, queue_s)
            records.append(
                replace(
                    base,
                    cost_usd=self._attempt_cost(
                        error.prompt_tokens, error.completion_tokens, error.cached_prompt_tokens
                    ),
                    prompt_tokens=error.prompt_tokens,
                    completion_tokens=error.completion_tokens,
                    cached_prompt_tokens=error.cached_prompt_tokens,
                    outcome="failed",
                    error=f"{type(error).__name__}: {error}",
                    attempt=len(records) + 1,
                    final=final,
                    latency_s=max(0.0, latency_s - waited - refused_s),
                    queue_s=queue_s[0],
                )
            )

        def on_fault(error: LLMTransientError, latency_s: float) -> None:
            failed(error, latency_s, final=False)

        try:
            completion = call_with_retries(
                attempt, self.retry, on_fault, sleep=self.sleep, time_left_s=deadline.left_s
            )
        except LLMAuthError as error:
            # The refused attempt is kept before the run stops: the episode's row says a
            # call was made, at a cost not known.
            failed(error, time.perf_counter() - began[0], final=True)
            self._keep(records)
            raise
        except LLMTransientError as error:
            records[-1] = replace(records[-1], final=True)  # the last attempt ends the call
            return CallResult(
                None, tuple(records), f"gave up after {len(records)} attempt(s): {error}"
            )
        except LLMError as error:
            failed(error, time.perf_counter() - began[0], final=True)
            return CallResult(None, tuple(records), str(error))
        self._keep_refused(base, completion.refused, records, queue_s)
        completion = replace(completion, refused=())  # recorded: the answer is its own
        records.append(self.answered(base, completion, len(records) + 1, queue_s[0]))
        if self.cache is not None and key is not None and completion.is_answer:
            self.cache.put(key, completion)
        return CallResult(completion, tuple(records))

    def _keep_refused(
        self,
        base: LlmCall,
        refused: Sequence[RefusedRequest],
        records: list[LlmCall],
        queue_s: list[float],
    ) -> float:
        """Append one ``refused`` record per request the server turned down for its form
        (the wait for a slot goes with the first request of the attempt, which waited);
        return their summed latency."""
        for request in refused:
            records.append(
                replace(
                    base,
                    outcome="refused",
                    error=request.error,
                    attempt=len(records) + 1,
                    final=False,
                    prompt_tokens=request.prompt_tokens,
                    completion_tokens=request.completion_tokens,
                    cost_usd=self._refused_cost(request),
                    latency_s=max(0.0, request.latency_s),
                    queue_s=queue_s[0],
                    structured_output=request.structured_output,
                    server_defaults=request.server_defaults,
                    temperature=None
                    if "temperature" in request.server_defaults
                    else base.temperature,
                )
            )
            queue_s[0] = 0.0
        return sum(request.latency_s for request in refused)
