"""What an endpoint accepts: structured-output levels, and decoding parameters it refuses.

OpenAI-compatible servers differ in what ``response_format`` they accept: OpenAI takes
the strict ``json_schema`` form; llama.cpp's server answers it with HTTP 500 but
constrains decoding by a schema attached to ``{"type": "json_object", "schema": ...}``;
others know only ``json_object`` or nothing at all. A backend tries the levels in
:data:`~skyvln_eval.llm.types.STRUCTURED_LEVELS` order and keeps, per endpoint and for
the rest of the process, the first level that was answered; :func:`negotiated_levels`
gives them for a run's provenance. A refusal of one schema (OpenAI's "Invalid schema for
response_format '<name>'") is kept for that schema alone, under the endpoint's name and
the schema's (``<endpoint> schema <name>``), so the endpoint's other schemas keep theirs.

Models differ in the decoding parameters they take too: OpenAI's reasoning models (o1,
o3, gpt-5) answer ``max_tokens`` with HTTP 400 "Unsupported parameter: 'max_tokens' ...
Use 'max_completion_tokens' instead", and a ``temperature`` other than their default with
"Unsupported value: 'temperature' ...". A backend then sends the budget as
``max_completion_tokens``, or leaves the refused parameter to the server's default, and
keeps that per endpoint (:class:`RequestAdaptation`); each call's record says which
parameters went unsent, so no table claims a temperature the model did not decode at.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from typing import Any, Final, Literal, get_args

from skyvln_eval.llm.types import STRUCTURED_LEVELS, StructuredLevel

#: What a backend config may say: negotiate (``auto``), or pin one level.
StructuredSetting = Literal["auto", "json_schema", "json_object_schema", "json_object", "prompt"]
STRUCTURED_SETTINGS: Final = get_args(StructuredSetting)

_levels: dict[str, StructuredLevel] = {}
#: (endpoint, level) pairs refused once by a bare 400 naming nothing.
_unexplained: set[tuple[str, StructuredLevel]] = set()
_lock = threading.Lock()

#: Decoding parameters a server may refuse and a request can go without (the server's
#: default applies); the budget is never dropped, only renamed.
OPTIONAL_PARAMETERS: Final = ("temperature", "top_p", "seed", "stop")


#: Keywords OpenAI's strict mode does not take (string lengths): left out of the
#: ``json_schema`` level only. Grammar-constrained servers use them to bound the answer;
#: the parser checks them either way.
_NOT_STRICT: Final = frozenset({"minLength", "maxLength"})


def strict_subset(schema: Any) -> Any:
    """``schema`` without the keywords OpenAI's strict structured output refuses."""
    if isinstance(schema, dict):
        return {k: strict_subset(v) for k, v in schema.items() if k not in _NOT_STRICT}
    if isinstance(schema, list):
        return [strict_subset(v) for v in schema]
    return schema


def response_format(
    level: StructuredLevel, schema: dict[str, Any], name: str
) -> dict[str, Any] | None:
    """The ``response_format`` request field of ``level`` (``None``: send none)."""
    if level == "json_schema":
        return {
            "type": "json_schema",
            "json_schema": {"name": name, "schema": strict_subset(schema), "strict": True},
        }
    if level == "json_object_schema":
        return {"type": "json_object", "schema": schema}
    if level == "json_object":
        return {"type": "json_object"}
    return None


def next_level(level: StructuredLevel) -> StructuredLevel | None:
    """The next, less constrained level (``None`` after the last)."""
    index = STRUCTURED_LEVELS.index(level)
    return STRUCTURED_LEVELS[index + 1] if index + 1 < len(STRUCTURED_LEVELS) else None


def negotiated_level(endpoint: str) -> StructuredLevel | None:
    with _lock:
        return _levels.get(endpoint)


def refused_without_reason(endpoint: str, level: StructuredLevel) -> bool:
    """Note that ``endpoint`` refused ``level`` with a bare HTTP 400 naming nothing; whether
    it had done so before. One such refusal may be a one-off fault: the level is given up
    for the endpoint only when it happens again (a refusal that names the format is
    believed at once)."""
    with _lock:
        seen = (endpoint, level) in _unexplained
        _unexplained.add((endpoint, level))
        return seen


def remember_level(endpoint: str, level: StructuredLevel) -> None:
    """Keep ``level`` for ``endpoint``: a later call never tries a level above it again."""
    with _lock:
        known = _levels.get(endpoint)
        if known is None or STRUCTURED_LEVELS.index(level) > STRUCTURED_LEVELS.index(known):
            _levels[endpoint] = level


def negotiated_levels() -> dict[str, StructuredLevel]:
    """Every endpoint's level so far in this process (for provenance)."""
    with _lock:
        return dict(sorted(_levels.items()))


def forget_levels() -> None:
    """Forget every endpoint's level and adaptation (tests; a long-lived process whose
    servers changed)."""
    with _lock:
        _levels.clear()
        _unexplained.clear()
        _adaptations.clear()


@dataclass(frozen=True)
class RequestAdaptation:
    """How an endpoint's requests differ from the standard ones, after it refused some:
    the budget sent as ``max_completion_tokens``, and parameters left to its defaults."""

    completion_tokens_field: bool = False
    server_defaults: frozenset[str] = frozenset()

    def refusing(self, parameter: str) -> RequestAdaptation | None:
        """This adaptation after the server refused ``parameter`` (``None``: nothing left
        to change, the request cannot be sent in a form the server takes)."""
        if parameter == "max_tokens" and not self.completion_tokens_field:
            return replace(self, completion_tokens_field=True)
        if parameter in OPTIONAL_PARAMETERS and parameter not in self.server_defaults:
            return replace(self, server_defaults=self.server_defaults | {parameter})
        return None

    def apply(self, request: dict[str, Any]) -> dict[str, Any]:
        """``request`` (the keyword arguments of a chat completion) as this endpoint takes it."""
        out = {k: v for k, v in request.items() if k not in self.server_defaults}
        if self.completion_tokens_field and "max_tokens" in out:
            out["max_completion_tokens"] = out.pop("max_tokens")
        return out


_adaptations: dict[str, RequestAdaptation] = {}


def adaptation(endpoint: str) -> RequestAdaptation:
    with _lock:
        return _adaptations.get(endpoint, RequestAdaptation())


def remember_adaptation(endpoint: str, found: RequestAdaptation) -> None:
    """Keep what ``endpoint`` refused (with what it refused before, from other threads)."""
    with _lock:
        known = _adaptations.get(endpoint, RequestAdaptation())
        _adaptations[endpoint] = RequestAdaptation(
            known.completion_tokens_field or found.completion_tokens_field,
            known.server_defaults | found.server_defaults,
        )
