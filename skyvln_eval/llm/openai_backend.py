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

Errors are classified by :mod:`.openai_errors`. The client's own retries are off
(``max_retries=0``): :class:`~skyvln_eval.llm.client.LLMClient` retries, so that every
fault is recorded. The request body is made by :mod:`.openai_request`.

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

import functools
import json
import logging
import os
import ssl
import threading
import time
from collections.abc import Sequence
from typing import Any, Final

from skyvln_eval.errors import (
    ConfigError,
    LLMAuthError,
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
    refused_without_reason,
    remember_adaptation,
    remember_level,
    response_format,
)
from skyvln_eval.llm.openai_errors import (
    Asker,
    FormatRefused,
    ParameterRefused,
    body_text,
    brief,
    quota_error,
    rate_limit_wait_s,
    retry_after_s,
    status_error,
    timed_out,
)
from skyvln_eval.llm.openai_request import (
    TASK_DATA_FIELD,
    Usage,
    checked_extra_body,
    messages_payload,
    reported_usage,
)
from skyvln_eval.llm.prices import VENDOR_SERVERS
from skyvln_eval.llm.redact import (
    excerpt,
    readable_body,
    redacted_url,
    refuse_secrets_in_url,
    scrub,
)
from skyvln_eval.llm.types import (
    STRUCTURED_LEVELS,
    Completion,
    GenerationConfig,
    Message,
    RefusedRequest,
    StructuredLevel,
)

log = logging.getLogger(__name__)

OPENAI_BASE_URL: Final = VENDOR_SERVERS["openai"]
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
        model = self.checked_model(model)
        if structured_output not in STRUCTURED_SETTINGS:
            raise ConfigError(
                f"structured_output must be one of {', '.join(STRUCTURED_SETTINGS)}, "
                f"got {structured_output!r}"
            )
        if base_url is not None:  # as LLMConfig refuses it, for backends made without one
            refuse_secrets_in_url(base_url, "base_url")
        self.model = model
        self.base_url = (base_url or OPENAI_BASE_URL).rstrip("/")
        self.api_key_env = api_key_env
        self.takes_images = takes_images
        self.structured_output = structured_output
        self.send_task_data = send_task_data
        self.system_role = system_role
        self.extra_body = checked_extra_body(extra_body or {})
        # Imported now, not in the first call, whose deadline would pay for it (~0.5 s);
        # the TLS context and the request code too (~0.1-0.2 s once per process).
        try:
            import openai.resources.chat.completions  # noqa: F401
        except ImportError as error:  # pragma: no cover - the test extra installs openai
            raise MissingExtraError("the openai backend", "openai", str(error)) from error
        _tls_context()

    @classmethod
    def checked_model(cls, model: str | None) -> str:
        if not model:
            raise ConfigError(
                "the openai backend needs a model: 'openai:<model>', e.g. 'openai:gpt-4o'"
            )
        return model

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
        if self.send_task_data:  # a test server may answer from it: never the model's answers
            identity["task_data"] = True
        if self.structured_output != "auto":
            # A pinned level shapes the request (a response format, or none): its answers
            # are not another level's (negotiated ones, "auto", are keyed as before).
            identity["structured_output"] = self.structured_output
        return identity

    @property
    def endpoint(self) -> str:
        """``openai:<model>@<base_url>``: how messages and provenance name the endpoint."""
        return f"openai:{self.model}@{self.base_url}"

    def structured_level(self, schema_name: str | None = None) -> StructuredLevel:
        """The level the next schema-constrained call starts at: the endpoint's, or lower
        where the endpoint refused this schema itself (:meth:`schema_endpoint`)."""
        if self.structured_output != "auto":
            return self.structured_output
        known = [negotiated_level(self.endpoint) or "json_schema"]
        if schema_name is not None:
            known.append(negotiated_level(self.schema_endpoint(schema_name)) or "json_schema")
        return max(known, key=STRUCTURED_LEVELS.index)

    def schema_endpoint(self, schema_name: str) -> str:
        """How the level of one schema is kept, and named in provenance, once the endpoint
        refused that schema ("Invalid schema for response_format 'subgoals'") while its
        level stays good for the others."""
        return f"{self.endpoint} schema {schema_name}"

    def _secret(self) -> str | None:
        return os.environ.get(self.api_key_env) or None

    def _scrub(self, text: str) -> str:
        return scrub(text, self._secret())

    def _where(self) -> str:
        """:attr:`endpoint` for messages, the API key never in it (credentials and a query
        are refused in ``base_url``; were one there, it would be left out too)."""
        return self._scrub(f"openai:{self.model}@{redacted_url(self.base_url)}")

    def missing_key(self) -> str | None:
        # OpenAI's own server needs a key; local servers usually take any, or none.
        if self._secret() is None and self.base_url == OPENAI_BASE_URL:
            return (
                f"{self._where()}: set the environment variable {self.api_key_env} to the API key"
            )
        return None

    def _asker(self) -> Asker:
        return Asker(self._where(), self.model, self.api_key_env, self.system_role)

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
        missing = self.missing_key()
        if missing is not None:
            raise LLMAuthError(missing)
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

    def _request(self, messages: Sequence[Message], config: GenerationConfig) -> dict[str, Any]:
        kwargs: dict[str, Any] = {
            "model": self.model,
            "messages": messages_payload(messages, self.system_role, self.takes_images),
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
            level = self.structured_level(config.schema_name)
        ends_at = time.monotonic() + config.timeout_s
        adapted = adaptation(self.endpoint)
        refused: list[RefusedRequest] = []
        # A level a bare 400 (naming nothing) made this call step below: kept for the
        # endpoint only once a lower level is answered. A 400 the plain prompt gets as
        # well was never about the format (a proxy's fault, a bad request).
        unexplained: StructuredLevel | None = None
        # Where the levels this call steps down to are kept: the endpoint, or this schema
        # alone once the endpoint refused the schema itself (the levels below are refused
        # for it then: OpenAI takes no schema beside json_object, and refuses that for
        # every schema).
        keep_at = self.endpoint
        try:
            while True:
                request = adapted.apply(kwargs)
                if level is not None:
                    fmt = response_format(level, config.json_schema or {}, config.schema_name)
                    if fmt is not None:
                        request["response_format"] = fmt
                unsent = tuple(sorted(p for p in adapted.server_defaults if p in kwargs))
                # Timed from here: making a client (a process's first also loads the
                # library's request code) is set-up, not the model's latency.
                client = self._checkout()
                started = time.perf_counter()
                try:
                    response, body = self._create_by(ends_at, request, client)
                    break
                except FormatRefused as refusal:
                    lower = self._step_down(level, refusal)  # raises when nothing is left
                    what = f"structured output level {level!r} refused"
                    refused.append(refusal.record(what, started, level, unsent))
                    assert level is not None  # _step_down raised otherwise
                    if refusal.one_schema:
                        keep_at = self.schema_endpoint(config.schema_name)
                    if refusal.named:  # known now, whatever the next request does
                        remember_level(keep_at, lower)
                    elif refused_without_reason(self.endpoint, level):
                        # A first bare 400 (maybe a one-off fault) steps down for this
                        # call only; a second is believed if a lower level is answered.
                        unexplained = lower
                    level = lower
                except ParameterRefused as refusal:
                    found = self._adapt(adapted, refusal)  # raises when nothing is left
                    what = f"parameter {refusal.parameter!r} refused"
                    refused.append(refusal.record(what, started, level, unsent))
                    adapted = found
                    remember_adaptation(self.endpoint, adapted)
            latency = time.perf_counter() - started  # the answered request's own time
            if unexplained is not None:
                remember_level(keep_at, unexplained)
            return self._completion(
                response, body, latency, level, unsent, tuple(refused), config.max_tokens
            )
        except LLMError as error:
            # The requests refused before this failure were sent all the same: the client
            # records them from here.
            error.refused = tuple(refused)
            raise

    def _adapt(self, adapted: RequestAdaptation, refusal: ParameterRefused) -> RequestAdaptation:
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

    def _step_down(self, level: StructuredLevel | None, refusal: FormatRefused) -> StructuredLevel:
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

    def _create_by(self, ends_at: float, kwargs: dict[str, Any], client: Any) -> tuple[Any, str]:
        """One request on ``client`` (checked out; checked in again unless abandoned),
        answered in full before ``ends_at`` (``time.monotonic``) or given up: the parsed
        answer and its body."""
        timeout_s = kwargs["timeout"]
        left = ends_at - time.monotonic()
        if left <= 0.0:
            self._checkin(client)
            raise timed_out(self._where(), timeout_s)
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
            raise timed_out(self._where(), timeout_s)
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
            quota = quota_error(error, self._scrub(body_text(error)), self._where())
            if quota is not None:
                raise quota from None
            headers = error.response.headers
            wait_s = retry_after_s(headers)
            if wait_s is None:  # OpenAI's own hints: its message, its rate-limit headers
                wait_s = rate_limit_wait_s(headers, str(getattr(error, "message", "") or ""))
            raise LLMTransientError(
                f"rate limited (HTTP 429): {brief(self._scrub(body_text(error)), 200)}", wait_s
            ) from None
        except openai.APITimeoutError:
            raise timed_out(self._where(), timeout_s) from None
        except openai.APIConnectionError as error:
            # A dead or unreachable endpoint: named, since a run may call several.
            raise LLMTransientError(
                self._scrub(f"{self._where()}: connection failed or body cut short: {error}")
            ) from None
        except openai.APIStatusError as error:
            raise status_error(
                error, self._scrub(body_text(error)), kwargs, self._asker()
            ) from None
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

    def _completion(
        self,
        response: Any,
        body: str,
        latency_s: float,
        level: StructuredLevel | None,
        server_defaults: tuple[str, ...],
        refused: tuple[RefusedRequest, ...] = (),
        budget: int | None = None,
    ) -> Completion:
        # Usage first: a response that fails below may still say what it billed, and the
        # failed attempt's record counts it.
        usage = reported_usage(response, budget)
        try:
            choice = response.choices[0]
            content = choice.message.content
            text = _content_text(content)
            if text is None:
                # Scrubbed, then cut: a key cut first is no longer the key scrub knows.
                shown = self._scrub(json.dumps(content, default=str))[:80]
                fault = LLMTransientError(
                    f"malformed response: the message content is {type(content).__name__} "
                    f"{shown}, not text"
                )
                raise _with_usage(fault, usage)
            text = self._scrub(text)
            # As the server said it: None when it gave no reason (not "stop", which would
            # say the model ended its answer itself).
            reason = getattr(choice, "finish_reason", None)
            finish = None if reason is None else str(reason)
            declined = getattr(choice.message, "refusal", None)
            if isinstance(declined, str) and declined.strip():
                # OpenAI's structured outputs: the model declined; its reason is what it
                # said. Content beside a refusal is not an answer either: it is kept after
                # the reason, for the record, and never parsed.
                reason = self._scrub(declined)
                text = f"{reason}\n[content beside the refusal] {text}" if text else reason
                finish = "refusal"
            if finish == "error":
                # Gateways end a generation that failed on their side with this reason:
                # what came before it is not an answer. Retried as a fault.
                fault = LLMTransientError(
                    "the server's generation failed (finish_reason 'error'); what came back: "
                    f"{excerpt(text, self._secret())}"
                )
                raise _with_usage(fault, usage)
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
            raise _with_usage(fault, usage) from None
        return Completion(
            text=text,
            backend=self.name,
            model=self.model,
            prompt_tokens=usage.prompt_tokens,
            completion_tokens=usage.completion_tokens,
            cached_prompt_tokens=usage.cached_prompt_tokens,
            reasoning_tokens=usage.reasoning_tokens,
            latency_s=latency_s,
            finish_reason=finish,
            structured_output=level,
            server_defaults=server_defaults,
            refused=refused,
        )


def _with_usage(fault: LLMTransientError, usage: Usage) -> LLMTransientError:
    """``fault`` with what its response billed, for the failed attempt's record."""
    fault.prompt_tokens, fault.completion_tokens = usage.prompt_tokens, usage.completion_tokens
    fault.cached_prompt_tokens = usage.cached_prompt_tokens
    return fault


def _content_text(content: Any) -> str | None:
    """A message's content as text: a string; a list of content parts (some servers answer
    in the request's form) as its text parts joined; none as empty; ``None`` for anything
    else (no text: a malformed response)."""
    if content is None or isinstance(content, str):
        return content or ""
    if isinstance(content, list) and all(
        isinstance(part, dict) and part.get("type") == "text" and isinstance(part.get("text"), str)
        for part in content
    ):
        return "".join(part["text"] for part in content)
    return None
