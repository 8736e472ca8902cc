"""What counts as a word of a text: runs of letters and digits, in any script.

One definition for the agent's parser (copied landmark phrases, whether an instruction
has words and so at least one sub-goal) and the rule stand-in that answers it, so that the
two never disagree on whether a text says anything.
"""

from __future__ import annotations

import re
from typing import Final

WORD: Final = re.compile(r"[^\W_]+")


def phrase_words(text: str) -> list[str]:
    """The words of a text, lower case, without punctuation."""
    return WORD.findall(text.lower())
