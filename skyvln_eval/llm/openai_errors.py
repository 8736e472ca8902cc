"""What an OpenAI-compatible server's errors mean, for :mod:`.openai_backend`.

Errors are told apart by what the server says: 401 / 403 (:class:`LLMAuthError`), a
context overflow (:class:`LLMContextOverflowError`, not retried), 408, 409, 425, 429 and
5xx (transient, retried by the client), 400, 413 and 422 (the request refused for its
content: the model's failure), other 4xx (:class:`LLMEndpointError`: no such route or
model, not retried, and no answer of the model). Two refusals are not the call's
error but a reason to send it again in another form: a response format the server cannot
do (:class:`FormatRefused`: HTTP 400, or a 5xx whose body names the format, the schema or
a grammar, unless a 400 clearly names another cause) and a decoding parameter the model
does not take (:class:`ParameterRefused`: HTTP 400 naming it).
"""

from __future__ import annotations

import contextlib
import datetime
import email.utils
import math
import re
import time
from dataclasses import dataclass
from typing import Any, Final

from skyvln_eval.errors import (
    LLMAuthError,
    LLMContextOverflowError,
    LLMEndpointError,
    LLMError,
    LLMQuotaError,
    LLMTransientError,
)
from skyvln_eval.llm.redact import readable_body
from skyvln_eval.llm.types import RefusedRequest, StructuredLevel

#: HTTP statuses that ask to try again later (RFC 9110: 408 Request Timeout, 409
#: Conflict, 425 Too Early, 429 Too Many Requests), as 5xx do; the openai client retries
#: them too.
TRY_AGAIN_STATUSES = frozenset({408, 409, 425, 429})
#: HTTP statuses that refuse a request for its content (a prompt too large, a field the
#: server does not take): the model's or the request's failure, not the endpoint's.
CONTENT_REFUSED_STATUSES = frozenset({400, 413, 422})

#: Words in an error body that say the request is longer than the model's context.
_CONTEXT_OVERFLOW = re.compile(
    r"context length|context window|maximum context|context_length_exceeded|too many tokens"
    r"|prompt is too long|exceeds? the (?:model'?s? )?(?:maximum )?context|n_ctx",
    re.IGNORECASE,
)
#: Words in an error body that say the server cannot do the requested response format.
_FORMAT_WORDS = re.compile(
    r"response[_ ]format|json[_ ]schema|json[_ ]object|schema|grammar|structured output"
    r"|guided[_ ](?:decoding|json)",  # vLLM's words for its constrained decoding
    re.IGNORECASE,
)
#: Request fields other than the response format an error body may name as its cause (a
#: model not found, a budget too large): a 400 naming one of them is no format refusal.
_OTHER_FIELDS = re.compile(
    r"\b(?:model|max_tokens|max_completion_tokens|messages|temperature|top_p|seed|stop)\b",
    re.IGNORECASE,
)
#: A server refusing the system message (OpenAI's o1-mini: "Unsupported value:
#: 'messages[0].role' does not support 'system' with this model"; Gemma chat templates:
#: "System role not supported").
_SYSTEM_ROLE_REFUSED = re.compile(
    r"role'? does not support 'system'|system role (?:is )?not supported", re.IGNORECASE
)
#: How OpenAI (and servers that copy its errors) names a parameter the model does not take,
#: for bodies without the ``param`` field.
_UNSUPPORTED = re.compile(r"unsupported (?:parameter|value):\s*'(\w+)'", re.IGNORECASE)


def retry_after_s(headers: Any, now: float | None = None) -> float | None:
    """How long the server asks us to wait, from its headers: OpenAI's ``retry-after-ms``,
    else ``Retry-After`` in seconds or as an HTTP date (RFC 9110; a date in the past is 0);
    ``None`` when it says nothing readable (our own backoff then decides)."""
    if headers is None:
        return None
    with contextlib.suppress(TypeError, ValueError):
        milliseconds = headers.get("retry-after-ms")
        if milliseconds is not None and math.isfinite(float(milliseconds)):
            return float(milliseconds) / 1000.0
    value = headers.get("retry-after")
    if value is None:
        return None
    with contextlib.suppress(TypeError, ValueError):
        seconds = float(value)
        return seconds if math.isfinite(seconds) else None
    with contextlib.suppress(TypeError, ValueError, IndexError, OverflowError):
        when = email.utils.parsedate_to_datetime(value)
        if when.tzinfo is None:  # "-0000": HTTP dates are in GMT
            when = when.replace(tzinfo=datetime.UTC)
        return max(0.0, when.timestamp() - (time.time() if now is None else now))
    return None


#: OpenAI's error codes (and types) of a 429 that no wait mends: the account's quota or
#: billing limit is used up, not a rate limit.
BILLING_CODES: Final = frozenset(
    {"insufficient_quota", "billing_hard_limit_reached", "billing_not_active"}
)


def quota_error(error: Any, body: str, where: str) -> LLMQuotaError | None:
    """The run-stopping error of a 429 whose ``code`` or ``type`` names the account's quota
    or billing (see :data:`BILLING_CODES`), else ``None`` (a rate limit: retried)."""
    said = {str(getattr(error, name, "") or "") for name in ("code", "type")}
    named = sorted(said & BILLING_CODES)
    if not named:
        return None
    return LLMQuotaError(
        f"{where} refused the request: the account's quota or billing limit is used up "
        f"(HTTP 429 {named[0]}: {brief(body)}); no retry helps: add credit or raise the "
        "limit in the provider's billing settings, then run again"
    )


#: A duration as OpenAI writes it ("6m0s", "1s", "20ms", "41.724s", "1h2m3.5s").
_DURATION = re.compile(
    r"(?:(\d+(?:\.\d+)?)h)?(?:(\d+(?:\.\d+)?)m(?!s))?"
    r"(?:(\d+(?:\.\d+)?)s)?(?:(\d+(?:\.\d+)?)ms)?"
)
#: OpenAI's rate-limit message: "... Please try again in 41.724s." / "in 20ms".
_TRY_AGAIN_IN = re.compile(r"try again in ((?:\d+(?:\.\d+)?(?:ms|h|m|s))+)", re.IGNORECASE)


def duration_s(text: str) -> float | None:
    """Seconds of a duration written as OpenAI writes them (``None``: not one)."""
    found = _DURATION.fullmatch(text.strip())
    if found is None or not any(found.groups()):
        return None
    hours, minutes, seconds, milliseconds = (float(g or 0) for g in found.groups())
    return hours * 3600 + minutes * 60 + seconds + milliseconds / 1000


def rate_limit_wait_s(headers: Any, message: str) -> float | None:
    """How long a 429 without Retry-After says to wait: OpenAI's "Please try again in
    41.724s" in its message (the limit that was hit), else the later of its
    ``x-ratelimit-reset-requests`` / ``x-ratelimit-reset-tokens`` headers whose limit is
    used up (all of them when none says so); ``None``: it says nothing (our backoff)."""
    said = _TRY_AGAIN_IN.search(message)
    if said is not None and (seconds := duration_s(said.group(1))) is not None:
        return seconds
    if headers is None:
        return None
    resets: dict[str, float] = {}
    for limit in ("requests", "tokens"):
        value = headers.get(f"x-ratelimit-reset-{limit}")
        seconds = None if value is None else duration_s(str(value))
        if seconds is not None:
            resets[limit] = seconds
    used_up = [s for k, s in resets.items() if headers.get(f"x-ratelimit-remaining-{k}") == "0"]
    waits = used_up or list(resets.values())
    return max(waits) if waits else None


def body_text(error: Any) -> str:
    """What the server said: the parsed error message and the raw body, as one string."""
    parts = [str(getattr(error, "message", "") or "")]
    response = getattr(error, "response", None)
    with contextlib.suppress(Exception):  # a streamed or closed body: the message is all
        parts.append(readable_body(response.text) if response is not None else "")
    return " ".join(p for p in parts if p)


def timed_out(endpoint: str, timeout_s: float) -> LLMTransientError:
    return LLMTransientError(
        f"{endpoint}: no complete answer within {timeout_s:.3g} s (timeout, connect to last byte)"
    )


class Refused(Exception):
    """The server turned the request down for its form; the call goes on in another."""

    def record(
        self,
        what: str,
        started: float,
        level: StructuredLevel | None,
        unsent: tuple[str, ...],
    ) -> RefusedRequest:
        """This refusal as a request of its own, timed from ``started`` (perf_counter)."""
        return RefusedRequest(
            error=f"{what} ({self})",
            latency_s=time.perf_counter() - started,
            structured_output=level,
            server_defaults=unsent,
        )


#: Where a server's error body turns into the Python traceback some servers append
#: (llama-cpp-python's does): what the server said comes before it.
_TRACEBACK = re.compile(r"Traceback \(most recent call last\)|\n\s*File \"")


def brief(body: str, chars: int = 300) -> str:
    """What an error body says, for a message on one line: up to any traceback, whitespace
    runs as one space, at most ``chars`` characters (``…`` marks a cut)."""
    said = " ".join(_TRACEBACK.split(body, maxsplit=1)[0].split())
    return said if len(said) <= chars else said[: chars - 1] + "…"


#: OpenAI's words for a schema its strict mode cannot take (``Invalid schema for
#: response_format 'subgoals': ... array schema missing items``): that schema's fault, not
#: the endpoint's, whose other schemas it still takes.
_ONE_SCHEMA = re.compile(r"invalid schema for response_format", re.IGNORECASE)


class FormatRefused(Refused):
    """The server cannot do the response format of this request (the body says why).
    ``named``: the body names the format (its words), not a bare 400 naming nothing;
    ``one_schema``: it refused this request's schema, not the level for every schema."""

    def __init__(self, status: int, body: str) -> None:
        super().__init__(f"HTTP {status}: {brief(body)}")
        self.named = bool(_FORMAT_WORDS.search(body))
        self.one_schema = bool(_ONE_SCHEMA.search(body))


class ParameterRefused(Refused):
    """The model does not take one decoding parameter of this request (HTTP 400)."""

    def __init__(self, parameter: str, body: str) -> None:
        super().__init__(f"HTTP 400: {brief(body)}")
        self.parameter = parameter


def refused_parameter(error: Any, body: str, request: dict[str, Any]) -> str | None:
    """The decoding parameter of ``request`` a 400 says the model does not take, if any:
    named in an "Unsupported parameter / value" message, or in OpenAI's ``param`` field of
    an ``unsupported_*`` error (not, say, a budget too large, which no renaming fixes)."""
    found = _UNSUPPORTED.search(body)
    named = found.group(1) if found else None
    if named is None and str(getattr(error, "code", "") or "").startswith("unsupported_"):
        named = getattr(error, "param", None)
    if isinstance(named, str) and named in request and named != "response_format":
        return named
    return None


@dataclass(frozen=True)
class Asker:
    """Who sent a refused request, as its error messages name it: the endpoint (``where``,
    no secret in it), the model, the key's environment variable and whether the request
    had a system role."""

    where: str
    model: str
    api_key_env: str
    system_role: bool


def status_error(error: Any, body: str, request: dict[str, Any], asker: Asker) -> Exception:
    """The error an HTTP error status of the openai client (``error``, with the server's
    scrubbed ``body``) stands for, given the ``request`` it answered."""
    status = int(error.status_code)
    has_format = "response_format" in request
    excerpt = brief(body)
    if status in (401, 403):
        return LLMAuthError(
            f"{asker.where} refused the credentials (HTTP {status}: {excerpt}); check "
            f"the API key in the environment variable {asker.api_key_env}"
        )
    if _CONTEXT_OVERFLOW.search(body) and status < 500:
        return LLMContextOverflowError(
            f"the prompt does not fit the model's context (HTTP {status}: {excerpt})"
        )
    refused = refused_parameter(error, body, request) if status == 400 else None
    if refused is not None:
        return ParameterRefused(refused, body)
    if status < 500 and asker.system_role and _SYSTEM_ROLE_REFUSED.search(body):
        return LLMError(
            f"request refused (HTTP {status}: {excerpt}); this model takes no system "
            "role: set system_role: false in its backend config"
        )
    if has_format and status == 400 and _names_another_cause(error, body, asker.model):
        # Stepping down would not help and would leave the endpoint at a lower level for
        # the rest of the process: the server's words are the error.
        return LLMError(
            f"request refused (HTTP 400: {excerpt}); the server names no structured-output "
            "format as the cause, so the request was not sent again at a lower level (if "
            "the format is the cause, pin one in the backend config: structured_output: "
            "json_object, or prompt)"
        )
    if has_format and (
        status == 400
        # 422: a request validator (FastAPI servers) naming the field it does not take.
        or ((status == 422 or status >= 500) and _FORMAT_WORDS.search(body))
    ):
        return FormatRefused(status, body)
    if status >= 500 or status in TRY_AGAIN_STATUSES:
        what = "server error" if status >= 500 else "try again later"
        return LLMTransientError(
            f"{what} (HTTP {status}: {excerpt})", retry_after_s(error.response.headers)
        )
    if status in CONTENT_REFUSED_STATUSES:
        return LLMError(f"request refused (HTTP {status}: {excerpt})")
    return LLMEndpointError(
        f"{asker.where} cannot serve the request (HTTP {status}: {excerpt}); check its "
        f"base_url and that it serves the model {asker.model!r}"
    )


def _names_another_cause(error: Any, body: str, model: str) -> bool:
    """Whether a 400 clearly names a cause other than the response format: OpenAI's
    ``param`` field, or a request field or the model's name in the body, and nothing
    about the format. A 400 that names nothing is taken for a format refusal."""
    if _FORMAT_WORDS.search(body):
        return False
    param = getattr(error, "param", None)
    if isinstance(param, str) and param and param != "response_format":
        return True
    return bool(_OTHER_FIELDS.search(body)) or model in body
