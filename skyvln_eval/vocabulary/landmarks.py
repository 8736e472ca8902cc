"""Landmark words: categories and the phrases people use for them, colours, attribute words.

Besides the categories a detector names (:data:`CATEGORY_PHRASES`), people describe what
they see from above with generic words: "the grey building", "a house with a blue roof",
"the parking lot", "a pond" (:data:`GENERIC_PHRASES`). A generic word makes a phrase a
landmark, but it is no category: "the building" does not match every church and hotel in
sight; only the same generic word on both sides counts (less than a category), and the
attribute words (colours, shapes) do the rest.

Only vocabulary and small text helpers live here; nothing in it looks at a map.
"""

from __future__ import annotations

import functools
import re
from typing import Final

#: Landmark categories and the phrases people use for them (longest first when matching).
CATEGORY_PHRASES: Final[dict[str, tuple[str, ...]]] = {
    "water_tower": ("water tower",),
    "gas_station": ("gas station", "petrol station", "fuel station", "filling station"),
    "mall": ("shopping mall", "shopping centre", "shopping center", "mall"),
    "restaurant": ("restaurant", "pizzeria", "diner", "cafe", "eatery"),
    "church": ("church", "chapel", "cathedral"),
    "stadium": ("stadium", "arena"),
    "roundabout": ("roundabout", "traffic circle"),
    "bridge": ("bridge",),
    "park": ("park",),
    "school": ("school", "academy"),
    "hospital": ("hospital", "clinic", "medical center", "medical centre"),
    "hotel": ("hotel", "motel", "inn"),
    "tower": ("skyscraper", "high-rise", "tower"),
}
#: Generic things seen from above and the words people use for them (by kind): landmarks
#: in instructions, but no detector category. Roads and rivers are left out: "along the
#: main road" says which way, not what to find.
GENERIC_PHRASES: Final[dict[str, tuple[str, ...]]] = {
    "building": ("building", "buildings", "structure", "structures"),
    "house": ("house", "houses", "villa", "cottage"),
    "warehouse": ("warehouse", "warehouses", "shed", "sheds", "hangar"),
    "factory": ("factory", "factories", "power plant"),
    "parking_lot": ("parking lot", "parking lots", "car park", "parking area", "parking"),
    "pond": ("pond", "ponds", "lake"),
    "field": ("field", "fields", "lawn", "meadow"),
    "court": (
        "tennis court",
        "tennis courts",
        "basketball court",
        "basketball courts",
        "court",
        "courts",
    ),
    "pool": ("swimming pool", "pool"),
    "roof": ("roof", "roofs", "rooftop"),
}
#: How the detector names each category.
CATEGORY_LABELS: Final[dict[str, str]] = {c: p[0] for c, p in CATEGORY_PHRASES.items()}

COLOURS: Final = (
    "red",
    "orange",
    "yellow",
    "green",
    "blue",
    "white",
    "grey",
    "gray",
    "black",
    "beige",
    "brown",
    "dark",
)
#: Words written for another of the same meaning when comparing descriptions.
_SAME_AS: Final = {"gray": "grey", "circular": "round"}

_STOPWORDS: Final = frozenset(
    [
        "a",
        "an",
        "the",
        "with",
        "and",
        "of",
        "on",
        "in",
        "its",
        "it",
        "over",
        "by",
        "to",
        "at",
        "that",
        "is",
        "are",
        "your",
        "you",
        "will",
        "see",
        "there",
        "which",
        "this",
        "from",
        "for",
        "inside",
        "around",
    ]
)
_WORD = re.compile(r"[a-z]+")


@functools.lru_cache(maxsize=4096)
def landmark_kind(text: str) -> tuple[str, bool] | None:
    """What a phrase names first, a category or a generic kind, and whether it is a
    category: ``"a small restaurant ..."`` -> ``("restaurant", True)``, ``"the house by the
    church"`` -> ``("house", False)``; None if neither.

    Remembered per text: an episode asks about the same phrases and captions again and
    again, and each new text is a search per phrase."""
    lowered = text.lower()
    best: tuple[int, str, bool] | None = None
    for specific, table in ((True, CATEGORY_PHRASES), (False, GENERIC_PHRASES)):
        for kind, phrases in table.items():
            for phrase in phrases:
                match = re.search(rf"\b{re.escape(phrase)}\b", lowered)
                if match and (best is None or match.start() < best[0]):
                    best = (match.start(), kind, specific)
    return None if best is None else (best[1], best[2])


def category_of(text: str) -> str | None:
    """The landmark category a phrase names (``"a small restaurant ..."`` -> ``restaurant``);
    None for a generic thing named first (``"the building next to the school"``)."""
    kind = landmark_kind(text)
    return kind[0] if kind is not None and kind[1] else None


def generic_kind_of(text: str) -> str | None:
    """The generic kind a phrase names first (``"a long white building"`` -> ``building``);
    None when it names a category first, or nothing."""
    kind = landmark_kind(text)
    return kind[0] if kind is not None and not kind[1] else None


def content_words(text: str) -> set[str]:
    """Lower-case words of ``text`` without filler words (gray counted as grey, circular as
    round)."""
    words = {w for w in _WORD.findall(text.lower()) if w not in _STOPWORDS}
    return {_SAME_AS.get(w, w) for w in words}


def colours_in(text: str) -> set[str]:
    return {c for c in content_words(text) if c in COLOURS}


def text_similarity(phrase: str, label: str, caption: str) -> float:
    """How well a detection (label, caption) fits a landmark phrase, in [0, 1].

    Same category counts most, the same generic kind ("pond" and a pond) half as much, a
    generic word against a category ("building" and a church) nothing; shared attribute
    words (colours, shapes) add the rest; a colour the phrase names that the caption
    contradicts takes some away.
    """
    kind = landmark_kind(phrase)
    seen = landmark_kind(f"{label} {caption}")
    score = 0.0
    if kind is not None and kind == seen:
        score = 0.6 if kind[1] else 0.3
    wanted = content_words(phrase)
    if wanted:
        score += 0.4 * len(wanted & content_words(f"{label} {caption}")) / len(wanted)
    phrase_colours, caption_colours = colours_in(phrase), colours_in(caption)
    if phrase_colours and caption_colours and not phrase_colours & caption_colours:
        score -= 0.2
    return max(0.0, min(1.0, score))
