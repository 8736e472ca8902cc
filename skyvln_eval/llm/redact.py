"""Keeping an API key out of what a server's answer puts into errors and records.

Servers echo the key in their error bodies ("Incorrect API key provided: sk-..."), and not
always as typed: JSON may escape any character as ``\\uXXXX`` and ``/`` as ``\\/``, a URL
or form field percent-encodes it, Python's ``repr`` (the openai client's error message
shows the parsed body so) escapes quotes and backslashes. Replacing the key's exact text
misses all of those, so :func:`scrub` matches the key with every character in any of its
forms, mixed as a server may mix them. A server that echoes the ``Authorization`` header
shows the key in base64 (``Basic base64(user:key)``, or the key alone): any base64 text
(standard or URL-safe, padded or not) that holds the key is replaced too.

Nothing in a server's URL is hidden this way: :func:`refuse_secrets_in_url` refuses a URL
with credentials or a query as a server's, and :func:`redacted_url` is how messages show
a URL that may hold either.
"""

from __future__ import annotations

import base64
import functools
import json
import re
import string
from typing import Final

from skyvln_eval.errors import ConfigError

#: What the key is replaced by.
REDACTED: Final = "[API key]"
#: Keys shorter than this are placeholders, not secrets (a local server takes any key,
#: and people set "x" or "none"): hiding every "x" of an error would garble it.
SHORTEST_SECRET: Final = 8
#: Characters of an excerpt shown of a body that is not what was expected.
EXCERPT_CHARS: Final = 200


def _char_forms(char: str) -> list[str]:
    """Every text one character of the key can appear as in a body, as regex patterns."""
    code = ord(char)
    forms = [re.escape(char), rf"\\u{code:04x}"]  # matched ignoring case: \u002F too
    forms += ["".join(f"%{byte:02x}" for byte in char.encode("utf-8"))]
    if code > 0xFFFF:  # JSON writes it as a surrogate pair
        high, low = divmod(code - 0x10000, 0x400)
        forms.append(rf"\\u{0xD800 + high:04x}\\u{0xDC00 + low:04x}")
    if char in "/\"'\\":  # JSON's \/ and \", repr's \' and \\
        forms.append(re.escape("\\" + char))
    if char == " ":  # a form field's space
        forms.append(r"\+")
    return forms


@functools.lru_cache(maxsize=8)
def _key_pattern(key: str) -> re.Pattern[str]:
    parts = ["(?:" + "|".join(_char_forms(char)) + ")" for char in key]
    return re.compile("".join(parts), re.IGNORECASE)


#: The characters of base64 text, standard or URL-safe, and its padding.
_BASE64_CHARS: Final = frozenset(string.ascii_letters + string.digits + "+/-_")


def _base64_cores(key: str) -> list[str]:
    """The base64 characters that the key's bytes alone decide, wherever it starts in the
    encoded text: base64 packs 3 bytes into 4 characters, so the key's encoding depends on
    its offset modulo 3 (after "user:" in a Basic header it is not the key's own). The 1-3
    characters at each end that share bits with the text around the key are left out."""
    raw = key.encode("utf-8")
    cores = []
    for offset in range(3):
        encoded = base64.b64encode(bytes(offset) + raw).decode("ascii")
        start = -(-8 * offset // 6)  # characters that hold a bit of the bytes before the key
        end = 8 * (offset + len(raw)) // 6  # characters made of those bytes only
        cores.append(encoded[start:end])
    return cores


@functools.lru_cache(maxsize=8)
def _base64_pattern(key: str) -> re.Pattern[str]:
    """The key's :func:`_base64_cores`, standard and URL-safe, in any of
    :func:`_char_forms`' escapings (JSON may write ``/`` as ``\\/``)."""
    cores = []
    for core in _base64_cores(key):
        for alphabet in (core, core.translate(str.maketrans("+/", "-_"))):
            cores.append("".join("(?:" + "|".join(_char_forms(char)) + ")" for char in alphabet))
    return re.compile("|".join(cores), re.IGNORECASE)


def _scrub_base64(text: str, key: str) -> str:
    """``text`` with each base64 run that holds the key replaced whole, its ends (which hold
    bits of the key too) and padding included. The run is widened by hand, not by the
    pattern: a leading ``[A-Za-z0-9+/_-]*`` would make the search quadratic in a long run."""
    pieces = []
    done = 0
    for found in _base64_pattern(key).finditer(text):
        if found.start() < done:  # inside the run replaced last
            continue
        start, end = found.start(), found.end()
        while start > done and text[start - 1] in _BASE64_CHARS:
            start -= 1
        while end < len(text) and text[end] in _BASE64_CHARS:
            end += 1
        while end < len(text) and text[end] == "=":
            end += 1
        pieces += [text[done:start], REDACTED]
        done = end
    return "".join(pieces) + text[done:]


def scrub(text: str, key: str | None) -> str:
    """``text`` with every occurrence of ``key`` replaced, in whatever escaping, and every
    base64 text that holds it (see the module docstring). Matching ignores case: a hex
    escape may be written either way, and hiding a look-alike of the key costs nothing. A
    key shorter than :data:`SHORTEST_SECRET` characters is a placeholder and is left as it
    is."""
    if not key or len(key) < SHORTEST_SECRET:
        return text
    return _scrub_base64(_key_pattern(key).sub(REDACTED, text), key)


def readable_body(raw: str) -> str:
    """A JSON body as plain JSON (no ``\\/`` or ``\\uXXXX`` escapes, so what the server
    said reads as it said it), anything else as it came."""
    try:
        return json.dumps(json.loads(raw), ensure_ascii=False)
    except ValueError:
        return raw


def excerpt(raw: str, key: str | None, chars: int = EXCERPT_CHARS) -> str:
    """The start of a body, key scrubbed (before it is cut, so no part of the key is
    left at the cut), quoted as a Python string so that its ends are plain."""
    cleaned = scrub(raw, key)
    shown = cleaned[:chars] + ("…" if len(cleaned) > chars else "")
    return repr(shown)


def _url_parts(url: str) -> tuple[str, str, str, str, str]:
    """``url`` as (scheme with "://", credentials, the rest of its server and path, query,
    fragment), split by hand: ``urllib.parse`` raises on some malformed URLs (a bad port,
    an unclosed '['), and a message about a URL must never fail. The credentials are all
    up to the last '@' before the path ends, so a password with a '/' in it is all in
    them."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        scheme, rest = "", url
    rest, hash_sign, fragment = rest.partition("#")
    rest, question_mark, query = rest.partition("?")
    credentials, at, address = rest.rpartition("@")
    return (
        scheme + sep,
        credentials + at,
        address,
        question_mark + query,
        hash_sign + fragment,
    )


def redacted_url(url: str) -> str:
    """``url`` as messages show it: its credentials ("user:password@") as
    ``[credentials]@``, its query as ``?[query]``, its fragment as ``#[fragment]``."""
    scheme, credentials, address, query, fragment = _url_parts(url)
    return (
        scheme
        + ("[credentials]@" if credentials else "")
        + address
        + ("?[query]" if query else "")
        + ("#[fragment]" if fragment else "")
    )


def refuse_secrets_in_url(url: str, where: str) -> None:
    """Raise :class:`ConfigError` when ``url``, which names a server, holds credentials, a
    query or a fragment, saying what to use instead; the error shows the URL redacted.
    What a server's URL holds is written everywhere the server is named (run configs, the
    episode logs, table labels, run folder names, messages), so none of it may be secret;
    refused on load, nothing of it reaches any of those. A '@' in a path (which no server
    of the toolkit's needs) reads as credentials too: written ``%40``, it is accepted."""
    _, credentials, _, query, fragment = _url_parts(url)
    held, instead = [], []
    if credentials:
        held.append("credentials (user:password@)")
        instead.append(
            "the API key comes from the environment variable named by api_key_env (default "
            "OPENAI_API_KEY) and is sent as a bearer token"
        )
    if query:
        held.append("a query string")
        instead.append(
            "query parameters are not supported (fields to add to every request body go in "
            "extra_body)"
        )
    if fragment:
        held.append("a fragment")
        instead.append("a fragment is no part of a server's address")
    if held:
        raise ConfigError(
            f"{where} {redacted_url(url)!r} has {' and '.join(held)} in it, which would be "
            f"written wherever the server is named (configs, logs, labels, messages): "
            f"{'; '.join(instead)}"
        )
