"""Any OpenAI-compatible chat-completions server (OpenAI, vLLM, Ollama, llama.cpp).

The official ``openai`` client (extra ``openai``) is imported on first use, never at
toolkit import. The API
key is read from the environment variable ``api_key_env`` when the client is made and
handed to the client only: it is not stored on the backend, not part of its identity or
of any cache key, and is scrubbed from every error message this module raises.

Images go as data URLs when the backend is told the model takes them (``takes_images``).
When a call asks for a JSON schema, it is sent as ``response_format`` (structured output);
a server that rejects it with HTTP 400 is remembered and prompted plainly from then on
(``structured_output="auto"``). The client's own retries are off (``max_retries=0``):
:class:`~skyvln_eval.llm.client.LLMClient` retries, so that every fault is recorded.
"""

from __future__ import annotations

import base64
import json
import logging
import os
import threading
import time
from collections.abc import Sequence
from typing import Any, Final, Literal

from skyvln_eval.errors import ConfigError, LLMError, LLMTransientError, MissingExtraError
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.types import Completion, GenerationConfig, Message

log = logging.getLogger(__name__)

OPENAI_BASE_URL: Final = "https://api.openai.com/v1"
StructuredMode = Literal["auto", "on", "off"]


def _retry_after_s(headers: Any) -> float | None:
    value = None if headers is None else headers.get("retry-after")
    try:
        return None if value is None else float(value)
    except ValueError:  # an HTTP date: fall back to our own backoff
        return None


class OpenAIBackend(LLMBackend):
    """Chat completions over the OpenAI protocol; see the module docstring."""

    name = "openai"
    kind = "llm"

    def __init__(
        self,
        model: str | None = None,
        base_url: str | None = None,
        api_key_env: str = "OPENAI_API_KEY",
        takes_images: bool = False,
        structured_output: StructuredMode = "auto",
    ) -> None:
        if not model:
            raise ConfigError(
                "the openai backend needs a model: 'openai:<model>', e.g. 'openai:gpt-4o'"
            )
        if structured_output not in ("auto", "on", "off"):
            raise ConfigError(
                f"structured_output must be auto, on or off, got {structured_output!r}"
            )
        self.model = model
        self.base_url = (base_url or OPENAI_BASE_URL).rstrip("/")
        self.api_key_env = api_key_env
        self.takes_images = takes_images
        self.structured_output = structured_output
        self._schema_refused = False
        self._client: Any = None
        self._lock = threading.Lock()

    def identity(self) -> dict[str, Any]:
        return {"backend": self.name, "model": self.model, "base_url": self.base_url}

    def _secret(self) -> str | None:
        return os.environ.get(self.api_key_env) or None

    def _scrub(self, text: str) -> str:
        secret = self._secret()
        return text.replace(secret, "[API key]") if secret else text

    def _get_client(self) -> Any:
        with self._lock:
            if self._client is None:
                try:
                    import openai
                except ImportError as error:  # pragma: no cover - the test extra installs openai
                    raise MissingExtraError("the openai backend", "openai", str(error)) from error
                secret = self._secret()
                if secret is None and self.base_url == OPENAI_BASE_URL:
                    raise LLMError(
                        f"set the environment variable {self.api_key_env} to call {self.base_url}"
                    )
                # Local servers usually accept any key; the client insists on one.
                self._client = openai.OpenAI(
                    api_key=secret or "unused", base_url=self.base_url, max_retries=0
                )
            return self._client

    def _payload(self, messages: Sequence[Message]) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for message in messages:
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

    def _wants_schema(self, config: GenerationConfig) -> bool:
        if config.json_schema is None or self.structured_output == "off":
            return False
        return not (self.structured_output == "auto" and self._schema_refused)

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        client = self._get_client()
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
        structured = self._wants_schema(config)
        if structured:
            kwargs["response_format"] = {
                "type": "json_schema",
                "json_schema": {
                    "name": config.schema_name,
                    "schema": config.json_schema,
                    "strict": True,
                },
            }
        started = time.perf_counter()
        try:
            response = self._create(client, kwargs)
        except _SchemaRefused:
            self._schema_refused = True
            log.warning(
                "%s refused response_format (structured output): prompting plainly from now on",
                self.base_url,
            )
            kwargs.pop("response_format")
            structured = False
            response = self._create(client, kwargs)
        latency = time.perf_counter() - started
        return self._completion(response, latency, structured)

    def _create(self, client: Any, kwargs: dict[str, Any]) -> Any:
        import openai

        try:
            return client.chat.completions.create(**kwargs)
        except openai.RateLimitError as error:
            raise LLMTransientError(
                "rate limited (HTTP 429)", _retry_after_s(error.response.headers)
            ) from None
        except openai.APITimeoutError:
            raise LLMTransientError(f"no answer within {kwargs['timeout']} s (timeout)") from None
        except openai.APIConnectionError as error:
            raise LLMTransientError(
                self._scrub(f"connection failed or body cut short: {error}")
            ) from None
        except openai.APIStatusError as error:
            status = error.status_code
            if status >= 500:
                raise LLMTransientError(
                    f"server error (HTTP {status})", _retry_after_s(error.response.headers)
                ) from None
            if status == 400 and "response_format" in kwargs and self.structured_output == "auto":
                raise _SchemaRefused() from None
            raise LLMError(
                self._scrub(f"request refused (HTTP {status}): {error.message}")
            ) from None
        except (openai.APIResponseValidationError, json.JSONDecodeError, ValueError) as error:
            raise LLMTransientError(
                self._scrub(f"malformed response: {type(error).__name__}")
            ) from None

    def _completion(self, response: Any, latency_s: float, structured: bool) -> Completion:
        try:
            choice = response.choices[0]
            text = choice.message.content or ""
            usage = response.usage
            prompt_tokens = int(getattr(usage, "prompt_tokens", 0) or 0)
            completion_tokens = int(getattr(usage, "completion_tokens", 0) or 0)
            finish = str(choice.finish_reason or "stop")
        except (AttributeError, IndexError, TypeError) as error:
            raise LLMTransientError(
                f"malformed response: no choices ({type(error).__name__})"
            ) from None
        return Completion(
            text=text,
            backend=self.name,
            model=self.model,
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            latency_s=latency_s,
            finish_reason=finish,
            structured=structured,
        )


class _SchemaRefused(Exception):
    """The server answered HTTP 400 to a request carrying ``response_format``."""
