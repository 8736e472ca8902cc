"""Commander / follower dialogs for synthetic trajectories: facts put into words.

Instructions say what a commander looking at the map would (:mod:`.facts`): compass
headings, turns at intersections, distances, landmarks inside the ground-truth views
(with the side they are on) and the destination's appearance. Each clause is written
with a sentence frame drawn from the families a split speaks (:mod:`.phrasebook`), from
a wording stream of its own, so the same route can be phrased by any family. Later
rounds open with the follower's question (``[QUE]``) and the commander's answer
(``[INS]``), as in AVDN.
"""

from __future__ import annotations

import re
import string
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.worlds.city.plan import LandmarkSpec
from skyvln_eval.worlds.sample.facts import LandmarkFact, RoundFacts
from skyvln_eval.worlds.sample.phrasebook import Family, families_named
from skyvln_eval.worlds.sample.pilot import PlanGeo
from skyvln_eval.worlds.sample.wording import compass_erly, compass_ward

#: Version of the dialogs' wording: 1 spoke a handful of fixed frames; 2 speaks families
#: of frames, disjoint between seen and unseen splits; 3 adds the answer to a follower
#: who is already there (``answer.arrived``); 4 writes "an easterly", not "a easterly".
#: Part of the sample's cache key.
DIALOG_VERSION: Final = 4


def _with_articles(template: str, values: dict[str, str]) -> str:
    """``template`` with "a {field}" made "an {field}" where the value starts with a vowel
    ("an easterly heading"); only the frame's own article, never one inside a value."""
    for name, value in values.items():
        if value[:1].lower() in "aeiou":
            template = re.sub(rf"\b([Aa]) (?=\{{{name}\}})", r"\1n ", template)
    return template


_ANSWER_SLOTS: Final = {
    "which_way": "answer.which_way",
    "close": "answer.close",
    "is_it": "answer.is_it",
    "can_see": "answer.can_see",
}
_SENTENCE_START = re.compile(r"(^|[.!?]\s+)([a-z])")


@dataclass(frozen=True)
class Utterance:
    """Text and the ids of the frames it was written with, in order."""

    text: str
    frames: tuple[str, ...]


@dataclass(frozen=True)
class AnswerFacts:
    """What the commander tells a follower who asks the way, from the ground-truth route.

    ``direction``: a compass point ("north", "northeast", ...) to fly, or "left" / "right"
    to turn, or "ahead" to keep the heading. ``distance_m``: how far to fly. ``landmark``:
    the description of the next landmark on the route, or of the destination when
    ``is_destination``. ``wrong_heading``: the compass point the follower is flying when
    it is the wrong one (the answer then opens with a correction). ``arrived``: the
    follower is already there (the answer then only says to stop).
    """

    direction: str
    distance_m: float | None = None
    landmark: str | None = None
    is_destination: bool = False
    wrong_heading: str | None = None
    arrived: bool = False


def sentence_case(text: str) -> str:
    return _SENTENCE_START.sub(lambda m: m.group(1) + m.group(2).upper(), text)


Value = str | int | LandmarkFact | None


class Clause(NamedTuple):
    text: str
    frame_id: str
    family: Family


class Phraser:
    """Writes clauses with frames of ``families``, choosing from a stream seeded by ``seed``."""

    def __init__(self, families: Sequence[str], seed: int) -> None:
        self.families = families_named(families)
        self.rng = np.random.default_rng(seed)

    def family(self) -> Family:
        return self.families[int(self.rng.integers(len(self.families)))]

    def clause(self, slot: str, **facts: Value) -> Clause:
        """One clause saying ``facts`` in the frame for ``slot`` of a family drawn at random."""
        family = self.family()
        frame = family.frame(slot)
        fields = [f for _, f, _, _ in string.Formatter().parse(frame.template) if f]
        values = {f: self._value(family, f, facts) for f in fields}
        text = _with_articles(frame.template, values).format(**values)
        return Clause(text, frame.frame_id, family)

    def _value(self, family: Family, field: str, facts: dict[str, Value]) -> str:
        style = family.style
        value = facts[field.split("_")[0]]  # dir_erly and dir_ward say "dir" another way
        if isinstance(value, LandmarkFact):  # lm
            named = "" if value.name is None else style.name.format(name=value.name)
            return value.description + named
        if field in ("dir", "old"):
            return style.point(self.rng, str(value))
        if field.endswith("_erly"):
            return compass_erly(str(value))
        if field.endswith("_ward"):
            return compass_ward(str(value))
        if field == "nth" and isinstance(value, int):
            return style.ordinal(value)
        if field == "side":
            return style.sides[str(value)]
        if field == "dist" and isinstance(value, int):
            return style.distance(self.rng, value)
        if value is None:
            raise ValueError(f"frame field {field!r} has no value")
        return str(value)  # lr, word, lm given as text

    def join(self, clauses: list[Clause]) -> Utterance:
        """Clauses as sentences: all but the last joined in the manner of one of the
        families, the last on its own, as a commander closes with where to stop."""
        texts = [c.text for c in clauses]
        within = self.family().style.within
        sentences = [within.join(texts[:-1]), texts[-1]] if len(texts) > 1 else texts
        text = " ".join(s.rstrip(".") + "." for s in sentences)
        return Utterance(sentence_case(text), tuple(c.frame_id for c in clauses))


def _round_clauses(phraser: Phraser, facts: RoundFacts) -> list[Clause]:
    clauses = [phraser.clause("head.road" if facts.along_road else "head", dir=facts.heading)]
    for turn in facts.turns:
        if turn.roundabout:
            clauses.append(phraser.clause("turn.roundabout", lr=turn.direction))
        elif turn.at is not None:
            clauses.append(phraser.clause("turn.at", lr=turn.direction, word=turn.at.word))
        else:
            clauses.append(phraser.clause("turn.nth", lr=turn.direction, nth=turn.ordinal))
    if facts.passing is not None:
        passing = facts.passing
        clauses.append(phraser.clause("pass", lm=passing.landmark, side=passing.side))
    if facts.destination is not None:
        slot = "destination.distance" if facts.destination_distance else "destination"
        clauses.append(phraser.clause(slot, lm=facts.destination, dist=facts.distance_m))
    elif facts.stop_at is not None:
        clauses.append(phraser.clause("stop.at", word=facts.stop_at.word))
    else:
        clauses.append(phraser.clause("stop.distance", dist=facts.distance_m))
    return clauses


def render_round(phraser: Phraser, facts: RoundFacts) -> Utterance:
    """One round as an AVDN ``instructions`` string: ``[INS] ...`` or ``[QUE] ... [INS] ...``."""
    clauses = _round_clauses(phraser, facts)
    if facts.question is None:
        body = phraser.join(clauses)
        return Utterance(f"[INS] {body.text}", body.frames)
    question = facts.question
    asked = phraser.clause(f"question.{question.kind}", old=question.heading, word=question.word)
    if question.kind == "keep":
        slot = "answer.yes" if question.heading == question.next_heading else "answer.correct"
    else:
        slot = _ANSWER_SLOTS[question.kind]
    answer = _answered(phraser.clause(slot, old=question.heading), phraser.join(clauses))
    return Utterance(
        f"[QUE] {sentence_case(asked.text)} [INS] {answer.text}", (asked.frame_id, *answer.frames)
    )


def _answered(opening: Clause, body: Utterance) -> Utterance:
    """An answer's opening ("Yes, keep going") joined to the rest in its family's manner."""
    joiner = opening.family.style.answer_joiner
    rest = body.text if joiner.endswith(". ") else body.text[0].lower() + body.text[1:]
    return Utterance(sentence_case(opening.text) + joiner + rest, (opening.frame_id, *body.frames))


def render_trajectory(
    rounds: Sequence[RoundFacts], families: Sequence[str], seed: int
) -> list[Utterance]:
    """Every round of one trajectory phrased with frames of ``families`` (the split's own,
    or any others: the same route in other words), deterministically for ``seed``."""
    phraser = Phraser(families, seed)
    return [render_round(phraser, facts) for facts in rounds]


def commander_answer(facts: AnswerFacts, families: Sequence[str], seed: int) -> Utterance:
    """The commander's answer to a follower's clarification question, in the words of
    ``families`` (e.g. ``SPLIT_FAMILIES[split]``), deterministically for ``seed``.

    It opens with a correction when the follower flies the wrong way, then says which way
    (a compass point, a turn, or straight on), then how far and what comes next; to a
    follower who is already there, only that it is there and should stop.
    """
    phraser = Phraser(families, seed)
    if facts.arrived:
        return phraser.join([phraser.clause("answer.arrived")])
    if facts.wrong_heading is not None:
        opening = phraser.clause("answer.correct", old=facts.wrong_heading)
    else:
        opening = phraser.clause("answer.which_way")
    clauses = []
    if facts.direction in ("left", "right"):
        clauses.append(phraser.clause("turn.here", lr=facts.direction))
    elif facts.direction == "ahead":
        clauses.append(phraser.clause("straight"))
    else:
        clauses.append(phraser.clause("head", dir=facts.direction))
    metres = None if facts.distance_m is None else max(50, int(round(facts.distance_m / 50) * 50))
    if facts.landmark is not None:
        slot = "destination" if facts.is_destination else "next"
        if metres is not None:
            slot += ".distance"
        clauses.append(phraser.clause(slot, lm=facts.landmark, dist=metres))
    elif metres is not None:
        clauses.append(phraser.clause("stop.distance", dist=metres))
    return _answered(opening, phraser.join(clauses))


def attention_circles(
    geo: PlanGeo, mentioned: Sequence[LandmarkSpec], stop_xy: NDArray[np.float64], mpp: float
) -> list[list[object]]:
    """Attention circles ``[[lat, lng], radius_px]`` on mentioned landmarks and the stop."""
    circles: list[list[object]] = []
    for lm in mentioned:
        extent = float(np.ptp(lm.polygon, axis=0).max())
        lat, lng = (float(v) for v in geo.to_latlng(lm.polygon.mean(axis=0)))
        circles.append([[lat, lng], int(np.clip(extent / mpp / 2, 15, 150))])
    lat, lng = (float(v) for v in geo.to_latlng(stop_xy))
    circles.append([[lat, lng], round(40 / mpp)])
    return circles
