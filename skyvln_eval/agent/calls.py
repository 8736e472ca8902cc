"""LLM calls whose answer must be JSON: parse, record failures, and repair.

Every call the agent makes goes through :func:`call_json`. An answer the parser rejects,
one cut off at its token budget (``finish_reason == "length"``), one the server's content
filter stopped (``"content_filter"``, Azure OpenAI's and others'), or the model's refusal
(OpenAI's structured outputs; the backend gives ``finish_reason == "refusal"``) is an
``invalid`` attempt: its record says why, and the call is asked again (``repair``): the
invalid answer and the parser's reason go back to the model, at the repair temperature
(higher than the first try's, so the same answer is not simply repeated) and, for a
cut-off answer, with a larger budget. A reasoning model (OpenAI's o-series, gpt-5) whose
hidden reasoning used the whole budget left nothing visible to shorten: it is asked the
same again with four times the budget (at most :data:`MAX_BUDGET_TOKENS`), and its record
says the reasoning used the budget. The exchange of every request (prompt, answer, error, the
records of its attempts with tokens, latency, decoding settings and finish reason) is
kept for the run log.

When no answer could be used, the result says so (``value is None`` with ``error``) and
the calling module records what it does instead as a
:class:`~skyvln_eval.llm_records.ModuleFailure`: never an empty result passed off as an
answer.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final, Generic, TypeVar

from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import RepairPolicy
from skyvln_eval.llm.types import GenerationConfig, Message
from skyvln_eval.llm_records import LlmCall, ModuleFailure

T = TypeVar("T")

NO_REPAIR: Final = RepairPolicy(repairs=0)
MAX_BUDGET_TOKENS: Final = 32768
#: How much a budget grows when a model's reasoning used it all before any visible answer:
#: more than an answer cut short needs, since reasoning grows with the room it is given.
REASONING_BUDGET_FACTOR: Final = 4.0

REPAIR_REQUEST: Final = (
    "Your previous answer could not be used: {reason}. Answer again with exactly one JSON "
    "object in the required format and nothing else: no prose, no code."
)
CUT_OFF_REQUEST: Final = (
    "Your previous answer was cut off after {tokens} tokens, before it was complete. Answer "
    "again, more briefly, with exactly one complete JSON object in the required format."
)


@dataclass
class JsonCall(Generic[T]):
    """The parsed value (``None`` when unusable), the raw answer, records, exchanges, error."""

    value: T | None
    text: str | None
    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    error: str | None = None
    repairs: int = 0

    @property
    def repaired(self) -> bool:
        return self.repairs > 0

    def failure(self, module: str, substitute: str) -> ModuleFailure | None:
        """The module failure to record when this call gave nothing usable (else None)."""
        if self.value is not None:
            return None
        return ModuleFailure(
            step_index=-1, module=module, reason=self.error or "no answer", substitute=substitute
        )


def exchange(
    module: str,
    messages: Sequence[Message],
    config: GenerationConfig,
    text: str | None,
    error: str | None,
    records: Sequence[LlmCall],
) -> dict[str, Any]:
    """One request as the run log keeps it: prompt, answer, error, decoding, attempts."""
    return {
        "module": module,
        "prompt": [
            {"role": m.role, "text": m.text, "images": [i.label for i in m.images]}
            for m in messages
        ],
        "response": text,
        "error": error,
        "decoding": {
            "temperature": config.temperature,
            "top_p": config.top_p,
            "max_tokens": config.max_tokens,
            "seed": config.seed,
            "schema": config.schema_name if config.json_schema is not None else None,
        },
        "calls": [r.to_json_dict() for r in records],
    }


def _invalid(records: list[LlmCall], reason: str) -> None:
    records[-1] = replace(records[-1], outcome="invalid", error=f"invalid output: {reason}")


def call_json(
    client: LLMClient,
    module: str,
    messages: Sequence[Message],
    config: GenerationConfig,
    parse: Callable[[str], T],
    repair: RepairPolicy = NO_REPAIR,
) -> JsonCall[T]:
    """Call, parse with ``parse`` (which raises :class:`ActionParseError`), repair as asked."""
    out: JsonCall[T] = JsonCall(None, None)
    asked, current = list(messages), config
    for index in range(repair.repairs + 1):
        result = client.call(module, asked, current, repair=index > 0)
        records = list(result.records)
        completion = result.completion
        if completion is None:  # no answer after retries: nothing to repair
            out.error = result.error or "no answer"
            out.records += records
            out.exchanges.append(exchange(module, asked, current, None, out.error, records))
            return out
        text = completion.text
        # What the model is told when asked again (None: the same request, asked again).
        follow_up: str | None
        if completion.finish_reason == "length" and not text.strip():
            # Nothing visible was cut: the model's hidden reasoning used the budget (the
            # server's count says how much, when it gives one). "More briefly" would not
            # help; the same request with more room does.
            spent = completion.reasoning_tokens
            used = "" if spent is None else f" ({spent} reasoning tokens)"
            reason = (
                f"the model's reasoning used the whole budget of max_tokens={current.max_tokens}"
                f"{used} before any visible answer (finish_reason 'length')"
            )
            follow_up = None
            budget = min(MAX_BUDGET_TOKENS, math.ceil(current.max_tokens * REASONING_BUDGET_FACTOR))
        elif completion.finish_reason == "length":
            reason = (
                f"the answer was cut off at max_tokens={current.max_tokens} "
                "(finish_reason 'length')"
            )
            follow_up = CUT_OFF_REQUEST.format(tokens=current.max_tokens)
            budget = min(MAX_BUDGET_TOKENS, math.ceil(current.max_tokens * repair.budget_factor))
        elif completion.finish_reason == "refusal":
            reason = f"the model declined to answer: {text[:200]!r}"
            follow_up = REPAIR_REQUEST.format(reason=reason)
            budget = current.max_tokens
        elif completion.finish_reason == "content_filter":
            # What the server's filter let through is not the model's answer, even if it parses.
            reason = (
                "the server's content filter stopped the answer (finish_reason 'content_filter')"
            )
            follow_up = REPAIR_REQUEST.format(reason=reason)
            budget = current.max_tokens
        elif not text.strip():
            # Nothing to parse (a reply of tool calls only, or no content): say so, to the
            # record and to the model asked again, not "not a JSON object".
            reason = "the answer had no text"
            follow_up = REPAIR_REQUEST.format(reason=reason)
            budget = current.max_tokens
        else:
            try:
                out.value = parse(text)
            except ActionParseError as error:
                reason = str(error)
                follow_up = REPAIR_REQUEST.format(reason=reason)
                budget = current.max_tokens
            else:
                out.text, out.error = text, None
                out.records += records
                out.exchanges.append(exchange(module, asked, current, text, None, records))
                return out
        _invalid(records, reason)
        out.text, out.error = text, reason
        out.records += records
        out.exchanges.append(exchange(module, asked, current, text, reason, records))
        if index < repair.repairs:
            out.repairs += 1
            if follow_up is not None:
                asked = [*asked, Message("assistant", text), Message("user", follow_up)]
            current = replace(
                current, temperature=max(current.temperature, repair.temperature), max_tokens=budget
            )
    if out.repairs:
        out.error = f"no usable answer after {out.repairs} repair(s); last: {out.error}"
    return out
