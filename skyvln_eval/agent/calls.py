"""LLM calls whose answer must be JSON: parse, record failures, and repair once on request.

Every call the agent makes goes through :func:`call_json`. Its records (one per attempt,
see :class:`~skyvln_eval.llm.client.LLMClient`) get the parse error of an unusable answer
in their ``error`` field, and the exchange (prompt text, answer, error) is kept for the
run log. With ``repair=True`` an unusable answer is sent back once with the reason and a
request for JSON only, under the module name ``<module>_repair``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Generic, TypeVar

from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.types import GenerationConfig, LLMCallRecord, Message

T = TypeVar("T")

REPAIR_REQUEST = (
    "Your previous answer could not be used: {reason}. Answer again with exactly one JSON "
    "object in the required format and nothing else: no prose, no code."
)


@dataclass
class JsonCall(Generic[T]):
    """The parsed value (``None`` when unusable), the raw answer, records, exchanges, error."""

    value: T | None
    text: str | None
    records: list[LLMCallRecord] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    error: str | None = None
    repaired: bool = False


def _exchange(
    module: str, messages: Sequence[Message], text: str | None, error: str | None
) -> dict[str, Any]:
    return {
        "module": module,
        "prompt": [{"role": m.role, "text": m.text, "images": len(m.images)} for m in messages],
        "response": text,
        "error": error,
    }


def _one(
    client: LLMClient,
    module: str,
    messages: Sequence[Message],
    config: GenerationConfig,
    parse: Callable[[str], T],
) -> JsonCall[T]:
    result = client.call(module, messages, config)
    records = list(result.records)
    if result.completion is None:
        return JsonCall(
            None, None, records, [_exchange(module, messages, None, result.error)], result.error
        )
    text = result.completion.text
    try:
        value = parse(text)
    except ActionParseError as error:
        reason = str(error)
        records[-1] = replace(records[-1], error=f"invalid output: {reason}")
        return JsonCall(None, text, records, [_exchange(module, messages, text, reason)], reason)
    return JsonCall(value, text, records, [_exchange(module, messages, text, None)])


def call_json(
    client: LLMClient,
    module: str,
    messages: Sequence[Message],
    config: GenerationConfig,
    parse: Callable[[str], T],
    repair: bool = False,
) -> JsonCall[T]:
    """Call, parse with ``parse`` (which raises :class:`ActionParseError`), repair once if asked."""
    first = _one(client, module, messages, config, parse)
    if first.value is not None or not repair or first.text is None:
        return first
    follow_up = [
        *messages,
        Message("assistant", first.text),
        Message("user", REPAIR_REQUEST.format(reason=first.error)),
    ]
    second = _one(client, f"{module}_repair", follow_up, config, parse)
    second.records = first.records + second.records
    second.exchanges = first.exchanges + second.exchanges
    second.repaired = True
    if second.value is None:
        second.error = f"first answer: {first.error}; repair: {second.error}"
    return second
