"""A misspelt config field is named with the field it was probably meant to be."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from skyvln_eval.errors import describe_validation_error
from skyvln_eval.harness.config import RunConfig
from skyvln_eval.harness.plan import ReproducePlan


def _problems(model: type, data: dict[str, object]) -> str:
    with pytest.raises(ValidationError) as caught:
        model.model_validate(data)  # type: ignore[attr-defined]
    return describe_validation_error(caught.value, model)


def test_a_misspelt_field_gets_the_close_names_at_its_own_depth() -> None:
    text = _problems(
        RunConfig, {"system": "x", "agent": {"name": "skyvln", "llm": {"temperatur": 0.5}}}
    )
    assert "agent.llm.temperatur: Extra inputs are not permitted" in text
    assert "(did you mean 'temperature', 'repair_temperature'?)" in text


def test_inside_a_list_the_items_fields_are_offered() -> None:
    data = {"table1": {"systems": [{"label": "Full", "agent": {}, "controler": "nmpc"}]}}
    text = _problems(ReproducePlan, data)
    assert "table1.systems.0.controler: Extra inputs are not permitted" in text
    assert "(did you mean 'controller', 'controller_settings'?)" in text


def test_without_a_close_name_the_known_ones_are_listed() -> None:
    text = _problems(RunConfig, {"system": "x", "zzz": 1})
    assert "zzz: Extra inputs are not permitted (known: system, data, splits," in text


def test_without_the_model_the_message_is_pydantics() -> None:
    with pytest.raises(ValidationError) as caught:
        RunConfig.model_validate({"system": "x", "temperatur": 1})
    assert describe_validation_error(caught.value).endswith("Extra inputs are not permitted")
