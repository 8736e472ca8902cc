"""How the synthetic commander writes numbers, compass points, sides, ordinals and names.

Each family of sentence frames (:mod:`.phrasebook`) has a :class:`Style`: distances as
digits ("150 meters", "150m", "0.15 km") or as words ("a hundred and fifty metres",
"half a kilometre"), compass points bare ("northeast", "north-east", "north east"),
abbreviated ("NE"), as adverbs and adjectives ("north-eastward", "north-easterly") or
colloquially ("up to the northeast"). Every choice draws from the generator's own
wording stream; nothing here is shared with any reader of the text.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

# The generator spells numbers with its own lists, not the vocabulary's: the reader of
# the text and its writer share no code, so neither can lean on the other's choices.
_ONES = [
    "zero",
    "one",
    "two",
    "three",
    "four",
    "five",
    "six",
    "seven",
    "eight",
    "nine",
    "ten",
    "eleven",
    "twelve",
    "thirteen",
    "fourteen",
    "fifteen",
    "sixteen",
    "seventeen",
    "eighteen",
    "nineteen",
]
_TENS = ["-", "-", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety"]
_ORDINAL_WORDS = ("first", "second", "third", "fourth", "fifth")
_ABBREVIATIONS = {
    "north": "N",
    "northeast": "NE",
    "east": "E",
    "southeast": "SE",
    "south": "S",
    "southwest": "SW",
    "west": "W",
    "northwest": "NW",
}


def _below_hundred(n: int) -> str:
    if n < 20:
        return _ONES[n]
    tens, ones = divmod(n, 10)
    return _TENS[tens] + ("" if ones == 0 else f"-{_ONES[ones]}")


def number_words(n: int, a_hundred: bool = False, with_and: bool = True) -> str:
    """An integer below a million in words: 150 -> "one hundred and fifty" (or "a hundred
    and fifty" with ``a_hundred``; "one hundred fifty" without ``with_and``)."""
    if n < 100:
        return _below_hundred(n)
    if n >= 1000:
        thousands, rest = divmod(n, 1000)
        head = (
            "a thousand" if thousands == 1 and a_hundred else f"{number_words(thousands)} thousand"
        )
        if rest == 0:
            return head
        joint = " and " if rest < 100 and with_and else " "
        return head + joint + number_words(rest, False, with_and)
    hundreds, rest = divmod(n, 100)
    head = "a hundred" if hundreds == 1 and a_hundred else f"{_ONES[hundreds]} hundred"
    if rest == 0:
        return head
    return f"{head} {'and ' if with_and else ''}{_below_hundred(rest)}"


def _km(metres: int) -> str:
    return f"{metres / 1000:g}"


def _split_compass(point: str) -> tuple[str, str]:
    """("north", "east") for "northeast"; ("north", "") for "north"."""
    for first in ("north", "south"):
        if point.startswith(first) and point != first:
            return first, point[len(first) :]
    return point, ""


def compass_hyphen(point: str) -> str:
    first, second = _split_compass(point)
    return f"{first}-{second}" if second else first


def compass_spaced(point: str) -> str:
    first, second = _split_compass(point)
    return f"{first} {second}" if second else first


def compass_erly(point: str) -> str:
    """The adjective: "northerly", "north-easterly"."""
    return compass_hyphen(point) + "erly"


def compass_ward(point: str) -> str:
    """The adverb: "northward", "north-eastward"."""
    return compass_hyphen(point) + "ward"


def compass_colloquial(point: str) -> str:
    """ "up north", "down south", "out west", "up to the northeast"."""
    first, second = _split_compass(point)
    if second:
        return f"{'up' if first == 'north' else 'down'} to the {point}"
    return {"north": "up north", "south": "down south", "east": "out east", "west": "out west"}[
        point
    ]


def pick(rng: np.random.Generator, options: list[str] | tuple[str, ...]) -> str:
    return str(options[int(rng.integers(len(options)))])


@dataclass(frozen=True)
class Style:
    """How one family renders the values its frames leave open.

    ``distances`` and ``compass`` are lists of renderers, one chosen at random per use;
    ``sides`` maps left / right / ahead to the family's phrase; ``next_word`` names the
    next intersection when no ordinal is given; ``name`` wraps a landmark's proper name;
    ``within`` joins the clauses of one sentence and ``answer_joiner`` the answer to the
    rest of the instruction.
    """

    distances: tuple[Callable[[int], str], ...]
    compass: tuple[Callable[[str], str], ...]
    sides: dict[str, str]
    name: str
    within: str
    answer_joiner: str
    ordinals: Callable[[int], str] = field(default=lambda k: _ORDINAL_WORDS[k - 1])
    next_word: str = "next"

    def distance(self, rng: np.random.Generator, metres: int) -> str:
        return self.distances[int(rng.integers(len(self.distances)))](metres)

    def point(self, rng: np.random.Generator, compass_point: str) -> str:
        return self.compass[int(rng.integers(len(self.compass)))](compass_point)

    def ordinal(self, k: int) -> str:
        return self.next_word if k == 0 else self.ordinals(k)


def numeric_ordinal(k: int) -> str:
    return f"{k}{ {1: 'st', 2: 'nd', 3: 'rd'}.get(k, 'th') }"


def digits(unit: str, space: bool = True) -> Callable[[int], str]:
    return lambda m: f"{m}{' ' if space else ''}{unit}"


def kilometres(unit: str) -> Callable[[int], str]:
    return lambda m: f"{_km(m)} {unit}"


def words(unit: str, a_hundred: bool = False) -> Callable[[int], str]:
    def render(m: int) -> str:
        if a_hundred and m == 500:
            return f"half a {'kilometre' if unit.endswith('res') else 'kilometer'}"
        return f"{number_words(m, a_hundred)} {unit}"

    return render


def abbreviated(point: str) -> str:
    return _ABBREVIATIONS[point]
