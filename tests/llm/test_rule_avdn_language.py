"""The rule stand-in reads the language of real AVDN commanders, not only the sample's.

Instructions written by hand in the style of AVDN dialogs (no generator wrote them, none
is taken from the dataset): clock directions relative to the drone, turning back, roof
colours and shapes, generic structures ("the grey building", "a parking lot", "the pond")
as landmarks, "the destination is ...", "you are almost there", "keep going straight".
The drone faces east (90 deg) in every reading with a heading, so that a clock hour and
its compass point differ.
"""

from __future__ import annotations

from typing import Any

import pytest

from skyvln_eval.agent.subgoals import DialogText, parse_subgoals, subgoal_messages
from skyvln_eval.llm import GenerationConfig, create_backend, read_task_data
from skyvln_eval.llm.rule.instructions import landmark_phrases, parse_instruction
from skyvln_eval.llm.rule.matching import compare
from skyvln_eval.vocabulary import (
    category_of,
    clock_at,
    generic_kind_of,
    relative_compass,
    text_similarity,
)

EAST = 90.0


def head(direction: str) -> dict[str, Any]:
    return {"kind": "head", "direction": direction}


def goal(kind: str, landmark: str, **fields: Any) -> dict[str, Any]:
    return {"kind": kind, "landmark": landmark, **fields}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # The audit's five: each read as nothing but "head ahead", or nothing, before.
        (
            "fly towards the big white building at your 2 o'clock",
            [head("southeast"), goal("pass", "the big white building")],
        ),
        (
            "Go forward and you will see a parking lot with many cars, the destination is the "
            "grey building next to it.",
            [
                goal("pass", "a parking lot with many cars"),
                goal("destination", "the grey building"),
            ],
        ),
        (
            "The destination is the round building with a dark roof, it is in front of you.",
            [goal("destination", "the round building with a dark roof")],
        ),
        (
            "Please turn to your 9 o'clock and fly straight, the target is a long white building.",
            [head("north"), goal("destination", "a long white building")],
        ),
        (
            "Turn around and fly to the house with the blue roof",
            # Sent there last, with nowhere else to stop: where to stop.
            [head("west"), goal("stop_at", "the house with the blue roof")],
        ),
        # More in the same style.
        ("You are almost there, keep going straight.", [head("ahead")]),
        (
            "Turn to 10 o'clock direction and fly over the road, you will see a tennis court, "
            "stop there.",
            [head("northeast"), goal("stop_at", "a tennis court")],
        ),
        (
            "Yes. Keep going straight, you will pass a pond on your left.",
            [goal("pass", "a pond", side="left")],
        ),
        (
            "Make a U-turn. Your destination is the warehouse with the grey roof.",
            [head("west"), goal("destination", "the warehouse with the grey roof")],
        ),
        (
            "Head to your two o clock. The goal is a small house with a red roof next to the "
            "swimming pool.",
            [
                head("southeast"),
                goal("destination", "a small house with a red roof next to the swimming pool"),
            ],
        ),
        (
            "Go back the way you came and stop at the parking lot.",
            [head("west"), goal("stop_at", "the parking lot")],
        ),
        (
            "Move towards 11 o'clock, the destination is a tall building with a flat roof",
            [head("northeast"), goal("destination", "a tall building with a flat roof")],
        ),
        (
            "No, reverse your direction. The target is the long building beside the field.",
            [head("west"), goal("destination", "the long building beside the field")],
        ),
        (
            "Fly north along the road for about 200 meters and you will reach a square "
            "building, that is your destination.",
            [head("north"), goal("destination", "a square building", distance_m=200.0)],
        ),
        (
            "you are almost there, the destination is the dark roof at your 1 o'clock.",
            [head("southeast"), goal("destination", "the dark roof")],
        ),
        (
            "Continue south-west, pass the factory on your right and stop above the white "
            "warehouse.",
            [
                head("southwest"),
                goal("pass", "the factory", side="right"),
                goal("stop_at", "the white warehouse"),
            ],
        ),
        (
            "Go straight and turn left at the second intersection, the destination is the "
            "circular building.",
            [
                {"kind": "turn", "direction": "left", "ordinal": 2},
                goal("destination", "the circular building"),
            ],
        ),
        # A clock hour with nowhere to fly says where a landmark is seen.
        (
            "At your 3 o'clock you can see a tennis court. Fly to 12 o'clock and land on the "
            "brown house.",
            [
                goal("pass", "a tennis court", side="right"),
                head("east"),
                goal("stop_at", "the brown house"),
            ],
        ),
        ("Fly back, the destination is the lake.", [head("west"), goal("destination", "the lake")]),
        (
            "Turn to your 6 o'clock and go 100 m.",
            [head("west"), {"kind": "stop_after", "distance_m": 100.0}],
        ),
        # The sample's categories read as before, next to a generic word.
        (
            "The destination is the church roof at your 12 o'clock.",
            [head("east"), goal("destination", "the church roof")],
        ),
        # Told not to turn back: no heading from it.
        ("Don't turn around, keep going straight.", [head("ahead")]),
    ],
)
def test_avdn_style_instructions_are_read_with_the_drones_heading(
    text: str, expected: list[dict[str, Any]]
) -> None:
    assert parse_instruction(text, None, EAST) == expected


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Fly to your 12 o'clock.", [head("ahead")]),
        ("fly towards the building at your 2 o'clock", [{"kind": "turn", "direction": "right"}]),
        ("Turn to ten o'clock.", [{"kind": "turn", "direction": "left"}]),
        ("Turn to your 6 o'clock.", [{"kind": "turn", "direction": "right"}] * 2),
        ("Turn around.", [{"kind": "turn", "direction": "right"}] * 2),
    ],
)
def test_without_a_heading_clock_directions_are_turns(
    text: str, expected: list[dict[str, Any]]
) -> None:
    got = parse_instruction(text)
    assert [g for g in got if g["kind"] != "pass"] == expected


def test_clock_hours_are_read_in_the_forms_people_write_them() -> None:
    for text in ("2 o'clock", "2 o clock", "2 oclock", "two o'clock", "two o clock"):
        assert clock_at(text.split(), 0) == (2, len(text.split())), text
    assert clock_at(["13", "o'clock"], 0) is None
    assert clock_at(["2", "clocks"], 0) is None
    assert clock_at(["2", "meters"], 0) is None
    # 12 is the heading, 3 the right, 6 behind, 9 the left; the nearest of 8 points.
    assert [relative_compass(h * 30.0, EAST) for h in (12, 1, 2, 3, 6, 9, 10)] == [
        "east",
        "southeast",
        "southeast",
        "south",
        "west",
        "north",
        "northeast",
    ]


def test_generic_structures_are_landmarks_but_no_category() -> None:
    assert landmark_phrases("Fly over the grey roof and the car park, then the house.") == [
        "the grey roof",
        "the car park",
        "the house",
    ]
    assert category_of("the round building with a dark roof") is None
    assert generic_kind_of("the round building with a dark roof") == "building"
    assert category_of("the house next to the church") is None  # a house, placed by a church
    assert category_of("a white hospital with a red cross on its roof") == "hospital"
    assert category_of("the church roof") == "church"
    assert category_of("the parking lot by the park") is None
    assert category_of("the park by the parking lot") == "park"
    phrase = "the round building with a dark roof"
    # A generic word is no category match with every detection...
    assert text_similarity("the building", "church", "a church") == 0.0
    assert text_similarity("the building", "hotel", "a hotel") == 0.0
    # ... the same generic word counts (half a category), attributes add the rest.
    assert text_similarity(phrase, "building", "a round building with a dark roof") == 0.7
    assert text_similarity(phrase, "church", "a round church with a dark roof") == pytest.approx(
        0.3
    )
    assert text_similarity("the circular pond", "pond", "a round pond") == pytest.approx(0.3 + 0.4)
    # Categories score as before.
    assert text_similarity("a red church", "church", "a red church") == 1.0
    # HSD's description: the same generic word is a partial match at most, a category
    # strong; a generic word against a category is no more than its attributes.
    assert compare("the grey building", "building", "a grey building")[0] == "partial"
    assert compare("the grey church", "church", "a grey church")[0] == "strong"
    assert compare("the round building", "church", "a red church")[0] == "none"


def test_the_subgoal_request_says_which_way_the_drone_faces() -> None:
    dialog = DialogText((), None, "Turn to your 3 o'clock, the destination is the grey building.")
    messages = subgoal_messages(dialog, 91.6)
    data = read_task_data(messages)
    assert data["heading_deg"] == 92
    assert "You are facing 92 degrees (compass bearing)." in messages[-1].text
    answer = create_backend("rule").generate(messages, GenerationConfig()).text
    plan = parse_subgoals(answer, dialog)
    assert [g.to_dict() for g in plan.subgoals] == [
        head("south"),
        goal("destination", "the grey building"),
    ]
    # Without a heading the request says nothing of it, and the reader turns right.
    bare = subgoal_messages(dialog)
    assert "heading_deg" not in read_task_data(bare) and "facing" not in bare[-1].text
    answer = create_backend("rule").generate(bare, GenerationConfig()).text
    assert parse_subgoals(answer, dialog).subgoals[0].to_dict() == {
        "kind": "turn",
        "direction": "right",
    }
