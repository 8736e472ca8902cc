"""The closed action vocabulary and strict parsing of LLM decisions, hostile output included."""

from __future__ import annotations

import json
from collections.abc import Callable

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyvln_eval.agent import (
    Climb,
    FlyTo,
    Move,
    Stop,
    Turn,
    Waypoint,
    action_from_dict,
    action_to_dict,
    decision_json_schema,
    parse_decision,
)
from skyvln_eval.agent.actions import ACTION_SPECS, FieldSpec
from skyvln_eval.errors import ActionParseError

LANDMARKS = {"L3": (30.0, -40.0)}


def decision(action: object, thought: str = "ok") -> str:
    return json.dumps({"thought": thought, "action": action})


@pytest.mark.parametrize(
    ("action", "expected"),
    [
        ({"type": "move_forward", "distance_m": 50}, Move("forward", 50.0)),
        ({"type": "move_left", "distance_m": 12.5}, Move("left", 12.5)),
        ({"type": "move_right", "distance_m": 0}, Move("right", 0.0)),
        ({"type": "turn", "degrees": -90}, Turn(-90.0)),
        ({"type": "ascend", "distance_m": 20}, Climb(20.0)),
        ({"type": "descend", "distance_m": 20}, Climb(-20.0)),
        ({"type": "fly_to", "landmark": "L3"}, FlyTo("L3", 30.0, -40.0)),
        ({"type": "fly_to", "landmark": "L3", "height_m": 50}, FlyTo("L3", 30.0, -40.0, 50.0)),
        ({"type": "waypoint", "x": 0.5, "y": -1, "altitude": 0.25}, Waypoint(0.5, -1.0, 0.25)),
        ({"type": "stop"}, Stop()),
    ],
)
def test_every_action_of_the_vocabulary_parses(action: dict[str, object], expected: object) -> None:
    thought, parsed = parse_decision(decision(action, "go"), LANDMARKS)
    assert thought == "go" and parsed == expected
    assert action_from_dict(action_to_dict(parsed), LANDMARKS) == parsed  # round trip


def test_structured_output_nulls_and_a_code_fence_are_accepted() -> None:
    action = {"type": "turn", "degrees": 45, "distance_m": None, "landmark": None, "x": None}
    fenced = "```json\n" + decision(action) + "\n```"
    assert parse_decision(fenced, {})[1] == Turn(45.0)
    # A fence on one line, and the reasoning block a reasoning model served without a
    # reasoning parser writes first (an audit: every episode an error; no repair can
    # take it out), are read as the answer they hold.
    assert parse_decision("```json " + decision(action) + " ```", {})[1] == Turn(45.0)
    thinking = "<think>The user wants JSON. {not this}</think>\n\n" + decision(action)
    assert parse_decision(thinking, {})[1] == Turn(45.0)
    with pytest.raises(ActionParseError, match="not a JSON object"):
        parse_decision("<think>only reasoning</think>", {})
    with pytest.raises(ActionParseError, match="not a JSON object"):  # prose is still prose
        parse_decision("Here it is: ```json\n" + decision(action) + "\n```", {})


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("Sure! I will fly north now.", "not a JSON object"),
        ('{"thought": "x", "action": {"type": "stop"}', "not valid JSON"),
        ('{"thought": "x"}', "no 'action'"),
        (decision({"type": "teleport"}), "unknown action type 'teleport'"),
        (decision({"type": "move_forward"}), r"needs field\(s\) distance_m"),
        (decision({"type": "move_forward", "distance_m": "50"}), "must be a number"),
        (decision({"type": "move_forward", "distance_m": True}), "must be a number"),
        (decision({"type": "turn", "degrees": 720}), "outside the allowed"),
        (decision({"type": "ascend", "distance_m": -5}), "outside the allowed"),
        (decision({"type": "fly_to", "landmark": "L9"}), "not a known one"),
        (decision({"type": "waypoint", "x": 3, "y": 0, "altitude": 0.5}), "outside the allowed"),
        ('{"thought": "x", "action": {"type": "move_forward", "distance_m": NaN}}', "NaN"),
        ('{"thought": "a", "thought": "b", "action": {"type": "stop"}}', "duplicate key"),
        (decision({"type": "stop"}) + decision({"type": "stop"}), "not valid JSON"),
        ("x" * 30_000, "more than"),
    ],
)
def test_invalid_output_is_rejected_with_a_reason(text: str, reason: str) -> None:
    with pytest.raises(ActionParseError, match=reason):
        parse_decision(text, LANDMARKS)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        # An action that asks to run code: the type is not in the vocabulary ...
        (
            decision({"type": "run_code", "code": "import os; os.system('rm -rf /')"}),
            "unknown action type",
        ),
        # ... nor can code ride along on a valid action ...
        (
            decision({"type": "stop", "code": "__import__('os').system('id')"}),
            "does not take field",
        ),
        (
            decision({"type": "move_forward", "distance_m": 10, "shell": "curl evil"}),
            "does not take field",
        ),
        # ... nor replace the action or sit beside it.
        (
            json.dumps({"thought": "t", "action": "__import__('os').system('id')"}),
            "must be a JSON object",
        ),
        (
            json.dumps({"thought": "t", "action": {"type": "stop"}, "exec": "print(1)"}),
            "unexpected top-level",
        ),
        # A huge distance is refused, not clipped silently.
        (decision({"type": "move_forward", "distance_m": 1e9}), "distance_m.*outside the allowed"),
        (decision({"type": "ascend", "distance_m": 5000}), "outside the allowed"),
    ],
)
def test_hostile_output_is_rejected_never_executed(text: str, reason: str) -> None:
    with pytest.raises(ActionParseError, match=reason):
        parse_decision(text, LANDMARKS)


def _instance(kind: str, value_of: Callable[[FieldSpec], object]) -> dict[str, object]:
    return {"type": kind, **{spec.name: value_of(spec) for spec in ACTION_SPECS[kind]}}


def _agree(validator: jsonschema.Draft202012Validator, action: dict[str, object]) -> bool:
    """Whether schema and parser give the same verdict on ``action``; returns the verdict."""
    text = decision(action)
    by_schema = validator.is_valid(json.loads(text))
    try:
        parse_decision(text, LANDMARKS)
        by_parser = True
    except ActionParseError:
        by_parser = False
    assert by_schema == by_parser, (action, by_schema, by_parser)
    return by_parser


def _in_range(spec: FieldSpec, where: float) -> object:
    if spec.kind == "string":
        return "L3"
    return spec.low + where * (spec.high - spec.low)


def test_the_decision_schema_is_a_union_with_exactly_each_actions_fields() -> None:
    schema = decision_json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    variants = schema["properties"]["action"]["anyOf"]
    assert [v["properties"]["type"]["enum"] for v in variants] == [[k] for k in ACTION_SPECS]
    for variant, (kind, specs) in zip(variants, ACTION_SPECS.items(), strict=True):
        assert set(variant["properties"]) == {"type", *(spec.name for spec in specs)}, kind
        assert variant["additionalProperties"] is False


def test_without_landmarks_a_decision_cannot_fly_to_one() -> None:
    none = decision_json_schema([])
    jsonschema.Draft202012Validator.check_schema(none)
    kinds = [v["properties"]["type"]["enum"][0] for v in none["properties"]["action"]["anyOf"]]
    assert "fly_to" not in kinds and len(kinds) == len(ACTION_SPECS) - 1
    fly_to = {"type": "fly_to", "landmark": "L3", "height_m": None}
    assert not jsonschema.Draft202012Validator(none).is_valid(json.loads(decision(fly_to)))
    with pytest.raises(ActionParseError, match="not a known one"):
        parse_decision(decision(fly_to), {})


@settings(max_examples=60, deadline=None)
@given(where=st.floats(0.0, 1.0), kind=st.sampled_from(list(ACTION_SPECS)))
def test_whatever_the_schema_allows_the_parser_accepts(where: float, kind: str) -> None:
    validator = jsonschema.Draft202012Validator(decision_json_schema(list(LANDMARKS)))
    assert _agree(validator, _instance(kind, lambda spec: _in_range(spec, where)))


def test_what_the_schema_refuses_the_parser_refuses_with_a_reason() -> None:
    validator = jsonschema.Draft202012Validator(decision_json_schema(list(LANDMARKS)))
    # A decision's schema names only its landmarks: an id it does not know, both refuse.
    assert not _agree(validator, {"type": "fly_to", "landmark": "L9", "height_m": None})
    for kind, specs in ACTION_SPECS.items():
        valid = _instance(kind, lambda spec: _in_range(spec, 0.5))
        for spec in specs:
            if spec.kind == "number":  # just outside the range, on both sides
                for outside in (spec.low - 1.0, spec.high + 1.0, 10**400):
                    assert not _agree(validator, {**valid, spec.name: outside})
            if spec.required:  # a required field missing
                assert not _agree(validator, {k: v for k, v in valid.items() if k != spec.name})
        others = {spec.name for specs_ in ACTION_SPECS.values() for spec in specs_}
        for name in sorted(others - {spec.name for spec in specs}):  # another action's field
            assert not _agree(validator, {**valid, name: 1.0})
        assert not _agree(validator, {**valid, "code": "import os"})


def test_an_absurd_number_from_a_real_model_is_refused_with_a_reason_not_a_crash() -> None:
    # What Gemma 3 270M wrote under a grammar (see shared/REAL_LLM.md), and worse.
    for text in (
        decision({"type": "move_forward", "distance_m": 2e15}),
        '{"thought": "x", "action": {"type": "turn", "degrees": ' + "9" * 400 + "}}",
        '{"thought": "x", "action": {"type": "turn", "degrees": ' + "9" * 5000 + "}}",
        '{"thought": "x", "action": {"type": "turn", "degrees": 1e999}}',
    ):
        with pytest.raises(ActionParseError, match=r"outside|finite|usable"):
            parse_decision(text, LANDMARKS)
    # A raw newline inside the thought is harmless and accepted.
    raw = '{"thought": "line one\nline two", "action": {"type": "stop"}}'
    assert parse_decision(raw, LANDMARKS)[1] == Stop()
