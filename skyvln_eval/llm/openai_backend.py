"""Any OpenAI-compatible chat-completions server (OpenAI, vLLM, Ollama, llama.cpp).

The official ``openai`` client (extra ``openai``) is imported on first use, never at
toolkit import. The API key is read from the environment variable ``api_key_env`` when
the client is made and handed to the client only: it is not stored on the backend, not
part of its identity or of any cache key, and is scrubbed from every error message this
module raises.

Structured output is negotiated per endpoint (:mod:`.negotiation`): a call that asks for
a JSON schema is sent at the most constrained level the server is not known to refuse
(``json_schema`` strict, then ``json_object`` with the schema, plain ``json_object``,
then none: the prompt asks for JSON and the parser checks it). A refusal (HTTP 400, or a
5xx whose body names the response format, the schema or a grammar) moves one level down
at once, except a 400 whose body clearly names another cause (OpenAI's ``param``, a
request field such as the model or ``max_tokens``, the model's name) and nothing about
the format: that is the call's error, with the server's words, and the endpoint keeps its
level. Refused credentials (401 / 403) are never a format refusal. The level that
answers is remembered for the endpoint for the rest of the process and recorded with
every call. ``structured_output`` pins a level instead. Each
refused request goes back to the client with its own time (``Completion.refused``, or the
error's ``refused`` when the call fails after it), which records it as an attempt: every
request sent is one record.

A model that refuses a decoding parameter (HTTP 400 naming it, as OpenAI's reasoning
models do for ``max_tokens``, ``temperature``, ``top_p``, ``stop``) gets the request again
at once without it: the budget as ``max_completion_tokens``, the others left to the
server's defaults. The endpoint keeps that for the rest of the process (:mod:`.negotiation`)
and every answer records which parameters were not sent.

Errors are told apart by what the server says: 401 / 403 (:class:`LLMAuthError`), a
context overflow (:class:`LLMContextOverflowError`, not retried), 429 and 5xx
(transient, retried by the client), other 4xx (refused). The client's own retries are off
(``max_retries=0``): :class:`~skyvln_eval.llm.client.LLMClient` retries, so that every
fault is recorded.

``timeout_s`` bounds a whole attempt, from connect to last byte. The HTTP library's own
timeouts bound each network operation, so a server that sends its answer one byte at a
time, each within them, could hold a call for as long as it likes: the request therefore
runs in a helper thread, and the caller stops waiting when the time is up. The abandoned
request's client is closed (its next read fails) and never used again.

``extra_body`` adds fields of the user's to every request body (``reasoning_effort`` of
OpenAI's reasoning models, a server's sampling options); they are part of the backend's
identity, so answers cached with other fields are not reused. The fields the toolkit
sets itself (model, messages, decoding, response format) cannot be given there.

Some models have no system role (Gemma), and some servers drop a system message without
a word: llama-cpp-python's ``gemma`` chat format leaves it out of the prompt. With
``system_role=False`` the system text opens the first user message instead, as Gemma's
own chat template places it, so the instructions reach the model either way.
"""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import datetime
import email.utils
import functools
import json
import logging
import math
import os
import re
import ssl
import threading
import time
import urllib.parse
from collections.abc import Sequence
from typing import Any, Final

from skyvln_eval.errors import (
    ConfigError,
    LLMAuthError,
    LLMContextOverflowError,
    LLMError,
    LLMTransientError,
    MissingExtraError,
)
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.negotiation import (
    STRUCTURED_SETTINGS,
    RequestAdaptation,
    StructuredSetting,
    adaptation,
    negotiated_level,
    next_level,
    remember_adaptation,
    remember_level,
    response_format,
)
from skyvln_eval.llm.prices import VENDOR_SERVERS
from skyvln_eval.llm.redact import excerpt, readable_body, scrub
from skyvln_eval.llm.types import (
    Completion,
    GenerationConfig,
    Message,
    RefusedRequest,
    StructuredLevel,
)

log = logging.getLogger(__name__)

OPENAI_BASE_URL: Final = VENDOR_SERVERS["openai"]
#: Words in an error body that say the request is longer than the model's context.
_CONTEXT_OVERFLOW = re.compile(
    r"context length|context window|maximum context|context_length_exceeded|too many tokens"
    r"|prompt is too long|exceeds? the (?:model'?s? )?(?:maximum )?context|n_ctx",
    re.IGNORECASE,
)
#: Words in an error body that say the server cannot do the requested response format.
_FORMAT_WORDS = re.compile(
    r"response[_ ]format|json[_ ]schema|json[_ ]object|schema|grammar|structured output",
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
#: Where the loopback test server finds the task data of a request (only when asked for).
TASK_DATA_FIELD: Final = "skyvln_task_data"
#: Request fields the toolkit sets (decoding settings have their own config fields); a
#: ``stream`` or ``n`` of the user's would break the answer's parsing.
RESERVED_FIELDS: Final = frozenset(
    {
        "model",
        "messages",
        "temperature",
        "top_p",
        "max_tokens",
        "max_completion_tokens",
        "seed",
        "stop",
        "response_format",
        "stream",
        "n",
        "timeout",
        TASK_DATA_FIELD,
    }
)


def checked_extra_body(extra_body: Any) -> dict[str, Any]:
    """``extra_body`` as a plain JSON object, or a :class:`ConfigError` saying what is wrong."""
    if not isinstance(extra_body, dict):
        raise ConfigError(f"extra_body must be a mapping of request fields, got {extra_body!r}")
    taken = sorted(set(extra_body) & RESERVED_FIELDS)
    if taken:
        raise ConfigError(
            f"extra_body cannot set {', '.join(taken)}: the toolkit sets these fields "
            "(decoding settings have their own config fields: temperature, top_p, max_tokens, "
            "budgets, seed)"
        )
    try:
        return dict(json.loads(json.dumps(extra_body, sort_keys=True, allow_nan=False)))
    except (TypeError, ValueError) as error:
        raise ConfigError(f"extra_body must be plain JSON: {error}") from None


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


def _body_text(error: Any) -> str:
    """What the server said: the parsed error message and the raw body, as one string."""
    parts = [str(getattr(error, "message", "") or "")]
    response = getattr(error, "response", None)
    with contextlib.suppress(Exception):  # a streamed or closed body: the message is all
        parts.append(readable_body(response.text) if response is not None else "")
    return " ".join(p for p in parts if p)


def _timed_out(endpoint: str, timeout_s: float) -> LLMTransientError:
    return LLMTransientError(
        f"{endpoint}: no complete answer within {timeout_s:.3g} s (timeout, connect to last byte)"
    )


#: Idle HTTP clients per (server, key), shared by every backend of the process: agents are
#: built per episode, and a client (with its connection pool) is costly to make. The key
#: lives only inside the clients, as when each backend made its own.
_idle_clients: dict[tuple[str, str | None], list[Any]] = {}
_idle_lock = threading.Lock()


_tls_lock = threading.Lock()


def _tls_context() -> ssl.SSLContext | bool:
    """One verifying TLS context for every client of the process, made as the HTTP library
    makes its default one: each client would otherwise load the certificate store again
    (~30 ms of CPU, paid by every episode thread that starts a client). Made under a lock:
    episode threads that start together would otherwise all miss the cache and each make
    one, at once."""
    with _tls_lock:
        return _made_tls_context()


@functools.lru_cache(maxsize=1)
def _made_tls_context() -> ssl.SSLContext | bool:
    import importlib

    for name in ("httpx2", "httpx"):  # recent openai releases use httpx2, older ones httpx
        try:
            http = importlib.import_module(name)
        except ImportError:
            continue
        make = getattr(http, "create_ssl_context", None)
        if make is not None:
            context: ssl.SSLContext = make()
            return context
    return True  # the client's own default


def without_system_role(messages: Sequence[Message]) -> list[Message]:
    """``messages`` for a model without a system role: the system messages' text opens the
    first user message (a user message of its own when there is none)."""
    system = "\n\n".join(m.text for m in messages if m.role == "system")
    rest = [m for m in messages if m.role != "system"]
    if not system:
        return rest
    first_user = next((i for i, m in enumerate(rest) if m.role == "user"), None)
    if first_user is None:
        return [Message("user", system), *rest]
    opened = dataclasses.replace(rest[first_user], text=f"{system}\n\n{rest[first_user].text}")
    return [*rest[:first_user], opened, *rest[first_user + 1 :]]


def _usage(response: Any) -> tuple[int | None, int | None]:
    """The prompt and completion tokens a response reports (``None``: not reported, or
    not a count: see below)."""
    usage = getattr(response, "usage", None)
    counts = []
    for name in ("prompt_tokens", "completion_tokens"):
        value = getattr(usage, name, None) if usage is not None else None
        with contextlib.suppress(TypeError, ValueError):
            value = None if value is None else int(value)
        counts.append(value if isinstance(value, int) and value >= 0 else None)
    if counts[0] == 0:
        # A prompt was sent, so a server saying 0 prompt tokens counts nothing (some
        # gateways fill the usage object with zeros): taken at its word, the call would
        # cost a known $0 and top the cost ranking. Neither count of it is believed.
        return None, None
    return counts[0], counts[1]


class _Refused(Exception):
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


class _FormatRefused(_Refused):
    """The server cannot do the response format of this request (the body says why)."""

    def __init__(self, status: int, body: str) -> None:
        super().__init__(f"HTTP {status}: {body[:300]}")


class _ParameterRefused(_Refused):
    """The model does not take one decoding parameter of this request (HTTP 400)."""

    def __init__(self, parameter: str, body: str) -> None:
        super().__init__(f"HTTP 400: {body[:300]}")
        self.parameter = parameter


def _refused_parameter(error: Any, body: str, request: dict[str, Any]) -> str | None:
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


class OpenAIBackend(LLMBackend):
    """Chat completions over the OpenAI protocol; see the module docstring.

    ``send_task_data`` adds each request's task data (see :mod:`.taskdata`) to the body
    as ``skyvln_task_data``, for test servers that stand in for a model (the loopback
    server answers from it as the rule backend would). Off by default: real servers
    never receive it, and OpenAI refuses unknown fields.

    ``system_role=False`` sends system messages as the start of the first user message
    (see the module docstring); the identity says so, so cached answers of the two forms
    are kept apart.
    """

    name = "openai"
    kind = "llm"

    def __init__(
        self,
        model: str | None = None,
        base_url: str | None = None,
        api_key_env: str = "OPENAI_API_KEY",
        takes_images: bool = False,
        structured_output: StructuredSetting = "auto",
        send_task_data: bool = False,
        system_role: bool = True,
        extra_body: dict[str, Any] | None = None,
    ) -> None:
        if not model:
            raise ConfigError(
                "the openai backend needs a model: 'openai:<model>', e.g. 'openai:gpt-4o'"
            )
        if structured_output not in STRUCTURED_SETTINGS:
            raise ConfigError(
                f"structured_output must be one of {', '.join(STRUCTURED_SETTINGS)}, "
                f"got {structured_output!r}"
            )
        self.model = model
        self.base_url = (base_url or OPENAI_BASE_URL).rstrip("/")
        self.api_key_env = api_key_env
        self.takes_images = takes_images
        self.structured_output = structured_output
        self.send_task_data = send_task_data
        self.system_role = system_role
        self.extra_body = checked_extra_body(extra_body or {})
        # Imported now, not in the first call, whose deadline would pay for it (~0.5 s).
        try:
            import openai  # noqa: F401
        except ImportError as error:  # pragma: no cover - the test extra installs openai
            raise MissingExtraError("the openai backend", "openai", str(error)) from error

    def identity(self) -> dict[str, Any]:
        identity: dict[str, Any] = {
            "backend": self.name,
            "model": self.model,
            "base_url": self.base_url,
        }
        if not self.system_role:  # the model sees other prompts: other cache keys
            identity["system_role"] = False
        if self.extra_body:  # other request fields, other answers
            identity["extra_body"] = self.extra_body
        return identity

    @property
    def endpoint(self) -> str:
        """``openai:<model>@<base_url>``: how messages and provenance name the endpoint."""
        return f"openai:{self.model}@{self.base_url}"

    def structured_level(self) -> StructuredLevel:
        """The level the next schema-constrained call starts at."""
        if self.structured_output != "auto":
            return self.structured_output
        return negotiated_level(self.endpoint) or "json_schema"

    def _secret(self) -> str | None:
        return os.environ.get(self.api_key_env) or None

    def _scrub(self, text: str) -> str:
        return scrub(text, self._secret())

    def _where(self) -> str:
        """:attr:`endpoint` for messages: a password or query in the URL left out, the API
        key never in it."""
        url = urllib.parse.urlsplit(self.base_url)
        netloc = url.netloc
        if url.password:
            netloc = netloc.replace(f":{url.password}@", ":[password]@", 1)
        shown = urllib.parse.urlunsplit((url.scheme, netloc, url.path, "", ""))
        return self._scrub(f"openai:{self.model}@{shown}{'?[query]' if url.query else ''}")

    def _checkout(self) -> Any:
        """An idle client, or a new one: a client serves one request at a time, so that
        one abandoned at its deadline can be closed without touching another's."""
        secret = self._secret()
        with _idle_lock:
            idle = _idle_clients.get((self.base_url, secret))
            if idle:
                return idle.pop()
        try:
            import openai
        except ImportError as error:  # pragma: no cover - the test extra installs openai
            raise MissingExtraError("the openai backend", "openai", str(error)) from error
        if secret is None and self.base_url == OPENAI_BASE_URL:
            raise LLMAuthError(
                f"{self._where()}: set the environment variable {self.api_key_env} to the API key"
            )
        # Local servers usually accept any key; the client insists on one.
        return openai.OpenAI(
            api_key=secret or "unused",
            base_url=self.base_url,
            max_retries=0,
            http_client=openai.DefaultHttpxClient(verify=_tls_context()),
        )

    def _checkin(self, client: Any) -> None:
        with _idle_lock:
            _idle_clients.setdefault((self.base_url, self._secret()), []).append(client)

    def _payload(self, messages: Sequence[Message]) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for message in messages if self.system_role else without_system_role(messages):
            if message.images and self.takes_images:
                parts: list[dict[str, Any]] = [{"type": "text", "text": message.text}]
                for image in message.images:
                    encoded = base64.b64encode(image.data).decode("ascii")
                    url = f"data:{image.mime_type};base64,{encoded}"
                    parts.append({"type": "image_url", "image_url": {"url": url}})
                out.append({"role": message.role, "content": parts})
            else:
                out.append({"role": message.role, "content": message.text})
        return out

    def _request(self, messages: Sequence[Message], config: GenerationConfig) -> dict[str, Any]:
        kwargs: dict[str, Any] = {
            "model": self.model,
            "messages": self._payload(messages),
            "temperature": config.temperature,
            "top_p": config.top_p,
            "max_tokens": config.max_tokens,
            "timeout": config.timeout_s,
        }
        if config.seed is not None:
            kwargs["seed"] = config.seed
        if config.stop:
            kwargs["stop"] = list(config.stop)
        extra = dict(self.extra_body)
        if self.send_task_data:
            data = next((m.task_data for m in reversed(messages) if m.task_data), None)
            if data is not None:
                extra[TASK_DATA_FIELD] = data
        if extra:
            kwargs["extra_body"] = extra
        return kwargs

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        """One answer, after as many requests as negotiation takes (see the module
        docstring). The completion's latency is the answered request's time; each request
        turned down for its form before it is listed in ``refused`` with its own time (and
        attached to the error, when the call fails after some), so none goes unrecorded."""
        kwargs = self._request(messages, config)
        level: StructuredLevel | None = None
        if config.json_schema is not None:
            level = self.structured_level()
        ends_at = time.monotonic() + config.timeout_s
        adapted = adaptation(self.endpoint)
        refused: list[RefusedRequest] = []
        try:
            while True:
                request = adapted.apply(kwargs)
                if level is not None:
                    fmt = response_format(level, config.json_schema or {}, config.schema_name)
                    if fmt is not None:
                        request["response_format"] = fmt
                unsent = tuple(sorted(p for p in adapted.server_defaults if p in kwargs))
                started = time.perf_counter()
                try:
                    response, body = self._create_by(ends_at, request)
                    break
                except _FormatRefused as refusal:
                    lower = self._step_down(level, refusal)  # raises when nothing is left
                    what = f"structured output level {level!r} refused"
                    refused.append(refusal.record(what, started, level, unsent))
                    level = lower
                    remember_level(self.endpoint, level)  # known now, whatever the next does
                except _ParameterRefused as refusal:
                    found = self._adapt(adapted, refusal)  # raises when nothing is left
                    what = f"parameter {refusal.parameter!r} refused"
                    refused.append(refusal.record(what, started, level, unsent))
                    adapted = found
                    remember_adaptation(self.endpoint, adapted)
            latency = time.perf_counter() - started  # the answered request's own time
            return self._completion(response, body, latency, level, unsent, tuple(refused))
        except LLMError as error:
            # The requests refused before this failure were sent all the same: the client
            # records them from here.
            error.refused = tuple(refused)
            raise

    def _adapt(self, adapted: RequestAdaptation, refusal: _ParameterRefused) -> RequestAdaptation:
        found = adapted.refusing(refusal.parameter)
        if found is None:
            raise LLMError(self._scrub(f"{self._where()}: request refused ({refusal})"))
        change = (
            "the budget goes as max_completion_tokens"
            if found.completion_tokens_field != adapted.completion_tokens_field
            else "calls go without it, at the server's default (recorded with each call)"
        )
        log.warning(
            "%s does not take %s (%s); %s",
            self._where(),
            refusal.parameter,
            self._scrub(str(refusal)),
            change,
        )
        return found

    def _step_down(self, level: StructuredLevel | None, refusal: _FormatRefused) -> StructuredLevel:
        if level is None:  # pragma: no cover - no format was sent, so none can be refused
            raise LLMError(self._scrub(f"{self._where()}: request refused ({refusal})"))
        if self.structured_output != "auto":
            raise LLMError(
                self._scrub(
                    f"{self._where()} refused structured output level {level!r}, pinned by "
                    f"structured_output in the backend config ({refusal}); use 'auto' to "
                    "negotiate a level the server accepts"
                )
            )
        lower = next_level(level)
        if lower is None:  # pragma: no cover - the last level sends no format
            raise LLMError(self._scrub(f"{self._where()}: request refused ({refusal})"))
        log.warning(
            "%s refused structured output level %s (%s); trying %s",
            self._where(),
            level,
            self._scrub(str(refusal)),
            lower,
        )
        return lower

    def _create_by(self, ends_at: float, kwargs: dict[str, Any]) -> tuple[Any, str]:
        """One request, answered in full before ``ends_at`` (``time.monotonic``) or given up:
        the parsed answer and its body."""
        timeout_s = kwargs["timeout"]
        client = self._checkout()
        left = ends_at - time.monotonic()
        if left <= 0.0:
            self._checkin(client)
            raise _timed_out(self._where(), timeout_s)
        outcome: dict[str, Any] = {}
        done = threading.Event()

        def send() -> None:
            try:
                outcome["response"] = self._create(client, kwargs | {"timeout": left}, timeout_s)
            except BaseException as error:  # handed to the caller below
                outcome["error"] = error
            finally:
                done.set()

        threading.Thread(target=send, name="skyvln-llm-request", daemon=True).start()
        if not done.wait(left):
            # Closing may wait for the stuck read, so it is done aside, never waited for.
            threading.Thread(target=client.close, name="skyvln-llm-close", daemon=True).start()
            raise _timed_out(self._where(), timeout_s)
        self._checkin(client)
        if "error" in outcome:
            raise outcome["error"]
        answered: tuple[Any, str] = outcome["response"]
        return answered

    def _create(self, client: Any, kwargs: dict[str, Any], timeout_s: float) -> tuple[Any, str]:
        """The parsed answer and the body it was parsed from (for errors that show it)."""
        import openai

        try:
            raw = client.chat.completions.with_raw_response.create(**kwargs)
            return self._parsed(raw), raw.text
        except openai.RateLimitError as error:
            raise LLMTransientError(
                f"rate limited (HTTP 429): {self._scrub(_body_text(error))[:200]}",
                retry_after_s(error.response.headers),
            ) from None
        except openai.APITimeoutError:
            raise _timed_out(self._where(), timeout_s) from None
        except openai.APIConnectionError as error:
            # A dead or unreachable endpoint: named, since a run may call several.
            raise LLMTransientError(
                self._scrub(f"{self._where()}: connection failed or body cut short: {error}")
            ) from None
        except openai.APIStatusError as error:
            raise self._status_error(error, kwargs) from None
        except openai.APIResponseValidationError as error:
            raise LLMTransientError(
                self._scrub(f"malformed response: {error}: ")
                + excerpt(error.response.text, self._secret())
            ) from None

    def _parsed(self, raw: Any) -> Any:
        """The completion object of a raw HTTP 200, or an error that says what came back
        instead (a gateway's HTML page, a body that is not valid JSON), with its start."""
        kind = raw.headers.get("content-type") or "none"
        try:
            response = raw.parse()
        except ValueError as error:  # JSONDecodeError among them
            shown = excerpt(raw.text, self._secret())
            raise LLMTransientError(
                f"malformed response: the body is not valid JSON ({self._scrub(str(error))}; "
                f"content-type {kind}): {shown}"
            ) from None
        if response is None or isinstance(response, str | bytes):
            # The client parses JSON only when the content type says JSON; anything else
            # comes back as the body's text.
            raise LLMTransientError(
                f"malformed response: the body is not JSON (content-type {kind}): "
                f"{excerpt(raw.text, self._secret())}"
            )
        return response

    def _status_error(self, error: Any, request: dict[str, Any]) -> Exception:
        status = int(error.status_code)
        body = self._scrub(_body_text(error))
        has_format = "response_format" in request
        excerpt = body[:300]
        if status in (401, 403):
            return LLMAuthError(
                f"{self._where()} refused the credentials (HTTP {status}: {excerpt}); check "
                f"the API key in the environment variable {self.api_key_env}"
            )
        if _CONTEXT_OVERFLOW.search(body) and status < 500:
            return LLMContextOverflowError(
                f"the prompt does not fit the model's context (HTTP {status}: {excerpt})"
            )
        refused = _refused_parameter(error, body, request) if status == 400 else None
        if refused is not None:
            return _ParameterRefused(refused, body)
        if status < 500 and self.system_role and _SYSTEM_ROLE_REFUSED.search(body):
            return LLMError(
                f"request refused (HTTP {status}: {excerpt}); this model takes no system "
                "role: set system_role: false in its backend config"
            )
        if has_format and status == 400 and self._names_another_cause(error, body):
            # Stepping down would not help and would leave the endpoint at a lower level for
            # the rest of the process: the server's words are the error.
            return LLMError(
                f"request refused (HTTP 400: {excerpt}); the server names no structured-output "
                "format as the cause, so the request was not sent again at a lower level"
            )
        if has_format and (status == 400 or (status >= 500 and _FORMAT_WORDS.search(body))):
            return _FormatRefused(status, body)
        if status >= 500:
            return LLMTransientError(
                f"server error (HTTP {status}: {excerpt})", retry_after_s(error.response.headers)
            )
        return LLMError(f"request refused (HTTP {status}: {excerpt})")

    def _names_another_cause(self, error: Any, body: str) -> bool:
        """Whether a 400 clearly names a cause other than the response format: OpenAI's
        ``param`` field, or a request field or the model's name in the body, and nothing
        about the format. A 400 that names nothing is taken for a format refusal."""
        if _FORMAT_WORDS.search(body):
            return False
        param = getattr(error, "param", None)
        if isinstance(param, str) and param and param != "response_format":
            return True
        return bool(_OTHER_FIELDS.search(body)) or self.model in body

    def _completion(
        self,
        response: Any,
        body: str,
        latency_s: float,
        level: StructuredLevel | None,
        server_defaults: tuple[str, ...],
        refused: tuple[RefusedRequest, ...] = (),
    ) -> Completion:
        # Usage first: a response that fails below may still say what it billed, and the
        # failed attempt's record counts it.
        prompt_tokens, completion_tokens = _usage(response)
        try:
            choice = response.choices[0]
            text = choice.message.content or ""
            # As the server said it: None when it gave no reason (not "stop", which would
            # say the model ended its answer itself).
            reason = getattr(choice, "finish_reason", None)
            finish = None if reason is None else str(reason)
            declined = getattr(choice.message, "refusal", None)
            if not text and isinstance(declined, str) and declined:
                # OpenAI's structured outputs: the model declined; its reason is the answer.
                text, finish = declined, "refusal"
        except (AttributeError, IndexError, TypeError) as error:
            # Gateways (OpenRouter) answer HTTP 200 with an error object when the model
            # behind them failed: what it says is the reason.
            # Anything else: the start of what came back.
            said = getattr(response, "error", None)
            if said:
                detail = self._scrub(json.dumps(said, default=str))[:300]
            else:
                detail = f"the body is {excerpt(readable_body(body), self._secret())}"
            fault = LLMTransientError(
                f"malformed response: no choices ({type(error).__name__}): {detail}"
            )
            fault.prompt_tokens, fault.completion_tokens = prompt_tokens, completion_tokens
            raise fault from None
        return Completion(
            text=text,
            backend=self.name,
            model=self.model,
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            latency_s=latency_s,
            finish_reason=finish,
            structured_output=level,
            server_defaults=server_defaults,
            refused=refused,
        )
