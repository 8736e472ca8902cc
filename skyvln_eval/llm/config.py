"""Typed configuration of an LLM backend and the client around it (YAML-loadable)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from skyvln_eval.llm.cache import ResponseCache
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.prices import load_prices
from skyvln_eval.llm.registry import create_backend
from skyvln_eval.llm.retry import RetryPolicy
from skyvln_eval.llm.types import GenerationConfig


class RetryConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    max_attempts: int = Field(default=4, ge=1, le=20)
    initial_delay_s: float = Field(default=0.5, ge=0.0)
    multiplier: float = Field(default=2.0, ge=1.0)
    max_delay_s: float = Field(default=20.0, ge=0.0)
    jitter: float = Field(default=0.25, ge=0.0, le=1.0)
    max_retry_after_s: float = Field(default=60.0, ge=0.0)

    def policy(self, seed: int = 0) -> RetryPolicy:
        return RetryPolicy(**self.model_dump(), seed=seed)


class LLMConfig(BaseModel):
    """Which backend (``"rule"``, ``"openai:gpt-4o"``, ``"replay:openai:gpt-4o"``, ...), its
    server and decoding settings, retries, concurrency, cache and price table.

    The API key is never part of the configuration: ``api_key_env`` names the environment
    variable it is read from.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: str = "rule"
    base_url: str | None = None
    api_key_env: str = "OPENAI_API_KEY"
    takes_images: bool = False
    structured_output: Literal["auto", "on", "off"] = "auto"
    temperature: float = Field(default=0.0, ge=0.0, le=2.0)
    top_p: float = Field(default=1.0, gt=0.0, le=1.0)
    max_tokens: int = Field(default=512, ge=16, le=32768)
    seed: int | None = 0
    timeout_s: float = Field(default=60.0, gt=0.0)
    max_concurrency: int = Field(default=4, ge=1, le=256)
    retry: RetryConfig = RetryConfig()
    cache_path: str | None = None
    prices_path: str | None = None

    def generation(self, **overrides: Any) -> GenerationConfig:
        """Decoding settings for one kind of call (``json_schema`` etc. as overrides)."""
        return GenerationConfig(
            temperature=self.temperature,
            top_p=self.top_p,
            max_tokens=self.max_tokens,
            seed=self.seed,
            timeout_s=self.timeout_s,
            **overrides,
        )

    def backend_options(self) -> dict[str, Any]:
        name = self.backend.partition(":")[0]
        if name == "openai":
            return {
                "base_url": self.base_url,
                "api_key_env": self.api_key_env,
                "takes_images": self.takes_images,
                "structured_output": self.structured_output,
            }
        if name == "replay":
            return {"base_url": self.base_url}
        return {}


def build_client(config: LLMConfig) -> LLMClient:
    """The backend named by ``config`` inside a client with its cache, retries and prices."""
    backend = create_backend(config.backend, **config.backend_options())
    cache = ResponseCache(Path(config.cache_path)) if config.cache_path else None
    return LLMClient(
        backend=backend,
        cache=cache,
        retry=config.retry.policy(seed=config.seed or 0),
        prices=load_prices(config.prices_path),
        max_concurrency=config.max_concurrency,
    )
