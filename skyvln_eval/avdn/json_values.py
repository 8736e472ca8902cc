"""Checks of single JSON values of an AVDN record: numbers, text, nested number lists.

Python's json reads more than a record can be used as: booleans are ints, integers have
no bound, and NaN, infinities and lone surrogate escapes decode. These say why a value
is not what the format needs, for :mod:`skyvln_eval.avdn.validation` to report.
"""

from __future__ import annotations

import json
import math
from typing import Any, TypeGuard


class UnderflowedNumber(float):
    """A JSON number that is not zero but that a 64-bit float reads as 0.0 (``1e-400``);
    ``literal`` is its text. Kept apart so a check can refuse it, as it refuses ``1e400``
    (infinite): a record whose number silently became another is not the one written."""

    literal: str

    def __new__(cls, literal: str) -> UnderflowedNumber:
        number = super().__new__(cls, 0.0)
        number.literal = literal
        return number


def read_json_float(literal: str) -> float:
    """A ``parse_float`` for :func:`json.loads` that marks an underflowed literal."""
    value = float(literal)
    if value == 0.0 and any(digit in literal.split("e")[0].split("E")[0] for digit in "123456789"):
        return UnderflowedNumber(literal)
    return value


def is_number(value: Any) -> bool:
    # bool is a subclass of int in Python but a different JSON type.
    return type(value) is float or type(value) is int


def number_problem(value: Any, what: str = "value") -> str | None:
    """Why ``value`` is not a finite number a 64-bit float holds (None if it is one)."""
    if isinstance(value, UnderflowedNumber):
        return f"{value.literal} is too small for a 64-bit float (it would read as 0)"
    if not is_number(value):
        return f"expected a number, got {shown(value)}"
    try:
        finite = math.isfinite(value)
    except OverflowError:  # JSON allows any integer; one beyond 1.8e308 is no float
        return f"an integer of {len(str(abs(value)))} digits is too large for a 64-bit float"
    if not finite:
        return f"NaN or infinite {what} ({value!r})"
    return None


def unwritable(value: Any, path: str) -> tuple[str, str] | None:
    """(path, problem) for the first part of ``value`` that strict JSON in UTF-8 cannot
    hold, though Python's json reads it: a string or key that is not valid Unicode (a
    lone surrogate escape such as ``"\\ud83d"``, half an emoji), a NaN or infinite
    number, or an object that gave a key more than once (only its last value is held).
    Records are kept verbatim in every log, as strict JSON (the viewer's JSON.parse,
    orjson): no writing of these reads back as the same value."""
    if type(value) is float and not math.isfinite(value):
        return path, f"NaN or infinite value ({value!r}): strict JSON has none"
    if isinstance(value, UnderflowedNumber):
        return path, str(number_problem(value))
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError as exc:
            bad = ascii(value[exc.start : exc.end])
            return path, f"not valid Unicode text: lone surrogate {bad} at character {exc.start}"
        return None
    if isinstance(value, list):
        for i, item in enumerate(value):
            if found := unwritable(item, f"{path}[{i}]"):
                return found
    elif isinstance(value, dict):
        # The loader's RepeatedKeys: the values before the last were dropped, silently.
        for key in getattr(value, "repeated", ()):
            return f"{path}[{key!a}]", "key given more than once (JSON keeps the last value)"
        for key, item in value.items():
            name = f"{path}[{key!a}]"
            if found := unwritable(key, name) or unwritable(item, name):
                return found
    return None


def text_ok(value: Any) -> TypeGuard[str]:
    return isinstance(value, str) and unwritable(value, "") is None


def shown(value: Any) -> str:
    """A JSON value for a message, as JSON writes it where Python would not: ``null``,
    ``true``; else its type and Python form (``string 'x'``, ``integer 3``)."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    return f"{type_name(value)} {value!r}"


def type_name(value: Any) -> str:
    if value is None:
        return "null"
    return {
        bool: "boolean",
        int: "integer",
        float: "number",
        str: "string",
        list: "list",
        dict: "object",
    }.get(type(value), type(value).__name__)


def locate_bad_number(value: Any, path: str, depth: int) -> tuple[str, str] | None:
    """Walk a nested list and return (path, problem) for its first bad element."""
    if depth == 0:
        problem = number_problem(value, "coordinate")
        return None if problem is None else (path, problem)
    if not isinstance(value, list):
        return path, f"expected a list, got {type_name(value)}"
    for i, item in enumerate(value):
        found = locate_bad_number(item, f"{path}[{i}]", depth - 1)
        if found:
            return found
    return None
