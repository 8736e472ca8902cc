"""The rule backend's view of text: words, proper names, sentences and clauses.

Proper names come out first (in brackets or quotes, or after "called" / "named" /
"known as", as a run of capitalised words), so "Eagle Arena" is not read as a stadium
and "St. Peter's" does not end a sentence. The rest becomes words (hyphenated and
contracted words kept whole, "150m" split into number and unit), then sentences (at
. ! ?) and clauses (at , ; : and dashes, at "then", and at "and" when a new clause
starts after it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from skyvln_eval.vocabulary import CLAUSE_OPENERS, UNITS_M, category_of

NAME: Final = "<name>"
_BRACKETED = re.compile(r"\(([^()]*)\)|\[([^\[\]]*)\]|\"([^\"]+)\"|“([^”]+)”")
_NAME_WORD = r"(?:[A-Z][a-z]{0,2}\.(?=\s+[A-Z])|[A-Z0-9][\w'’&-]*)"
_NAME_FILLER = r"(?:of|the|de|and|la)"
_CUED_NAME = re.compile(
    rf"\b(?:called|named|known as)\s+({_NAME_WORD}(?:\s+(?:{_NAME_WORD}|{_NAME_FILLER}))*"
    r"(?:\s+[a-z]+)?)"
)
_TOKEN = re.compile(
    r"\x00(?P<name>\d+)\x00"
    r"|(?P<ordinal>\d+(?:st|nd|rd|th))\b"
    r"|(?P<number>\d+(?:\.\d+)?)"
    r"|(?P<word>[A-Za-z]+(?:['’][A-Za-z]+)*(?:-[A-Za-z]+)*)"
    r"|(?P<punct>[.!?;:,()\[\]—–]|\s-\s)"
)
_SENTENCE_END: Final = frozenset({".", "!", "?"})
_CLAUSE_BREAK: Final = frozenset({",", ";", ":", "(", ")", "[", "]", "—", "–", "-"})
#: Short words that end with a period without ending a sentence.
_ABBREVIATIONS: Final = frozenset({"approx", "st", "dr", "mt", "ave", "rd", "no", "nr"})


@dataclass(frozen=True)
class Word:
    """One word: ``text`` as written, ``low`` lower-cased (a name's is :data:`NAME`)."""

    text: str
    low: str
    name: str | None = None


def _cut_names(text: str) -> tuple[str, list[str]]:
    """The text with each proper name replaced by a marker, and the names in order."""
    names: list[str] = []

    def keep(name: str) -> str:
        names.append(name.strip())
        return f" \x00{len(names) - 1}\x00 "

    text = _BRACKETED.sub(lambda m: keep(next(g for g in m.groups() if g is not None)), text)

    def cued(m: re.Match[str]) -> str:
        name = m.group(1)
        last = name.split()[-1]
        if last.islower() and category_of(last) is None:  # a trailing plain word is not
            name = name[: -len(last)].rstrip()  # part of the name ("named Inn here")
            return m.group(0)[: m.start(1) - m.start(0)] + keep(name) + " " + last
        return m.group(0)[: m.start(1) - m.start(0)] + keep(name)

    return _CUED_NAME.sub(cued, text), names


def words_of(text: str) -> list[Word | str]:
    """Words and punctuation marks (as plain strings) of ``text``, names as one word each."""
    cut, names = _cut_names(text)
    out: list[Word | str] = []
    for m in _TOKEN.finditer(cut):
        if m.group("name") is not None:
            out.append(Word(names[int(m.group("name"))], NAME, names[int(m.group("name"))]))
        elif m.group("punct") is not None:
            out.append(m.group("punct").strip())
        else:
            raw = m.group(0).replace("’", "'")
            # "150m", "0.2km": a unit written onto its number is a word of its own.
            unit = re.fullmatch(r"(\d+(?:\.\d+)?)([a-z]+)", raw.lower())
            if unit and unit.group(2) in UNITS_M:
                out += [Word(unit.group(1), unit.group(1)), Word(unit.group(2), unit.group(2))]
            else:
                out.append(Word(raw, raw.lower()))
    return out


def sentences_of(text: str) -> list[list[list[Word]]]:
    """Sentences of ``text``, each a list of clauses, each a list of words."""
    sentences: list[list[list[Word]]] = []
    clauses: list[list[Word]] = []
    clause: list[Word] = []

    def end_clause() -> None:
        nonlocal clause
        if clause:
            clauses.append(clause)
        clause = []

    tokens = words_of(text)
    for i, token in enumerate(tokens):
        if isinstance(token, str):
            previous = tokens[i - 1] if i else None
            abbreviation = isinstance(previous, Word) and previous.low in _ABBREVIATIONS
            if token in _SENTENCE_END and not (token == "." and abbreviation):
                end_clause()
                if clauses:
                    sentences.append(clauses)
                clauses = []
            elif token in _CLAUSE_BREAK:
                end_clause()
            continue
        following = tokens[i + 1] if i + 1 < len(tokens) else None
        if token.low == "then":
            end_clause()
            continue
        if token.low == "and" and isinstance(following, Word) and following.low in CLAUSE_OPENERS:
            end_clause()
            continue
        clause.append(token)
    end_clause()
    if clauses:
        sentences.append(clauses)
    return sentences
