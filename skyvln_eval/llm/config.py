"""Typed configuration of an LLM backend and the client around it (YAML-loadable)."""

from __future__ import annotations

import re
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from pydantic import Field, field_validator, model_validator

from skyvln_eval.config_model import StrictModel
from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.llm.cache import ResponseCache
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.negotiation import StructuredSetting
from skyvln_eval.llm.prices import load_prices
from skyvln_eval.llm.redact import redacted_url, refuse_secrets_in_url
from skyvln_eval.llm.registry import check_spec, create_backend
from skyvln_eval.llm.retry import RetryPolicy
from skyvln_eval.llm.types import GenerationConfig


class RetryConfig(StrictModel):
    max_attempts: int = Field(default=4, ge=1, le=20)
    initial_delay_s: float = Field(default=0.5, ge=0.0)
    multiplier: float = Field(default=2.0, ge=1.0)
    max_delay_s: float = Field(default=20.0, ge=0.0)
    jitter: float = Field(default=0.25, ge=0.0, le=1.0)
    max_retry_after_s: float = Field(default=60.0, ge=0.0)
    deadline_s: float | None = Field(
        default=None,
        gt=0.0,
        description="the whole call, every attempt and wait (default: timeout_s x max_attempts)",
    )

    def policy(self, seed: int = 0, default_deadline_s: float | None = None) -> RetryPolicy:
        settings = self.model_dump()
        if settings["deadline_s"] is None:
            settings["deadline_s"] = default_deadline_s
        return RetryPolicy(**settings, seed=seed)


@dataclass(frozen=True)
class RepairPolicy:
    """How unusable answers are asked for again: how often, how hot, with what budget."""

    repairs: int = 1
    temperature: float = 0.7
    budget_factor: float = 2.0


#: Default ``max_tokens`` per agent module: the sub-goal list of a long dialog needs more
#: room than a one-word match level.
DEFAULT_BUDGETS: dict[str, int] = {
    "subgoals": 1024,
    "hsd_describe": 256,
    "hsd_rank": 256,
    "motion": 512,
    "navgpt": 512,
    "clarify": 192,
}
#: Every agent module that calls an LLM, by the name ``budgets`` gives it: those with a
#: default budget and the VLM detector's ``detect`` (at ``max_tokens`` unless given one).
LLM_MODULES: tuple[str, ...] = (*DEFAULT_BUDGETS, "detect")


#: What follows an '@' of a backend spec and is a server written without its scheme: a
#: host with a port or a path, localhost or an IPv4 address ('model@2024' is a model id).
_SERVER_WITHOUT_SCHEME = re.compile(
    r"(localhost|\d{1,3}(\.\d{1,3}){3})(:\d+)?(/\S*)?|[\w.-]+:\d+(/\S*)?|[\w-]+(\.[\w-]+)+/\S*"
)


#: A URL's scheme and "://": a backend spec's server starts at the first one.
_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://")
#: 'user:password@host' after a spec's '@', written without a scheme: a model id has no
#: such part, and the password would be sent to api.openai.com in the model's name.
_CREDENTIALS_WITHOUT_SCHEME = re.compile(r"@[^@\s/]*:[^@\s/]*@[\w.-]+")


def _checked_server(url: str, where: str) -> str:
    """``url`` if it is an http(s) URL with a host and nothing secret in it (no credentials,
    query or fragment); else the error says how to write it (a server without its scheme
    went to OpenAI's as a model name, or failed every call). Errors show it redacted."""
    try:
        refuse_secrets_in_url(url, where)
    except ConfigError as error:
        raise ValueError(str(error)) from None
    parts = urllib.parse.urlsplit(url)
    if parts.scheme in ("http", "https") and parts.netloc:
        return url
    if not parts.scheme or _SERVER_WITHOUT_SCHEME.fullmatch(url):
        hint = f": write http://{url} (or https://)"
    else:
        hint = ": a server is an http:// or https:// URL"
    raise ValueError(f"{where} {url!r} is not an http(s) URL with a host{hint}")


def shown_backend(spec: str) -> str:
    """A backend spec (or what was given as one) as messages show it: from its first URL
    scheme on, else after its first '@', the server, perhaps with credentials or a query,
    redacted by :func:`~skyvln_eval.llm.redact.redacted_url`."""
    found = _SCHEME.search(spec)
    if found is not None:
        return spec[: found.start()] + redacted_url(spec[found.start() :])
    name, at, rest = spec.partition("@")
    return name + at + redacted_url(rest) if at else spec


def _split_server(backend: str) -> tuple[str, str, str]:
    """``backend`` as (spec, '@', server) like ``str.rpartition('@')``, but a server given
    with its scheme starts at the '@' before its first scheme: the server may have an '@'
    of its own ('openai:m@http://user:pw@host/v1' names 'http://user:pw@host/v1', refused)."""
    found = _SCHEME.search(backend)
    if found is None or not backend[: found.start()].endswith("@"):
        return backend.rpartition("@")
    return backend[: found.start() - 1], "@", backend[found.start() :]


#: How :attr:`LLMConfig.answered_by` marks a backend whose server is sent the task data.
TASK_DATA_PREFIX: Final = "task-data:"


class LLMConfig(StrictModel):
    """Which backend (``"rule"``, ``"openai:gpt-4o"``, ``"replay:openai:gpt-4o"``, ...), its
    server and decoding settings, retries, repair, concurrency, cache and price table.

    The API key is never part of the configuration: ``api_key_env`` names the environment
    variable it is read from. A server (``base_url``, or the one a spec names after '@')
    with credentials, a query or a fragment is refused: its URL is written into run
    configs, episode logs, table labels and messages.

    ``timeout_s`` bounds one attempt from connect to last byte (a server that answers a
    byte at a time cannot stretch it), ``retry.deadline_s`` the whole call with its
    retries (default ``timeout_s`` times ``retry.max_attempts``). ``max_tokens`` is the
    budget of a call; ``budgets`` gives agent modules (those of
    :data:`LLM_MODULES`) their own, over :data:`DEFAULT_BUDGETS` (e.g. ``{motion: 1024}``
    changes only the motion module's). An unusable answer is asked for again ``repairs``
    times, at ``repair_temperature`` (above the first try's, so that the same mistake is not
    simply repeated) and, when the answer was cut off at the budget, with
    ``repair_budget_factor`` times the budget.
    """

    backend: str = "rule"
    base_url: str | None = None
    api_key_env: str = "OPENAI_API_KEY"
    takes_images: bool = False
    image_max_side_px: int = Field(default=512, ge=32, le=4096)
    structured_output: StructuredSetting = "auto"
    send_task_data: bool = Field(
        default=False, description="test servers only: add each request's task data to its body"
    )
    system_role: bool = Field(
        default=True,
        description="false for models without a system role (Gemma): the system prompt "
        "opens the first user message",
    )
    extra_body: dict[str, Any] = Field(
        default_factory=dict,
        description="fields added to every request body, e.g. {reasoning_effort: low} "
        "(openai backend); part of the cache key",
    )
    temperature: float = Field(default=0.0, ge=0.0, le=2.0)
    top_p: float = Field(default=1.0, gt=0.0, le=1.0)
    max_tokens: int = Field(default=512, ge=16, le=32768)
    budgets: dict[str, int] = Field(default_factory=lambda: dict(DEFAULT_BUDGETS))
    repairs: int = Field(default=1, ge=0, le=5)
    repair_temperature: float = Field(default=0.7, ge=0.0, le=2.0)
    repair_budget_factor: float = Field(default=2.0, ge=1.0, le=16.0)
    seed: int | None = 0
    timeout_s: float = Field(default=60.0, gt=0.0)
    max_concurrency: int = Field(default=4, ge=1, le=256)
    retry: RetryConfig = RetryConfig()
    cache_path: str | None = None
    prices_path: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _server_in_backend(cls, data: Any) -> Any:
        """``backend: openai:<model>@<base_url>`` (the form ``$SKYVLN_EVAL_BACKENDS`` takes)
        as ``backend: openai:<model>`` with that ``base_url``: read as a model name, the
        server part was sent to api.openai.com."""
        if not isinstance(data, dict) or not isinstance(data.get("backend"), str):
            return data
        spec, at, url = _split_server(data["backend"])
        shown = shown_backend(data["backend"])
        if not _SCHEME.search(data["backend"]) and _CREDENTIALS_WITHOUT_SCHEME.search(
            data["backend"]
        ):
            _checked_server(data["backend"].partition("@")[2], f"backend {shown!r}: the server")
        if at and (_SERVER_WITHOUT_SCHEME.fullmatch(url) or "://" in url):
            # A server without its scheme, or with another than http(s) ('@ftp://x' was
            # part of a model name, sent to api.openai.com), or with credentials or a
            # query: raises, saying how to write it.
            _checked_server(url, f"backend {shown!r}: the server")
        if not at or not url.startswith(("http://", "https://")):
            return data  # no server named ('@' may be part of a model id: 'model@2024')
        if not spec.partition(":")[2]:
            raise ValueError(f"backend {shown!r}: expected '<backend>:<model>@<url>'")
        given = data.get("base_url")
        if given is not None and given != url:
            raise ValueError(
                f"backend {shown!r} names the server {url!r} and base_url is "
                f"{redacted_url(str(given))!r}: give it once"
            )
        return {**data, "backend": spec, "base_url": url}

    @field_validator("base_url")
    @classmethod
    def _server_url(cls, url: str | None) -> str | None:
        return None if url is None else _checked_server(url, "base_url")

    @field_validator("backend")
    @classmethod
    def _known_backend(cls, spec: str) -> str:
        # Checked on load, name and model ('openai:' has none), so that a misspelt backend
        # stops a run before its first episode rather than failing in each.
        try:
            check_spec(spec)
        except ConfigError as error:
            raise ValueError(str(error)) from None
        return spec

    @field_validator("extra_body")
    @classmethod
    def _extra_body_fields(cls, extra_body: dict[str, Any]) -> dict[str, Any]:
        # Checked on load, as the backend is: a run stops before its first episode.
        from skyvln_eval.llm.openai_request import checked_extra_body

        try:
            return checked_extra_body(extra_body)
        except ConfigError as error:
            raise ValueError(str(error)) from None

    @field_validator("budgets")
    @classmethod
    def _budgets_in_range(cls, budgets: dict[str, int]) -> dict[str, int]:
        for module, tokens in budgets.items():
            # A misspelt module's budget would go unused, silently: its module kept another.
            if module not in LLM_MODULES:
                raise ValueError(str(UnknownNameError("agent module", module, LLM_MODULES)))
            if not 16 <= tokens <= 32768:
                raise ValueError(f"budget of {module!r} must be in [16, 32768], got {tokens}")
        # Over the defaults: {motion: 4096} alone left the other modules at max_tokens.
        return {**DEFAULT_BUDGETS, **budgets}

    @model_validator(mode="after")
    def _replay_has_a_cache(self) -> LLMConfig:
        # Checked on load: without one, every episode of the run failed on its own.
        if self.backend.startswith("replay:") and not self.cache_path:
            raise ValueError(
                f"backend {self.backend!r} answers only from the response cache: set "
                "cache_path to the cache the replayed backend's run wrote"
            )
        return self

    def generation(self, module: str | None = None, **overrides: Any) -> GenerationConfig:
        """Decoding settings for ``module``'s calls (``json_schema`` etc. as overrides)."""
        budget = self.budgets.get(module, self.max_tokens) if module else self.max_tokens
        settings: dict[str, Any] = {
            "temperature": self.temperature,
            "top_p": self.top_p,
            "max_tokens": budget,
            "seed": self.seed,
            "timeout_s": self.timeout_s,
        }
        return GenerationConfig(**(settings | overrides))

    @property
    def call_deadline_s(self) -> float:
        """Seconds one logical call may take, every attempt and wait included."""
        return self.retry.deadline_s or self.timeout_s * self.retry.max_attempts

    def repair_policy(self) -> RepairPolicy:
        return RepairPolicy(self.repairs, self.repair_temperature, self.repair_budget_factor)

    def missing_key(self) -> str | None:
        """What to set when the backend needs an API key the environment lacks (the
        backend's own rule, :meth:`~skyvln_eval.llm.base.LLMBackend.missing_key`), else
        ``None``. Makes the backend: its optional dependencies are imported."""
        return create_backend(self.backend, **self.backend_options()).missing_key()

    @property
    def answered_by(self) -> str:
        """What answers the calls, as the results record it: the backend, marked
        ``task-data:`` when the server is sent each request's task data (a test server
        answers from it as the rule stand-in does: not a model's answer)."""
        return f"{TASK_DATA_PREFIX}{self.backend}" if self.send_task_data else self.backend

    def backend_options(self) -> dict[str, Any]:
        name = self.backend.partition(":")[0]
        if name == "openai":
            return {
                "base_url": self.base_url,
                "api_key_env": self.api_key_env,
                "takes_images": self.takes_images,
                "structured_output": self.structured_output,
                "send_task_data": self.send_task_data,
                "system_role": self.system_role,
                "extra_body": self.extra_body,
            }
        if name == "replay":
            return {
                "base_url": self.base_url,
                "system_role": self.system_role,
                "extra_body": self.extra_body,
                "send_task_data": self.send_task_data,
                "structured_output": self.structured_output,
            }
        return {}


def build_client(config: LLMConfig) -> LLMClient:
    """The backend named by ``config`` inside a client with its cache, retries and prices."""
    backend = create_backend(config.backend, **config.backend_options())
    cache = ResponseCache(Path(config.cache_path)) if config.cache_path else None
    return LLMClient(
        backend=backend,
        cache=cache,
        retry=config.retry.policy(seed=config.seed or 0, default_deadline_s=config.call_deadline_s),
        prices=load_prices(config.prices_path),
        max_concurrency=config.max_concurrency,
    )
