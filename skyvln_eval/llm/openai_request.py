"""The body of a chat-completions request and the counts of its answer, for
:mod:`.openai_backend`: the fields the toolkit sets, the user's extra fields, the messages
(images as data URLs for models that take them; system text moved into the first user
message for models without a system role) and the tokens a response reports.
"""

from __future__ import annotations

import base64
import dataclasses
import json
from collections.abc import Sequence
from typing import Any, Final

from skyvln_eval.errors import ConfigError
from skyvln_eval.llm.types import Message

#: Where the loopback test server finds the task data of a request (only when asked for).
TASK_DATA_FIELD: Final = "skyvln_task_data"
#: Request fields the toolkit sets (decoding settings have their own config fields); a
#: ``stream`` or ``n`` of the user's would break the answer's parsing.
RESERVED_FIELDS: Final = frozenset(
    {
        "model",
        "messages",
        "temperature",
        "top_p",
        "max_tokens",
        "max_completion_tokens",
        "seed",
        "stop",
        "response_format",
        "stream",
        "n",
        "timeout",
        TASK_DATA_FIELD,
    }
)


def checked_extra_body(extra_body: Any) -> dict[str, Any]:
    """``extra_body`` as a plain JSON object, or a :class:`ConfigError` saying what is wrong."""
    if not isinstance(extra_body, dict):
        raise ConfigError(f"extra_body must be a mapping of request fields, got {extra_body!r}")
    taken = sorted(set(extra_body) & RESERVED_FIELDS)
    if taken:
        raise ConfigError(
            f"extra_body cannot set {', '.join(taken)}: the toolkit sets these fields "
            "(decoding settings have their own config fields: temperature, top_p, max_tokens, "
            "budgets, seed)"
        )
    try:
        return dict(json.loads(json.dumps(extra_body, sort_keys=True, allow_nan=False)))
    except (TypeError, ValueError) as error:
        raise ConfigError(f"extra_body must be plain JSON: {error}") from None


def without_system_role(messages: Sequence[Message]) -> list[Message]:
    """``messages`` for a model without a system role: the system messages' text opens the
    first user message (a user message of its own when there is none)."""
    system = "\n\n".join(m.text for m in messages if m.role == "system")
    rest = [m for m in messages if m.role != "system"]
    if not system:
        return rest
    first_user = next((i for i, m in enumerate(rest) if m.role == "user"), None)
    if first_user is None:
        return [Message("user", system), *rest]
    opened = dataclasses.replace(rest[first_user], text=f"{system}\n\n{rest[first_user].text}")
    return [*rest[:first_user], opened, *rest[first_user + 1 :]]


def messages_payload(
    messages: Sequence[Message], system_role: bool, takes_images: bool
) -> list[dict[str, Any]]:
    """``messages`` as the request's ``messages`` field: images as data URLs when the model
    ``takes_images``, the system text in the first user message without a ``system_role``."""
    out: list[dict[str, Any]] = []
    for message in messages if system_role else without_system_role(messages):
        if message.images and takes_images:
            parts: list[dict[str, Any]] = [{"type": "text", "text": message.text}]
            for image in message.images:
                encoded = base64.b64encode(image.data).decode("ascii")
                url = f"data:{image.mime_type};base64,{encoded}"
                parts.append({"type": "image_url", "image_url": {"url": url}})
            out.append({"role": message.role, "content": parts})
        else:
            out.append({"role": message.role, "content": message.text})
    return out


#: More tokens than any model takes or writes in one call: a count beyond it is not one.
MAX_PLAUSIBLE_TOKENS: Final = 100_000_000


def _token_count(value: Any) -> int | None:
    """A reported token count, or ``None`` when it is not one: a boolean (``true`` would
    count 1), a fraction (100.7 is no count, not 100), a negative or implausibly large
    number (a cost of 1e25 USD). Whole numbers in a float or a decimal string are counts."""
    if isinstance(value, bool):
        return None
    if (isinstance(value, float) and value.is_integer()) or (
        isinstance(value, str) and value.isascii() and value.isdigit()
    ):
        value = int(value)
    if not isinstance(value, int):
        return None
    return value if 0 <= value <= MAX_PLAUSIBLE_TOKENS else None


@dataclasses.dataclass(frozen=True)
class Usage:
    """The token counts a response reports (``None``: not reported, or not a count).

    ``cached_prompt_tokens`` is the part of the prompt a provider's prompt cache served
    (OpenAI's ``usage.prompt_tokens_details.cached_tokens``, billed at a discount);
    ``reasoning_tokens`` the part of the completion a reasoning model spent thinking
    (``usage.completion_tokens_details.reasoning_tokens``, billed as output, never shown).
    """

    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    cached_prompt_tokens: int | None = None
    reasoning_tokens: int | None = None


def _detail(usage: Any, group: str, name: str) -> int | None:
    """A count inside a usage detail object (an object or, from some servers, a dict)."""
    details = getattr(usage, group, None)
    if isinstance(details, dict):
        return _token_count(details.get(name))
    return _token_count(getattr(details, name, None))


def reported_usage(response: Any, completion_budget: int | None = None) -> Usage:
    """The token counts a response reports (see :class:`Usage`); a completion count above
    ``completion_budget``, the most the request let the model write (``max_tokens``, or
    ``max_completion_tokens``, which counts reasoning too), is no count of this answer
    (an audit's server said 90 million tokens for a 1024-token budget: $8910 an episode)."""
    usage = getattr(response, "usage", None)
    if usage is None:
        return Usage()
    prompt = _token_count(getattr(usage, "prompt_tokens", None))
    completion = _token_count(getattr(usage, "completion_tokens", None))
    cached = _detail(usage, "prompt_tokens_details", "cached_tokens")
    reasoning = _detail(usage, "completion_tokens_details", "reasoning_tokens")
    if prompt == 0:
        # A prompt was sent, so 0 prompt tokens counts nothing: taken at its word, the
        # call would cost a known $0 and top the cost ranking. Ollama says 0 when its
        # cache served the whole prompt, and its completion count is right: only the
        # prompt count is unknown. Some gateways fill the whole usage object with zeros:
        # a completion of 0 tokens beside it is no count either.
        prompt, cached = None, None
        if completion == 0:
            completion, reasoning = None, None
    if completion is not None and completion_budget is not None and completion > completion_budget:
        completion, reasoning = None, None
    if cached is not None and prompt is not None and cached > prompt:
        cached = None  # more cached than sent: not a count of this prompt
    if reasoning is not None and completion is not None and reasoning > completion:
        reasoning = None
    return Usage(prompt, completion, cached, reasoning)
