"""Numbers and distances as people write them: digits or words, with a unit.

"150 m", "150m", "150 meters", "0.15 km", "one hundred and fifty metres", "a hundred
fifty meters", "two hundred fifty", "half a kilometre", "a quarter of a mile", "500 ft"
all read as metres. A number needs a unit to be a distance.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

_ONES: Final = (
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
)
_TENS: Final = ("twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety")
#: Number words and their values; "hundred" and "thousand" multiply what came before.
NUMBER_WORDS: Final[dict[str, int]] = {
    **{w: i for i, w in enumerate(_ONES)},
    **{w: 20 + 10 * i for i, w in enumerate(_TENS)},
}
SCALES: Final[dict[str, int]] = {"hundred": 100, "thousand": 1000}
FRACTIONS: Final[dict[str, float]] = {"half": 0.5, "quarter": 0.25}
#: Units of length and their size in metres.
UNITS_M: Final[dict[str, float]] = {
    **dict.fromkeys(("m", "meter", "meters", "metre", "metres"), 1.0),
    **dict.fromkeys(("km", "kilometer", "kilometers", "kilometre", "kilometres"), 1000.0),
    **dict.fromkeys(("klick", "klicks", "click", "clicks"), 1000.0),
    **dict.fromkeys(("ft", "foot", "feet"), 0.3048),
    **dict.fromkeys(("yd", "yard", "yards"), 0.9144),
    **dict.fromkeys(("mi", "mile", "miles"), 1609.344),
}
#: Words that only say a number is rough: skipped around numbers.
APPROXIMATELY: Final = frozenset(
    {"about", "around", "roughly", "approximately", "approx", "some", "nearly", "almost", "~"}
)
#: Ordinal words and their rank ("next" and its kin: the first one from here).
ORDINALS: Final[dict[str, int]] = {
    "first": 1,
    "second": 2,
    "third": 3,
    "fourth": 4,
    "fifth": 5,
    "sixth": 6,
    "next": 1,
    "following": 1,
    "coming": 1,
    "upcoming": 1,
}


def ordinal_of(word: str) -> int | None:
    """The rank an ordinal names: "second" or "2nd" -> 2; else None."""
    lowered = word.lower()
    if lowered in ORDINALS:
        return ORDINALS[lowered]
    if lowered[:-2].isdigit() and lowered[-2:] in ("st", "nd", "rd", "th"):
        return int(lowered[:-2])
    return None


def _word_value(word: str) -> int | None:
    """ "forty-five" -> 45, "seven" -> 7, else None."""
    parts = word.split("-")
    if all(p in NUMBER_WORDS for p in parts) and len(parts) <= 2:
        return sum(NUMBER_WORDS[p] for p in parts)
    return None


def _number_at(words: Sequence[str], i: int) -> tuple[float, int] | None:
    """A number written from ``words[i]`` on, and the index after it."""
    word = words[i]
    try:
        return float(word), i + 1
    except ValueError:
        pass
    total, current, j, seen = 0.0, 0.0, i, False
    while j < len(words):
        w = words[j]
        value = _word_value(w)
        if value is not None:
            current, seen = current + value, True
        elif w in ("a", "an", "one") and j + 1 < len(words) and words[j + 1] in SCALES:
            current, seen = current + 1, True
        elif w in SCALES and seen:
            if SCALES[w] == 1000:
                total, current = total + max(current, 1) * 1000, 0.0
            else:
                current = max(current, 1) * 100
        elif w == "and" and seen and j + 1 < len(words) and _word_value(words[j + 1]) is not None:
            pass
        else:
            break
        j += 1
    return (total + current, j) if seen else None


def _fraction_at(words: Sequence[str], i: int) -> tuple[float, int] | None:
    """ "half a", "a quarter of a", or a lone "a" right before a unit: (value, unit index)."""
    j, value = i, 1.0
    if words[j] in ("a", "an"):
        j += 1
    if j < len(words) and words[j] in FRACTIONS:
        value, j = FRACTIONS[words[j]], j + 1
    elif j == i:
        return None
    while j < len(words) and words[j] in ("of", "a", "an"):
        j += 1
    return (value, j) if j < len(words) and words[j] in UNITS_M else None


def distance_at(words: Sequence[str], i: int) -> tuple[float, int] | None:
    """A distance in metres written from ``words[i]`` on ("150 m", "half a kilometre",
    "a hundred and fifty metres"), and the index after it; None if there is none."""
    number = _fraction_at(words, i) or _number_at(words, i)
    if number is None:
        return None
    value, j = number
    if j < len(words) and words[j] in UNITS_M:
        return value * UNITS_M[words[j]], j + 1
    return None


def distances_in(words: Sequence[str]) -> list[tuple[int, float]]:
    """(index, metres) of every distance in ``words`` (lower-case words, digits as written)."""
    found: list[tuple[int, float]] = []
    i = 0
    while i < len(words):
        hit = distance_at(words, i)
        if hit is None:
            i += 1
            continue
        found.append((i, hit[0]))
        i = hit[1]
    return found
