"""Sub-goal extraction: the rule backend's reading of instructions and strict parsing."""

from __future__ import annotations

import json

import jsonschema
import pytest

from skyvln_eval.agent.subgoals import (
    MAX_PHRASE_WORDS,
    SUBGOAL_FIELDS,
    DialogText,
    SubGoal,
    parse_subgoals,
    subgoal_messages,
    subgoals_json_schema,
)
from skyvln_eval.avdn import parse_utterances
from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm import GenerationConfig, create_backend, read_task_data
from skyvln_eval.llm.rule.instructions import parse_instruction


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "Go south, you will pass a bridge that carries Bridge Street over the river on your "
            "left. Fly about 100 meters and wait there.",
            [
                {"kind": "head", "direction": "south"},
                {
                    "kind": "pass",
                    "landmark": "a bridge that carries bridge street over the river",
                    "side": "left",
                },
                {"kind": "stop_after", "distance_m": 100.0},
            ],
        ),
        (
            "Head northeast along the road, turn left at the second intersection. "
            "Stop when you reach the gas station.",
            [
                {"kind": "head", "direction": "northeast"},
                {"kind": "turn", "direction": "left", "ordinal": 2},
                {"kind": "stop_at", "landmark": "the gas station"},
            ],
        ),
        (
            "Good, move towards the south. After about 200 meters you will see a small restaurant "
            "with a black roof (Golden Wok restaurant); that is your destination.",
            [
                {"kind": "head", "direction": "south"},
                {
                    "kind": "destination",
                    "landmark": "a small restaurant with a black roof",
                    "name": "Golden Wok restaurant",
                    "distance_m": 200.0,
                },
            ],
        ),
        (
            "At the roundabout take the right, stop over a church with a cross-shaped red roof "
            "and a bell tower, that is the destination.",
            [
                {"kind": "turn", "direction": "right", "landmark": "the roundabout"},
                {
                    "kind": "destination",
                    "landmark": "a church with a cross-shaped red roof and a bell tower",
                },
            ],
        ),
        ("Yes, keep going. No idea what else to say", [{"kind": "head", "direction": "ahead"}]),
        ("?!", []),
    ],
)
def test_the_rule_backend_reads_instructions_into_subgoals(
    text: str, expected: list[dict[str, object]]
) -> None:
    assert parse_instruction(text) == expected


def test_the_prompt_carries_earlier_rounds_and_the_current_one() -> None:
    turns = parse_utterances("[INS] Go west. Stop when you reach the church.", 1)
    turns += parse_utterances("[QUE] Where now? [INS] Go north. The destination is a red hotel.", 2)
    messages = subgoal_messages(DialogText.of(turns, current_round=2))
    data = read_task_data(messages)
    text = messages[-1].text  # the model reads the same, once, in prose
    assert "Where now?" in text and "Go west. Stop when you reach the church." in text
    assert data["task"] == "subgoals" and data["question"] == "Where now?"
    assert data["instruction"] == "Go north. The destination is a red hotel."
    assert data["previous_rounds"] == ["commander: Go west. Stop when you reach the church."]
    answer = create_backend("rule").generate(messages, GenerationConfig()).text
    plan = parse_subgoals(answer, DialogText.of(turns, current_round=2))
    assert plan.subgoals == (
        SubGoal("head", direction="north"),
        SubGoal("destination", landmark="a red hotel"),
    )
    assert plan.landmark_phrases == ["a red hotel"]
    assert plan.context_landmarks == ("the church",)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        ({"subgoals": [{"kind": "fly_away"}]}, "kind 'fly_away' is not one of"),
        ({"subgoals": [{"kind": "destination"}]}, "needs a landmark phrase"),
        ({"subgoals": [{"kind": "head", "direction": "up"}]}, "not a compass point"),
        ({"subgoals": [{"kind": "stop_after", "distance_m": 1e7}]}, "distance_m must be"),
        ({"subgoals": [{"kind": "turn", "direction": "left", "ordinal": 0}]}, "ordinal must be"),
        ({"subgoals": [{"kind": "head", "direction": "north", "cmd": "rm"}]}, "unknown field"),
        ({"subgoals": "go north"}, "must be a list"),
        # What Gemma 3 270M wrote under the grammar: a fragment of JSON as a landmark.
        ({"subgoals": [{"kind": "pass", "landmark": "}, {"}]}, r"'\}, \{' has no words"),
        (
            {"subgoals": [{"kind": "stop_at", "landmark": "the blue stadium"}]},
            r"landmark 'the blue stadium' is not in the dialog \(it has no 'blue', 'stadium'\)",
        ),
        (
            {"subgoals": [{"kind": "destination", "landmark": "the church", "name": "St Mary"}]},
            r"subgoals\[0\].name 'St Mary' is not in the dialog",
        ),
        (
            {
                "subgoals": [{"kind": "stop_at", "landmark": "the church"}],
                "context_landmarks": ["a red hotel"],
            },
            r"context_landmarks\[0\]",
        ),
        # The instruction has words, so a plan without sub-goals is a failed extraction.
        ({"subgoals": [], "context_landmarks": []}, "'subgoals' is empty"),
        # Another object altogether: the repair is told what is missing and what is not ours.
        ({"answer": 42}, "the field 'subgoals' .* is missing; unknown field.s. answer"),
        # Copied, but only where, not what (Gemma 3 270M: ten sub-goals "pass 'left'").
        ({"subgoals": [{"kind": "pass", "landmark": "the west"}]}, "'the west' names no landmark"),
        (
            {"subgoals": [{"kind": "head", "direction": "west"}], "context_landmarks": ["west"]},
            r"context_landmarks\[0\] 'west' names no landmark",
        ),
        # A decoder's loop: the same sub-goal three times in a row.
        (
            {"subgoals": [{"kind": "stop_at", "landmark": "the church"}] * 3},
            r"subgoals\[0\] to subgoals\[2\] are the same sub-goal",
        ),
    ],
)
def test_invalid_subgoals_are_rejected_with_a_reason(
    payload: dict[str, object], reason: str
) -> None:
    dialog = DialogText(("commander: Go west.",), None, "Stop when you reach the church.")
    with pytest.raises(ActionParseError, match=reason):
        parse_subgoals(json.dumps(payload), dialog)


def test_a_step_said_twice_and_a_landmark_with_a_direction_are_plans() -> None:
    dialog = DialogText((), None, "Turn left, then turn left again at the church on the left.")
    answer = {
        "subgoals": [
            {"kind": "turn", "direction": "left"},
            {"kind": "turn", "direction": "left"},
            {"kind": "stop_at", "landmark": "the church on the left"},
        ]
    }
    plan = parse_subgoals(json.dumps(answer), dialog)
    assert plan.landmark_phrases == ["the church on the left"]


def test_speaker_labels_of_earlier_rounds_are_not_dialog_words() -> None:
    dialog = DialogText(("commander: Go west.", "follower: Which way?"), None, "Stop here.")
    answer = {"subgoals": [{"kind": "stop_at", "landmark": "the follower"}]}
    with pytest.raises(ActionParseError, match=r"'follower'"):
        parse_subgoals(json.dumps(answer), dialog)
    assert {"go", "west", "which", "way", "stop", "here"} == dialog.words()


@pytest.mark.parametrize(
    ("landmark", "copied"),
    [
        ("the gas station", True),
        ("Gas-Station", True),
        ("The River-bridge", True),
        ("the river's bridge", False),  # 's' is no word of the dialog
        ("Bridge, gas station", True),
        ("the church", False),  # a word the dialog does not have
        ("}, {", False),  # what Gemma 3 270M wrote without the grammar
        ("commander", False),  # a speaker label, not a word said
        ("the " * MAX_PHRASE_WORDS + "bridge", False),  # too many words
        ("", False),
    ],
)
def test_the_schema_allows_the_copied_phrases_the_parser_accepts_and_none_it_refuses(
    landmark: str, copied: bool
) -> None:
    dialog = DialogText(
        ("commander: Go south to the river.",), "Which bridge?", "Stop at the gas station."
    )
    item = dict.fromkeys(SUBGOAL_FIELDS) | {"kind": "stop_at", "landmark": landmark}
    answer = {"subgoals": [item], "context_landmarks": []}
    validator = jsonschema.Draft202012Validator(subgoals_json_schema(dialog))
    assert validator.is_valid(answer) is copied
    if copied:
        assert parse_subgoals(json.dumps(answer), dialog).landmark_phrases == [landmark]
    else:
        with pytest.raises(ActionParseError):
            parse_subgoals(json.dumps(answer), dialog)
    head = dict.fromkeys(SUBGOAL_FIELDS) | {"kind": "head", "direction": "south"}
    context = {"subgoals": [head], "context_landmarks": [landmark]}
    assert validator.is_valid(context) is copied


@pytest.mark.parametrize(
    ("kind", "landmark", "accepted"),
    [
        ("pass", None, False),
        ("destination", None, False),
        ("head", None, True),
        ("stop_at", "the gas station", True),
        ("turn", "the river", True),
    ],
)
def test_the_schema_and_the_parser_agree_on_which_kinds_name_a_landmark(
    kind: str, landmark: str | None, accepted: bool
) -> None:
    dialog = DialogText((), None, "Go south to the river and stop at the gas station.")
    item = dict.fromkeys(SUBGOAL_FIELDS) | {"kind": kind, "landmark": landmark}
    answer = {"subgoals": [item], "context_landmarks": []}
    validator = jsonschema.Draft202012Validator(subgoals_json_schema(dialog))
    assert validator.is_valid(answer) is accepted
    if accepted:
        assert parse_subgoals(json.dumps(answer), dialog).subgoals[0].kind == kind
    else:
        with pytest.raises(ActionParseError, match="needs a landmark phrase"):
            parse_subgoals(json.dumps(answer), dialog)


def test_a_dialog_without_words_has_a_schema_that_allows_only_what_the_parser_takes() -> None:
    dialog = DialogText((), None, "?!")
    validator = jsonschema.Draft202012Validator(subgoals_json_schema(dialog))
    head = dict.fromkeys(SUBGOAL_FIELDS) | {"kind": "head", "direction": "north"}
    answer = {"subgoals": [head], "context_landmarks": []}
    assert validator.is_valid(answer)
    assert parse_subgoals(json.dumps(answer), dialog).subgoals == (
        SubGoal("head", direction="north"),
    )
    for refused in (
        {"subgoals": [head | {"kind": "pass"}], "context_landmarks": []},
        {"subgoals": [head | {"landmark": "north"}], "context_landmarks": []},
        {"subgoals": [], "context_landmarks": ["north"]},
    ):
        assert not validator.is_valid(refused)
        with pytest.raises(ActionParseError):
            parse_subgoals(json.dumps(refused), dialog)


@pytest.mark.parametrize(("instruction", "empty_allowed"), [("Keep going.", False), ("?!", True)])
def test_an_empty_plan_is_refused_by_schema_and_parser_when_the_instruction_has_words(
    instruction: str, empty_allowed: bool
) -> None:
    dialog = DialogText(("commander: Go west.",), None, instruction)
    empty: dict[str, list[str]] = {"subgoals": [], "context_landmarks": []}
    validator = jsonschema.Draft202012Validator(subgoals_json_schema(dialog))
    assert validator.is_valid(empty) is empty_allowed
    if empty_allowed:
        assert parse_subgoals(json.dumps(empty), dialog).subgoals == ()
    else:
        with pytest.raises(ActionParseError, match="'subgoals' is empty"):
            parse_subgoals(json.dumps(empty), dialog)


def test_copied_phrases_are_read_word_for_word_whatever_the_case_and_punctuation() -> None:
    dialog = DialogText(
        ("commander: Fly past the Red-Roofed church.",), "Where?", "Stop at the gas station."
    )
    answer = {
        "subgoals": [{"kind": "stop_at", "landmark": "The GAS station,"}],
        "context_landmarks": ["red roofed church"],
    }
    plan = parse_subgoals(json.dumps(answer), dialog)
    assert plan.landmark_phrases == ["The GAS station,"]
    assert plan.context_landmarks == ("red roofed church",)


def test_structured_output_nulls_are_accepted() -> None:
    item = {
        "kind": "stop_after",
        "landmark": None,
        "name": None,
        "direction": None,
        "side": None,
        "distance_m": 150,
        "ordinal": None,
    }
    answer = json.dumps({"subgoals": [item], "context_landmarks": []})
    plan = parse_subgoals(answer, DialogText((), None, "Fly 150 metres."))
    assert plan.subgoals == (SubGoal("stop_after", distance_m=150.0),)


def test_the_random_backend_plans_one_heading_the_parser_accepts() -> None:
    # A floor for comparisons must not fail its extractions: its plan is never empty.
    dialog = DialogText((), None, "Fly to the red building by the river.")
    backend = create_backend("random")
    headings = set()
    for seed in range(8):
        answer = backend.generate(subgoal_messages(dialog), GenerationConfig(seed=seed)).text
        (goal,) = parse_subgoals(answer, dialog).subgoals
        assert goal.kind == "head"
        headings.add(goal.direction)
    assert len(headings) > 1  # random, not one fixed heading


@pytest.mark.parametrize(
    ("instruction", "understood"), [("Keep going.", True), ("日本", False), ("é", False)]
)
def test_the_rule_stand_in_s_failed_reading_is_refused_not_hidden(
    instruction: str, understood: bool
) -> None:
    # Words the stand-in has no cue for get an empty plan, which the parser refuses (both
    # read words by one definition, vocabulary.words): the agent records a failed module,
    # where a guess of "ahead" passed for a reading.
    dialog = DialogText((), None, instruction)
    answer = create_backend("rule").generate(subgoal_messages(dialog), GenerationConfig()).text
    if understood:
        assert parse_subgoals(answer, dialog).subgoals
    else:
        with pytest.raises(ActionParseError, match="'subgoals' is empty"):
            parse_subgoals(answer, dialog)


def _arrays(schema: object) -> list[dict[str, object]]:
    if isinstance(schema, dict):
        own = [schema] if schema.get("type") == "array" else []
        return own + [a for value in schema.values() for a in _arrays(value)]
    if isinstance(schema, list):
        return [a for value in schema for a in _arrays(value)]
    return []


def test_the_schema_of_a_dialog_without_words_gives_every_array_its_items() -> None:
    # OpenAI's strict mode refused the whole schema ("array schema missing items") for the
    # empty context_landmarks of a dialog with no words.
    dialog = DialogText((), None, "?! ...")
    schema = subgoals_json_schema(dialog)
    arrays = _arrays(schema)
    assert len(arrays) == 2 and all("items" in array for array in arrays)
    assert schema["properties"]["context_landmarks"]["maxItems"] == 0
    validator = jsonschema.Draft202012Validator(schema)
    assert validator.is_valid({"subgoals": [], "context_landmarks": []})
    assert not validator.is_valid({"subgoals": [], "context_landmarks": ["x"]})


def test_every_modules_parser_refuses_fields_its_schema_does_not_have() -> None:
    # An audit: the motion parser refused an extra top-level field while the sub-goal,
    # HSD and clarification parsers took it without a word. One rule, the schemas'.
    from skyvln_eval.agent.clarify import _parse_question
    from skyvln_eval.agent.hsd import _parse_description, _rank_parser

    dialog = DialogText(("commander: Go west.",), None, "Stop when you reach the church.")
    subgoals = {"subgoals": [{"kind": "stop_at", "landmark": "the church"}], "reasoning": "x"}
    answers = [
        (lambda text: parse_subgoals(text, dialog), subgoals),
        (_parse_description, {"description": "a church", "match": "strong", "notes": ""}),
        (_rank_parser(["L1"]), {"ranking": ["L1"], "best": "L1", "confidence": 1, "why": ""}),
        (_parse_question, {"question": "Which church?", "thought": ""}),
    ]
    for parse, answer in answers:
        with pytest.raises(ActionParseError, match=r"unexpected top-level field\(s\)"):
            parse(json.dumps(answer))
        fine = {
            k: v for k, v in answer.items() if k not in ("reasoning", "notes", "why", "thought")
        }
        parse(json.dumps(fine))  # the same answer without it is taken
