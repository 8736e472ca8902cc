"""Landmark words: categories and the phrases people use for them, colours, attribute words.

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
def category_of(text: str) -> str | None:
    """The landmark category a phrase names (``"a small restaurant ..."`` -> ``restaurant``).

    Remembered per text: an episode asks about the same phrases and captions again and
    again, and each new text is a search per category phrase."""
    lowered = text.lower()
    best: tuple[int, str] | None = None
    for category, phrases in CATEGORY_PHRASES.items():
        for phrase in phrases:
            match = re.search(rf"\b{re.escape(phrase)}\b", lowered)
            if match and (best is None or match.start() < best[0]):
                best = (match.start(), category)
    return None if best is None else best[1]


def content_words(text: str) -> set[str]:
    """Lower-case words of ``text`` without filler words (gray counted as grey)."""
    words = {w for w in _WORD.findall(text.lower()) if w not in _STOPWORDS}
    return {"grey" if w == "gray" else w for w in words}


def colours_in(text: str) -> set[str]:
    return {"grey" if c == "gray" else c for c in content_words(text) if c in COLOURS}


def text_similarity(phrase: str, label: str, caption: str) -> float:
    """How well a detection (label, caption) fits a landmark phrase, in [0, 1].

    Same category counts most; shared attribute words (colours, shapes) add the rest; a
    colour the phrase names that the caption contradicts takes some away.
    """
    category = category_of(phrase)
    seen = category_of(f"{label} {caption}")
    score = 0.6 if category is not None and category == seen else 0.0
    wanted = content_words(phrase)
    if wanted:
        score += 0.4 * len(wanted & content_words(f"{label} {caption}")) / len(wanted)
    phrase_colours, caption_colours = colours_in(phrase), colours_in(caption)
    if phrase_colours and caption_colours and not phrase_colours & caption_colours:
        score -= 0.2
    return max(0.0, min(1.0, score))
