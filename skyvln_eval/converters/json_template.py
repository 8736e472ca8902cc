"""Many JSON messages of one shape, written by filling in the text of one.

The log writer encodes a message dict with :func:`~.writer.encode_json`. A run log has
messages that differ only in a few numbers (the obstacles every half second, each camera
image's time and bytes), and building and encoding a dict for each cost more than the
rest of their writing. A :class:`JsonTemplate` is made from one such message whose
varying values are :func:`slot` markers: it encodes it once, and :meth:`JsonTemplate.fill`
puts the JSON texts of the values where the markers were. The result is the writer's
encoding of the message with those values as long as each text is what the encoder writes
for the value (``float_texts`` for floats, ``str`` for ints, ``json.dumps(...,
ensure_ascii=False)`` for strings); the tests compare the two. A template made from
text that is not the toolkit's own (a model's words) must check :attr:`JsonTemplate.slots`:
such text may spell a marker.
"""

from __future__ import annotations

import re
from typing import Any

from skyvln_eval.converters.writer import encode_json

# A slot is a string no message holds (NUL bytes); the encoder writes NUL as \u0000.
_MARK = "\x00slot\x00"
_ENCODED = re.compile(r'"\\u0000slot\\u0000(\d+)"')


def slot(index: int) -> str:
    """The marker of the ``index``-th value of :meth:`JsonTemplate.fill` (from 0)."""
    return f"{_MARK}{index}"


class JsonTemplate:
    """The encoded text of a message with :func:`slot` markers, ready to be filled in."""

    def __init__(self, message: Any) -> None:
        text = encode_json(message).decode("utf-8")
        parts = _ENCODED.split(text)
        literals, indices = parts[0::2], [int(i) for i in parts[1::2]]
        if sorted(indices) != list(range(len(indices))):
            raise ValueError(f"slots {indices}: each of 0..n-1 must appear exactly once")
        self.slots = len(indices)
        # str.format's own fields where the markers were; braces of the text doubled.
        escaped = [literal.replace("{", "{{").replace("}", "}}") for literal in literals]
        fields = [f"{{{i}}}" for i in indices]
        self._format = "".join(
            part for pair in zip(escaped, [*fields, ""], strict=True) for part in pair
        )

    def fill(self, *texts: str) -> bytes:
        """The message's JSON with the ``texts`` (JSON texts, one per slot) in its slots."""
        return self._format.format(*texts).encode("utf-8")
