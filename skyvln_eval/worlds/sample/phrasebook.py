"""The synthetic commander's sentence frames, in families, and which split speaks which.

A frame is one way of saying one thing (a *slot*: a heading, a turn at the n-th
intersection, the destination with its distance, an answer to the follower's question,
...). A family is one commander's manner of speaking: a frame for every slot plus a
:class:`~.wording.Style` for numbers, compass points, sides and names. The seen splits
(train, val_seen) and the unseen ones (val_unseen, test_unseen) speak disjoint families
(:data:`SPLIT_FAMILIES`). val_unseen's are validation phrasings (the rule stand-in was
developed with them in its tests); test_unseen's are held out: no test reads them and
the idioms only they use are not in the stand-in's vocabulary.

Placeholders: ``{dir}`` / ``{dir_erly}`` / ``{dir_ward}`` the compass point to fly,
``{old}`` / ``{old_erly}`` / ``{old_ward}`` the one the follower flew, ``{lr}`` left or
right, ``{nth}`` an ordinal, ``{word}`` a landmark's category word, ``{lm}`` its full
description (with its name when given), ``{side}`` where it is, ``{dist}`` a distance.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.worlds.sample.wording import (
    Style,
    abbreviated,
    compass_colloquial,
    compass_hyphen,
    compass_spaced,
    digits,
    kilometres,
    numeric_ordinal,
    words,
)

#: Slots by topic: what a frame can be about.
TOPICS: Final[dict[str, tuple[str, ...]]] = {
    "question": (
        "question.which_way",
        "question.keep",
        "question.close",
        "question.is_it",
        "question.can_see",
    ),
    "answer": (
        "answer.which_way",
        "answer.yes",
        "answer.close",
        "answer.is_it",
        "answer.can_see",
        "answer.arrived",
    ),
    "correction": ("answer.correct",),
    "direction": (
        "head",
        "head.road",
        "turn.nth",
        "turn.at",
        "turn.roundabout",
        "turn.here",
        "straight",
    ),
    "landmark": ("pass", "stop.at", "next"),
    "distance": ("stop.distance", "next.distance"),
    "destination": ("destination", "destination.distance"),
}
SLOTS: Final = tuple(slot for slots in TOPICS.values() for slot in slots)


@dataclass(frozen=True)
class Frame:
    """One sentence frame: ``"<family>/<slot>"`` is its id."""

    family: str
    slot: str
    template: str

    @property
    def frame_id(self) -> str:
        return f"{self.family}/{self.slot}"


@dataclass(frozen=True)
class Family:
    name: str
    style: Style
    frames: Mapping[str, str]

    def frame(self, slot: str) -> Frame:
        return Frame(self.name, slot, self.frames[slot])


_PLAIN = Family(
    "plain",
    Style(
        distances=(digits("meters"),),
        compass=(str,),
        sides={"left": "on your left", "right": "on your right", "ahead": "in front of you"},
        name=" ({name})",
        within=", ",
        answer_joiner=", ",
    ),
    {
        "question.which_way": "I am at the stop, which way should I go now?",
        "question.keep": "Should I keep flying {old}?",
        "question.close": "Am I close to the destination?",
        "question.is_it": "Is the destination the {word} near me?",
        "question.can_see": "I can see the {word}. Where to now?",
        "answer.which_way": "Go on",
        "answer.yes": "Yes, keep going",
        "answer.correct": "No, not {old} any more",
        "answer.close": "Not yet",
        "answer.is_it": "No, it is not",
        "answer.can_see": "Good",
        "answer.arrived": "You are there now, stop here",
        "head": "go {dir}",
        "head.road": "head {dir} along the road",
        "turn.nth": "turn {lr} at the {nth} intersection",
        "turn.at": "turn {lr} at the intersection by the {word}",
        "turn.roundabout": "at the roundabout take the {lr}",
        "turn.here": "turn {lr} here",
        "straight": "go straight on",
        "pass": "you will pass {lm} {side}",
        "stop.at": "stop when you reach the {word}",
        "next": "you will reach {lm}",
        "stop.distance": "stop after about {dist}",
        "next.distance": "after about {dist} you will reach {lm}",
        "destination": "the destination is {lm}",
        "destination.distance": "after about {dist} you will see {lm}; that is your destination",
    },
)
_CHATTY = Family(
    "chatty",
    Style(
        distances=(digits("m"), digits("metres"), words("metres", a_hundred=True)),
        compass=(compass_hyphen,),
        sides={
            "left": "on your left side",
            "right": "on your right side",
            "ahead": "straight ahead",
        },
        name=" ({name})",
        within=", ",
        answer_joiner=", ",
    ),
    {
        "question.which_way": "Okay, I'm at the spot. Where do I go from here?",
        "question.keep": "Do I keep going {old}?",
        "question.close": "Am I nearly there?",
        "question.is_it": "Is it the {word} right below me?",
        "question.can_see": "The {word} is in view. What next?",
        "answer.which_way": "Sure, from here",
        "answer.yes": "Yes, that's right, carry on",
        "answer.correct": "No, don't keep going {old}",
        "answer.close": "Not quite, there's still a bit to go",
        "answer.is_it": "No, that's not the one",
        "answer.can_see": "Great",
        "answer.arrived": "That's it, you're right over it, stop there",
        "head": "fly towards the {dir}",
        "head.road": "fly {dir} following the street",
        "turn.nth": "take a {lr} at the {nth} intersection",
        "turn.at": "make a {lr} turn at the intersection next to the {word}",
        "turn.roundabout": "go {lr} at the roundabout",
        "turn.here": "take a {lr} from here",
        "straight": "keep flying straight",
        "pass": "keep {lm} {side}",
        "stop.at": "wait once you get to the {word}",
        "next": "look for {lm}",
        "stop.distance": "fly about {dist} and wait there",
        "next.distance": "fly about {dist} and look for {lm}",
        "destination": "stop over {lm}, that is the destination",
        "destination.distance": "stop over {lm} after about {dist}; that's the destination",
    },
)
_TERSE = Family(
    "terse",
    Style(
        distances=(digits("m", space=False), kilometres("km")),
        compass=(abbreviated, str),
        sides={"left": "to the left", "right": "to the right", "ahead": "ahead"},
        name=" [{name}]",
        within=". ",
        answer_joiner=". ",
        ordinals=numeric_ordinal,
    ),
    {
        "question.which_way": "At the stop. Direction?",
        "question.keep": "Still {old}?",
        "question.close": "Close?",
        "question.is_it": "That {word}?",
        "question.can_see": "{word} in sight. Next?",
        "answer.which_way": "Next leg",
        "answer.yes": "Affirmative",
        "answer.correct": "Negative, no more {old}",
        "answer.close": "Negative, not yet",
        "answer.is_it": "Negative",
        "answer.can_see": "Copy",
        "answer.arrived": "On target, hold",
        "head": "proceed {dir}",
        "head.road": "follow the road {dir}",
        "turn.nth": "{lr} at the {nth} junction",
        "turn.at": "{lr} at the junction beside the {word}",
        "turn.roundabout": "{lr} exit at the roundabout",
        "turn.here": "{lr} turn now",
        "straight": "straight on",
        "pass": "{lm} {side}",
        "stop.at": "halt at the {word}",
        "next": "next up: {lm}",
        "stop.distance": "halt at {dist}",
        "next.distance": "{lm} in {dist}",
        "destination": "target: {lm}",
        "destination.distance": "target {lm}, {dist} out",
    },
)
_FORMAL = Family(
    "formal",
    Style(
        distances=(words("metres"),),
        compass=(compass_hyphen,),
        sides={
            "left": "on your left-hand side",
            "right": "on your right-hand side",
            "ahead": "directly ahead of you",
        },
        name=", known as {name}",
        within="; ",
        answer_joiner=". ",
        next_word="following",
    ),
    {
        "question.which_way": "I have reached the waypoint. Please advise on the heading.",
        "question.keep": "Shall I maintain a {old_erly} heading?",
        "question.close": "Am I approaching the destination?",
        "question.is_it": "Is the {word} beneath me the destination?",
        "question.can_see": "The {word} is now visible. Please advise.",
        "answer.which_way": "Understood, please proceed as follows",
        "answer.yes": "Affirmative, maintain your present heading",
        "answer.correct": "Negative, do not continue {old_ward}",
        "answer.close": "You have not yet arrived",
        "answer.is_it": "That is not the destination",
        "answer.can_see": "Very good",
        "answer.arrived": "You have arrived; please remain in position",
        "head": "proceed in a {dir_erly} direction",
        "head.road": "proceed {dir_ward} along the road",
        "turn.nth": "at the {nth} intersection, turn {lr}",
        "turn.at": "upon reaching the intersection adjacent to the {word}, turn {lr}",
        "turn.roundabout": "at the traffic circle, take the {lr} exit",
        "turn.here": "turn {lr} at this point",
        "straight": "maintain your present heading",
        "pass": "{lm} will be {side}",
        "stop.at": "come to a halt upon reaching the {word}",
        "next": "you will then arrive at {lm}",
        "stop.distance": "after approximately {dist}, come to a halt",
        "next.distance": "in approximately {dist} you will arrive at {lm}",
        "destination": "your final destination is {lm}",
        "destination.distance": (
            "approximately {dist} further on, you will find your destination, {lm}"
        ),
    },
)
_RADIO = Family(
    "radio",
    Style(
        distances=(digits("meters"), kilometres("kilometers")),
        compass=(compass_spaced,),
        sides={"left": "off your left", "right": "off your right", "ahead": "dead ahead"},
        name=" named {name}",
        within=", then ",
        answer_joiner=". ",
    ),
    {
        "question.which_way": "Holding at the stop point, which heading?",
        "question.keep": "Continue {old}, over?",
        "question.close": "How far out am I, over?",
        "question.is_it": "Is the target that {word}, over?",
        "question.can_see": "Eyes on the {word}, next instruction?",
        "answer.which_way": "Roger, here is the next leg",
        "answer.yes": "Roger that, continue",
        "answer.correct": "Negative on {old}",
        "answer.close": "Not there yet",
        "answer.is_it": "Negative, wrong building",
        "answer.can_see": "Roger",
        "answer.arrived": "Roger, you are over the target, hold position",
        "head": "vector {dir}",
        "head.road": "stay on the road heading {dir}",
        "turn.nth": "hang a {lr} at the {nth} crossing",
        "turn.at": "hang a {lr} at the crossing by the {word}",
        "turn.roundabout": "at the traffic circle bear {lr}",
        "turn.here": "hang a {lr} now",
        "straight": "hold your heading",
        "pass": "you'll fly past {lm}, it'll be {side}",
        "stop.at": "hold position over the {word}",
        "next": "next checkpoint is {lm}",
        "stop.distance": "hold position after {dist}",
        "next.distance": "next checkpoint is {lm}, {dist} out",
        "destination": "final target is {lm}",
        "destination.distance": "{dist} on you'll reach the target, {lm}",
    },
)
_STORY = Family(
    "story",
    Style(
        distances=(words("meters", a_hundred=True),),
        compass=(compass_colloquial,),
        sides={"left": "to your left", "right": "to your right", "ahead": "right in front of you"},
        name=", the one called {name}",
        within=", and then ",
        answer_joiner=". ",
    ),
    {
        "question.which_way": "Here I am at the end of the last leg. Which way now?",
        "question.keep": "Is it still {old} from here?",
        "question.close": "How much further is it?",
        "question.is_it": "Could the {word} under me be the place?",
        "question.can_see": "I'm looking at the {word}. What now?",
        "answer.which_way": "All right, listen",
        "answer.yes": "Yes, still the same way",
        "answer.correct": "No, forget about {old}",
        "answer.close": "There's still a way to go",
        "answer.is_it": "No, not that one",
        "answer.can_see": "Perfect",
        "answer.arrived": "You've made it, so stop and hover right where you are",
        "head": "make your way {dir}",
        "head.road": "follow the street that runs {dir}",
        "turn.nth": "when you get to the {nth} crossroads, bear {lr}",
        "turn.at": "at the crossroads with the {word} on the corner, bear {lr}",
        "turn.roundabout": "at the roundabout, exit to the {lr}",
        "turn.here": "bear {lr} from where you are",
        "straight": "carry straight on",
        "pass": "look out for {lm} {side} as you go",
        "stop.at": "stop and hover when the {word} is right below you",
        "next": "before long you'll come to {lm}",
        "stop.distance": "once you have covered {dist}, stop and hover",
        "next.distance": "after {dist} or so you'll come to {lm}",
        "destination": "what you are looking for is {lm}",
        "destination.distance": "about {dist} on, {lm} is where your journey ends",
    },
)

FAMILIES: Final[dict[str, Family]] = {
    f.name: f for f in (_PLAIN, _CHATTY, _TERSE, _FORMAL, _RADIO, _STORY)
}
#: Which families each split speaks. Seen and unseen splits share none.
SPLIT_FAMILIES: Final[dict[str, tuple[str, ...]]] = {
    "train": ("plain", "chatty"),
    "val_seen": ("plain", "chatty"),
    "val_unseen": ("terse", "formal"),
    "test_unseen": ("radio", "story"),
}
SEEN_SPLITS: Final = ("train", "val_seen")
UNSEEN_SPLITS: Final = ("val_unseen", "test_unseen")


def seen_families() -> tuple[str, ...]:
    return tuple(dict.fromkeys(f for s in SEEN_SPLITS for f in SPLIT_FAMILIES[s]))


def held_out_families() -> tuple[str, ...]:
    return tuple(dict.fromkeys(f for s in UNSEEN_SPLITS for f in SPLIT_FAMILIES[s]))


def all_frames() -> list[Frame]:
    return [family.frame(slot) for family in FAMILIES.values() for slot in SLOTS]


def families_named(names: Sequence[str]) -> list[Family]:
    """The families of ``names`` (at least one), with "did you mean" for an unknown name."""
    if not names:
        raise ConfigError("at least one phrasing family is needed")
    for name in names:
        if name not in FAMILIES:
            raise UnknownNameError("phrasing family", name, list(FAMILIES))
    return [FAMILIES[n] for n in names]
