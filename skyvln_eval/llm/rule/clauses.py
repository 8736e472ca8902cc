"""What one clause of an instruction says, read word by word against the vocabulary.

A clause is scanned for landmark mentions first (a category or generic word, "the church
roof" or "the parking lot" as one, with the adjectives before it and, after "with" /
"that" / ..., the rest of its description), then the words outside them for cues: compass
points (and whether a negation denies them), clock directions and turning back, left /
right as a turn or as a side, ahead, junctions and ordinals, distances, and the words that
make a clause about stopping, the destination or passing something.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from skyvln_eval.llm.rule.text import NAME, Word
from skyvln_eval.vocabulary import (
    AHEAD_PHRASES,
    CATEGORY_PHRASES,
    DESCRIPTION_ENDS,
    DESCRIPTION_GOES_ON,
    DESTINATION_CUES,
    DETERMINERS,
    GENERIC_PHRASES,
    JUNCTIONS,
    MOTION_VERBS,
    NEGATIONS,
    PASS_CUES,
    PERCEPTION_VERBS,
    PREPOSITIONS,
    PRONOUNS,
    RIGHT_AS_CORRECT_AFTER,
    RIGHT_AS_JUST_BEFORE,
    SIDE_PREPOSITIONS,
    STOP_CUES,
    TURN_AROUND,
    TURN_VERBS,
    Cue,
    clock_at,
    compass_point,
    compass_points_in,
    distance_at,
    distances_in,
    ordinal_of,
)

#: Category phrases (and generic ones, category None) as word tuples, longest first
#: ("water tower" before "tower").
_CATEGORY_WORDS: list[tuple[tuple[str, ...], str | None]] = sorted(
    [
        *((tuple(p.split()), c) for c, phrases in CATEGORY_PHRASES.items() for p in phrases),
        *((tuple(p.split()), None) for phrases in GENERIC_PHRASES.values() for p in phrases),
    ],
    key=lambda item: -len(item[0]),
)
# First words of stop and destination cues end a description ("a red church where you
# stop"); "get" is left out, too common a word to end one.
_CUE_STARTS = frozenset(c[0] for c in (*STOP_CUES, *DESTINATION_CUES) if c[0] != "get")
_LEFT_STOPS = (
    PREPOSITIONS
    | PRONOUNS
    | TURN_VERBS
    | MOTION_VERBS
    | PERCEPTION_VERBS
    | DESCRIPTION_ENDS
    | _CUE_STARTS
)
_TRAILING = PREPOSITIONS | DETERMINERS | frozenset({"and", "or", "it", "straight", "just"})
#: Words that place one landmark by another ("the house next to the pond").
_LOCATING: Final = frozenset(
    {
        ("beside",),
        ("next", "to"),
        ("near",),
        ("behind",),
        ("opposite",),
        ("close", "to"),
        ("across", "from"),
        ("adjacent", "to"),
    }
)
#: Clock hours that say on which side a landmark is seen.
_CLOCK_SIDES = {
    **dict.fromkeys(range(1, 6), "right"),
    **dict.fromkeys(range(7, 12), "left"),
    12: "ahead",
}
_BEFORE_A_TURN = TURN_VERBS | MOTION_VERBS | frozenset({"a", "the", "hard", "sharp", "slight"})


@dataclass
class Mention:
    """A landmark mentioned in a clause: its phrase as written (lower case), its category
    (None for a generic one: "the grey building") and where it is in the clause (word
    indexes, end excluded)."""

    phrase: str
    category: str | None
    start: int
    end: int


@dataclass
class ClauseReading:
    """What a clause says: headings (and denied ones), a clock direction (``clock``, the
    hour) or turning back (``around``), a turn or a side, a junction and its ordinal,
    landmarks and proper names, a distance, and whether it speaks of stopping, of the
    destination or of passing, or denies something."""

    headings: list[str] = field(default_factory=list)
    denied: list[str] = field(default_factory=list)
    clock: int | None = None
    around: bool = False
    turn: str | None = None
    side: str | None = None
    junction: bool = False
    ordinal: int | None = None
    mentions: list[Mention] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    distance_m: float | None = None
    stop: bool = False
    destination: bool = False
    passing: bool = False
    negated: bool = False
    #: A verb of motion sends the drone *to* a landmark of the clause ("fly over to the
    #: church"): where it is to get to, unless a cue says otherwise.
    reach: bool = False

    @property
    def roundabout(self) -> Mention | None:
        return next((m for m in self.mentions if m.category == "roundabout"), None)


def _category_at(words: Sequence[str], i: int) -> tuple[int, str | None] | None:
    """(length, category) of the landmark words at ``words[i]``, run together ("the church
    roof", "the parking lot building"): the first category among them, None if all are
    generic."""
    length, category, found = 0, None, False
    while i + length < len(words):
        hit = next(
            (
                (len(phrase), c)
                for phrase, c in _CATEGORY_WORDS
                if tuple(words[i + length : i + length + len(phrase)]) == phrase
            ),
            None,
        )
        if hit is None:
            break
        length, category, found = length + hit[0], category or hit[1], True
    return (length, category) if found else None


def _is_boundary(words: Sequence[str], k: int) -> bool:
    w = words[k]
    return (
        w in _LEFT_STOPS
        or w == NAME
        or compass_point(w) is not None
        or distance_at(words, k) is not None
        or ordinal_of(w) is not None
        or w in ("o'clock", "oclock", "clock")
    )


def _mentions(words: Sequence[str]) -> list[Mention]:
    found: list[Mention] = []
    i = 0
    while i < len(words):
        hit = _category_at(words, i) if words[i] != NAME else None
        if hit is None:
            i += 1
            continue
        length, category = hit
        start = i
        for k in range(i - 1, max(-1, i - 6), -1):  # adjectives before it, up to "a" / "the"
            if words[k] in DETERMINERS:
                start = k
                break
            if _is_boundary(words, k):
                break
            start = k
        end = i + length
        opens = end < len(words) and words[end] in DESCRIPTION_GOES_ON
        if opens and not (words[end] == "that" and end + 1 < len(words) and words[end + 1] == "is"):
            end += 1
            while end < len(words) and not (
                words[end] in DESCRIPTION_ENDS
                or words[end] in TURN_VERBS
                or words[end] in _CUE_STARTS
                or words[end] == NAME
                or compass_point(words[end]) is not None
                or distance_at(words, end) is not None
            ):
                end += 1
        while end > i + length and words[end - 1] in _TRAILING:
            end -= 1
        last = found[-1] if found else None
        if last is not None and tuple(words[last.end : start]) in _LOCATING:
            # "the long building beside the field": one landmark, placed by another.
            start, category = last.start, last.category or category
            found.pop()
        found.append(Mention(" ".join(words[start:end]), category, start, end))
        i = end
    return found


def _has_cue(words: Sequence[str], cues: Sequence[Cue]) -> int | None:
    """Index of the first cue of ``cues`` in ``words`` (None if none)."""
    for i in range(len(words)):
        if any(tuple(words[i : i + len(c)]) == c for c in cues):
            return i
    return None


def _left_right(words: Sequence[str], turning: bool) -> tuple[str | None, str | None]:
    """(turn, side): a left / right said as a turn ("turn left", "take the right") or as
    the side something is on ("on your left", "left-hand side", "to the right")."""
    turn = side = None
    for i, w in enumerate(words):
        base = w.removesuffix("-hand")
        if base not in ("left", "right"):
            continue
        before = words[i - 1] if i else ""
        after = words[i + 1] if i + 1 < len(words) else ""
        # "right below you" is "just below you"; at a junction "right at it" turns.
        just = w == "right" and after in RIGHT_AS_JUST_BEFORE and before not in _BEFORE_A_TURN
        if (just and not turning) or (w == "right" and before in RIGHT_AS_CORRECT_AFTER):
            continue  # neither a side nor a turn ("that's right": correct)
        on_a_side = (
            w != base
            or after == "side"
            or (before in ("your", "the", "my") and i > 1 and words[i - 2] in SIDE_PREPOSITIONS)
        )
        if on_a_side and not turning:
            side = side or base
        else:
            turn = turn or base
    return turn, side


#: Words before "to" that make it say where something is, not where to go ("next to").
NEAR_BEFORE_TO: Final = frozenset(
    {"next", "close", "closer", "near", "nearer", "adjacent", "parallel", "due", "up"}
)


def _sent_to_landmark(words: Sequence[str], mentions: Sequence[Mention]) -> bool:
    """Whether a verb of motion and then "to" come before one of the clause's landmarks
    ("go to the red roof", "head north to the pond"), "to" not saying where something is
    ("next to", "close to")."""
    for i, word in enumerate(words):
        if word != "to" or (i and words[i - 1] in NEAR_BEFORE_TO):
            continue
        if any(w in MOTION_VERBS for w in words[:i]) and any(m.start > i for m in mentions):
            return True
    return False


def read_clause(clause: Sequence[Word]) -> ClauseReading:
    """The reading of one clause (see the module docstring)."""
    all_words = [w.low for w in clause]
    reading = ClauseReading(names=[w.name for w in clause if w.name is not None])
    reading.mentions = _mentions(all_words)
    inside = {k for m in reading.mentions for k in range(m.start, m.end)}
    kept = [i for i in range(len(clause)) if i not in inside and clause[i].low != NAME]
    words = [all_words[i] for i in kept]
    as_written = [clause[i].text for i in kept]
    negations = [i for i, w in enumerate(words) if w in NEGATIONS]
    reading.negated = bool(negations)
    points = compass_points_in(as_written)
    for i, point in points:  # "not north", "no more west": denied unless a point comes between
        denied = any(q < i and not any(q < j < i for j, _ in points) for q in negations)
        (reading.denied if denied else reading.headings).append(point)
    reading.clock = next(
        (hit[0] for i in range(len(words)) if (hit := clock_at(words, i)) is not None), None
    )
    reading.around = _has_cue(words, TURN_AROUND) is not None
    reading.destination = _has_cue(words, DESTINATION_CUES) is not None
    reading.stop = _has_cue(words, STOP_CUES) is not None
    reading.passing = _has_cue(words, PASS_CUES) is not None
    reading.reach = _sent_to_landmark(all_words, reading.mentions)
    turn_verb = any(w in TURN_VERBS for w in words)
    # A roundabout is where to turn unless the clause says to stop at it, pass it, ...
    roundabout_only = not (reading.destination or reading.stop or reading.passing)
    reading.junction = any(w in JUNCTIONS for w in words) or (
        reading.roundabout is not None and (turn_verb or roundabout_only)
    )
    if reading.junction:
        reading.ordinal = next(
            (
                o
                for i, w in enumerate(words)
                if (o := ordinal_of(w)) is not None and words[i + 1 : i + 2] != ["to"]
            ),
            None,  # "next to the church" is where, not which
        )
    turning = reading.junction or turn_verb
    reading.turn, reading.side = _left_right(words, turning)
    if reading.turn is not None and reading.ordinal is None:  # "take the second right"
        at = words.index(reading.turn) if reading.turn in words else 0
        reading.ordinal = ordinal_of(words[at - 1]) if at > 0 else None
    if reading.side is None and _has_cue(words, AHEAD_PHRASES) is not None and not turning:
        reading.side = "ahead"
    moving = turning or any(w in MOTION_VERBS for w in words)
    # "At 3 o'clock you will see a pond": where a landmark is, not where to fly.
    seen_at = not (moving or reading.destination or reading.stop or reading.side)
    if reading.clock in _CLOCK_SIDES and reading.mentions and seen_at:
        reading.side, reading.clock = _CLOCK_SIDES[reading.clock], None
    distances = distances_in(words)
    reading.distance_m = distances[0][1] if distances else None
    return reading
