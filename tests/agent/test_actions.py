"""The closed action vocabulary and strict parsing of LLM decisions, hostile output included."""

from __future__ import annotations

import json

import jsonschema
import pytest

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


def test_the_decision_schema_is_valid_and_matches_the_parser() -> None:
    schema = decision_json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    full = {
        "thought": "t",
        "action": {
            "type": "move_forward",
            "distance_m": 30,
            "degrees": None,
            "landmark": None,
            "height_m": None,
            "x": None,
            "y": None,
            "altitude": None,
        },
    }
    jsonschema.validate(full, schema)
    assert parse_decision(json.dumps(full), {})[1] == Move("forward", 30.0)
