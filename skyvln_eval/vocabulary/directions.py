"""Direction words: compass points in the forms people write them, sides and turns.

A compass point can be written bare ("northeast", "north-east", "north east"), as an
abbreviation ("NE", in capitals), as an adverb or adjective ("northward", "northwards",
"north-easterly", "northbound", "northern") or colloquially ("up north", where "up" is
only colour). :func:`compass_point` reads one word; :func:`compass_points_in` reads a
sequence of words, joining "north" + "east" written apart.

Directions relative to the drone are read too: clock hours ("at your 2 o'clock", "two o
clock": 12 is straight ahead, 3 the right, 6 behind, 9 the left; :func:`clock_at`) and
the words of turning back ("turn around", "make a U-turn", "fly back": :data:`TURN_AROUND`).
:func:`relative_compass` turns either into a compass point given the drone's heading.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from skyvln_eval.vocabulary.quantities import NUMBER_WORDS

#: Compass points and their bearings, degrees clockwise from north.
COMPASS: Final[dict[str, float]] = {
    "north": 0.0,
    "northeast": 45.0,
    "east": 90.0,
    "southeast": 135.0,
    "south": 180.0,
    "southwest": 225.0,
    "west": 270.0,
    "northwest": 315.0,
}
#: Abbreviations, read only when written in capitals ("N", "NE": not the word "n").
COMPASS_ABBREVIATIONS: Final[dict[str, str]] = {
    "N": "north",
    "NE": "northeast",
    "E": "east",
    "SE": "southeast",
    "S": "south",
    "SW": "southwest",
    "W": "west",
    "NW": "northwest",
}
#: Endings that make a compass word an adverb or adjective without changing the point.
COMPASS_SUFFIXES: Final = ("wards", "ward", "erly", "ern", "bound")
SIDES: Final = ("left", "right")
#: Words that put a left / right after them on a side ("on your left", "to the right").
SIDE_PREPOSITIONS: Final = frozenset({"on", "to", "at", "by", "from", "along"})
#: Phrases saying that something is ahead rather than to a side.
AHEAD_PHRASES: Final = (
    ("in", "front"),
    ("straight", "ahead"),
    ("directly", "ahead"),
    ("ahead",),
)

#: Words after an hour that make it a clock direction ("2 o'clock", "2 o clock", "2 oclock").
CLOCK_WORDS: Final[tuple[tuple[str, ...], ...]] = (("o'clock",), ("oclock",), ("o", "clock"))
#: Saying to fly the way the drone came from, or the opposite way to its heading.
TURN_AROUND: Final[tuple[tuple[str, ...], ...]] = (
    ("turn", "around"),
    ("turn", "round"),
    ("turn", "back"),
    ("u-turn",),
    ("u", "turn"),
    ("uturn",),
    ("go", "back"),
    ("fly", "back"),
    ("head", "back"),
    ("come", "back"),
    ("move", "back"),
    ("backward",),
    ("backwards",),
    ("reverse",),
    ("opposite", "direction"),
    ("opposite", "way"),
)
#: Hours of the clock, degrees clockwise from straight ahead.
CLOCK_HOUR_DEG: Final = 30.0


def compass_point(word: str) -> str | None:
    """The compass point one word names: "north-easterly" -> "northeast"; else None.

    ``word`` is as written: capitals matter only for abbreviations ("NE", not "ne").
    """
    if word in COMPASS_ABBREVIATIONS:
        return COMPASS_ABBREVIATIONS[word]
    stem = word.lower().replace("-", "")
    for suffix in COMPASS_SUFFIXES:
        if stem.endswith(suffix) and stem[: -len(suffix)] in COMPASS:
            stem = stem[: -len(suffix)]
            break
    return stem if stem in COMPASS else None


def compass_points_in(words: Sequence[str]) -> list[tuple[int, str]]:
    """(index, compass point) of every compass point in ``words``, written as one word or
    as two ("north east", "south westward")."""
    found: list[tuple[int, str]] = []
    i = 0
    while i < len(words):
        point = compass_point(words[i])
        if point in ("north", "south") and i + 1 < len(words):
            second = compass_point(words[i + 1])
            if second in ("east", "west"):
                found.append((i, f"{point}{second}"))
                i += 2
                continue
        if point is not None:
            found.append((i, point))
        i += 1
    return found


def compass_word(bearing_deg: float) -> str:
    """The nearest of the eight compass points."""
    names = list(COMPASS)
    return names[int(((bearing_deg % 360.0) + 22.5) // 45.0) % 8]


def clock_at(words: Sequence[str], i: int) -> tuple[int, int] | None:
    """The clock hour written from ``words[i]`` on ("2 o'clock", "two o clock", "12
    oclock"; lower-case words) and the index after it; None if there is none."""
    word = words[i]
    hour = int(word) if word.isdigit() else NUMBER_WORDS.get(word)
    if hour is None or not 1 <= hour <= 12:
        return None
    for cue in CLOCK_WORDS:
        if tuple(words[i + 1 : i + 1 + len(cue)]) == cue:
            return hour, i + 1 + len(cue)
    return None


def relative_compass(offset_deg: float, heading_deg: float) -> str:
    """The compass point ``offset_deg`` clockwise from the drone's heading (compass degrees),
    the nearest of the eight: 60 deg off a heading of 0 is "northeast"."""
    return compass_word(heading_deg + offset_deg)
