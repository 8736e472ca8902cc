"""Structured-output levels: what each sends, which comes next, which an endpoint accepted.

OpenAI-compatible servers differ in what ``response_format`` they accept: OpenAI takes
the strict ``json_schema`` form; llama.cpp's server answers it with HTTP 500 but
constrains decoding by a schema attached to ``{"type": "json_object", "schema": ...}``;
others know only ``json_object`` or nothing at all. A backend tries the levels in
:data:`~skyvln_eval.llm.types.STRUCTURED_LEVELS` order and keeps, per endpoint and for
the rest of the process, the first level that was answered; :func:`negotiated_levels`
gives them for a run's provenance.
"""

from __future__ import annotations

import threading
from typing import Any, Final, Literal, get_args

from skyvln_eval.llm.types import STRUCTURED_LEVELS, StructuredLevel

#: What a backend config may say: negotiate (``auto``), or pin one level.
StructuredSetting = Literal["auto", "json_schema", "json_object_schema", "json_object", "prompt"]
STRUCTURED_SETTINGS: Final = get_args(StructuredSetting)

_levels: dict[str, StructuredLevel] = {}
_lock = threading.Lock()


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
    """Forget every endpoint's level (tests; a long-lived process whose servers changed)."""
    with _lock:
        _levels.clear()
