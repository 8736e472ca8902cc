"""The rule backend's reading of instructions: a lexicon and keyword reader.

It knows words, not sentences: landmark categories and colours, compass points in their
many forms, left / right / ahead, numbers and units, verbs of turning, cues of stopping,
of the destination and of passing, negations (:mod:`skyvln_eval.vocabulary`). Each clause
is read for those (:mod:`.clauses`); a sentence then puts its clauses together, so the
order a commander chooses does not matter:

- a compass point not denied ("not north any more") is a heading;
- a clock direction ("at your 2 o'clock") or turning back ("turn around", "fly back") is
  a heading too, the compass point that far round from the drone's heading when the
  instruction is read (12 o'clock straight on); without a heading, 12 o'clock is ahead,
  1 to 5 a right turn, 7 to 11 a left turn, and 6 or turning back two right turns (the
  sub-goals have no "back");
- a left / right with a verb of turning or at a junction is a turn; a junction's ordinal
  ("the second crossing") or landmark ("by the church", "the roundabout") qualifies the
  turn said in the same clause or next to it ("At the first intersection, turn left");
- a landmark is the destination, a place to stop at, or one to pass by the cues of its
  clause, or by a cue elsewhere in the sentence ("Target: a red church"), or by a later
  "that is your destination";
- a landmark the drone is sent to ("fly to the red roof") is where to stop when it is the
  instruction's last landmark and nothing else says where to stop;
- a distance belongs to the sentence's stop or destination, or is a stop of its own;
- a sentence that only says to stop, in an instruction without another stop, is a stop
  where the drone is ("you are there, stop").

When the instruction answers the follower's question with a no, the compass point the
follower asked about is denied too ("Still north?" "Negative, ...").
"""

from __future__ import annotations

from typing import Any

from skyvln_eval.llm.rule.clauses import ClauseReading, read_clause
from skyvln_eval.llm.rule.text import Word, sentences_of, words_of
from skyvln_eval.vocabulary import NEGATIVE_ANSWERS, compass_points_in, relative_compass
from skyvln_eval.vocabulary.cues import MOTION_VERBS
from skyvln_eval.vocabulary.directions import CLOCK_HOUR_DEG
from skyvln_eval.vocabulary.words import phrase_words

Goal = dict[str, Any]
_ROLELESS = "mention"  # a landmark no cue has given a role yet
_JUNCTION = "junction"  # a junction said before (or without) its turn
_REACH = "_reach"  # marks a landmark the drone is sent to ("fly to the church")


class _Sentence:
    """The goals one sentence adds, and what its clauses left for the others to settle."""

    def __init__(self, goals: list[Goal], denied: set[str], heading_deg: float | None) -> None:
        self.goals = goals  # the whole instruction's, appended to in order
        self.start = len(goals)
        self.denied = denied
        self.heading_deg = heading_deg
        self.turn_waiting: Goal | None = None
        self.junction_waiting: Goal | None = None
        self.free_destination: list[int] = []
        self.free_stop: list[int] = []
        self.free_sides: list[str] = []
        self.distance_m: float | None = None
        self.clause_of: dict[int, int] = {}  # id(goal) -> clause index

    def own(self) -> list[Goal]:
        return self.goals[self.start :]

    def add(self, goal: Goal, clause: int) -> Goal:
        self.goals.append(goal)
        self.clause_of[id(goal)] = clause
        return goal

    def drop(self, goal: Goal) -> None:
        """Remove this very goal (an equal one elsewhere stays)."""
        del self.goals[next(i for i, g in enumerate(self.goals) if g is goal)]

    def read(self, k: int, r: ClauseReading) -> None:
        hour = 6 if r.around and r.clock is None else r.clock
        if hour is not None and not r.negated:
            for goal in _relative_goals(hour, self.heading_deg):
                if goal["kind"] == "turn" or self.goals[-1:] != [goal]:
                    self.add(goal, k)
        for point in r.headings:
            last = self.goals[-1] if self.goals else {}
            if point not in self.denied and last != {"kind": "head", "direction": point}:
                self.add({"kind": "head", "direction": point}, k)
        if r.turn is not None:
            turn = self.add({"kind": "turn", "direction": r.turn}, k)
            said = self._junction(r)  # "the second right", "left at the church"
            if said:
                turn.update(said)
            elif self.junction_waiting is not None:  # "At the second crossing, bear left"
                self.drop(self.junction_waiting)
                turn.update({f: v for f, v in self.junction_waiting.items() if f != "kind"})
                self.junction_waiting = None
            else:
                self.turn_waiting = turn
        elif r.junction:
            qualifier = self._junction(r)
            if self.turn_waiting is not None:  # "Turn left, at the second crossing"
                self.turn_waiting.update(qualifier)
                self.turn_waiting = None
            else:
                self.junction_waiting = self.add({"kind": _JUNCTION, **qualifier}, k)
        else:
            self._landmarks(k, r)
        if r.distance_m is not None and self.distance_m is None:
            self.distance_m = r.distance_m

    @staticmethod
    def _junction(r: ClauseReading) -> Goal:
        qualifier: Goal = {} if r.ordinal is None else {"ordinal": r.ordinal}
        landmark = r.roundabout or next(iter(r.mentions), None)
        if landmark is not None:
            qualifier["landmark"] = landmark.phrase
        return qualifier

    def _landmarks(self, k: int, r: ClauseReading) -> None:
        sure = not r.negated
        for m in r.mentions:
            if r.destination and sure:
                kind = "destination"
            elif r.stop and sure:
                kind = "stop_at"
            elif r.side is not None or r.passing:
                kind = "pass"
            else:
                kind = _ROLELESS
            goal = self.add({"kind": kind, "landmark": m.phrase}, k)
            if kind == "pass" and r.side is not None:
                goal["side"] = r.side
            if kind == _ROLELESS and r.reach:
                goal[_REACH] = True
        for name in r.names:  # a name follows the landmark it names
            named = [g for g in self.own() if g.get("landmark") and g["kind"] != "turn"]
            if named and "name" not in named[-1]:
                named[-1]["name"] = name
        if not r.mentions:
            if r.destination and sure:
                self.free_destination.append(k)
            elif r.stop and sure:
                self.free_stop.append(k)
            if r.side is not None and r.turn is None:
                self.free_sides.append(r.side)

    def settle(self) -> None:
        """Give the cues said apart from their landmark to it; the distance to the stop."""
        for g in self.own():  # a junction no turn came for: a roundabout is just a landmark
            if g["kind"] == _JUNCTION:
                if "landmark" in g:
                    g.pop("ordinal", None)
                    g["kind"] = _ROLELESS
                else:
                    self.drop(g)
        own = self.own()
        for side in self.free_sides:
            open_ = [g for g in own if g["kind"] in ("pass", _ROLELESS) and "side" not in g]
            if open_:
                open_[-1].update(kind="pass", side=side)
        for k in self.free_destination:
            target = self._nearest_roleless(k) or next(
                (g for g in reversed(self.goals) if g["kind"] in ("pass", "stop_at")), None
            )
            if target is not None:
                target["kind"] = "destination"
                target.pop("side", None)
        for k in self.free_stop:
            target = self._nearest_roleless(k)
            if target is not None:
                target["kind"] = "stop_at"
        if self.distance_m is not None:
            stops = [g for g in own if g["kind"] in ("destination", "stop_at")]
            roleless = [g for g in own if g["kind"] == _ROLELESS]
            if stops and "distance_m" not in stops[0]:
                stops[0]["distance_m"] = self.distance_m
            elif roleless:  # "the church in 200 m": where to go, and how far
                roleless[-1].update(kind="stop_at", distance_m=self.distance_m)
            elif not stops:
                self.goals.append({"kind": "stop_after", "distance_m": self.distance_m})
        for g in self.own():
            if g["kind"] == _ROLELESS:
                g["kind"] = "pass"
        if self.free_stop and not self.own() and not _has_stop(self.goals):
            # "Stop right there": a sentence that says only to stop, and nothing said
            # before where or when: it is here ("Wait, turn left" is not).
            self.goals.append({"kind": "stop"})

    def _nearest_roleless(self, k: int) -> Goal | None:
        roleless = [g for g in self.own() if g["kind"] == _ROLELESS]
        after = [g for g in roleless if self.clause_of[id(g)] >= k]
        return after[0] if after else (roleless[-1] if roleless else None)


def _relative_goals(hour: int, heading_deg: float | None) -> list[Goal]:
    """The sub-goals of a clock direction (hour 1-12; turning back is 6 o'clock): a heading
    with the drone's heading known, else turns (see the module docstring)."""
    if heading_deg is not None:
        point = relative_compass(hour % 12 * CLOCK_HOUR_DEG, heading_deg)
        return [{"kind": "head", "direction": point}]
    if hour == 12:
        return [{"kind": "head", "direction": "ahead"}]
    if hour == 6:
        return [{"kind": "turn", "direction": "right"}, {"kind": "turn", "direction": "right"}]
    return [{"kind": "turn", "direction": "right" if hour < 6 else "left"}]


def _has_stop(goals: list[Goal]) -> bool:
    return any(g["kind"] in ("destination", "stop_at", "stop_after", "stop") for g in goals)


def _denied_by_answer(text: str, question: str | None) -> set[str]:
    """Compass points the follower asked about, when the instruction opens with a no."""
    words = [w for w in words_of(text) if isinstance(w, Word)]
    if not question or not words or words[0].low not in NEGATIVE_ANSWERS:
        return set()
    asked = [w.text for w in words_of(question) if isinstance(w, Word)]
    return {point for _, point in compass_points_in(asked)}


def parse_instruction(
    text: str, question: str | None = None, heading_deg: float | None = None
) -> list[dict[str, Any]]:
    """Sub-goals (as JSON dicts) of one instruction, in order; ``question`` is the
    follower's question the instruction answers, if any; ``heading_deg`` the drone's
    compass heading as the request gives it (clock directions and turning back are read
    from it), if any."""
    goals: list[Goal] = []
    denied = _denied_by_answer(text, question)
    for clauses in sentences_of(text):
        sentence = _Sentence(goals, denied, heading_deg)
        for k, clause in enumerate(clauses):
            sentence.read(k, read_clause(clause))
        sentence.settle()
    _stop_at_last_reached(goals)
    if not goals and MOTION_VERBS & set(phrase_words(text)):
        # Told to go on without where ("Yes, keep going"): a sub-goal too. Words with no
        # cue at all ("On target, hold") give no plan: a failed reading, which the agent
        # records (a guess of "ahead" there made a failure look like a reading).
        goals.append({"kind": "head", "direction": "ahead"})
    return goals


def _stop_at_last_reached(goals: list[Goal]) -> None:
    """An instruction that says nowhere to stop but ends by sending the drone to a landmark
    ("Fly to the red building."): that landmark is where to stop, not one to pass (with
    anything said after it, "go to the pond and turn left", it stays one to pass)."""
    reached = [g for g in goals if g.pop(_REACH, False)]
    if _has_stop(goals) or not reached or goals[-1] is not reached[-1]:
        return
    if reached[-1]["kind"] == "pass" and "side" not in reached[-1]:
        reached[-1]["kind"] = "stop_at"


def landmark_phrases(text: str) -> list[str]:
    """Every landmark phrase a text mentions (earlier rounds' context), once each."""
    phrases = [
        m.phrase
        for clauses in sentences_of(text)
        for clause in clauses
        for m in read_clause(clause).mentions
    ]
    return list(dict.fromkeys(phrases))
