"""Direction words: compass points in the forms people write them, sides and turns.

A compass point can be written bare ("northeast", "north-east", "north east"), as an
abbreviation ("NE", in capitals), as an adverb or adjective ("northward", "northwards",
"north-easterly", "northbound", "northern") or colloquially ("up north", where "up" is
only colour). :func:`compass_point` reads one word; :func:`compass_points_in` reads a
sequence of words, joining "north" + "east" written apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

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
