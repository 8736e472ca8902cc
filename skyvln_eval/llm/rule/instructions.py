"""The rule backend's reading of instructions: clause patterns to sub-goals.

It understands the phrasings commanders use in AVDN-style dialogs (and that the synthetic
sample's templates produce): compass headings, turns at intersections or landmarks,
landmarks to pass on a side, distances to fly, landmarks to stop at, and the
destination's description with its name in brackets. Anything else is ignored, as a
careful but literal reader would.
"""

from __future__ import annotations

import re
from typing import Any, Final

from skyvln_eval.agent.lexicon import COMPASS_PATTERN, category_of

ORDINALS: Final = {"first": 1, "second": 2, "third": 3, "fourth": 4, "fifth": 5, "next": 1}
_DISTANCE = r"(\d+(?:\.\d+)?)\s*(?:m|meters|metres)\b"
_PATTERNS: Final = (
    (
        "turn_nth",
        re.compile(r"turn (left|right) at the (first|second|third|fourth|fifth|next) intersection"),
    ),
    (
        "turn_by",
        re.compile(r"turn (left|right) at the (?:intersection|crossing) (?:by|near|with) (.+)"),
    ),
    ("roundabout", re.compile(r"at the (roundabout|traffic circle),? take the (left|right)")),
    ("see_after", re.compile(rf"after about {_DISTANCE} you will see (.+)")),
    (
        "pass",
        re.compile(r"(?:you will pass|keep|pass) (.+?) (on your (left|right)|in front of you)"),
    ),
    ("stop_after", re.compile(rf"(?:stop|land|wait) after (?:about )?{_DISTANCE}")),
    ("fly_about", re.compile(rf"(?:fly|go|move) (?:about|around|roughly) {_DISTANCE}")),
    ("stop_at", re.compile(r"stop (?:when you reach|at) (.+)")),
    ("stop_over", re.compile(r"stop (?:over|above) (.+)")),
    ("destination_is", re.compile(r"(?:the|your) destination is (.+)")),
    ("turn", re.compile(r"\bturn (left|right)\b")),
)
_DESTINATION_TAIL = re.compile(r"^that is (?:the|your) destination$")


def _landmark(phrase: str) -> tuple[str, str | None]:
    """A landmark phrase without its bracketed name, and the name."""
    name = re.search(r"\(([^)]+)\)", phrase)
    cleaned = re.sub(r"\s*\([^)]*\)", "", phrase).strip(" ,.;")
    return cleaned, None if name is None else name.group(1).strip()


def _goal(kind: str, **fields: Any) -> dict[str, Any]:
    return {"kind": kind, **{k: v for k, v in fields.items() if v is not None}}


def _clause_goals(clause: str) -> list[dict[str, Any]]:
    for name, pattern in _PATTERNS:
        m = pattern.search(clause)
        if m is None:
            continue
        if name == "turn_nth":
            return [_goal("turn", direction=m.group(1), ordinal=ORDINALS[m.group(2)])]
        if name == "turn_by":
            return [_goal("turn", direction=m.group(1), landmark=_landmark(m.group(2))[0])]
        if name == "roundabout":
            return [_goal("turn", direction=m.group(2), landmark=m.group(1))]
        if name == "see_after":
            phrase, label = _landmark(m.group(2))
            return [_goal("stop_at", landmark=phrase, name=label, distance_m=float(m.group(1)))]
        if name == "pass":
            side = m.group(3) or "ahead"
            return [_goal("pass", landmark=_landmark(m.group(1))[0], side=side)]
        if name in ("stop_after", "fly_about"):
            return [_goal("stop_after", distance_m=float(m.group(1)))]
        if name in ("stop_at", "stop_over"):
            phrase, label = _landmark(m.group(1))
            return [_goal("stop_at", landmark=phrase, name=label)]
        if name == "destination_is":
            phrase, label = _landmark(m.group(1))
            return [_goal("destination", landmark=phrase, name=label)]
        if name == "turn":
            return [_goal("turn", direction=m.group(1))]
    compass = re.search(COMPASS_PATTERN, clause)
    if compass and re.search(r"\b(head|fly|go|move|towards|continue|keep)\b", clause):
        return [_goal("head", direction=compass.group(1))]
    return []


def parse_instruction(text: str) -> list[dict[str, Any]]:
    """Sub-goals (as JSON dicts) of one instruction, in order."""
    goals: list[dict[str, Any]] = []
    for clause in re.split(r"[.;,]\s*|\s+then\s+", text.lower()):
        clause = clause.strip()
        if not clause:
            continue
        if _DESTINATION_TAIL.match(clause) and goals and goals[-1].get("landmark"):
            goals[-1]["kind"] = "destination"
            continue
        goals.extend(_clause_goals(clause))
    # A bracketed name split off by a comma inside brackets is rare; names stay as found.
    return [g for g in goals if g["kind"] != "turn" or "direction" in g]


def landmark_phrases(text: str) -> list[str]:
    """Every landmark phrase an instruction mentions (for earlier rounds' context)."""
    return [
        g["landmark"]
        for g in parse_instruction(text)
        if g.get("landmark") and category_of(g["landmark"])
    ]
