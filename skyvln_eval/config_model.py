"""The base of the toolkit's config models: unknown fields refused, frozen, finite numbers,
and no boolean taken for a number.

Pydantic's lax mode reads ``true`` as 1 and ``false`` as 0 where a number is expected, and
YAML reads unquoted true / false / yes / no / on / off as booleans: ``workers: true`` ran
one worker and ``detector: {miss_rate: true}`` missed every landmark, without a word (an
audit). The controllers' settings already refused them; every config model does now.
"""

from __future__ import annotations

import types
import typing
from typing import Any, Union

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

from skyvln_eval.errors import FIELD_PATH_CONTEXT

_NUMBERS = (int, float)


def _numbers_in(annotation: Any) -> bool:
    """Whether ``annotation`` takes numbers and never a boolean (``int``, ``float | None``,
    ``Annotated[float, ...]``; a tuple of them is :func:`_tuple_of_numbers`)."""
    if annotation in _NUMBERS:
        return True
    origin = typing.get_origin(annotation)
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if origin is typing.Annotated:
        return _numbers_in(args[0])
    if origin in (Union, types.UnionType):
        return bool(args) and all(_numbers_in(a) for a in args)
    return False


def _tuple_of_numbers(annotation: Any) -> bool:
    """Whether ``annotation`` is a tuple (or an optional one) of numbers only."""
    origin = typing.get_origin(annotation)
    args = [a for a in typing.get_args(annotation) if a not in (type(None), Ellipsis)]
    if origin in (Union, types.UnionType):
        return any(_tuple_of_numbers(a) for a in args)
    return origin is tuple and bool(args) and all(_numbers_in(a) for a in args)


def _boolean(where: str | None) -> PydanticCustomError:
    return PydanticCustomError(
        "bool_for_number",
        "expected a number, got a boolean (YAML reads unquoted true / false / yes / no / on / "
        "off as booleans)",
        {FIELD_PATH_CONTEXT: where} if where else {},
    )


class StrictModel(BaseModel):
    """A config model: unknown fields refused, frozen, no inf or NaN, no boolean for a
    number (nor in a tuple of numbers); boolean fields take booleans as before."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_boolean_for_a_number(cls, value: Any, info: ValidationInfo) -> Any:
        if info.field_name is None:
            return value
        annotation = cls.model_fields[info.field_name].annotation
        if isinstance(value, bool) and _numbers_in(annotation):
            raise _boolean(None)
        if isinstance(value, list | tuple) and _tuple_of_numbers(annotation):
            for i, item in enumerate(value):
                if isinstance(item, bool):
                    raise _boolean(str(i))
        return value
