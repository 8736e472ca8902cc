"""Strict parsing of LLM output: one JSON object, nothing else, never executed.

The whole answer must be a single JSON object, optionally inside one Markdown code fence
(```` ```json ... ``` ````), which many models add even when told not to. A reasoning
model served without a reasoning parser starts its answer with its reasoning in one
``<think>...</think>`` block, which no repair request can take out (its chat template
writes it): that block is left out, and the rest parsed as any answer (the record keeps
the answer as given). Prose around the object, several objects, NaN / Infinity,
duplicate keys or an answer longer than :data:`MAX_OUTPUT_CHARS` are rejected with an
:class:`ActionParseError` that says why, which the motion generator sends back to the
model once as its repair request.
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Mapping, Sequence
from typing import Any, Final

from skyvln_eval.agent.actions import Action, action_from_dict
from skyvln_eval.errors import ActionParseError
from skyvln_eval.fileio import object_with_unique_keys

MAX_OUTPUT_CHARS: Final = 20_000
MAX_THOUGHT_CHARS: Final = 4_000
_FENCE = re.compile(r"^```(?:json|JSON)?\s*(.*?)\s*```$", re.DOTALL)
_REASONING = re.compile(r"^<think>.*?</think>", re.DOTALL)


def _no_constants(name: str) -> Any:
    raise ActionParseError(f"JSON constant {name} is not allowed")


def _duplicate_key(key: str) -> ActionParseError:
    return ActionParseError(f"duplicate key {key!r} in the JSON object")


_unique_keys = functools.partial(object_with_unique_keys, refuse=_duplicate_key)


def load_json_object(text: str) -> dict[str, Any]:
    """The single JSON object ``text`` consists of (fence allowed); raises otherwise."""
    if len(text) > MAX_OUTPUT_CHARS:
        raise ActionParseError(f"output is {len(text)} characters, more than {MAX_OUTPUT_CHARS}")
    body = _REASONING.sub("", text.strip(), count=1).strip()
    fenced = _FENCE.match(body)
    if fenced:
        body = fenced.group(1).strip()
    if not body.startswith("{"):
        preview = body[:60].replace("\n", " ")
        raise ActionParseError(f"output is not a JSON object (it starts with {preview!r})")
    try:
        # strict=False: a raw newline inside a string (grammar-constrained decoders write
        # them) is harmless and accepted; everything else must be JSON.
        data = json.loads(
            body, strict=False, parse_constant=_no_constants, object_pairs_hook=_unique_keys
        )
    except json.JSONDecodeError as error:
        raise ActionParseError(
            f"output is not valid JSON ({error.msg} at character {error.pos})"
        ) from None
    except (ValueError, RecursionError) as error:  # e.g. an integer of thousands of digits
        raise ActionParseError(f"output is not usable JSON ({error})") from None
    if not isinstance(data, dict):
        raise ActionParseError("output must be one JSON object")
    return data


def refuse_other_fields(data: Mapping[str, Any], allowed: Sequence[str]) -> None:
    """Refuse top-level fields of an answer other than ``allowed``, as its schema does
    (``additionalProperties: false``): the same rule for every module (the motion
    generator's refused them while the others took them without a word)."""
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise ActionParseError(
            f"unexpected top-level field(s) {', '.join(unknown)}; only {', '.join(allowed)}"
        )


def parse_decision(
    text: str, landmark_offsets: Mapping[str, tuple[float, float]]
) -> tuple[str, Action]:
    """``{"thought": str, "action": {...}}`` -> (thought, validated action)."""
    data = load_json_object(text)
    refuse_other_fields(data, ("thought", "action"))
    if "action" not in data:
        raise ActionParseError("the JSON object has no 'action'")
    thought = data.get("thought", "")
    if not isinstance(thought, str):
        raise ActionParseError("'thought' must be a string")
    if len(thought) > MAX_THOUGHT_CHARS:
        raise ActionParseError(f"'thought' is longer than {MAX_THOUGHT_CHARS} characters")
    return thought, action_from_dict(data["action"], landmark_offsets)
