"""The records of LLM use that an episode leaves behind: one per call attempt, one per failure.

Both the LLM client that makes the calls and the metrics that count them use these two
types, so they live here, below both (``llm`` and ``metrics`` import this module; it
imports neither).

* :class:`LlmCall`: one attempt of one call an agent module made: one request sent. A
  logical call is one or more attempts (retries of transient faults, requests sent again
  in another form); its last attempt has ``final=True``. ``outcome`` says what the
  attempt gave: ``ok`` (an answer the module could use), ``invalid`` (an answer it could
  not use: unparseable, out of range, cut off at ``max_tokens``), ``failed`` (no answer:
  a transport fault, an HTTP error, a timeout) or ``refused`` (the server turned the
  request down for its form, a structured-output level or a decoding parameter, and the
  call went on at once in another form: negotiation, not a failure of the call; a call
  whose last form is refused ends in a ``failed`` attempt, so a ``refused`` one is never
  final).
  Tokens are ``None`` when the server did not report them and cost is ``None`` when it is
  unknown (no price for the model, or no token counts): unknown is never written as 0.
* :class:`ModuleFailure`: an agent module whose LLM answer could not be used in the end
  (after retries and repair), and what the agent used instead. A failure of the module
  that chooses the action (``motion``, ``navgpt``) means the decision's action is the
  safe fallback.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, Final, Literal, get_args

from skyvln_eval.errors import (
    LLMEndpointError,
    LLMTransientError,
    ResultRecordError,
    ValidationIssue,
)

CallOutcome = Literal["ok", "invalid", "failed", "refused"]
#: Outcomes of an attempt that got no answer (the server's, a transport's or a refusal).
UNANSWERED: Final = frozenset({"failed", "refused"})
CALL_OUTCOMES: Final = get_args(CallOutcome)
#: How a call's record names the errors that leave it with no answer from the endpoint.
_ENDPOINT_FAILURES: Final = (f"{LLMTransientError.__name__}:", f"{LLMEndpointError.__name__}:")
#: Modules whose answer is the decision's action: their failure means a fallback action.
ACTION_MODULES: Final = frozenset({"motion", "navgpt"})


def _issue(message: str, field_name: str) -> ResultRecordError:
    return ResultRecordError(ValidationIssue(file="<record>", message=message, field=field_name))


def _known_keys(cls: type, data: Any) -> dict[str, Any]:
    """``data`` checked to be an object with no key the record does not have."""
    if not isinstance(data, dict):
        raise _issue(f"expected an object, got {type(data).__name__}", "")
    unknown = sorted(set(data) - {f.name for f in fields(cls)})
    if unknown:
        raise _issue(f"unknown key(s) {unknown}", unknown[0])
    return data


def _check_count(value: Any, name: str, optional: bool) -> None:
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise _issue(f"must be a non-negative integer, got {value!r}", name)


def _check_amount(value: Any, name: str, optional: bool) -> None:
    if value is None and optional:
        return
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        raise _issue(f"must be a finite non-negative number, got {value!r}", name)


@dataclass(frozen=True, kw_only=True)
class LlmCall:
    """One attempt of one LLM call by an agent module; see the module docstring.

    ``latency_s`` is the LLM's time for this attempt's one request (sent to answered, or to
    the error or refusal that ended it), never another request's of the same call,
    excluding ``queue_s``, the wait for a free slot under the client's concurrency limit.
    ``temperature``, ``max_tokens`` and ``structured_output`` (the level of structured
    output the request used: ``json_schema``, ``json_object_schema``, ``json_object`` or
    ``prompt``) are the decoding settings actually sent; ``server_defaults`` names those the
    model refused, which were not sent (``temperature`` is then ``None``: the server's
    default). ``cached_prompt_tokens`` is the part of ``prompt_tokens`` a provider's prompt
    cache served (OpenAI bills it at its ``cached_input`` price), ``reasoning_tokens`` the
    part of ``completion_tokens`` a reasoning model spent thinking (``None``: not
    reported; records written before these fields have none). ``repair`` marks a call that
    asked again after an unusable answer. A cache hit has ``cached=True`` and the
    original call's tokens, cost and latency.
    """

    module: str
    backend: str
    model: str
    outcome: CallOutcome = "ok"
    error: str | None = None
    attempt: int = 1
    final: bool = True
    repair: bool = False
    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    cached_prompt_tokens: int | None = None
    reasoning_tokens: int | None = None
    cost_usd: float | None = None
    latency_s: float = 0.0
    queue_s: float = 0.0
    cached: bool = False
    finish_reason: str | None = None
    temperature: float | None = None
    max_tokens: int | None = None
    structured_output: str | None = None
    server_defaults: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("module", "backend"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise _issue(f"must be a non-empty string, got {getattr(self, name)!r}", name)
        if self.outcome not in CALL_OUTCOMES:
            raise _issue(f"must be one of {CALL_OUTCOMES}, got {self.outcome!r}", "outcome")
        if self.outcome != "ok" and not self.error:
            raise _issue(f"an attempt with outcome {self.outcome!r} needs its error", "error")
        if isinstance(self.attempt, bool) or not isinstance(self.attempt, int) or self.attempt < 1:
            raise _issue(f"must be an integer >= 1, got {self.attempt!r}", "attempt")
        _check_count(self.prompt_tokens, "prompt_tokens", optional=True)
        _check_count(self.completion_tokens, "completion_tokens", optional=True)
        _check_count(self.cached_prompt_tokens, "cached_prompt_tokens", optional=True)
        _check_count(self.reasoning_tokens, "reasoning_tokens", optional=True)
        _check_count(self.max_tokens, "max_tokens", optional=True)
        _check_amount(self.cost_usd, "cost_usd", optional=True)
        _check_amount(self.latency_s, "latency_s", optional=False)
        _check_amount(self.queue_s, "queue_s", optional=False)
        if not isinstance(self.server_defaults, list | tuple) or not all(
            isinstance(p, str) for p in self.server_defaults
        ):
            got = self.server_defaults
            raise _issue(f"must be a list of names, got {got!r}", "server_defaults")
        object.__setattr__(self, "server_defaults", tuple(self.server_defaults))  # JSON: a list
        if self.outcome == "refused" and self.final:
            raise _issue("a refused request never ends its call (the call went on)", "final")

    @property
    def answered(self) -> bool:
        """Whether the request got an answer (usable or not)."""
        return self.outcome not in UNANSWERED

    @property
    def unanswered_after_retries(self) -> bool:
        """Whether this attempt ended its call with no answer from the endpoint: after the
        retries of a transient fault (an outage, a timeout, a server error), or refused by
        an endpoint that cannot serve it (no such route or model). The endpoint's failure,
        not the model's (a prompt beyond its context, refused, is the model's)."""
        return (
            self.final
            and self.outcome == "failed"
            and (self.error or "").startswith(_ENDPOINT_FAILURES)
        )

    @property
    def tokens(self) -> int | None:
        """Prompt plus completion tokens, ``None`` when the server reported none."""
        if self.prompt_tokens is None and self.completion_tokens is None:
            return None
        return (self.prompt_tokens or 0) + (self.completion_tokens or 0)

    def to_json_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json_dict(cls, data: Any) -> LlmCall:
        return cls(**_known_keys(cls, data))


@dataclass(frozen=True, kw_only=True)
class ModuleFailure:
    """A module whose answer could not be used at decision ``step_index``, and the stand-in.

    ``substitute`` says what the agent did instead (``"stop action"``, ``"no sub-goals"``,
    ``"proposal order"``, ...); ``reason`` is the last error.
    """

    step_index: int
    module: str
    reason: str
    substitute: str

    def __post_init__(self) -> None:
        if isinstance(self.step_index, bool) or not isinstance(self.step_index, int):
            raise _issue(f"must be an integer, got {self.step_index!r}", "step_index")
        for name in ("module", "reason", "substitute"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise _issue(f"must be a non-empty string, got {getattr(self, name)!r}", name)

    @property
    def action_fallback(self) -> bool:
        """Whether the decision's action was the fallback (the action module failed)."""
        return self.module in ACTION_MODULES

    def to_json_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json_dict(cls, data: Any) -> ModuleFailure:
        return cls(**_known_keys(cls, data))


def fallback_steps(failures: Sequence[ModuleFailure]) -> set[int]:
    """The decisions (step indices) whose action was the fallback: their action module
    failed, however many of its failures a decision recorded."""
    return {f.step_index for f in failures if f.action_fallback}


def module_usage(
    calls: Sequence[LlmCall], failures: Sequence[ModuleFailure]
) -> dict[str, dict[str, Any]]:
    """Per agent module: calls (repairs included), requests (every attempt sent: retries
    and refused forms included), refused requests (negotiation), failed calls (no answer
    after retries), parse failures (unusable answers), repairs, fallbacks (module
    failures), tokens (``None`` once an answered request's are unknown) and LLM seconds
    (every request's time, refused and failed ones included).
    """
    out: dict[str, dict[str, Any]] = {}

    def entry(module: str) -> dict[str, Any]:
        return out.setdefault(
            module,
            {
                "calls": 0,
                "requests": 0,
                "refused_requests": 0,
                "failed_calls": 0,
                "parse_failures": 0,
                "repairs": 0,
                "fallbacks": 0,
                "prompt_tokens": 0,
                "completion_tokens": 0,
                "llm_s": 0.0,
            },
        )

    for call in calls:
        row = entry(call.module)
        row["llm_s"] += call.latency_s
        row["requests"] += 1
        row["refused_requests"] += call.outcome == "refused"
        for key in ("prompt_tokens", "completion_tokens"):
            value = getattr(call, key)
            if value is None and not call.answered:
                continue  # a request with no answer that reported no tokens adds none
            row[key] = None if value is None or row[key] is None else row[key] + value
        row["parse_failures"] += call.outcome == "invalid"
        if call.final:
            row["calls"] += 1
            row["repairs"] += call.repair
            row["failed_calls"] += call.outcome == "failed"
    for failure in failures:
        entry(failure.module)["fallbacks"] += 1
    for row in out.values():
        row["llm_s"] = round(row["llm_s"], 6)
    return dict(sorted(out.items()))
