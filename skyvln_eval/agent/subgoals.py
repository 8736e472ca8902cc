"""Sub-goal extraction: the LLM turns the dialog into ordered sub-goals and landmark phrases.

The paper's ``L = LLM(T, prompt)``: the current round's instruction (with the follower's
question, if any) and the earlier rounds (``pre_dialogs``) go in; an ordered list of
sub-goals comes out, each a motion (head towards a compass point, turn, stop after a
distance) or a landmark phrase (pass it, stop at it, it is the destination). Landmarks
named only in earlier rounds come back as ``context_landmarks``: the agent starts where
those rounds ended, so TrackBack memory can recognise them near the start.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Final, Literal

from skyvln_eval.agent.parsing import load_json_object, refuse_other_fields
from skyvln_eval.avdn.records import DialogTurn
from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm.taskdata import task_message
from skyvln_eval.llm.types import Message
from skyvln_eval.vocabulary.directions import compass_point
from skyvln_eval.vocabulary.words import WORD, phrase_words

#: Fields of one sub-goal in the LLM's JSON (``null`` where they do not apply).
SUBGOAL_FIELDS: Final = ("kind", "landmark", "name", "direction", "side", "distance_m", "ordinal")
SubGoalKind = Literal["head", "turn", "pass", "stop_after", "stop_at", "destination", "stop"]
SUBGOAL_KINDS: Final = ("head", "turn", "pass", "stop_after", "stop_at", "destination", "stop")
LANDMARK_KINDS: Final = ("pass", "stop_at", "destination")  # these name their landmark
DIRECTIONS: Final = (
    "north",
    "northeast",
    "east",
    "southeast",
    "south",
    "southwest",
    "west",
    "northwest",
    "left",
    "right",
    "ahead",
)


@dataclass(frozen=True)
class SubGoal:
    """One step of the instruction.

    ``direction`` is a compass point (``head``) or left / right (``turn``); ``side`` where
    a landmark to ``pass`` should be; ``distance_m`` how far (``stop_after``, or the
    distance given for a landmark); ``ordinal`` which intersection a ``turn`` is at.
    ``stop``: stop where the drone is (the commander says it is there).
    """

    kind: SubGoalKind
    landmark: str | None = None
    name: str | None = None
    direction: str | None = None
    side: str | None = None
    distance_m: float | None = None
    ordinal: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class SubGoalPlan:
    """Sub-goals in order, and landmark phrases of earlier rounds (context)."""

    subgoals: tuple[SubGoal, ...]
    context_landmarks: tuple[str, ...] = ()

    @property
    def landmark_phrases(self) -> list[str]:
        """The paper's ordered set L of landmark phrases."""
        return [g.landmark for g in self.subgoals if g.landmark]


MAX_SUBGOALS: Final = 10  # an instruction rarely has more than 6; bounds a decoder
MAX_PHRASE_CHARS: Final = 300
MAX_PHRASE_WORDS: Final = 20
SIDES: Final = ("left", "right", "ahead")
#: Words that say where or how, not what: a landmark phrase made only of them (Gemma 3
#: 270M filled a plan with ten sub-goals "pass 'left'") names nothing a detector can find.
#: The schema's phrase pattern does not forbid such a phrase (a pattern that needs one
#: naming word and counts every word to :data:`MAX_PHRASE_WORDS` would hold the dialog's
#: words once per position of that word): a grammar lets it through, and the parser refuses
#: it with the reason the repair shows the model.
NOT_LANDMARK_WORDS: Final = frozenset(
    (
        *DIRECTIONS,
        *("straight", "forward", "front", "side", "way", "direction", "turn", "go", "fly"),
        *("head", "the", "a", "an", "this", "that", "its", "your", "my", "it", "you", "to"),
        *("on", "at", "of", "in", "by", "from", "towards", "toward", "into", "past", "and"),
        *("then", "there", "here"),
    )
)
#: The same sub-goal this many times in a row is a decoder's loop, not an instruction.
MAX_REPEATS: Final = 2


SUBGOALS_SYSTEM: Final = (
    "You read navigation dialogs between a drone pilot (follower) and a commander who sees "
    "the map. You split the current instruction into ordered sub-goals and extract every "
    "landmark phrase exactly as written. You answer with one JSON object only."
)


@dataclass(frozen=True)
class DialogText:
    """The dialog as prompts show it: earlier rounds, the follower's latest question and the
    commander's current instruction."""

    previous: tuple[str, ...]
    question: str | None
    instruction: str

    @classmethod
    def of(cls, turns: Sequence[DialogTurn], current_round: int) -> DialogText:
        previous = tuple(f"{t.speaker}: {t.text}" for t in turns if t.round_index < current_round)
        current = [t for t in turns if t.round_index >= current_round]
        question = " ".join(t.text for t in current if t.speaker == "follower") or None
        instruction = " ".join(t.text for t in current if t.speaker == "commander")
        return cls(previous, question, instruction)

    def said(self) -> str:
        """What the speakers said, as one text: the earlier rounds without their speaker
        labels (those are the prompt's words, not the dialog's), the question, the
        instruction."""
        earlier = [_without_speaker(line) for line in self.previous]
        return " ".join((*earlier, self.question or "", self.instruction))

    def instructs(self) -> bool:
        """Whether the current instruction has words, so that it has at least one sub-goal
        (an empty plan for it is a failed extraction, not a plan)."""
        return bool(phrase_words(self.instruction))

    def words(self) -> frozenset[str]:
        """Every word the speakers said (:func:`phrase_words`): what copied phrases are made
        of."""
        return frozenset(phrase_words(self.said()))

    def prose(self) -> str:
        return (
            f"Earlier rounds:\n{chr(10).join(self.previous) or '(none)'}\n"
            f"Follower's question: {self.question or '(none)'}\n"
            f"Commander's current instruction: {self.instruction}\n"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "previous_rounds": list(self.previous),
            "question": self.question,
            "instruction": self.instruction,
        }


def _without_speaker(line: str) -> str:
    """An earlier round's line (``"commander: ..."``) without its speaker label."""
    speaker, separator, text = line.partition(": ")
    return text if separator and speaker in ("commander", "follower") else line


def subgoal_messages(dialog: DialogText, heading_deg: float | None = None) -> list[Message]:
    """The prompt: earlier rounds as context, the current round to decompose, and the way
    the drone faces (``heading_deg``, compass degrees from its own pose, when known):
    commanders speak relative to it ("at your 2 o'clock", "turn around"), and a head
    sub-goal takes a compass point."""
    facing = None if heading_deg is None else round(heading_deg) % 360
    prose = (
        "Decompose the commander's current instruction into sub-goals, in order.\n"
        "Kinds: head (fly towards a compass point: direction), turn (direction left/right, "
        "ordinal of the intersection or the landmark it is at), pass (a landmark to pass, "
        "side left/right/ahead), stop_after (distance_m), stop_at (a landmark to stop at), "
        "destination (the landmark that is the destination; its name if given, and "
        "distance_m if the commander says how far), stop (stop where you are: the commander "
        "says you are there). Copy landmark phrases word for word. "
        "Give at least one sub-goal (head ahead when the commander only says to go on). "
        "List landmarks mentioned only in earlier rounds as context_landmarks.\n"
        + dialog.prose()
        + ("" if facing is None else f"You are facing {facing} degrees (compass bearing).\n")
        + 'Answer as {"subgoals": [{"kind": ..., "landmark": ..., "name": ..., "direction": ..., '
        '"side": ..., "distance_m": ..., "ordinal": ...}], "context_landmarks": [...]} with '
        "null for fields that do not apply.\n"
    )
    return [
        Message("system", SUBGOALS_SYSTEM),
        task_message(
            prose,
            "subgoals",
            dialog.to_dict() | ({} if facing is None else {"heading_deg": facing}),
        ),
    ]


def _check_copied(phrase: str | None, dialog_words: frozenset[str], where: str) -> None:
    """A landmark phrase or name must be copied from the dialog: every word of it is a
    word of the dialog. A small model under a grammar fills arrays with fragments (Gemma 3
    270M wrote the landmark ``"}, {"``); an answer the dialog cannot have given is refused
    with the words it lacks, which the repair shows the model."""
    if phrase is None:
        return
    words = phrase_words(phrase)
    if not words:
        raise ActionParseError(
            f"{where} {phrase!r} has no words: copy the phrase word for word from the dialog"
        )
    if len(words) > MAX_PHRASE_WORDS:
        raise ActionParseError(
            f"{where} {phrase!r} has {len(words)} words; a landmark phrase has at most "
            f"{MAX_PHRASE_WORDS}: copy only the landmark's words"
        )
    missing = list(dict.fromkeys(w for w in words if w not in dialog_words))
    if missing:
        raise ActionParseError(
            f"{where} {phrase!r} is not in the dialog (it has no "
            f"{', '.join(repr(w) for w in missing)}): copy phrases word for word"
        )


def _check_names_a_landmark(phrase: str | None, where: str) -> None:
    """A landmark phrase must have a word that names something (:data:`NOT_LANDMARK_WORDS`,
    compass points in any form); the refusal says so, for the repair."""
    if phrase is None:
        return
    words = phrase_words(phrase)
    if all(w in NOT_LANDMARK_WORDS or compass_point(w) is not None for w in words):
        raise ActionParseError(
            f"{where} {phrase!r} names no landmark, only a direction or filler words: copy "
            "the landmark's own words (what it is, its name or look), or use a head or turn "
            "sub-goal for a direction"
        )


def _check_no_loop(goals: Sequence[SubGoal]) -> None:
    """More than :data:`MAX_REPEATS` equal sub-goals in a row are refused."""
    for i in range(MAX_REPEATS, len(goals)):
        if all(goals[j] == goals[i] for j in range(i - MAX_REPEATS, i)):
            raise ActionParseError(
                f"subgoals[{i - MAX_REPEATS}] to subgoals[{i}] are the same sub-goal "
                f"{goals[i].to_dict()} {MAX_REPEATS + 1} times in a row: give each step of "
                "the instruction once"
            )


def _nullable(schema: dict[str, Any]) -> dict[str, Any]:
    # anyOf rather than a type list: grammar converters drop enums and lengths of the latter.
    return {"anyOf": [schema, {"type": "null"}]}


def phrase_schema(dialog: DialogText) -> dict[str, Any] | None:
    """A landmark phrase or name copied from ``dialog``: words of the dialog (as written, in
    lower case or capitalised), at most :data:`MAX_PHRASE_WORDS`, separated by spaces,
    commas, hyphens or apostrophes. A grammar-constrained decoder can then only write what
    :func:`parse_subgoals` accepts as copied (Gemma 3 270M, unconstrained, wrote ``"}, {"``).
    ``None`` when the dialog has no words: no phrase can be copied from it."""
    forms = {
        form
        for token in WORD.findall(dialog.said())
        for form in (token, token.lower(), token.capitalize())
    }
    if not forms:
        return None
    # Plain groups: llama.cpp's schema-to-grammar converter refuses "(?:".
    word = "(" + "|".join(sorted(forms, key=lambda w: (-len(w), w))) + ")"
    pattern = f"^{word}([ ,'-]+{word}){{0,{MAX_PHRASE_WORDS - 1}}}$"
    return {"type": "string", "maxLength": MAX_PHRASE_CHARS, "pattern": pattern}


def subgoals_json_schema(dialog: DialogText) -> dict[str, Any]:
    """The sub-goal answer's schema for ``dialog``, which :func:`parse_subgoals` agrees
    with: a sub-goal has one of two shapes, by kind, both with every field (null where it
    does not apply): a ``pass``, ``stop_at`` or ``destination`` names its landmark (copied,
    :func:`phrase_schema`), the other kinds may."""
    phrase = phrase_schema(dialog)
    # Without words to copy, phrases are null, no sub-goal names a landmark and there are no
    # context landmarks (as the parser would find); a schema nothing satisfies could make a
    # server refuse the level for the whole run.
    maybe_phrase = _nullable(phrase) if phrase is not None else {"type": "null"}

    def shape(kinds: Sequence[str], landmark: dict[str, Any]) -> dict[str, Any]:
        return {
            "type": "object",
            "additionalProperties": False,
            "required": list(SUBGOAL_FIELDS),
            "properties": {
                "kind": {"type": "string", "enum": list(kinds)},
                "landmark": landmark,
                "name": maybe_phrase,
                "direction": _nullable({"type": "string", "enum": list(DIRECTIONS)}),
                "side": _nullable({"type": "string", "enum": list(SIDES)}),
                "distance_m": _nullable({"type": "number", "exclusiveMinimum": 0, "maximum": 5000}),
                # An enum, not a range: grammar-constrained decoders (llama.cpp's among
                # them) enforce enums but not numeric bounds (Gemma wrote 200 here).
                "ordinal": _nullable({"type": "integer", "enum": list(range(1, 11))}),
            },
        }

    others = shape([k for k in SUBGOAL_KINDS if k not in LANDMARK_KINDS], maybe_phrase)
    if phrase is None:
        # No words, so no context landmark: an empty array. Its items are said all the same:
        # OpenAI's strict mode refuses an array schema without them.
        shapes, context = [others], {"type": "array", "maxItems": 0, "items": {"type": "string"}}
    else:
        shapes = [shape(LANDMARK_KINDS, phrase), others]
        context = {"type": "array", "maxItems": MAX_SUBGOALS, "items": phrase}
    return {
        "type": "object",
        "additionalProperties": False,
        "required": ["subgoals", "context_landmarks"],
        "properties": {
            "subgoals": {
                "type": "array",
                "minItems": 1 if dialog.instructs() else 0,
                "maxItems": MAX_SUBGOALS,
                "items": {"anyOf": shapes},
            },
            "context_landmarks": context,
        },
    }


def _optional_str(item: dict[str, Any], key: str, where: str) -> str | None:
    value = item.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or len(value) > MAX_PHRASE_CHARS:
        raise ActionParseError(
            f"{where}.{key} must be a string of at most {MAX_PHRASE_CHARS} characters"
        )
    return value.strip() or None


def parse_subgoals(text: str, dialog: DialogText) -> SubGoalPlan:
    """Validate the LLM's sub-goal JSON for ``dialog`` (its landmark phrases, names and
    context landmarks must be copied from it); :class:`ActionParseError` says what is
    wrong."""
    dialog_words = dialog.words()
    data = load_json_object(text)
    if "subgoals" not in data:
        others = sorted(set(data) - {"context_landmarks"})
        raise ActionParseError(
            "the field 'subgoals' (a list of sub-goal objects) is missing"
            + (f"; unknown field(s) {', '.join(others)}" if others else "")
        )
    refuse_other_fields(data, ("subgoals", "context_landmarks"))
    items = data.get("subgoals")
    if not isinstance(items, list) or len(items) > MAX_SUBGOALS:
        raise ActionParseError(f"'subgoals' must be a list of at most {MAX_SUBGOALS} items")
    if not items and dialog.instructs():
        raise ActionParseError(
            "'subgoals' is empty, but the commander's instruction has words: give at least "
            "one sub-goal (head ahead when it only says to go on)"
        )
    goals = []
    for i, item in enumerate(items):
        where = f"subgoals[{i}]"
        if not isinstance(item, dict):
            raise ActionParseError(f"{where} must be an object")
        unknown = set(item) - set(SUBGOAL_FIELDS)
        if unknown:
            raise ActionParseError(f"{where} has unknown field(s) {', '.join(sorted(unknown))}")
        kind = item.get("kind")
        if kind not in SUBGOAL_KINDS:
            raise ActionParseError(
                f"{where}.kind {kind!r} is not one of {', '.join(SUBGOAL_KINDS)}"
            )
        direction = _optional_str(item, "direction", where)
        if direction is not None and direction.lower() not in DIRECTIONS:
            raise ActionParseError(
                f"{where}.direction {direction!r} is not a compass point, left, right or ahead"
            )
        distance = item.get("distance_m")
        if distance is not None and (
            isinstance(distance, bool)
            or not isinstance(distance, int | float)
            or not 0 < distance <= 5000  # before any float(): NaN fails it, huge ints too
        ):
            raise ActionParseError(
                f"{where}.distance_m must be a number in (0, 5000], got {distance!r}"
            )
        ordinal = item.get("ordinal")
        if ordinal is not None and (
            isinstance(ordinal, bool) or not isinstance(ordinal, int) or not 1 <= ordinal <= 10
        ):
            raise ActionParseError(
                f"{where}.ordinal must be an integer in [1, 10], got {ordinal!r}"
            )
        landmark = _optional_str(item, "landmark", where)
        if kind in LANDMARK_KINDS and landmark is None:
            raise ActionParseError(f"{where} of kind {kind} needs a landmark phrase")
        name = _optional_str(item, "name", where)
        _check_copied(landmark, dialog_words, f"{where}.landmark")
        _check_names_a_landmark(landmark, f"{where}.landmark")
        _check_copied(name, dialog_words, f"{where}.name")
        side = _optional_str(item, "side", where)
        if side is not None and side.lower() not in SIDES:
            raise ActionParseError(f"{where}.side {side!r} is not one of {', '.join(SIDES)}")
        goals.append(
            SubGoal(
                kind=kind,
                landmark=landmark,
                name=name,
                direction=None if direction is None else direction.lower(),
                side=None if side is None else side.lower(),
                distance_m=None if distance is None else float(distance),
                ordinal=ordinal,
            )
        )
    _check_no_loop(goals)
    context = data.get("context_landmarks", [])
    if not isinstance(context, list) or not all(isinstance(c, str) for c in context):
        raise ActionParseError("'context_landmarks' must be a list of strings")
    if len(context) > MAX_SUBGOALS or any(len(c) > MAX_PHRASE_CHARS for c in context):
        raise ActionParseError(
            f"'context_landmarks' must hold at most {MAX_SUBGOALS} phrases of at most "
            f"{MAX_PHRASE_CHARS} characters"
        )
    context = [c.strip() for c in context if c.strip()]
    for i, phrase in enumerate(context):
        _check_copied(phrase, dialog_words, f"context_landmarks[{i}]")
        _check_names_a_landmark(phrase, f"context_landmarks[{i}]")
    return SubGoalPlan(tuple(goals), tuple(context))
